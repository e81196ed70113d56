import numpy as np
import pytest
import torch
import trimesh

from monoavatar.body import lbs
from monoavatar.body.subdivide import subdivide
from monoavatar.render import vertex_normals
from tests.geometry import point_triangle_distance


def test_subdivided_mesh_lies_on_the_original(anny64):
    body = anny64
    rest = body().vertices
    sub = subdivide(body.faces, body.uv, body.face_uv, body.skin_weights)
    fine = sub.apply(rest)
    assert sub.faces.shape[0] == 4 * body.faces.shape[0]
    coarse = trimesh.Trimesh(rest[0].numpy(), body.faces.numpy(), process=False)
    fine_mesh = trimesh.Trimesh(fine[0].numpy(), sub.faces.numpy(), process=False)
    new = fine[0, sub.num_coarse :].numpy()
    rng = np.random.default_rng(0)
    sample = new[rng.choice(len(new), 200, replace=False)]
    triangles = rest[0].numpy()[body.faces.numpy()]
    assert point_triangle_distance(sample, triangles).max() <= 1e-6
    assert abs(fine_mesh.area - coarse.area) < 1e-9 * coarse.area + 1e-12
    # every edge of the coarse mesh is split exactly once
    assert sub.edges.shape[0] == len(coarse.edges_unique)


def test_subdivided_skinning_reproduces_coarse_posing(anny64):
    body = anny64
    sub = subdivide(body.faces, body.uv, body.face_uv, body.skin_weights)
    gen = torch.Generator().manual_seed(0)
    pose = 0.4 * torch.randn(1, body.num_joints, 3, generator=gen, dtype=torch.float64)
    out = body(pose=pose)
    fine_rest = sub.apply(out.rest_vertices)
    fine_posed = lbs.skin(fine_rest, sub.weights, out.transforms)
    # original vertices: identical
    assert torch.allclose(fine_posed[:, : sub.num_coarse], out.vertices, atol=1e-12)
    # new vertices: on the posed coarse surface up to LBS's blending of neighbours
    coarse = trimesh.Trimesh(out.vertices[0].numpy(), body.faces.numpy(), process=False)
    _, dist, _ = trimesh.proximity.closest_point(coarse, fine_posed[0, sub.num_coarse :: 5].numpy())
    assert np.median(dist) < 1e-4 and dist.max() < 5e-3


def test_normal_displacement_eq_c3(anny64):
    body = anny64
    sub = subdivide(body.faces, body.uv, body.face_uv, body.skin_weights)
    rest = body().vertices
    s = torch.full((1, sub.edges.shape[0]), 0.01, dtype=torch.float64)
    fine = sub.apply(rest, displacement=s, coarse_faces=body.faces)
    mid = 0.5 * (rest[:, sub.edges[:, 0]] + rest[:, sub.edges[:, 1]])
    moved = (fine[:, sub.num_coarse :] - mid).norm(dim=-1)
    assert torch.allclose(moved, torch.full_like(moved, 0.01))
    # outward: the displaced mesh encloses more volume
    n = vertex_normals(rest, body.faces)
    e = sub.edges
    avg = torch.nn.functional.normalize(n[:, e[:, 0]] + n[:, e[:, 1]], dim=-1)
    assert torch.allclose(fine[:, sub.num_coarse :] - mid, 0.01 * avg)


def test_uv_and_weights_subdivide_consistently(anny64):
    body = anny64
    sub = subdivide(body.faces, body.uv, body.face_uv, body.skin_weights)
    assert sub.face_uv.shape == sub.faces.shape
    uv = sub.uv[sub.face_uv]
    assert uv.min() >= 0 and uv.max() <= 1
    assert torch.allclose(sub.weights.sum(1), torch.ones(sub.weights.shape[0], dtype=torch.float64))

    # the UV triangle of each fine face is a quarter of its coarse UV triangle
    def area(tri):
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        return 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]).abs()

    coarse_area = area(body.uv[body.face_uv]).sum()
    assert torch.allclose(area(uv).sum(), coarse_area)


def _icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    ico = trimesh.creation.icosphere(subdivisions=level, radius=1.0)
    return np.asarray(ico.vertices), np.asarray(ico.faces)


def _no_uv(faces: np.ndarray, n: int):
    f = torch.as_tensor(faces)
    return f, torch.zeros(n, 2, dtype=torch.float64), f, torch.ones(n, 1, dtype=torch.float64)


def test_cotangent_laplacian_of_a_plane_and_a_sphere() -> None:
    from monoavatar.core.geometry import cotangent_laplacian

    v, f = _icosphere(2)
    L = cotangent_laplacian(v, f)
    assert abs(L - L.T).max() < 1e-12 and np.abs(L.sum(axis=1)).max() < 1e-12
    # on the unit sphere L x / (vertex area) is the mean-curvature normal 2 n (outwards with
    # this sign convention); barycentric areas are crude at the 12 valence-5 vertices
    area = np.zeros(len(v))
    tri = v[f]
    a = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    np.add.at(area, f.ravel(), np.repeat(a / 3, 3))
    Hn = (L @ v) / area[:, None]
    radial = np.einsum("vc,vc->v", Hn, v)
    assert np.median(radial) == pytest.approx(2.0, rel=0.02)
    np.testing.assert_allclose(radial, 2.0, rtol=0.15)
    # a flat grid: interior rows vanish on linear functions
    x, y = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 6))
    g = np.stack([x.ravel(), y.ravel(), np.zeros(36)], 1)
    idx = np.arange(36).reshape(6, 6)
    q = [idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]]
    gf = np.concatenate([np.stack([q[0], q[1], q[2]], -1).reshape(-1, 3),
                         np.stack([q[0], q[2], q[3]], -1).reshape(-1, 3)])  # fmt: skip
    interior = ((idx > 5) & (idx < 30) & (idx % 6 != 0) & (idx % 6 != 5)).ravel()
    lin = 2.0 * g[:, 0] - g[:, 1]
    assert np.abs((cotangent_laplacian(g, gf) @ lin)[interior]).max() < 1e-12


def test_smooth_displacement_moves_midpoints_onto_the_sphere() -> None:
    from monoavatar.body.subdivide import smooth_displacement

    v, f = _icosphere(2)
    sub = subdivide(*_no_uv(f, len(v)))
    s = smooth_displacement(sub, v, f)
    assert s.shape == (sub.edges.shape[0],)
    plain = sub.apply(torch.as_tensor(v)[None])[0, sub.num_coarse :].numpy()
    smooth = sub.apply(torch.as_tensor(v)[None], s, coarse_faces=torch.as_tensor(f))[0]
    new = smooth[sub.num_coarse :].numpy()
    before = np.abs(np.linalg.norm(plain, axis=1) - 1.0).mean()
    after = np.abs(np.linalg.norm(new, axis=1) - 1.0).mean()
    assert s.min() > 0  # outwards
    assert after < 0.2 * before, (before, after)
    # the coarse vertices stay where they were
    np.testing.assert_array_equal(smooth[: sub.num_coarse].numpy(), v)


def test_smooth_displacement_leaves_a_plane_flat() -> None:
    from monoavatar.body.subdivide import smooth_displacement

    x, y = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(25)], 1)
    idx = np.arange(25).reshape(5, 5)
    q = [idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]]
    f = np.concatenate([np.stack([q[0], q[1], q[2]], -1).reshape(-1, 3),
                        np.stack([q[0], q[2], q[3]], -1).reshape(-1, 3)])  # fmt: skip
    sub = subdivide(*_no_uv(f, len(v)))
    s = smooth_displacement(sub, v, f)
    assert np.abs(s.numpy()).max() < 1e-9
