"""What the installed focas-edge.service hands the daemon: its environment and its credentials.

`check-config --as-service` runs in an admin's shell, whose environment is not the service's: systemd
reads the unit's EnvironmentFile= (secrets.env, root-only) and the sources of LoadCredential= as root
before it starts the daemon. To answer "would the service have its MQTT password?" this reads the unit
and its drop-ins as systemd does: the unit file from the first directory that has it (/etc before /run
before /lib), drop-ins `focas-edge.service.d/*.conf` from all of them in file-name order (a name in a
higher directory hides the same name below), and an empty assignment resets a list.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass, field
from pathlib import Path

UNIT_NAME = "focas-edge.service"
UNIT_DIRS = (Path("/etc/systemd/system"), Path("/run/systemd/system"), Path("/usr/local/lib/systemd/system"),
             Path("/lib/systemd/system"), Path("/usr/lib/systemd/system"))
# The daemon sees a credential NAME at /run/credentials/focas-edge.service/NAME.
CREDENTIALS_DIR = Path("/run/credentials") / UNIT_NAME


@dataclass
class ServiceUnit:
    """The settings of the unit and its drop-ins that decide what secrets the daemon gets."""

    files: list[Path]
    environment: set[str] = field(default_factory=set)  # names set by Environment=
    environment_files: list[tuple[Path, bool]] = field(default_factory=list)  # (path, optional '-')
    credentials: dict[str, str] = field(default_factory=dict)  # LoadCredential= id -> source

    def environment_names(self) -> set[str]:
        """Every variable the service starts with (the files read as systemd would: KEY=VALUE lines)."""
        names = set(self.environment)
        for path, _optional in self.environment_files:
            try:
                text = path.read_text(encoding="utf-8", errors="replace")
            except OSError:
                continue
            for line in text.splitlines():
                key, eq, _ = line.strip().removeprefix("export ").partition("=")
                if eq and key and not key.startswith(("#", ";")):
                    names.add(key.strip())
        return names


def read_unit(dirs: tuple[Path, ...] | None = None) -> ServiceUnit | None:
    """The installed unit with its drop-ins, or None when no directory (UNIT_DIRS) has focas-edge.service."""
    dirs = UNIT_DIRS if dirs is None else dirs
    main = next((d / UNIT_NAME for d in dirs if (d / UNIT_NAME).is_file()), None)
    if main is None:
        return None
    drop_ins: dict[str, Path] = {}
    for directory in reversed(dirs):  # lowest priority first, so a higher directory's file wins by name
        for path in sorted((directory / f"{UNIT_NAME}.d").glob("*.conf")):
            drop_ins[path.name] = path
    unit = ServiceUnit([main, *(drop_ins[name] for name in sorted(drop_ins))])
    for path in unit.files:
        _apply(unit, path)
    return unit


def _apply(unit: ServiceUnit, path: Path) -> None:
    section = ""
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return
    for raw in lines:
        line = raw.strip()
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
        if section != "Service" or "=" not in line or line.startswith(("#", ";")):
            continue
        key, _, value = (part.strip() for part in line.partition("="))
        if key == "Environment":
            if not value:
                unit.environment.clear()
            for assignment in shlex.split(value):
                unit.environment.add(assignment.partition("=")[0])
        elif key == "EnvironmentFile":
            if not value:
                unit.environment_files.clear()
            else:
                unit.environment_files.append((Path(value.lstrip("-")), value.startswith("-")))
        elif key == "LoadCredential":
            if not value:
                unit.credentials.clear()
            else:
                name, _, source = value.partition(":")
                unit.credentials[name] = source or name


def password_problems(password_env: str | None, password_file: Path | None,
                      unit: ServiceUnit | None) -> list[str]:
    """Why the service would start without the MQTT password the config names (run exits 2 on it, or
    systemd refuses the start when a LoadCredential= source is missing), as 'key: message' lines."""
    if password_env:
        if unit is None:
            return [f"mqtt.password_env: no {UNIT_NAME} is installed to give the service {password_env}"]
        if password_env not in unit.environment_names():
            where = next((str(p) for p, _ in unit.environment_files), "an EnvironmentFile= in a drop-in")
            return [f"mqtt.password_env: the service does not get {password_env} ({UNIT_NAME} sets it neither "
                    f"in Environment= nor in {where}); fix: put {password_env}=... in {where} (root, 0600)"]
    if password_file is not None and CREDENTIALS_DIR in password_file.parents:
        name = password_file.name
        if unit is None or name not in unit.credentials:
            return [f"mqtt.password_file: {password_file} is a systemd credential, but {UNIT_NAME} loads no "
                    f"credential {name!r}: install the LoadCredential={name}:... drop-in "
                    f"(/usr/share/focas-edge/systemd/focas-edge-credentials.conf, docs/install.md)"]
        source = Path(unit.credentials[name])
        if source.is_absolute() and not source.is_file():
            return [f"mqtt.password_file: {UNIT_NAME} loads credential {name!r} from {source} "
                    f"(LoadCredential=), which does not exist: systemd would refuse the start "
                    f"(status=243/CREDENTIALS); fix: install -m 0600 /dev/stdin {source}"]
    return []
