"""The MQTT connection layer: TLS with a client certificate, username/password, backoff, clean start."""

from __future__ import annotations

import asyncio
import itertools
import logging
import os
import random
import re
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from edge.publish import Publisher, PublishSettings, mqtt_wire
from edge.publish.mqtt import RAW_WRITE_BYTES, MqttConnection, backoff_delay
from tests.helpers import Mosquitto, async_wait_for, mosquitto_binary
from tests.integration.mqtt_observer import Observer
from tests.integration.tcp_relay import TcpRelay

pytestmark = pytest.mark.integration


def test_backoff_grows_exponentially_to_the_cap_with_jitter() -> None:
    rng = random.Random(7)
    for attempt in range(40):
        ceiling = min(30.0, 0.5 * 2 ** attempt)
        delays = [backoff_delay(attempt, 0.5, 30.0, rng) for _ in range(50)]
        assert all(ceiling / 2 <= d <= ceiling for d in delays)
        assert len(set(delays)) > 1, "jittered"
    assert backoff_delay(100, 0.5, 30.0, rng) <= 30.0


def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A throwaway CA, a server certificate for 127.0.0.1 and a client certificate; and a client certificate
    of another CA ("stranger"), which the broker does not accept."""
    d = tmp_path_factory.mktemp("pki")
    for ca in ("ca", "other-ca"):
        openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{ca}.key", "-out", f"{ca}.crt",
                "-days", "2", "-subj", f"/CN=test-{ca}", cwd=d)
    for name, ca, extra in (("server", "ca", "subjectAltName=IP:127.0.0.1"),
                            ("client", "ca", "extendedKeyUsage=clientAuth"),
                            ("stranger", "other-ca", "extendedKeyUsage=clientAuth")):
        openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key", "-out", f"{name}.csr",
                "-subj", f"/CN={name}", cwd=d)
        (d / f"{name}.ext").write_text(extra + "\n")
        openssl("x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.crt", "-CAkey", f"{ca}.key",
                "-CAcreateserial", "-out", f"{name}.crt", "-days", "2", "-extfile", f"{name}.ext", cwd=d)
    return d


def custom_broker(config: str) -> Iterator[Mosquitto]:
    binary = mosquitto_binary()
    if binary is None:
        pytest.skip("mosquitto is not installed")
    broker = Mosquitto(binary)
    # As root, mosquitto drops to user "mosquitto", which cannot read files under pytest's 0700 tmp dirs.
    user = "user root\n" if os.geteuid() == 0 else ""
    broker.conf.write_text(f"listener {broker.port} 127.0.0.1\npersistence false\nlog_dest stderr\n"
                           f"{user}{config}")
    broker.start()
    try:
        yield broker
    finally:
        broker.close()


@pytest.fixture
def tls_broker(pki: Path) -> Iterator[Mosquitto]:
    yield from custom_broker(f"allow_anonymous true\ncafile {pki / 'ca.crt'}\ncertfile {pki / 'server.crt'}\n"
                             f"keyfile {pki / 'server.key'}\nrequire_certificate true\n")


@pytest.fixture
def auth_broker(tmp_path: Path) -> Iterator[Mosquitto]:
    pw = tmp_path / "passwd"
    pw.write_text("")
    subprocess.run(["mosquitto_passwd", "-b", str(pw), "edge", "s3cret"], check=True, capture_output=True)
    yield from custom_broker(f"allow_anonymous false\npassword_file {pw}\n")


def settings(broker: Mosquitto, state: Path, **kw: object) -> PublishSettings:
    s = PublishSettings(host=broker.host, port=broker.port, formats=frozenset({"sparkplug", "json"}),
                        state_dir=state, reconnect_min_s=0.05, reconnect_max_s=0.2, keepalive=5)
    for key, value in kw.items():
        setattr(s, key, value)
    return s


@pytest.mark.parametrize("protocol", ["3.1.1", "5"])
async def test_tls_with_client_certificate(tls_broker: Mosquitto, pki: Path, tmp_path: Path,
                                           protocol: str) -> None:
    pub = Publisher(settings(tls_broker, tmp_path, protocol=protocol, tls=True, tls_ca_file=pki / "ca.crt",
                             tls_cert_file=pki / "client.crt", tls_key_file=pki / "client.key"))
    await pub.start()
    try:
        assert await pub.wait_ready(10), "TLS session with client certificate"
    finally:
        await pub.stop()


async def test_tls_without_client_certificate_keeps_retrying(tls_broker: Mosquitto, pki: Path,
                                                             tmp_path: Path) -> None:
    pub = Publisher(settings(tls_broker, tmp_path, tls=True, tls_ca_file=pki / "ca.crt"))
    await pub.start()
    try:
        assert not await pub.wait_ready(1.0)
        assert pub.counters["dropped"] == 0 and not pub.connected
    finally:
        await pub.stop()


def mqtt_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "edge.publish.mqtt" and r.levelno == logging.WARNING]


async def first_tls_warning(broker: Mosquitto, state: Path, ca_file: Path, caplog: pytest.LogCaptureFixture) -> str:
    """Connect over TLS without a client certificate; the first WARNING the connection logs."""
    caplog.set_level(logging.INFO, logger="edge.publish.mqtt")
    pub = Publisher(settings(broker, state, tls=True, tls_ca_file=ca_file, formats=frozenset({"sparkplug"})))
    await pub.start()
    try:
        await async_wait_for(lambda: mqtt_warnings(caplog), timeout=10, message="a WARNING for the failed session")
    finally:
        await pub.stop()
    return mqtt_warnings(caplog)[0]


async def test_mutual_tls_rejection_is_a_warning_with_the_cause(tls_broker: Mosquitto, pki: Path, tmp_path: Path,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    """The broker wants a client certificate and none is configured: said at WARNING, as a bad password is."""
    first = await first_tls_warning(tls_broker, tmp_path, pki / "ca.crt", caplog)
    assert "before CONNACK" in first and f"port={tls_broker.port}" in first, first
    assert "client certificate" in first and "mqtt.tls.cert_file" in first, first


async def test_tls_verification_failure_is_a_warning_with_the_cause(tls_broker: Mosquitto, tmp_path: Path,
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    """A CA that did not sign the broker's certificate: a configuration error, not an INFO line."""
    openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "other.key", "-out", "other.crt",
            "-days", "2", "-subj", "/CN=other-ca", cwd=tmp_path)
    first = await first_tls_warning(tls_broker, tmp_path / "state", tmp_path / "other.crt", caplog)
    assert "TLS handshake failed" in first and "certificate verify failed" in first, first
    assert "mqtt.tls.ca_file" in first, first
    assert not [r for r in caplog.records if r.levelno < logging.WARNING and "certificate" in r.getMessage()]


