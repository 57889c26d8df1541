"""Why an MQTT connect attempt failed, said in the config's terms (for one WARNING line per attempt).

A broker that requires a client certificate lets a TLS 1.3 client finish its handshake and then closes
the session when it reads CONNECT: paho reports only "connection lost" and logs the TLS alert on its own
(silent) logger. edge.publish.mqtt keeps paho's first error of the attempt and asks here for the hint.
"""

from __future__ import annotations

import errno
import socket
import ssl

from edge.publish.settings import PublishSettings


def is_tls_failure(error: BaseException) -> bool:
    """A TLS handshake or certificate verification error (not a refused or unreachable TCP connect)."""
    return isinstance(error, ssl.SSLError | ssl.CertificateError)


# A TCP connect that met these found nobody at the broker's port: the broker never saw the attempt.
_NOBODY_THERE = frozenset({errno.ECONNREFUSED, errno.EHOSTUNREACH, errno.ENETUNREACH, errno.EHOSTDOWN,
                           errno.ETIMEDOUT})


def nobody_answered(error: BaseException) -> bool:
    """The attempt ended before any broker process saw it: the port refused, the host or network was
    unreachable, or the TCP connect timed out. Such an attempt costs the broker nothing, so it may be repeated
    often (edge.publish.mqtt probes at ~1 s); a name that does not resolve, a TLS failure or a refused
    CONNECT are answers, and keep the growing backoff."""
    if isinstance(error, socket.gaierror) or is_tls_failure(error):
        return False
    if isinstance(error, TimeoutError | ConnectionRefusedError):
        return True
    return isinstance(error, OSError) and error.errno in _NOBODY_THERE


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
