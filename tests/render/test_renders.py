"""Convenience renders: normals, labels, UVs, texture sampling, textured colour."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh
from render_scenes import look_at_camera

from monoavatar.core.camera import PinholeCamera
from monoavatar.render import (
    rasterize,
    render_depth,
    render_face_labels,
    render_normals,
    render_silhouette,
    render_textured,
    render_uv,
    render_vertex_labels,
    sample_texture,
    vertex_normals,
)

IDENTITY_CAMERA = PinholeCamera.from_focal(40.0, 48, 40)


def textured_quad(z: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A fronto-parallel quad, x in [-1, 1], y in [-0.8, 0.8] (y down), facing the camera,
    with glTF UVs: its top-left corner (in the image) has uv (0, 0). UVs are indexed apart
    from the vertices. Returns vertices, faces, uv (4, 2), face_uv_idx."""
    vertices = np.array([[-1.0, -0.8, z], [1.0, -0.8, z], [1.0, 0.8, z], [-1.0, 0.8, z]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # normal (0, 0, -1): towards the camera
    uv = np.array([[1.0, 1.0], [0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    face_uv_idx = np.array([[1, 0, 2], [1, 3, 0]])
    return vertices, faces, uv, face_uv_idx


def test_vertex_normals_of_a_sphere_are_radial() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    normals = vertex_normals(torch.as_tensor(sphere.vertices), sphere.faces)
    torch.testing.assert_close(normals, torch.as_tensor(sphere.vertices), atol=2e-2, rtol=0)
    torch.testing.assert_close(normals.norm(dim=-1), torch.ones(len(sphere.vertices)).double())


def test_vertex_normals_are_area_weighted() -> None:
    # Vertex 0 is shared by a big face in the z = 0 plane and a small face in the x = 0 plane.
    v = torch.tensor(
        [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]
    )
    faces = torch.tensor([[0, 1, 2], [0, 4, 3]])
    n0 = vertex_normals(v, faces)[0]
    expected = torch.tensor([1.0, 0.0, 4.0]) / math.sqrt(17.0)  # areas 0.5 and 2
    torch.testing.assert_close(n0, expected)


def test_degenerate_faces_give_finite_normals() -> None:
    v = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
    normals = vertex_normals(v, torch.tensor([[0, 1, 2], [1, 1, 1]]))
    assert bool(torch.isfinite(normals).all())
    assert bool((normals == 0).all())


def test_rendered_normals_of_a_sphere_match_the_geometry() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    centre = np.array([0.1, -0.05, 0.2])
    sphere.apply_translation(centre)
    camera = look_at_camera(np.array([0.8, 0.5, -2.0]), centre, 60.0, 40, 40)
    frags = rasterize(sphere.vertices, sphere.faces, camera)
    mask = frags.mask
    world = render_normals(torch.as_tensor(sphere.vertices), sphere.faces, frags)
    # The visible point of each pixel, from the depth buffer and the pixel ray.
    rows, cols = torch.nonzero(mask, as_tuple=True)
    pix = torch.stack([cols, rows, torch.ones_like(cols)], -1).double() + torch.tensor(
        [0.5, 0.5, 0.0], dtype=torch.float64
    )
    cam_points = (pix @ torch.as_tensor(np.linalg.inv(camera.K)).T) * frags.depth[mask, None]
    world_points = (cam_points - torch.as_tensor(camera.t)) @ torch.as_tensor(camera.R)
    radial = (world_points - torch.as_tensor(centre)) / 0.5
    torch.testing.assert_close(world[mask], radial, atol=2e-2, rtol=0)
    assert bool((world[~mask] == 0).all())
    in_camera = render_normals(sphere.vertices, sphere.faces, frags, camera=camera)
    torch.testing.assert_close(in_camera[mask], world[mask] @ torch.as_tensor(camera.R).T)
    assert float(in_camera[mask][:, 2].max()) < 0.05  # visible surface faces the camera


def test_silhouette_and_depth() -> None:
    v, f, _, _ = textured_quad(z=3.0)
    frags = rasterize(v, f, IDENTITY_CAMERA)
    mask = render_silhouette(frags)
    assert mask.dtype == torch.bool and torch.equal(mask, frags.face_id >= 0)
    depth = render_depth(frags, background=-1.0)
    assert bool((depth[mask] == 3.0).all()) and bool((depth[~mask] == -1.0).all())


def test_face_and_vertex_labels() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
    sphere.apply_translation([0.0, 0.0, 2.5])
    frags = rasterize(sphere.vertices, sphere.faces, IDENTITY_CAMERA)
    mask = frags.mask
    face_labels = np.arange(len(sphere.faces)) % 7
    by_face = render_face_labels(face_labels, frags)
    torch.testing.assert_close(by_face[mask], torch.as_tensor(face_labels)[frags.face_id[mask]])
    assert bool((by_face[~mask] == -1).all())
    by_vertex = render_vertex_labels(np.arange(len(sphere.vertices)) * 3, sphere.faces, frags, -5)
    nearest = np.zeros(mask.shape, dtype=np.int64)
    # Independent check: the labelled vertex is the face corner nearest to the visible point.
    cam = sphere.vertices  # camera frame == world frame here
    for r, c in zip(*np.nonzero(mask.numpy()), strict=True):
        corners = sphere.faces[frags.face_id[r, c]]
        point = (frags.bary[r, c].double().numpy()[:, None] * cam[corners]).sum(0)
        nearest[r, c] = corners[np.argmin(np.linalg.norm(cam[corners] - point, axis=1))]
    agree = by_vertex.numpy()[mask.numpy()] == 3 * nearest[mask.numpy()]
    assert agree.mean() > 0.97  # barycentric argmax vs Euclidean nearest corner
    assert bool((by_vertex[~mask] == -5).all())


def test_uv_render_with_separate_uv_indexing() -> None:
    v, f, uv, face_uv_idx = textured_quad()
    frags = rasterize(v, f, IDENTITY_CAMERA)
    uv_image = render_uv(torch.as_tensor(uv), face_uv_idx, frags, background=-1.0)
    rows, cols = torch.nonzero(frags.mask, as_tuple=True)
    # Pixel centre -> point on the quad (z = 2, f = 40, centre (24, 20)) -> glTF uv.
    x = (cols.double() + 0.5 - 24.0) * 2.0 / 40.0
    y = (rows.double() + 0.5 - 20.0) * 2.0 / 40.0
    expected = torch.stack([(x + 1.0) / 2.0, (y + 0.8) / 1.6], -1)
    torch.testing.assert_close(uv_image[frags.mask], expected, atol=1e-6, rtol=0)
    assert bool((uv_image[~frags.mask] == -1.0).all())


def test_sample_texture_follows_gltf_convention() -> None:
    texture = torch.arange(12, dtype=torch.float64).reshape(3, 4, 1)  # row 0 = top
    centres = torch.tensor(
        [[0.125, 1 / 6], [0.875, 1 / 6], [0.125, 5 / 6], [0.375, 0.5]], dtype=torch.float64
    )
    values = sample_texture(texture, centres).numpy()[:, 0]
    np.testing.assert_allclose(values, [0, 3, 8, 5], atol=1e-12)
    between = torch.tensor([[0.25, 1 / 6], [0.125, 1 / 3]], dtype=torch.float64)
    np.testing.assert_allclose(sample_texture(texture, between).numpy()[:, 0], [0.5, 2.0])
    outside = sample_texture(texture, torch.tensor([[-0.5, -0.5], [2.0, 2.0]]))
    np.testing.assert_allclose(outside.numpy()[:, 0], [0.0, 11.0])  # clamp to edge
    assert sample_texture(texture, torch.zeros(2, 5, 2)).shape == (2, 5, 1)


def test_textured_render_unlit_lit_and_background() -> None:
    v, f, uv, face_uv_idx = textured_quad()
    frags = rasterize(v, f, IDENTITY_CAMERA)
    mask = frags.mask
    # 2 x 2 texture: red top-left, green top-right, blue bottom-left, white bottom-right.
    texture = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0.0, 0.0, 1.0], [1.0, 1.0, 1.0]]])
    background = torch.full((40, 48, 3), 0.25)
    unlit = render_textured(v, f, frags, uv, face_uv_idx, texture, None, background)
    assert bool((unlit[~mask] == 0.25).all())
    # Image top-left of the quad shows the texture's top-left texel (glTF: v down).
    quad_rows, quad_cols = torch.nonzero(mask, as_tuple=True)
    top, left = int(quad_rows.min()), int(quad_cols.min())
    bottom, right = int(quad_rows.max()), int(quad_cols.max())
    torch.testing.assert_close(unlit[top, left], torch.tensor([1.0, 0.0, 0.0]), atol=0.1, rtol=0)
    torch.testing.assert_close(unlit[top, right], torch.tensor([0.0, 1.0, 0.0]), atol=0.1, rtol=0)
    torch.testing.assert_close(unlit[bottom, left], torch.tensor([0.0, 0.0, 1.0]), atol=0.1, rtol=0)
    # Uniform radiance 0.6 shades everything by 0.6, whatever the normal.
    sh = torch.zeros(3, 9)
    sh[:, 0] = 0.6 * 2.0 * math.sqrt(math.pi)
    lit = render_textured(v, f, frags, uv, face_uv_idx, texture, sh, 0.0)
    torch.testing.assert_close(lit[mask], 0.6 * unlit[mask])
    assert bool((lit[~mask] == 0).all())


def test_textured_render_is_differentiable() -> None:
    v, f, uv, face_uv_idx = textured_quad()
    frags = rasterize(v, f, IDENTITY_CAMERA)
    vertices = torch.as_tensor(v).requires_grad_()
    texture = torch.rand(8, 8, 3, dtype=torch.float64, requires_grad=True)
    sh = torch.zeros(3, 9, dtype=torch.float64)
    sh[:, 0] = 2.0
    sh[:, 2] = -1.0  # light from -z, i.e. from the camera side
    sh.requires_grad_()
    image = render_textured(vertices, f, frags, uv, face_uv_idx, texture, sh)
    image.sum().backward()
    for t in (vertices, texture, sh):
        assert t.grad is not None and bool(torch.isfinite(t.grad).all())
    assert texture.grad is not None and sh.grad is not None
    assert float(texture.grad.abs().sum()) > 0 and float(sh.grad.abs().sum()) > 0


def test_invalid_input() -> None:
    v, f, uv, face_uv_idx = textured_quad()
    frags = rasterize(v, f, IDENTITY_CAMERA)
    with pytest.raises(ValueError, match="texture"):
        render_textured(v, f, frags, uv, face_uv_idx, torch.zeros(4, 4))
    with pytest.raises(ValueError, match="background"):
        render_textured(v, f, frags, uv, face_uv_idx, torch.zeros(4, 4, 3), None, torch.zeros(2))
    with pytest.raises(ValueError, match="faces index"):
        render_uv(uv, np.array([[0, 1, 4]]), frags)
    with pytest.raises(ValueError, match="labels"):
        render_face_labels(np.array([1]), frags)
    with pytest.raises(ValueError, match="integer"):
        render_vertex_labels(np.ones(4), f, frags)
    with pytest.raises(ValueError, match="uv"):
        sample_texture(torch.zeros(2, 2, 3), torch.zeros(5, 3))


def test_render_textured_leaves_the_background_untouched():
    """A full-size background tensor is the caller's: rendering twice must not accumulate."""
    from monoavatar.core.camera import PinholeCamera
    from monoavatar.render import rasterize, render_textured

    cam = PinholeCamera.from_focal(50.0, 32, 32)
    vertices = torch.tensor([[-0.5, -0.5, 2.0], [0.5, -0.5, 2.0], [0.0, 0.5, 2.0]])
    faces = torch.tensor([[0, 1, 2]])
    frags = rasterize(vertices, faces, cam)
    uv = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]])
    background = torch.zeros(32, 32, 3)
    image = render_textured(vertices, faces, frags, uv, faces, torch.ones(4, 4, 3),
                            background=background)  # fmt: skip
    assert image.sum() > 0
    assert background.abs().sum() == 0


def test_read_only_numpy_inputs_render_the_same_without_a_warning() -> None:
    """Broadcast views (read-only) of the SH and the texture are copied, not shared with a
    torch warning, and give the same image as writable arrays."""
    import warnings

    v, f, uv, face_uv_idx = textured_quad()
    frags = rasterize(v, f, IDENTITY_CAMERA)
    texture = np.random.default_rng(0).uniform(0.1, 0.9, (4, 4, 3))
    sh = np.zeros((2, 3, 9))
    sh[..., 0] = 1.5
    sh[..., 2] = -0.5
    read_only_sh = np.broadcast_to(sh[0], (2, 3, 9))[1]
    read_only_texture = np.broadcast_to(texture, (1, 4, 4, 3))[0]
    assert not read_only_sh.flags.writeable and not read_only_texture.flags.writeable
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image = render_textured(v, f, frags, uv, face_uv_idx, read_only_texture, read_only_sh)
    expected = render_textured(v, f, frags, uv, face_uv_idx, texture.copy(), sh[0].copy())
    torch.testing.assert_close(image, expected)
