"""The OPC UA server's work per value change, counted in one process: no client, no network, no crypto.

The fleet benchmark (bench/opcua.py) measures the whole gateway with a real client, on a shared host where
single timings wander; this one isolates what the server does for each changed value a client has
subscribed to (DataValue built, the monitored item told, the notification queued, the Publish response
encoded) and reports process CPU per notification, so an A/B of two branches is a counted comparison.

    python -m bench.opcua_notify [--machines 100] [--metrics 74] [--ticks 200] [--profile] [--no-client]

--no-client: the same value changes with nobody subscribed (the server's cost of a value no one reads).
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import pstats
import tempfile
import time
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.ua.ua_binary import struct_to_binary

from edge.opcua.server import GatewayServer
from edge.opcua.settings import OpcUaSettings
from edge.samples import MetricSpec, MetricType, Sample

KINDS = (MetricType.DOUBLE, MetricType.INT32, MetricType.BOOLEAN, MetricType.INT16, MetricType.STRING)
CHANGED_PER_TICK = 0.1  # the share of a machine's metrics that change between two polls


class _Request:
    """What a publish request carries that forwarding its response reads."""

    def __init__(self) -> None:
        self.results: list[ua.StatusCode] = []
        self.requesthdr = ua.RequestHeader()


def server_settings(prefix: str) -> OpcUaSettings:
    """An in-process server for counting: no security, anonymous, any free port, state in a fresh temp dir."""
    return OpcUaSettings(state_dir=Path(tempfile.mkdtemp(prefix=prefix)), host="127.0.0.1", port=0,
                         security=("None",), allow_anonymous=True)


def metric_specs(metrics: int) -> list[MetricSpec]:
    """`metrics` macros, their types cycling through KINDS."""
    return [MetricSpec(f"Macro/{i}", KINDS[i % len(KINDS)]) for i in range(metrics)]


async def measure(machines: int, metrics: int, ticks: int, profile: bool, client: bool = True) -> dict[str, Any]:
    gateway = GatewayServer(server_settings("opcua-notify-"))
    await gateway.start()
    try:
        specs = metric_specs(metrics)
        now_ms = int(time.time() * 1000)
        for m in range(machines):
            await gateway.machine_online(f"m{m}", specs, [_sample(s, 0, now_ms) for s in specs], frozenset())
        assert gateway.server is not None and gateway.space is not None
        iserver = gateway.server.iserver
        sent = {"bytes": 0, "responses": 0}

        async def forward(result: ua.PublishResult, request: _Request) -> None:
            response = ua.PublishResponse()
            response.Parameters = result
            result.Results = request.results
            sent["bytes"] += len(struct_to_binary(response))
            sent["responses"] += 1

        params = ua.CreateSubscriptionParameters(RequestedPublishingInterval=3_600_000, RequestedLifetimeCount=10**6,
                                                 RequestedMaxKeepAliveCount=10**5, PublishingEnabled=True)
        created = await iserver.subscription_service.create_subscription(params, forward, ua.NodeId(1, 0),
                                                                        request_callback=lambda _id: _Request())
        subscription = iserver.subscription_service.subscriptions[created.SubscriptionId]
        items = []
        for m in range(machines):
            for handle, spec in enumerate(specs):
                node = ua.NodeId(f"m{m}/Metrics/{spec.name}", gateway.space.ns)
                item = ua.MonitoredItemCreateRequest()
                item.ItemToMonitor = ua.ReadValueId(NodeId=node, AttributeId=ua.AttributeIds.Value)
                item.MonitoringMode = ua.MonitoringMode.Reporting
                item.RequestedParameters = ua.MonitoringParameters(ClientHandle=m * metrics + handle, QueueSize=10)
                items.append(item)
        if not client:
            items.clear()  # the subscription stays, with nothing to report
        created_items = await subscription.monitored_item_srv.create_monitored_items(
            ua.CreateMonitoredItemsParameters(SubscriptionId=created.SubscriptionId, ItemsToCreate=items))
        assert all(result.StatusCode.is_good() for result in created_items)
        await subscription.publish_results()  # the initial values
        sent["bytes"] = sent["responses"] = 0
        step = max(1, int(1 / CHANGED_PER_TICK))
        batches = [[[_sample(spec, tick, now_ms + tick) for spec in specs[(tick + m) % step::step]]
                    for m in range(machines)] for tick in range(1, ticks + 1)]
        changes = sum(len(batch) for tick in batches for batch in tick)
        profiler = cProfile.Profile() if profile else None
        started = time.process_time()
        if profiler is not None:
            profiler.enable()
        for tick in batches:
            for m, batch in enumerate(tick):
                await gateway.machine_data(f"m{m}", batch)
            await subscription.publish_results()
        if profiler is not None:
            profiler.disable()
        cpu = time.process_time() - started
        if profiler is not None:
            pstats.Stats(profiler).sort_stats("tottime").print_stats(25)
        return {"machines": machines, "monitored_items": len(items), "notifications": changes,
                "cpu_us_per_notification": cpu / changes * 1e6, "bytes_per_notification": sent["bytes"] / changes,
                "publish_responses": sent["responses"]}
    finally:
        await gateway.stop()


def _sample(spec: MetricSpec, tick: int, stamp_ms: int) -> Sample:
    value: object = {MetricType.DOUBLE: tick * 0.5, MetricType.INT32: tick, MetricType.BOOLEAN: tick % 2 == 1,
                     MetricType.INT16: tick % 1000, MetricType.STRING: f"O{tick:04d}"}[spec.type]
    return Sample(spec.name, value, spec.type, stamp_ms)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=100)
    parser.add_argument("--metrics", type=int, default=74)
    parser.add_argument("--ticks", type=int, default=200)
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--no-client", action="store_true", help="no monitored item: values nobody reads")
    args = parser.parse_args()
    print(asyncio.run(measure(args.machines, args.metrics, args.ticks, args.profile, not args.no_client)))


if __name__ == "__main__":
    main()
