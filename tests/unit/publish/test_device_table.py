"""Device tables: devices declaring the same metrics share one layout; each keeps its own aliases and values."""

from __future__ import annotations

from edge.publish import payload as pl
from edge.publish.aliases import AliasMap
from edge.publish.device_table import layout_of
from edge.publish.node import SparkplugNode
from edge.samples import MetricSpec, MetricType, Sample

SPECS = [MetricSpec("Status/Run", MetricType.INT16), MetricSpec("Macro/500", MetricType.DOUBLE)]


def test_equal_spec_lists_share_one_layout_and_a_repeated_name_keeps_its_first_place() -> None:
    assert layout_of(list(SPECS)) is layout_of(tuple(SPECS))
    later = MetricSpec("Status/Run", MetricType.INT32)
    layout = layout_of([*SPECS, later])
    assert layout.names == ("Status/Run", "Macro/500")
    assert layout.specs["Status/Run"] is later and layout.slots["Status/Run"][0] == 0


def test_two_devices_share_a_layout_but_not_their_aliases_or_values() -> None:
    n = SparkplugNode("G", "E", AliasMap(), clock=lambda: 1000)
    n.session_started(1)
    n.device_online("m1", SPECS, [Sample("Macro/500", 1.5, MetricType.DOUBLE, 5)])
    n.device_online("m2", SPECS, [Sample("Macro/500", 2.5, MetricType.DOUBLE, 6)])
    births = {m.topic.rsplit("/", 1)[-1]: pl.decode(m.payload) for m in n.births()[1:]}
    macro = {d: {m.name: m for m in p.metrics}["Macro/500"] for d, p in births.items()}
    assert (macro["m1"].double_value, macro["m2"].double_value) == (1.5, 2.5)
    assert macro["m1"].alias != macro["m2"].alias
    assert n.birth_samples("m2") == [("m2", [Sample("Macro/500", 2.5, MetricType.DOUBLE, 6)])]


def test_a_device_declared_again_keeps_the_last_values_of_the_metrics_it_still_has() -> None:
    n = SparkplugNode("G", "E", AliasMap(), clock=lambda: 1000)
    n.session_started(1)
    n.device_online("m1", SPECS, [Sample("Status/Run", 3, MetricType.INT16, 5),
                                  Sample("Macro/500", 1.5, MetricType.DOUBLE, 5)])
    n.device_online("m1", [SPECS[1], MetricSpec("Macro/501", MetricType.DOUBLE)], [])
    assert n.birth_samples("m1") == [("m1", [Sample("Macro/500", 1.5, MetricType.DOUBLE, 5)])]
