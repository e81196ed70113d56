"""Rasteriser: analytic scenes, an independent ray caster, and the slow reference."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch
import trimesh
from render_scenes import concatenate, look_at_camera, raycast

from monoavatar.core.camera import PinholeCamera
from monoavatar.render import Fragments, RasterSettings, rasterize
from monoavatar.render.raster import (
    _edge_function,
    _rasterize_reference,
    _setup_faces,
    _to_camera_and_pixels,
)

IDENTITY = np.eye(3)


def camera_at_origin(K: np.ndarray, width: int, height: int) -> PinholeCamera:
    """World frame = camera frame."""
    return PinholeCamera(K=K, R=IDENTITY, t=np.zeros(3), width=width, height=height)


def centres_inside(lo: float, hi: float, n: int) -> np.ndarray:
    """(n,) bool: which pixel centres i + 0.5 lie in [lo, hi]."""
    c = np.arange(n) + 0.5
    return (c >= lo) & (c <= hi)


def quad(x0: float, x1: float, y0: float, y1: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def assert_agrees_with_reference(
    vertices: np.ndarray,
    faces: np.ndarray,
    camera: PinholeCamera,
    settings: RasterSettings | None = None,
) -> Fragments:
    fast = rasterize(vertices, faces, camera, settings)
    ref = _rasterize_reference(vertices, faces, camera, settings)
    differ = fast.face_id != ref.face_id
    # Only exact depth ties (e.g. a centre on a shared edge) may resolve differently.
    tie = (fast.depth - ref.depth).abs() <= 1e-6 * ref.depth.clamp_max(1e6)
    assert bool((~differ | tie).all()), f"{int((differ & ~tie).sum())} pixels disagree"
    assert int(differ.sum()) <= max(2, differ.numel() // 200)
    same = ~differ & fast.mask
    torch.testing.assert_close(fast.bary[same], ref.bary[same], atol=1e-5, rtol=0)
    torch.testing.assert_close(fast.depth[same], ref.depth[same], rtol=1e-6, atol=0)
    return fast


# -- analytic scenes --------------------------------------------------------------------------


def test_fronto_parallel_square_exact_coverage_and_depth() -> None:
    K = np.array([[90.0, 0.0, 30.3], [0.0, 110.0, 25.1], [0.0, 0.0, 1.0]])
    camera = camera_at_origin(K, width=64, height=48)
    z = 2.0
    v, f = quad(-0.41, 0.37, -0.23, 0.29, z)
    frags = rasterize(v, f, camera)

    u_lo, u_hi = 90.0 * -0.41 / z + 30.3, 90.0 * 0.37 / z + 30.3
    v_lo, v_hi = 110.0 * -0.23 / z + 25.1, 110.0 * 0.29 / z + 25.1
    expected = centres_inside(v_lo, v_hi, 48)[:, None] & centres_inside(u_lo, u_hi, 64)[None, :]
    assert expected.sum() > 500
    np.testing.assert_array_equal(frags.mask.numpy(), expected)
    np.testing.assert_array_equal(frags.depth.numpy()[expected], np.float32(z))
    assert np.isinf(frags.depth.numpy()[~expected]).all()
    np.testing.assert_allclose(frags.bary.sum(-1).numpy()[expected], 1.0, atol=1e-6)
    assert (frags.bary.numpy()[~expected] == 0).all()
    assert set(np.unique(frags.face_id.numpy())) == {-1, 0, 1}


def test_cube_front_face_depth_and_coverage() -> None:
    camera = PinholeCamera.from_focal(50.0, 64, 64)
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    cube.apply_translation([0.1, -0.05, 3.0])
    frags = rasterize(cube.vertices, cube.faces, camera)
    # Front face z = 2.5 spans x in [-0.4, 0.6], y in [-0.55, 0.45]: u in [24, 44], v in [21, 41].
    expected = centres_inside(21.0, 41.0, 64)[:, None] & centres_inside(24.0, 44.0, 64)[None, :]
    np.testing.assert_array_equal(frags.mask.numpy(), expected)
    np.testing.assert_allclose(frags.depth.numpy()[expected], 2.5, rtol=1e-7)
    front = np.flatnonzero(np.isclose(cube.triangles_center[:, 2], 2.5))
    assert set(np.unique(frags.face_id.numpy()[expected])) <= set(front.tolist())


def test_large_triangles_covering_the_image() -> None:
    """Faces far larger than any bucket (evaluated in slabs) against the reference."""
    camera = PinholeCamera.from_focal(120.0, 300, 200)
    v, f = quad(-5.0, 5.0, -4.0, 4.0, 2.0)
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    sphere.apply_translation([0.2, 0.1, 1.5])
    vertices = np.concatenate([v, sphere.vertices])
    faces = np.concatenate([f, sphere.faces + 4])
    frags = assert_agrees_with_reference(vertices, faces, camera)
    assert bool(frags.mask.all())
    background = frags.face_id < 2
    np.testing.assert_allclose(frags.depth.numpy()[background.numpy()], 2.0, rtol=1e-7)


# -- independent ray caster ---------------------------------------------------------------


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return trimesh.transformations.quaternion_matrix(q / np.linalg.norm(q))


def sphere_and_occluder() -> trimesh.Trimesh:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    sphere.apply_translation([0.0, 0.0, 3.0])
    box = trimesh.creation.box(extents=(0.4, 0.4, 0.1))
    box.apply_transform(trimesh.transformations.rotation_matrix(0.5, [0.3, 1.0, 0.2]))
    box.apply_translation([0.25, 0.1, 2.3])
    return concatenate([sphere, box])


def torus_and_capsules() -> trimesh.Trimesh:
    rng = np.random.default_rng(7)
    torus = trimesh.creation.torus(major_radius=0.45, minor_radius=0.15)
    torus.apply_transform(random_rotation(rng))
    torus.apply_translation([0.0, 0.0, 2.6])
    parts = [torus]
    for _ in range(4):
        capsule = trimesh.creation.capsule(height=0.5, radius=0.08, count=[24, 12])
        capsule.apply_transform(random_rotation(rng))
        capsule.apply_translation(rng.uniform([-0.5, -0.5, 2.2], [0.5, 0.5, 2.8]))
        parts.append(capsule)
    return concatenate(parts)


@pytest.mark.parametrize("scene", [sphere_and_occluder, torus_and_capsules])
@pytest.mark.parametrize("oblique", [False, True])
def test_agrees_with_ray_casting(scene: Callable[[], trimesh.Trimesh], oblique: bool) -> None:
    mesh = scene()
    target = np.array([0.0, 0.0, 2.7])
    eye = np.array([1.2, -0.7, 0.6]) if oblique else np.zeros(3)
    camera = look_at_camera(eye, target, focal=260.0, width=200, height=200)
    frags = rasterize(torch.as_tensor(mesh.vertices, dtype=torch.float32), mesh.faces, camera)
    ray_face, ray_depth = raycast(mesh, camera)

    ours = frags.mask.numpy()
    hit = ray_face >= 0
    assert 0.1 < hit.mean() < 0.9
    assert (ours == hit).mean() >= 0.995
    both = ours & hit
    depth_ok = np.abs(frags.depth.numpy()[both] - ray_depth[both]) <= 1e-5 * ray_depth[both]
    assert depth_ok.mean() >= 0.995
    # The same face is hit except where a ray grazes an edge.
    assert (frags.face_id.numpy()[both] == ray_face[both]).mean() >= 0.99


# -- fast path == slow reference -----------------------------------------------------------


def test_matches_reference_on_triangle_soup() -> None:
    """Overlapping and interpenetrating triangles of all sizes and both windings."""
    rng = np.random.default_rng(0)
    centres = rng.uniform([-1.0, -1.0, 2.0], [1.0, 1.0, 4.0], size=(80, 3))
    scale = rng.uniform(0.05, 0.8, size=(80, 1, 1))
    vertices = (centres[:, None, :] + scale * rng.normal(size=(80, 3, 3))).reshape(-1, 3)
    faces = np.arange(240).reshape(80, 3)
    camera = PinholeCamera.from_focal(30.0, 48, 40)
    frags = assert_agrees_with_reference(vertices, faces, camera)
    assert len(np.unique(frags.face_id.numpy())) > 40


@pytest.mark.parametrize("cull", [False, True])
def test_matches_reference_on_meshes(cull: bool) -> None:
    mesh = sphere_and_occluder()
    camera = look_at_camera(np.array([0.3, 0.2, 0.0]), np.array([0.0, 0.0, 3.0]), 90.0, 48, 40)
    settings = RasterSettings(cull_backfaces=cull)
    assert_agrees_with_reference(mesh.vertices, mesh.faces, camera, settings)


def fan_mesh(
    rng: np.random.Generator, hub: np.ndarray, spokes: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fan of up to ``spokes`` triangles around ``hub`` (pixel coordinates) whose spokes pass,
    up to rounding, through pixel centres. Returns vertices (S + 1, 2), faces (S, 3) and the
    (S, 2) centres that lie on the S spokes; spoke i ends at vertex i + 1."""
    angles = rng.uniform(0.0, 2.0 * np.pi, spokes)
    radius = rng.uniform(6.0, 12.0, (spokes, 1))
    centres = np.floor(hub + radius * np.stack([np.cos(angles), np.sin(angles)], 1)) + 0.5
    centres = np.unique(centres, axis=0)
    spokes = len(centres)
    direction = centres - hub
    centres = centres[np.argsort(np.arctan2(direction[:, 1], direction[:, 0]))]
    outer = hub + rng.uniform(1.3, 2.0, (spokes, 1)) * (centres - hub)
    k = np.arange(spokes)
    faces = np.stack([np.zeros(spokes, dtype=np.int64), k + 1, (k + 1) % spokes + 1], 1)
    return np.concatenate([hub[None], outer]), faces, centres


