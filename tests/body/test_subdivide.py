import numpy as np
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
    pose = 0.4 * torch.randn(1, body.num_joints, 3, dtype=torch.float64)
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
