"""Username, password and TLS on a paho client: one place for the daemon's publisher and `watch`."""

from __future__ import annotations

import ssl

import paho.mqtt.client as paho

from edge.publish.settings import PublishSettings


def apply_credentials(client: paho.Client, settings: PublishSettings) -> None:
    """Log in and encrypt as the settings say (the server certificate is always verified unless tls_insecure)."""
    if settings.username is not None:
        client.username_pw_set(settings.username, settings.password)
    if settings.tls:
        client.tls_set(ca_certs=str(settings.tls_ca_file) if settings.tls_ca_file else None,
                       certfile=str(settings.tls_cert_file) if settings.tls_cert_file else None,
                       keyfile=str(settings.tls_key_file) if settings.tls_key_file else None,
                       cert_reqs=ssl.CERT_REQUIRED)
        if settings.tls_insecure:
            client.tls_insecure_set(True)
