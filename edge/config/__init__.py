"""The YAML config: one file, validated completely before anything connects.

`load_config(path)` returns a Config or raises edge.ConfigError listing every problem with its path and
line in the file; soft findings land in `Config.warnings`. What lives here:

  fields          the field types every section shares (durations, Sparkplug ids, metric names), the model base
  mqtt            `mqtt:` broker, TLS, login (secrets from an environment variable or a file), Sparkplug, JSON
  poll            `poll:` periods, macro and PMC ranges, parameter and diagnosis numbers; the poll grid
  writes          `writes:` allow rules, rate limit, one machine's effective WritePolicy
  machines        `machines:` endpoint and transport rules, timeouts, CNC paths, alarms settings
  opcua           `opcua:` the optional OPC UA server: endpoint, security modes, users (secrets as for mqtt)
  root            Config, the top level (http, spool, state_dir) and the questions across sections
  load            YAML (a key given twice is refused) to Config, problems with paths and lines, cross-checks
  merge, lines    `defaults:`/`templates:` expanded into each machine; problem paths mapped to line numbers
  gateways        `gateways:` one fleet file for many gateways: who polls which machine, per-gateway overrides
  service_access  can the daemon's account (or the systemd service's) read and write what the config names
  service_unit    what the installed focas-edge.service hands the daemon: environment and credentials
  listen_port     can the status endpoint (`http:`) and the OPC UA server (`opcua:`) listen where the
                  config says (run and check-config, one wording)
  init_writer     a first config written from what the machines answered (`focas-edge init`)
  bundled         the example configs and unit files shipped inside the wheel

Rules:
  1. This package imports only the standard library, pydantic, PyYAML, edge.focas (targets, items, model,
     paths; the init writer also connect and probe) and the edge root (ConfigError). Never collect,
     publish, command, service or cli: they read the config, the config knows nothing of them.
  2. Other packages import the names below through `edge.config`, not the section modules. Inside the
     package, modules import each other directly, never through this file (it imports them).
  3. ConfigError is defined in edge/__init__.py, not here: focas, fwlib and sim raise it too and must not
     import the config.
"""

from edge.config.fields import check_sparkplug_id
from edge.config.gateways import GATEWAY_ENV
from edge.config.load import format_path, load_config, parse_config
from edge.config.machines import AlarmsConfig, MachineConfig
from edge.config.poll import SHORTEST_PERIOD_S, PollPlan
from edge.config.root import DEFAULT_STATE_DIR, Config
from edge.config.writes import AllowRule, RateLimit, WritePolicy

__all__ = [
    "DEFAULT_STATE_DIR",
    "GATEWAY_ENV",
    "SHORTEST_PERIOD_S",
    "AlarmsConfig",
    "AllowRule",
    "Config",
    "MachineConfig",
    "PollPlan",
    "RateLimit",
    "WritePolicy",
    "check_sparkplug_id",
    "format_path",
    "load_config",
    "parse_config",
]
