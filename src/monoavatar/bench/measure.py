"""Body measurements of a synth scene's ground truth (the generating body under the clothes and
the clothed canonical mesh), with trimesh's plane sections and ray casts instead of the measure
stage's own, so that an error in those cannot hide in the comparison."""

from __future__ import annotations

import numpy as np
import torch
import trimesh
from trimesh.ray.ray_triangle import RayMeshIntersector

from monoavatar.body import BodyModel
from monoavatar.datasets.synth_scene import SynthGroundTruth
from monoavatar.measure import (
    Measurement,
    MeasureSettings,
    Section,
    Slicer,
    measure_mesh,
    transfer_parts,
    vertex_parts,
)

__all__ = ["ground_truth_measurements", "trimesh_slicer"]


def _section(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray,
             normal: np.ndarray) -> Section:  # fmt: skip
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    lines, face_index = trimesh.intersections.mesh_plane(mesh, normal, origin, return_faces=True)
    return Section(np.asarray(lines, float).reshape(-1, 2, 3), np.asarray(face_index, np.int64),
                   np.asarray(origin, float), np.asarray(normal, float) / np.linalg.norm(normal))


def _hits(vertices: np.ndarray, faces: np.ndarray, x: float, z: float) -> np.ndarray:
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    start = np.array([[x, float(vertices[:, 1].min()) - 1.0, z]])
    locations, _, _ = RayMeshIntersector(mesh).intersects_location(
        start, np.array([[0.0, 1.0, 0.0]]), multiple_hits=True)
    return np.sort(np.asarray(locations, float)[:, 1])


def trimesh_slicer() -> Slicer:
    """A :class:`~monoavatar.measure.Slicer` made of trimesh's ``mesh_plane`` and its
    pure-Python ray-triangle intersector."""
    return Slicer(section=_section, hits=_hits)


def ground_truth_measurements(truth: SynthGroundTruth, body: BodyModel, subject: int = 0,
                              settings: MeasureSettings | None = None
                              ) -> dict[str, dict[str, Measurement]]:  # fmt: skip
    """``{"body": …, "clothed": …}`` measurements of a scene's subject: the generating body
    model (``body``, the model :attr:`SynthGroundTruth.body_model` names) in its rest pose with
    the true shape, and the clothed canonical mesh, both with the true skeleton."""
    if body.identity != truth.body_model:
        raise ValueError(f"the truth was made with {truth.body_model!r}, got {body.identity!r}")
    with torch.no_grad():
        rest, joints = body.rest_shape(torch.as_tensor(truth.shapes[subject:subject + 1],
                                                       dtype=body.dtype))  # fmt: skip
    v, j = rest[0].double().numpy(), joints[0].double().numpy()
    parts = vertex_parts(body.skin_weights.double().numpy(), body.joint_names)
    mesh = truth.canonical_mesh(subject)
    cv, cf = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    slicer = trimesh_slicer()
    return {
        "body": measure_mesh(v, body.faces.numpy(), parts, j, body.joint_names, settings, slicer),
        "clothed": measure_mesh(cv, cf, transfer_parts(v, parts, cv), j, body.joint_names,
                                settings, slicer),
    }  # fmt: skip
