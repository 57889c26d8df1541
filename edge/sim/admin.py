"""A small HTTP/JSON control endpoint for a running fleet, for tools in another process (stdlib only).

    GET  /machines                 every machine: ports, request counters, faults, state summary
    GET  /machines/<i>             one machine
    GET  /machines/<i>/writes      its write log
    POST /machines/<i>/faults      {"latency": 0.5, "hang": 1, "refuse": 2, "drop_after": 3, "garbage": 1,
                                    "ew": {"read_macros": 6}, "max_sessions": 1, "drop_now": true,
                                    "clear": true}
    POST /machines/<i>/state       {"macros": {"500": 1.5}, "params": {"6711": 0, "1815/1": 48},
                                    "pmc": {"R100": [1, 2]}, "param_write_enable": true,
                                    "clock_offset": 3600, "timezone": "Europe/Berlin",
                                    "raise_alarm": {"number": 1004, "type": 15, "axis": 0, "message": "..."},
                                    "clear_alarms": true, "emergency": false, "feed_hold": true}

Every answer is JSON; errors are {"error": "..."} with 400 (bad request) or 404 (no such machine/path).
Runs on the fleet's event loop: state and faults change between requests, never during one.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import re
from collections.abc import Callable
from typing import Any

from edge.focas.errors import CncError
from edge.sim.fleet import Fleet, Machine
from edge.sim.state_alarms import ALARM_TYPES

log = logging.getLogger(__name__)

MAX_BODY = 1 << 20
PROTOCOL = "admin"
_REASONS = {200: "OK", 400: "Bad Request", 404: "Not Found", 405: "Method Not Allowed", 413: "Too Large"}


class HttpError(Exception):
    def __init__(self, status: int, message: str) -> None:
        self.status = status
        super().__init__(message)


class AdminServer:
    """`await AdminServer(fleet, port=8190).start()`; port 0 picks a free one."""

    def __init__(self, fleet: Fleet, host: str = "127.0.0.1", port: int = 0) -> None:
        self.fleet = fleet
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    async def start(self) -> int:
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
        self.port = int(self._server.sockets[0].getsockname()[1])
        log.info("sim admin endpoint url=%s", self.url)
        return self.port

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None

    async def __aenter__(self) -> AdminServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    # ---- HTTP --------------------------------------------------------------------------------------
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            status, body = await self._respond(reader)
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
            writer.close()
            return
        data = json.dumps(body, default=str).encode()
        head = (f"HTTP/1.1 {status} {_REASONS.get(status, 'Error')}\r\nContent-Type: application/json\r\n"
                f"Content-Length: {len(data)}\r\nConnection: close\r\n\r\n")
        writer.write(head.encode() + data)
        with contextlib.suppress(ConnectionError):
            await writer.drain()
        writer.close()

    async def _respond(self, reader: asyncio.StreamReader) -> tuple[int, Any]:
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 10)
        lines = head.decode("latin-1").split("\r\n")
        parts = lines[0].split()
        if len(parts) < 2:
            return 400, {"error": f"malformed request line {lines[0]!r}"}
        method, path = parts[0].upper(), parts[1].split("?")[0].rstrip("/")
        fields = (line.partition(":") for line in lines[1:] if line)
        headers = {name.strip().lower(): value.strip() for name, _, value in fields}
        length = int(headers.get("content-length", "0") or 0)
        if length > MAX_BODY:
            return 413, {"error": f"body of {length} bytes; at most {MAX_BODY}"}
        raw = await asyncio.wait_for(reader.readexactly(length), 10) if length else b""
        try:
            payload = json.loads(raw) if raw else {}
            return 200, self.handle(method, path, payload)
        except HttpError as exc:
            return exc.status, {"error": str(exc)}
        except json.JSONDecodeError as exc:
            return 400, {"error": f"body is not JSON: {exc}"}
        except (CncError, ValueError, TypeError, KeyError) as exc:
            return 400, {"error": f"{type(exc).__name__}: {exc}"}

    # ---- routes (also callable directly) -----------------------------------------------------------
    def handle(self, method: str, path: str, payload: Any) -> Any:
        """Dispatch one request; raises HttpError for unknown paths or methods."""
        if path == "/machines":
            _expect(method, "GET")
            return [m.describe() for m in self.fleet]
        match = re.fullmatch(r"/machines/(\d+)(?:/(faults|state|writes))?", path)
        if not match:
            raise HttpError(404, f"no route {path!r}; see GET /machines")
        machine = self._machine(int(match.group(1)))
        action = match.group(2)
        if action is None:
            _expect(method, "GET")
            return machine.describe()
        if action == "writes":
            _expect(method, "GET")
            return [w._asdict() | {"old": _jsonable(w.old), "new": _jsonable(w.new)}
                    for w in machine.state.writes()]
        _expect(method, "POST")
        if not isinstance(payload, dict):
            raise HttpError(400, f"expected a JSON object, got {type(payload).__name__}")
        if action == "faults":
            return apply_faults(machine, payload)
        return apply_state(machine, payload)

    def _machine(self, index: int) -> Machine:
        if not 0 <= index < len(self.fleet):
            raise HttpError(404, f"no machine {index}; the fleet has 0..{len(self.fleet) - 1}")
        return self.fleet[index]


def _expect(method: str, allowed: str) -> None:
    if method != allowed:
        raise HttpError(405, f"{method} not allowed here; use {allowed}")


def _jsonable(value: object) -> object:
    return value.hex() if isinstance(value, bytes) else value


def apply_faults(machine: Machine, changes: dict[str, Any]) -> dict[str, Any]:
    """Set faults on one machine (also used by the scenario loader and tests)."""
    changes = dict(changes)
    if changes.pop("clear", False):
        machine.faults.clear()
    drop_now = bool(changes.pop("drop_now", False))
    machine.faults.update(changes)
    dropped = machine.drop_connections() if drop_now else 0
    return {"faults": machine.faults.describe(), "dropped": dropped}


def _pmc_address(text: str) -> tuple[str, int]:
    match = re.fullmatch(r"([A-Za-z])(\d+)", text.strip())
    if not match:
        raise ValueError(f"PMC address {text!r}: expected a letter and a number, e.g. R100")
    return match.group(1).upper(), int(match.group(2))


def _param_target(text: str) -> tuple[int, int]:
    number, _, axis = str(text).partition("/")
    return int(number), int(axis) if axis else 0


def _set_macros(machine: Machine, values: dict[str, Any]) -> None:
    for number, value in values.items():
        machine.state.write_macro(int(number), None if value is None else float(value), PROTOCOL)


def _set_params(machine: Machine, values: dict[str, Any]) -> None:
    for target, value in values.items():
        number, axis = _param_target(target)
        machine.state.set_param(number, axis, value, PROTOCOL)


def _set_pmc(machine: Machine, values: dict[str, Any]) -> None:
    for address, data in values.items():
        area, start = _pmc_address(address)
        raw = bytes.fromhex(data) if isinstance(data, str) else bytes(data)
        machine.state.write_pmc(area, start, raw, PROTOCOL)


_STATE_ACTIONS: dict[str, Callable[[Machine, Any], None]] = {
    "param_write_enable": lambda m, v: m.state.set_param_write_enable(bool(v)),
    "clock_offset": lambda m, v: setattr(m.state, "clock_offset", float(v)),
    "timezone": lambda m, v: setattr(m.state, "timezone", str(v)),
    "emergency": lambda m, v: m.state.set_emergency(bool(v)),
    "feed_hold": lambda m, v: m.state.set_feed_hold(bool(v)),
    "macros": lambda m, v: _set_macros(m, dict(v)),
    "params": lambda m, v: _set_params(m, dict(v)),
    "pmc": lambda m, v: _set_pmc(m, dict(v)),
    "raise_alarm": lambda m, v: _raise_alarm(m, dict(v)),
    "clear_alarms": lambda m, v: m.state.clear_alarms(None if v is True else int(v)),
}


def _raise_alarm(machine: Machine, spec: dict[str, Any]) -> None:
    atype = spec.get("type", ALARM_TYPES["EX"])
    if isinstance(atype, str):
        atype = ALARM_TYPES[atype.upper()]
    machine.state.raise_alarm(int(spec["number"]), int(atype), int(spec.get("axis", 0)),
                              str(spec.get("message", "")))


def apply_state(machine: Machine, changes: dict[str, Any]) -> dict[str, Any]:
    """Change one machine's state: macros, params, PMC bytes, switches, clock, alarms."""
    unknown = sorted(set(changes) - set(_STATE_ACTIONS))
    if unknown:
        raise ValueError(f"unknown state key(s) {unknown}; expected some of {sorted(_STATE_ACTIONS)}")
    for key, value in changes.items():
        _STATE_ACTIONS[key](machine, value)
    return machine.describe()
