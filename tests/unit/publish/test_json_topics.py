"""The retained JSON state of a machine whose session dropped says STALE, never GOOD."""

from __future__ import annotations

import json

from edge.publish.json_topics import JsonTopics
from edge.samples import MetricType, Quality, Sample


def test_a_stale_restatement_keeps_the_value_and_its_cnc_time_and_says_since_when() -> None:
    topics = JsonTopics("focas")
    sample = Sample("Spindle/1/Speed", 1200, MetricType.INT32, 1_800_000_000_000, Quality.GOOD)
    live = topics.state("m1", sample)
    stale = topics.state("m1", sample, stale_since_ms=1_800_000_015_250)
    assert live.topic == stale.topic == "focas/m1/state/Spindle/1/Speed" and stale.retain and live.retain
    live_doc, stale_doc = json.loads(live.payload), json.loads(stale.payload)
    assert live_doc["quality"] == "GOOD" and "stale_since" not in live_doc
    assert stale_doc["quality"] == "STALE" and stale_doc["stale_since"] == "2027-01-15T08:00:15.250Z"
    assert (stale_doc["value"], stale_doc["ts"]) == (1200, 1_800_000_000_000)
    assert stale_doc["seq"] > live_doc["seq"]