class AttemptTimes:
    """A condition for async_wait_for (the count of failed attempts) that notes the loop time at which each
    was seen: the retry delays as the connection's status shows them, polled every 10 ms."""

    def __init__(self, attempts: Callable[[], int]) -> None:
        self._attempts = attempts
        self.times: list[float] = []

    def __call__(self) -> int:
        now = asyncio.get_running_loop().time()
        self.times.extend([now] * (self._attempts() - len(self.times)))
        return len(self.times)

    def gaps(self) -> list[float]:
        return [round(b - a, 3) for a, b in itertools.pairwise(self.times)]


@pytest.mark.parametrize("client_cert", ["none", "of another CA"])
async def test_a_broker_refusing_the_client_certificate_is_retried_with_the_growing_backoff_and_said_once(
        tls_broker: Mosquitto, pki: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture, client_cert: str) -> None:
    """`require_certificate true`. With TLS 1.3 the broker checks the client certificate after the client has
    finished its handshake and sent CONNECT, and the client mostly reads only an EOF (the alert is lost to the
    close): still a refusal on the merits, retried with the backoff growing to `reconnect_max_s`, not every
    `reconnect_not_serving_s` for ever as a broker that accepts and does not serve is. One WARNING naming it."""
    caplog.set_level(logging.DEBUG, logger="edge.publish.mqtt")
    cert = {} if client_cert == "none" else {"tls_cert_file": pki / "stranger.crt",
                                             "tls_key_file": pki / "stranger.key"}
    cap, not_serving = 4.0, 1.0
    pub = Publisher(settings(tls_broker, tmp_path, tls=True, tls_ca_file=pki / "ca.crt",
                             formats=frozenset({"sparkplug"}), reconnect_min_s=0.5, reconnect_max_s=cap,
                             reconnect_not_serving_s=not_serving, **cert))

    def failed_attempts() -> int:
        (_, state), = pub.broker_states()
        return state.failed_attempts

    seen = AttemptTimes(failed_attempts)
    await pub.start()
    try:
        await async_wait_for(lambda: seen() >= 7, timeout=60, message="seven refused TLS sessions")
        (_, state), = pub.broker_states()
        assert not state.connected and state.reason == "TLS", state
    finally:
        await pub.stop()
    waited = seen.gaps()
    floors = [min(cap, 0.5 * 2 ** i) / 2 for i in range(len(waited))]  # 0.25, 0.5, 1, 2, 2, 2: drawn in [c/2, c]
    assert all(w >= floor - 0.1 for w, floor in zip(waited, floors, strict=True)), (waited, floors)
    assert all(w <= cap + 1.5 for w in waited), waited  # capped (+ the attempt's own handshake)
    assert min(waited[3:]) > not_serving + 0.5, waited  # not the "accepted, not serving" retry
    assert attempts_logged(caplog, "TLS handshake failed (the broker closed the session before CONNACK)") >= 7
    warnings = broker_warnings(caplog, f"{tls_broker.host}:{tls_broker.port}")
    assert len(warnings) == 1, warnings  # then one a minute (this test is shorter): tests/unit test_broker_trouble
    assert "TLS handshake failed" in warnings[0] and "reason=TLS" in warnings[0], warnings[0]
    assert "client certificate" in warnings[0] and "mqtt.tls.cert_file" in warnings[0], warnings[0]


