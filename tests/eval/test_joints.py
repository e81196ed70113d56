"""MPJPE and PA-MPJPE on hand-computed cases (inputs in metres, results in mm)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from monoavatar.eval import joint_errors, mpjpe, pa_mpjpe


def _skeleton(frames: int = 4, joints: int = 13, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(frames, joints, 3)) * 0.4


def test_mpjpe_of_a_uniform_3_4_5_offset_is_5_mm() -> None:
    gt = _skeleton()
    pred = gt + np.array([0.003, 0.004, 0.0])
    assert mpjpe(pred, gt) == pytest.approx(5.0, abs=1e-9)
    np.testing.assert_allclose(joint_errors(pred, gt), 5.0, atol=1e-9)
    assert pa_mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-9)  # a translation is aligned away


def test_pa_mpjpe_is_zero_for_a_similarity_transformed_copy() -> None:
    gt = _skeleton(frames=3)
    pred = np.empty_like(gt)
    for t in range(3):  # a different similarity per frame
        rot = Rotation.random(random_state=t).as_matrix()
        pred[t] = 1.5 * gt[t] @ rot.T + np.array([t, 1.0, -2.0])
    assert mpjpe(pred, gt) > 100.0
    assert pa_mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-9)
    # One transform for the whole sequence cannot undo per-frame transforms ...
    assert pa_mpjpe(pred, gt, per="sequence") > 10.0
    # ... but does undo a single one.
    rot = Rotation.random(random_state=9).as_matrix()
    same = 0.7 * gt @ rot.T + np.array([0.2, 0.0, 3.0])
    assert pa_mpjpe(same, gt, per="sequence") == pytest.approx(0.0, abs=1e-9)


def test_pa_mpjpe_closed_form_for_a_saddle_displacement() -> None:
    """Square (±1, ±1, 0) m with z = d·x·y added to the prediction.

    The displacement is orthogonal to every rotation and translation (Σ x²y = Σ xy² = Σ xy
    = 0), so rigid Procrustes leaves it: PA-MPJPE = MPJPE = d = 10 mm. With scale, the
    prediction (mean squared radius 2 + d²) is shrunk by s = 2 / (2 + d²), giving per joint
    |s (x, y, d) - (x, y, 0)| = d √(2 / (2 + d²)).
    """
    gt = np.array([[1.0, 1.0, 0.0], [-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, 1.0, 0.0]])
    d = 0.01
    pred = gt + np.c_[np.zeros((4, 2)), d * gt[:, 0] * gt[:, 1]]
    assert mpjpe(pred, gt) == pytest.approx(10.0, abs=1e-9)
    assert pa_mpjpe(pred, gt, with_scale=False) == pytest.approx(10.0, abs=1e-9)
    expected = 1000 * d * np.sqrt(2 / (2 + d**2))
    assert pa_mpjpe(pred, gt) == pytest.approx(expected, abs=1e-9)
    assert expected < 10.0 - 1e-4  # the scale term is visible at this tolerance


def test_pa_mpjpe_never_exceeds_mpjpe() -> None:
    gt = _skeleton(seed=1)
    pred = gt + np.random.default_rng(2).normal(size=gt.shape) * 0.02
    assert 0 < pa_mpjpe(pred, gt) <= mpjpe(pred, gt)


def test_masked_joints_are_ignored_in_error_and_alignment() -> None:
    gt = _skeleton(frames=2, joints=5)
    pred = gt + np.array([0.0, 0.0, 0.002])
    pred[:, 4, 2] += 1.0  # a wild joint (1 m off in z), masked out
    mask = np.array([True, True, True, True, False])
    assert mpjpe(pred, gt, mask) == pytest.approx(2.0, abs=1e-9)
    assert pa_mpjpe(pred, gt, mask) == pytest.approx(0.0, abs=1e-9)
    per_frame = np.ones((2, 5), dtype=bool)
    per_frame[0, 4] = False
    # frame 0: 4 joints at 2 mm; frame 1: 4 at 2 mm and one at |(0, 0, 1.002)| m.
    assert mpjpe(pred, gt, per_frame) == pytest.approx((8 * 2.0 + 1002.0) / 9, abs=1e-9)
    # Frames with < 3 valid joints are skipped by per-frame alignment.
    few = np.zeros((2, 5), dtype=bool)
    few[1, :4] = True
    few[0, :2] = True
    assert pa_mpjpe(pred, gt, few) == pytest.approx(0.0, abs=1e-9)


def test_single_frame_input_and_validation() -> None:
    gt = _skeleton(frames=1)[0]
    assert mpjpe(gt + 0.001, gt) == pytest.approx(np.sqrt(3.0), abs=1e-9)
    assert joint_errors(gt, gt).shape == (1, 13)
    with pytest.raises(ValueError, match="shapes differ"):
        mpjpe(gt, gt[:5])
    with pytest.raises(TypeError, match="boolean"):
        mpjpe(gt, gt, np.ones(13))
    with pytest.raises(ValueError, match="no joint"):
        mpjpe(gt, gt, np.zeros(13, dtype=bool))
    with pytest.raises(ValueError, match="no frame"):
        pa_mpjpe(gt, gt, np.arange(13) < 2)
