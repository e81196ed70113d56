"""Sparse mesh operators for the consensus-shape regularisers (Sec. B.3.3, Eq. B.9 and B.11).

Pure functions of a mesh's connectivity (and of the body model's mirror map); they return
``scipy.sparse`` matrices acting on one coordinate of the per-vertex values (V,).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges (E, 2), ``i < j``, of a triangle list (F, 3)."""
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {f.shape}")
    pairs = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0)


def uniform_laplacian(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """The uniform (graph) Laplacian ``L = I − D⁻¹ A`` of a mesh, (V, V).

    ``(L x)_i = x_i − mean of x over i's neighbours``: the offset of a vertex from the centroid
    of its one-ring (the differential coordinate δ_i of Eq. B.9 when applied to positions).
    Vertices without neighbours get a zero row.
    """
    edges = mesh_edges(faces)
    if edges.size and edges.max() >= num_vertices:
        raise ValueError(f"faces index vertex {edges.max()} but num_vertices={num_vertices}")
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    adjacency = sp.csr_matrix(
        (np.ones(len(rows)), (rows, cols)), shape=(num_vertices, num_vertices)
    )
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    inv = np.divide(1.0, degree, out=np.zeros_like(degree), where=degree > 0)
    identity = sp.diags((degree > 0).astype(np.float64))
    return (identity - sp.diags(inv) @ adjacency).tocsr()


def edge_laplacian(
    faces: np.ndarray, num_vertices: int, vertex_weights: np.ndarray | None = None
) -> sp.csr_matrix:
    """The weighted combinatorial Laplacian K (V, V) with ``xᵀ K x = Σ_edges τ_ij (x_i − x_j)²``,
    ``τ_ij`` the mean of the two vertices' weights (1 when None): a membrane energy."""
    edges = mesh_edges(faces)
    w = np.ones(len(edges))
    if vertex_weights is not None:
        vw = np.asarray(vertex_weights, dtype=np.float64)
        w = 0.5 * (vw[edges[:, 0]] + vw[edges[:, 1]])
    i, j = edges[:, 0], edges[:, 1]
    rows = np.concatenate([i, j, i, j])
    cols = np.concatenate([i, j, j, i])
    vals = np.concatenate([w, w, -w, -w])
    return sp.csr_matrix((vals, (rows, cols)), shape=(num_vertices, num_vertices))


def symmetry_operators(mirror: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Residual operators of the symmetry term (Eq. B.11) for mirror pairs ``(i, mirror[i])``.

    The term is ``Σ_i |diag(−1, 1, 1) d_i − d_mirror(i)|²``; on the x coordinate its residual
    is ``(−I − P) d_x``, on y and z ``(I − P) d_y``, with P the permutation ``(P d)_i =
    d_mirror(i)``. Returns ``(S_x, S_yz)``, each (V, V).
    """
    m = np.asarray(mirror, dtype=np.int64)
    n = len(m)
    if m.ndim != 1 or (n and (m.min() < 0 or m.max() >= n)):
        raise ValueError("mirror must be a (V,) array of vertex indices in [0, V)")
    perm = sp.csr_matrix((np.ones(n), (np.arange(n), m)), shape=(n, n))
    identity = sp.identity(n, format="csr")
    return (-identity - perm).tocsr(), (identity - perm).tocsr()
