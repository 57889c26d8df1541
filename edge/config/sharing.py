"""Machines configured alike share one copy of the equal parts of their config.

A fleet file gives hundreds of machines the same poll section (from `defaults:`, a template, or lines
copied): validated, each was its own PollPlan of ~6 kB (PMC and macro ranges, periods, each a model), 6 MB
of the process at 1,000 machines, kept for reload's comparison. The models are frozen, so one instance
serves every machine with an equal part (a multi-path machine's path devices share theirs the same way,
through model_copy). The shared part is put in place in the machine's fresh model, not in a copy of it:
a copy was its own `__dict__` and fields-set of ~1.2 kB a machine (the machine's own are freed anyway).
"""

from __future__ import annotations

from pydantic import BaseModel
from pydantic_core import PydanticSerializationError

from edge.config.machines import MachineConfig

SHARED_PARTS = ("poll", "timeouts", "alarms", "writes")


def share_equal_parts(machines: list[MachineConfig]) -> list[MachineConfig]:
    """The machines, each part in SHARED_PARTS equal to an earlier machine's replaced by that one."""
    seen: dict[tuple[str, str], list[BaseModel]] = {}
    for machine in machines:
        fields = vars(machine)  # frozen: the value is equal, only which object holds it changes
        for part in SHARED_PARTS:
            value = getattr(machine, part)
            if not isinstance(value, BaseModel):
                continue
            try:
                bucket = seen.setdefault((part, value.model_dump_json()), [])
            except PydanticSerializationError:  # not comparable by its JSON: kept as it is
                continue
            first = next((other for other in bucket if other == value), None)
            if first is None:
                bucket.append(value)
            elif first is not value:
                fields[part] = first
    return machines
