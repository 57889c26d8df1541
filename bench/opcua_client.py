"""The OPC UA benchmark's client, in its own process: subscribes to every metric of every machine and times
what arrives. Commands on stdin, one JSON line per answer on stdout:

    python -m bench.opcua_client URL USER PASSWORD CERT KEY STAMP_METRIC
    -> {"items": N}          once subscribed to every variable below each machine's Metrics folder
    start                    forget what arrived so far, record from now on
    report                   -> {"notifications": n, "seconds": s, "change_ms": [...], "sample_ms": [...]}
    burst                    one CreateMonitoredItems request of 10,000 items (a second subscription)
                             -> {"burst_s": seconds until the server answered}
    stop                     disconnect and exit

change = the simulator's stamp macro value (its wall clock at the change) to receipt here; sample = the
SourceTimestamp (the CNC time of the read) to receipt, over every notification.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from typing import Any

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from bench.simproc import stamp_latency

NS_URI = "urn:focas-edge:machines"
BROWSE_BATCH = 500
SUBSCRIBE_BATCH = 1000
BURST_ITEMS = 10_000


class Recorder:
    def __init__(self, stamp_handles: set[int]) -> None:
        self.stamp_handles = stamp_handles
        self.recording = False
        self.started = time.monotonic()
        self.notifications = 0
        self.change_ms: list[float] = []
        self.sample_ms: list[float] = []

    def datachange_notification(self, node: Any, value: Any, data: Any) -> None:
        if not self.recording:
            return
        received = time.time()
        self.notifications += 1
        dv = data.monitored_item.Value
        if dv.SourceTimestamp is not None:
            self.sample_ms.append((received - dv.SourceTimestamp.timestamp()) * 1000)
        if data.monitored_item.ClientHandle in self.stamp_handles and isinstance(value, float):
            self.change_ms.append(stamp_latency(value, received) * 1000)

    def start(self) -> None:
        self.notifications = 0
        self.change_ms.clear()
        self.sample_ms.clear()
        self.started = time.monotonic()
        self.recording = True

    def report(self) -> dict[str, Any]:
        return {"notifications": self.notifications, "seconds": time.monotonic() - self.started,
                "change_ms": self.change_ms, "sample_ms": self.sample_ms}


async def variables(client: Client) -> list[ua.NodeId]:
    """Every variable below every machine's Metrics folder, browsed level by level in batched requests."""
    ns = await client.get_namespace_index(NS_URI)
    machines = await client.get_node(ua.NodeId("Machines", ns)).get_children()
    level = [ua.NodeId(f"{m.nodeid.Identifier}/Metrics", ns) for m in machines]
    found: list[ua.NodeId] = []
    while level:
        following: list[ua.NodeId] = []
        for first in range(0, len(level), BROWSE_BATCH):
            params = ua.BrowseParameters()
            for node_id in level[first:first + BROWSE_BATCH]:
                params.NodesToBrowse.append(ua.BrowseDescription(
                    NodeId=node_id, BrowseDirection=ua.BrowseDirection.Forward,
                    ReferenceTypeId=ua.NodeId(ua.ObjectIds.HierarchicalReferences), IncludeSubtypes=True,
                    NodeClassMask=ua.NodeClass.Object | ua.NodeClass.Variable, ResultMask=ua.BrowseResultMask.All))
            for result in await client.uaclient.browse(params):
                for ref in result.References:
                    if ref.NodeClass == ua.NodeClass.Variable:
                        if ref.BrowseName.Name != "EngineeringUnits":
                            found.append(ref.NodeId.NodeId if hasattr(ref.NodeId, "NodeId") else ref.NodeId)
                    else:
                        following.append(ref.NodeId)
        level = following
    return found


async def burst(client: Client, nodes: list[ua.NodeId]) -> float:
    """10,000 monitored items in one request: the largest single step a client can ask of the server."""
    items = [client.get_node(nodes[i % len(nodes)]) for i in range(BURST_ITEMS)]
    subscription = await client.create_subscription(1000, Recorder(set()))
    started = time.monotonic()
    await subscription.subscribe_data_change(items, queuesize=1)
    return time.monotonic() - started


async def main(url: str, user: str, password: str, cert: str, key: str, stamp_metric: str) -> None:
    client = Client(url, timeout=60)
    client.application_uri = "urn:focas-edge:bench-client"
    client.set_user(user)
    client.set_password(password)
    await client.set_security(SecurityPolicyBasic256Sha256, certificate=cert, private_key=key,
                              mode=ua.MessageSecurityMode.SignAndEncrypt)
    await client.connect()
    nodes = await variables(client)
    stamp_ids = {n for n in nodes if str(n.Identifier).endswith(f"/Metrics/{stamp_metric}")}
    recorder = Recorder(set())
    subscription = await client.create_subscription(
        ua.CreateSubscriptionParameters(RequestedPublishingInterval=20, RequestedLifetimeCount=3000,
                                        RequestedMaxKeepAliveCount=100, MaxNotificationsPerPublish=0,
                                        PublishingEnabled=True), recorder)
    for first in range(0, len(nodes), SUBSCRIBE_BATCH):
        batch = [client.get_node(n) for n in nodes[first:first + SUBSCRIBE_BATCH]]
        await subscription.subscribe_data_change(batch, queuesize=10)
    recorder.stamp_handles = {handle for handle, item in subscription._monitored_items.items()
                              if item.node.nodeid in stamp_ids}
    print(json.dumps({"items": len(nodes), "stamp_items": len(recorder.stamp_handles)}), flush=True)
    loop = asyncio.get_running_loop()
    while True:
        line = (await loop.run_in_executor(None, sys.stdin.readline)).strip()
        if line == "start":
            recorder.start()
            print(json.dumps({"started": True}), flush=True)
        elif line == "report":
            print(json.dumps(recorder.report()), flush=True)
        elif line == "burst":
            print(json.dumps({"burst_s": await burst(client, nodes)}), flush=True)
        else:
            break
    await client.disconnect()


if __name__ == "__main__":
    asyncio.run(main(*sys.argv[1:7]))
