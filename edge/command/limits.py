"""What the control can hold, checked before a write is queued (the CNC remains the final judge).

Only rules that hold for every control of a family are enforced here; exact PMC area sizes depend on
the PMC model and memory option, so an address past the end is left to the CNC (EW_NUMBER ->
out_of_range), and the allow-list is where an integrator bounds the addresses a machine really has.
"""

from __future__ import annotations

from edge.command.errors import CommandRefused, ErrorCode
from edge.focas.model import PmcType, SysInfo
from edge.focas.targets import MacroTarget, ParamTarget, PmcTarget, WritableTarget

# FANUC custom macro variables: #1-#33 local (belong to the running program), #100-#199/#500-#999 common,
# #1000 and up system variables (offsets, interface signals...). #0 is <vacant> and read-only; #34-#99 do
# not exist.
LOCAL_MACROS = range(1, 34)
MISSING_MACROS = range(34, 100)
FLOAT_PMC_TYPES = (PmcType.FLOAT, PmcType.DOUBLE)


def check_limits(target: WritableTarget, sysinfo: SysInfo | None) -> None:
    """Raise CommandRefused(out_of_range) for a number the control family does not have."""
    if isinstance(target, MacroTarget):
        _check_macros(target)
    elif isinstance(target, PmcTarget):
        _check_pmc(target, sysinfo)
    elif isinstance(target, ParamTarget):
        _check_param_axis(target, sysinfo)


def _check_macros(target: MacroTarget) -> None:
    for number in (target.first, target.last):
        if number == 0:
            raise CommandRefused(ErrorCode.OUT_OF_RANGE, f"{target}: #0 is <vacant> and cannot be written")
        if number in LOCAL_MACROS:
            raise CommandRefused(ErrorCode.OUT_OF_RANGE, f"{target}: #{number} is a local variable of the "
                                 "running program; common variables are #100-#199 and #500-#999")
        if number in MISSING_MACROS:
            raise CommandRefused(ErrorCode.OUT_OF_RANGE, f"{target}: there is no macro variable #{number}")


def _check_pmc(target: PmcTarget, sysinfo: SysInfo | None) -> None:
    if target.data_type in FLOAT_PMC_TYPES and sysinfo is not None and not sysinfo.is_30i_style:
        raise CommandRefused(ErrorCode.OUT_OF_RANGE, f"{target}: {target.data_type.name.lower()} PMC data "
                             f"exists on 30i-B/0i-F class controls only; this is a {sysinfo.model_name}")


def _check_param_axis(target: ParamTarget, sysinfo: SysInfo | None) -> None:
    if sysinfo is not None and target.axis > sysinfo.max_axis:
        raise CommandRefused(ErrorCode.OUT_OF_RANGE, f"{target}: axis {target.axis} is beyond this "
                             f"control's {sysinfo.max_axis} axes")
