"""The OPC UA server's work per Publish, counted in one process: a client's Publish request read (its
acknowledgement of the last response), the waiting subscription's response built, encoded, signed and
encrypted (Basic256Sha256 Sign&Encrypt) and written to a transport that only counts. No network, no
decryption of the request (asyncua's receive path, unchanged), no value changes: their notifications are
queued as the taps queue them (bytes per item), `--items` of them per publish.

The fleet benchmark (bench/opcua.py) measures the whole gateway at ~50 publishes a second, where a few
µs per publish are below its noise; this reports process CPU per Publish, so an A/B of two trees
(PYTHONPATH) is a counted comparison.

    python -m bench.opcua_publish [--publishes 3000] [--items 80]
"""

from __future__ import annotations

import argparse
import asyncio
import datetime
import os
import statistics
import time
from typing import Any

from asyncua import Server, ua
from asyncua.common.connection import SecureConnection, TransportLimits
from asyncua.common.utils import Buffer
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from asyncua.server.internal_session import SessionState
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua.ua_binary import struct_to_binary
from cryptography import x509
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import NameOID

from edge.opcua import subscriptions
from edge.opcua.processor import GatewayProcessor

ROUNDS = 5


def _certificate() -> tuple[Any, Any]:
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "bench")])
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(1).not_valid_before(datetime.datetime(2020, 1, 1))
            .not_valid_after(datetime.datetime(2040, 1, 1)).sign(key, hashes.SHA256()))
    return cert, key


class _Transport:
    def __init__(self) -> None:
        self.bytes = 0

    def write(self, data: bytes) -> None:
        self.bytes += len(data)

    def get_extra_info(self, _name: str) -> None:
        return None


async def client_subscription(session: Any, served: UaProcessor) -> Any:
    """A subscription of `session` whose responses `served` sends, as a client's CreateSubscription makes it,
    publishing only when told to (an hour's publishing interval)."""
    created = await session.create_subscription(
        ua.CreateSubscriptionParameters(RequestedPublishingInterval=3_600_000, RequestedLifetimeCount=10_000,
                                        RequestedMaxKeepAliveCount=1_000, PublishingEnabled=True),
        served.forward_publish_response, request_callback=served.get_publish_request)
    return session.subscription_service.subscriptions[created.SubscriptionId]


async def measure(publishes: int, items: int) -> dict[str, Any]:
    server = Server()
    await server.init()
    subscriptions.install(server.iserver.subscription_service)
    (cert, key), (peer, _) = _certificate(), _certificate()
    policy = SecurityPolicyBasic256Sha256(peer, cert, key, ua.MessageSecurityMode.SignAndEncrypt)
    policy.make_local_symmetric_key(os.urandom(32), os.urandom(32))
    transport = _Transport()
    served = GatewayProcessor(server.iserver, transport, TransportLimits())
    served._connection = SecureConnection(policy, TransportLimits())
    session = served.session = server.iserver.create_session("bench", external=True)
    session.state = SessionState.Activated
    subscription = await client_subscription(session, served)
    sid = subscription.data.SubscriptionId
    await asyncio.sleep(0)  # its first publish, waiting for a request
    note = b"\x07\x00\x00\x00" + struct_to_binary(ua.DataValue(ua.Variant(2.5, ua.VariantType.Double)))
    seqhdr = ua.SequenceHeader()
    seqhdr.SequenceNumber, seqhdr.RequestId = 1, 9
    request = ua.PublishRequest()
    request.RequestHeader.AuthenticationToken = ua.NodeId(os.urandom(32), 1, ua.NodeIdType.ByteString)
    request.RequestHeader.TimeoutHint = 10_000
    per_round: list[float] = []
    try:
        for _ in range(ROUNDS):
            spent = 0.0
            for _ in range(publishes // ROUNDS):
                acked = subscription._notification_seq - 1  # the client acknowledges the last response
                request.RequestHeader.RequestHandle = acked + 1
                request.Parameters.SubscriptionAcknowledgements = [
                    ua.SubscriptionAcknowledgement(SubscriptionId=sid, SequenceNumber=acked)] if acked else []
                body = Buffer(struct_to_binary(request))
                queued = subscription._triggered_datachanges
                for item in range(items):
                    queued[item] = note
                started = time.process_time()
                await served.process_message(seqhdr, body)
                await subscription.publish_results()
                spent += time.process_time() - started
            per_round.append(spent / (publishes // ROUNDS) * 1e6)
    finally:
        await session.delete_subscriptions([sid])
    return {"publishes": publishes, "items": items, "cpu_us_per_publish": statistics.median(per_round),
            "rounds_us": [round(value, 1) for value in per_round],
            "bytes_per_publish": transport.bytes / max(publishes, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--publishes", type=int, default=3000)
    parser.add_argument("--items", type=int, default=80, help="notifications per publish")
    args = parser.parse_args()
    print(asyncio.run(measure(args.publishes, args.items)))


if __name__ == "__main__":
    main()
