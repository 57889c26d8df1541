"""Can the daemon use what its config names, as the systemd service will run it?

`check-config` runs as whoever types it (usually root), but the unit runs the daemon as the unprivileged
`focas-edge` user behind ProtectSystem=strict: a file root can read or a state_dir root can create may be
out of the service's reach, and the service would only find out at start. These checks answer from the
file modes for the service's account (owner, group and supplementary groups; ACLs are not consulted).
`run` asks the same questions (state_files_problem, unreadable_file) for its own account at start, so both
commands refuse the same thing in the same words.
"""

from __future__ import annotations

import contextlib
import grp
import os
import pwd
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path

from edge.config.listen_port import service_port_problem
from edge.config.root import Config
from edge.config.service_unit import password_problems, read_unit

SERVICE_USER = "focas-edge"
# The unit's StateDirectory=: systemd creates it owned by the service user, and under ProtectSystem=strict
# it is the only place the service may write.
UNIT_STATE_DIR = Path("/var/lib/focas-edge")
# Files systemd hands the service at start (LoadCredential=); they do not exist outside it.
CREDENTIALS_ROOT = Path("/run/credentials")

READ, WRITE, SEARCH = 4, 2, 1
STATE_ENTRIES_LIMIT = 10_000  # a state_dir holds a few dozen files; a mistaken state_dir: / must not hang


@dataclass(frozen=True)
class Account:
    name: str
    uid: int
    gids: frozenset[int]
    group: str = ""  # the primary group's name, for the chown that fixes a state_dir
    gid: int | None = None  # the primary group

    @property
    def owner(self) -> str:
        return f"{self.name}:{self.group or self.name}"


def lookup_account(name: str) -> Account:
    """The account with its primary and supplementary groups; KeyError when there is no such user."""
    entry = pwd.getpwnam(name)
    gids = {entry.pw_gid} | {g.gr_gid for g in grp.getgrall() if name in g.gr_mem}
    return Account(name, entry.pw_uid, frozenset(gids), _group_name(entry.pw_gid), entry.pw_gid)


def current_account() -> Account:
    """The account this process runs as (what `run` and a plain `check-config` are checked against)."""
    uid, gid = os.geteuid(), os.getegid()
    try:
        name = pwd.getpwuid(uid).pw_name
    except KeyError:
        name = str(uid)
    return Account(name, uid, frozenset({gid, *os.getgroups()}), _group_name(gid), gid)


