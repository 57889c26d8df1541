"""`focas-edge read HOST[:PORT] ITEM...`: read items from one CNC in one batched request and print them.

Items use the target grammar of edge.focas.targets (macro:500-505, param:1815/1, pmc:D2204.word, sysinfo ...).
A readable table by default; `--json` prints one JSON object per item per line: {item, value, error, refused}
(`refused`: each part of a composite the CNC refused, with its return code).
Exit 0 when every item and part was read, 3 when every item answered but some parts were refused, 1 when
an item (or the connection) failed whole, 2 on bad usage.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, is_dataclass, replace
from datetime import datetime
from typing import Any, TypeVar

from edge import ConfigError
from edge.cli import EXIT_FAILURE, EXIT_OK, EXIT_PARTIAL, EXIT_USAGE
from edge.cli.named_reads import NAMED_READS, Parts, Shaper
from edge.collect import refused_as_axis_type
from edge.focas import items as it
from edge.focas.errors import CncError, FocasError
from edge.focas.model import ParamRecord
from edge.focas.targets import (
    ALL_AXES,
    DiagTarget,
    MacroTarget,
    NamedTarget,
    ParamTarget,
    PmcTarget,
    Target,
    TargetError,
    parse_target,
    split_path,
)

DEFAULT_TIMEOUT = 5.0


# ---- shared by read and write ------------------------------------------------------------------------------


T = TypeVar("T")


def add_connection_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("address", metavar="HOST[:PORT]",
                        help="CNC address: host, host:port, tcp:host:port, or unix:/path (packed transport)")
    parser.add_argument("--transport", choices=("focas", "packed"), default="focas",
                        help="focas: native FOCAS/Ethernet (default); packed: the packed-buffer surface")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, metavar="SECONDS",
                        help=f"connect and request timeout (default {DEFAULT_TIMEOUT:g})")
    parser.add_argument("--path", type=int, default=None, metavar="N",
                        help="CNC path to read or write (a twin-turret lathe has 2; default 1); an item may "
                             "name it instead with @N (macro:500@2), the same for every item")


def open_cnc(args: argparse.Namespace) -> Any:
    """An unconnected session for the CLI's address/transport/timeout; ConfigError on a bad address."""
    from edge.focas.connect import open_session

    path = getattr(args, "path", None) or 1
    if path < 1:
        raise ConfigError([f"--path {path}: paths are numbered from 1"])
    if path != 1 and args.transport != "focas":
        raise ConfigError([f"--path {path}: the {args.transport} transport reads path 1 only"])
    extra: dict[str, Any] = {"path": path} if path != 1 else {}
    return open_session(args.transport, args.address, timeout=args.timeout, connect_timeout=args.timeout,
                        **extra)


def describe_error(exc: BaseException) -> str:
    """An error as one line that names the EW code where the CNC gave one."""
    if isinstance(exc, CncError):
        return f"{exc.name} ({exc.code}): {exc}"
    return f"{type(exc).__name__}: {exc}"


def error_object(exc: BaseException) -> dict[str, Any]:
    error: dict[str, Any] = {"type": type(exc).__name__, "message": str(exc)}
    if isinstance(exc, CncError):
        error |= {"code": exc.name, "ew": exc.code}
    return error


