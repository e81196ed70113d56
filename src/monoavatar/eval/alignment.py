"""Similarity alignment of corresponding point sets (Umeyama, closed form).

A similarity transform maps a point ``x`` (metres) to ``scale * rotation @ x + translation``.
:func:`align_similarity` finds the one that minimises the (weighted) mean squared distance
between transformed source points and their corresponding target points [Umeyama 1991,
"Least-squares estimation of transformation parameters between two point patterns",
IEEE TPAMI 13(4)]. The rotation is always proper (``det = +1``): mirrored data yields the best
rotation, never a reflection.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from monoavatar.eval._checks import FloatArray, as_points

__all__ = ["SimilarityTransform", "align_similarity"]


@dataclass(frozen=True)
class SimilarityTransform:
    """``x ↦ scale * rotation @ x + translation`` for points ``x`` in metres.

    Attributes:
        rotation: (3, 3) proper rotation matrix (orthonormal, determinant +1).
        translation: (3,) translation in metres.
        scale: unitless isotropic scale (1.0 for a rigid transform); positive, except 0.0 from
            :func:`align_similarity` when all target points coincide.
    """

    rotation: FloatArray
    translation: FloatArray
    scale: float = 1.0

    @classmethod
    def identity(cls) -> SimilarityTransform:
        """The transform that leaves every point where it is."""
        return cls(rotation=np.eye(3), translation=np.zeros(3), scale=1.0)

    def apply(self, points: ArrayLike) -> FloatArray:
        """Transform points.

        Args:
            points: (N, 3) points in metres.

        Returns:
            (N, 3) float64 transformed points in metres.
        """
        p = as_points("points", points)
        out: FloatArray = self.scale * (p @ self.rotation.T) + self.translation
        return out

    @property
    def matrix(self) -> FloatArray:
        """(4, 4) homogeneous matrix ``[[s R, t], [0, 1]]``."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m

    def inverse(self) -> SimilarityTransform:
        """The transform ``y ↦ rotationᵀ (y - translation) / scale``."""
        r_inv = self.rotation.T
        return SimilarityTransform(
            rotation=r_inv,
            translation=-(r_inv @ self.translation) / self.scale,
            scale=1.0 / self.scale,
        )

    def compose(self, first: SimilarityTransform) -> SimilarityTransform:
        """The transform ``x ↦ self(first(x))`` (``first`` is applied first)."""
        return SimilarityTransform(
            rotation=self.rotation @ first.rotation,
            translation=self.scale * (self.rotation @ first.translation) + self.translation,
            scale=self.scale * first.scale,
        )


def align_similarity(
    source: ArrayLike,
    target: ArrayLike,
    with_scale: bool = True,
    weights: ArrayLike | None = None,
) -> SimilarityTransform:
    """Closed-form least-squares similarity (or rigid) transform from ``source`` to ``target``.

    Minimises ``Σ_i w_i |scale * R @ source_i + t - target_i|²`` over proper rotations ``R``
    (``det R = +1``), translations ``t`` and, if ``with_scale``, a scale ``scale > 0``
    (Umeyama 1991). When the optimal orthogonal matrix would be a reflection (e.g. for
    mirrored data) the sign of the axis of the smallest singular value is flipped, which gives
    the best *proper* rotation; a reflection is never returned.

    Args:
        source: (N, 3) points in metres, ``N >= 1``.
        target: (N, 3) corresponding points in metres (row ``i`` corresponds to row ``i``).
        with_scale: also estimate a scale; if False the transform is rigid (scale 1).
        weights: optional (N,) non-negative weights (relative; they are normalised); default
            uniform.

    Returns:
        The transform mapping ``source`` onto ``target``.

    Raises:
        ValueError: on shape mismatch, invalid weights, or ``with_scale`` with a source whose
            (weighted) points all coincide (scale undefined).
    """
    src = as_points("source", source, min_count=1)
    tgt = as_points("target", target, min_count=1)
    if src.shape != tgt.shape:
        raise ValueError(f"source and target: shapes differ, {src.shape} vs {tgt.shape}")
    n = src.shape[0]
    if weights is None:
        w = np.full(n, 1.0 / n)
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (n,):
            raise ValueError(f"weights: expected shape ({n},), got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError("weights: must be finite, non-negative and not all zero")
        w = w / w.sum()

    mu_src = w @ src
    mu_tgt = w @ tgt
    src_c = src - mu_src
    tgt_c = tgt - mu_tgt
    var_src = float(w @ np.einsum("ij,ij->i", src_c, src_c))
    cov = (tgt_c * w[:, None]).T @ src_c  # (3, 3): Σ_i w_i (y_i - μ_y)(x_i - μ_x)ᵀ

    u, d, vt = np.linalg.svd(cov)
    signs = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        signs[2] = -1.0
    rotation = (u * signs) @ vt

    if with_scale:
        if var_src <= 1e-300:
            raise ValueError("source: all points coincide, the scale is undefined")
        scale = float(np.dot(d, signs) / var_src)
    else:
        scale = 1.0
    translation = mu_tgt - scale * (rotation @ mu_src)
    return SimilarityTransform(rotation=rotation, translation=translation, scale=scale)
