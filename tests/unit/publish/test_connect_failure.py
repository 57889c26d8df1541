"""The hint and the name of a failed MQTT connect: the setting to change, said in the config's terms."""

from __future__ import annotations

from pathlib import Path

from edge.publish.broker_trouble import TLS
from edge.publish.connect_failure import closed_before_connack, hint
from edge.publish.settings import PublishSettings

EOF_AFTER_HANDSHAKE = "failed to receive on socket: EOF occurred in violation of protocol (_ssl.c:2427)"
UNKNOWN_CA = "failed to receive on socket: [SSL: TLSV1_ALERT_UNKNOWN_CA] tlsv1 alert unknown ca (_ssl.c:2580)"


def test_a_tls_session_the_broker_ended_before_connack_names_the_client_certificate() -> None:
    without = PublishSettings(tls=True)
    with_cert = PublishSettings(tls=True, tls_cert_file=Path("client.crt"), tls_key_file=Path("client.key"))
    assert "requires a client certificate" in hint(EOF_AFTER_HANDSHAKE, without)
    assert "mqtt.tls.cert_file and mqtt.tls.key_file" in hint(EOF_AFTER_HANDSHAKE, without)
    assert "refuses the client certificate" in hint(EOF_AFTER_HANDSHAKE, with_cert)
    assert "does not accept the client certificate" in hint(UNKNOWN_CA, with_cert)
    assert "signed by a CA the broker trusts" in hint(UNKNOWN_CA, with_cert)


def test_no_tls_hint_for_a_cause_that_never_reached_tls() -> None:
    settings = PublishSettings(tls=True)
    assert hint("[Errno 111] Connection refused", settings) == ""
    assert hint("[Errno -2] Name or service not known", settings) == ""
    assert hint(EOF_AFTER_HANDSHAKE, PublishSettings()) == ""


def test_a_refused_tls_session_is_one_reason_however_paho_words_it() -> None:
    for cause in (EOF_AFTER_HANDSHAKE, UNKNOWN_CA, "failed to receive on socket: [Errno 104] Connection reset by peer"):
        what, said, reason = closed_before_connack(cause, tls=True)
        assert what.startswith("TLS handshake failed") and "before CONNACK" in what and reason == TLS
        assert said == cause
    assert closed_before_connack("Unspecified error", tls=True) == ("connection closed before CONNACK",
                                                                   "Unspecified error", None)
    assert closed_before_connack("failed to receive on socket: [Errno 104] Connection reset by peer",
                                 tls=False)[2] is None
