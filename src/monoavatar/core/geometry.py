"""Geometry shared by every layer above: argument checks for vertex and face arrays,
area-weighted vertex normals, the cotangent Laplacian, viewing rays of pixels, and the rotation
taking the optical axis onto a viewing ray (the hip-ray frame of the landmarks among them)."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from monoavatar.core.landmarks import HIP_LANDMARKS

__all__ = ["camera_rays", "cotangent_laplacian", "face_indices", "float_tensor",
           "hip_ray_rotations", "ray_rotations", "vertex_normals", "writable"]  # fmt: skip


def writable(x: object) -> object:
    """``x``, copied when it is a read-only NumPy array (a broadcast view, say), which torch
    would otherwise share with a warning."""
    if isinstance(x, np.ndarray) and not x.flags.writeable:
        return np.array(x)
    return x


def float_tensor(x: Tensor | np.ndarray, name: str, last: int | None = None) -> Tensor:
    t = x if isinstance(x, Tensor) else torch.as_tensor(writable(np.asarray(x, np.float64)))
    if not t.is_floating_point():
        raise ValueError(f"{name} must be floating point, got dtype {t.dtype}")
    if last is not None and (t.ndim != 2 or t.shape[1] != last):
        raise ValueError(f"{name} must have shape (N, {last}), got {tuple(t.shape)}")
    return t


def face_indices(faces: Tensor | np.ndarray, num_vertices: int) -> Tensor:
    f = torch.as_tensor(faces)
    if f.is_floating_point() or f.dtype == torch.bool:
        raise ValueError(f"faces must be integers, got dtype {f.dtype}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {tuple(f.shape)}")
    f = f.to(dtype=torch.int64)
    if f.numel() and (int(f.min()) < 0 or int(f.max()) >= num_vertices):
        raise ValueError(
            f"faces index [{int(f.min())}, {int(f.max())}] but there are {num_vertices} vertices"
        )
    return f


def vertex_normals(vertices: Tensor | np.ndarray, faces: Tensor | np.ndarray) -> Tensor:
    """Area-weighted unit vertex normals.

    Each face adds its unnormalised normal ``(v1 - v0) x (v2 - v0)`` (length = twice its area,
    orientation by the right-hand rule on the corner order) to its three corners; the sums are
    normalised. Vertices used by no face, or whose faces cancel, get the zero vector.

    Args:
        vertices: (..., V, 3) positions (any units), optionally batched.
        faces: (F, 3) integer vertex indices.
    Returns:
        (..., V, 3) unit normals, dtype of ``vertices`` (float64 for arrays); differentiable.
    """
    v = float_tensor(vertices, "vertices")
    if v.ndim < 2 or v.shape[-1] != 3:
        raise ValueError(f"vertices must have shape (..., V, 3), got {tuple(v.shape)}")
    f = face_indices(faces, v.shape[-2]).to(v.device)
    v0, v1, v2 = v[..., f[:, 0], :], v[..., f[:, 1], :], v[..., f[:, 2], :]
    face_n = torch.cross(v1 - v0, v2 - v0, dim=-1)
    acc = torch.zeros_like(v)
    for k in range(3):
        acc = acc.index_add(-2, f[:, k], face_n)
    return F.normalize(acc, dim=-1)


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> object:
    """The cotangent Laplacian ``L`` of a triangle mesh, a (V, V) scipy CSR matrix with
    ``(L x)_i = Σ_j w_ij (x_i − x_j)``, ``w_ij = ½ (cot α_ij + cot β_ij)`` over the angles
    opposite edge (i, j) (one on a boundary edge). Symmetric, rows sum to 0; positive
    semi-definite when no angle is obtuse.

    Args:
        vertices: (V, 3) positions; faces: (F, 3) vertex indices.
    """
    import scipy.sparse as sp

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = f[:, (k + 1) % 3], f[:, (k + 2) % 3], f[:, k]  # edge (i, j) opposite o
        a, b = v[i] - v[o], v[j] - v[o]
        cross = np.linalg.norm(np.cross(a, b), axis=1)
        cot = np.einsum("nc,nc->n", a, b) / np.maximum(cross, 1e-20)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    n = len(v)
    W = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, n)).tocsr()  # fmt: skip
    return sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W


def ray_rotations(directions: Tensor) -> Tensor:
    """(..., 3, 3) the smallest rotations taking the camera's axis (0, 0, 1) to ``directions``
    (..., 3) (any length; Rodrigues' formula about their cross product with the axis, the
    identity where they are parallel to it). A direction pointing backwards (−z) turns
    about the camera's x axis."""
    d = directions / directions.norm(dim=-1, keepdim=True)
    x, y, c = d[..., 0], d[..., 1], d[..., 2]
    # K = [z]× for the unit axis k = z × d / |z × d|: R = I + sin K + (1 − cos) K², and with
    # z × d = (−y, x, 0) the terms combine into the closed form below (no division by sin).
    h = torch.where(c > -1 + 1e-9, 1.0 / (1.0 + c).clamp_min(1e-9), torch.zeros_like(c))
    r = torch.stack([
        torch.stack([1 - h * x * x, -h * x * y, x], dim=-1),
        torch.stack([-h * x * y, 1 - h * y * y, y], dim=-1),
        torch.stack([-x, -y, c], dim=-1),
    ], dim=-2)  # fmt: skip
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=d.dtype, device=d.device))
    return torch.where((c <= -1 + 1e-9)[..., None, None], flip, r)


def camera_rays(pixels: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(..., 2) pixel coordinates → (..., 3) their viewing rays K⁻¹ (x, y, 1)ᵀ in the camera
    frame (OpenCV axes, z = 1, float64); ``K`` (3, 3) the intrinsics, pixels."""
    px = np.asarray(pixels, dtype=np.float64)
    homogeneous = np.concatenate([px, np.ones((*px.shape[:-1], 1))], axis=-1)
    return homogeneous @ np.linalg.inv(np.asarray(K, dtype=np.float64)).T


def hip_ray_rotations(rays: Tensor) -> Tensor:
    """(..., 33, 3) viewing rays of mediapipe's landmarks (or camera-frame points; any length,
    z > 0) → (..., 3, 3) the *hip-ray frame*: the camera turned (:func:`ray_rotations`) so its
    axis bisects the two hips' rays; its columns are that frame's axes in camera
    coordinates."""
    unit = rays / rays.norm(dim=-1, keepdim=True)
    left, right = HIP_LANDMARKS
    return ray_rotations(0.5 * (unit[..., left, :] + unit[..., right, :]))
