"""A heavy, rude OPC UA client for test_opcua_daemon, run as its own process (as a real one would be, so its
own work does not load the daemon's event loop): subscribes 10,000 monitored items, writes wrong types,
then drops the connection without closing its session. Prints one JSON line with what it saw.

    python -m tests.integration.opcua_rude_client URL USER PASSWORD CERT KEY
"""

from __future__ import annotations

import asyncio
import json
import sys
from typing import Any

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

ITEMS = 10_000


class Quiet:
    def datachange_notification(self, *_: Any) -> None:
        pass


async def main(url: str, user: str, password: str, cert: str, key: str) -> dict[str, Any]:
    # The client's own liveness probe (a read every second, 1 s to answer) would call a server that is busy
    # with this very client's 10,000 items "lost" on a loaded host; this client is rude, not impatient.
    client = Client(url, timeout=30, watchdog_intervall=30.0)
    client.application_uri = "urn:focas-edge:test-client"
    client.set_user(user)
    client.set_password(password)
    await client.set_security(SecurityPolicyBasic256Sha256, certificate=cert, private_key=key,
                              mode=ua.MessageSecurityMode.SignAndEncrypt)
    await client.connect()
    ns = await client.get_namespace_index("urn:focas-edge:machines")
    nodes = [client.get_node(ua.NodeId(f"m1/Metrics/Macro/{500 + i % 11}", ns)) for i in range(ITEMS)]
    subscription = await client.create_subscription(100, Quiet())
    handles = await subscription.subscribe_data_change(nodes, queuesize=1)
    macro = client.get_node(ua.NodeId("m1/Metrics/Macro/501", ns))
    statuses = []
    for wrong in (ua.Variant("text", ua.VariantType.String), ua.Variant(1, ua.VariantType.Int32),
                  ua.Variant([1.0, 2.0], ua.VariantType.Double)):
        params = ua.WriteParameters()
        params.NodesToWrite = [ua.WriteValue(NodeId=macro.nodeid, AttributeId=ua.AttributeIds.Value,
                                             Value=ua.DataValue(wrong))]
        (status,) = await client.uaclient.write(params)
        statuses.append(status.name)
    client.uaclient.protocol.transport.abort()  # gone without closing its session or its items
    return {"items": sum(isinstance(h, int) for h in handles), "writes": statuses}


if __name__ == "__main__":
    print(json.dumps(asyncio.run(main(*sys.argv[1:6]))), flush=True)
