"""Remote writes: a request (JSON cmd topic or Sparkplug DCMD) parsed, validated, authorised, queued per machine,
written through the machine's session, read back, answered and audited.

What lives here: the daemon's entry point (service), request parsing and the write vocabulary (requests,
dcmd), the policy (policy: enabled switch, allow-list with bounds, rate limit), CNC limits (limits,
signedness), the per-machine write queue (executor), one target's read/write/verify (target_io), replies
(results), the audit log (audit: size-bounded, rotated by the daemon; refusal_summary: one line for a refused
command), reply codes (errors) and what it is told about the machines (settings).

Rules:
1. command may import edge.focas, edge.samples and its own modules; from edge.collect what the poll plan and
   the poller give today: MachinePlan, PlannedRead and metric_values (a DCMD metric's write target and a
   read-back's values come from the machine's plan), MachineSettings (path routing, and the plan before a
   poller has one) and MachinePoller (type only: writes run on the poller's session).
2. It never imports edge.config: it takes CommandSettings, which edge.service.settings builds from the config.
3. It never imports edge.service or edge.cli; edge.publish only for type checking (CommandService replies
   through the Publisher and audits its CommandSource; the daemon wires the two together).
Other packages import command through the names below.
"""

from edge.command.errors import CommandRefused
from edge.command.requests import WriteOp, pmc_bytes
from edge.command.service import CommandService
from edge.command.settings import AllowRule, CommandSettings, RateLimit, WritePolicy
from edge.command.target_io import check_param, expected_macro, param_record, read_item, write_target

__all__ = [
    "AllowRule",
    "CommandRefused",
    "CommandService",
    "CommandSettings",
    "RateLimit",
    "WriteOp",
    "WritePolicy",
    "check_param",
    "expected_macro",
    "param_record",
    "pmc_bytes",
    "read_item",
    "write_target",
]
