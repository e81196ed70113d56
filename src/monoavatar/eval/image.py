"""Image-space metrics: silhouette IoU and PSNR."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["psnr", "silhouette_iou"]


def silhouette_iou(pred: ArrayLike, gt: ArrayLike) -> float:
    """Intersection over union of two boolean masks.

    Args:
        pred: boolean mask of any shape, e.g. (H, W) or (T, H, W) (all elements are pooled).
        gt: boolean mask of the same shape.

    Returns:
        ``|pred ∧ gt| / |pred ∨ gt|`` in [0, 1]. Two empty masks agree perfectly, so their IoU
        is defined as 1.0 (an empty prediction against a non-empty truth gives 0.0).

    Raises:
        TypeError: if a mask is not boolean (threshold soft or 0/255 masks explicitly first).
        ValueError: if the shapes differ.
    """
    p = np.asarray(pred)
    g = np.asarray(gt)
    for name, a in (("pred", p), ("gt", g)):
        if a.dtype != np.bool_:
            raise TypeError(f"{name}: expected a boolean mask, got dtype {a.dtype}")
    if p.shape != g.shape:
        raise ValueError(f"pred and gt: shapes differ, {p.shape} vs {g.shape}")
    union = int(np.count_nonzero(p | g))
    if union == 0:
        return 1.0
    return int(np.count_nonzero(p & g)) / union


def psnr(
    pred: ArrayLike,
    gt: ArrayLike,
    mask: ArrayLike | None = None,
    data_range: float | None = None,
) -> float:
    """Peak signal-to-noise ratio ``10 log10(data_range² / MSE)`` in decibels.

    The data range (peak value) is 255 for uint8 images and 1.0 for floating-point images,
    whose values must then lie in [0, 1]; pass ``data_range`` to override (e.g. 65535 for
    uint16, or for float images in another range, which are then not range-checked). The MSE
    is taken over all channels of the selected pixels, in float64.

    Args:
        pred: (H, W) or (H, W, C) image, uint8 or float.
        gt: same shape and dtype kind as ``pred``.
        mask: optional boolean (H, W) mask (or the image's full shape); only True pixels count.
        data_range: peak value; default from the dtype as above.

    Returns:
        PSNR in dB; ``inf`` for identical images.

    Raises:
        TypeError: dtype kinds differ, or the mask is not boolean.
        ValueError: shapes differ, float values outside [0, 1] with the default range, or the
            mask selects nothing.
    """
    p = np.asarray(pred)
    g = np.asarray(gt)
    if p.shape != g.shape:
        raise ValueError(f"pred and gt: shapes differ, {p.shape} vs {g.shape}")
    if p.dtype.kind != g.dtype.kind or (p.dtype.kind == "u" and p.dtype != g.dtype):
        raise TypeError(f"pred and gt: dtypes differ, {p.dtype} vs {g.dtype}")
    if data_range is None:
        if p.dtype == np.uint8:
            peak = 255.0
        elif p.dtype.kind == "f":
            peak = 1.0
            for name, a in (("pred", p), ("gt", g)):
                if a.size and (not np.all(np.isfinite(a)) or a.min() < 0.0 or a.max() > 1.0):
                    raise ValueError(
                        f"{name}: float images must lie in [0, 1] (got [{a.min()}, {a.max()}]);"
                        " pass data_range for another range"
                    )
        else:
            raise TypeError(f"pred: pass data_range for dtype {p.dtype}")
    else:
        peak = float(data_range)
        if not peak > 0:
            raise ValueError(f"data_range: expected > 0, got {data_range}")

    diff2 = (p.astype(np.float64) - g.astype(np.float64)) ** 2
    if mask is not None:
        m = np.asarray(mask)
        if m.dtype != np.bool_:
            raise TypeError(f"mask: expected a boolean array, got dtype {m.dtype}")
        if m.shape == p.shape:
            selected = diff2[m]
        elif m.shape == p.shape[:2]:
            selected = diff2[m].ravel()
        else:
            raise ValueError(f"mask: expected shape {p.shape[:2]} or {p.shape}, got {m.shape}")
    else:
        selected = diff2.ravel()
    if selected.size == 0:
        raise ValueError("mask/images: no pixel selected")
    mse = float(selected.mean())
    if mse == 0.0:
        return float("inf")
    return float(10.0 * np.log10(peak * peak / mse))
