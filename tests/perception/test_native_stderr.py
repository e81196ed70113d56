"""mediapipe's native start-up lines stay off the user's terminal; what native code wrote is
shown when the block fails."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from monoavatar.perception.mediapipe_backend import native_stderr_hidden


def test_hidden_text_is_shown_when_the_block_raises(capfd: pytest.CaptureFixture[str]) -> None:
    with native_stderr_hidden():
        os.write(2, b"quiet start-up line\n")
    with pytest.raises(RuntimeError), native_stderr_hidden():
        os.write(2, b"the native error message\n")
        raise RuntimeError("failed")
    err = capfd.readouterr().err
    assert "quiet start-up line" not in err
    assert "the native error message" in err


def test_mediapipe_starts_without_log_lines() -> None:
    code = ("import numpy as np\n"
            "from monoavatar.perception.mediapipe_backend import MediaPipePose, MediaPipeFaceMesh\n"
            "image = np.zeros((96, 96, 3), np.uint8)\n"
            "MediaPipePose().detect(image)\n"
            "MediaPipeFaceMesh().detect(image)\n"
            "print('ok')\n")  # fmt: skip
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)  # fmt: skip
    assert run.stdout.strip() == "ok"
    for noise in ("TensorFlow Lite", "absl::InitializeLog", "Feedback manager"):
        assert noise not in run.stderr, run.stderr
