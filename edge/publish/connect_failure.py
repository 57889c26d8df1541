"""What to change when an MQTT connect fails, said in the config's terms (the hint on the outage's WARNING).

The reason itself (refused, TLS, not authorised, ...) is edge.publish.broker_trouble.classify, the one
classifier of broker connect errors; this module only turns a cause into the setting to look at, and names
an attempt the broker closed before its CONNACK.

A broker that requires a client certificate lets a TLS 1.3 client finish its handshake and then closes
the session when it reads CONNECT: paho reports only "connection lost" and logs the TLS alert on its own
(silent) logger, and the alert itself is mostly lost to the close (paho's error is then an SSL EOF).
edge.publish.mqtt keeps paho's first error of the attempt and asks here for the hint.
"""

from __future__ import annotations

from edge.publish.broker_trouble import (
    NOT_AUTHORISED,
    REFUSED,
    TIMED_OUT,
    TLS,
    UNREACHABLE,
    UNRESOLVABLE,
    classify,
    tls_refused,
)
from edge.publish.settings import PublishSettings

# Causes that never reached a TLS session: no TLS hint for them.
_BELOW_TLS = frozenset({REFUSED, UNRESOLVABLE, TIMED_OUT, UNREACHABLE, NOT_AUTHORISED})
# The alerts of a broker that does not accept the client certificate it was sent.
_CERT_NOT_ACCEPTED = ("unknown ca", "bad certificate", "certificate expired", "certificate revoked",
                      "certificate unknown", "unsupported certificate")
_CHECK_CERT = "check that mqtt.tls.cert_file is signed by a CA the broker trusts and is still valid"


def hint(cause: str, settings: PublishSettings) -> str:
    """What to change, when the cause says it; empty when it does not."""
    text = cause.lower()
    if "certificate required" in text or "certificate_required" in text:
        return "the broker requires a client certificate: set mqtt.tls.cert_file and mqtt.tls.key_file"
    if "certificate verify failed" in text or "certificate_verify_failed" in text:
        return ("the broker's certificate is not trusted: check mqtt.tls.ca_file and that mqtt.host is a name "
                "or address the certificate carries")
    if any(words in text or words.replace(" ", "_") in text for words in _CERT_NOT_ACCEPTED):
        return f"the broker does not accept the client certificate: {_CHECK_CERT}"
    if not settings.tls or classify(cause) in _BELOW_TLS:
        return ""
    if settings.tls_cert_file is None:
        return ("the broker closed the TLS session before CONNACK, as one that requires a client certificate "
                "does: set mqtt.tls.cert_file and mqtt.tls.key_file")
    return ("the broker closed the TLS session before CONNACK, as one that refuses the client certificate does: "
            + _CHECK_CERT)


def closed_before_connack(cause: str, tls: bool) -> tuple[str, str, str | None]:
    """(what, cause, reason) of an attempt closed before its CONNACK, for the outage's line: a TLS session
    the broker refused (broker_trouble.tls_refused) is a failed TLS handshake, said so and classed TLS however
    paho words it (an EOF, a reset, an alert), so the outage keeps one reason and one WARNING."""
    if tls_refused(cause, tls):
        return "TLS handshake failed (the broker closed the session before CONNACK)", cause, TLS
    return "connection closed before CONNACK", cause, None