# f = 1, z = 1, no principal point: pixel coordinates equal world x, y exactly.
PIXEL_CAMERA = PinholeCamera(K=np.eye(3), R=IDENTITY, t=np.zeros(3), width=400, height=400)


@pytest.mark.parametrize("shared", [True, False])
def test_watertight_on_edges_through_pixel_centres(shared: bool) -> None:
    """Pixel centres on edges shared by two faces are covered by one of them, never by neither
    — also when the faces do not share vertex indices (as at UV seams)."""
    rng = np.random.default_rng(3)
    for _ in range(2):
        verts: list[np.ndarray] = []
        faces: list[np.ndarray] = []
        centres: list[np.ndarray] = []
        offset = 0
        for hub in np.stack(np.meshgrid(np.arange(10), np.arange(10)), -1).reshape(-1, 2):
            v, f, c = fan_mesh(rng, 20.0 + 40.0 * hub + rng.uniform(0.0, 1.0, 2), 24)
            faces.append(f + offset)
            verts.append(v)
            offset += len(v)
            centres.append(c)
        xy, tri = np.concatenate(verts), np.concatenate(faces)
        if not shared:
            xy, tri = xy[tri].reshape(-1, 2), np.arange(3 * len(tri)).reshape(-1, 3)
        vertices = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        mask = rasterize(vertices, tri, PIXEL_CAMERA).mask.numpy()
        on_edges = np.concatenate(centres).astype(int)
        assert mask[on_edges[:, 1], on_edges[:, 0]].all(), "a centre on a shared edge was missed"