async def test_a_tls_address_that_accepts_and_closes_keeps_the_short_retry_and_connects_once_it_serves(
        tls_broker: Mosquitto, pki: Path) -> None:
    """A proxy in front of a TLS broker that is down closes during the handshake (the connect itself fails): not
    a refusal on the merits, so it is retried within `reconnect_not_serving_s`; only a session whose handshake
    the broker finished and then ended before CONNACK is one."""
    relay = TcpRelay(tls_broker.host, tls_broker.port)
    await relay.start()
    relay.accepting = False
    not_serving = 1.0
    s = PublishSettings(host=relay.host, port=relay.port, keepalive=5, reconnect_min_s=0.5, reconnect_max_s=30.0,
                        reconnect_not_serving_s=not_serving, tls=True, tls_ca_file=pki / "ca.crt",
                        tls_cert_file=pki / "client.crt", tls_key_file=pki / "client.key")
    conn = MqttConnection(s, "tls-not-serving", before_connect=lambda unsent: None, on_connected=lambda tag: None,
                          on_disconnected=lambda: None, on_message=lambda msg: None)
    seen = AttemptTimes(lambda: conn.trouble.failed_attempts)
    conn.start()
    try:
        await async_wait_for(lambda: seen() >= 6, timeout=30, message="six attempts turned away")
        waited = seen.gaps()
        assert all(w <= not_serving + 0.5 for w in waited), waited  # the backoff would be at 4-8 s by the last
        assert conn.trouble.reason != "not authorised" and not conn.connected
        relay.accepting = True
        await async_wait_for(lambda: conn.connected, timeout=not_serving + 2.0, message="TLS session via the relay")
    finally:
        await conn.stop()
        await relay.close()


async def test_username_password(auth_broker: Mosquitto, tmp_path: Path) -> None:
    bad = Publisher(settings(auth_broker, tmp_path / "a", username="edge", password="wrong", client_id="bad"))
    good = Publisher(settings(auth_broker, tmp_path / "b", username="edge", password="s3cret", client_id="ok"))
    await bad.start()
    await good.start()
    try:
        assert await good.wait_ready(10)
        assert not bad.connected
    finally:
        await bad.stop()
        await good.stop()


@pytest.mark.parametrize("protocol", ["3.1.1", "5"])
async def test_reconnects_after_broker_restart_with_clean_session(mosquitto: Mosquitto, tmp_path: Path,
                                                                  protocol: str) -> None:
    pub = Publisher(settings(mosquitto, tmp_path, protocol=protocol))
    await pub.start()
    try:
        assert await pub.wait_ready()
        mosquitto.stop()
        await async_wait_for(lambda: not pub.connected, message="connection loss noticed")
        await pub.device_data("cnc1", [])  # nothing to send, nothing raised
        mosquitto.start()
        await async_wait_for(lambda: pub.ready and pub.counters["sparkplug_connects"] == 2, timeout=15,
                             message="reconnected")
    finally:
        await pub.stop()


