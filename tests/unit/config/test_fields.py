"""Host names and IP addresses in the config are checked for form where the file is read, never resolved:
a mistyped address is refused with its line instead of being retried for ever."""

from __future__ import annotations

from pathlib import Path

import pytest

from edge import ConfigError
from edge.config import load_config
from edge.config.fields import check_host
from tests.unit.config.minimal import MINIMAL, parse, problems_of


@pytest.mark.parametrize("host", ["10.0.0.1", "192.168.10.255", "cnc-1", "cnc-1.plant.example", "broker_1",
                                  "localhost", "fe80::1", "[::1]", "::", "0.0.0.0", "host.example."])
def test_addresses_and_dns_names_pass(host: str) -> None:
    assert check_host(host) == host


@pytest.mark.parametrize(("host", "why"), [
    ("192.168.10.577", "'192.168.10.577' is not a valid IPv4 address (577 is more than 255)"),
    ("10.0.0", "'10.0.0' is not a valid IPv4 address (four numbers 0..255"),
    ("cnc 1", "'cnc 1' is not a valid host name: label 'cnc 1'"),
    ("-cnc", "label '-cnc'"),
    ("cnc..plant", "an empty label (two dots in a row)"),
    ("fe80::zz", "'fe80::zz' is not a valid IPv6 address"),
    (" cnc", "without spaces"),
    ("a" * 64, "label"),
])
def test_a_mistyped_address_or_name_is_refused_saying_why(host: str, why: str) -> None:
    with pytest.raises(ValueError) as info:
        check_host(host)
    assert why in str(info.value)


def test_every_host_key_is_checked() -> None:
    text = MINIMAL.replace("host: broker", "host: broker..x").replace("host: 10.0.0.1", "host: 10.0.0.256\n"
                                                                      "    fwlib_host: tcp:1.2.3.999:8200")
    problems = problems_of(text + "http: {host: 300.1.1.1}\nopcua: {host: 'a b'}\n")
    keys = sorted(p.split(":", 1)[0] for p in problems)
    assert keys == ["http.host", "machines[0].fwlib_host", "machines[0].host", "mqtt.host", "opcua.host"], problems
    assert parse(MINIMAL).mqtt.host == "broker"


def test_the_refusal_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "edge.yaml"
    path.write_text(MINIMAL.replace("host: 10.0.0.1", "host: 192.168.10.577"))
    with pytest.raises(ConfigError) as info:
        load_config(path)
    (problem,) = info.value.problems
    assert problem == ("machines[0].host: '192.168.10.577' is not a valid IPv4 address (577 is more than 255) "
                       "(line 7)")
