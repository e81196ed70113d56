"""Consensus shape (Sec. B.3.3): data term, silhouette rays and their unposing, the sparse
regularisers, and small end-to-end fits on silhouettes rendered from known shapes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from monoavatar.body import REGIONS, BodyModel
from monoavatar.core.camera import PinholeCamera, plucker, point_line_distance
from monoavatar.fit.laplacian import (
    edge_laplacian,
    mesh_edges,
    symmetry_operators,
    uniform_laplacian,
)
from monoavatar.fit.rays import (
    CanonicalRays,
    frame_shift,
    silhouette_boundary,
    silhouette_correspondences,
)
from monoavatar.fit.shape import (
    ShapeFitError,
    ShapeSettings,
    fit_consensus_shape,
    geman_mcclure,
)
from monoavatar.fit.shape_solver import line_data_energy
from monoavatar.render import rasterize, vertex_normals
from tests.gradcheck import directional_gradcheck

# -- data term ---------------------------------------------------------------------------------


def test_geman_mcclure_values():
    r2 = torch.tensor([0.0, 1e-6, 1.0, 1e6], dtype=torch.float64)
    rho = geman_mcclure(r2, sigma=0.1)
    assert rho[0] == 0
    assert rho[1] == pytest.approx(1e-6, rel=1e-3)  # ≈ r² for small residuals
    assert (rho <= 0.01 + 1e-12).all()  # bounded by σ²
    assert rho[3] == pytest.approx(0.01, rel=1e-6)


def test_line_data_energy_matches_direct_point_to_line_distance():
    gen = torch.Generator().manual_seed(0)
    o = torch.randn(50, 3, generator=gen, dtype=torch.float64)
    d = torch.randn(50, 3, generator=gen, dtype=torch.float64)
    x = torch.randn(50, 3, generator=gen, dtype=torch.float64)
    m, n = plucker(o, d)
    rel = x - o
    direct = (rel - (rel * n).sum(-1, keepdim=True) * n).norm(dim=-1)
    assert torch.allclose(point_line_distance(x, m, n), direct, atol=1e-12)
    sigma = 0.7
    expected = (sigma**2 * direct**2 / (sigma**2 + direct**2)).sum()
    assert line_data_energy(x, m, n, sigma).item() == pytest.approx(expected.item(), rel=1e-12)
    rays = CanonicalRays(
        vertex_ids=np.arange(50),
        moment=m.numpy(),
        direction=n.numpy(),
        plane_normal=np.zeros((50, 3)),
        frame=np.zeros(50, np.int64),
        image_distance=np.zeros(50),
    )
    assert np.allclose(rays.distances(x.numpy()), direct.numpy(), atol=1e-12)


def test_line_data_energy_gradient():
    gen = torch.Generator().manual_seed(1)
    m, n = plucker(
        torch.randn(20, 3, generator=gen, dtype=torch.float64),
        torch.randn(20, 3, generator=gen, dtype=torch.float64),
    )
    x = torch.randn(20, 3, generator=gen, dtype=torch.float64)
    fd, ad = directional_gradcheck(lambda v: line_data_energy(v, m, n, 0.5), x)
    assert fd == pytest.approx(ad, rel=1e-6, abs=1e-9)


# -- silhouette boundary and sparse operators ------------------------------------------------------


def test_silhouette_boundary_of_a_disc_is_subpixel_and_outward():
    h = w = 120
    cx, cy, radius = 60.3, 58.7, 31.4
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    mask = (cols - cx) ** 2 + (rows - cy) ** 2 < radius**2
    s = silhouette_boundary(mask, 200)
    assert 150 <= len(s) <= 200
    rel = s.points - np.array([cx, cy])
    r = np.linalg.norm(rel, axis=1)
    assert abs(r.mean() - radius) < 0.1  # sub-pixel edge, unbiased on average
    assert np.abs(r - radius).max() < 0.5
    assert (np.einsum("nc,nc->n", s.normals, rel / r[:, None]) > 0.97).all()
    assert len(silhouette_boundary(np.zeros((10, 10), bool), 50)) == 0


def test_silhouette_boundary_leaves_out_the_image_border():
    mask = np.zeros((40, 30), bool)
    mask[20:, 10:20] = True  # a person cut off by the bottom of the image
    s = silhouette_boundary(mask, 1000)
    assert len(s) > 0
    assert s.points[:, 1].max() < 39.0
    # left and right edges at x = 10 and x = 20, the top edge at y = 20
    on_side = np.abs(s.normals[:, 0]) > 0.9
    assert np.allclose(np.sort(np.unique(np.round(s.points[on_side, 0]))), [10.0, 20.0])


def test_silhouette_boundary_rejects_bad_shape():
    with pytest.raises(ValueError, match="H, W"):
        silhouette_boundary(np.zeros((2, 3, 4), bool), 10)


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A flat n × n vertex grid in the z = 0 plane and its triangles."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    verts = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d.ravel()], 1), np.stack([a, d.ravel(), c], 1)])
    return verts, faces


def test_uniform_laplacian_is_zero_on_linear_fields_inside():
    verts, faces = _grid(6)
    L = uniform_laplacian(faces, len(verts))
    assert np.allclose(np.asarray(L.sum(axis=1)).ravel(), 0)
    field = 0.3 * verts[:, 0] - 1.2 * verts[:, 1] + 2.0
    interior = (verts[:, 0] > 0) & (verts[:, 0] < 5) & (verts[:, 1] > 0) & (verts[:, 1] < 5)
    assert np.allclose((L @ field)[interior], 0, atol=1e-12)


def test_edge_laplacian_quadratic_form_sums_over_edges():
    verts, faces = _grid(4)
    weights = np.linspace(0.5, 2.0, len(verts))
    K = edge_laplacian(faces, len(verts), weights)
    x = np.random.default_rng(0).normal(size=len(verts))
    e = mesh_edges(faces)
    tau = 0.5 * (weights[e[:, 0]] + weights[e[:, 1]])
    assert x @ K @ x == pytest.approx(np.sum(tau * (x[e[:, 0]] - x[e[:, 1]]) ** 2))


def test_symmetry_operators_vanish_on_mirrored_offsets():
    mirror = np.array([1, 0, 2])  # vertices 0 and 1 are a pair, 2 lies on the plane
    sx, syz = symmetry_operators(mirror)
    d = np.array([[0.3, 0.1, -0.2], [-0.3, 0.1, -0.2], [0.0, 0.5, 0.4]])
    assert np.allclose(sx @ d[:, 0], 0) and np.allclose(syz @ d[:, 1], 0)
    assert np.allclose(syz @ d[:, 2], 0)
    assert not np.allclose(sx @ np.array([0.3, 0.3, 0.0]), 0)
    with pytest.raises(ValueError):
        symmetry_operators(np.array([0, 5]))


def test_frame_shift_recovers_an_image_plane_translation():
    rng = np.random.default_rng(2)
    centre = np.array([0.0, 0.0, 3.0])
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    points = rng.normal(size=(200, 3)) * 0.3
    # planes through the camera centre and the points, normals ⟂ line of sight
    sight = points - centre
    normals = np.cross(sight, rng.normal(size=(200, 3)))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    true = np.array([0.02, -0.01, 0.0])
    shift = frame_shift(points - true, normals, centre, axes, sigma=0.05)
    assert np.allclose(shift, true, atol=1e-9)


# -- rendered scenes -------------------------------------------------------------------------------


def _camera(size: int = 360) -> PinholeCamera:
    return PinholeCamera.look_at(
        eye=np.array([0.0, 0.0, 3.2]),
        target=np.array([0.0, -0.05, 0.0]),
        up=np.array([0.0, 1.0, 0.0]),
        focal_px=0.5 * size * 3.2 / 1.0,
        width=size,
        height=size,
    )


def _turn_poses(body: BodyModel, count: int, extra: bool = False) -> torch.Tensor:
    pose = torch.zeros(count, body.num_joints, 3)
    pose[:, 0, 1] = torch.arange(count) * (2 * np.pi / count)  # a turn about the vertical axis
    if extra:
        pose[:, body.joint_index("elbow_l"), 1] = 0.4
        pose[:, body.joint_index("knee_r"), 0] = 0.3
        pose[:, body.joint_index("shoulder_r"), 2] = -0.2
    return pose


def _render(body: BodyModel, canonical: torch.Tensor, pose: torch.Tensor, camera: PinholeCamera):
    """Masks (F, H, W) of a canonical mesh (V, 3) posed by ``pose`` (F, J, 3), and the
    transforms used."""
    shape = body.default_shape(1)
    rest, _ = body.rest_shape(shape)
    offsets = (canonical - rest[0]).to(body.dtype)
    with torch.no_grad():
        out = body(shape=shape.expand(len(pose), -1), pose=pose, offsets=offsets)
    masks = np.stack([rasterize(v, body.faces, camera).mask.numpy() for v in out.vertices])
    return masks, out.transforms


def test_unposed_rays_touch_the_true_canonical_surface(anny32):
    body = anny32
    camera = _camera()
    with torch.no_grad():
        canonical = body.rest_shape(body.default_shape(1))[0][0]
    pose = _turn_poses(body, 3, extra=True)
    masks, transforms = _render(body, canonical, pose, camera)
    samples = [silhouette_boundary(m, 250) for m in masks]
    rays, shifts = silhouette_correspondences(body, canonical, transforms, samples, camera)
    assert len(rays) > 500 and np.all(shifts == 0)
    v = canonical.double().numpy()
    plane = np.abs(rays.plane_distances(v))
    line = rays.distances(v)
    # 1 px ≈ 2 mm here: the unposed silhouette planes touch their vertices within a pixel,
    # the lines within a vertex spacing (the tangential part of the point-to-line distance)
    assert np.median(plane) < 1.5e-3 and np.mean(plane < 5e-3) > 0.9
    assert np.median(line) < 6e-3
    # matched in threads, chunk by chunk: the same rays in the same order
    threaded, _ = silhouette_correspondences(body, canonical, transforms, samples, camera,
                                             chunk=2, workers=3)  # fmt: skip
    for name in ("vertex_ids", "moment", "direction", "plane_normal", "frame"):
        np.testing.assert_array_equal(getattr(threaded, name), getattr(rays, name))
    # a ray unposed with the wrong frame's pose misses by centimetres
    wrong, _ = silhouette_correspondences(body, canonical, transforms[[1, 2, 0]], samples, camera)
    assert np.median(np.abs(wrong.plane_distances(v))) > 5 * np.median(plane)


@pytest.fixture(scope="module")
def bulge_scene(anny32):
    """Silhouettes of 8 frames of a turn of Anny's average body with a smooth 2.5 cm bulge on
    the belly, symmetric about the body's mid-plane."""
    body = anny32
    camera = _camera(300)
    with torch.no_grad():
        rest = body.rest_shape(body.default_shape(1))[0][0]
    normals = vertex_normals(rest, body.faces)
    centre = torch.tensor([0.0, 0.05, 0.15])
    weight = torch.exp(-((rest - centre) ** 2).sum(-1) / (2 * 0.09**2))
    weight = weight * (normals[:, 2] > 0.3) * (body.regions == REGIONS.index("torso"))
    truth = rest + 0.025 * weight[:, None] * normals
    pose = _turn_poses(body, 8)
    masks, _ = _render(body, truth, pose, camera)
    return body, camera, masks, pose, truth, weight > 0.5


