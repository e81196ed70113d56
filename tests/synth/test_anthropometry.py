"""Body proportions of rest-pose bodies and the adult ranges of suite v2's subjects."""

import numpy as np
import pytest
import torch

from monoavatar.synth.anthropometry import (
    ADULT_PROPORTIONS,
    adult_proportion_ranges,
    body_proportions,
    measure_body,
    plausible,
)

NAMES = ("pelvis", "head", "shoulder_l", "elbow_l", "wrist_l", "hip_l", "knee_l", "ankle_l",
         "shoulder_r", "elbow_r", "wrist_r", "hip_r", "knee_r", "ankle_r")  # fmt: skip


def _box(lo, hi, n=6):
    """(n³, 3) points filling the axis-aligned box [lo, hi]."""
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def test_proportions_of_a_stick_figure_match_its_measures():
    # a 1.7 m figure: a 0.26 m x 0.10 m sole per foot, hands reaching 0.19 m from the wrist,
    # a 0.23 m tall, 0.16 m wide head, 0.30 + 0.25 m arm bones, 0.40 + 0.40 m leg bones
    joints = {"pelvis": (0, 0.95, 0), "head": (0, 1.55, 0)}
    parts = [(_box((-0.08, 1.47, -0.1), (0.08, 1.70, 0.1)), "head"),
             (_box((-0.2, 0.5, -0.1), (0.2, 1.4, 0.1)), "pelvis")]  # fmt: skip
    for side, s in (("l", 1.0), ("r", -1.0)):
        joints |= {f"ankle_{side}": (0.1 * s, 0.08, 0), f"knee_{side}": (0.1 * s, 0.48, 0),
                   f"hip_{side}": (0.1 * s, 0.88, 0), f"shoulder_{side}": (0.18 * s, 1.40, 0),
                   f"elbow_{side}": (0.48 * s, 1.40, 0), f"wrist_{side}": (0.73 * s, 1.40, 0)}
        foot = _box((0.05 * s, 0.0, -0.06), (0.15 * s, 0.03, 0.2))
        foot = np.vstack([foot, [[0.1 * s, 0.1, 0.0]]])  # the ankle, above the sole
        hand = np.array([[0.73 * s, 1.40, 0.0], [0.92 * s, 1.40, 0.0]])
        parts += [(foot, f"ankle_{side}"), (hand, f"wrist_{side}")]
    vertices = np.vstack([p for p, _ in parts])
    part = np.concatenate([np.full(len(p), NAMES.index(n)) for p, n in parts])
    j = np.array([joints[n] for n in NAMES], dtype=float)
    got = body_proportions(vertices, j, part, NAMES)
    stature = 1.70
    for side in "lr":
        assert got[f"foot_length/{side}"] == pytest.approx(0.26 / stature)
        assert got[f"foot_breadth/{side}"] == pytest.approx(0.10 / 0.26)
        assert got[f"hand_length/{side}"] == pytest.approx(0.19 / stature)
        assert got[f"arm_length/{side}"] == pytest.approx(0.55 / stature)
        assert got[f"leg_length/{side}"] == pytest.approx(0.80 / stature)
    assert got["head_height"] == pytest.approx(0.23 / stature)
    assert got["head_breadth"] == pytest.approx(0.16 / stature)
    assert got["shoulder_width"] == pytest.approx(0.36 / stature)
    assert body_proportions(vertices, j, part, ("a",) * len(NAMES)) == {}  # not Anny's names


def test_the_adult_ranges_are_the_phenotype_corners_and_reject_caricatures(anny_local):
    ranges = adult_proportion_ranges(anny_local)
    assert ranges.keys() == ADULT_PROPORTIONS.keys()
    for key, (low, high) in ranges.items():
        assert ADULT_PROPORTIONS[key] == pytest.approx((low, high), abs=1e-3), key
    # human foot length is about 0.15 of the stature: the range holds it and not a fifth
    assert ADULT_PROPORTIONS["foot_length"][0] < 0.15 < ADULT_PROPORTIONS["foot_length"][1] < 0.18
    shape = np.zeros(anny_local.shape_dim)
    assert plausible(measure_body(anny_local, shape)[1])
    names = anny_local.local_change_names
    for change in ("foot-scale-incr", "foot-scale-horiz-incr"):
        big = shape.copy()
        big[6 + names.index("l-" + change)] = big[6 + names.index("r-" + change)] = 0.9
        assert not plausible(measure_body(anny_local, big)[1]), change


def test_wide_subjects_have_adult_proportions(anny_local):
    from monoavatar.synth.subjects import sample_subject

    for seed in range(3):
        spec = sample_subject(np.random.default_rng(seed), anny_local, "minimal", "wide")
        with torch.no_grad():
            v, j = anny_local.rest_shape(torch.as_tensor(spec.shape, dtype=torch.float32)[None])
        part = anny_local.skin_weights.argmax(dim=1).numpy()
        got = body_proportions(v[0].double().numpy(), j[0].double().numpy(), part,
                               tuple(anny_local.joint_names))  # fmt: skip
        assert len(got) == 13
        for key, value in got.items():
            low, high = ADULT_PROPORTIONS[key.split("/")[0]]
            assert low <= value <= high, (seed, key, value)
