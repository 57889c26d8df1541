"""The server side of the packed surface's framing: one asyncio listener, any responder behind it.

Both servers of the surface sit on this: the simulator (edge.sim.packed_server, a MachineState behind it)
and the FOCAS library host (edge.fwlib, FANUC's library behind it). The endpoint reads frames, awaits the
responder for each in arrival order (the surface answers in order, so a client may pipeline) and writes
the answer with the request's command and seq echoed. A malformed frame ends that connection only.

Both responders answer a refused request the same way (error_status, error_answer): the CNC's EW_* code,
except EW_PASSWD, which this surface sends as 11 (seed 002, docs/packed-protocol.md §3.5); EW_ATTRIB for a
PMC area the surface does not define; EW_LENGTH for a payload that does not parse.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import stat
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from edge.focas import packed as pk
from edge.focas.errors import EW_ATTRIB, EW_LENGTH, EW_PASSWD, CncError, ProtocolError
from edge.focas.packed.frame import FrameDecoder, PackedFrame

log = logging.getLogger(__name__)

# (command id, request payload) -> response payload; never raises for a CNC-side failure (answers a status).
Responder = Callable[[int, bytes], Awaitable[bytes]]
_READ_CHUNK = 65536
# Requests an endpoint remembers (newest last) for tests and probes to observe. Bounded: the library host
# serves for months, and an unbounded log grows with every request.
REQUEST_LOG = 4096


def error_status(error: CncError | ProtocolError) -> int:
    """The status a server answers for a request its responder refused with `error`."""
    if isinstance(error, CncError):
        return pk.PACKED_EW_PASSWD if error.code == EW_PASSWD else error.code
    if isinstance(error, pk.PmcCodeError):
        return EW_ATTRIB
    return EW_LENGTH


def error_answer(command: int, status: int) -> bytes:
    """The response payload carrying a failure: ODBALMHIS's negative num_alm (encode_alarm_history_error),
    else a lone i16 status."""
    if command == pk.Command.RDALMHISTRY:
        return pk.encode_alarm_history_error(status)
    return pk.encode_status(status)


@dataclass(frozen=True, slots=True)
class PackedRequest:
    """One request as the server saw it (tests observe chunking and counts here)."""

    command: int
    payload: bytes


@dataclass(eq=False)
class PackedEndpoint:
    """A listening packed-surface server; `address` is what PackedClient takes."""

    server: asyncio.Server
    respond: Responder
    name: str = ""
    host: str = ""
    port: int = 0
    unix_path: str = ""
    requests: deque[PackedRequest] = field(default_factory=lambda: deque(maxlen=REQUEST_LOG))
    _sessions: dict[asyncio.Task[None], asyncio.StreamWriter] = field(default_factory=dict)

    @property
    def address(self) -> str:
        if self.unix_path:
            return f"unix:{self.unix_path}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp:{host}:{self.port}"

    @property
    def connections(self) -> int:
        """Client connections now open."""
        return len(self._sessions)

    def requests_for(self, command: int) -> list[PackedRequest]:
        return [r for r in self.requests if r.command == command]

    async def close(self) -> None:
        """Stop listening and end every open session (the server does not wait for clients to hang up)."""
        self.server.close()
        for writer in self._sessions.values():
            writer.close()  # the session's read then ends and its task returns
        await asyncio.gather(*self._sessions, return_exceptions=True)
        await self.server.wait_closed()
        if self.unix_path:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.unix_path)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._sessions[task] = writer
        try:
            await self._session(reader, writer)
        finally:
            self._sessions.pop(task, None)

    async def _session(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername") or self.address
        decoder = FrameDecoder()
        try:
            while data := await reader.read(_READ_CHUNK):
                for frame in decoder.feed(data):
                    self.requests.append(PackedRequest(frame.command, frame.payload))
                    reply = await self.respond(frame.command, frame.payload)
                    writer.write(PackedFrame(frame.command, frame.seq, reply).encode())
                await writer.drain()
        except ProtocolError as exc:
            log.warning("packed client sent a malformed frame peer=%s machine=%s error=%s",
                        peer, self.name, exc)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()


async def start_packed_endpoint(
    respond: Responder,
    host: str = "127.0.0.1",
    port: int = 0,
    *,
    unix_path: str | None = None,
    unix_mode: int | None = None,
    name: str = "",
) -> PackedEndpoint:
    """Serve `respond` on host:port (port 0 = any free port) or, given unix_path, on that Unix socket.

    unix_mode (e.g. 0o660) is applied to the socket file before the first client can be accepted, so a
    library host can restrict who may connect to the daemon's user or group.
    """
    handle: PackedEndpoint
    if unix_path:
        with contextlib.suppress(FileNotFoundError):
            if stat.S_ISSOCK(os.stat(unix_path).st_mode):
                os.unlink(unix_path)
        old_umask = os.umask(0o777 ^ unix_mode) if unix_mode is not None else None
        try:
            server = await asyncio.start_unix_server(lambda r, w: handle._serve(r, w), path=unix_path)
        finally:
            if old_umask is not None:
                os.umask(old_umask)
        if unix_mode is not None:
            os.chmod(unix_path, unix_mode)
        handle = PackedEndpoint(server, respond, name=name, unix_path=unix_path)
    else:
        server = await asyncio.start_server(lambda r, w: handle._serve(r, w), host, port)
        bound = server.sockets[0].getsockname()
        handle = PackedEndpoint(server, respond, name=name, host=host, port=int(bound[1]))
    log.info("packed surface serving machine=%s address=%s", name, handle.address)
    return handle