def _fit(scene, **kw):
    body, camera, masks, pose, _, _ = scene
    settings = ShapeSettings(rounds=3, rays_per_frame=250, **kw)
    return fit_consensus_shape(
        body, masks, camera, pose, torch.zeros(len(pose), 3), body.default_shape(1)[0], settings
    )


def test_offsets_recover_a_bulge_that_shape_parameters_cannot(bulge_scene):
    *_, truth, bulge = bulge_scene
    threads = torch.get_num_threads()
    with_offsets = _fit(bulge_scene)
    assert torch.get_num_threads() == threads  # the fit's thread setting is undone
    shape_only = _fit(bulge_scene, fit_offsets=False)
    err = (with_offsets.vertices - truth).norm(dim=-1)
    err0 = (shape_only.vertices - truth).norm(dim=-1)
    assert err[bulge].mean() < 0.5 * err0[bulge].mean()
    assert err[bulge].mean() < 0.008
    assert with_offsets.offsets.shape == truth.shape
    assert len(with_offsets.diagnostics) == 3
    assert with_offsets.diagnostics[-1].median_distance_mm < 2.0


def test_a_symmetric_truth_stays_symmetric(bulge_scene):
    body = bulge_scene[0]
    result = _fit(bulge_scene)
    v = result.vertices.double()
    flip = torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64)
    asym = (v * flip - v[body.mirror]).norm(dim=-1)
    truth = bulge_scene[4].double()
    # the truth is symmetric up to Anny's own mirror-pair accuracy (≈ 8 µm at worst)
    assert (truth * flip - truth[body.mirror]).norm(dim=-1).max() < 2e-5
    assert asym.mean() < 3e-4  # without the symmetry term: ≈ 1 mm


