"""Filling texture holes: a harmonic (Laplace) fill over the surface's texel graph, and dilation
beyond the chart borders.

Texels never seen get the colour of the harmonic function that equals the seen colours on the
seen texels: each unseen texel is the mean of its graph neighbours (``L x = 0`` on the unseen
set, Dirichlet data on the seen one). Because the graph of
:func:`monoavatar.texture.atlas.texel_graph` links texels across UV seams, colour flows between
charts that meet on the surface rather than between charts that happen to be close in the image.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["dilate_texture", "harmonic_fill"]

# Weight of the pull of every unseen texel towards the mean seen colour; keeps the system
# regular where a connected group of unseen texels touches no seen one.
_ANCHOR = 1e-6


def harmonic_fill(graph: sp.spmatrix, values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Harmonic interpolation of ``values`` from the ``known`` nodes of a graph.

    Args:
        graph: (N, N) symmetric sparse non-negative edge weights.
        values: (N, C) values; rows where ``known`` is False are ignored.
        known: (N,) bool.
    Returns:
        (N, C) float64: ``values`` on known nodes; on the others the solution of
        ``sum_j w_ij (x_i - x_j) = 0``. Groups of unknown nodes that touch no known node get
        the mean known value; zeros everywhere when nothing is known.
    """
    W = sp.csr_matrix(graph, dtype=np.float64)
    vals = np.asarray(values, dtype=np.float64)
    if vals.ndim == 1:
        vals = vals[:, None]
    known = np.asarray(known, dtype=bool)
    n = W.shape[0]
    if W.shape != (n, n) or vals.shape[0] != n or known.shape != (n,):
        raise ValueError(
            f"graph {W.shape}, values {vals.shape} and known {known.shape} must agree on N"
        )
    out = vals.copy()
    unknown = np.flatnonzero(~known)
    if unknown.size == 0:
        return out
    if not known.any():
        out[:] = 0.0
        return out
    mean = vals[known].mean(axis=0)
    W_uu = W[unknown][:, unknown]
    W_uk = W[unknown][:, np.flatnonzero(known)]
    degree = np.asarray(W[unknown].sum(axis=1)).ravel()
    A = sp.diags(degree + _ANCHOR) - W_uu
    b = W_uk @ vals[known] + _ANCHOR * mean[None, :]
    solve = spla.factorized(sp.csc_matrix(A))
    out[unknown] = np.stack([solve(b[:, c]) for c in range(b.shape[1])], axis=1)
    return out


def dilate_texture(
    image: np.ndarray, valid: np.ndarray, iterations: int, fill_rest: bool = True
) -> np.ndarray:
    """Grow a texture beyond its valid texels, so that bilinear and mipmapped lookups near chart
    borders do not mix in background.

    Each iteration gives every invalid texel with a valid 8-neighbour the mean of its valid
    neighbours, and marks it valid.

    Args:
        image: (S, S, C) float texture.
        valid: (S, S) bool.
        iterations: rings of texels to add (>= 0).
        fill_rest: give texels still invalid afterwards the mean valid colour.
    Returns:
        (S, S, C) float32 texture (valid texels unchanged).
    """
    import cv2

    out = np.array(image, dtype=np.float32, copy=True)
    ok = np.array(valid, dtype=bool, copy=True)
    if not ok.any():
        return out
    for _ in range(max(0, int(iterations))):
        w = ok.astype(np.float32)
        total = cv2.boxFilter(out * w[..., None], -1, (3, 3), normalize=False,
                              borderType=cv2.BORDER_CONSTANT)  # fmt: skip
        count = cv2.boxFilter(w, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        grow = (count > 0) & ~ok
        if not grow.any():
            break
        out[grow] = total[grow] / count[grow][:, None]
        ok |= grow
    if fill_rest and not ok.all():
        out[~ok] = out[ok].mean(axis=0)
    return out
