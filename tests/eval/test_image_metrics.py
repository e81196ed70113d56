"""Silhouette IoU and PSNR on hand-computed arrays."""

from __future__ import annotations

import numpy as np
import pytest

from monoavatar.eval import psnr, silhouette_iou


def test_iou_of_two_overlapping_squares_is_one_third() -> None:
    a = np.zeros((4, 4), dtype=bool)
    b = np.zeros((4, 4), dtype=bool)
    a[0:2, 0:2] = True  # 4 pixels
    b[0:2, 1:3] = True  # 4 pixels, 2 shared -> union 6
    assert silhouette_iou(a, b) == pytest.approx(1 / 3)
    assert silhouette_iou(a, a) == 1.0
    assert silhouette_iou(np.stack([a, a]), np.stack([a, b])) == pytest.approx(6 / 10)


def test_iou_empty_masks() -> None:
    empty = np.zeros((3, 5), dtype=bool)
    full = np.ones((3, 5), dtype=bool)
    assert silhouette_iou(empty, empty) == 1.0  # defined: both agree there is nothing
    assert silhouette_iou(empty, full) == 0.0
    assert silhouette_iou(full, empty) == 0.0


def test_iou_validation() -> None:
    with pytest.raises(TypeError, match="boolean"):
        silhouette_iou(np.zeros((2, 2), np.uint8), np.zeros((2, 2), dtype=bool))
    with pytest.raises(ValueError, match="shapes differ"):
        silhouette_iou(np.zeros((2, 2), dtype=bool), np.zeros((2, 3), dtype=bool))


def test_psnr_of_a_uniform_error_of_0_1_is_20_db() -> None:
    gt = np.full((8, 6, 3), 0.5)
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=1e-9)
    assert psnr(np.float32(gt - 0.1) * np.ones((8, 6, 3), np.float32), np.float32(gt)) == (
        pytest.approx(20.0, abs=1e-4)
    )


def test_psnr_uint8_uses_a_range_of_255() -> None:
    gt = np.zeros((4, 4, 3), np.uint8)
    pred = np.full((4, 4, 3), 51, np.uint8)  # error 51 = 255 / 5 -> 20 log10(5) dB
    assert psnr(pred, gt) == pytest.approx(20 * np.log10(5), abs=1e-9)
    assert psnr(gt, pred) == pytest.approx(20 * np.log10(5), abs=1e-9)  # no uint8 wrap-around
    assert psnr(pred, gt, data_range=51) == pytest.approx(0.0, abs=1e-12)


def test_psnr_mask_and_identical_images() -> None:
    gt = np.zeros((4, 4, 3))
    pred = gt.copy()
    pred[:2] = 0.1
    pred[2:] = 1.0
    mask = np.zeros((4, 4), dtype=bool)
    mask[:2] = True
    assert psnr(pred, gt, mask=mask) == pytest.approx(20.0, abs=1e-9)
    assert psnr(pred, gt, mask=np.broadcast_to(mask[..., None], (4, 4, 3))) == pytest.approx(20.0)
    # Unmasked: MSE = (0.01 + 1) / 2 over the two halves.
    assert psnr(pred, gt) == pytest.approx(-10 * np.log10(0.505), abs=1e-9)
    assert psnr(gt, gt) == float("inf")


def test_psnr_validation() -> None:
    img = np.zeros((2, 2))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        psnr(img + 2.0, img)
    assert psnr(img + 2.0, img, data_range=20.0) == pytest.approx(20.0)
    with pytest.raises(TypeError, match="dtypes differ"):
        psnr(img.astype(np.uint8), img)
    with pytest.raises(ValueError, match="no pixel"):
        psnr(img, img, mask=np.zeros((2, 2), dtype=bool))
    with pytest.raises(ValueError, match="shapes differ"):
        psnr(img, np.zeros((2, 3)))
