"""Can the daemon use what its config names, as the systemd service will run it?

`check-config` runs as whoever types it (usually root), but the unit runs the daemon as the unprivileged
`focas-edge` user behind ProtectSystem=strict: a file root can read or a state_dir root can create may be
out of the service's reach, and the service would only find out at start. These checks answer from the
file modes for the service's account (owner, group and supplementary groups; ACLs are not consulted).
"""

from __future__ import annotations

import grp
import pwd
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path

from edge.config.root import Config

SERVICE_USER = "focas-edge"
# The unit's StateDirectory=: systemd creates it owned by the service user, and under ProtectSystem=strict
# it is the only place the service may write.
UNIT_STATE_DIR = Path("/var/lib/focas-edge")
# Files systemd hands the service at start (LoadCredential=); they do not exist outside it.
CREDENTIALS_ROOT = Path("/run/credentials")

READ, WRITE, SEARCH = 4, 2, 1


@dataclass(frozen=True)
class Account:
    name: str
    uid: int
    gids: frozenset[int]


def lookup_account(name: str) -> Account:
    """The account with its primary and supplementary groups; KeyError when there is no such user."""
    entry = pwd.getpwnam(name)
    gids = {entry.pw_gid} | {g.gr_gid for g in grp.getgrall() if name in g.gr_mem}
    return Account(name, entry.pw_uid, frozenset(gids))


def allowed(account: Account, path: Path, want: int) -> bool:
    """Whether the mode bits of `path` grant `want` (READ/WRITE/SEARCH bits) to the account."""
    if account.uid == 0:
        return True
    info = path.stat()
    if info.st_uid == account.uid:
        bits = info.st_mode >> 6
    elif info.st_gid in account.gids:
        bits = info.st_mode >> 3
    else:
        bits = info.st_mode
    return bits & want == want


def blocking_parent(account: Account, path: Path) -> Path | None:
    """The first directory above `path` the account cannot enter, if any."""
    for parent in reversed(path.parents):
        if parent.exists() and not allowed(account, parent, SEARCH):
            return parent
    return None


def named_files(config: Config) -> list[tuple[str, Path]]:
    """Every file the daemon reads, by its key in the config."""
    mqtt = config.mqtt
    files: list[tuple[str, Path]] = []
    if mqtt.tls is not None:
        for key in ("ca_file", "cert_file", "key_file"):
            path = getattr(mqtt.tls, key)
            if path is not None:
                files.append((f"mqtt.tls.{key}", Path(path)))
    if mqtt.password_file is not None:
        files.append(("mqtt.password_file", Path(mqtt.password_file)))
    opcua = config.opcua
    if opcua.enabled:
        files += [(f"opcua.{key}", Path(path)) for key in ("certificate_file", "private_key_file")
                  if (path := getattr(opcua, key)) is not None]
        files += [(f"opcua.users[{index}].password_file", Path(user.password_file))
                  for index, user in enumerate(opcua.users) if user.password_file is not None]
    return files


def unreadable_file(account: Account, key: str, path: Path) -> str | None:
    if CREDENTIALS_ROOT in path.parents:
        return None  # systemd makes it readable by the service at start
    try:
        parent = blocking_parent(account, path)
        if parent is not None:
            return f"{key}: user {account.name} cannot enter {parent} to read {path}"
        if not allowed(account, path, READ):
            return f"{key}: user {account.name} cannot read {path} (mode {stat.filemode(path.stat().st_mode)})"
    except OSError as exc:
        return f"{key}: cannot read {path} ({exc.strerror})"
    return None


def state_dir_problem(path: Path) -> str | None:
    """Why the daemon (as the current user) could not keep its state in `path`, or None.

    Probed by doing: the missing directories are created, a file is written, and both are removed again.
    """
    created: list[Path] = []
    try:
        for directory in [*reversed(path.parents), path]:
            if not directory.exists():
                directory.mkdir()
                created.append(directory)
        if not path.is_dir():
            return f"state_dir: {path} is not a directory"
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        return f"state_dir: cannot create or write {path} ({exc.strerror})"
    finally:
        for directory in reversed(created):
            directory.rmdir()
    return None


def service_state_dir_problem(account: Account, path: Path) -> str | None:
    """Why the service could not keep its state in `path`, or None."""
    if path == UNIT_STATE_DIR:
        return None  # StateDirectory=: systemd creates it and hands it to the service user
    if UNIT_STATE_DIR not in path.parents:
        return (f"state_dir: {path} is read-only for the service (the unit's ProtectSystem=strict leaves only "
                f"{UNIT_STATE_DIR} writable): leave state_dir out, or add ReadWritePaths={path} in a drop-in")
    existing = next(p for p in (path, *path.parents) if p.exists())
    parent = blocking_parent(account, existing)
    if parent is not None:
        return f"state_dir: user {account.name} cannot enter {parent}"
    if not allowed(account, existing, WRITE | SEARCH):
        return f"state_dir: user {account.name} cannot write {existing}"
    return None


def service_problems(config: Config, user: str = SERVICE_USER) -> list[str]:
    """Everything the service account could not read or write, as 'key: message' lines."""
    try:
        account = lookup_account(user)
    except KeyError:
        return [f"service user {user!r} does not exist (the package creates it; or pass --service-user NAME)"]
    problems = [unreadable_file(account, key, path) for key, path in named_files(config)]
    problems.append(service_state_dir_problem(account, config.resolved_state_dir))
    return [p for p in problems if p is not None]
