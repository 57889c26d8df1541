"""Every output of the collector's samples behind one DeviceSink: the MQTT publisher, then the others.

The pollers hand each machine's births, data, events and offlines to this one sink; it passes them to
the publisher first (MQTT timing unchanged) and then to each further output (the OPC UA server), whose
methods only post and return. A further output that raises is logged and skipped: it never stops the
publisher's data, nor the poll loop.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from edge.collect import DeviceSink
from edge.samples import MetricSpec, Sample

log = logging.getLogger(__name__)


class Outputs:
    def __init__(self, publisher: DeviceSink, others: Sequence[DeviceSink] = ()) -> None:
        self.publisher = publisher
        self.others = list(others)

    async def device_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample]) -> None:
        await self.publisher.device_online(device_id, specs, samples)
        for output in self.others:
            await self._guard(output.device_online(device_id, specs, samples), output, device_id)

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        await self.publisher.device_data(device_id, samples)
        for output in self.others:  # _guard, inline: every poll tick with a change comes this way
            try:
                await output.device_data(device_id, samples)
            except Exception:
                log.exception("output failed, skipped output=%s machine=%s", type(output).__name__, device_id)

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        await self.publisher.device_events(device_id, events)
        for output in self.others:
            await self._guard(output.device_events(device_id, events), output, device_id)

    async def device_offline(self, device_id: str) -> None:
        await self.publisher.device_offline(device_id)
        for output in self.others:
            await self._guard(output.device_offline(device_id), output, device_id)

    @staticmethod
    async def _guard(call: object, output: DeviceSink, device_id: str) -> None:
        try:
            await call  # type: ignore[misc]
        except Exception:
            log.exception("output failed, skipped output=%s machine=%s", type(output).__name__, device_id)
