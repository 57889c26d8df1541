"""DBIRTHs written by hand (edge.publish.birth_bytes) are byte for byte what the protobuf runtime writes.

The reference is the runtime encoding the node used before (and still uses for the NBIRTH): one
`add_birth_metric` per declared metric, the value or an explicit null, engUnit and Quality properties, the
description, is_historical. Hypothesis drives both with the same device tables, including values the fast
writers hand to the runtime (wrong Python type, out of range, float32 overflow, text that is not UTF-8),
values the runtime refuses (counted, sent null + BAD) and metrics with no value yet.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from edge.publish.aliases import AliasMap
from edge.publish.node import SparkplugNode
from edge.publish.sparkplug_b_pb2 import Payload
from edge.samples import MetricSpec, MetricType, Quality, Sample
from tests.unit.publish.test_ddata import values

CLOCK_MS = 1_700_000_000_123
TYPES = list(MetricType)

names = st.text(min_size=1, max_size=8).filter(lambda n: not set(n) & set("/+#"))
units = st.one_of(st.none(), st.just(""), st.sampled_from(["rpm", "°C"]))
descriptions = st.one_of(st.none(), st.just(""), st.text(max_size=6))
specs = st.lists(st.builds(MetricSpec, names, st.sampled_from(TYPES), unit=units, description=descriptions),
                 min_size=1, max_size=12, unique_by=lambda s: s.name)


@settings(max_examples=300, deadline=None)
@given(specs, st.data())
def test_dbirth_bytes_equal_the_runtime_encoding(declared: list[MetricSpec], data: st.DataObject) -> None:
    n = SparkplugNode("G", "E", AliasMap(None), clock=lambda: CLOCK_MS)
    n.session_started(3)
    last = [data.draw(st.one_of(st.none(), st.builds(
        lambda value, ts, quality, historical, spec=spec: Sample(spec.name, value, spec.type, ts, quality, historical),
        values, st.integers(0, 2**45), st.sampled_from(list(Quality)), st.booleans()))) for spec in declared]
    n.device_online("m1", declared, [s for s in last if s is not None])
    n.nbirth()
    dev = n._devices["m1"]
    reference = Payload(timestamp=CLOCK_MS, seq=1)
    n._add_birth_metrics(reference, "m1", dev, CLOCK_MS)
    errors, not_good = n.encode_errors, set(dev.not_good)
    (dbirth,) = n.dbirth("m1")
    assert dbirth.payload == reference.SerializeToString()
    assert n.encode_errors == 2 * errors and dev.not_good == not_good


def test_a_fleet_sized_dbirth_is_the_runtimes_too() -> None:
    declared = [MetricSpec(f"Axis/{i}/Load", MetricType.DOUBLE, unit="%", description="servo load") for i in range(90)]
    declared += [MetricSpec("Status/Run", MetricType.INT16), MetricSpec("Counters/Parts", MetricType.UINT32)]
    n = SparkplugNode("G", "E", AliasMap(None), clock=lambda: CLOCK_MS)
    n.session_started(3)
    n.device_online("m1", declared, [Sample(s.name, 1.5 if s.type is MetricType.DOUBLE else 7, s.type, CLOCK_MS - i)
                                     for i, s in enumerate(declared[:-1])])
    n.nbirth()
    reference = Payload(timestamp=CLOCK_MS, seq=1)
    n._add_birth_metrics(reference, "m1", n._devices["m1"], CLOCK_MS)
    assert n.dbirth("m1")[0].payload == reference.SerializeToString()
