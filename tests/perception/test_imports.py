from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize(
    "statement",
    [
        "import monoavatar.perception.errors; import monoavatar.io",
        "import monoavatar.io.openpose; import monoavatar.perception",
        "from monoavatar.perception import perceive; from monoavatar.io import read_frames",
    ],
)
def test_packages_import_in_any_order_without_mediapipe(statement: str) -> None:
    """io and perception import each other's submodules: no import cycle may break, and
    mediapipe (slow to import) is loaded only when a mediapipe detector is made."""
    code = f"{statement}; import sys; assert 'mediapipe' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
