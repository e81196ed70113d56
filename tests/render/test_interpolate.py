"""Attribute interpolation: gradients, perspective correctness, per-corner attributes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from render_scenes import concatenate, look_at_camera

from monoavatar.core.camera import PinholeCamera
from monoavatar.render import (
    Fragments,
    interpolate,
    interpolate_masked,
    rasterize,
    scatter_masked,
)


def tilted_sphere_scene() -> tuple[trimesh.Trimesh, PinholeCamera, Fragments]:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
    box = trimesh.creation.box(extents=(2.0, 2.0, 0.2))
    box.apply_transform(trimesh.transformations.rotation_matrix(0.9, [1.0, 0.3, 0.0]))
    box.apply_translation([0.0, 0.0, 1.2])
    mesh = concatenate([sphere, box])
    camera = look_at_camera(np.array([0.4, -0.3, -2.5]), np.zeros(3), 60.0, 40, 32)
    return mesh, camera, rasterize(mesh.vertices, mesh.faces, camera)


def test_gradcheck_per_vertex_and_per_corner() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    mesh.apply_translation([0.0, 0.0, 2.0])
    camera = PinholeCamera.from_focal(20.0, 12, 10)
    frags = rasterize(mesh.vertices, mesh.faces, camera)
    assert 0 < int(frags.mask.sum()) < 120
    faces = torch.as_tensor(mesh.faces)
    gen = torch.Generator().manual_seed(0)
    per_vertex = torch.randn(len(mesh.vertices), 2, dtype=torch.float64, generator=gen)
    per_corner = torch.randn(len(mesh.faces), 3, 2, dtype=torch.float64, generator=gen)
    fill = torch.tensor([0.5, -1.0], dtype=torch.float64)
    for attributes in (per_vertex, per_corner):
        torch.autograd.gradcheck(
            lambda a, f: interpolate(a, faces, frags, fill=f),
            (attributes.requires_grad_(), fill.clone().requires_grad_()),
        )


def test_interpolated_positions_lie_on_pixel_rays_at_the_depth() -> None:
    """Perspective-correct barycentrics: the interpolated camera-space point of each pixel
    projects to that pixel's centre, and its z is the depth buffer."""
    mesh, camera, frags = tilted_sphere_scene()
    cam = torch.as_tensor(mesh.vertices @ camera.R.T + camera.t)
    points = interpolate(cam, mesh.faces, frags)[frags.mask]
    pixels = points @ torch.as_tensor(camera.K).T
    pixels = pixels[:, :2] / pixels[:, 2:]
    rows, cols = torch.nonzero(frags.mask, as_tuple=True)
    centres = torch.stack([cols, rows], dim=-1).double() + 0.5
    assert len(centres) > 300
    torch.testing.assert_close(pixels, centres, atol=2e-5, rtol=0)
    torch.testing.assert_close(points[:, 2].float(), frags.depth[frags.mask], rtol=1e-6, atol=0)


def test_screen_space_interpolation_would_fail_the_ray_test() -> None:
    """The same check with the affine (screen-space) barycentrics is off by far more than the
    tolerance above: the test can tell the two apart."""
    mesh, camera, frags = tilted_sphere_scene()
    cam = mesh.vertices @ camera.R.T + camera.t
    fid = frags.face_id[frags.mask].numpy()
    b = frags.bary[frags.mask].double().numpy()
    z = cam[mesh.faces[fid], 2]
    affine = b / z
    affine /= affine.sum(-1, keepdims=True)  # undo the perspective correction
    points = np.einsum("nk,nkc->nc", affine, cam[mesh.faces[fid]])
    pixels = points @ camera.K.T
    rows, cols = np.nonzero(frags.mask.numpy())
    err = np.abs(pixels[:, :2] / pixels[:, 2:] - np.stack([cols, rows], -1) - 0.5).max()
    assert err > 1e-2


def test_per_corner_equals_per_vertex_and_fill() -> None:
    mesh, _, frags = tilted_sphere_scene()
    attributes = torch.randn(len(mesh.vertices), 3, generator=torch.Generator().manual_seed(1))
    faces = torch.as_tensor(mesh.faces)
    a = interpolate(attributes, faces, frags, fill=7.0)
    b = interpolate(attributes[faces], faces, frags, fill=7.0)
    torch.testing.assert_close(a, b)
    assert a.shape == (32, 40, 3)
    assert bool((a[~frags.mask] == 7.0).all())


def test_constant_attribute_is_constant() -> None:
    mesh, _, frags = tilted_sphere_scene()
    ones = torch.ones(len(mesh.vertices), 1)
    image = interpolate(ones, mesh.faces, frags)
    torch.testing.assert_close(image[frags.mask], torch.ones(int(frags.mask.sum()), 1))
    assert bool((image[~frags.mask] == 0).all())


def test_empty_fragments() -> None:
    camera = PinholeCamera.from_focal(10.0, 5, 4)
    frags = rasterize(np.zeros((3, 3)), np.array([[0, 1, 2]]), camera)
    out = interpolate(torch.ones(3, 2, requires_grad=True), np.array([[0, 1, 2]]), frags, 0.25)
    assert out.shape == (4, 5, 2) and bool((out == 0.25).all())
    out.sum().backward()


@pytest.mark.parametrize(
    ("attributes", "faces", "message"),
    [
        (torch.ones(3, 2), np.array([[0, 1, 3]]), "attributes have 3 rows"),
        (torch.ones(2, 3, 2), np.array([[0, 1, 2]]), "F=1"),
        (torch.ones(3), np.array([[0, 1, 2]]), "shape \\(V, C\\)"),
        (torch.ones(3, 2, dtype=torch.int64), np.array([[0, 1, 2]]), "floating-point"),
        (torch.ones(3, 2), np.array([0, 1, 2]), "shape \\(F, 3\\)"),
    ],
)
def test_invalid_input(attributes: torch.Tensor, faces: np.ndarray, message: str) -> None:
    camera = PinholeCamera.from_focal(10.0, 5, 4)
    frags = rasterize(np.zeros((4, 3)), np.zeros((0, 3), dtype=np.int64), camera)
    with pytest.raises(ValueError, match=message):
        interpolate(attributes, faces, frags)


def test_fragments_of_another_mesh_are_rejected() -> None:
    mesh, _, frags = tilted_sphere_scene()
    with pytest.raises(ValueError, match="fragments refer to face"):
        interpolate(torch.ones(3, 1), np.array([[0, 1, 2]]), frags)
    with pytest.raises(ValueError, match="fill"):
        interpolate(torch.ones(len(mesh.vertices), 2), mesh.faces, frags, torch.ones(3))


def test_masked_interpolation_and_scatter() -> None:
    mesh, _, frags = tilted_sphere_scene()
    attributes = torch.randn(len(mesh.vertices), 2, generator=torch.Generator().manual_seed(2))
    image = interpolate(attributes, mesh.faces, frags, fill=-3.0)
    values = interpolate_masked(attributes, mesh.faces, frags)
    torch.testing.assert_close(values, image[frags.mask])
    torch.testing.assert_close(scatter_masked(values, frags, fill=-3.0), image)
    with pytest.raises(ValueError, match="covered pixels"):
        scatter_masked(values[1:], frags)
