"""The config turned into the settings of the layers the service wires together (the publisher's today), so
those layers take plain values and need not know the pydantic config models.
"""

from __future__ import annotations

from edge.config import Config
from edge.publish.settings import PublishSettings


def publish_settings(config: Config) -> PublishSettings:
    """The publisher's view of the config (secrets read here, at start, never logged)."""
    mqtt = config.mqtt
    tls = mqtt.tls
    spb = mqtt.sparkplug
    settings = PublishSettings(
        host=mqtt.host,
        port=mqtt.effective_port,
        tls=tls is not None,
        tls_ca_file=tls.ca_file if tls else None,
        tls_cert_file=tls.cert_file if tls else None,
        tls_key_file=tls.key_file if tls else None,
        tls_insecure=tls.insecure_skip_verify if tls else False,
        username=mqtt.username,
        password=mqtt.read_password(),
        protocol=mqtt.protocol,
        keepalive=mqtt.keepalive,
        formats=frozenset(mqtt.formats),
        json_prefix=mqtt.json_topics.prefix,
        state_dir=config.resolved_state_dir,
    )
    if mqtt.client_id:
        settings.client_id = mqtt.client_id
    elif spb is not None:
        settings.client_id = f"focas-edge-{spb.group_id}-{spb.edge_node_id}"
    if spb is not None:
        settings.group_id = spb.group_id
        settings.edge_node_id = spb.edge_node_id
        settings.primary_host_id = spb.primary_host_id
    return settings
