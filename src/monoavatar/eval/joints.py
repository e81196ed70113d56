"""3D joint position errors: MPJPE and Procrustes-aligned PA-MPJPE.

Inputs are joint positions in metres, shaped (T, J, 3) (T frames, J joints) or (J, 3) for a
single frame; results are in **millimetres**, the unit of the literature's tables (Paper A,
Tab. A.1 reports the same quantity in cm, with per-frame and per-sequence Procrustes alignment).

An optional boolean mask, (T, J) or (J,) (broadcast over frames), selects the joints that
count (e.g. annotated or visible ones); masked-out joints are ignored both in the alignment and
in the mean.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from monoavatar.eval._checks import BoolArray, FloatArray
from monoavatar.eval.alignment import align_similarity

__all__ = ["acceleration_error", "joint_errors", "mpjpe", "pa_mpjpe", "tracking_errors"]


def _prepare(
    pred: ArrayLike, gt: ArrayLike, mask: ArrayLike | None
) -> tuple[FloatArray, FloatArray, BoolArray]:
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.ndim == 2:
        p = p[None]
    if g.ndim == 2:
        g = g[None]
    if p.ndim != 3 or p.shape[2] != 3:
        raise ValueError(f"pred: expected shape (T, J, 3) or (J, 3), got {np.shape(pred)}")
    if g.shape != p.shape:
        raise ValueError(f"pred and gt: shapes differ, {p.shape} vs {g.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(g))):
        raise ValueError("pred/gt: contain non-finite values (mask them out and pass finite ones)")
    t, j = p.shape[:2]
    if mask is None:
        m = np.ones((t, j), dtype=bool)
    else:
        m = np.asarray(mask)
        if m.dtype != np.bool_:
            raise TypeError(f"mask: expected a boolean array, got dtype {m.dtype}")
        if m.shape == (j,):
            m = np.broadcast_to(m, (t, j))
        elif m.shape != (t, j):
            raise ValueError(f"mask: expected shape ({t}, {j}) or ({j},), got {m.shape}")
    if not m.any():
        raise ValueError("mask: selects no joint")
    return p, g, np.asarray(m, dtype=bool)


def joint_errors(pred: ArrayLike, gt: ArrayLike) -> FloatArray:
    """Euclidean distance per frame and joint, without alignment.

    Args:
        pred: (T, J, 3) or (J, 3) predicted joints, metres.
        gt: same shape, ground-truth joints, metres.

    Returns:
        (T, J) distances in millimetres (T = 1 for (J, 3) inputs).
    """
    p, g, _ = _prepare(pred, gt, None)
    out: FloatArray = np.linalg.norm(p - g, axis=2) * 1000.0
    return out


def mpjpe(pred: ArrayLike, gt: ArrayLike, mask: ArrayLike | None = None) -> float:
    """Mean per-joint position error: mean Euclidean distance over (frame, joint) pairs.

    No alignment (the root is not subtracted); align the inputs first if the protocol
    requires it.

    Args:
        pred: (T, J, 3) or (J, 3) predicted joints, metres.
        gt: same shape, ground-truth joints, metres.
        mask: optional boolean (T, J) or (J,); only True entries count.

    Returns:
        The mean distance in millimetres.
    """
    p, g, m = _prepare(pred, gt, mask)
    return float(np.linalg.norm(p - g, axis=2)[m].mean() * 1000.0)


def pa_mpjpe(
    pred: ArrayLike,
    gt: ArrayLike,
    mask: ArrayLike | None = None,
    *,
    per: Literal["frame", "sequence"] = "frame",
    with_scale: bool = True,
) -> float:
    """MPJPE after Procrustes alignment of the prediction to the ground truth.

    The prediction is aligned by a least-squares similarity transform (rotation, translation
    and, with ``with_scale``, isotropic scale; never a reflection), estimated from the masked
    joints, then MPJPE is computed over the same joints.

    Args:
        pred: (T, J, 3) or (J, 3) predicted joints, metres.
        gt: same shape, ground-truth joints, metres.
        mask: optional boolean (T, J) or (J,); only True entries are aligned and counted.
        per: ``"frame"``: one transform per frame (the usual PA-MPJPE; Tab. A.1 "local");
            frames with fewer than 3 valid joints are left out of the mean.
            ``"sequence"``: one transform for all frames together (Tab. A.1 "global").
        with_scale: estimate the scale too (standard); False gives rigid alignment.

    Returns:
        The mean distance in millimetres.

    Raises:
        ValueError: if no frame has at least 3 valid joints (per-frame), or fewer than 3
            joints are valid in total (per-sequence).
    """
    p, g, m = _prepare(pred, gt, mask)
    if per == "sequence":
        if m.sum() < 3:
            raise ValueError(f"mask: per-sequence alignment needs >= 3 joints, got {m.sum()}")
        transform = align_similarity(p[m], g[m], with_scale=with_scale)
        aligned = transform.apply(p[m])
        return float(np.linalg.norm(aligned - g[m], axis=1).mean() * 1000.0)
    if per != "frame":
        raise ValueError(f"per: expected 'frame' or 'sequence', got {per!r}")
    distances: list[FloatArray] = []
    for frame in range(p.shape[0]):
        valid = m[frame]
        if valid.sum() < 3:
            continue
        transform = align_similarity(p[frame][valid], g[frame][valid], with_scale=with_scale)
        aligned = transform.apply(p[frame][valid])
        distances.append(np.linalg.norm(aligned - g[frame][valid], axis=1))
    if not distances:
        raise ValueError("mask: no frame has the >= 3 valid joints per-frame alignment needs")
    return float(np.concatenate(distances).mean() * 1000.0)


def acceleration_error(pred: ArrayLike, gt: ArrayLike) -> float:
    """Mean distance between the predicted and true joint accelerations (second differences
    over frames), millimetres per frame²: how much jitter a track adds. pred, gt (T, J, 3)
    metres, T >= 3."""
    p, g, _ = _prepare(pred, gt, None)
    if p.shape[0] < 3:
        raise ValueError(f"acceleration needs at least 3 frames, got {p.shape[0]}")
    accel = np.diff(p, 2, axis=0) - np.diff(g, 2, axis=0)
    return float(np.linalg.norm(accel, axis=2).mean() * 1000.0)


def tracking_errors(pred: ArrayLike, gt: ArrayLike) -> dict[str, float]:
    """Table A.1's figures for a tracked sequence: mean joint error after a similarity per frame
    (``local_mm``) and one for the whole sequence (``global_mm``), and the acceleration error
    (``acceleration_mm_per_frame2``). pred, gt (T, J, 3) metres."""
    return {
        "local_mm": pa_mpjpe(pred, gt, per="frame"),
        "global_mm": pa_mpjpe(pred, gt, per="sequence"),
        "acceleration_mm_per_frame2": acceleration_error(pred, gt),
    }
