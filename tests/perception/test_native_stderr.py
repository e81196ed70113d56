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


def _python(*lines: str) -> subprocess.CompletedProcess[str]:
    """Run ``lines`` as a program in a fresh interpreter (stderr as a terminal's: fd 2)."""
    return subprocess.run([sys.executable, "-c", "\n".join(lines)], capture_output=True,
                          text=True, timeout=180, check=True)  # fmt: skip


def test_python_stderr_stays_visible_in_a_subprocess() -> None:
    """Inside the block native writes vanish, progress bars and warnings (Python's
    sys.stderr) do not, nesting included."""
    run = _python("import os, sys",
                  "from monoavatar.perception.mediapipe_backend import native_stderr_hidden",
                  "with native_stderr_hidden():",
                  "    os.write(2, b'native outer\\n')",
                  "    print('python outer', file=sys.stderr)",
                  "    with native_stderr_hidden():",
                  "        os.write(2, b'native inner\\n')",
                  "        print('python inner', file=sys.stderr)",
                  "os.write(2, b'native after\\n')")  # fmt: skip
    assert run.stderr.split() == ["python", "outer", "python", "inner", "native", "after"]


def test_the_stderr_copy_is_closed_with_the_block() -> None:
    """The block's copy of the terminal is closed when it ends: nothing that held it (a finished
    progress bar) leaves an 'unclosed file' ResourceWarning behind (Python's dev mode shows
    them)."""
    program = "\n".join([
        "import gc, sys",
        "from tqdm import tqdm",
        "from monoavatar.perception.mediapipe_backend import native_stderr_hidden",
        "with native_stderr_hidden():",
        "    copy = sys.stderr",
        "    done = list(tqdm(range(3), file=copy))",
        "print(copy is not sys.stderr, copy.closed)",
        "del copy",
        "gc.collect()",
    ])  # fmt: skip
    run = subprocess.run([sys.executable, "-X", "dev", "-c", program], capture_output=True,
                         text=True, timeout=180, check=True)  # fmt: skip
    assert run.stdout.split() == ["True", "True"]
    assert "ResourceWarning" not in run.stderr, run.stderr


def test_perception_prints_no_native_log_lines() -> None:
    """Perception of a real photograph of a person (every model starts: detector, landmarks,
    segmentation, face mesh) in a fresh process, as the CLI runs it: no native log lines."""
    run = _python("import numpy as np",
                  "from skimage import data",
                  "from monoavatar.io.frames import Frames",
                  "from monoavatar.perception.pipeline import perceive",
                  "photo = np.ascontiguousarray(data.astronaut())",
                  "frames = Frames(np.stack([photo] * 3), np.arange(3) / 3.0, np.arange(3))",
                  "obs = perceive(frames, use_cache=False)",
                  "print(int((~obs.no_person).sum()), int(obs.face_found.sum()))")  # fmt: skip
    assert run.stdout.split() == ["3", "3"]  # the person and the face were found every time
    for noise in ("TensorFlow Lite", "absl::InitializeLog", "Feedback manager", "W0000"):
        assert noise not in run.stderr, run.stderr