def test_offsets_init_is_kept_where_the_silhouettes_say_nothing(bulge_scene):
    """Seen from the front only, the belly bulge lies inside the outline: from D = 0 the fit
    cannot find it, from offsets_init = the truth (a learned prediction) it keeps it, and the
    outline still holds the avatar where it is seen."""
    body, camera, masks, pose, truth, bulge = bulge_scene
    with torch.no_grad():
        rest = body.rest_shape(body.default_shape(1))[0][0]

    def fit(init):
        return fit_consensus_shape(body, masks[:1], camera, pose[:1], torch.zeros(1, 3),
                                   body.default_shape(1)[0], ShapeSettings(rounds=3),
                                   offsets_init=init)  # fmt: skip

    err_zero = (fit(None).vertices - truth).norm(dim=-1)
    err_init = (fit(truth - rest).vertices - truth).norm(dim=-1)
    assert err_zero[bulge].mean() > 0.015  # the bulge is 2.5 cm: not found
    assert err_init[bulge].mean() < 0.004  # kept
    assert err_init.mean() < 0.004
    with pytest.raises(ShapeFitError, match="offsets_init must have shape"):
        fit(torch.zeros(5, 3))


def test_shoes_are_taken_up_by_the_feet(anny32):
    """A shoe is real displacement around the foot (1.2 cm along the normals here): the
    feet's rigidity term keeps a foot whole but must not keep the shoe out of the avatar
    (with the earlier feet weight, 0.2, the feet moved out by a median 1.2 mm)."""
    body = anny32
    camera = _camera(300)
    with torch.no_grad():
        rest = body.rest_shape(body.default_shape(1))[0][0]
    normals = vertex_normals(rest, body.faces)
    foot = body.regions == REGIONS.index("feet")
    truth = rest + 0.012 * foot[:, None] * normals
    pose = _turn_poses(body, 8)
    masks, _ = _render(body, truth, pose, camera)
    result = _fit((body, camera, masks, pose, truth, foot))
    outward = ((result.vertices - rest) * normals).sum(-1)
    assert outward[foot].median() > 0.004  # a third of the shoe at least (1.2 mm before)
    assert (result.vertices - truth).norm(dim=-1)[~foot].mean() < 0.004  # the rest stays put


