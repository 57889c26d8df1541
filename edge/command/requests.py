"""The JSON write request and the validated write it becomes, checked before anything reaches a CNC.

    {"id": "42", "target": "pmc:R100.3", "value": true}          one write
    {"target": "macro:500@2", "value": 1.5}                      on path 2 (or "path": 2; both must agree)
    [{"id": "a", "target": "macro:500", "value": 1.25}, {...}]   several, applied in order

`WriteRequest` (pydantic) checks the shape, the target grammar (edge.focas.targets, shared with the CLI and the
allow-list) and that the value fits the target's type and width; it yields a `WriteOp`, the plain value
the executor carries out. Every refusal has a reply code (edge.command.errors) as its pydantic error type.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass, replace
from typing import Any

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictInt,
    StrictStr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from edge.command.errors import CommandRefused, ErrorCode
from edge.command.signedness import PMC_READINGS
from edge.focas.model import PmcType
from edge.focas.targets import (
    MAX_PATH,
    MacroTarget,
    ParamTarget,
    PmcTarget,
    TargetError,
    WritableTarget,
    parse_writable,
    split_path,
)

I32 = (-(2**31), 2**31 - 1)
FLOAT32_MAX = 3.4028234663852886e38
MAX_WRITES_PER_REQUEST = 64
# A request is at most three levels deep (list > object > list value); deeper is refused before parsing,
# so no document can drive the JSON parser into RecursionError (~1000 levels).
MAX_JSON_DEPTH = 16

WriteValue = float | bool | int | tuple[int | float, ...]


@dataclass(frozen=True, slots=True)
class WriteOp:
    """One validated write. `value`: float (macro), bool (any bit), int|float (parameter), or a tuple of
    elements (PMC, one per data_type element of the range). `bounded`: the allow rule that accepted it has
    a min/max, so a value only fitting the other signed/unsigned reading is refused (edge.command.signedness)."""

    target: WritableTarget
    value: WriteValue
    bounded: bool = False
    path: int | None = None  # the CNC path named by the request (`@2`, "path": 2); None: the device's own

    @property
    def text(self) -> str:
        return str(self.target) if self.path is None else f"{self.target}@{self.path}"

    def reply_value(self) -> object:
        """The requested value as a reply or audit line shows it."""
        if isinstance(self.value, tuple):
            return self.value[0] if len(self.value) == 1 else list(self.value)
        return self.value


def _wrong(message: str) -> PydanticCustomError:
    return PydanticCustomError(ErrorCode.WRONG_TYPE.value, message)


def _number(what: str, raw: object) -> int | float:
    """A finite number that converts to a float (bounds and policies compare floats; a 400-digit integer
    would raise OverflowError there, far from the request that carried it)."""
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        raise _wrong(f"{what}: expected a number, got {_shown(raw)}")
    if isinstance(raw, float) and not math.isfinite(raw):
        raise _wrong(f"{what}: expected a finite number, got {raw}")
    if isinstance(raw, int):
        try:
            float(raw)
        except OverflowError:
            raise _wrong(f"{what}: an integer of {len(str(abs(raw)))} digits is larger than any number a CNC "
                         "holds") from None
    return raw


def _shown(raw: object, limit: int = 80) -> str:
    """A value as a refusal quotes it, cut short (the message goes to the reply and the audit line)."""
    text = json.dumps(raw, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _integer(what: str, raw: object) -> int:
    value = _number(what, raw)
    if isinstance(value, float):
        if not value.is_integer():
            raise _wrong(f"{what}: expected an integer, got {value}")
        return int(value)
    return value


def _bit(what: str, raw: object) -> bool:
    if isinstance(raw, bool):
        return raw
    if isinstance(raw, int | float) and raw in (0, 1):
        return bool(raw)
    raise _wrong(f"{what}: a bit takes true/false or 0/1, got {_shown(raw)}")


def macro_value(target: MacroTarget, raw: object) -> float:
    """A macro takes one finite number whose integer part fits the 32-bit scaled form."""
    what = str(target)
    if target.count != 1:
        raise _wrong(f"{what}: write one macro at a time")
    value = float(_number(what, raw))
    if not I32[0] <= value <= I32[1]:
        raise _wrong(f"{what}: {value} does not fit a macro's 32-bit scaled value "
                     f"(|value| up to {I32[1]}; decimals beyond 32 bits are rounded)")
    return value


def pmc_elements(target: PmcTarget, raw: object) -> tuple[int | float, ...]:
    """One element per data_type element of the range: a scalar for one, a list of exactly count."""
    what = str(target)
    parts = raw if isinstance(raw, list) else [raw]
    if len(parts) != target.count:
        raise _wrong(f"{what}: holds {target.count} {target.data_type.name.lower()} element(s), "
                     f"got {len(parts)} value(s)")
    kind = target.data_type
    out: list[int | float] = []
    for index, part in enumerate(parts):
        where = f"{what} element {index}" if len(parts) > 1 else what
        if kind in (PmcType.FLOAT, PmcType.DOUBLE):
            number = float(_number(where, part))
            if kind is PmcType.FLOAT and abs(number) > FLOAT32_MAX:
                raise _wrong(f"{where}: {number} does not fit a 32-bit float")
            out.append(number)
            continue
        integer = _integer(where, part)
        low, high = PMC_READINGS[kind].accepted  # either reading: 0xFF and -1 are the same byte
        if not low <= integer <= high:
            raise _wrong(f"{where}: {integer} does not fit a {kind.name.lower()} ({kind.width * 8} bits, "
                         f"{low}..{high})")
        out.append(integer)
    return tuple(out)


def pmc_bytes(target: PmcTarget, elements: tuple[int | float, ...]) -> bytes:
    """Elements big-endian, the byte order the PMC read answers in (what you write is what you read)."""
    kind = target.data_type
    if kind is PmcType.FLOAT:
        return struct.pack(f">{len(elements)}f", *elements)
    if kind is PmcType.DOUBLE:
        return struct.pack(f">{len(elements)}d", *elements)
    width = kind.width
    mask = (1 << (8 * width)) - 1
    return b"".join((int(e) & mask).to_bytes(width, "big") for e in elements)


def param_value(target: ParamTarget, raw: object) -> int | float:
    """A whole parameter: a number; whether it fits is checked against the type the CNC reports."""
    if target.last != target.first:
        raise _wrong(f"{target}: write one parameter at a time")
    return _number(str(target), raw)


def make_op(target: WritableTarget, raw: object) -> WriteOp:
    """The validated write of `raw` to `target`; PydanticCustomError(wrong_type) if it does not fit."""
    if isinstance(target, MacroTarget):
        return WriteOp(target, macro_value(target, raw))
    if isinstance(target, PmcTarget):
        if target.bit is not None:
            return WriteOp(target, _bit(str(target), raw))
        return WriteOp(target, pmc_elements(target, raw))
    if target.bit is not None:
        if target.last != target.first:
            raise _wrong(f"{target}: a bit addresses one parameter")
        return WriteOp(target, _bit(str(target), raw))
    return WriteOp(target, param_value(target, raw))


class WriteRequest(BaseModel):
    """One write as it arrives on `<prefix>/<machine>/cmd`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: StrictStr | StrictInt | None = None
    target: str = Field(max_length=64)
    value: Any  # checked against the target by make_op, which names what was expected
    client: str | None = Field(default=None, max_length=128)  # self-declared, for the audit log
    path: StrictInt | None = Field(default=None, ge=1, le=MAX_PATH)  # the CNC path; `@N` in target says the same

    @field_validator("target")
    @classmethod
    def _grammar(cls, text: str) -> str:
        try:
            parse_writable(split_path(text)[0])
        except TargetError as exc:
            raise PydanticCustomError(ErrorCode.INVALID_TARGET.value, str(exc)) from None
        return text

    @model_validator(mode="after")
    def _fits(self) -> WriteRequest:
        self.op()
        return self

    def op(self) -> WriteOp:
        text, suffix = split_path(self.target)
        if suffix is not None and self.path is not None and suffix != self.path:
            raise PydanticCustomError(ErrorCode.MALFORMED.value, f"target {self.target!r} names path {suffix} "
                                      f"but path is {self.path}; name the path once, or the same in both")
        path = suffix if suffix is not None else self.path
        return replace(make_op(parse_writable(text), self.value), path=path)