def test_shared_edges_have_exactly_opposite_edge_functions() -> None:
    """The mechanism behind watertightness: at centres (up to rounding) on a shared edge, the
    two faces' edge functions are exact negatives, whatever the faces' corner order."""
    rng = np.random.default_rng(5)
    xy, faces, centres = fan_mesh(rng, np.array([200.3, 199.7]), 24)
    spokes = len(faces)
    # Start each face at a random corner (same winding).
    faces = np.stack(
        [np.roll(f, int(r)) for f, r in zip(faces, rng.integers(0, 3, spokes), strict=True)]
    )
    vertices = np.concatenate([xy, np.ones((spokes + 1, 1))], axis=1)
    pz = _to_camera_and_pixels(vertices, PIXEL_CAMERA)
    setup, _ = _setup_faces(pz, faces, 400, 400, RasterSettings())
    row_of_face = np.argsort(setup.face)
    assert np.array_equal(setup.face[row_of_face], np.arange(spokes))

    def edge_value(face: int, a: int, b: int, centre: np.ndarray) -> float:
        k = 3 - int(np.flatnonzero(faces[face] == a)[0]) - int(np.flatnonzero(faces[face] == b)[0])
        rows = row_of_face[[face]]
        return float(_edge_function(setup, k, rows, centre[:1], centre[1:])[0])

    for i in range(spokes):  # spoke to vertex i + 1 is shared by faces i and i - 1
        first = edge_value(i, 0, i + 1, centres[i])
        second = edge_value((i - 1) % spokes, 0, i + 1, centres[i])
        assert first == -second
        assert abs(first) < 1e-9  # the centre does lie on the edge


