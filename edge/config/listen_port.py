"""Can a server of the daemon (the status endpoint `http:`, the OPC UA server `opcua:`) listen where the config
says? One wording for `run` and `check-config`.

A port already taken used to surface as a 38-line asyncio traceback and a restart loop. `run` turns the
bind error into one line (exit 2); `check-config` binds the same addresses for a moment to say it first.
`section` names the config section whose host/port the line is about.
"""

from __future__ import annotations

import contextlib
import errno
import socket
from pathlib import Path

UNPRIVILEGED_PORT_START = Path("/proc/sys/net/ipv4/ip_unprivileged_port_start")


def bind_problem(host: str, port: int, error: OSError, section: str = "http") -> str:
    """The one line for a server that cannot listen on host:port."""
    if isinstance(error, socket.gaierror):
        return f"{section}.host: cannot resolve {host!r} ({error.strerror})"
    if error.errno == errno.EADDRINUSE:
        return (f"{section}.port: {host}:{port} is already in use by another program (another focas-edge? "
                f"`ss -ltnp 'sport = :{port}'` names it): stop it or choose another {section}.port")
    if error.errno == errno.EACCES:
        return (f"{section}.port: {port} is a privileged port and this user may not listen on it: choose one "
                f"from {unprivileged_port_start()} up")
    if error.errno == errno.EADDRNOTAVAIL:
        return f"{section}.host: {host} is not an address of this machine"
    return f"{section}.port: cannot listen on {host}:{port} ({error.strerror or error})"


def probe(host: str, port: int, section: str = "http") -> str | None:
    """Bind every address `host` resolves to, as the daemon's server does (SO_REUSEADDR), and let go."""
    sockets: list[socket.socket] = []
    try:
        for family, kind, proto, _, address in socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM,
                                                                  flags=socket.AI_PASSIVE):
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
    except OSError as exc:
        return bind_problem(host, port, exc, section)
    finally:
        for sock in sockets:
            sock.close()
    return None


def unprivileged_port_start() -> int:
    """The lowest port a process without CAP_NET_BIND_SERVICE may listen on (Linux: usually 1024)."""
    with contextlib.suppress(OSError, ValueError):
        return int(UNPRIVILEGED_PORT_START.read_text())
    return 1024


def service_port_problem(port: int, section: str = "http") -> str | None:
    """The unit drops every capability (CapabilityBoundingSet=), so a port root can bind may be refused to it."""
    start = unprivileged_port_start()
    if port < start:
        return (f"{section}.port: {port} is below {start}, and the service runs without capabilities "
                f"(CapabilityBoundingSet=): choose one from {start} up")
    return None
