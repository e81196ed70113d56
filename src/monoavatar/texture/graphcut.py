"""Texture merging by semantic graph cuts (Sec. C.3.4, Eq. C.16–C.20).

The median of :mod:`monoavatar.texture.backproject` mixes views per texel, so a view that is
misregistered by a few pixels drags a garment's colour over its neighbour's (skin on the shirt
at the shoulders, a hem smeared down the trousers). Here each texel takes its colour from *one*
view, chosen so that switches between views (seams) fall where they cannot be seen: on the
boundary between two semantic regions, or where the two views agree.

1. **Colour classes.** A Gaussian mixture in CIELab is fitted to the seen colours (the number of
   components picked by BIC); its components are the semantic labels (a garment, skin, hair, a
   print). Each view labels the texels it sees by their most likely class.
2. **Label fusion** (Eq. C.16–C.17): the UV label map minimises
   ``Σ_t φ_t(x_t) + Σ_(t,q) ψ(x_t, x_q)`` with ``φ_t(x) = 1 − Σ_k [X_k(t) = x] cos²α_kt / K_t``
   (``K_t`` the views seeing t) and the Potts term ``ψ = label_smoothness · [x_t ≠ x_q]`` over
   the texel graph, neighbours across UV seams included (alpha expansion).
3. **Merging** (Eq. C.18–C.20): every texel t holds a source view ``u_t``; the cost of view k
   at t is ``θ_t(k) = w_vis sin²α_kt + w_gmm m(U_k(t), x_t) + w_silh E_silh,k`` (Eq. C.19:
   viewing angle, Mahalanobis distance of the view's colour to its label's Gaussian, the view's
   silhouette error ``1 − IoU``). Repeatedly a view k is drawn (with probability ∝ 1 /
   E_silh,k) and a binary graph cut decides, for the texels k sees, whether to update to k or
   keep the current source; neighbours t, q of one label pay the seam cost (Eq. C.20)
   ``η = ½ (‖U_a(t) − U_b(t)‖ + ‖U_a(q) − U_b(q)‖)`` for sources a ≠ b, neighbours of
   different labels pay nothing.
4. **Cross-blending**: the one-hot source weights are averaged ``blend_steps`` times over the
   same-label texel graph, so a seam left inside a region fades over a few texels. Each
   source's colour at a texel is the mean of the views that agree with it there (within
   ``consensus``): noise averages out as in a median, a disagreeing view stays out.

The face-consistency term of Eq. C.19 is left out (docs/decisions.md). Colours are linear RGB in
[0, 1]; texels are the chart texels of a :class:`monoavatar.texture.atlas.TexelAtlas`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from monoavatar.texture.atlas import TextureError

__all__ = [
    "GraphCutSettings",
    "binary_cut",
    "colour_classes",
    "fuse_labels",
    "merge_views",
    "potts_expansion",
]

_BIG = 1e6  # unary cost that forbids a label


@dataclass(frozen=True)
class GraphCutSettings:
    """Options of :func:`merge_views`.

    Attributes:
        max_classes: most colour classes (semantic labels, at most 127); BIC picks from 2 to
            this.
        class_samples: seen colours the mixture is fitted on (a random subset).
        label_smoothness: Potts weight of label fusion (Eq. C.17), in units of φ.
        label_cycles: alpha-expansion cycles over all labels.
        w_vis, w_gmm, w_silh: weights of the viewing angle, colour and silhouette terms of
            Eq. C.19.
        seam_weight: weight of the seam cost of Eq. C.20 (colour distance, RGB in [0, 1]).
        sweeps: update/keep cuts per key frame (the views drawn are ``sweeps · F``).
        blend_steps: neighbourhood averages of the cross-blend (0: none).
        consensus: RGB distance; a texel's colour from its source view is averaged with the
            other views' colours there that lie this close to it (image noise averages out,
            a misregistered view's other colour does not come in); 0 takes the source alone.
        seed: seeds the mixture and the draws of views.
    """

    max_classes: int = 6
    class_samples: int = 20000
    label_smoothness: float = 0.5
    label_cycles: int = 3
    w_vis: float = 1.0
    w_gmm: float = 1.0
    w_silh: float = 1.0
    seam_weight: float = 1.0
    sweeps: int = 2
    blend_steps: int = 2
    consensus: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        if not 2 <= self.max_classes <= 127:
            raise TextureError(f"max_classes must lie in [2, 127], got {self.max_classes}")
        for name in ("class_samples", "label_cycles"):
            if getattr(self, name) < 1:
                raise TextureError(f"{name} must be at least 1, got {getattr(self, name)}")
        for name in ("label_smoothness", "w_vis", "w_gmm", "w_silh", "seam_weight",
                     "consensus"):  # fmt: skip
            if getattr(self, name) < 0:
                raise TextureError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("sweeps", "blend_steps"):
            if getattr(self, name) < 0:
                raise TextureError(f"{name} must be >= 0, got {getattr(self, name)}")


# -- graph cuts -------------------------------------------------------------------------------


def binary_cut(
    cost0: np.ndarray,
    cost1: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    e00: np.ndarray,
    e01: np.ndarray,
    e10: np.ndarray,
    e11: np.ndarray,
) -> np.ndarray:
    """Exact minimiser of a submodular binary energy by one max-flow (PyMaxflow).

    ``E(b) = Σ_t cost_{b_t}(t) + Σ_e E_{b_i b_j}(e)`` with the pairwise table
    ``(e00, e01, e10, e11)`` per edge ``(i, j)``; it must hold ``e00 + e11 <= e01 + e10``.
    The table is rewritten as ``e00 + (e10 − e00) b_i + (e11 − e10) b_j
    + (e01 + e10 − e00 − e11)(1 − b_i) b_j``, whose last term is one directed edge.

    Args:
        cost0, cost1: (N,) costs of labels 0 and 1.
        i, j: (E,) node indices; e00, e01, e10, e11: (E,) pairwise costs.
    Returns:
        (N,) bool, True where label 1 is chosen.
    """
    import maxflow

    n = cost0.shape[0]
    c0 = np.asarray(cost0, np.float64).copy()
    c1 = np.asarray(cost1, np.float64).copy()
    e00, e01, e10, e11 = (np.asarray(e, np.float64) for e in (e00, e01, e10, e11))
    cross = e01 + e10 - e00 - e11
    if (cross < -1e-9 * (1.0 + np.abs(e01) + np.abs(e10))).any():
        raise TextureError("binary_cut: the pairwise costs are not submodular")
    np.add.at(c1, i, e10 - e00)
    np.add.at(c1, j, e11 - e10)
    low = np.minimum(c0, c1)
    g = maxflow.Graph[float](n, len(i))
    nodes = g.add_nodes(n)
    # a node in the sink segment (label 1) cuts its source edge: capacity = cost of label 1
    g.add_grid_tedges(nodes, c1 - low, c0 - low)
    if len(i):
        g.add_edges(np.asarray(i, np.int64), np.asarray(j, np.int64),
                    np.maximum(cross, 0.0), np.zeros(len(i)))  # fmt: skip
    g.maxflow()
    return np.asarray(g.get_grid_segments(nodes), dtype=bool)


def potts_expansion(
    unary: np.ndarray, i: np.ndarray, j: np.ndarray, weight: np.ndarray | float, cycles: int = 3
) -> np.ndarray:
    """Alpha expansion for ``Σ_t unary[t, x_t] + Σ_e weight_e [x_i ≠ x_j]`` (Eq. C.17).

    Starts from the per-node minimum and expands every label ``cycles`` times (or until no
    expansion lowers the energy); within a factor 2 of the optimum.

    Args:
        unary: (N, L) costs; i, j: (E,) edges; weight: (E,) or a scalar, non-negative.
    Returns:
        (N,) int labels.
    """
    n, n_labels = unary.shape
    w = np.broadcast_to(np.asarray(weight, np.float64), (len(i),))
    x = np.argmin(unary, axis=1)
    rows = np.arange(n)

    def energy(lab: np.ndarray) -> float:
        return float(unary[rows, lab].sum() + (w * (lab[i] != lab[j])).sum())

    best = energy(x)
    for _ in range(cycles):
        improved = False
        for a in range(n_labels):
            e00 = w * (x[i] != x[j])
            e01 = w * (x[i] != a)
            e10 = w * (x[j] != a)
            move = binary_cut(unary[rows, x], unary[:, a], i, j, e00, e01, e10, np.zeros_like(w))
            cand = np.where(move, a, x)
            e = energy(cand)
            if e < best - 1e-9:
                x, best, improved = cand, e, True
        if not improved:
            break
    return x


# -- semantic labels --------------------------------------------------------------------------


def to_lab(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) RGB in [0, 1] → CIELab (L in [0, 100])."""
    import cv2

    flat = np.clip(np.asarray(rgb, np.float32).reshape(-1, 1, 3), 0.0, 1.0)
    return np.asarray(cv2.cvtColor(flat, cv2.COLOR_RGB2Lab)).reshape(np.shape(rgb))


