"""docs/topics.md's metric catalogue against real births: every metric in the NBIRTH and in a DBIRTH of
every simulator profile is listed there with its Sparkplug datatype and unit, and every listed metric is
in one of those births, so the catalogue cannot drift from what the daemon publishes."""

from __future__ import annotations

import asyncio
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.publish.payload import METRIC_TYPE
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from edge.sim.profiles import PROFILES
from tests.helpers import Mosquitto
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer, properties

pytestmark = pytest.mark.integration

TOPICS_MD = Path(__file__).resolve().parents[2] / "docs" / "topics.md"
# A plan using every optional family, so every catalogued metric can appear.
RICH_POLL = ("{positions: [absolute, machine, relative, distance], macros: [500], "
             "pmc: [{range: D2204, data_type: word}, {range: R160, data_type: bit}], "
             "params: [6711, {number: 1850, axis: all}], diags: [410, {number: 980, axis: 1}], tool_offsets: 1}")


@dataclass(frozen=True)
class Row:
    pattern: str
    datatype: str
    units: frozenset[str]
    regex: re.Pattern[str]


PLACEHOLDERS = {"<n>": r"\d+", "<area>": "[A-Z]", "<axis>": "[^/.]+", "<state>": "[A-Z_]+"}


def catalogue(section: str) -> list[Row]:
    """The rows of one catalogue table (`### <section>`): `name pattern` | Sparkplug datatype | ... | unit."""
    text = TOPICS_MD.read_text()
    body = text.split(f"### {section}", 1)[1].split("\n#", 1)[0]
    rows = []
    for line in body.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 4 or not cells[0].startswith("`"):
            continue
        pattern = cells[0].strip("`")
        regex = re.compile("".join(PLACEHOLDERS[part] if part.startswith("<") else re.escape(part)
                                   for part in re.split(r"(<[^>]+>)", pattern)))
        units = frozenset(re.findall(r"`([^`]*)`", cells[3])) or frozenset({""})
        rows.append(Row(pattern, cells[1], units, regex))
    assert rows, f"no catalogue table under '### {section}' in {TOPICS_MD}"
    return rows


def check(metrics: list[tuple[str, str, str]], rows: list[Row], where: str) -> set[str]:
    """Every (name, datatype, unit) matches exactly one row with that datatype and unit; the patterns used."""
    used = set()
    for name, datatype, unit in metrics:
        matching = [row for row in rows if row.regex.fullmatch(name)]
        assert len(matching) == 1, f"{where}: metric {name!r} matches {[r.pattern for r in matching]}"
        row = matching[0]
        assert datatype == row.datatype and unit in row.units, \
            f"{where}: {name} is {datatype} {unit!r}, the catalogue says {row.datatype} {sorted(row.units)}"
        used.add(row.pattern)
    return used


def birth_metrics(observer: Observer, topic: str) -> list[tuple[str, str, str]]:
    (birth,) = [m for m in observer.on(topic)][:1]
    return [(m.name, METRIC_TYPE[m.datatype].value, str(properties(m).get("engUnit", "")))
            for m in birth.spb().metrics]


async def test_catalogue_matches_the_births_of_every_profile(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    profiles = sorted(PROFILES)
    async with Fleet([MachineSpec(profile=p) for p in profiles], base_port=0, packed_base_port=0) as fleet:
        machines = "".join(f"  - {{id: m{i}, host: 127.0.0.1, port: {m.port}, poll: {RICH_POLL}}}\n"
                           for i, m in enumerate(fleet))
        # The packed transport publishes what the native one cannot (alarm history, work offsets, modal, tool).
        machines += (f"  - {{id: mp, transport: packed, address: 'tcp:127.0.0.1:{fleet[0].packed_port}', "
                     "poll: {work_offsets: [54], modal: true, tool_number: true}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines,
                                                   "alarms: {mode: ActivePlusHistory}\n")))
        task = asyncio.create_task(daemon.run())
        try:
            for device in [*(f"m{i}" for i in range(len(profiles))), "mp"]:
                await observer.wait_topic(f"spBv1.0/plant/DBIRTH/gw/{device}", timeout=20)
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    node_rows, device_rows = catalogue("Node metrics (NBIRTH)"), catalogue("Device metrics (DBIRTH)")
    used_node = check(birth_metrics(observer, "spBv1.0/plant/NBIRTH/gw"), node_rows, "NBIRTH")
    used_device: set[str] = set()
    for i, profile in enumerate(profiles):
        used_device |= check(birth_metrics(observer, f"spBv1.0/plant/DBIRTH/gw/m{i}"), device_rows,
                             f"DBIRTH of {profile}")
    used_device |= check(birth_metrics(observer, "spBv1.0/plant/DBIRTH/gw/mp"), device_rows, "packed DBIRTH")
    assert {r.pattern for r in node_rows} == used_node, "catalogued node metrics no NBIRTH carries"
    assert {r.pattern for r in device_rows} == used_device, "catalogued device metrics no DBIRTH carries"
