"""Device tables: devices declaring the same metrics share one layout; each keeps its own aliases and values."""

from __future__ import annotations

from edge.publish import payload as pl
from edge.publish.aliases import AliasMap
from edge.publish.device_table import layout_of
from edge.publish.node import SparkplugNode
from edge.publish.sparkplug_b_pb2 import Payload
from edge.samples import MetricSpec, MetricType, Sample

SPECS = [MetricSpec("Status/Run", MetricType.INT16), MetricSpec("Macro/500", MetricType.DOUBLE)]


def dbirths(n: SparkplugNode) -> dict[str, dict[str, Payload.Metric]]:
    """Each device's DBIRTH of the next births(), as its metrics by name: what a host learns of it."""
    return {m.topic.rsplit("/", 1)[-1]: {x.name: x for x in pl.decode(m.payload).metrics}
            for m in n.births() if "/DBIRTH/" in m.topic}


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
    births = dbirths(n)
    macro = {d: metrics["Macro/500"] for d, metrics in births.items()}
    assert (macro["m1"].double_value, macro["m2"].double_value) == (1.5, 2.5)
    assert (macro["m1"].timestamp, macro["m2"].timestamp) == (5, 6)  # each device's own sample
    assert macro["m1"].alias != macro["m2"].alias
    assert births["m2"]["Status/Run"].is_null  # declared but never reported: carried as null


def test_a_device_declared_again_keeps_the_last_values_of_the_metrics_it_still_has() -> None:
    n = SparkplugNode("G", "E", AliasMap(), clock=lambda: 1000)
    n.session_started(1)
    n.device_online("m1", SPECS, [Sample("Status/Run", 3, MetricType.INT16, 5),
                                  Sample("Macro/500", 1.5, MetricType.DOUBLE, 5)])
    n.device_online("m1", [SPECS[1], MetricSpec("Macro/501", MetricType.DOUBLE)], [])
    birth = dbirths(n)["m1"]
    assert set(birth) == {"Macro/500", "Macro/501"}  # Status/Run is no longer declared
    assert (birth["Macro/500"].double_value, birth["Macro/500"].timestamp) == (1.5, 5)
    assert birth["Macro/501"].is_null


def test_devices_whose_aliases_have_the_same_widths_share_their_offsets_and_data_names_each_its_own() -> None:
    """The alias field offsets are one tuple for the devices whose aliases are as wide; each DDATA still names
    its own device's metric (the alias its DBIRTH gave)."""
    n = SparkplugNode("G", "E", AliasMap(), clock=lambda: 1000)
    n.session_started(1)
    for device in ("m1", "m2"):
        n.device_online(device, SPECS, [])
    births = dbirths(n)
    tables = n._devices
    assert tables["m1"].alias_ends is tables["m2"].alias_ends
    assert tables["m1"].alias_data != tables["m2"].alias_data
    for device in ("m1", "m2"):
        (message,) = n.device_data(device, [Sample("Macro/500", 7.5, MetricType.DOUBLE, 9)])
        (metric,) = pl.decode(message.payload).metrics
        assert metric.alias == births[device]["Macro/500"].alias and metric.double_value == 7.5