def colour_classes(colours: np.ndarray, settings: GraphCutSettings) -> object:
    """A full-covariance Gaussian mixture over CIELab colours, 2..``max_classes`` components by
    BIC (a sklearn ``GaussianMixture``).

    Args:
        colours: (M, 3) RGB in [0, 1], M >= 2.
    """
    from sklearn.mixture import GaussianMixture

    rng = np.random.default_rng(settings.seed)
    if len(colours) > settings.class_samples:
        colours = colours[rng.choice(len(colours), settings.class_samples, replace=False)]
    lab = to_lab(colours).astype(np.float64)
    best, best_bic = None, np.inf
    for k in range(2, min(settings.max_classes, max(len(lab) // 10, 2)) + 1):
        gmm = GaussianMixture(k, covariance_type="full", reg_covar=1e-2,
                              random_state=settings.seed).fit(lab)  # fmt: skip
        bic = gmm.bic(lab)
        if bic < best_bic:
            best, best_bic = gmm, bic
    return best


def fuse_labels(
    view_labels: np.ndarray,
    cos: np.ndarray,
    n_labels: int,
    i: np.ndarray,
    j: np.ndarray,
    settings: GraphCutSettings,
) -> np.ndarray:
    """The UV label map of Eq. C.16–C.17.

    Args:
        view_labels: (F, N) int label of each texel in each view (any value where unseen).
        cos: (F, N) cosine of each view's viewing angle, 0 where the view does not see it.
        n_labels: L; i, j: (E,) texel-graph edges.
    Returns:
        (N,) int labels; texels no view sees take their neighbours' labels.
    """
    seen = cos > 0
    votes = np.zeros((cos.shape[1], n_labels))
    w = np.where(seen, cos.astype(np.float64) ** 2, 0.0)
    for k in range(n_labels):
        votes[:, k] = (w * (view_labels == k)).sum(axis=0)
    count = seen.sum(axis=0)
    phi = 1.0 - votes / np.maximum(count, 1)[:, None]
    phi[count == 0] = 1.0
    return potts_expansion(phi, i, j, settings.label_smoothness, settings.label_cycles)


# -- merging ----------------------------------------------------------------------------------


def _mahalanobis(gmm: object, lab: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(M,) Mahalanobis distance of Lab colours (M, 3) to the Gaussian of their label (M,)."""
    means = gmm.means_  # type: ignore[attr-defined]
    prec = gmm.precisions_cholesky_  # type: ignore[attr-defined]  # (L, 3, 3)
    d = lab - means[labels]
    z = np.einsum("mc,mcd->md", d, prec[labels])
    return np.asarray(np.sqrt((z * z).sum(axis=1)))


def _seam(
    colours: np.ndarray, seen: np.ndarray, a: np.ndarray, b: np.ndarray,
    t: np.ndarray, q: np.ndarray, unseen: float,
) -> np.ndarray:  # fmt: skip
    """(E,) seam cost of Eq. C.20 between texels t and q (E,) showing views a and b (E,):
    the mean over both texels of the two views' colour distance (``unseen`` where one of the
    views does not see the texel), 0 where a = b."""
    out = np.zeros(len(t))
    for p in (t, q):
        diff = np.linalg.norm(
            colours[a, p].astype(np.float32) - colours[b, p].astype(np.float32), axis=1
        )
        both = seen[a, p] & seen[b, p]
        out += 0.5 * np.where(both, diff, unseen)
    out[a == b] = 0.0
    return out


def _consensus(colours: np.ndarray, seen: np.ndarray, view: int, texels: np.ndarray,
               radius: float) -> np.ndarray:  # fmt: skip
    """(M, 3) colours of ``view`` at ``texels`` (M,), each averaged with the other views that
    see the texel within ``radius`` (RGB distance) of it; ``radius`` 0 keeps the view's own."""
    own = colours[view, texels].astype(np.float32)
    if radius <= 0:
        return own
    total = np.zeros_like(own)
    count = np.zeros(len(texels), np.float32)
    for k in range(colours.shape[0]):
        c = colours[k, texels].astype(np.float32)
        near = seen[k, texels] & (np.linalg.norm(c - own, axis=1) < radius)
        total[near] += c[near]
        count += near
    return np.where(count[:, None] > 0, total / np.maximum(count, 1.0)[:, None], own)


def merge_views(
    colours: np.ndarray,
    cos: np.ndarray,
    silhouette_error: np.ndarray,
    graph: sp.spmatrix,
    settings: GraphCutSettings | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Merge per-view texel colours into one texture by semantic graph cuts (steps 1–4 of the
    module docstring).

    Args:
        colours: (F, N, 3) RGB in [0, 1] of each chart texel in each view (float16 will do).
        cos: (F, N) float cosine of the viewing angle; 0 where the view does not see the texel.
        silhouette_error: (F,) ``1 − IoU`` of each view's rendered and observed silhouettes.
        graph: (N, N) texel graph (:func:`monoavatar.texture.atlas.texel_graph`).
        settings: :class:`GraphCutSettings`.
    Returns:
        (N, 3) float32 colours (0 where no view sees the texel) and (N,) int semantic labels.
    """
    s = settings or GraphCutSettings()
    n_views, n = cos.shape
    if colours.shape != (n_views, n, 3) or silhouette_error.shape != (n_views,):
        raise TextureError(
            f"colours {colours.shape}, cos {cos.shape} and silhouette_error "
            f"{silhouette_error.shape} must agree on (F, N)"
        )
    seen = cos > 0
    any_seen = seen.any(axis=0)
    out = np.zeros((n, 3), np.float32)
    upper = sp.triu(sp.csr_matrix(graph), k=1).tocoo()
    ei, ej = upper.row.astype(np.int64), upper.col.astype(np.int64)
    if not any_seen.any():
        return out, np.zeros(n, np.int64)

    # 1. colour classes and per-view labels
    fv, ft = np.nonzero(seen)
    sample = colours[fv, ft].astype(np.float32)
    gmm = colour_classes(sample, s)
    n_labels = int(gmm.n_components)  # type: ignore[attr-defined]
    lab = to_lab(sample).astype(np.float64)
    view_labels = np.zeros((n_views, n), np.int8)
    view_labels[fv, ft] = gmm.predict(lab)  # type: ignore[attr-defined]

    # 2. label fusion
    labels = fuse_labels(view_labels, cos, n_labels, ei, ej, s)

    # 3. per-view cost θ (Eq. C.19), BIG where unseen
    theta = np.full((n_views, n), _BIG, np.float32)
    c = cos[fv, ft].astype(np.float64)
    theta[fv, ft] = (
        s.w_vis * (1.0 - c * c)
        + s.w_gmm * _mahalanobis(gmm, lab, labels[ft])
        + s.w_silh * silhouette_error[fv]
    )
    source = np.argmin(theta, axis=0)
    same = labels[ei] == labels[ej]
    si, sj = ei[same], ej[same]
    unseen_seam = 1.0  # colour distance charged for a view that does not see the texel
    rng = np.random.default_rng(s.seed)
    p = 1.0 / np.maximum(silhouette_error, 1e-3)
    p /= p.sum()
    for k in rng.choice(n_views, size=s.sweeps * n_views, p=p):
        nodes = np.flatnonzero(seen[k])
        if nodes.size == 0:
            continue
        local = np.full(n, -1, np.int64)
        local[nodes] = np.arange(nodes.size)
        cost0 = theta[source[nodes], nodes].copy()
        cost1 = theta[k, nodes].copy()
        inside_i, inside_j = local[si] >= 0, local[sj] >= 0
        # edges with both ends among the candidates: a pairwise table
        both = inside_i & inside_j
        t, q = si[both], sj[both]
        ut, uq, kb = source[t], source[q], np.full(len(t), k)
        e00 = s.seam_weight * _seam(colours, seen, ut, uq, t, q, unseen_seam)
        e01 = s.seam_weight * _seam(colours, seen, ut, kb, t, q, unseen_seam)
        e10 = s.seam_weight * _seam(colours, seen, kb, uq, t, q, unseen_seam)
        e00 = np.minimum(e00, e01 + e10)  # keep the table submodular
        # edges with one end outside: that end keeps its source, a unary term for the other
        out_j, out_i = inside_i & ~inside_j, ~inside_i & inside_j
        for t_in, q_out in ((si[out_j], sj[out_j]), (sj[out_i], si[out_i])):
            uq = source[q_out]
            keep = _seam(colours, seen, source[t_in], uq, t_in, q_out, unseen_seam)
            upd = _seam(colours, seen, np.full(len(t_in), k), uq, t_in, q_out, unseen_seam)
            np.add.at(cost0, local[t_in], s.seam_weight * keep)
            np.add.at(cost1, local[t_in], s.seam_weight * upd)
        update = binary_cut(cost0, cost1, local[t], local[q], e00, e01, e10, np.zeros_like(e00))
        source[nodes[update]] = k

    # 4. cross-blend over the same-label graph
    used, src = np.unique(source, return_inverse=True)
    weights = np.zeros((n, len(used)), np.float32)
    weights[np.arange(n), src] = 1.0
    if s.blend_steps and len(si):
        adj = sp.coo_matrix((np.ones(2 * len(si), np.float32),
                             (np.r_[si, sj], np.r_[sj, si])), shape=(n, n)).tocsr()  # fmt: skip
        degree = np.asarray(adj.sum(axis=1)).ravel().astype(np.float32)
        for _ in range(s.blend_steps):
            weights = (weights + adj @ weights) / (1.0 + degree)[:, None]
    weights *= seen[used].T
    total = weights.sum(axis=1)
    weights[total == 0, src[total == 0]] = 1.0
    weights /= np.maximum(weights.sum(axis=1), 1e-12)[:, None]
    for m, view in enumerate(used):
        at = np.flatnonzero(weights[:, m] > 0)
        out[at] += weights[at, m : m + 1] * _consensus(colours, seen, view, at, s.consensus)
    out[~any_seen] = 0.0
    return out, labels
