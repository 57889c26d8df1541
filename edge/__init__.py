"""focas-edge: FANUC FOCAS/Ethernet edge collector publishing Sparkplug B 3.0 and JSON over MQTT.

ConfigError lives here, not in edge.config, because focas, fwlib and sim raise it too (bad addresses,
bad scenario files) and must not import the config.
"""

__version__ = "0.1.0"


class ConfigError(Exception):
    """The configuration is invalid; `problems` lists every finding as 'path: message'."""

    def __init__(self, problems: list[str], source: str = "config") -> None:
        self.problems = list(problems)
        self.source = source
        lines = "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(f"{source}: {len(self.problems)} problem(s):\n{lines}")
