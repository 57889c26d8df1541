"""The daemon's outputs: the publisher first, then the others; one that raises never stops the rest."""

from __future__ import annotations

from collections.abc import Sequence

from edge.samples import MetricSpec, MetricType, Sample
from edge.service.outputs import Outputs


class Recording:
    def __init__(self, calls: list[tuple[str, str]], name: str, fail: bool = False) -> None:
        self.calls, self.name, self.fail = calls, name, fail

    async def _note(self, kind: str) -> None:
        self.calls.append((self.name, kind))
        if self.fail:
            raise RuntimeError("broken output")

    async def device_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample]) -> None:
        await self._note("online")

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        await self._note("data")

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        await self._note("events")

    async def device_offline(self, device_id: str) -> None:
        await self._note("offline")


async def test_each_call_reaches_the_publisher_first_and_survives_a_broken_output() -> None:
    calls: list[tuple[str, str]] = []
    outputs = Outputs(Recording(calls, "mqtt"), [Recording(calls, "broken", fail=True), Recording(calls, "opcua")])
    sample = Sample("Macro/500", 1.0, MetricType.DOUBLE, 0)
    await outputs.device_online("m1", [MetricSpec("Macro/500", MetricType.DOUBLE)], [sample])
    await outputs.device_data("m1", [sample])
    await outputs.device_events("m1", [sample])
    await outputs.device_offline("m1")
    assert calls == [(name, kind) for kind in ("online", "data", "events", "offline")
                     for name in ("mqtt", "broken", "opcua")]
