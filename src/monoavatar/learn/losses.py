"""Image losses for training image-to-image networks: SSIM and multi-scale SSIM, masked L1,
and the least-squares GAN losses. Pure functions of (B, C, H, W) tensors.

SSIM (Wang et al. 2004), per pixel, from local statistics under a Gaussian window of
standard deviation σ (pixels), truncated to ``window`` taps:

``SSIM = l · cs``, ``l = (2 μx μy + C1) / (μx² + μy² + C1)``,
``cs = (2 σxy + C2) / (σx² + σy² + C2)``, ``C1 = (0.01 L)²``, ``C2 = (0.03 L)²``,

with L the ``data_range`` (max − min of the data: 1 for images in [0, 1], 2 for normals and
displacements in [−1, 1]) and population (not sample) variances. Borders are extended by
symmetric reflection (``d c b a | a b c d``, scipy's ``"reflect"``), so the map has the size
of the image and equals scikit-image's ``structural_similarity(..., gaussian_weights=True,
use_sample_covariance=False, full=True)`` map.

MS-SSIM (Wang et al. 2003) over M scales, each half the size of the previous one (2×2 means,
the last row or column of an odd size kept on its own):
``MS-SSIM = Π_{j<M} mean(cs_j)^{w_j} · mean(SSIM_M)^{w_M}``, per image and channel, then
averaged over channels. The default weights are the standard five-scale ones
(0.0448, 0.2856, 0.3001, 0.2363, 0.1333), truncated to M and renormalised to sum 1. Each mean
is floored at 1e-4 before its power, so that anti-correlated structure (cs < 0, possible for
data of either sign) gives a finite value and gradient instead of NaN.

Masks. A mask (B, 1, H, W) of weights in [0, 1] makes the losses ignore what lies where it is
0: the local statistics are weighted by it (normalised convolution,
``μx = G ∗ (m x) / G ∗ m``, likewise for the second moments), the maps are averaged with it,
and the images are downsampled with it (``x_{j+1} = pool(m x) / pool(m)``,
``m_{j+1} = pool(m)``). A pixel of weight 0 therefore has no influence at all on the result
(as long as its value is finite). With a mask of ones the definitions are the unmasked ones.
An image whose mask is all 0 has MS-SSIM 1 (nothing to compare).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import torch
from torch import Tensor
from torch.nn import functional as F

from monoavatar.core.errors import MonoavatarError

__all__ = [
    "MS_SSIM_WEIGHTS",
    "LossInputError",
    "lsgan_discriminator_loss",
    "lsgan_generator_loss",
    "masked_cross_entropy",
    "masked_l1",
    "ms_dssim",
    "ms_ssim",
    "ssim_map",
]

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
"""Wang et al. (2003)'s weights of the five scales, finest first."""

_K1 = 0.01
_K2 = 0.03
_FLOOR = 1e-4  # lower bound of each scale's mean before the power (see the module docstring)
_TINY = 1e-12  # lower bound of a normalising weight (its numerator is then 0 too)

Reduction = Literal["mean", "none"]


class LossInputError(MonoavatarError, ValueError):
    """Inputs of a loss that do not fit each other or its settings."""


def _check_pair(x: Tensor, y: Tensor, mask: Tensor | None) -> None:
    if x.ndim != 4 or x.shape != y.shape:
        raise LossInputError(
            f"the two images must be (B, C, H, W) of one shape, got {tuple(x.shape)} and "
            f"{tuple(y.shape)}"
        )
    if mask is not None and (
        mask.ndim != 4 or mask.shape[1] != 1 or mask.shape[0] != x.shape[0]
        or mask.shape[2:] != x.shape[2:]
    ):  # fmt: skip
        b, _, h, w = x.shape
        raise LossInputError(
            f"the mask must be ({b}, 1, {h}, {w}) for images {tuple(x.shape)}, "
            f"got {tuple(mask.shape)}"
        )


def _check_window(window: int, sigma: float, data_range: float) -> None:
    if window < 1 or window % 2 == 0:
        raise LossInputError(f"window must be an odd number of pixels, got {window}")
    if not sigma > 0:
        raise LossInputError(f"sigma must be positive, got {sigma}")
    if not data_range > 0:
        raise LossInputError(f"data_range must be positive, got {data_range}")


def _gaussian(window: int, sigma: float, like: Tensor) -> Tensor:
    """(window,) normalised Gaussian taps, centred, in ``like``'s dtype and device."""
    r = window // 2
    t = torch.arange(-r, r + 1, dtype=torch.float64)
    g = torch.exp(-(t**2) / (2.0 * sigma**2))
    return (g / g.sum()).to(dtype=like.dtype, device=like.device)


def _pad_symmetric(x: Tensor, pad: int) -> Tensor:
    """(…, H, W) -> (…, H + 2 pad, W + 2 pad), edges mirrored including the edge pixel."""
    if pad == 0:
        return x
    x = torch.cat([x[..., :pad].flip(-1), x, x[..., -pad:].flip(-1)], dim=-1)
    return torch.cat([x[..., :pad, :].flip(-2), x, x[..., -pad:, :].flip(-2)], dim=-2)


