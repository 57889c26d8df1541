"""A mosquitto `acl_file` for one gateway: who may send it commands and who may speak as it.

The gateway's own policy (writes.enabled, the allow-list) decides what a command may change; the broker
decides who may send one at all. This file gives the gateway's account the right to publish only the
gateway's topics (so no other client can forge its births, data or replies) and to read its commands, and
gives the MES account the only right to publish those commands (DCMD, NCMD, `<prefix>/<machine>/cmd`).
Anything not granted is refused by mosquitto (a refused PUBLISH is dropped; with MQTT 3.1.1 the client is
not told).

The topics come from the same settings the daemon publishes with (edge.service.settings.publish_settings and
edge.publish's JsonTopics), so a changed JSON prefix or Sparkplug id is followed, never hardcoded.
"""

from __future__ import annotations

from dataclasses import dataclass

from edge.config import Config
from edge.publish.json_topics import JsonTopics
from edge.service.settings import publish_settings

SPARKPLUG = "spBv1.0"


@dataclass(frozen=True, slots=True)
class AclTopics:
    """The topic filters of one gateway, per right."""

    gateway_writes: tuple[str, ...]
    gateway_reads: tuple[str, ...]
    commands: tuple[str, ...]  # only the MES account may publish these
    published: tuple[str, ...]  # what readers (the MES, dashboards) subscribe to


def acl_topics(config: Config) -> AclTopics:
    """The gateway's topics as the daemon will use them (its secrets are not read)."""
    mqtt = config.mqtt.model_copy(update={"password_env": None, "password_file": None})
    settings = publish_settings(config.model_copy(update={"mqtt": mqtt}))
    writes: list[str] = []
    reads: list[str] = []
    commands: list[str] = []
    published: list[str] = []
    if "sparkplug" in settings.formats:
        node = f"{SPARKPLUG}/{settings.group_id}/{{}}/{settings.edge_node_id}"
        writes += [node.format(kind) for kind in ("NBIRTH", "NDATA", "NDEATH")]
        writes += [node.format(kind) + "/+" for kind in ("DBIRTH", "DDATA", "DDEATH")]
        commands += [node.format("NCMD"), node.format("DCMD") + "/+"]
        reads += list(commands)
        # Its own births and deaths: another session's there is an identity conflict (edge.publish.identity).
        reads += [node.format("NBIRTH"), node.format("NDEATH")]
        if settings.primary_host_id:
            reads.append(f"{SPARKPLUG}/STATE/{settings.primary_host_id}")
        published.append(f"{SPARKPLUG}/{settings.group_id}/#")
    if "json" in settings.formats:
        topics = JsonTopics(settings.json_prefix)
        prefix = topics.prefix
        writes += [topics.gateway_status_topic, f"{prefix}/+/online", f"{prefix}/+/state/#",
                   f"{prefix}/+/events/#", f"{prefix}/+/history/#", f"{topics.command_filter}/reply/#"]
        commands.append(topics.command_filter)
        reads.append(topics.command_filter)
        published.append(f"{prefix}/#")
    return AclTopics(tuple(writes), tuple(reads), tuple(commands), tuple(published))


def render_acl(config: Config, gateway_user: str, mes_user: str, primary_host_user: bool = True) -> str:
    """The mosquitto acl_file text for `config`'s gateway, its account `gateway_user` and the MES `mes_user`."""
    topics = acl_topics(config)
    spb = config.mqtt.sparkplug
    who = f"{spb.group_id}/{spb.edge_node_id}" if spb is not None else "the JSON gateway"
    # mosquitto takes the rest of a `topic` line as the topic: comments go on lines of their own.
    out = [
        f"# mosquitto acl_file for focas-edge {who}, written by `focas-edge init --acl` (docs/writes.md, "
        "\"Who may write\").",
        "# mosquitto.conf needs:  allow_anonymous false / password_file FILE / acl_file THIS-FILE",
        "# Accounts: mosquitto_passwd -c FILE " + gateway_user + " ; mosquitto_passwd FILE " + mes_user,
        "# Anything not granted here is refused. Several gateways on one broker: one `user` block each.",
        "",
        f"# The gateway (mqtt.username: {gateway_user}): publishes only its own topics, reads its commands.",
        f"user {gateway_user}",
        *(f"topic write {topic}" for topic in topics.gateway_writes),
        *(f"topic read {topic}" for topic in topics.gateway_reads),
        "",
        "# The MES: the only account that may send commands (writes to a CNC); reads what the gateway publishes.",
        f"user {mes_user}",
        *(f"topic write {topic}" for topic in topics.commands),
        *(f"topic read {topic}" for topic in topics.published),
        f"topic read {SPARKPLUG}/STATE/#",
    ]
    if spb is not None and spb.primary_host_id and primary_host_user:
        out += ["# The MES is the Sparkplug primary host (mqtt.sparkplug.primary_host_id): it publishes STATE.",
                f"topic write {SPARKPLUG}/STATE/{spb.primary_host_id}"]
    out += [
        "",
        "# A reader (dashboard, historian) that must never write: uncomment and name its account.",
        "# user dashboard",
        *(f"# topic read {topic}" for topic in topics.published),
        "",
    ]
    return "\n".join(out)
