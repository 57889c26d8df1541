"""Publishing: samples in, MQTT out, as a Sparkplug B 3.0 edge node and as plain JSON topics, with store and
forward. Knows samples and metrics, not FOCAS.

What lives here (one job per module):
  publisher          Publisher, the facade the daemon and the pollers call: fans each call out to the formats
  sparkplug_session  the edge node's MQTT session: Will and bdSeq, subscriptions, births, STATE, rebirth, NCMD/DCMD
  json_session       the JSON topics' MQTT session: retained status and state, events, commands, replies
  link               per connection: the outbox of unconfirmed live batches, the QoS 1 barrier probe, suspect-dead
  replay             per format: the paced replay of the spool after a reconnect
  holding            the Spool interface, and the writer that survives a failing spool
  inbound            CommandSource and the command handlers the command layer installs
  tasks              the one owner of the publisher's background tasks
  identity           is another gateway using our Sparkplug id or client id? evidence in, ERROR and backoff out
  node, ddata, payload, aliases, bdseq, primary_host   Sparkplug, sans-IO: births, seq, metric encoding, STATE
  json_topics        JSON topic names and bodies, sans-IO
  mqtt, mqtt_wire, credentials, connect_failure        the paho connection driven by the asyncio loop
  broker_trouble     a broker outage said once, summarised a minute, and its end; the state the status shows;
                     the one classifier of connect errors (connect_failure only adds the setting to check)
  forwarding, replay_dedupe, spool, spool_disk         store and forward bookkeeping, the SQLite spool
  state_store        small JSON documents in state_dir (bdSeq, aliases)
  settings           PublishSettings: what this layer needs from the config, as a plain dataclass

Rules:
1. Publish knows samples and metrics (edge.samples), never FOCAS. It does not import edge.focas,
   edge.collect, edge.command, edge.service or edge.cli. It may import edge.config (the layer below), but
   needs only edge.samples and edge.statefile: the daemon builds PublishSettings from the config.
2. Nothing here blocks or raises because the broker is away: what cannot go out live is held in the spool
   and replayed, and every loss is counted.
3. One asyncio loop runs it all; each session is the single writer of its connection, so Sparkplug seq
   order is wire order.
4. Other packages import what they need through this module (`__all__`); tests may reach into modules.
"""

from edge.publish import payload
from edge.publish.credentials import apply_credentials
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.holding import DroppingSpool, Spool
from edge.publish.inbound import CommandSource, DeviceCommands, RefusedMetric
from edge.publish.publisher import Publisher
from edge.publish.settings import PublishSettings
from edge.publish.spool import open_spool

__all__ = [
    "CommandSource",
    "DeviceCommands",
    "DroppingSpool",
    "ForwardingPolicy",
    "PublishSettings",
    "Publisher",
    "RefusedMetric",
    "Spool",
    "apply_credentials",
    "open_spool",
    "payload",
]
