"""The layer contract (``[tool.importlinter]`` in pyproject.toml) holds, and it catches an
import that climbs a layer: a copy of the package with one such import breaks it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _lint(source_root: Path, config: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(source_root)}
    lint = Path(sys.executable).with_name("lint-imports")
    return subprocess.run([str(lint), "--config", str(config), "--no-cache"], env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def test_the_layers_hold() -> None:
    result = _lint(ROOT / "src", ROOT / "pyproject.toml")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_an_upward_import_breaks_the_contract(tmp_path: Path) -> None:
    shutil.copytree(ROOT / "src" / "monoavatar", tmp_path / "src" / "monoavatar",
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    camera = tmp_path / "src" / "monoavatar" / "core" / "camera.py"
    camera.write_text(camera.read_text() + "\nfrom monoavatar.bench import runner  # noqa\n")
    result = _lint(tmp_path / "src", tmp_path / "pyproject.toml")
    assert result.returncode != 0
    assert "monoavatar.core is not allowed to import monoavatar.bench" in result.stdout
