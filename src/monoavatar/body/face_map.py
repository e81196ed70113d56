"""Where the 468 face-mesh landmarks lie on the body model's surface (Paper C, Sec. C.3.2).

The face term of the detailed reconstruction pulls fixed points of the body's surface towards
the rays of the face-mesh landmarks detected in a frame. Each landmark is a point on one
triangle of the body mesh, given by the triangle's index and barycentric coordinates, so the
map holds for any shape and pose of the same mesh. The shipped map of Anny's mesh is built by
:func:`monoavatar.learn.face_map.build_face_map` (a render of the average body, the face mesh
run on it, the landmarks back-projected) and stored in ``body/data/face_map_anny.npz``.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from monoavatar.body.model import BodyModel, BodyModelError
from monoavatar.core.files import atomic_write_npz
from monoavatar.core.landmarks import NUM_FACE_LANDMARKS

__all__ = ["FaceMap", "load_face_map", "shipped_face_map_path"]


@dataclass(frozen=True)
class FaceMap:
    """The face-mesh landmarks as points on a mesh's triangles.

    Attributes:
        triangles: (468,) int64 index of each landmark's triangle in the mesh's faces.
        bary: (468, 3) float64 barycentric coordinates in that triangle (rows sum to 1).
        num_vertices, num_faces: the mesh the map belongs to.
    """

    triangles: np.ndarray
    bary: np.ndarray
    num_vertices: int
    num_faces: int

    def __post_init__(self) -> None:
        n = NUM_FACE_LANDMARKS
        if self.triangles.shape != (n,) or self.bary.shape != (n, 3):
            raise BodyModelError(f"a face map has {n} triangles and barycentric rows, got "
                                 f"{self.triangles.shape} and {self.bary.shape}")  # fmt: skip
        if (self.triangles < 0).any() or (self.triangles >= self.num_faces).any():
            raise BodyModelError("a face map's triangle index lies outside its mesh")
        if not np.allclose(self.bary.sum(1), 1.0, atol=1e-6) or (self.bary < -1e-6).any():
            raise BodyModelError("a face map's barycentric coordinates must be >= 0 and sum to 1")

    def points(self, vertices: Tensor, faces: Tensor) -> Tensor:
        """(..., V, 3) vertices of the mesh with faces (F, 3) → (..., 468, 3) the landmarks'
        surface points (differentiable in the vertices)."""
        if vertices.shape[-2] != self.num_vertices or faces.shape[0] != self.num_faces:
            raise BodyModelError(
                f"this face map belongs to a mesh of {self.num_vertices} vertices and "
                f"{self.num_faces} faces, not {vertices.shape[-2]} and {faces.shape[0]}"
            )
        corners = faces[torch.as_tensor(self.triangles)]  # (468, 3)
        w = torch.as_tensor(self.bary, dtype=vertices.dtype, device=vertices.device)
        return torch.einsum("...lkc,lk->...lc", vertices[..., corners, :], w)

    def save(self, path: str | Path) -> None:
        atomic_write_npz(path, triangles=self.triangles.astype(np.int64), bary=self.bary,
                         num_vertices=np.int64(self.num_vertices),
                         num_faces=np.int64(self.num_faces))  # fmt: skip

    @classmethod
    def load(cls, path: str | Path) -> FaceMap:
        with np.load(path, allow_pickle=False) as data:
            return cls(np.asarray(data["triangles"], np.int64),
                       np.asarray(data["bary"], np.float64), int(data["num_vertices"]),
                       int(data["num_faces"]))  # fmt: skip


def shipped_face_map_path(name: str = "anny") -> Path:
    """The shipped map of a body model's mesh (``anny``: Anny's, with or without its local
    shape changes, which share the mesh)."""
    return Path(str(resources.files("monoavatar.body") / "data" / f"face_map_{name}.npz"))


def load_face_map(body: BodyModel) -> FaceMap:
    """The shipped face map of ``body``'s mesh.

    Raises:
        BodyModelError: none is shipped for this body model (only Anny's is).
    """
    path = shipped_face_map_path("anny")
    face_map = FaceMap.load(path) if path.is_file() else None
    if face_map is None or (face_map.num_vertices, face_map.num_faces) != (
            body.num_vertices, int(body.faces.shape[0])):  # fmt: skip
        raise BodyModelError(f"no face map is shipped for the body model {body.identity!r} "
                             "(only for Anny's mesh): build one with "
                             "monoavatar.learn.face_map.build_face_map")  # fmt: skip
    return face_map
