"""The face-mesh landmark map: its points are barycentric combinations of their triangles'
corners (a closed form, and its derivative), it round-trips through its file, it refuses maps
that cannot be right, and the shipped one belongs to Anny's mesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from monoavatar.body import BodyModel
from monoavatar.body.face_map import FaceMap, load_face_map, shipped_face_map_path
from monoavatar.body.model import BodyModelError

N = 468


def _random_map(num_vertices: int, faces: np.ndarray, seed: int = 0) -> FaceMap:
    rng = np.random.default_rng(seed)
    bary = rng.dirichlet(np.ones(3), N)
    return FaceMap(rng.integers(len(faces), size=N), bary, num_vertices, len(faces))


def test_points_are_barycentric_combinations_with_that_derivative() -> None:
    rng = np.random.default_rng(1)
    vertices = torch.tensor(rng.normal(size=(2, 10, 3)), requires_grad=True)  # a batch of 2
    faces = torch.as_tensor(rng.integers(10, size=(7, 3)))
    face_map = _random_map(10, faces.numpy())
    points = face_map.points(vertices, faces)
    assert points.shape == (2, N, 3)
    corners = vertices.detach().numpy()[:, faces.numpy()[face_map.triangles]]  # (2, N, 3, 3)
    expected = np.einsum("blkc,lk->blc", corners, face_map.bary)
    np.testing.assert_allclose(points.detach().numpy(), expected, atol=1e-12)
    # d(sum of landmark 5's x) / d(vertex) is its barycentric weight on that vertex
    points[:, 5, 0].sum().backward()
    grad = np.zeros(10)
    np.add.at(grad, faces.numpy()[face_map.triangles[5]], face_map.bary[5])
    np.testing.assert_allclose(vertices.grad[0, :, 0].numpy(), grad, atol=1e-12)
    np.testing.assert_allclose(vertices.grad[..., 1:].numpy(), 0.0)


def test_round_trip_and_refusals(tmp_path: Path) -> None:
    faces = np.random.default_rng(2).integers(10, size=(7, 3))
    face_map = _random_map(10, faces)
    face_map.save(tmp_path / "map.npz")
    again = FaceMap.load(tmp_path / "map.npz")
    np.testing.assert_array_equal(again.triangles, face_map.triangles)
    np.testing.assert_array_equal(again.bary, face_map.bary)
    assert (again.num_vertices, again.num_faces) == (10, 7)
    with pytest.raises(BodyModelError, match="outside"):
        FaceMap(np.full(N, 7), face_map.bary, 10, 7)
    with pytest.raises(BodyModelError, match="sum to 1"):
        FaceMap(face_map.triangles, 2 * face_map.bary, 10, 7)
    with pytest.raises(BodyModelError, match="468"):
        FaceMap(face_map.triangles[:5], face_map.bary[:5], 10, 7)
    with pytest.raises(BodyModelError, match="mesh of 10 vertices"):
        face_map.points(torch.zeros(11, 3), torch.as_tensor(faces))


def test_the_shipped_map_belongs_to_annys_mesh_and_lies_on_its_face(anny32: BodyModel) -> None:
    assert shipped_face_map_path().is_file()
    face_map = load_face_map(anny32)
    with torch.no_grad():
        rest, _ = anny32.rest_shape(anny32.default_shape(1))
        points = face_map.points(rest[0], anny32.faces).numpy()
        kp = anny32.keypoints(rest)[0].numpy()
    # all on the head (above the shoulders), in front of the ears (the body faces +Z); the nose
    # tip (face-mesh landmark 1) on the body's midline; the eyes' centres (between the corners
    # 33 and 133, 362 and 263) within 6 mm of the body model's own eye landmarks (2 and 5, from
    # its landmark regressor), one the other's mirror image
    assert (points[:, 1] > kp[[11, 12], 1].max()).all()
    assert (points[:, 2] > kp[[7, 8], 2].min() - 0.01).all()
    assert abs(points[1, 0]) < 0.005
    right, left = 0.5 * (points[33] + points[133]), 0.5 * (points[362] + points[263])
    assert np.linalg.norm(right - kp[5]) < 0.006 and np.linalg.norm(left - kp[2]) < 0.006
    np.testing.assert_allclose(left * [-1, 1, 1], right, atol=0.003)
    # down the midline: forehead (10), between the eyes (168), nose tip (1), lower lip (14), chin
    # (152); the nose tip within 1 cm of the face's front-most point
    heights = points[[10, 168, 1, 14, 152], 1]
    assert (np.diff(heights) < 0).all(), heights
    v = rest[0].numpy()
    face = v[(np.abs(v[:, 0]) < 0.02) & (v[:, 1] > points[152, 1]) & (v[:, 1] < points[168, 1])]
    assert np.linalg.norm(face[np.argmax(face[:, 2])] - points[1]) < 0.01
