"""The layering of shared/DESIGN.md §3 holds: import-linter checks pyproject.toml's contracts on the tree.

The second test proves the check can fail: a copy of edge/ with one import that runs against the layers
(the FOCAS codecs importing the daemon) must break a contract.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def lint_imports(package_parent: Path) -> subprocess.CompletedProcess[str]:
    """Run import-linter on the `edge` package found under `package_parent`, with the project's contracts."""
    env = {**os.environ, "PYTHONPATH": str(package_parent), "COLUMNS": "250"}  # one line per contract
    script = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    return subprocess.run(
        [sys.executable, "-c", script, "--config", str(REPO / "pyproject.toml"), "--no-cache"],
        cwd=package_parent, env=env, capture_output=True, text=True, timeout=120, check=False)


def test_the_tree_keeps_every_layer_contract() -> None:
    result = lint_imports(REPO)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


@pytest.mark.parametrize(("module", "bad_import", "contract"), [
    ("focas/frame.py", "import edge.service.daemon", "Layers point down"),
    ("publish/payload.py", "import edge.focas.model", "publish knows samples and metrics, never FOCAS"),
    ("sim/faults.py", "import edge.focas.client", "the simulator serves with the focas codecs"),
    ("collect/changes.py", "import edge.config", "collect and command take settings dataclasses"),
])
def test_an_import_against_the_layers_breaks_a_contract(tmp_path: Path, module: str, bad_import: str,
                                                        contract: str) -> None:
    shutil.copytree(REPO / "edge", tmp_path / "edge", ignore=shutil.ignore_patterns("__pycache__"))
    target = tmp_path / "edge" / module
    target.write_text(target.read_text() + f"\n{bad_import}  # deliberately against the layers\n")
    result = lint_imports(tmp_path)
    assert result.returncode != 0, result.stdout
    broken = [line for line in result.stdout.splitlines() if line.endswith(" BROKEN")]
    assert any(line.startswith(contract) for line in broken), result.stdout