@pytest.mark.parametrize("protocol", ["3.1.1", "5"])
async def test_qos0_batches_keep_publish_order_with_paho_packets_and_retain(
        mosquitto: Mosquitto, tmp_path: Path, protocol: str) -> None:
    """QoS 0 packets are encoded by us and written once per loop turn; QoS 1 ones by paho. A subscriber
    must see them in publish order, and a retained QoS 0 message must be retained."""
    connected = asyncio.Event()
    conn = MqttConnection(settings(mosquitto, tmp_path, protocol=protocol), "order-test",
                          before_connect=lambda unsent: None, on_connected=lambda tag: connected.set(),
                          on_disconnected=lambda: None, on_message=lambda msg: None)
    observer = Observer(mosquitto, ("order/#",))
    conn.start()
    try:
        await asyncio.wait_for(connected.wait(), 10)
        sent = []
        for i in range(60):  # one loop turn: QoS 0 batch, then paho's QoS 1 packet must come after it
            payload = f"{i}".encode()
            assert conn.publish("order/x", payload, qos=1 if i % 7 == 3 else 0)
            sent.append(payload)
        await async_wait_for(lambda: len(observer.on("order/x")) == len(sent), message="all 60 messages")
        assert [m.payload for m in observer.on("order/x")] == sent
        assert conn.publish("order/retained", b"kept", qos=0, retain=True)
        await async_wait_for(lambda: observer.on("order/retained"), message="retained message")
    finally:
        await conn.stop()
        observer.close()
    late = Observer(mosquitto, ("order/retained",))
    try:
        await async_wait_for(lambda: late.on("order/retained"), message="retained for a late subscriber")
        assert late.on("order/retained")[0].retain and late.on("order/retained")[0].payload == b"kept"
    finally:
        late.close()


async def test_a_turn_of_megabytes_goes_out_in_bounded_writes_in_order_and_room_is_waited_for(
        mosquitto: Mosquitto, tmp_path: Path) -> None:
    """A loop turn's QoS 0 packets (1,000 DBIRTHs after a reconnect, a replay's slice) reach paho as writes
    of about RAW_WRITE_BYTES, not one of megabytes that paho copies again after every partial send; they
    arrive whole and in order; `wait_for_room` returns once the kernel has taken what was queued."""
    connected = asyncio.Event()
    conn = MqttConnection(settings(mosquitto, tmp_path), "bulk-test", before_connect=lambda unsent: None,
                          on_connected=lambda tag: connected.set(), on_disconnected=lambda: None,
                          on_message=lambda msg: None)
    observer = Observer(mosquitto, ("bulk/#",))
    conn.start()
    try:
        await asyncio.wait_for(connected.wait(), 10)
        writes: list[int] = []
        queue = mqtt_wire.queue_raw

        def counted(client: object, data: bytes) -> None:
            writes.append(len(data))
            queue(client, data)  # type: ignore[arg-type]

        sent = [i.to_bytes(4, "big") * 1250 for i in range(800)]  # 5 kB each, 4 MB in one turn
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(mqtt_wire, "queue_raw", counted)
            for payload in sent:
                assert conn.publish("bulk/x", payload)
            assert conn.held >= sum(map(len, sent))
            await asyncio.wait_for(conn.wait_for_room(0), 30)
        assert conn.held == 0
        assert len(writes) > 1 and max(writes) < RAW_WRITE_BYTES + 5100
        await async_wait_for(lambda: len(observer.on("bulk/x")) == len(sent), timeout=30,
                             message="all 800 messages")
        assert [m.payload for m in observer.on("bulk/x")] == sent
    finally:
        await conn.stop()
        observer.close()


