"""The example configs and systemd units shipped inside the wheel, so an installed focas-edge can write them out.

They live in the repository's config/ and systemd/ (edge/bundled/ links to both), one copy for the
checkout, the wheel and the .deb.
"""

from __future__ import annotations

from importlib.resources import files
from importlib.resources.abc import Traversable


def bundled(kind: str) -> list[Traversable]:
    """The files of one kind, 'config' (example YAML) or 'systemd' (units and drop-ins), by name."""
    folder = files("edge").joinpath("bundled", kind)
    return sorted((f for f in folder.iterdir() if f.is_file()), key=lambda f: f.name)
