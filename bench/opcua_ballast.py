"""The daemon with the latency probes and an inert heap the size of the OPC UA server's address space:
`python -m bench.opcua_ballast CONFIG OUT.json`.

Issue 28's question: is the server's extra CPU its work, or the 280 MB heap it brings (cache and TLB misses,
larger GC generations) making the daemon's other work slower? Here the server is off and the process holds
about as many tracked objects and bytes as the server's address space (asyncua's nodes: small objects, dicts
and lists referring to each other), built before the machines and frozen with start-up's objects.
"""

from __future__ import annotations

import json
import random
import signal
import sys
from pathlib import Path
from typing import Any

from bench.latency_daemon import Window, install
from edge.service.daemon import Daemon, run_daemon

NODES = 300_000  # x 4 tracked objects: about the 1.2-1.4 M objects the server adds at 100 machines
PAYLOAD = 16  # bytes a node: about the 210 MB the server adds


class _Node:
    """Shaped like an asyncua NodeData: attributes in a dict, references in a list."""

    def __init__(self, index: int) -> None:
        self.attributes: dict[str, Any] = {"value": [index], "name": {"text": str(index)}}
        self.references: list[Any] = []
        self.payload = bytes(PAYLOAD)


def ballast(count: int = NODES) -> list[_Node]:
    nodes = [_Node(i) for i in range(count)]
    linked = nodes[:]
    random.Random(28).shuffle(linked)
    for node, other in zip(nodes, linked, strict=True):
        node.references.append(other)
    return nodes


def main() -> int:
    config, out = Path(sys.argv[1]), Path(sys.argv[2])
    window = Window()
    signal.signal(signal.SIGUSR1, lambda signum, frame: window.reset())
    signal.signal(signal.SIGUSR2, lambda signum, frame: out.write_text(json.dumps(window.report())))
    held: list[_Node] = []

    def configure(daemon: Daemon) -> None:
        held.extend(ballast())
        install(window, daemon)

    return run_daemon(config, configure)


if __name__ == "__main__":
    sys.exit(main())
