"""Mesh subdivision that carries UVs and skinning weights along (Sec. C.3.1, Eq. C.3; Sec. E.4.1).

Every edge (i, j) gets a new vertex ``v_{N+e} = ½ (v_i + v_j) + s_e n_e`` (Eq. C.3), with
``n_e`` the mean of the two vertex normals in the canonical pose and ``s_e`` a displacement
along it (0 for plain 4-way midpoint subdivision, Sec. E.4.1). Each triangle becomes four. UVs,
which are indexed separately (seams), are subdivided on their own index set; skinning weights
of a new vertex are the mean of its edge's two vertices. :func:`smooth_displacement` gives the
``s_e`` of the smoothest fine surface through the coarse vertices (Eq. C.4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from monoavatar.core.geometry import cotangent_laplacian, vertex_normals


def _edges_and_faces(faces: np.ndarray, offset: int) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges (E, 2) of a triangle list and its 4-way split (4F, 3), new vertex of edge e
    at index ``offset + e``."""
    corners = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1)  # (F,3,2)
    keys = np.sort(corners.reshape(-1, 2), axis=1)
    edges, inverse = np.unique(keys, axis=0, return_inverse=True)
    mid = offset + inverse.reshape(-1, 3)  # (F, 3): midpoints of edges 01, 12, 20
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    m01, m12, m20 = mid[:, 0], mid[:, 1], mid[:, 2]
    new_faces = np.concatenate(
        [
            np.stack([a, m01, m20], 1),
            np.stack([m01, b, m12], 1),
            np.stack([m20, m12, c], 1),
            np.stack([m01, m12, m20], 1),
        ]
    )
    return edges, new_faces


@dataclass
class Subdivision:
    """One level of subdivision of a mesh with separately indexed UVs.

    Attributes:
        edges: (E, 2) vertex pairs; new vertex e has index V + e.
        faces: (4F, 3) subdivided faces.
        uv: (T + E_uv, 2) subdivided UVs; face_uv: (4F, 3).
        weights: (V + E, J) skinning weights.
        num_coarse: V.
    """

    edges: Tensor
    faces: Tensor
    uv: Tensor
    face_uv: Tensor
    weights: Tensor
    num_coarse: int

    def apply(
        self,
        vertices: Tensor,
        displacement: Tensor | None = None,
        normals: Tensor | None = None,
        coarse_faces: Tensor | None = None,
    ) -> Tensor:
        """Fine vertices from coarse ones (Eq. C.3).

        Args:
            vertices: (B, V, 3) coarse vertices (canonical pose).
            displacement: (B, E) or (E,) ``s_e`` along the edge normals, metres; None = 0.
            normals: (B, V, 3) coarse vertex normals; computed from ``coarse_faces`` if None.
        Returns:
            (B, V + E, 3).
        """
        a, b = vertices[:, self.edges[:, 0]], vertices[:, self.edges[:, 1]]
        new = 0.5 * (a + b)
        if displacement is not None:
            if normals is None:
                if coarse_faces is None:
                    raise ValueError("displacement needs normals or coarse_faces")
                normals = vertex_normals(vertices, coarse_faces)
            n = normals[:, self.edges[:, 0]] + normals[:, self.edges[:, 1]]
            n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
            new = new + displacement.unsqueeze(-1) * n
        return torch.cat([vertices, new], dim=1)


def subdivide(faces: Tensor, uv: Tensor, face_uv: Tensor, weights: Tensor) -> Subdivision:
    """Subdivide a mesh's connectivity, UVs and weights once (4-way split).

    Args:
        faces: (F, 3) long; uv: (T, 2); face_uv: (F, 3) long; weights: (V, J).
    """
    f = faces.cpu().numpy()
    V = weights.shape[0]
    edges, new_faces = _edges_and_faces(f, V)
    uv_edges, new_face_uv = _edges_and_faces(face_uv.cpu().numpy(), uv.shape[0])
    uv_e = torch.as_tensor(uv_edges, device=uv.device)
    new_uv = torch.cat([uv, 0.5 * (uv[uv_e[:, 0]] + uv[uv_e[:, 1]])])
    e = torch.as_tensor(edges, device=weights.device)
    new_w = torch.cat([weights, 0.5 * (weights[e[:, 0]] + weights[e[:, 1]])])
    return Subdivision(
        edges=e,
        faces=torch.as_tensor(new_faces, device=faces.device),
        uv=new_uv,
        face_uv=torch.as_tensor(new_face_uv, device=face_uv.device),
        weights=new_w,
        num_coarse=V,
    )


def smooth_displacement(sub: Subdivision, vertices: Tensor | np.ndarray,
                        coarse_faces: Tensor | np.ndarray) -> Tensor:  # fmt: skip
    """The displacements ``s`` (E,) of Eq. C.4: the fine surface through the coarse vertices
    whose new vertices, moved along their edge normals (Eq. C.3), minimise ``‖L M_f‖²``, L the
    cotangent Laplacian of the midpoint-subdivided mesh (its weights held fixed), metres.

    A linear least-squares problem in ``s``; solved by its normal equations (sparse, E × E).

    Args:
        sub: the subdivision; vertices: (V, 3) coarse canonical vertices, metres;
        coarse_faces: (F, 3) their faces.
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    v = torch.as_tensor(np.asarray(vertices, np.float64))[None]
    n = vertex_normals(v, torch.as_tensor(np.asarray(coarse_faces)))
    edges = sub.edges.cpu().numpy()
    e_n = (n[0, edges[:, 0]] + n[0, edges[:, 1]]).numpy()
    e_n /= np.maximum(np.linalg.norm(e_n, axis=1, keepdims=True), 1e-12)
    mid = sub.apply(v)[0].numpy()  # s = 0
    L = sp.csr_matrix(cotangent_laplacian(mid, sub.faces.cpu().numpy()))
    new = L[:, sub.num_coarse :]
    # L (mid + N s) per coordinate c: L mid_c + L_new diag(n_c) s
    A = sp.vstack([new @ sp.diags(e_n[:, c]) for c in range(3)]).tocsr()
    b = -np.concatenate([L @ mid[:, c] for c in range(3)])
    AtA = (A.T @ A).tocsc()
    ridge = 1e-9 * float(AtA.diagonal().mean())  # edges that no residual sees stay at 0
    s = spla.spsolve(AtA + ridge * sp.identity(AtA.shape[0], format="csc"), A.T @ b)
    return torch.as_tensor(np.asarray(s))
