"""edge/focas/__init__.py rule 2: the sans-IO modules never import asyncio or sockets, nor a module that does.

Checked at run time in a fresh interpreter, so an import anywhere down the chain counts (a codec importing
a helper that imports the session would pass an AST check of the codec alone).
"""

from __future__ import annotations

import json
import subprocess
import sys

SANS_IO = [
    "edge.focas",
    "edge.focas.errors",
    "edge.focas.model",
    "edge.focas.items",
    "edge.focas.targets",
    "edge.focas.frame",
    "edge.focas.values",
    "edge.focas.functions",
    "edge.focas.native",
    "edge.focas.paths",
    "edge.focas.packed",
    "edge.focas.packed.frame",
]
FORBIDDEN_ROOTS = {"asyncio", "socket", "selectors", "ssl"}
CLIENT_SIDE = {"deadline", "session", "client", "routed", "connect", "probe", "packed.client", "packed.endpoint"}

# Imports each module in turn and reports, per module, what it newly brought into sys.modules.
_PROBE = """
import importlib, json, sys
report = {}
for name in sys.argv[1:]:
    before = set(sys.modules)
    importlib.import_module(name)
    report[name] = sorted(set(sys.modules) - before)
print(json.dumps(report))
"""


def test_sans_io_modules_pull_in_no_asyncio_socket_or_client_module() -> None:
    done = subprocess.run([sys.executable, "-c", _PROBE, *SANS_IO], capture_output=True, text=True, timeout=60,
                          check=True)
    report: dict[str, list[str]] = json.loads(done.stdout)
    forbidden = FORBIDDEN_ROOTS | {f"edge.focas.{name}" for name in CLIENT_SIDE}
    offenders = {
        module: [m for m in loaded if m.split(".")[0] in FORBIDDEN_ROOTS or m in forbidden
                 or (m.startswith("edge.") and not m.startswith("edge.focas"))]
        for module, loaded in report.items()
    }
    found = {module: bad for module, bad in offenders.items() if bad}
    assert found == {}, "first imported by -> what it pulled in: " + json.dumps(found)
