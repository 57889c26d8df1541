"""The Sparkplug replay encodes parsed spool rows; a row it cannot read is read as samples, or dropped."""

from __future__ import annotations

import asyncio
from collections import Counter
from pathlib import Path

from bench.replay_cost import NodeTarget, PacketConn
from edge.publish import payload as pl
from edge.publish import replay
from edge.publish.aliases import AliasMap
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.holding import SpoolWriter
from edge.publish.link import DeliveryLink
from edge.publish.node import SparkplugNode
from edge.publish.replay import Replayer
from edge.publish.replay_dedupe import DeliveredValues
from edge.publish.spool import DiskSpool
from edge.publish.tasks import BackgroundTasks
from edge.samples import MetricSpec, MetricType, Sample


def _replay(spool: DiskSpool, node: SparkplugNode, delivered: DeliveredValues, counters: Counter[str]) -> list[bytes]:
    """One replay of the whole spool over a link whose barriers all succeed; the payloads sent."""
    tasks = BackgroundTasks()
    link = DeliveryLink("sparkplug", SpoolWriter(spool, counters), counters, ForwardingPolicy(replay_rows_per_s=1e6),
                        tasks, delivered)
    conn = PacketConn(keep=True)
    link.attach(conn, "test")  # type: ignore[arg-type]
    replayer = Replayer(link, NodeTarget(node), spool, counters, tasks, delivered)
    asyncio.run(replayer._replay_rows(conn, link.session))  # type: ignore[arg-type]
    return conn.kept or []


def test_rows_go_out_in_order_and_an_unreadable_one_is_dropped_without_a_seq(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite")
    for i in range(4):
        spool.hold("sparkplug", "m1", "data", [Sample("a", float(i), MetricType.DOUBLE, 100 + i)])
    bodies = {2: b'[["a", 1.0, "Double", 101.0, 192]]',  # a float timestamp: read leniently, as samples
              3: b'[["a", 2.0, "Double", 102, 7]]'}  # no such quality: unreadable
    for row_id, body in bodies.items():
        spool._conn().execute("UPDATE spool SET body = ? WHERE id = ?", (body, row_id))
    node = SparkplugNode("G", "E", AliasMap(None), clock=lambda: 1)
    node.session_started(1)
    node.device_online("m1", [MetricSpec("a", MetricType.DOUBLE)], [])
    node.births()
    counters: Counter[str] = Counter()
    payloads = [pl.decode(payload) for payload in _replay(spool, node, DeliveredValues(), counters)]
    assert [p.seq for p in payloads] == [2, 3, 4], "consecutive after NBIRTH 0 and DBIRTH 1"
    assert [(m.timestamp, m.double_value, m.is_historical) for p in payloads for m in p.metrics] == \
        [(100, 0.0, True), (101, 1.0, True), (103, 3.0, True)]
    assert spool.pending() == 0 and spool.dropped == 1 and counters["replayed_rows"] == 3
    spool.close()


def test_a_devices_rows_share_ddata_in_order_and_a_row_the_host_may_have_goes_alone(tmp_path: Path) -> None:
    """Rows of one device in a step go out MERGE_ROWS to a DDATA, oldest first; a row whose values the host
    may have (a birth carried them) goes through the dedupe on its own, after the rows before it."""
    spool = DiskSpool(tmp_path / "s.sqlite")
    rows = replay.MERGE_ROWS + 3
    for i in range(rows):
        for device in ("m1", "m2"):
            spool.hold("sparkplug", device, "data", [Sample("a", float(i), MetricType.DOUBLE, 100 + i)])
    node = SparkplugNode("G", "E", AliasMap(None), clock=lambda: 1)
    node.session_started(1)
    for device in ("m1", "m2"):
        node.device_online(device, [MetricSpec("a", MetricType.DOUBLE)], [])
    node.births()
    delivered = DeliveredValues()
    delivered.record("m2", [Sample("a", 5.0, MetricType.DOUBLE, 105)])  # as if a DBIRTH carried it
    kept = _replay(spool, node, delivered, Counter())
    sent = [[m.double_value for m in pl.decode(payload).metrics] for payload in kept]
    m1 = [float(i) for i in range(rows)]
    assert sent[:2] == [m1[:replay.MERGE_ROWS], m1[replay.MERGE_ROWS:]]
    assert sent[2:] == [[0.0, 1.0, 2.0, 3.0, 4.0], m1[6:replay.MERGE_ROWS], m1[replay.MERGE_ROWS:]], \
        "m2: the rows before 105, 105 left out as the host's, then the rest"
    assert [pl.decode(payload).seq for payload in kept] == list(range(3, 3 + len(sent)))
    assert spool.pending() == 0 and delivered.skipped == 1
    spool.close()


def test_values_a_birth_carried_are_left_out_of_the_merged_rows_without_samples(tmp_path: Path) -> None:
    """Rows whose timestamps only births share stay on the merged path: the values a DBIRTH carried are
    left out (counted as skipped), the row's other values go out in the same DDATA, no row as samples."""
    spool = DiskSpool(tmp_path / "s.sqlite")
    for i in range(6):
        spool.hold("sparkplug", "m1", "data", [Sample("a", float(i), MetricType.DOUBLE, 100 + i),
                                               Sample("b", float(-i), MetricType.DOUBLE, 100 + i)])
    node = SparkplugNode("G", "E", AliasMap(None), clock=lambda: 1)
    node.session_started(1)
    node.device_online("m1", [MetricSpec("a", MetricType.DOUBLE), MetricSpec("b", MetricType.DOUBLE)], [])
    node.births()
    delivered = DeliveredValues()
    # The DBIRTH carried a = 3.0 at 103 (its latest) and b = -5.0 at 105; b = 9.0 at 103 was not sent.
    delivered.record_birth("m1", [Sample("a", 3.0, MetricType.DOUBLE, 103), Sample("b", -5.0, MetricType.DOUBLE, 105)])
    counters: Counter[str] = Counter()
    kept = _replay(spool, node, delivered, counters)
    sent = [[(m.timestamp, m.double_value) for m in pl.decode(payload).metrics] for payload in kept]
    everything = [(100 + i, v) for i in range(6) for v in (float(i), float(-i))]
    assert sent == [[pair for pair in everything if pair not in {(103, 3.0), (105, -5.0)}]], "one DDATA"
    assert delivered.skipped == 2 and counters["replayed_rows_as_samples"] == 0
    assert spool.pending() == 0 and counters["replayed_rows"] == 6
    spool.close()


def test_a_row_whose_every_value_a_birth_carried_is_acknowledged_and_not_sent(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite")
    spool.hold("sparkplug", "m1", "data", [Sample("a", 1.0, MetricType.DOUBLE, 100)])
    node = SparkplugNode("G", "E", AliasMap(None), clock=lambda: 1)
    node.session_started(1)
    node.device_online("m1", [MetricSpec("a", MetricType.DOUBLE)], [])
    node.births()
    delivered = DeliveredValues()
    delivered.record_birth("m1", [Sample("a", 1.0, MetricType.DOUBLE, 100)])
    counters: Counter[str] = Counter()
    assert _replay(spool, node, delivered, counters) == []
    assert spool.pending() == 0 and delivered.skipped == 1 and counters["replayed_rows"] == 1
    spool.close()
