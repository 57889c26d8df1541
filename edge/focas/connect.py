"""Open a CNC session by transport name and address string, so callers never branch on the transport.

Addresses: ``host``, ``host:port``, ``tcp:host:port``, ``[v6addr]:port`` for both transports, and
``unix:/path/to.sock`` for the packed transport only.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from edge import ConfigError
from edge.focas.client import DEFAULT_PORT, FocasClient
from edge.focas.session import CncSession

TRANSPORTS = ("focas", "packed")
LIBRARY_TIMEOUT_SHARE = 0.75  # of the machine's request timeout, for a library host beside a native session


@dataclass(frozen=True, slots=True)
class Address:
    """A parsed CNC address: TCP host and port, or a Unix socket path."""

    host: str = ""
    port: int = DEFAULT_PORT
    unix_path: str = ""

    @property
    def is_unix(self) -> bool:
        return bool(self.unix_path)


def parse_address(address: str, default_port: int = DEFAULT_PORT) -> Address:
    text = address.strip()
    if text.startswith("unix:"):
        path = text[len("unix:") :]
        if not path:
            raise ConfigError([f"address {address!r}: unix: needs a socket path"])
        return Address(unix_path=path)
    if text.startswith("tcp:"):
        text = text[len("tcp:") :]
    host, port_text = text, ""
    if text.startswith("["):  # [v6]:port
        close = text.find("]")
        if close < 0:
            raise ConfigError([f"address {address!r}: missing ']' after the IPv6 host"])
        host, rest = text[1:close], text[close + 1 :]
        port_text = rest[1:] if rest.startswith(":") else rest
    elif text.count(":") == 1:
        host, port_text = text.split(":")
    if not host:
        raise ConfigError([f"address {address!r}: expected host, host:port, tcp:host:port or unix:/path"])
    port = default_port
    if port_text:
        if not port_text.isdigit() or not 0 < int(port_text) < 65536:
            raise ConfigError([f"address {address!r}: port must be 1..65535, got {port_text!r}"])
        port = int(port_text)
    return Address(host=host, port=port)


def open_session(transport: str, address: str, *, fwlib_host: str | None = None, **kw: Any) -> CncSession:
    """An unconnected session; use it as `async with open_session("focas", "10.0.0.5:8193") as cnc:`.

    With fwlib_host (a native machine that also has a FOCAS library host), a RoutedSession: each function
    goes to the transport that has it, native first.
    """
    if fwlib_host is not None:
        if transport != "focas":
            raise ConfigError([f"fwlib_host {fwlib_host!r}: only beside transport focas (native)"])
        from edge.focas.routed import RoutedSession

        common = {k: v for k, v in kw.items() if k not in ("max_subpackets", "path")}  # timeouts and backoff
        # The library host's requests time out first, so its own session resets cleanly (its items fail)
        # before the routed session's timeout could reset the native connection too.
        library = {**common, "timeout": LIBRARY_TIMEOUT_SHARE * float(common.get("timeout", 5.0))}
        return RoutedSession(open_session("focas", address, **kw), open_session("packed", fwlib_host, **library),
                             **common)
    if transport == "focas":
        parsed = parse_address(address)
        if parsed.is_unix:
            raise ConfigError([f"address {address!r}: the focas transport speaks TCP only"])
        return FocasClient(parsed.host, parsed.port, **kw)
    if transport == "packed":
        module = importlib.import_module("edge.focas.packed.client")
        packed_client: Any = module.PackedClient
        session: CncSession = packed_client(address, **kw)
        return session
    raise ConfigError([f"transport {transport!r}: expected one of {', '.join(TRANSPORTS)}"])
