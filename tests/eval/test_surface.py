"""Surface distances and the bi-directional surface error, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from monoavatar.eval import (
    SimilarityTransform,
    align_icp,
    bidirectional_surface_error,
    closest_points_on_mesh,
    point_to_surface_distance,
    surface_error_after_alignment,
)
from monoavatar.eval.surface import TriangleIndex

# ---------------------------------------------------------------------------- fixtures


def icosphere(subdivisions: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere whose vertices lie exactly (to rounding) on the sphere of ``radius``."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * radius
    return v, np.asarray(mesh.faces, dtype=np.int64)


def bumpy_mesh(subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A closed mesh with no symmetry: a tri-axial ellipsoid with one off-axis bump (metres)."""
    v, f = icosphere(subdivisions, 1.0)
    bump = 1.0 + 0.25 * np.exp(-8.0 * ((v - np.array([0.6, 0.6, 0.5])) ** 2).sum(axis=1))
    return v * np.array([0.3, 0.9, 0.2]) * bump[:, None], f


def convex_interior_distance(points: np.ndarray, v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Exact distance from points *inside* a convex polyhedron to its surface.

    For an interior point the closest boundary point lies on the nearest facet plane, so the
    distance is ``min_f (h_f - n_f · p)`` with unit outward normals ``n_f`` and plane offsets
    ``h_f`` — an independent closed form.
    """
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= np.sign(np.einsum("ij,ij->i", n, (a + b + c) / 3.0))[:, None]  # outward
    h = np.einsum("ij,ij->i", n, a)
    return (h[None, :] - points @ n.T).min(axis=1)


# ------------------------------------------------------------- point-triangle closed forms

TRIANGLE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
CASES = {
    # name: (query, closest point, barycentric)
    "above interior": ([0.2, 0.3, 0.5], [0.2, 0.3, 0.0], [0.5, 0.2, 0.3]),
    "below interior": ([0.1, 0.1, -2.0], [0.1, 0.1, 0.0], [0.8, 0.1, 0.1]),
    "in plane, inside": ([0.25, 0.25, 0.0], [0.25, 0.25, 0.0], [0.5, 0.25, 0.25]),
    "beside edge ab": ([0.5, -0.3, 0.4], [0.5, 0.0, 0.0], [0.5, 0.5, 0.0]),
    "beside edge bc": ([1.0, 1.0, 1.0], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5]),
    "beside edge ca": ([-0.7, 0.4, 0.0], [0.0, 0.4, 0.0], [0.6, 0.0, 0.4]),
    "beyond vertex a": ([-1.0, -2.0, 3.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
    "beyond vertex b": ([2.0, -1.0, 0.5], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
    "beyond vertex c": ([-0.5, 3.0, -1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_point_triangle_closed_forms(case: str) -> None:
    query, closest, bary = (np.array(x) for x in CASES[case])
    expected = float(np.linalg.norm(query - closest))
    # Same configuration in an arbitrary rigid pose: distances and barycentrics are invariant.
    rot = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    shift = np.array([0.4, -2.0, 1.5])
    for r, t in ((np.eye(3), np.zeros(3)), (rot, shift)):
        tri = TRIANGLE @ r.T + t
        cp = closest_points_on_mesh((query @ r.T + t)[None], tri, [[0, 1, 2]])
        assert cp.distances[0] == pytest.approx(expected, abs=1e-12)
        np.testing.assert_allclose(cp.points[0], closest @ r.T + t, atol=1e-12)
        np.testing.assert_allclose(cp.barycentric[0], bary, atol=1e-12)


def test_distance_is_to_the_surface_not_to_the_nearest_vertex() -> None:
    # A large triangle; a point 1 cm above its centroid is ~0.58 m from every vertex.
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3) / 2, 0.0]])
    point = np.array([[0.5, np.sqrt(3) / 6, 0.01]])
    assert point_to_surface_distance(point, tri, [[0, 1, 2]])[0] == pytest.approx(0.01, abs=1e-15)


def test_degenerate_triangles_give_finite_exact_distances() -> None:
    collinear = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    d = point_to_surface_distance([[0.5, 1.0, 0.0], [3.0, 0.0, 0.0]], collinear, [[0, 1, 2]])
    np.testing.assert_allclose(d, [1.0, 1.0], atol=1e-12)
    point_like = np.array([[1.0, 2.0, 3.0]] * 3)
    d = point_to_surface_distance([[1.0, 2.0, 5.0]], point_like, [[0, 1, 2]])
    np.testing.assert_allclose(d, [2.0], atol=1e-12)


def test_matches_independent_brute_force_on_a_triangle_soup() -> None:
    """Candidate search is exact: equals trimesh's per-triangle closest point, minimised
    over every triangle, on triangles of very different sizes; also when few nearest
    centroids are taken per bin (most points then need the ball search)."""
    rng = np.random.default_rng(3)
    sizes = rng.uniform(0.005, 1.0, size=(150, 1, 1))
    tri = rng.normal(size=(150, 3, 3)) * sizes + rng.normal(size=(150, 1, 3))
    vertices = tri.reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    points = np.concatenate([rng.normal(size=(150, 3)) * 1.5, vertices[:150] + 0.01])
    ours = closest_points_on_mesh(points, vertices, faces)

    rep_points = np.repeat(points, len(tri), axis=0)
    rep_tri = np.tile(tri, (len(points), 1, 1))
    brute = np.linalg.norm(
        trimesh.triangles.closest_point(rep_tri, rep_points) - rep_points, axis=1
    )
    truth = brute.reshape(len(points), -1).min(axis=1)
    np.testing.assert_allclose(ours.distances, truth, atol=1e-12)
    for k in (1, 3):
        few = TriangleIndex(tri, k=k).query(points)
        np.testing.assert_allclose(few.distances, truth, atol=1e-12)
    # The reported point is on the reported face, at the reported barycentric coordinates.
    rebuilt = np.einsum("ni,nij->nj", ours.barycentric, tri[ours.face_indices])
    np.testing.assert_allclose(rebuilt, ours.points, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(points - ours.points, axis=1), ours.distances)
    assert ours.barycentric.min() >= -1e-12


def test_input_validation() -> None:
    v, f = icosphere(1, 1.0)
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\)"):
        point_to_surface_distance(np.zeros((4, 2)), v, f)
    with pytest.raises(ValueError, match="faces: vertex indices must lie in"):
        point_to_surface_distance(np.zeros((1, 3)), v, f + 1)
    with pytest.raises(TypeError, match="integer"):
        point_to_surface_distance(np.zeros((1, 3)), v, f.astype(float))
    with pytest.raises(ValueError, match="non-finite"):
        point_to_surface_distance(np.full((1, 3), np.nan), v, f)
    assert point_to_surface_distance(np.zeros((0, 3)), v, f).shape == (0,)


# ----------------------------------------------------------------- the bi-directional metric


def test_unit_sphere_against_radius_1001_gives_1_mm() -> None:
    """Concentric icospheres r = 1 and r = 1.001 of the same tessellation (metres).

    gt → pred: each gt vertex w = 1.001 v lies radially outside the pred vertex v, and w - v
    is in the normal cone of the convex pred mesh at v (every pred point x has v·x <= 1), so
    its distance is exactly 1 mm. pred → gt: v is inside the convex gt mesh; its distance is
    the closed form ``min_f (h_f - n_f·v)``, between 1 mm × (facet-plane offset) and 1 mm.
    """
    pv, pf = icosphere(5, 1.0)
    gv, gf = icosphere(5, 1.001)
    err = bidirectional_surface_error(pv, pf, gv, gf)

    np.testing.assert_allclose(err.gt_to_pred, 1e-3, rtol=1e-9)
    subset = np.arange(0, len(pv), 37)
    np.testing.assert_allclose(
        err.pred_to_gt[subset], convex_interior_distance(pv[subset], gv, gf), atol=1e-13
    )
    # Tessellation bound: facet planes of the r = 1 mesh lie at h >= h_min from the centre.
    h_min = convex_interior_distance(np.zeros((1, 3)), pv, pf)[0]
    assert np.all(err.pred_to_gt >= 1e-3 * h_min - 1e-13)
    assert np.all(err.pred_to_gt <= 1e-3 + 1e-13)
    assert err.mean == pytest.approx(0.5 * (err.pred_to_gt_mean + err.gt_to_pred_mean))
    # pred → gt lies within 1 mm × [h_min, 1], gt → pred is 1 mm: the mean within 0.14 µm.
    assert err.mean_mm == pytest.approx(1.0, abs=0.5 * (1 - h_min))
    assert err.mean_mm == pytest.approx(1.0, abs=1e-3)


def test_coarse_sphere_vertices_against_finer_sphere_surface() -> None:
    """Vertices exactly on r = 1 against a finer r = 1.001 mesh: the exact point-to-surface
    distance is ~1 mm, whereas vertex-to-vertex would give several mm."""
    pv, _ = icosphere(2, 1.0)
    gv, gf = icosphere(5, 1.001)
    d = point_to_surface_distance(pv, gv, gf)
    np.testing.assert_allclose(d, convex_interior_distance(pv, gv, gf), atol=1e-13)
    h_min = convex_interior_distance(np.zeros((1, 3)), gv, gf)[0]  # ≈ 1.001 - 0.24 mm
    assert np.all(d <= 1e-3 + 1e-13)
    assert np.all(d >= h_min - 1.0 - 1e-13)
    assert d.mean() * 1000 == pytest.approx(1.0, abs=0.25)


def test_bidirectional_directions_hand_computed() -> None:
    """gt: unit square at z = 0; pred: a 2 x 1 rectangle covering it (6 vertices, 4 triangles).

    pred → gt: vertices at x = 2 are 1 m away, the other 4 on the square: mean 2/6.
    gt → pred: every gt vertex is on the pred surface: 0. Metric: (1/3 + 0) / 2 = 1/6.
    """
    gv = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    gf = np.array([[0, 1, 2], [0, 2, 3]])
    pv = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], float)
    pf = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    err = bidirectional_surface_error(pv, pf, gv, gf)
    np.testing.assert_allclose(err.pred_to_gt, [0, 0, 1, 0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(err.gt_to_pred, 0.0, atol=1e-15)
    assert err.pred_to_gt_mean == pytest.approx(1 / 3)
    assert err.gt_to_pred_mean == pytest.approx(0.0)
    assert err.mean == pytest.approx(1 / 6)


# ----------------------------------------------------------------------------- alignment


def _transform(
    angle_deg: float, axis: list[float], t: list[float], s: float
) -> SimilarityTransform:
    axis_arr = np.asarray(axis) / np.linalg.norm(axis)
    rot = Rotation.from_rotvec(np.deg2rad(angle_deg) * axis_arr).as_matrix()
    return SimilarityTransform(rotation=rot, translation=np.asarray(t, float), scale=s)


@pytest.mark.parametrize("use_source_faces", [False, True])
def test_icp_recovers_a_known_similarity(use_source_faces: bool) -> None:
    gv, gf = bumpy_mesh()
    truth = _transform(12.0, [0.2, 1.0, -0.4], [0.04, -0.03, 0.02], 1.07)
    source = truth.inverse().apply(gv)
    result = align_icp(
        source, gv, gf, source_faces=gf if use_source_faces else None, tolerance=1e-12
    )
    assert result.converged
    np.testing.assert_allclose(result.transform.rotation, truth.rotation, atol=1e-8)
    np.testing.assert_allclose(result.transform.translation, truth.translation, atol=1e-8)
    assert result.transform.scale == pytest.approx(truth.scale, abs=1e-8)
    assert result.mean_distance < 1e-8


def test_icp_rigid_keeps_the_scale() -> None:
    gv, gf = bumpy_mesh()
    truth = _transform(8.0, [1.0, 0.3, 0.2], [0.01, 0.02, -0.03], 1.0)
    result = align_icp(truth.inverse().apply(gv), gv, gf, with_scale=False, tolerance=1e-12)
    assert result.transform.scale == 1.0
    np.testing.assert_allclose(result.transform.matrix, truth.matrix, atol=1e-8)


@pytest.mark.parametrize("correspondences", ["same_topology", None])
def test_alignment_makes_the_error_invariant_to_a_similarity(correspondences: str | None) -> None:
    """The prediction differs in shape (noise) from the truth; moving, turning and scaling it
    must not change the error after alignment, and an exact similarity copy of the truth
    must score zero."""
    gv, gf = bumpy_mesh()
    pred = gv + 0.004 * np.random.default_rng(5).normal(size=gv.shape)
    moves = [
        _transform(0.0, [0, 0, 1], [0, 0, 0], 1.0),
        _transform(20.0, [0.3, 0.8, -0.5], [0.3, -0.1, 1.2], 0.8),
        _transform(35.0, [-1.0, 0.2, 0.1], [-2.0, 0.5, 0.0], 1.3),
    ]
    errors = [
        surface_error_after_alignment((m.apply(pred), gf), (gv, gf), correspondences) for m in moves
    ]
    # Closed form: exactly invariant. ICP: the noisy prediction's point-to-surface objective
    # has shallow local optima (kinks where closest triangles switch); they differ by well
    # under a micrometre in the metric here (measured 0.4 µm of 2.9 mm).
    rel, atol = (1e-9, 1e-9) if correspondences else (1e-3, 1e-3)
    for e in errors:
        assert e.error.mean == pytest.approx(errors[0].error.mean, rel=rel)
        np.testing.assert_allclose(
            e.aligned_pred_vertices, errors[0].aligned_pred_vertices, atol=atol
        )
    assert 1e-3 < errors[0].error.mean < 5e-3  # noise of 4 mm per axis, i.e. a real error

    # ICP reports the metric it reached: the bi-directional error of the aligned mesh, each
    # direction measured in the ground truth's frame (here at a scale of 1/1.3).
    icp = align_icp(moves[2].apply(pred), gv, gf, source_faces=gf)
    reached = bidirectional_surface_error(icp.transform.apply(moves[2].apply(pred)), gf, gv, gf)
    assert icp.mean_distance == pytest.approx(reached.mean, rel=1e-12)

    exact_copy = surface_error_after_alignment((moves[2].apply(gv), gf), (gv, gf), correspondences)
    assert exact_copy.error.mean < 1e-9
    np.testing.assert_allclose(exact_copy.transform.matrix, moves[2].inverse().matrix, atol=1e-7)


def test_alignment_method_and_trimesh_inputs() -> None:
    gv, gf = bumpy_mesh(2)
    pred = trimesh.Trimesh(gv * 1.1, gf, process=False)
    gt = trimesh.Trimesh(gv, gf, process=False)
    pairs = np.stack([np.arange(0, len(gv), 5)] * 2, axis=1)
    a = surface_error_after_alignment(pred, gt, pairs)
    b = surface_error_after_alignment(pred, gt, pairs, refine=True)
    c = surface_error_after_alignment(pred, gt)
    assert (a.method, b.method, c.method) == ("correspondences", "correspondences+icp", "icp")
    for r in (a, b, c):
        assert r.transform.scale == pytest.approx(1 / 1.1, abs=1e-8)
        assert r.error.mean < 1e-8
    unscaled = surface_error_after_alignment(pred, gt, "same_topology", with_scale=False)
    assert unscaled.transform.scale == 1.0 and unscaled.error.mean > 1e-3
    with pytest.raises(ValueError, match="vertex counts differ"):
        surface_error_after_alignment((gv[:-1], gf[:1]), gt, "same_topology")