@dataclass(frozen=True, slots=True)
class RequestItem:
    """One element of a request: its validated write, or why it was refused; id/client as sent."""

    index: int
    id: object
    client: str | None
    op: WriteOp | None
    target_text: str | None
    requested: object
    refused: CommandRefused | None = None


@dataclass(frozen=True, slots=True)
class ParsedRequest:
    """The items of a request; `refused`: the request as a whole is refused (too many writes), each item
    answered with that refusal under its own id."""

    items: tuple[RequestItem, ...]
    is_list: bool
    refused: CommandRefused | None = None


def parse_request(payload: bytes, max_bytes: int) -> ParsedRequest:
    """Bytes from the cmd topic -> items; a request that cannot be read at all raises CommandRefused."""
    if len(payload) > max_bytes:
        raise CommandRefused(ErrorCode.PAYLOAD_TOO_LARGE,
                             f"request is {len(payload)} bytes; at most {max_bytes} are accepted")
    try:
        text = payload.decode("utf-8")
        check_depth(text)
        document = json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, UnicodeDecodeError, a >4300-digit integer
        raise CommandRefused(ErrorCode.MALFORMED, f"expected a UTF-8 JSON object or list: {exc}") from None
    is_list = isinstance(document, list)
    elements = document if is_list else [document]
    if not elements:
        raise CommandRefused(ErrorCode.MALFORMED, "expected at least one write, got an empty list")
    if len(elements) > MAX_WRITES_PER_REQUEST:
        refusal = CommandRefused(ErrorCode.MALFORMED, f"{len(elements)} writes in one request; at most "
                                 f"{MAX_WRITES_PER_REQUEST}; nothing was written")
        return ParsedRequest(tuple(unread_item(i, e, refusal) for i, e in enumerate(elements)), is_list, refusal)
    return ParsedRequest(tuple(parse_item(i, e) for i, e in enumerate(elements)), is_list)


