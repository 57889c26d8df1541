"""The library host's YAML file: the shipped example loads; bad files list every problem."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from edge import ConfigError
from edge.focas.model import ParamType
from edge.fwlib.settings import HostMachine, load_settings

EXAMPLE = Path(__file__).resolve().parents[3] / "config" / "fwlib-host.yaml"


def test_the_example_config_loads() -> None:
    settings = load_settings(EXAMPLE)
    assert settings.socket_mode == 0o600
    [machine] = settings.machines
    target = machine.target()
    assert (target.host, target.port) == ("192.168.10.21", 8193)
    assert target.param_types[6711] == ParamType.TWO_WORD and target.param_types[1815] == ParamType.BIT
    assert machine.address().path == "/run/focas-edge-fwlib/mill-1.sock"


def test_every_problem_is_listed(tmp_path: Path) -> None:
    config = tmp_path / "host.yaml"
    config.write_text(
        "library: /x.so\nsocket_mode: 'rw'\nmachines:\n"
        "  - {name: a, cnc: '10.0.0.1:99999', listen: 'unix:/run/a.sock'}\n"
        "  - {name: b, cnc: 10.0.0.2, listen: 'unix:/run/a.sock', params: {1: triple}}\n")
    with pytest.raises(ConfigError) as caught:
        load_settings(config)
    text = str(caught.value)
    assert "socket_mode" in text and "99999" in text and "machines.1.params.1" in text


def test_duplicate_sockets_and_remote_listeners_are_refused(tmp_path: Path) -> None:
    config = tmp_path / "host.yaml"
    config.write_text("library: /x.so\nmachines:\n"
                      "  - {name: a, cnc: 10.0.0.1, listen: 'unix:/run/a.sock'}\n"
                      "  - {name: b, cnc: 10.0.0.2, listen: 'unix:/run/a.sock'}\n"
                      "  - {name: c, cnc: 10.0.0.3, listen: 'tcp:192.168.1.5:18193'}\n")
    with pytest.raises(ConfigError) as caught:
        load_settings(config)
    assert "also a's" in str(caught.value) and "not loopback" in str(caught.value)
    config.write_text("library: /x.so\nallow_remote: true\nmachines:\n"
                      "  - {name: c, cnc: 10.0.0.3, listen: 'tcp:192.168.1.5:18193'}\n")
    assert load_settings(config).machines[0].address().port == 18193


@pytest.mark.parametrize(("cnc", "host", "port"), [
    ("10.0.0.1", "10.0.0.1", 8193), ("10.0.0.1:9000", "10.0.0.1", 9000), ("[fd00::5]:8194", "fd00::5", 8194),
])
def test_cnc_addresses_parse_as_the_daemons_do(cnc: str, host: str, port: int) -> None:
    machine = HostMachine(name="m", cnc=cnc, listen="unix:/run/m.sock")
    assert (machine.target().host, machine.target().port) == (host, port)


@pytest.mark.parametrize("cnc", ["unix:/run/cnc.sock", ":8193", "10.0.0.1:http"])
def test_a_cnc_address_that_is_not_host_port_is_refused(cnc: str) -> None:
    with pytest.raises(ValidationError, match="cnc"):
        HostMachine(name="m", cnc=cnc, listen="unix:/run/m.sock")
