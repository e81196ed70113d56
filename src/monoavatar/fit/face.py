"""The face against the face-mesh landmarks detected in the frames (Paper C, Sec. C.3.2).

The body's face points are the shipped :class:`~monoavatar.body.face_map.FaceMap`'s.

- :func:`face_errors`: a frame's face error, how far the face points project from the 468
  detected landmarks, as a fraction of the detected outer eye corners' distance (so a close-up
  and a full-body frame compare).
- :func:`face_rays`: the face term's correspondences (Eq. C.6–C.7): each detected landmark's
  camera ray unposed into the canonical frame, paired with its face point, for the consensus
  shape fit (:mod:`monoavatar.fit.shape`), which adds them to the silhouette rays.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel
from monoavatar.body.face_map import FaceMap
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.geometry import vertex_normals
from monoavatar.fit.rays import CanonicalRays, pixel_directions, unpose_lines

__all__ = ["EYE_CORNERS", "face_errors", "face_rays", "relative_face_error"]

#: The face mesh's outer eye corners (the person's right, then left): the error's unit.
EYE_CORNERS = (33, 263)


def relative_face_error(projected: np.ndarray, detected: np.ndarray) -> np.ndarray:
    """(N, 468, 2) projected face points and (N, 468, 3) detected landmarks (x px, y px,
    confidence; NaN where no face was found) → (N,) the median over the landmarks of the
    pixel distance, over the detected outer eye corners' distance; NaN for frames without a
    detected face."""
    found = np.isfinite(detected[..., :2]).all(axis=(1, 2))
    out = np.full(len(detected), np.nan)
    if found.any():
        d = detected[found, :, :2].astype(np.float64)
        eyes = np.linalg.norm(d[:, EYE_CORNERS[0]] - d[:, EYE_CORNERS[1]], axis=-1)
        err = np.linalg.norm(projected[found] - d, axis=-1)
        out[found] = np.median(err, axis=1) / np.maximum(eyes, 1e-9)
    return out


def face_errors(body: BodyModel, face_map: FaceMap, vertices: Tensor, camera: PinholeCamera,
                detected: np.ndarray) -> np.ndarray:  # fmt: skip
    """(N, V, 3) posed vertices (world, metres) seen by ``camera``, (N, 468, 3) detected
    landmarks → (N,) :func:`relative_face_error`."""
    with torch.no_grad():
        projected, _ = camera.project(face_map.points(vertices, body.faces))
    return relative_face_error(projected.double().numpy(), np.asarray(detected))


def face_rays(body: BodyModel, face_map: FaceMap, canonical: Tensor, transforms: Tensor,
              detected: np.ndarray, camera: PinholeCamera, *, rotations: Tensor | None = None,
              min_facing: float = 0.2, max_turn_deg: float = 180.0,
              ) -> tuple[CanonicalRays, np.ndarray]:  # fmt: skip
    """The face term's rays (Sec. C.3.2): the camera ray of every detected landmark, unposed
    into the canonical frame with the blended transform of its face point's dominant vertex
    (the triangle corner of largest barycentric weight), as the silhouette rays are (Eq. B.6).

    The term measures the face point ``l`` (not the vertex) against its ray, Eq. C.6
    ``|l × r_n − r_m|``. With ``l = v + δ``, δ the canonical offset from the dominant vertex
    to the face point (held fixed while the mesh moves little), that is the vertex's distance
    to the line shifted by −δ, moment ``r_m − δ × r_n``: so a face ray, like a silhouette
    ray, constrains one vertex, and the solver handles both alike (with the point-to-line
    projector, Eq. B.8).

    Landmarks whose face point looks away from the camera in the posed mesh (cosine between
    its normal and the direction to the camera below ``min_facing``) are left out: the face
    mesh places hidden landmarks by guess (half the face in a profile view). Frames whose
    face turns further than ``max_turn_deg`` from the camera (the angle between the mean
    normal of the posed face points and the direction from their centre to the camera) give
    no rays: on turned faces the face mesh's landmarks drift from where they lie on frontal
    ones (``docs/decisions.md``).

    Args:
        canonical: (V, 3) canonical vertices, metres.
        transforms: (F, J, 4, 4) rest → posed joint transforms of the F frames (as
            corrected by the silhouette step).
        detected: (F, 468, 3) landmarks (x px, y px, confidence), NaN rows where none.
        rotations: (F, J, 3, 3) joint rotations, for models with pose correctives.
    Returns:
        the rays (``frame`` indexes the F frames; ``plane_normal`` is a unit normal of a
        plane through the line, unused by the point-to-line term; ``image_distance`` the
        pixels between the detection and the posed face point's projection), and (N,) the
        landmarks' confidences.
    """
    detected = np.asarray(detected, dtype=np.float64)
    faces = body.faces
    corners = faces[torch.as_tensor(face_map.triangles)].numpy()  # (468, 3)
    dominant = corners[np.arange(len(corners)), np.argmax(face_map.bary, axis=1)]
    canon = canonical.detach().double()
    delta = face_map.points(canon, faces).numpy() - canon.numpy()[dominant]  # (468, 3)
    k_inv = np.linalg.inv(camera.K)
    weights = body.skin_weights.double()
    tf_all = transforms.detach().double()
    parts: list[CanonicalRays] = []
    conf_parts: list[np.ndarray] = []
    for f in np.flatnonzero(np.isfinite(detected[..., :2]).all(axis=(1, 2))):
        rest = canon
        corr = None
        if rotations is not None:
            corr = body.pose_correctives(rotations[f : f + 1].double())
            if corr is not None:
                corr = corr[0]
                rest = canon + corr
        blend = torch.einsum("vj,jmn->vmn", weights, tf_all[f, :, :3, :])
        posed = (blend[..., :3] @ rest.unsqueeze(-1)).squeeze(-1) + blend[..., 3]
        points = face_map.points(posed, faces).numpy()
        normals = face_map.points(vertex_normals(posed, faces), faces).numpy()
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        view = camera.center - points
        forward = normals.mean(0)
        centre = camera.center - points.mean(0)
        turn = np.arccos(np.clip(forward @ centre / (np.linalg.norm(forward)
                                                     * np.linalg.norm(centre)), -1.0, 1.0))
        if np.degrees(turn) > max_turn_deg:
            continue
        facing = np.einsum("lc,lc->l", normals, view) / np.linalg.norm(view, axis=1)
        keep = np.flatnonzero((facing > min_facing) & (detected[f, :, 2] > 0))
        if len(keep) == 0:
            continue
        pix = detected[f, keep, :2]
        dirs = pixel_directions(camera, k_inv, pix)
        side = np.cross(dirs, camera.R[1])
        side /= np.linalg.norm(side, axis=1, keepdims=True)
        m, n, p = unpose_lines(body, camera.center, dirs, side, dominant[keep], tf_all[f], corr)
        m = m - np.cross(delta[keep], n)
        with torch.no_grad():
            projected, _ = camera.project(torch.as_tensor(points[keep]))
        dist = np.linalg.norm(projected.double().numpy() - pix, axis=1)
        parts.append(CanonicalRays(dominant[keep], m, n, p, np.full(len(keep), f, np.int64),
                                   dist))  # fmt: skip
        conf_parts.append(detected[f, keep, 2])
    return CanonicalRays.concatenate(parts), np.concatenate([np.zeros(0), *conf_parts])
