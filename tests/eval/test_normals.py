"""Normal angular error and per-region errors against closed forms (planes, a sphere)."""

from __future__ import annotations

import numpy as np
import pytest

from monoavatar.eval.normals import compare_surfaces, mesh_vertex_normals


def _grid(n: int = 11, size: float = 1.0, offset=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A flat n x n vertex grid in the plane z = 0 (normal +z), centred at ``offset``."""
    u = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(u, u)
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1) + np.asarray(offset)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    f = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                        np.stack([a, d, c], -1).reshape(-1, 3)])  # fmt: skip
    return v, f


def _tilt(v: np.ndarray, degrees: float, centre) -> np.ndarray:
    t = np.radians(degrees)
    R = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    c = np.asarray(centre)
    return (v - c) @ R.T + c


def _sphere(n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere of radius 1 with outward winding."""
    theta = np.linspace(0, np.pi, n + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1]], v, [[0, 0, -1]]])
    rows, cols = len(theta), len(phi)
    ring = lambda r, c: 1 + r * cols + c % cols  # noqa: E731
    f = [[0, ring(0, c), ring(0, c + 1)] for c in range(cols)]
    for r in range(rows - 1):
        for c in range(cols):
            f += [[ring(r, c), ring(r + 1, c), ring(r + 1, c + 1)],
                  [ring(r, c), ring(r + 1, c + 1), ring(r, c + 1)]]  # fmt: skip
    f += [[len(v) - 1, ring(rows - 1, c + 1), ring(rows - 1, c)] for c in range(cols)]
    return v, np.array(f)


def test_vertex_normals_of_a_sphere_point_outwards() -> None:
    v, f = _sphere()
    n = mesh_vertex_normals(v, f)
    assert np.degrees(np.arccos(np.clip((n * v).sum(1), -1, 1))).max() < 2.0


def test_identical_meshes_have_no_error() -> None:
    v, f = _sphere()
    c = compare_surfaces(v, f, v, f)
    assert c.distance == pytest.approx(0.0, abs=1e-12)
    assert c.angle == pytest.approx(0.0, abs=1e-4)


@pytest.mark.parametrize("degrees", [5.0, 20.0])
def test_a_tilted_plane_is_off_by_its_tilt(degrees: float) -> None:
    gt_v, f = _grid()
    pred_v = _tilt(gt_v, degrees, (0, 0, 0))
    c = compare_surfaces(pred_v, f, gt_v, f)
    np.testing.assert_allclose(c.pred_angle, degrees, atol=1e-6)
    np.testing.assert_allclose(c.gt_angle, degrees, atol=1e-6)
    # the vertex of (x, y, 0) turned about the x axis lies |y| sin(tilt) above the plane z = 0
    # (and its foot point, at y cos(tilt), inside it)
    expect = np.abs(gt_v[:, 1]) * np.sin(np.radians(degrees))
    np.testing.assert_allclose(c.pred_to_gt, expect, atol=1e-9)


def test_a_sphere_against_a_larger_one() -> None:
    v, f = _sphere(32)
    c = compare_surfaces(1.05 * v, f, v, f)
    # concentric spheres: radial distance 0.05 (less the chords' sag), normals parallel
    assert c.pred_to_gt.mean() == pytest.approx(0.05, abs=2e-3)
    assert c.angle < 1.0


def test_regions_count_their_own_vertices() -> None:
    # ground truth: two patches far apart; prediction: patch A tilted 10°, patch B 30°
    a_v, a_f = _grid(offset=(-5.0, 0.0, 0.0))
    b_v, b_f = _grid(offset=(5.0, 0.0, 0.0))
    gt_v = np.concatenate([a_v, b_v])
    gt_f = np.concatenate([a_f, b_f + len(a_v)])
    pred_v = np.concatenate([_tilt(a_v, 10.0, (-5, 0, 0)), _tilt(b_v, 30.0, (5, 0, 0))])
    c = compare_surfaces(pred_v, gt_f, gt_v, gt_f)
    in_a = np.arange(len(gt_v)) < len(a_v)
    _, angle_a = c.region(in_a)
    _, angle_b = c.region(~in_a)
    assert angle_a == pytest.approx(10.0, abs=1e-6)
    assert angle_b == pytest.approx(30.0, abs=1e-6)
    assert c.angle == pytest.approx(20.0, abs=1e-6)
    assert np.isnan(c.region(np.zeros(len(gt_v), bool))[0])
    with pytest.raises(ValueError, match="region"):
        c.region(np.ones(3, bool))
