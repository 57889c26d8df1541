"""What the publishing layer needs to know, as one plain dataclass (edge.config builds it from YAML)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

MqttProtocol = Literal["3.1.1", "5"]
PublishFormat = Literal["sparkplug", "json"]


@dataclass
class PublishSettings:
    """Broker connection plus Sparkplug and JSON naming.

    With both formats enabled the publisher opens two MQTT connections to the same broker: one whose Will is
    the Sparkplug NDEATH (client id `<client_id>`), one whose Will is the JSON gateway status
    (`<client_id>-json`). An MQTT connection carries only one Will, and a Sparkplug reconnect (bdSeq, primary
    host offline) must not disturb JSON subscribers.
    """

    host: str = "127.0.0.1"
    port: int = 1883
    tls: bool = False
    tls_ca_file: Path | None = None  # None with tls=True: the system trust store
    tls_cert_file: Path | None = None  # client certificate (mutual TLS)
    tls_key_file: Path | None = None
    tls_insecure: bool = False  # skip host name verification (test brokers only)
    username: str | None = None
    password: str | None = None
    protocol: MqttProtocol = "3.1.1"
    keepalive: int = 30
    client_id: str = "focas-edge"
    formats: frozenset[PublishFormat] = field(default_factory=lambda: frozenset({"sparkplug", "json"}))
    group_id: str = "FocasEdge"
    edge_node_id: str = "gateway"
    primary_host_id: str | None = None
    json_prefix: str = "focas"
    state_dir: Path = Path("state")
    reconnect_min_s: float = 0.5  # first retry delay; doubles per failed attempt
    reconnect_max_s: float = 10.0  # cap of the retry delay (jitter: each delay is drawn in [d/2, d])
    # Cap of the delay while nobody listens at the broker's port (refused, unreachable): such attempts cost
    # the broker nothing, and a broker back from an outage is then reached within this (jittered) delay.
    reconnect_probe_s: float = 0.5
    # Cap of the delay while the broker's address accepts the TCP connect but does not serve (closed or reset
    # before CONNACK, or CONNACK "server unavailable/busy": a proxy or load balancer in front of a broker that
    # is down, a broker still starting); each delay is drawn in [cap/2, cap], so at most one attempt a second
    # at the default, and a broker serving again is reached within the cap. A TLS session the broker ended
    # after its handshake is not this but a refused client certificate (broker_trouble.tls_refused).
    reconnect_not_serving_s: float = 2.0
    rebirth_min_interval_s: float = 1.0  # rebirth requests inside this window after a rebirth coalesce
    connect_timeout_s: float = 10.0  # SUBACK wait before a session is considered broken
