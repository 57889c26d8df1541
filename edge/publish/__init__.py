"""Publishing: MQTT connection, Sparkplug B 3.0 edge-node session, JSON topics. Knows samples, not FOCAS."""

from edge.publish.publisher import CommandSource, DroppingSpool, Publisher, Spool
from edge.publish.settings import PublishSettings

__all__ = ["CommandSource", "DroppingSpool", "PublishSettings", "Publisher", "Spool"]