def json_value(value: object) -> object:
    """A decoded value as plain JSON data (dataclasses to objects, datetimes to ISO 8601)."""
    if isinstance(value, datetime):
        return value.isoformat()
    if is_dataclass(value) and not isinstance(value, type):
        return {k: json_value(v) for k, v in asdict(value).items()}
    if isinstance(value, dict):
        return {str(k): json_value(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_value(v) for v in value]
    if isinstance(value, float) and value != value:
        return None
    return value


# ---- target -> reads -> value ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ReadPlan:
    """The read items one CLI item needs and how their results become the printed value.

    `parts` names what may fail alone (a composite degrades part by part): the shaper gets None for every
    refused item, and the item fails only when every part was refused."""

    text: str
    items: tuple[it.ReadItem, ...]
    shape: Shaper
    parts: Parts = field(default_factory=dict)
    per_axis: ReadPlan | None = None  # an axis-0 number refused as axis-type is read this way instead


def plan_read(text: str) -> ReadPlan:
    """Raises TargetError for a string that is not a readable target."""
    target = parse_target(text)
    if isinstance(target, NamedTarget):
        named = NAMED_READS[target.name]
        return ReadPlan(text, named.items, named.shape, named.parts)
    items, shape = _reads_for(target)
    per_axis = None
    if isinstance(target, ParamTarget | DiagTarget) and target.axis == 0:
        per_axis_items, per_axis_shape = _reads_for(replace(target, axis=ALL_AXES))
        per_axis = ReadPlan(text, tuple(per_axis_items), per_axis_shape)
    return ReadPlan(text, tuple(items), shape, per_axis=per_axis)


def _reads_for(target: Target) -> tuple[list[it.ReadItem], Shaper]:
    assert not isinstance(target, NamedTarget)
    if isinstance(target, MacroTarget):
        return [it.ReadMacros(target.first, target.last)], \
            lambda r: _by_number(range(target.first, target.last + 1), r[0], "#")
    if isinstance(target, PmcTarget):
        item = it.ReadPmc(target.area, target.start, target.end, target.data_type)
        if target.bit is not None:
            bit = target.bit
            return [item], lambda r: (int(r[0][0]) >> bit) & 1
        addresses = range(target.start, target.end + 1, target.data_type.width)
        return [item], lambda r: _by_number(addresses, r[0], target.area)
    if isinstance(target, ParamTarget):
        read: it.ReadParams | it.ReadDiag = it.ReadParams(target.first, target.last, target.axis)
        param_bit = target.bit
    else:
        read, param_bit = it.ReadDiag(target.first, target.last, target.axis), None
    if target.axis == ALL_AXES:  # one value per controlled axis, by axis name
        return [read, it.ReadAxisNames()], lambda r: _records(r[0], param_bit, r[1])
    return [read], lambda r: _records(r[0], param_bit)


def _by_number(numbers: Sequence[int], values: Sequence[object], prefix: str) -> object:
    if len(numbers) == 1 and len(values) == 1:
        return values[0]
    return {f"{prefix}{n}": v for n, v in zip(numbers, values, strict=False)}


def _records(records: Sequence[ParamRecord], bit: int | None, axis_names: Sequence[str] = ()) -> object:
    def pick(value: object) -> object:
        return (value >> bit) & 1 if bit is not None and isinstance(value, int) else value

    def one(record: ParamRecord) -> object:
        if record.axis == ALL_AXES and axis_names:  # the controlled axes' slots, by name
            return {name: pick(v) for name, v in zip(axis_names, record.values, strict=False)}
        if len(record.values) > 1 and record.axis == ALL_AXES:  # a per-axis parameter read for every axis
            return [pick(v) for v in record.values]
        return pick(record.value)

    if len(records) == 1:
        return one(records[0])
    return {str(r.number): one(r) for r in records}


@dataclass(frozen=True, slots=True)
class ItemOutcome:
    item: str
    value: object = None
    error: BaseException | None = None
    part_errors: tuple[tuple[str, BaseException], ...] = ()


def _outcome(plan: ReadPlan, results: list[Any]) -> ItemOutcome:
    """One CLI item from its results: refused parts are left out and named; the item fails when an item that
    belongs to no part failed, or when every part was refused."""
    refused = tuple((name, error) for name, indices in plan.parts.items()
                    if (error := _first_error(results[i] for i in indices)) is not None)
    in_parts = {i for indices in plan.parts.values() for i in indices}
    failed = _first_error(r for i, r in enumerate(results) if i not in in_parts)
    if failed is None and plan.parts and len(refused) == len(plan.parts):
        failed = refused[0][1]
    if failed is not None:
        return ItemOutcome(plan.text, error=failed, part_errors=refused)
    shaped = [None if isinstance(r, BaseException) else r for r in results]
    try:
        return ItemOutcome(plan.text, plan.shape(shaped), part_errors=refused)
    except (IndexError, TypeError, ValueError, AttributeError) as exc:
        return ItemOutcome(plan.text, error=FocasError(f"unexpected answer shape: {exc}"))


def _first_error(results: Iterable[Any]) -> BaseException | None:
    return next((r for r in results if isinstance(r, BaseException)), None)


async def read_all(session: Any, plans: Sequence[ReadPlan]) -> list[ItemOutcome]:
    """Connect, read every plan's items in ONE batch, shape the results per CLI item."""
    try:
        async with session as cnc:
            outcomes = await read_batch(cnc, plans)
            retry = [(i, plan.per_axis) for i, (plan, outcome) in enumerate(zip(plans, outcomes, strict=True))
                     if plan.per_axis is not None and refused_as_axis_type(outcome.error)]
            if retry:  # axis-type numbers asked with axis 0: read them for every axis
                again = await read_batch(cnc, [p for _, p in retry if p is not None])
                for (index, _), outcome in zip(retry, again, strict=True):
                    outcomes[index] = outcome
    except FocasError as exc:
        return [ItemOutcome(plan.text, error=exc) for plan in plans]
    return outcomes


async def read_batch(cnc: Any, plans: Sequence[ReadPlan]) -> list[ItemOutcome]:
    """Every plan's items in ONE batch on a connected session, shaped per CLI item."""
    results = await cnc.batch([item for plan in plans for item in plan.items])
    outcomes = []
    position = 0
    for plan in plans:
        mine = results[position : position + len(plan.items)]
        position += len(plan.items)
        outcomes.append(_outcome(plan, mine))
    return outcomes


# ---- output -----------------------------------------------------------------------------------------


def print_json(outcomes: Sequence[ItemOutcome]) -> None:
    for outcome in outcomes:
        print(json.dumps({"item": outcome.item, "value": json_value(outcome.value),
                          "error": error_object(outcome.error) if outcome.error else None,
                          "refused": {part: error_object(error) for part, error in outcome.part_errors}}))


def print_table(outcomes: Sequence[ItemOutcome]) -> None:
    rows: list[tuple[str, str, str]] = []
    for outcome in outcomes:
        if outcome.error is not None:
            rows.append((outcome.item, "", "ERROR " + describe_error(outcome.error)))
            continue
        lines = _flatten(json_value(outcome.value)) if outcome.value not in ({}, None) or not outcome.part_errors \
            else []
        lines += [(part, "REFUSED " + describe_error(error)) for part, error in outcome.part_errors]
        for index, (key, text) in enumerate(lines):
            rows.append((outcome.item if index == 0 else "", key, text))
    widths = [max((len(r[i]) for r in rows), default=0) for i in range(2)]
    for item, key, text in rows:
        print(f"{item:<{widths[0]}}  {key:<{widths[1]}}  {text}".rstrip())


def _flatten(value: object, prefix: str = "") -> list[tuple[str, str]]:
    if isinstance(value, dict) and value:
        lines: list[tuple[str, str]] = []
        for key, inner in value.items():
            lines += _flatten(inner, f"{prefix}.{key}" if prefix else str(key))
        return lines
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        lines = []
        for index, inner in enumerate(value):
            lines += _flatten(inner, f"{prefix}[{index}]")
        return lines
    text = "(vacant)" if value is None else json.dumps(value) if isinstance(value, list | str) else str(value)
    return [(prefix, text)]


# ---- the subcommand ---------------------------------------------------------------------------------------


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "read", help="read items from one CNC",
        description="Read items from one CNC in one batched request. Items: "
                    f"{' '.join(NAMED_READS)} macro:500-505 param:6711 param:1815/1 param:1815/0.3 param:1850/all "
                    "diag:980-981/1 diag:308-309/all "
                    "pmc:D2204.word pmc:R100-R103 pmc:R100.3",
        epilog="A composite (program, loads, positions, timers ...) prints every part the CNC answered and names "
               "each refused part with its return code. Exit codes: 0 every item and part read, 3 every item "
               "answered but some parts were refused, 1 an item or the connection failed whole, 2 bad usage.")
    add_connection_arguments(parser)
    parser.add_argument("items", nargs="+", metavar="ITEM", help="what to read (see above)")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object per item: item, value, error, refused (part -> error)")
    parser.set_defaults(func=run)


