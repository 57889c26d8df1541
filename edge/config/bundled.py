"""The example configs and systemd units shipped inside the wheel, so an installed focas-edge can write them out.

They live in the repository's config/ and systemd/ (edge/bundled/ links to both), one copy for the
checkout, the wheel and the .deb.
"""

from __future__ import annotations

from importlib.resources import files
from importlib.resources.abc import Traversable
from pathlib import Path


def bundled(kind: str) -> list[Traversable]:
    """The files of one kind, 'config' (example YAML) or 'systemd' (units and drop-ins), by name."""
    folder = files("edge").joinpath("bundled", kind)
    return sorted((f for f in folder.iterdir() if f.is_file()), key=lambda f: f.name)


def write_bundled(kind: str, folder: Path, overwrite: bool = False) -> list[Path]:
    """Copy one kind's files into `folder` (made if missing); FileExistsError names a file already there."""
    sources = bundled(kind)
    targets = [folder / source.name for source in sources]
    existing = [str(t) for t in targets if t.exists()]
    if existing and not overwrite:
        raise FileExistsError(f"{', '.join(existing)} exist(s); use --force to overwrite")
    folder.mkdir(parents=True, exist_ok=True)
    for source, target in zip(sources, targets, strict=True):
        target.write_bytes(source.read_bytes())
    return targets
