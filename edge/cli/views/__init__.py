"""Terminal views of a broker's traffic: `watch` (decoded Sparkplug and JSON), the compact live view, and the
`make run` demo (`python -m edge.cli.views.demo`: simulated fleet + broker + daemon + live view).

They read what a subscriber receives on the broker (and, for the demo's compact view, the daemon's
DaemonView), so they may import service, publish (payload decoding), config and sim; nothing below imports them.
"""

__all__ = ["demo", "live_view", "watch"]
