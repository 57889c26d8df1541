"""bench opcua's diagnostic modes: a bad mode list is refused before anything starts; the ballast is the
inert, linked heap it claims to be."""

from __future__ import annotations

import gc
from pathlib import Path

import pytest

from bench import opcua
from bench.opcua_ballast import ballast


@pytest.mark.parametrize("modes", [("idle",), ("off", "turbo")])
def test_modes_must_include_off_and_be_known(modes: tuple[str, ...]) -> None:
    with pytest.raises(ValueError, match="opcua modes must include off"):
        opcua.run(modes=modes)


def test_diagnostic_modes_serve_no_client() -> None:
    assert "threaded: false" in opcua.opcua_section("idle", 7, Path("/p"))
    assert opcua.opcua_section("ballast", 7, Path("/p")) == ""


def test_ballast_nodes_are_tracked_and_linked() -> None:
    nodes = ballast(50)
    assert len(nodes) == 50
    assert all(gc.is_tracked(node) and len(node.references) == 1 for node in nodes)
    assert {id(node.references[0]) for node in nodes} == {id(node) for node in nodes}