def test_fit_validates_inputs(anny32):
    camera = _camera(64)
    masks = np.zeros((2, 64, 64), bool)
    pose = torch.zeros(2, anny32.num_joints, 3)
    with pytest.raises(ShapeFitError, match="poses"):
        fit_consensus_shape(
            anny32, masks, camera, pose[:1], torch.zeros(2, 3), anny32.default_shape(1)[0]
        )
    with pytest.raises(ShapeFitError, match="camera"):
        fit_consensus_shape(
            anny32,
            np.zeros((2, 32, 64), bool),
            camera,
            pose,
            torch.zeros(2, 3),
            anny32.default_shape(1)[0],
        )
    with pytest.raises(ShapeFitError, match="no silhouette"):
        fit_consensus_shape(
            anny32, masks, camera, pose, torch.zeros(2, 3), anny32.default_shape(1)[0]
        )
    with pytest.raises(ShapeFitError, match="unknown region"):
        ShapeSettings(rigid_regions=(("elbows", 1.0),))
    with pytest.raises(ShapeFitError, match="data_term"):
        ShapeSettings(data_term="point")  # type: ignore[arg-type]
    with pytest.raises(ShapeFitError, match="face_max_turn"):
        ShapeSettings(face_max_turn=0.0)
    with pytest.raises(ShapeFitError, match="w_face"):
        ShapeSettings(w_face=-1.0)
    from monoavatar.body.face_map import load_face_map

    with pytest.raises(ShapeFitError, match="face: expected"):
        fit_consensus_shape(anny32, masks, camera, pose, torch.zeros(2, 3),
                            anny32.default_shape(1)[0], ShapeSettings(w_face=1.0),
                            face=np.zeros((2, 68, 3)), face_map=load_face_map(anny32))  # fmt: skip


