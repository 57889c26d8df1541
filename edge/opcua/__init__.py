"""The optional OPC UA server (`opcua:` in the config, the `focas-edge[opcua]` extra built on asyncua).

It knows samples and metric specs (edge.samples), never FOCAS; writes reach the command layer through a
callable the service layer hands it. asyncua is imported only by the modules that serve (output, server,
address_space, alarms, security, values, nodes), and those only when `opcua.enabled`: `layout`, `writes`
and `settings` are pure, and `missing_extra()` tells check-config whether the extra is installed.

Rules:
  1. This package imports only the standard library, asyncua (and its cryptography), edge.samples,
     edge.statefile and its own modules. Never focas, config, collect, publish, command, service or cli:
     the service layer builds its OpcUaSettings and hands it a MetricWriter (edge/service/opcua_output.py).
  2. Every network wait has a timeout (start, stop, a write's outcome); every task it starts is its own to
     cancel (the mailbox drain, the server thread).
"""

from __future__ import annotations

import importlib.util

EXTRA_HINT = "pip install 'focas-edge[opcua]' (or: pip install 'asyncua>=2.1,<2.2')"


def missing_extra() -> str | None:
    """Why the server cannot run here (asyncua not installed), or None when it can."""
    if importlib.util.find_spec("asyncua") is None:
        return f"the OPC UA server needs the asyncua package, which is not installed: {EXTRA_HINT}"
    return None
