"""`focas-edge write HOST TARGET=VALUE...`: write to one CNC, read each value back, print the outcome.

    focas-edge write 10.0.0.5 macro:500=1.25 pmc:R100=0x41 pmc:R100.3=1 param:6711=0
    focas-edge write 10.0.0.5 pmc:R100-R103=1,2,3,4 pmc:D2204.word=600

Writes go in the order given and stop at the first failure. Every value is checked before connecting
(a bad one is exit 2 and nothing is written). Typed PMC values are sent big-endian, the byte order the
PMC read answers in, so what you write is what `read` shows. A write whose read-back differs (the ladder
or the CNC overwrote it) is a failure, exit 1. X (machine inputs) and F (CNC-to-PMC) addresses are owned
by the machine and the CNC; writing them needs --force. This tool bypasses the daemon's write policy: it
is for commissioning, by someone standing at the machine.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
from dataclasses import dataclass
from functools import partial
from typing import Any

from edge.cli import EXIT_FAILURE, EXIT_OK
from edge.cli.read import (
    ItemOutcome,
    add_connection_arguments,
    describe_error,
    error_object,
    json_value,
    parse_and_open,
    plan_read,
    read_batch,
)
from edge.command import (
    CommandRefused,
    WriteOp,
    check_param,
    expected_macro,
    param_record,
    pmc_bytes,
    read_item,
    write_target,
)
from edge.focas.errors import FocasError
from edge.focas.model import PmcType
from edge.focas.targets import MacroTarget, ParamTarget, PmcTarget, TargetError, WritableTarget, parse_assignment

# PMC areas whose signals another party owns: a write there changes what the ladder believes.
GUARDED_AREAS = {
    "X": "X is machine inputs (signals from the machine to the PMC): a write there makes the ladder "
         "see a switch or sensor state the machine did not report, until the next input scan",
    "F": "F is the CNC-to-PMC signals (the CNC's status to the ladder): a write there makes the ladder see "
         "a CNC state that is not real, until the CNC overwrites it",
}


class ReadBackDiffers(Exception):
    """The CNC answered the write, but the target does not hold the value written."""

    code = "read_back_differs"


@dataclass(frozen=True, slots=True)
class Write:
    """One validated write: the target and the value in the form the session method takes."""

    text: str
    target: WritableTarget
    value: float | int | bool | bytes


def parse_write(text: str, force: bool = False) -> Write:
    """`TARGET=VALUE` checked completely; TargetError says what is wrong (X and F need `force`)."""
    target, raw = parse_assignment(text)
    if isinstance(target, PmcTarget) and target.area in GUARDED_AREAS and not force:
        raise TargetError(f"{text!r}: {GUARDED_AREAS[target.area]}; pass --force to write it anyway")
    if isinstance(target, MacroTarget):
        if target.count != 1:
            raise TargetError(f"{text!r}: write one macro at a time (macro:N=VALUE)")
        return Write(text, target, _finite(text, raw))
    if isinstance(target, PmcTarget):
        if target.bit is not None:
            return Write(text, target, _bit(text, raw))
        return Write(text, target, _pmc_bytes(text, target, raw))
    if target.last != target.first:
        raise TargetError(f"{text!r}: write one parameter at a time (param:N[/AXIS]=VALUE)")
    if target.bit is not None:
        return Write(text, target, _bit(text, raw))
    return Write(text, target, _number(text, raw))


def _finite(text: str, raw: str) -> float:
    try:
        value = float(raw)
    except ValueError:
        raise TargetError(f"{text!r}: expected a number, got {raw!r}") from None
    if not math.isfinite(value):
        raise TargetError(f"{text!r}: {raw} is not a finite number")
    return value


def _integer(text: str, raw: str) -> int:
    try:
        return int(raw, 0)
    except ValueError:
        raise TargetError(f"{text!r}: expected an integer (decimal, 0x.. or 0b..), got {raw!r}") from None


def _number(text: str, raw: str) -> int | float:
    try:
        return int(raw, 0)
    except ValueError:
        return _finite(text, raw)


def _bit(text: str, raw: str) -> bool:
    lowered = raw.lower()
    if lowered in ("1", "true", "on"):
        return True
    if lowered in ("0", "false", "off"):
        return False
    raise TargetError(f"{text!r}: a bit takes 0 or 1, got {raw!r}")


def _pmc_bytes(text: str, target: PmcTarget, raw: str) -> bytes:
    parts = [p.strip() for p in raw.split(",")]
    if len(parts) != target.count:
        raise TargetError(f"{text!r}: {target} holds {target.count} value(s), got {len(parts)}")
    kind = target.data_type
    if kind in (PmcType.FLOAT, PmcType.DOUBLE):
        return pmc_bytes(target, tuple(_finite(text, p) for p in parts))
    bits = kind.width * 8
    values = []
    for part in parts:
        value = _integer(text, part)
        if not -(1 << (bits - 1)) <= value < (1 << bits):
            raise TargetError(f"{text!r}: {part} does not fit a {kind.name.lower()} ({bits} bits)")
        values.append(value)
    return pmc_bytes(target, tuple(values))


async def apply(session: Any, write: Write) -> None:
    """Send one write through the session's method for its kind."""
    await write_target(session, write.target, write.value)