def check_depth(text: str) -> None:
    """CommandRefused(malformed) if arrays/objects nest deeper than MAX_JSON_DEPTH (strings skipped)."""
    depth = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            if depth > MAX_JSON_DEPTH:
                raise CommandRefused(ErrorCode.MALFORMED, f"JSON nested deeper than {MAX_JSON_DEPTH} levels; "
                                     "a request is an object or a list of objects")
        elif char in "]}":
            depth -= 1


def parse_item(index: int, element: object) -> RequestItem:
    """One element of a request, validated; a refusal is kept with the id it carried."""
    if not isinstance(element, dict):
        refused = CommandRefused(ErrorCode.MALFORMED,
                                 f"write {index}: expected an object with target and value, got "
                                 f"{type(element).__name__}")
        return RequestItem(index, None, None, None, None, None, refused)
    try:
        request = WriteRequest.model_validate(element)
    except ValidationError as exc:
        return unread_item(index, element, _refusal(index, exc))
    except (ArithmeticError, ValueError, TypeError, RecursionError) as exc:  # a check that itself failed
        return unread_item(index, element, CommandRefused(
            ErrorCode.WRONG_TYPE, f"write {index}: value could not be checked ({type(exc).__name__}: {exc})"))
    return RequestItem(index, request.id, request.client, request.op(), request.target, request.value)


def unread_item(index: int, element: object, refusal: CommandRefused) -> RequestItem:
    """A refused element, keeping what identifies it in the reply and the audit line (id, client, target)."""
    fields: dict[str, Any] = element if isinstance(element, dict) else {}
    request_id = fields.get("id") if isinstance(fields.get("id"), str | int) else None
    client = fields.get("client") if isinstance(fields.get("client"), str) else None
    target_text = fields.get("target") if isinstance(fields.get("target"), str) else None
    return RequestItem(index, request_id, client, None, target_text, fields.get("value"), refusal)


_CODES = {code.value: code for code in ErrorCode}


def _refusal(index: int, exc: ValidationError) -> CommandRefused:
    """The first error decides the code; schema problems (missing, unknown key, not a scalar) are malformed."""
    error = exc.errors()[0]
    code = _CODES.get(error["type"], ErrorCode.MALFORMED)
    loc = ".".join(str(part) for part in error["loc"])
    message = str(error["msg"])
    if error["type"] == "extra_forbidden":
        message = "unknown key (expected id, target, value, client, path)"
    elif error["type"] == "missing":
        message = "required"
    return CommandRefused(code, f"write {index}" + (f" {loc}" if loc else "") + f": {message}")
