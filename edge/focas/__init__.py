"""The FOCAS protocol: sans-IO codecs for both wire formats and, on top of them, the asyncio clients.

What lives here, bottom up:

    errors      the one exception tree (FocasError; CncError keeps the EW_* code and the function)
    model       the typed values every transport returns (plain frozen dataclasses, no bytes)
    items       the transport-neutral read requests of ``batch()``
    targets     "macro:500"-style addresses for reads and writes
    frame       native FOCAS/Ethernet framing: header, subpackets, incremental stream decoder
    values      native payload values: 8-byte scaled numbers, PMC elements, parameter records
    function_entry  what one entry of that table is: Function (codecs of both directions), Context, Evidence
    functions   the native function table, shared by the client and the simulated CNC
    native      read items -> native subpackets, answers -> values
    packed      the packed-buffer surface (seeds 000-002): its codecs, and its framing, client and endpoint
    deadline    request deadlines on a shared wheel
    session     CncSession, the one API over both transports (batching, write rules, reconnect)
    client      FocasClient, the native transport's session
    routed      one machine over both transports (native first, the FOCAS library host for the rest)
    connect     open_session(transport, address): a session from strings
    paths       how many paths a control has
    probe       what a CNC answers, and how fast

Rules:

1. focas imports nothing else from edge/ except the root ``edge.ConfigError`` (address parsing).
2. The sans-IO modules (errors, model, items, targets, frame, values, function_entry, functions, native, paths, the
   packed codecs and packed.frame) never import asyncio or sockets, nor a module that does; the simulator
   builds on them and never on the client modules.
3. The client modules (deadline, session, client, routed, connect, probe, packed.client, packed.endpoint)
   sit on top of the codecs; nothing here imports them eagerly, so this ``__init__`` only names the
   public submodules (import each by its path) and the root of the exception tree.
"""

from __future__ import annotations

from edge.focas.errors import CncError, FocasError, ProtocolError

__all__ = [
    "CncError",
    "FocasError",
    "ProtocolError",
    "client",
    "connect",
    "deadline",
    "errors",
    "frame",
    "functions",
    "items",
    "model",
    "native",
    "packed",
    "paths",
    "probe",
    "routed",
    "session",
    "targets",
    "values",
]