async def test_wildcard_topic_still_refused_by_paho(mosquitto: Mosquitto, tmp_path: Path) -> None:
    connected = asyncio.Event()
    conn = MqttConnection(settings(mosquitto, tmp_path), "wild", before_connect=lambda unsent: None,
                          on_connected=lambda tag: connected.set(), on_disconnected=lambda: None,
                          on_message=lambda msg: None)
    conn.start()
    try:
        await asyncio.wait_for(connected.wait(), 10)
        with pytest.raises(ValueError, match="wildcard"):
            conn.publish("bad/+/topic", b"x")
    finally:
        await conn.stop()


def broker_warnings(caplog: pytest.LogCaptureFixture, address: str) -> list[str]:
    return [line for line in mqtt_warnings(caplog) if f"broker={address}" in line]


def attempts_logged(caplog: pytest.LogCaptureFixture, what: str) -> int:
    """Every attempt leaves a record (DEBUG once the outage has been said)."""
    return len([r for r in caplog.records if r.name == "edge.publish.mqtt" and what in r.getMessage()])


@pytest.mark.parametrize("protocol", ["3.1.1", "5"])
async def test_a_refused_login_is_one_warning_naming_the_broker_and_the_reason(
        auth_broker: Mosquitto, tmp_path: Path, caplog: pytest.LogCaptureFixture, protocol: str) -> None:
    """Not one line per attempt (every 0.2 s here): one WARNING, then a summary a minute (unit-tested)."""
    caplog.set_level(logging.DEBUG, logger="edge.publish.mqtt")
    pub = Publisher(settings(auth_broker, tmp_path, username="edge", password="wrong", protocol=protocol,
                             formats=frozenset({"sparkplug"})))
    await pub.start()
    try:
        await async_wait_for(lambda: attempts_logged(caplog, "connection refused") >= 6, 20,
                             message="six refused logins")
        address = f"{auth_broker.host}:{auth_broker.port}"
        warnings = broker_warnings(caplog, address)
        assert len(warnings) == 1, warnings
        assert "reason=not authorised" in warnings[0] and "Not authorized" in warnings[0], warnings[0]
        (_, state), = pub.broker_states()
        assert not state.connected and state.reason == "not authorised" and state.failed_attempts >= 6
    finally:
        await pub.stop()


async def test_an_unresolvable_broker_name_is_one_warning_saying_so(tmp_path: Path,
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="edge.publish.mqtt")
    s = PublishSettings(host="no-such-broker.invalid", port=1883, formats=frozenset({"json"}), state_dir=tmp_path,
                        reconnect_min_s=0.05, reconnect_max_s=0.2)
    pub = Publisher(s)
    await pub.start()
    try:
        await async_wait_for(lambda: attempts_logged(caplog, "connect failed") >= 4, 20, message="four attempts")
        warnings = broker_warnings(caplog, "no-such-broker.invalid:1883")
        assert len(warnings) == 1 and "reason=unresolvable" in warnings[0], warnings
    finally:
        await pub.stop()


async def test_a_broker_that_goes_away_is_said_twice_then_once_more_when_it_is_back(
        mosquitto: Mosquitto, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Lost (one WARNING), refused on reconnect (one WARNING with the reason), quiet meanwhile, back (one line
    with how long it was down)."""
    caplog.set_level(logging.DEBUG, logger="edge.publish.mqtt")
    pub = Publisher(settings(mosquitto, tmp_path, formats=frozenset({"json"})))
    await pub.start()
    try:
        assert await pub.wait_ready()
        mosquitto.stop()
        await async_wait_for(lambda: attempts_logged(caplog, "connect failed") >= 8, 20, message="eight attempts")
        warnings = mqtt_warnings(caplog)
        assert len(warnings) == 2, warnings
        assert "connection lost" in warnings[0] and "reason=refused" in warnings[1], warnings
        (_, state), = pub.broker_states()
        assert not state.connected and state.failed_attempts >= 8 and "Connection refused" in state.last_error
        mosquitto.start()
        await async_wait_for(lambda: pub.connected, 15, message="reconnected")
        back = [r.getMessage() for r in caplog.records if "available again" in r.getMessage()]
        assert len(back) == 1 and f"broker={mosquitto.host}:{mosquitto.port}" in back[0], back
        assert re.search(r"down_for=\d+s failed_attempts=\d+", back[0]), back[0]
        assert len(mqtt_warnings(caplog)) == 2
    finally:
        await pub.stop()
