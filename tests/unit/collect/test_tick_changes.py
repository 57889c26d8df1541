"""A poll tick publishes exactly the values that moved, element by element for list reads (macros, PMC).

The tick offers a moved list's elements to change detection only where they differ from the last tick's
(edge.collect.poller); these tests hold that to what a full pass would publish, including after a write's
read-back moved a metric's reported value between two ticks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.floor import DroppingSink
from edge.collect import plan as pl
from edge.collect import poller as poller_module
from edge.collect.changes import ChangeDetector
from edge.collect.poller import MachinePoller
from edge.collect.settings import MachineSettings
from edge.config import parse_config
from edge.focas import items as it
from edge.focas.model import Capabilities, SysInfo
from edge.focas.session import CncSession, ItemResult
from edge.samples import MetricType, Sample
from edge.service.settings import machine_settings

CONFIG = """
mqtt: {host: 127.0.0.1, sparkplug: {group_id: g, edge_node_id: n}}
machines:
  - id: m1
    host: 127.0.0.1
    poll: {macros: [500-503], periods: {status: 1, macros: 1}}
"""


class ScriptedSession(CncSession):
    """Answers each macro read with the list the test set; every other read with an error-free default."""

    transport = "scripted"

    def __init__(self) -> None:
        super().__init__()
        self.macros: list[float | None] = [1.0, 2.0, 3.0, 4.0]

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(self.transport, frozenset({"ReadMacros", "ReadClock"}))

    async def _open(self) -> SysInfo:  # pragma: no cover - the test never connects
        raise AssertionError("not used")

    async def _close(self) -> None:
        pass

    async def _batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:
        # A fresh list every time, as the client decodes a moved answer anew.
        return [list(self.macros) if isinstance(item, it.ReadMacros) else None for item in items]

    async def _write_macro(self, number: int, value: float) -> None:
        raise AssertionError("not used")

    async def _write_pmc_bytes(self, area: str, start: int, data: bytes) -> None:
        raise AssertionError("not used")

    async def _write_param(self, number: int, axis: int, ptype: int, value: int | float) -> None:
        raise AssertionError("not used")


def _settings() -> MachineSettings:
    config = parse_config(CONFIG)
    return machine_settings(config, config.machines[0])


async def _ready(tmp_path: Path) -> tuple[MachinePoller, ScriptedSession, pl.MachinePlan]:
    session = ScriptedSession()
    session._connected = True
    poller = MachinePoller(_settings(), DroppingSink(), tmp_path, session_factory=lambda _machine: session)
    plan = pl.MachinePlan.build(poller.machine.poll)
    plan = pl.MachinePlan(tuple(r for r in plan.reads if r.group is pl.Group.MACROS), plan.periods)
    poller._full_plan = poller._plan = plan
    poller._changes = ChangeDetector(plan.deadbands())
    poller._last_raw = [poller_module._NOTHING] * len(plan.reads)
    return poller, session, plan


async def _tick_values(poller: MachinePoller, plan: pl.MachinePlan) -> dict[str, Any]:
    tick = await poller._tick(plan, frozenset({pl.Group.MACROS}))
    return {s.name: s.value for s in tick.samples if s.name.startswith("Macro/")}


def test_macro_reads_are_elementwise_and_status_is_not() -> None:
    plan = pl.MachinePlan.build(_settings().poll)
    kinds = {type(r.item).__name__: pl.elementwise(r) for r in plan.reads}
    assert kinds["ReadMacros"] is True
    assert kinds["ReadStatus"] is False


async def test_only_the_moved_elements_are_published(tmp_path: Path) -> None:
    poller, session, plan = await _ready(tmp_path)
    assert await _tick_values(poller, plan) == {"Macro/500": 1.0, "Macro/501": 2.0, "Macro/502": 3.0,
                                                "Macro/503": 4.0}
    session.macros = [1.0, 7.0, 3.0, None]
    assert await _tick_values(poller, plan) == {"Macro/501": 7.0, "Macro/503": None}
    session.macros = [1.0, 7.0, 3.0, None]
    assert await _tick_values(poller, plan) == {}
    session.macros = [math.nan, 7.0, 3.0, None]
    nan_tick = await _tick_values(poller, plan)
    assert list(nan_tick) == ["Macro/500"] and math.isnan(nan_tick["Macro/500"])
    session.macros = [math.nan, 7.0, 3.0, 0.0]
    assert await _tick_values(poller, plan) == {"Macro/503": 0.0}  # NaN stays NaN: not published again
    session.macros = [math.nan, 7, 3.0, 0.0]  # an int equal to the float before: the same Double value
    assert await _tick_values(poller, plan) == {}
    session.macros = [math.nan, 8, 3.0, 0.0]  # a moved int element is coerced alone, as the whole list would be
    moved = await _tick_values(poller, plan)
    assert moved == {"Macro/501": 8.0} and type(moved["Macro/501"]) is float


async def test_a_value_reported_between_ticks_is_published_again_when_the_read_gives_the_old_one(
        tmp_path: Path) -> None:
    poller, session, plan = await _ready(tmp_path)
    await _tick_values(poller, plan)
    session.macros = [1.0, 2.0, 3.0, 5.0]  # the list moves (Macro/503), Macro/500 does not
    assert await _tick_values(poller, plan) == {"Macro/503": 5.0}
    # A write's read-back says Macro/500 is 9 now; the CNC then answers 1 again (another writer, a reset).
    await poller.report([Sample("Macro/500", 9.0, MetricType.DOUBLE, 1)])
    session.macros = [1.0, 2.0, 3.0, 6.0]
    assert await _tick_values(poller, plan) == {"Macro/500": 1.0, "Macro/503": 6.0}


async def test_an_element_the_last_answer_lacked_is_published(tmp_path: Path) -> None:
    poller, session, plan = await _ready(tmp_path)
    session.macros = [1.0, 2.0, 3.0]  # a short answer: Macro/503 has no value yet
    assert await _tick_values(poller, plan) == {"Macro/500": 1.0, "Macro/501": 2.0, "Macro/502": 3.0}
    session.macros = [1.0, 2.0, 3.0, 4.0]
    assert await _tick_values(poller, plan) == {"Macro/503": 4.0}
