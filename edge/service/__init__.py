"""The running daemon and its surroundings.

What lives here:

    daemon        the collector daemon: one publisher, a poller per machine, signals, reload, the watchdog
    state_lock    one daemon per state_dir: the flock the daemon holds and check-config asks about
    settings      the one place that turns the pydantic config into the settings dataclasses of the
                  layers below (PublishSettings, MachineSettings, PollSettings, CommandSettings,
                  OpcUaSettings)
    outputs       every output of the collector's samples behind one sink: the publisher, then the others
    opcua_output  the optional OPC UA server as one of those outputs, its writes bound to the command layer
    daemon_view   the read-only view of a running daemon that the status endpoint and the live view share
    status_http   /healthz, /metrics (Prometheus), /status.json and the status page
    status_page   status.json's document and the page rendered from it
    status_gateway  the gateway's identity and broker session: the page's block, status.json, systemd STATUS=
    value_freshness a value's age and whether it can still be called GOOD (status page and status.json)
    sdnotify      READY/RELOADING/STOPPING/WATCHDOG/STATUS to systemd
    gc_tuning     the garbage collector's settings for a long-running daemon
    heap_trim     the C heap's free pages back to the system after start-up, reloads and replays (malloc_trim)
    blocking_pool the daemon's named, bounded pool for its few blocking calls (the loop's default executor)
    logformat     text or JSON log lines (every subcommand uses it)

Rules:

1. service may import every layer below it (command, collect, publish, opcua, config, focas, the root types);
   only edge/cli imports service.
2. Only ``settings`` (and the daemon's reload comparison) read the pydantic config models; collect and
   command receive dataclasses.
3. This ``__init__`` imports nothing: every subcommand imports ``logformat`` at start, and loading the
   daemon's whole dependency tree for ``focas-edge read`` would cost every command its start-up time.
   Import each module by its path.
"""

__all__ = ["daemon", "daemon_view", "gc_tuning", "logformat", "opcua_output", "outputs", "sdnotify", "settings",
           "state_lock", "status_gateway", "status_http", "status_page", "value_freshness"]