def _group_name(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def owner_of(info: os.stat_result) -> str:
    try:
        user = pwd.getpwuid(info.st_uid).pw_name
    except KeyError:
        user = str(info.st_uid)
    return f"{user}:{_group_name(info.st_gid)}"


def allowed(account: Account, path: Path, want: int) -> bool:
    """Whether the mode bits of `path` grant `want` (READ/WRITE/SEARCH bits) to the account."""
    return account.uid == 0 or _allowed_by(account, path.stat(), want)


def _allowed_by(account: Account, info: os.stat_result, want: int) -> bool:
    if account.uid == 0:
        return True
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
    """Why the account could not read `path` (by the mode bits of it and the directories above), or None."""
    if CREDENTIALS_ROOT in path.parents:
        return None  # systemd makes it readable by the service at start (service_unit checks the source)
    try:
        parent = blocking_parent(account, path)
        if parent is not None:
            return f"{key}: user {account.name} cannot enter {parent} to read {path}"
        info = path.stat()
        if not _allowed_by(account, info, READ):
            return (f"{key}: user {account.name} cannot read {path} (owner {owner_of(info)}, mode "
                    f"{stat.filemode(info.st_mode)}); fix: chgrp {account.group or account.name} {path} && "
                    f"chmod g+r {path}")
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
                try:
                    directory.mkdir()
                except FileExistsError:
                    continue  # made meanwhile by another process probing beside us (two gateways starting)
                created.append(directory)
        if not path.is_dir():
            return f"state_dir: {path} is not a directory"
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        return f"state_dir: cannot create or write {path} ({exc.strerror})"
    finally:
        for directory in reversed(created):
            with contextlib.suppress(OSError):  # another process may be using it by now: then it stays
                directory.rmdir()
    return None


def state_files_problem(account: Account, state_dir: Path) -> str | None:
    """The first thing in state_dir the account could not read and write, with the command that fixes it.

    A `focas-edge run` as root before the service leaves root-owned files (0600 for the atomically written
    ones) in the state_dir the service user owns; the service would die on a PermissionError at its first
    read or write of one. Walked in a fixed order, so `run` and `check-config` name the same file. None
    when everything is usable or state_dir does not exist yet.
    """
    for path, info in _state_entries(state_dir):
        is_dir = stat.S_ISDIR(info.st_mode)
        if _allowed_by(account, info, READ | WRITE | SEARCH if is_dir else READ | WRITE):
            continue
        fix = (f"chmod -R u+rwX {state_dir}" if info.st_uid == account.uid
               else f"chown -R {account.owner} {state_dir}")
        return (f"state_dir: {path} belongs to {owner_of(info)} (mode {stat.filemode(info.st_mode)}), so user "
                f"{account.name} cannot {'enter and write' if is_dir else 'read and write'} it (left by a run "
                f"as another user?); fix: {fix}")
    return None


def _state_entries(state_dir: Path) -> list[tuple[Path, os.stat_result]]:
    """state_dir and everything below it (at most STATE_ENTRIES_LIMIT), sorted, without following links
    into other directories; each with the stat of what a name points to."""
    found: list[tuple[Path, os.stat_result]] = []
    pending = [state_dir]
    while pending and len(found) < STATE_ENTRIES_LIMIT:
        path = pending.pop(0)
        try:
            info = path.stat()
        except OSError:
            continue  # gone meanwhile, or a dangling link: nothing the daemon would open
        found.append((path, info))
        if stat.S_ISDIR(info.st_mode) and not path.is_symlink():
            try:
                pending[:0] = sorted(path.iterdir())
            except OSError:
                continue  # unlistable: its own entry above is what gets reported
    return found


def service_state_files_problem(account: Account, state_dir: Path) -> str | None:
    """state_files_problem as the service will meet it: systemd's StateDirectory= hands the unit's state
    directory and everything in it to the service user at start when the directory itself is owned by
    someone else, but leaves the files alone when the directory is already the service's."""
    if state_dir == UNIT_STATE_DIR and state_dir.is_dir():
        info = state_dir.stat()
        if info.st_uid != account.uid or (account.gid is not None and info.st_gid != account.gid):
            return None
    return state_files_problem(account, state_dir)


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


def service_problems(config: Config, user: str = SERVICE_USER, config_path: Path | None = None) -> list[str]:
    """Everything that would stop the service (its account, its unit, its sandbox) from running this config,
    as 'key: message' lines: files it could not read, a state_dir or state file it could not write, a
    password the unit does not hand it, a port it may not bind."""
    try:
        account = lookup_account(user)
    except KeyError:
        return [f"service user {user!r} does not exist (the package creates it; or pass --service-user NAME)"]
    problems = [] if config_path is None else [unreadable_file(account, "config", Path(config_path).absolute())]
    problems += [unreadable_file(account, key, path) for key, path in named_files(config)]
    state_dir = config.resolved_state_dir
    problems.append(service_state_dir_problem(account, state_dir) or service_state_files_problem(account, state_dir))
    mqtt = config.mqtt
    problems += password_problems(mqtt.password_env, mqtt.password_file, read_unit())
    if config.http.enabled:
        problems.append(service_port_problem(config.http.port))
    if config.opcua.enabled:
        problems.append(service_port_problem(config.opcua.port, "opcua"))
    return [p for p in problems if p is not None]
