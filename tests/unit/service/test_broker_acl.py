"""The broker ACL follows the config: the JSON prefix, the Sparkplug ids and the formats in use."""

from __future__ import annotations

from edge.config import parse_config
from edge.service.broker_acl import acl_topics, render_acl

BASE = "machines: [{id: m1, host: 127.0.0.1}]\n"


def test_topics_follow_the_configured_prefix_and_ids() -> None:
    config = parse_config("mqtt: {host: b, formats: [sparkplug, json], json: {prefix: plant7/cells/focas}, "
                          "sparkplug: {group_id: g1, edge_node_id: n9, primary_host_id: scada}, "
                          "password_env: NOT_SET_ANYWHERE, username: u}\n" + BASE, environ={}, secrets=False)
    topics = acl_topics(config)
    assert topics.commands == ("spBv1.0/g1/NCMD/n9", "spBv1.0/g1/DCMD/n9/+", "plant7/cells/focas/+/cmd")
    assert "plant7/cells/focas/+/cmd/reply/#" in topics.gateway_writes
    assert "spBv1.0/STATE/scada" in topics.gateway_reads
    assert not set(topics.commands) & set(topics.gateway_writes)
    text = render_acl(config, "edge", "mes")
    assert "topic write spBv1.0/STATE/scada" in text.split("user mes")[1]
    # mosquitto reads the rest of a topic line as the topic: no trailing comments on those lines.
    assert all("#" not in line.split(" ", 2)[2].replace("/#", "") for line in text.splitlines()
               if line.startswith("topic "))


def test_a_json_only_gateway_has_no_sparkplug_lines() -> None:
    config = parse_config("mqtt: {host: b, formats: [json]}\n" + BASE, environ={})
    text = render_acl(config, "edge", "mes")
    assert "spBv1.0/" not in text.replace("spBv1.0/STATE/#", "")
    assert f"topic write {config.mqtt.json_prefix}/+/cmd" in text  # focas/<host name>: no ids to name it