def test_backface_culling_convention() -> None:
    """Outward-wound sphere: culling back faces changes nothing; inward-wound sphere: culling
    leaves the far (inner) side."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    sphere.apply_translation([0.0, 0.0, 3.0])
    camera = PinholeCamera.from_focal(60.0, 40, 40)
    cull = RasterSettings(cull_backfaces=True)
    plain = rasterize(sphere.vertices, sphere.faces, camera)
    culled = rasterize(sphere.vertices, sphere.faces, camera, cull)
    assert torch.equal(plain.face_id, culled.face_id)
    inner = rasterize(sphere.vertices, sphere.faces[:, ::-1], camera, cull)
    assert bool(inner.mask.any())
    assert bool((inner.depth[inner.mask] >= plain.depth[inner.mask]).all())
    assert float(inner.depth[inner.mask].median()) > 3.2  # far side of the sphere


def test_tensor_and_array_inputs_agree() -> None:
    mesh = sphere_and_occluder()
    camera = PinholeCamera.from_focal(80.0, 32, 32)
    a = rasterize(mesh.vertices, mesh.faces, camera)
    b = rasterize(torch.as_tensor(mesh.vertices), torch.as_tensor(mesh.faces), camera)
    assert torch.equal(a.face_id, b.face_id)
    assert a.face_id.dtype == torch.int64 and a.bary.dtype == torch.float32
    assert a.depth.dtype == torch.float32 and a.bary.shape == (32, 32, 3)


# -- degenerate input -----------------------------------------------------------------------


def assert_empty(frags: Fragments, height: int, width: int) -> None:
    assert frags.face_id.shape == (height, width) and frags.bary.shape == (height, width, 3)
    assert bool((frags.face_id == -1).all())
    assert bool(torch.isinf(frags.depth).all()) and bool((frags.bary == 0).all())


def test_empty_mesh() -> None:
    camera = PinholeCamera.from_focal(10.0, 8, 6)
    assert_empty(rasterize(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), camera), 6, 8)
    assert_empty(rasterize(np.ones((5, 3)), np.zeros((0, 3), dtype=np.int64), camera), 6, 8)


def test_faces_behind_or_crossing_the_near_plane_are_culled() -> None:
    camera = PinholeCamera.from_focal(10.0, 16, 16)
    behind, f = quad(-1.0, 1.0, -1.0, 1.0, -2.0)
    assert_empty(rasterize(behind, f, camera), 16, 16)
    crossing = np.array([[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, -0.5]])
    assert_empty(rasterize(crossing, np.array([[0, 1, 2]]), camera), 16, 16)
    near, f = quad(-1.0, 1.0, -1.0, 1.0, 0.05)
    assert bool(rasterize(near, f, camera).mask.all())
    assert_empty(rasterize(near, f, camera, RasterSettings(near=0.1)), 16, 16)


def test_zero_area_and_offscreen_faces() -> None:
    camera = PinholeCamera.from_focal(10.0, 16, 16)
    v, f = quad(-0.5, 0.5, -0.5, 0.5, 2.0)
    collinear = [[0.0, 0.0, 1.0], [0.1, 0.1, 1.0], [0.2, 0.2, 1.0]]
    far_away = [[50.0, 50.0, 2.0], [51.0, 50.0, 2.0], [50.0, 51.0, 2.0]]
    vertices = np.concatenate([v, collinear, far_away])
    degenerate = np.array([[4, 5, 6], [4, 4, 5], [7, 7, 7], [5, 5, 5]])
    offscreen = np.array([[7, 8, 9]])
    frags = rasterize(vertices, np.concatenate([f, degenerate, offscreen]), camera)
    clean = rasterize(v, f, camera)
    assert torch.equal(frags.face_id, clean.face_id)
    assert bool(torch.isfinite(frags.bary).all())
    assert_empty(rasterize(vertices, degenerate, camera), 16, 16)


@pytest.mark.parametrize(
    ("vertices", "faces", "message"),
    [
        (np.zeros((4, 2)), np.array([[0, 1, 2]]), "shape \\(V, 3\\)"),
        (np.zeros((4, 3)), np.array([[0, 1, 4]]), "out of range"),
        (np.zeros((4, 3)), np.array([[0, -1, 2]]), "out of range"),
        (np.zeros((4, 3)), np.array([[0.0, 1.0, 2.0]]), "integers"),
        (np.zeros((4, 3)), np.array([0, 1, 2]), "shape \\(F, 3\\)"),
        (np.full((4, 3), np.nan), np.array([[0, 1, 2]]), "NaN"),
    ],
)
def test_invalid_input(vertices: np.ndarray, faces: np.ndarray, message: str) -> None:
    camera = PinholeCamera.from_focal(10.0, 8, 8)
    with pytest.raises(ValueError, match=message):
        rasterize(vertices, faces, camera)


def test_invalid_settings_and_camera() -> None:
    with pytest.raises(ValueError, match="near"):
        RasterSettings(near=0.0)
    with pytest.raises(ValueError, match="PinholeCamera"):
        rasterize(np.zeros((3, 3)), np.array([[0, 1, 2]]), "camera")  # type: ignore[arg-type]


def test_fragments_from_face_ids_give_back_the_rasterised_fragments() -> None:
    from monoavatar.render import fragments_from_face_ids

    mesh = sphere_and_occluder()
    camera = look_at_camera(np.array([0.3, 0.2, 0.0]), np.array([0.0, 0.0, 3.0]), 90.0, 48, 40)
    frags = rasterize(mesh.vertices, mesh.faces, camera)
    again = fragments_from_face_ids(mesh.vertices, mesh.faces, camera, frags.face_id.numpy())
    assert frags.mask.sum() > 100
    for a, b in ((frags.face_id, again.face_id), (frags.bary, again.bary),
                 (frags.depth, again.depth)):  # fmt: skip
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match="face_id must have shape"):
        fragments_from_face_ids(mesh.vertices, mesh.faces, camera, np.zeros((4, 4), np.int64))
    with pytest.raises(ValueError, match="faces"):
        fragments_from_face_ids(mesh.vertices, mesh.faces, camera,
                                np.full((40, 48), len(mesh.faces)))  # fmt: skip