def _blur(x: Tensor, taps: Tensor) -> Tensor:
    """Separable Gaussian filter of every channel of (B, K, H, W), same size."""
    k = x.shape[1]
    w = taps.numel()
    h = _pad_symmetric(x, w // 2)
    h = F.conv2d(h, taps.view(1, 1, 1, w).expand(k, 1, 1, w), groups=k)
    return F.conv2d(h, taps.view(1, 1, w, 1).expand(k, 1, w, 1), groups=k)


def _ssim_terms(
    x: Tensor, y: Tensor, mask: Tensor | None, taps: Tensor, data_range: float
) -> tuple[Tensor, Tensor]:
    """Luminance ``l`` and contrast-structure ``cs`` maps, each (B, C, H, W)."""
    c = x.shape[1]
    if mask is None:
        stats = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), taps)
    else:
        mx, my = mask * x, mask * y
        blurred = _blur(torch.cat([mask, mx, my, mx * x, my * y, mx * y], dim=1), taps)
        stats = blurred[:, 1:] / blurred[:, :1].clamp_min(_TINY)
    mu_x, mu_y, xx, yy, xy = stats.split(c, dim=1)
    var_x = (xx - mu_x * mu_x).clamp_min(0.0)
    var_y = (yy - mu_y * mu_y).clamp_min(0.0)
    cov = xy - mu_x * mu_y
    c1 = (_K1 * data_range) ** 2
    c2 = (_K2 * data_range) ** 2
    lum = (2.0 * mu_x * mu_y + c1) / (mu_x * mu_x + mu_y * mu_y + c1)
    cs = (2.0 * cov + c2) / (var_x + var_y + c2)
    return lum, cs


def _check_size(height: int, width: int, window: int, scales: int) -> None:
    h, w = height, width
    for _ in range(scales - 1):
        h, w = (h + 1) // 2, (w + 1) // 2
    if min(h, w) < window // 2:
        raise LossInputError(
            f"images of {height}×{width} are {h}×{w} at the coarsest of {scales} scales, "
            f"smaller than half the {window}-pixel window; use fewer scales or a smaller window"
        )


def ssim_map(
    x: Tensor,
    y: Tensor,
    window: int = 11,
    sigma: float = 1.5,
    data_range: float = 1.0,
    mask: Tensor | None = None,
) -> Tensor:
    """Per-pixel SSIM of x and y (module docstring: definition, borders, mask).

    Args:
        x, y: (B, C, H, W), H and W at least ``window // 2``.
        window: odd number of Gaussian taps; sigma: their standard deviation, pixels.
        data_range: L, the data's max − min.
        mask: optional (B, 1, H, W) weights of the local statistics.

    Returns:
        (B, C, H, W) SSIM in [−1, 1].

    Raises:
        LossInputError: shapes that do not match, bad window, sigma or range.
    """
    _check_pair(x, y, mask)
    _check_window(window, sigma, data_range)
    _check_size(x.shape[2], x.shape[3], window, 1)
    lum, cs = _ssim_terms(x, y, mask, _gaussian(window, sigma, x), data_range)
    return lum * cs


def _downsample(x: Tensor, y: Tensor, mask: Tensor | None
                ) -> tuple[Tensor, Tensor, Tensor | None]:  # fmt: skip
    """Halve x, y (and the mask) by 2×2 means; mask-weighted means where there is a mask."""
    if mask is None:
        return F.avg_pool2d(x, 2, ceil_mode=True), F.avg_pool2d(y, 2, ceil_mode=True), None
    m = F.avg_pool2d(mask, 2, ceil_mode=True)
    inv = 1.0 / m.clamp_min(_TINY)
    x = F.avg_pool2d(mask * x, 2, ceil_mode=True) * inv
    y = F.avg_pool2d(mask * y, 2, ceil_mode=True) * inv
    return x, y, m


def _mean(values: Tensor, mask: Tensor | None) -> Tensor:
    """(B, C, H, W) -> (B, C) mean over pixels, weighted by the mask if any."""
    if mask is None:
        return values.mean(dim=(-2, -1))
    total = (values * mask).sum(dim=(-2, -1))
    return total / mask.sum(dim=(-2, -1)).clamp_min(_TINY)


def _scale_weights(scales: int, weights: Sequence[float] | None) -> list[float]:
    if scales < 1:
        raise LossInputError(f"scales must be at least 1, got {scales}")
    if weights is None:
        if scales > len(MS_SSIM_WEIGHTS):
            raise LossInputError(
                f"the standard weights cover {len(MS_SSIM_WEIGHTS)} scales, got scales={scales}; "
                "pass weights"
            )
        weights = MS_SSIM_WEIGHTS[:scales]
    weights = [float(w) for w in weights]
    if len(weights) != scales:
        raise LossInputError(f"{scales} scales need {scales} weights, got {len(weights)}")
    if any(not (w >= 0 and math.isfinite(w)) for w in weights) or sum(weights) <= 0:
        raise LossInputError(f"weights must be non-negative with a positive sum, got {weights}")
    total = sum(weights)
    return [w / total for w in weights]


