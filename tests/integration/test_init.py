"""`focas-edge init` against simulated CNCs of every profile: the written config passes check-config and
polls what each control answered, no more."""

from __future__ import annotations

import contextlib
import re
import socketserver
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from edge.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, main
from edge.config import load_config
from edge.config.init_writer import STATUS_PERIODS_S
from edge.sim.fleet import Fleet, FleetThread, MachineSpec
from edge.sim.profiles import PROFILES

pytestmark = pytest.mark.integration

NAMES = ["mill-0if", "mill-16i", "mill-30i", "lathe-31i", "slow-30i", "lathe-2p"]
SLOW_S = 0.11  # slow-30i answers every request this late: one status batch fits a fifth of 1 s, nine trips do not


def test_init_writes_a_config_check_config_accepts_for_every_profile(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    specs = [MachineSpec(profile=name) for name in ("0i-F", "16i", "30i")]
    specs.append(MachineSpec(profile="31i", faults={"ew": {"read_macros": 6, "read_pmc": 1}}))
    specs.append(MachineSpec(profile="30i", faults={"latency": SLOW_S}))
    specs.append(MachineSpec(profile="31i-2p"))
    assert {spec.profile for spec in specs} == set(PROFILES)
    out = tmp_path / "edge.yaml"
    with FleetThread(Fleet(specs, base_port=0)) as fleet:
        addresses = [f"127.0.0.1:{machine.port}" for machine in fleet]
        code = main(["init", *addresses, "--names", ",".join(NAMES), "--broker", "mqtt.plant:1884",
                     "--node", "gw-7", "-o", str(out)])
    assert code == EXIT_OK, capsys.readouterr().err
    capsys.readouterr()
    assert main(["check-config", str(out)]) == EXIT_OK, capsys.readouterr()
    config = load_config(out, environ={})
    assert (config.mqtt.host, config.mqtt.effective_port) == ("mqtt.plant", 1884)
    assert config.mqtt.sparkplug is not None and config.mqtt.sparkplug.edge_node_id == "gw-7"
    assert not config.writes.enabled
    assert [m.id for m in config.machines] == NAMES
    assert [m.series for m in config.machines] == ["0i-FM", "16i-BM", "30i-BM", "31i-BT", "30i-BM", "31i-BT"]
    for machine in config.machines[:3]:
        poll = machine.poll
        assert poll.positions == ["absolute", "machine"] and poll.part_count
        assert [list(m.numbers) for m in poll.macros] == [[500, 501, 502, 503, 504, 505]]
        assert [p.range for p in poll.pmc] == ["F0-F3"]
        assert poll.periods.params == 60.0  # the status period is measured; the rest come from defaults
    # The status period is measured from the status group sent as ONE batch, as the daemon sends it (the fastest
    # of three). The simulators answer from a thread of this process, so a fast machine is only held to a
    # candidate period; the slow one's batch takes SLOW_S (> 0.1 s: not 0.5 s) and far less than 0.2 s (1 s),
    # where the nine sequential round trips the probe made (> 0.99 s) would have made it 5 s.
    fast = [machine.poll.periods.status for machine in config.machines[:3]]
    assert all(period in STATUS_PERIODS_S for period in fast), fast
    assert config.machines[4].poll.periods.status == 1.0, "one batch of a slow control, not its probe's trips"
    lathe = config.machines[3].poll
    assert lathe.macros == [] and lathe.pmc == [], "functions the control refused are left out"
    assert [m.paths for m in config.machines] == [1, 1, 1, 1, 1, 2], "a two-path lathe is configured with both paths"
    text = out.read_text()
    batch_ms = [float(ms) for ms in re.findall(r"# measured: one status batch took ([\d.]+) ms", text)]
    assert len(batch_ms) == len(NAMES) and SLOW_S * 1000 <= batch_ms[4] < 200, batch_ms
    assert "# macros: #500..#505 did not answer" in text
    assert yaml.safe_load(text)["writes"] == {"enabled": False}


def test_an_unreachable_cnc_is_a_comment_and_exit_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "edge.yaml"
    with FleetThread(Fleet([MachineSpec(profile="16i")], base_port=0)) as fleet:
        code = main(["init", f"127.0.0.1:{fleet[0].port}", "127.0.0.1:1", "--timeout", "2", "-o", str(out)])
    assert code == EXIT_FAILURE
    assert "127.0.0.1:1: connect" in capsys.readouterr().err
    text = out.read_text()
    assert "# NOT REACHED 127.0.0.1:1" in text
    assert [m.id for m in load_config(out, environ={}).machines] == [f"cnc-127-0-0-1-{fleet[0].port}"]


class _Banner(socketserver.BaseRequestHandler):
    """An SSH server's greeting: it speaks first."""

    def handle(self) -> None:
        self.request.sendall(b"SSH-2.0-OpenSSH_9.2p1 Debian-2\r\n")
        self.request.recv(64)


class _Http(socketserver.BaseRequestHandler):
    """A web server: silent until spoken to, then not FOCAS."""

    def handle(self) -> None:
        self.request.recv(64)
        self.request.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")


@contextlib.contextmanager
def serving(handler: type[socketserver.BaseRequestHandler]) -> Iterator[int]:
    with socketserver.ThreadingTCPServer(("127.0.0.1", 0), handler) as server:
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            yield server.server_address[1]
        finally:
            server.shutdown()
            thread.join()


def test_an_address_that_answers_but_not_as_focas_is_a_comment_saying_what_answered(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "edge.yaml"
    with FleetThread(Fleet([MachineSpec(profile="16i")], base_port=0)) as fleet, serving(_Banner) as ssh, \
            serving(_Http) as web:
        code = main(["init", f"127.0.0.1:{fleet[0].port}", f"127.0.0.1:{ssh}", f"127.0.0.1:{web}", "--timeout", "2",
                     "-o", str(out)])
    assert code == EXIT_FAILURE
    text = out.read_text()
    assert f"  # 127.0.0.1:{ssh} answered but not FOCAS: it sent 'SSH-2.0-OpenSSH_9.2p1 Debian-2'\n" in text
    assert f"  # 127.0.0.1:{web} answered but not FOCAS: the FOCAS hello got: " in text and "('HTTP')" in text
    assert "NOT REACHED" not in text
    assert f"127.0.0.1:{ssh} answered but not FOCAS" in capsys.readouterr().err
    assert [m.id for m in load_config(out, environ={}).machines] == [f"cnc-127-0-0-1-{fleet[0].port}"]


@pytest.mark.parametrize(("extra", "message"), [
    (["--names", "a"], "--names has 1 name(s) for 2 address(es)"),
    (["--names", "a,A"], "machine id(s) given twice (ids ignore case): A, a"),
    (["--names", "a,b/c"], "'b/c' contains /"),
    (["--group", "x#"], "'x#' contains #"),
    (["--broker", "mqtt..plant"], "mqtt..plant: 'mqtt..plant' is not a valid host name"),
])
def test_bad_usage_is_refused_before_anything_is_probed(extra: list[str], message: str, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["init", "127.0.0.1:1", "127.0.0.1:2", *extra, "-o", str(tmp_path / "x.yaml")]) == EXIT_USAGE
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.yaml").exists()


def test_an_existing_file_is_not_overwritten_without_force(tmp_path: Path) -> None:
    out = tmp_path / "edge.yaml"
    out.write_text("mine\n")
    assert main(["init", "127.0.0.1:1", "-o", str(out)]) == EXIT_USAGE
    assert out.read_text() == "mine\n"


def test_init_writes_the_bundled_units_out_too_running_this_installation(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The units run the focas-edge of the installation init runs from (this venv), not the .deb's /opt."""
    units = tmp_path / "units"
    repo_units = Path(__file__).resolve().parents[2] / "systemd"
    here = str(Path(sys.prefix) / "bin" / "focas-edge")
    with FleetThread(Fleet([MachineSpec(profile="16i")], base_port=0)) as fleet:
        args = ["init", f"127.0.0.1:{fleet[0].port}", "--units", str(units), "-o", str(tmp_path / "edge.yaml")]
        assert main(args) == EXIT_OK, capsys.readouterr().err
        written = {f.name: f.read_text() for f in units.iterdir()}
        assert written.keys() == {f.name for f in repo_units.iterdir() if f.is_file()}
        exec_starts = {name: [line for line in text.splitlines() if line.startswith("ExecStart=")]
                       for name, text in written.items()}
        assert exec_starts["focas-edge.service"] == [f"ExecStart={here} run --config /etc/focas-edge/edge.yaml"]
        assert exec_starts["focas-edge-fwlib-host.service"] == [
            f"ExecStart={here} fwlib-host --config /etc/focas-edge/fwlib-host.yaml"]
        if not Path("/opt/focas-edge").exists():
            assert not [name for name, text in written.items() if "/opt/" in text]
        for name, text in written.items():  # nothing else differs from the shipped files
            shipped = (repo_units / name).read_text().replace("/opt/focas-edge/bin/focas-edge", here)
            assert text.replace("ProtectHome=read-only", "ProtectHome=yes").replace(
                f"# {here} is under a home directory: read-only, not hidden\n", "") == shipped
        assert main(args) == EXIT_USAGE, "the units are not overwritten without --force"
        assert "use --force" in capsys.readouterr().err


def test_a_mistyped_cnc_address_is_refused_before_anything_is_probed(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["init", "192.168.10.577", "-o", str(tmp_path / "x.yaml")]) == EXIT_USAGE
    assert "192.168.10.577: '192.168.10.577' is not a valid IPv4 address (577 is more than 255)" in \
        capsys.readouterr().err
    assert not (tmp_path / "x.yaml").exists()


def test_init_acl_writes_the_broker_acl_beside_the_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "edge.yaml"
    with FleetThread(Fleet([MachineSpec(profile="30i")], base_port=0)) as fleet:
        code = main(["init", f"127.0.0.1:{fleet[0].port}", "--names", "m1", "--node", "gw-7", "--group", "site",
                     "-o", str(out), "--acl", "--acl-users", "line2-edge:mes-line2"])
    assert code == EXIT_OK, capsys.readouterr().err
    assert "mosquitto.acl" in capsys.readouterr().err
    acl = (tmp_path / "mosquitto.acl").read_text().splitlines()
    gateway = acl[acl.index("user line2-edge") + 1:acl.index("user mes-line2")]
    mes = acl[acl.index("user mes-line2") + 1:]
    assert "topic write spBv1.0/site/DDATA/gw-7/+" in gateway and "topic read spBv1.0/site/DCMD/gw-7/+" in gateway
    assert not any("CMD" in line or line.endswith("/cmd") for line in gateway if line.startswith("topic write"))
    commands = [line for line in mes if line.startswith("topic write")]
    assert commands == ["topic write spBv1.0/site/NCMD/gw-7", "topic write spBv1.0/site/DCMD/gw-7/+",
                        "topic write focas/site/gw-7/+/cmd"]  # the default JSON prefix names the gateway
    # The file exists now: a second run without --force refuses to overwrite it.
    assert main(["init", "127.0.0.1:1", "-o", str(tmp_path / "other.yaml"), "--acl",
                 str(tmp_path / "mosquitto.acl")]) == EXIT_USAGE
    assert "exists" in capsys.readouterr().err
