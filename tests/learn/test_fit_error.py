"""The single-image fitter's error on a synthetic photo, as ``train photo`` measures it: the
residuals are those of a fit (small, not zero) and mediapipe's native log lines stay hidden
while the detectors are reused over many photos."""

from __future__ import annotations

import json
import subprocess
import sys


def test_residuals_of_one_photo_in_a_fresh_process() -> None:
    program = "\n".join([
        "import json",
        "import numpy as np",
        "from monoavatar.body import load_body_model",
        "from monoavatar.learn.fit_error import residuals",
        "from monoavatar.learn.photo_data import PhotoDataSettings",
        "r = residuals(load_body_model('anny'), [3000000, 3000001], load_body_model('anny-local'),",
        "              PhotoDataSettings(), progress=False)",
        "print(json.dumps({'n': len(r.rotation), 'skipped': r.skipped,",
        "                  'rot': float(np.median(np.linalg.norm(r.rotation, axis=-1))),",
        "                  'trans': float(np.linalg.norm(r.translation, axis=-1).max())}))",
    ])  # fmt: skip
    run = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                         timeout=600, check=True)  # fmt: skip
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["n"] + len(out["skipped"]) == 2 and out["n"] >= 1
    # a fit, not the truth and not nonsense: joint rotations off by a few degrees to tens
    assert 0.01 < out["rot"] < 0.6
    assert out["trans"] < 0.5  # the root within half a metre, in camera axes, at true scale
    for noise in ("TensorFlow Lite", "absl::InitializeLog", "Feedback manager", "W0000"):
        assert noise not in run.stderr, run.stderr