def parse_and_open(command: str, args: argparse.Namespace, parse: Callable[[str], T],
                   texts: list[str]) -> tuple[list[T], Any] | int:
    """Every item parsed, then the session opened; a usage problem is printed and EXIT_USAGE returned."""
    try:
        bare, args.path = without_paths(texts, args.path)
        parsed = [parse(text) for text in bare]
        return parsed, open_cnc(args)
    except TargetError as exc:
        print(f"focas-edge {command}: {exc}", file=sys.stderr)
    except ConfigError as exc:
        print(f"focas-edge {command}: {'; '.join(exc.problems)}", file=sys.stderr)
    return EXIT_USAGE


def without_paths(texts: Sequence[str], explicit: int | None) -> tuple[list[str], int | None]:
    """The items without their `@N` (in `TARGET@N` or `TARGET@N=VALUE`) and the one path of the session: a
    command talks to one path, so every `@N` and --path must agree. TargetError names the item that does not."""
    bare: list[str] = []
    path = explicit
    for text in texts:
        target, sep, value = text.partition("=")
        target, named = split_path(target)
        if named is not None and path is not None and named != path:
            where = f"--path {explicit}" if explicit is not None else f"another item names @{path}"
            raise TargetError(f"{text!r}: names path {named} but {where}; one command reads or writes one path")
        path = named if named is not None else path
        bare.append(target + sep + value)
    return bare, path


def run(args: argparse.Namespace) -> int:
    prepared = parse_and_open("read", args, plan_read, args.items)
    if isinstance(prepared, int):
        return prepared
    plans, session = prepared
    outcomes = asyncio.run(read_all(session, plans))
    (print_json if args.json else print_table)(outcomes)
    return report_failures(outcomes)


def report_failures(outcomes: Sequence[ItemOutcome]) -> int:
    """Name every refused part and failed item on stderr; the exit status: 1 when an item failed whole, 3 when
    only parts were refused, 0 when everything was read."""
    for outcome in outcomes:
        if outcome.error is not None:
            print(f"focas-edge read: {outcome.item}: {describe_error(outcome.error)}", file=sys.stderr)
            continue
        for part, error in outcome.part_errors:
            print(f"focas-edge read: {outcome.item}: {part}: {describe_error(error)} (left out)", file=sys.stderr)
    if any(o.error is not None for o in outcomes):
        return EXIT_FAILURE
    return EXIT_PARTIAL if any(o.part_errors for o in outcomes) else EXIT_OK
