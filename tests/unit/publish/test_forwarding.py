"""The outbox of unconfirmed live batches: a barrier confirms exactly what was sent before it."""

from __future__ import annotations

from edge.publish.forwarding import HeldBatch, Outbox


def _record(outbox: Outbox, batch: HeldBatch) -> None:
    """The outbox remembers a sent batch by its parts, as the live path hands them."""
    outbox.add(batch.device_id, batch.kind, batch.samples)


def _batch(n: int) -> HeldBatch:
    return HeldBatch(f"m{n}", "data", [])


def test_a_barrier_confirms_what_was_recorded_before_it_and_nothing_after() -> None:
    outbox = Outbox()
    for n in range(5):
        _record(outbox, _batch(n))
    mark = outbox.mark()
    _record(outbox, _batch(5))
    _record(outbox, _batch(6))
    assert outbox.confirm(mark) == 5
    assert len(outbox) == 2
    assert outbox.confirm(mark) == 0  # a late duplicate PUBACK changes nothing
    assert [b.device_id for b in outbox.take_all()] == ["m5", "m6"]
    assert len(outbox) == 0 and outbox.confirm(outbox.mark()) == 0
