from __future__ import annotations

import math

import numpy as np

from monoavatar.perception.masks import (
    fill_holes,
    grabcut_refine,
    landmark_motion,
    largest_component,
    select_person,
    smooth_frame,
    temporal_smooth,
)


def test_temporal_smooth_weights() -> None:
    probs = np.zeros((5, 1, 1), np.float32)
    probs[2] = 1.0  # an impulse
    out = temporal_smooth(probs, np.arange(5), sigma=1.0)
    w = np.exp(-0.5 * np.arange(-2, 3) ** 2)
    # frame i's weight on frame 2 is exp(-½ (i-2)²) normalised over i's own window
    for i in range(5):
        window = np.array([j for j in range(5) if abs(j - i) <= 3])
        weights = np.exp(-0.5 * (window - i) ** 2)
        assert math.isclose(out[i, 0, 0], math.exp(-0.5 * (i - 2) ** 2) / weights.sum(),
                            rel_tol=1e-6)
    assert out[2, 0, 0] == np.float32(1.0 / w.sum())
    np.testing.assert_array_equal(temporal_smooth(probs, np.arange(5), 0.0), probs)
    far = temporal_smooth(probs, np.arange(5) * 10, sigma=1.0)
    np.testing.assert_array_equal(far, probs)  # frames 10 source frames apart are not mixed
    uint8 = temporal_smooth((probs * 255).astype(np.uint8), np.arange(5), 1.0)
    np.testing.assert_allclose(uint8, out * 255, rtol=1e-5)


def test_temporal_smooth_mixes_only_the_allowed_frames() -> None:
    probs = np.zeros((3, 1, 1), np.float32)
    probs[1] = 1.0
    alone = smooth_frame(probs, np.arange(3), 1, 1.0, mixable=np.zeros(3, bool))
    assert alone[0, 0] == 1.0  # frame 1 itself is always mixed
    one = smooth_frame(probs, np.arange(3), 1, 1.0, mixable=np.array([True, False, False]))
    assert math.isclose(one[0, 0], 1.0 / (1.0 + math.exp(-0.5)), rel_tol=1e-6)


def test_landmark_motion() -> None:
    a = np.zeros((5, 3))
    a[:, 1] = [0, 10, 20, 30, 40]  # extent 40 px
    a[:, 2] = 0.9
    b = a.copy()
    b[:, 0] += 2.0  # everything moves 2 px
    assert math.isclose(landmark_motion(a, b), 2.0 / 40.0)
    b[4, 0] += 100.0  # one landmark jumps: the 90th percentile sees part of it
    assert 2.0 / 40.0 < landmark_motion(a, b) < 102.0 / 40.0
    b[2:, 2] = 0.1  # fewer than 3 landmarks seen in both: unknown
    assert landmark_motion(a, b) == math.inf


def test_select_person_prefers_central_and_large() -> None:
    mask = np.zeros((100, 200), bool)
    mask[20:80, 90:120] = True  # central, 1800 px
    mask[10:90, 0:30] = True  # larger (2400 px) but at the edge
    mask[5:7, 150:152] = True  # a speck
    choice = select_person(mask, other_person_fraction=0.2)
    assert choice.num_people == 2
    assert choice.mask[50, 100] and not choice.mask[50, 10] and not choice.mask[6, 151]
    assert choice.others[50, 10] and not choice.others[6, 151]
    # equally central: the larger one wins
    mask2 = np.zeros((100, 200), bool)
    mask2[20:80, 60:80] = True
    mask2[10:90, 120:140] = True
    assert select_person(mask2).mask[50, 130]
    empty = select_person(np.zeros((4, 4), bool))
    assert empty.num_people == 0 and not empty.mask.any()
    # components below min_area are not people
    assert select_person(mask2, min_area=5000).num_people == 0


def test_largest_component() -> None:
    mask = np.zeros((10, 10), bool)
    mask[0:2, 0:2] = True
    mask[5:9, 5:9] = True
    out = largest_component(mask)
    assert out.sum() == 16 and out[6, 6]
    assert not largest_component(np.zeros((3, 3), bool)).any()


def test_fill_holes_small_only() -> None:
    mask = np.zeros((100, 100), bool)
    mask[10:90, 10:90] = True  # 6400 px
    mask[20:23, 20:23] = False  # a 9 px hole: segmentation noise
    mask[40:70, 40:70] = False  # a 900 px hole: e.g. between an arm and the torso
    mask[50:60, 0:11] = False  # a notch open to the border: not a hole
    out = fill_holes(mask, max_hole_fraction=0.01)
    assert out[21, 21] and not out[55, 55] and not out[55, 5]
    everything = fill_holes(mask, max_hole_fraction=float("inf"))
    assert everything[55, 55] and not everything[55, 5]
    assert not fill_holes(np.zeros((5, 5), bool)).any()


def test_grabcut_moves_the_boundary_to_the_edge() -> None:
    rng = np.random.default_rng(0)
    image = np.empty((120, 120, 3), np.uint8)
    image[:] = (40, 60, 200)  # blue background
    yy, xx = np.mgrid[:120, :120]
    person = (yy - 60) ** 2 + (xx - 60) ** 2 <= 30**2
    image[person] = (200, 90, 40)  # an orange disk
    image = np.clip(image + rng.normal(0, 6, image.shape), 0, 255).astype(np.uint8)
    rough = (yy - 60) ** 2 + (xx - 60) ** 2 <= 35**2  # 5 px too large
    refined = grabcut_refine(image, rough, band_px=8)

    def iou(a: np.ndarray, b: np.ndarray) -> float:
        return float((a & b).sum() / (a | b).sum())

    assert iou(refined, person) > 0.97 > iou(rough, person)
    np.testing.assert_array_equal(grabcut_refine(image, np.zeros_like(rough)), 0)
    assert grabcut_refine(image, rough, band_px=8).tolist() == refined.tolist()  # deterministic