async def write_all(session: Any, writes: list[Write]) -> list[ItemOutcome]:
    """Write in order, reading each target back; stop at the first failure."""
    outcomes: list[ItemOutcome] = []
    try:
        async with session as cnc:
            for write in writes:
                try:
                    await check_param_type(cnc, write)
                    await apply(cnc, write)
                except (FocasError, CommandRefused) as exc:
                    outcomes.append(ItemOutcome(write.text, error=exc))
                    break
                (read_back,) = await read_batch(cnc, [plan_read(str(write.target))])
                error = read_back.error
                if error is None and not holds(write, read_back.value):
                    error = ReadBackDiffers(f"written, but reads back {json.dumps(json_value(read_back.value))}, "
                                            f"not {write.text.partition('=')[2].strip()} (the ladder or the CNC "
                                            "may own this address)")
                outcomes.append(ItemOutcome(write.text, read_back.value, error))
                if error is not None:
                    break
    except FocasError as exc:
        failed = writes[len(outcomes)].text if len(outcomes) < len(writes) else "connection"
        outcomes.append(ItemOutcome(failed, error=exc))
    return outcomes


async def check_param_type(cnc: Any, write: Write) -> None:
    """A whole parameter's value must fit the type the CNC reports (2^31 is no 2-word value: it would land
    as -2^31); CommandRefused before anything is written. The daemon's rule, without its allow-list."""
    target = write.target
    if isinstance(target, ParamTarget) and target.bit is None and not isinstance(write.value, bytes | bool):
        result = await cnc.read(read_item(target))
        check_param(WriteOp(target, write.value), param_record(target, result))


def holds(write: Write, shown: object) -> bool:
    """Whether the value read back (as `read` shows it) is the value written."""
    target, wanted = write.target, write.value
    if isinstance(wanted, bool):
        return isinstance(shown, int) and bool(shown) is wanted
    if isinstance(target, PmcTarget):
        values = list(shown.values()) if isinstance(shown, dict) else [shown]
        numbers = tuple(v for v in values if isinstance(v, int | float) and not isinstance(v, bool))
        # compared as bytes: -1 written to a byte reads back 255
        return len(numbers) == len(values) and pmc_bytes(target, numbers) == wanted
    if not isinstance(shown, int | float) or isinstance(shown, bool) or isinstance(wanted, bytes):
        return False
    expected = expected_macro(float(wanted)) if isinstance(target, MacroTarget) else float(wanted)
    return math.isclose(float(shown), expected, rel_tol=1e-9, abs_tol=1e-9)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "write", help="write values to one CNC (commissioning tool)",
        description="Write TARGET=VALUE to one CNC in order, reading each back. Targets: macro:500=1.25 "
                    "pmc:R100=0x41 pmc:R100-R101=1,2 pmc:R100.3=1 pmc:D2204.word=600 param:6711=0 "
                    "param:1815/1=3 param:1815/0.3=1.",
        epilog="Exit codes: 0 every write done and read back, 1 the CNC refused one, a value read back differs "
               "or the network failed, 2 bad usage (an X or F address without --force).")
    add_connection_arguments(parser)
    parser.add_argument("writes", nargs="+", metavar="TARGET=VALUE")
    parser.add_argument("--json", action="store_true", help="one JSON object per write: item, value, error")
    parser.add_argument("--force", action="store_true",
                        help="allow writes to X (machine inputs) and F (CNC-to-PMC signals) addresses")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    prepared = parse_and_open("write", args, partial(parse_write, force=args.force), args.writes)
    if isinstance(prepared, int):
        return prepared
    writes, session = prepared
    outcomes = asyncio.run(write_all(session, writes))
    for outcome in outcomes:
        if args.json:
            print(json.dumps({"item": outcome.item, "value": json_value(outcome.value),
                              "error": _error_object(outcome.error) if outcome.error else None}))
        elif outcome.error is None:
            print(f"{outcome.item}  ok, reads back {json.dumps(json_value(outcome.value))}")
        if isinstance(outcome.error, ReadBackDiffers | CommandRefused):
            print(f"focas-edge write: {outcome.item}: {outcome.error}", file=sys.stderr)
        elif outcome.error is not None:
            print(f"focas-edge write: {outcome.item}: {describe_error(outcome.error)}", file=sys.stderr)
    ok = len(outcomes) == len(writes) and all(o.error is None for o in outcomes)
    return EXIT_OK if ok else EXIT_FAILURE


def _error_object(error: BaseException) -> dict[str, Any]:
    if isinstance(error, ReadBackDiffers):
        return {"type": type(error).__name__, "code": error.code, "message": str(error)}
    if isinstance(error, CommandRefused):
        return {"type": type(error).__name__, "code": str(error.code), "message": error.message}
    return error_object(error)