def ms_ssim(
    x: Tensor,
    y: Tensor,
    mask: Tensor | None = None,
    scales: int = 4,
    weights: Sequence[float] | None = None,
    window: int = 11,
    sigma: float = 1.5,
    data_range: float = 1.0,
    reduction: Reduction = "mean",
) -> Tensor:
    """Multi-scale SSIM (module docstring: definition, floor, mask).

    Args:
        x, y: (B, C, H, W); H and W at least ``window // 2 · 2^(scales − 1)``.
        mask: optional (B, 1, H, W) weights in [0, 1].
        scales: M; weights: M non-negative numbers (normalised here), finest first; None:
            the standard ones, truncated to M and renormalised.
        window, sigma, data_range: as :func:`ssim_map`.
        reduction: ``"mean"``: a scalar, the mean over the batch; ``"none"``: (B,).

    Returns:
        MS-SSIM in (0, 1], a scalar or (B,).

    Raises:
        LossInputError: shapes that do not match, images too small for the scales, bad
            settings.
    """
    _check_pair(x, y, mask)
    _check_window(window, sigma, data_range)
    w = _scale_weights(scales, weights)
    _check_size(x.shape[2], x.shape[3], window, scales)
    taps = _gaussian(window, sigma, x)
    present = None if mask is None else mask.sum(dim=(1, 2, 3)) > 0
    means: list[Tensor] = []
    for j in range(scales):
        lum, cs = _ssim_terms(x, y, mask, taps, data_range)
        if j < scales - 1:
            means.append(_mean(cs, mask))
            x, y, mask = _downsample(x, y, mask)
        else:
            means.append(_mean(lum * cs, mask))
    exponents = torch.tensor(w, dtype=x.dtype, device=x.device).view(-1, 1, 1)
    per_channel = (torch.stack(means).clamp_min(_FLOOR) ** exponents).prod(dim=0)
    value = per_channel.mean(dim=1)
    if present is not None:
        value = torch.where(present, value, torch.ones_like(value))
    return value.mean() if reduction == "mean" else value


def ms_dssim(
    x: Tensor,
    y: Tensor,
    mask: Tensor | None = None,
    scales: int = 4,
    weights: Sequence[float] | None = None,
    window: int = 11,
    sigma: float = 1.5,
    data_range: float = 1.0,
    reduction: Reduction = "mean",
) -> Tensor:
    """Structural dissimilarity ``(1 − MS-SSIM) / 2`` in [0, 1/2); arguments as
    :func:`ms_ssim`."""
    value = ms_ssim(x, y, mask, scales, weights, window, sigma, data_range, reduction)
    return (1.0 - value) / 2.0


def masked_l1(x: Tensor, y: Tensor, mask: Tensor) -> Tensor:
    """Weighted mean absolute difference ``Σ m |x − y| / (C Σ m)`` over the whole batch.

    Args:
        x, y: (B, C, H, W).
        mask: (B, 1, H, W) weights in [0, 1], the same for every channel.

    Returns:
        A scalar; 0 if the mask is all 0.
    """
    _check_pair(x, y, mask)
    total = (mask * (x - y).abs()).sum()
    return total / (mask.sum() * x.shape[1]).clamp_min(_TINY)


def masked_cross_entropy(logits: Tensor, probabilities: Tensor, mask: Tensor) -> Tensor:
    """Weighted mean cross-entropy of per-pixel class ``logits`` against target class
    ``probabilities``: ``Σ m · (−Σ_k p_k log softmax(l)_k) / Σ m`` over the whole batch.

    Args:
        logits: (B, K, H, W) unnormalised class scores.
        probabilities: (B, K, H, W) target class probabilities (one-hot, or soft where a
            pixel straddles classes), summing to 1 over K where the mask is not 0.
        mask: (B, 1, H, W) weights in [0, 1].

    Returns:
        A scalar, nats; 0 if the mask is all 0.
    """
    _check_pair(logits, probabilities, mask)
    nll = -(probabilities * torch.log_softmax(logits, dim=1)).sum(dim=1, keepdim=True)
    return (mask * nll).sum() / mask.sum().clamp_min(_TINY)


def lsgan_discriminator_loss(real_logits: Tensor, fake_logits: Tensor) -> Tensor:
    """Least-squares GAN loss of the discriminator (Mao et al. 2017), targets 1 and 0:
    ``(mean((D(real) − 1)²) + mean(D(fake)²)) / 2``. Logits of any shape; a scalar."""
    return 0.5 * ((real_logits - 1.0).square().mean() + fake_logits.square().mean())


def lsgan_generator_loss(fake_logits: Tensor) -> Tensor:
    """Least-squares GAN loss of the generator, target 1: ``mean((D(fake) − 1)²) / 2``.
    A scalar."""
    return 0.5 * (fake_logits - 1.0).square().mean()
