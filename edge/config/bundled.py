"""The example configs and systemd units shipped inside the wheel, so an installed focas-edge can write them out.

They live in the repository's config/ and systemd/ (edge/bundled/ links to both), one copy for the
checkout, the wheel and the .deb. The units run the .deb's /opt/focas-edge; written out for another
installation (a venv, a pip install) they are pointed at that installation's command instead, because a
unit whose ExecStart does not exist fails with status=203/EXEC and says little more.
"""

from __future__ import annotations

from importlib.resources import files
from importlib.resources.abc import Traversable
from pathlib import Path

PACKAGED_COMMAND = "/opt/focas-edge/bin/focas-edge"  # what the shipped units run: the .deb's venv
HOME_ROOTS = (Path("/home"), Path("/root"), Path("/run/user"))  # what the units' ProtectHome=yes hides


def bundled(kind: str) -> list[Traversable]:
    """The files of one kind, 'config' (example YAML) or 'systemd' (units and drop-ins), by name."""
    folder = files("edge").joinpath("bundled", kind)
    return sorted((f for f in folder.iterdir() if f.is_file()), key=lambda f: f.name)


def unit_for(text: str, command: str) -> str:
    """A shipped unit (or drop-in) made to run `command` (an executable path, maybe with arguments).

    An installation under a home directory stays visible to the service: ProtectHome=yes would hide it, so
    it becomes read-only instead.
    """
    text = text.replace(PACKAGED_COMMAND, command)
    program = Path(command.split()[0])
    if any(root == program or root in program.parents for root in HOME_ROOTS):
        text = text.replace("\nProtectHome=yes\n", f"\n# {program} is under a home directory: read-only, not hidden\n"
                                                   "ProtectHome=read-only\n")
    return text


def write_bundled(kind: str, folder: Path, overwrite: bool = False, command: str | None = None) -> list[Path]:
    """Copy one kind's files into `folder` (made if missing); FileExistsError names a file already there.

    `command`: the systemd files run that instead of /opt/focas-edge's (see unit_for).
    """
    sources = bundled(kind)
    targets = [folder / source.name for source in sources]
    existing = [str(t) for t in targets if t.exists()]
    if existing and not overwrite:
        raise FileExistsError(f"{', '.join(existing)} exist(s); use --force to overwrite it")
    folder.mkdir(parents=True, exist_ok=True)
    for source, target in zip(sources, targets, strict=True):
        data = source.read_bytes()
        if command is not None and kind == "systemd":
            data = unit_for(data.decode("utf-8"), command).encode("utf-8")
        target.write_bytes(data)
    return targets
