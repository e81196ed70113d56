"""Umeyama similarity alignment: exact recovery, no reflections, transform algebra."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from monoavatar.eval import SimilarityTransform, align_similarity


def _cost(t: SimilarityTransform, x: np.ndarray, y: np.ndarray) -> float:
    return float(((t.apply(x) - y) ** 2).sum())


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_recovers_a_known_random_similarity_exactly(seed: int) -> None:
    rng = np.random.default_rng(seed)
    truth = SimilarityTransform(
        rotation=Rotation.random(random_state=seed).as_matrix(),
        translation=rng.normal(size=3),
        scale=float(rng.uniform(0.2, 5.0)),
    )
    source = rng.normal(size=(25, 3))
    found = align_similarity(source, truth.apply(source))
    np.testing.assert_allclose(found.rotation, truth.rotation, atol=1e-12)
    np.testing.assert_allclose(found.translation, truth.translation, atol=1e-12)
    assert found.scale == pytest.approx(truth.scale, rel=1e-12)
    assert np.linalg.det(found.rotation) == pytest.approx(1.0, abs=1e-12)


def test_weights_select_the_points_that_count() -> None:
    rng = np.random.default_rng(7)
    truth = SimilarityTransform(Rotation.random(random_state=7).as_matrix(), np.ones(3), 2.0)
    source = rng.normal(size=(10, 3))
    target = truth.apply(source)
    target[7:] += 10.0  # outliers with zero weight
    weights = np.r_[np.ones(7), np.zeros(3)]
    found = align_similarity(source, target, weights=weights)
    np.testing.assert_allclose(found.matrix, truth.matrix, atol=1e-12)


def test_rigid_alignment_has_unit_scale() -> None:
    rng = np.random.default_rng(4)
    truth = SimilarityTransform(Rotation.random(random_state=4).as_matrix(), rng.normal(size=3))
    source = rng.normal(size=(6, 3))
    found = align_similarity(source, truth.apply(source) * 1.0, with_scale=False)
    assert found.scale == 1.0
    np.testing.assert_allclose(found.matrix, truth.matrix, atol=1e-12)


def test_mirrored_data_gives_the_best_proper_rotation_not_a_reflection() -> None:
    rng = np.random.default_rng(11)
    source = rng.normal(size=(30, 3)) * np.array([3.0, 2.0, 1.0])
    mirror = np.diag([-1.0, 1.0, 1.0])
    target = source @ mirror.T
    found = align_similarity(source, target)
    assert np.linalg.det(found.rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(found.rotation @ found.rotation.T, np.eye(3), atol=1e-12)
    # It is optimal among proper rotations: for nearby and random rotations, even with their
    # own best scale and translation (closed form for a fixed rotation), the cost is higher.
    best = _cost(found, source, target)
    assert best > 1.0  # a reflection cannot be undone by a rotation
    for k in range(100):
        delta = Rotation.from_rotvec(np.random.default_rng(k).normal(size=3) * 0.05).as_matrix()
        for rotation in (delta @ found.rotation, Rotation.random(random_state=k).as_matrix()):
            assert _best_cost_for_rotation(rotation, source, target) >= best - 1e-9


def _best_cost_for_rotation(rotation: np.ndarray, x: np.ndarray, y: np.ndarray) -> float:
    """min over s >= 0, t of Σ |s R x + t - y|² for a fixed R (s < 0 would be a reflection)."""
    rx = x @ rotation.T
    rxc, yc = rx - rx.mean(axis=0), y - y.mean(axis=0)
    s = max(float((rxc * yc).sum() / (rxc * rxc).sum()), 0.0)
    return float(((s * rxc - yc) ** 2).sum())


def test_mirrored_planar_data_is_matched_exactly_by_a_rotation() -> None:
    """Points in the plane z = 0 mirrored in x are a 180° turn about y away: the sign fix
    must find that rotation (residual 0), not the reflection diag(-1, 1, 1)."""
    rng = np.random.default_rng(2)
    source = np.c_[rng.normal(size=(12, 2)), np.zeros(12)]
    target = source * np.array([-1.0, 1.0, 1.0])
    found = align_similarity(source, target)
    np.testing.assert_allclose(found.rotation, np.diag([-1.0, 1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(found.apply(source), target, atol=1e-12)


def test_transform_algebra() -> None:
    a = SimilarityTransform(Rotation.random(random_state=1).as_matrix(), np.array([1, 2, 3.0]), 2.0)
    b = SimilarityTransform(
        Rotation.random(random_state=2).as_matrix(), np.array([0, -1, 4.0]), 0.5
    )
    x = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(a.inverse().apply(a.apply(x)), x, atol=1e-12)
    np.testing.assert_allclose(a.compose(b).apply(x), a.apply(b.apply(x)), atol=1e-12)
    np.testing.assert_allclose(a.compose(b).matrix, a.matrix @ b.matrix, atol=1e-12)
    np.testing.assert_allclose(SimilarityTransform.identity().apply(x), x)


def test_validation() -> None:
    with pytest.raises(ValueError, match="shapes differ"):
        align_similarity(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="scale is undefined"):
        align_similarity(np.ones((4, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="weights"):
        align_similarity(np.eye(3), np.eye(3), weights=[1.0, -1.0, 1.0])
