"""Which configured axis-0 parameter/diagnosis numbers a control treats as axis-type.

A number such as parameter 1850 exists once per axis. Read with axis 0, a control either answers the
all-axes record (axis -1, as the simulator does) or - not in any public capture, so both are accepted -
refuses with EW_ATTRIB or EW_NUMBER. Either way the number is then read for every axis (axis -1, the form
real clients use) and published per axis name. Asked once per session, with the static reads.
"""

from __future__ import annotations

import logging
from typing import Any

from edge.collect.settings import MachineSettings
from edge.focas import items as it
from edge.focas.errors import EW_ATTRIB, EW_NUMBER, OutOfRange
from edge.focas.values import ALL_AXES

log = logging.getLogger(__name__)

AXIS_TYPE_REFUSALS = frozenset({EW_ATTRIB, EW_NUMBER})

NumberRead = it.ReadParams | it.ReadDiag


def axis_zero_reads(machine: MachineSettings) -> list[tuple[str, NumberRead]]:
    """The configured axis-0 numbers as (metric folder, read)."""
    params = [("Param", it.ReadParams(p.number, p.number, 0)) for p in machine.poll.params if p.axis == 0]
    diags = [("Diag", it.ReadDiag(d.number, d.number, 0)) for d in machine.poll.diags if d.axis == 0]
    return [*params, *diags]


def answered_per_axis(result: object) -> bool:
    """True when a one-number record read came back as an all-axes record."""
    return isinstance(result, list) and len(result) == 1 and getattr(result[0], "axis", 0) == ALL_AXES


def refused_as_axis_type(result: object) -> bool:
    return isinstance(result, OutOfRange) and result.code in AXIS_TYPE_REFUSALS


def all_axes(read: NumberRead) -> NumberRead:
    return type(read)(read.first, read.last, ALL_AXES)


async def per_axis_numbers(session: Any, machine: MachineSettings) -> frozenset[tuple[str, int]]:
    """(folder, number) of every configured axis-0 number to read per axis on this control."""
    reads = axis_zero_reads(machine)
    if not reads:
        return frozenset()
    results = await session.batch([read for _, read in reads])
    found = {(folder, read.first) for (folder, read), result in zip(reads, results, strict=True)
             if answered_per_axis(result)}
    retry = [(folder, read) for (folder, read), result in zip(reads, results, strict=True)
             if refused_as_axis_type(result)]
    if retry:
        again = await session.batch([all_axes(read) for _, read in retry])
        for (folder, read), result in zip(retry, again, strict=True):
            if isinstance(result, list) and result:
                found.add((folder, read.first))
    for folder, number in sorted(found):
        log.info("axis-type number read per axis machine=%s %s=%d", machine.id, folder.lower(), number)
    return frozenset(found)
