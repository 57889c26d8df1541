"""Sparkplug DCMD metrics as writes: a metric name back to its target, and one DCMD as one request.

A DCMD metric arrives resolved (name or alias) and decoded to its birth type by the publisher; what the
command layer needs is the CNC address behind the name, which the machine's poll plan knows: a metric
of a macro read is that macro, of a PMC read that element's bytes, of a parameter read that parameter.
Adjacent PMC elements written by one DCMD merge into one range write (so a DCMD carrying R100..R139 is
one 40-byte write, which the session sends as 32 + 8 bytes).
"""

from __future__ import annotations

from collections.abc import Sequence

from edge.collect import MachinePlan, PlannedRead
from edge.command.requests import WriteOp
from edge.focas import items as it
from edge.focas.targets import ALL_AXES, MacroTarget, ParamTarget, PmcTarget, WritableTarget


def metric_target(plan: MachinePlan, name: str) -> WritableTarget | None:
    """The write target behind a writable metric of the plan; None if the name has none."""
    for read in plan.reads:
        for index, spec in enumerate(read.metrics):
            if spec.name == name and spec.writable:
                if read.bits and isinstance(read.item, it.ReadPmc):
                    byte = read.item.start + index // 8
                    return PmcTarget(read.item.area, byte, byte, read.item.data_type, bit=index % 8)
                return _element_target(read.item, index)
    return None


def _element_target(item: it.ReadItem, index: int) -> WritableTarget | None:
    if isinstance(item, it.ReadMacros):
        return MacroTarget(item.first + index, item.first + index)
    if isinstance(item, it.ReadPmc):
        width = item.data_type.width
        start = item.start + index * width
        return PmcTarget(item.area, start, start + width - 1, item.data_type)
    if isinstance(item, it.ReadParams):  # an all-axes read publishes one metric per axis, in axis order
        return ParamTarget(item.first, item.first, index + 1 if item.axis == ALL_AXES else item.axis)
    return None


def reads_touching(plan: MachinePlan, target: WritableTarget) -> list[PlannedRead]:
    """The plan's reads whose metrics a write to `target` can change (re-read them to publish)."""
    return [read for read in plan.reads if _overlaps(read.item, target)]


def _overlaps(item: it.ReadItem, target: WritableTarget) -> bool:
    if isinstance(target, MacroTarget) and isinstance(item, it.ReadMacros):
        return item.first <= target.last and target.first <= item.last
    if isinstance(target, PmcTarget) and isinstance(item, it.ReadPmc):
        return item.area == target.area and item.start <= target.end and target.start <= item.end
    if isinstance(target, ParamTarget) and isinstance(item, it.ReadParams):
        same_axis = item.axis in (target.axis, ALL_AXES)
        return item.first <= target.last and target.first <= item.last and same_axis
    return False


def merge_adjacent(ops: Sequence[WriteOp]) -> list[WriteOp]:
    """Consecutive writes to adjacent PMC elements of one area and type become one range write."""
    merged: list[WriteOp] = []
    for op in ops:
        previous = merged[-1] if merged else None
        if previous is not None and _continues(previous, op):
            assert isinstance(previous.target, PmcTarget) and isinstance(op.target, PmcTarget)
            assert isinstance(previous.value, tuple) and isinstance(op.value, tuple)
            target = PmcTarget(op.target.area, previous.target.start, op.target.end, op.target.data_type)
            merged[-1] = WriteOp(target, previous.value + op.value, previous.bounded or op.bounded)
        else:
            merged.append(op)
    return merged


def _continues(previous: WriteOp, op: WriteOp) -> bool:
    a, b = previous.target, op.target
    return (isinstance(a, PmcTarget) and isinstance(b, PmcTarget) and a.bit is None and b.bit is None
            and a.area == b.area and a.data_type is b.data_type and b.start == a.end + 1)
