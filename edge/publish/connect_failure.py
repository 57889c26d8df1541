"""What to change when an MQTT connect fails, said in the config's terms (the hint on the outage's WARNING).

The reason itself (refused, TLS, not authorised, ...) is edge.publish.broker_trouble.classify, the one
classifier of broker connect errors; this module only turns a cause into the setting to look at.

A broker that requires a client certificate lets a TLS 1.3 client finish its handshake and then closes
the session when it reads CONNECT: paho reports only "connection lost" and logs the TLS alert on its own
(silent) logger. edge.publish.mqtt keeps paho's first error of the attempt and asks here for the hint.
"""

from __future__ import annotations

from edge.publish.settings import PublishSettings


def hint(cause: str, settings: PublishSettings) -> str:
    """What to change, when the cause says it; empty when it does not."""
    text = cause.lower()
    if "certificate required" in text or "certificate_required" in text:
        return "the broker requires a client certificate: set mqtt.tls.cert_file and mqtt.tls.key_file"
    if "certificate verify failed" in text or "certificate_verify_failed" in text:
        return ("the broker's certificate is not trusted: check mqtt.tls.ca_file and that mqtt.host is a name "
                "or address the certificate carries")
    if settings.tls and settings.tls_cert_file is None:
        return ("the broker closed the TLS session before CONNACK; if it requires a client certificate, set "
                "mqtt.tls.cert_file and mqtt.tls.key_file")
    return ""