@pytest.mark.parametrize("data_term", ["plane", "line"])
def test_sparse_offset_solve_minimises_the_reference_energy(data_term):
    """The fast path (per-vertex blocks + sparse regularisers + CG) against the energy written
    directly in torch: its gradient vanishes at the solution."""
    from monoavatar.fit.shape_solver import Problem, offset_step, projectors

    verts, faces = _grid(7)
    V = len(verts)
    rng = np.random.default_rng(3)
    mirror = np.arange(V).reshape(7, 7)[:, ::-1].ravel()  # mirror x ↔ 6 − x
    rest = verts * 0.01 - np.array([0.03, 0.03, 0.0])  # centred on x = 0, metres
    n_rays = 120
    ids = rng.integers(0, V, n_rays)
    plane = rng.normal(size=(n_rays, 3))
    plane /= np.linalg.norm(plane, axis=1, keepdims=True)
    direction = np.cross(plane, rng.normal(size=(n_rays, 3)))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    point = rest[ids] + rng.normal(scale=0.004, size=(n_rays, 3))
    rays = CanonicalRays(
        ids,
        np.cross(point, direction),
        direction,
        plane,
        np.zeros(n_rays, np.int64),
        np.zeros(n_rays),
    )
    tau_lp, tau_var = rng.uniform(0.5, 2, V), rng.uniform(0.5, 2, V)
    rigid = rng.uniform(0, 1, V)
    sx, syz = symmetry_operators(mirror)
    problem = Problem(
        body=None,  # type: ignore[arg-type]  (not used by the offset step)
        laplacian=uniform_laplacian(faces, V),
        sym_x=sx,
        sym_yz=syz,
        tau_lp=tau_lp,
        tau_var=tau_var,
        rigidity=3.0 * edge_laplacian(faces, V, rigid),
        num_vertices=V,
    )
    sigma, scale, weights = 0.01, 0.7, (2.0, 0.3, 1.5)
    start = rng.normal(scale=0.002, size=(V, 3))
    reference = rng.normal(scale=0.001, size=(V, 3))
    proj = projectors(rays, data_term)
    anchor = rays.closest_points()
    solved = offset_step(
        problem, rest, start, reference, rays, proj, anchor, sigma, scale, weights, None, 1
    )
    # robust weights of the IRLS step, taken at the start
    diff0 = rest[ids] + start[ids] - anchor
    r2 = np.einsum("ni,nij,nj->n", diff0, proj, diff0)
    w = torch.as_tensor(scale * (sigma**2 / (sigma**2 + r2)) ** 2)
    L = torch.as_tensor(problem.laplacian.toarray())
    K = torch.as_tensor(problem.rigidity.toarray())
    Sx, Syz = torch.as_tensor(sx.toarray()), torch.as_tensor(syz.toarray())
    P, a = torch.as_tensor(proj), torch.as_tensor(anchor)
    rest_t, ref = torch.as_tensor(rest), torch.as_tensor(reference)

    def energy(d: torch.Tensor) -> torch.Tensor:
        diff = rest_t[ids] + d[ids] - a
        data = (w * torch.einsum("ni,nij,nj->n", diff, P, diff)).sum()
        lap = (torch.as_tensor(tau_lp)[:, None] * (L @ (d - ref)) ** 2).sum()
        var = (torch.as_tensor(tau_var)[:, None] * (d - ref) ** 2).sum()
        sym = (Sx @ d[:, 0]).square().sum() + (Syz @ d[:, 1:]).square().sum()
        rig = torch.einsum("vc,vw,wc->", d - ref, K, d - ref)
        return data + weights[0] * lap + weights[1] * var + weights[2] * sym + rig

    def grad(d: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(d).requires_grad_(True)
        (g,) = torch.autograd.grad(energy(x), x)
        return g.numpy()

    assert np.linalg.norm(grad(solved)) < 1e-3 * np.linalg.norm(grad(start))


def test_the_face_term_moves_the_face_to_its_landmarks(anny32):
    """The truth's face sits 6 mm lower than the body model's; the outline shows about half
    of that (chin, cheeks). Given the truth's face-mesh landmarks in the frames that see the
    face, the fit with E_face (Eq. C.7) puts the face's points where they are (exact poses:
    no translation correction, which would trade part of the face's shift for the frame's)."""
    from monoavatar.body.face_map import load_face_map

    body = anny32
    camera = _camera(300)
    face_map = load_face_map(body)
    with torch.no_grad():
        rest = body.rest_shape(body.default_shape(1))[0][0]
    face = body.regions == REGIONS.index("face")
    truth = rest.clone()
    truth[face, 1] -= 0.006
    pose = _turn_poses(body, 8)
    masks, transforms = _render(body, truth, pose, camera)
    with torch.no_grad():
        shape = body.default_shape(1)
        posed = body(shape=shape.expand(len(pose), -1), pose=pose, offsets=truth - rest).vertices
        pix, _ = camera.project(face_map.points(posed.double(), body.faces))
    detected = np.concatenate([pix.numpy(), np.ones((len(pose), 468, 1))], axis=-1)
    yaw = pose[:, 0, 1].numpy()
    detected[np.cos(yaw) < 0.5] = np.nan  # the face mesh finds faces within 60° of frontal
    target = face_map.points(truth.double(), body.faces)

    def error(**kw):
        fit = fit_consensus_shape(body, masks, camera, pose, torch.zeros(len(pose), 3),
                                  body.default_shape(1)[0],
                                  ShapeSettings(rounds=3, rays_per_frame=250,
                                                refine_translations=False, **kw),
                                  face=detected, face_map=face_map)  # fmt: skip
        points = face_map.points(fit.vertices.double(), body.faces)
        return (points - target).norm(dim=-1).mean().item(), fit.diagnostics[-1]

    without, diag0 = error()
    with_face, diag = error(w_face=1.0)
    assert diag0.face_rays == 0 and diag0.face_median_mm is None
    assert diag.face_rays > 900  # three frames see the face (fewer landmarks at 45°)
    assert without > 0.002  # measured 3.0 mm
    assert with_face < 0.3 * without and with_face < 0.001  # measured 0.6 mm
    assert diag.face_median_mm < 0.5
