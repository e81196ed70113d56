from __future__ import annotations

import subprocess
import sys


def test_the_cli_and_the_readers_do_not_load_mediapipe() -> None:
    """mediapipe (slow to import) is loaded only when a mediapipe detector is made: not by
    ``monoavatar --help``, nor by importing the readers and perception."""
    code = ("import monoavatar.perception, monoavatar.io, monoavatar.datasets, monoavatar.cli; "
            "import sys; assert 'mediapipe' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    out = subprocess.run([sys.executable, "-m", "monoavatar.cli", "--help"], check=True,
                         timeout=120, capture_output=True, text=True)
    assert "reconstruct" in out.stdout
