"""SSIM, MS-SSIM, masked L1 and the LSGAN losses: against scikit-image and an independent
numpy/scipy MS-SSIM, float64 gradient checks, the mask's exact ignorance of what lies under
its zeros, and finite values for anti-correlated data of either sign."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter
from skimage.metrics import structural_similarity

from monoavatar.core.threads import torch_threads
from monoavatar.learn.losses import (
    MS_SSIM_WEIGHTS,
    LossInputError,
    lsgan_discriminator_loss,
    lsgan_generator_loss,
    masked_cross_entropy,
    masked_l1,
    ms_dssim,
    ms_ssim,
    ssim_map,
)


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """Tiny tensors: one PyTorch thread (a second one would only wait for a busy core)."""
    with torch_threads(1):
        yield


def _pair(shape: tuple[int, ...], seed: int = 0, dtype: torch.dtype = torch.float64
          ) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """x uniform in [-1, 1]; y a scaled, noisy copy, clipped to [-1, 1]."""
    gen = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=gen, dtype=dtype) * 2 - 1
    noise = 0.4 * torch.randn(shape, generator=gen, dtype=dtype)
    y = (0.8 * x + noise).clamp(-1, 1)
    return x, y


def test_identical_images_have_ms_ssim_one_and_dssim_zero() -> None:
    x, _ = _pair((2, 3, 48, 40))
    mask = (torch.rand(2, 1, 48, 40, generator=torch.Generator().manual_seed(1)) > 0.3).double()
    for m in (None, mask):
        value = ms_ssim(x, x, m, data_range=2.0, reduction="none")
        torch.testing.assert_close(value, torch.ones(2, dtype=torch.float64))
        assert float(ms_dssim(x, x, m, data_range=2.0)) == pytest.approx(0.0, abs=1e-12)
    torch.testing.assert_close(ssim_map(x, x, data_range=2.0), torch.ones_like(x))


@pytest.mark.parametrize("data_range", [1.0, 2.0])
def test_ssim_map_equals_scikit_image(data_range: float) -> None:
    x, y = _pair((1, 3, 37, 45), seed=2)
    if data_range == 1.0:
        x, y = (x + 1) / 2, (y + 1) / 2
    mean, full = structural_similarity(
        x[0].numpy(), y[0].numpy(), channel_axis=0, gaussian_weights=True, sigma=1.5,
        use_sample_covariance=False, data_range=data_range, full=True,
    )  # fmt: skip
    ours = ssim_map(x, y, data_range=data_range)[0].numpy()
    np.testing.assert_allclose(ours, full, atol=1e-10)  # the whole map, borders included
    assert ours[:, 5:-5, 5:-5].mean() == pytest.approx(mean, abs=1e-10)  # skimage's mean
    ours32 = ssim_map(x.float(), y.float(), data_range=data_range)[0].numpy()
    assert ours32[:, 5:-5, 5:-5].mean() == pytest.approx(mean, abs=1e-4)


def _reference_ms_ssim(x: np.ndarray, y: np.ndarray, weights: list[float], L: float) -> float:
    """MS-SSIM of two (H, W) images written from the definition (scipy's Gaussian filter, 2×2
    block means), for sizes divisible by 2^(M-1)."""
    c1, c2 = (0.01 * L) ** 2, (0.03 * L) ** 2
    w = np.asarray(weights) / np.sum(weights)
    value = 1.0
    for j, wj in enumerate(w):

        def g(a: np.ndarray) -> np.ndarray:
            return gaussian_filter(a, 1.5, mode="reflect", truncate=3.5)

        mx, my = g(x), g(y)
        vx, vy, cxy = g(x * x) - mx**2, g(y * y) - my**2, g(x * y) - mx * my
        cs = (2 * cxy + c2) / (vx + vy + c2)
        if j == len(w) - 1:
            term = ((2 * mx * my + c1) / (mx**2 + my**2 + c1) * cs).mean()
        else:
            term = cs.mean()
            h, wd = x.shape
            x = x.reshape(h // 2, 2, wd // 2, 2).mean(axis=(1, 3))
            y = y.reshape(h // 2, 2, wd // 2, 2).mean(axis=(1, 3))
        value *= max(term, 1e-4) ** wj
    return value


@pytest.mark.parametrize("scales", [1, 3, 5])
def test_ms_ssim_follows_its_definition(scales: int) -> None:
    x, y = _pair((2, 2, 96, 80), seed=3)
    ours = ms_ssim(x, y, scales=scales, data_range=2.0, reduction="none").numpy()
    for b in range(2):
        expected = np.mean([
            _reference_ms_ssim(x[b, c].numpy(), y[b, c].numpy(),
                               list(MS_SSIM_WEIGHTS[:scales]), 2.0)
            for c in range(2)
        ])  # fmt: skip
        assert ours[b] == pytest.approx(expected, abs=1e-10)
    weights = [1.0, 2.0, 3.0][:scales] if scales <= 3 else None
    if weights is not None:
        custom = ms_ssim(x[:1], y[:1], scales=scales, weights=weights, data_range=2.0)
        ref = np.mean([_reference_ms_ssim(x[0, c].numpy(), y[0, c].numpy(), weights, 2.0)
                       for c in range(2)])  # fmt: skip
        assert float(custom) == pytest.approx(ref, abs=1e-10)


def test_anti_correlated_data_stays_finite() -> None:
    """y = −x: cs < 0 at every scale; the floor keeps value and gradient finite."""
    x, _ = _pair((1, 2, 32, 32), seed=4)
    x.requires_grad_(True)
    value = ms_ssim(x, -x.detach(), scales=3, data_range=2.0)
    value.backward()
    assert torch.isfinite(value) and 0 < float(value.detach()) < 0.1
    assert x.grad is not None and torch.isfinite(x.grad).all()


def test_gradients_match_finite_differences() -> None:
    x, y = _pair((1, 2, 12, 14), seed=5)
    mask = 0.2 + 0.8 * torch.rand(1, 1, 12, 14, generator=torch.Generator().manual_seed(6),
                                  dtype=torch.float64)  # fmt: skip
    mask[..., :3, :4] = 0.0

    def loss(a: torch.Tensor) -> torch.Tensor:
        return ms_dssim(a, y, mask, scales=2, window=5, sigma=1.0, data_range=2.0)

    assert torch.autograd.gradcheck(loss, (x.clone().requires_grad_(True),))
    assert torch.autograd.gradcheck(
        lambda a: ssim_map(a, y, window=5, sigma=1.0, data_range=2.0, mask=mask),
        (x.clone().requires_grad_(True),),
    )
    assert torch.autograd.gradcheck(
        lambda a: masked_l1(a, y, mask), (x.clone().requires_grad_(True),)
    )


def test_what_lies_under_a_zero_weight_changes_nothing() -> None:
    x, y = _pair((2, 3, 64, 64), seed=7, dtype=torch.float32)
    mask = torch.zeros(2, 1, 64, 64)
    mask[:, :, 10:50, 5:40] = 1.0
    mask[1, :, 20:30, 20:60] = 0.5
    changed = torch.where(mask > 0, y, torch.randn(y.shape) * 5)
    assert not torch.equal(changed, y)
    for fn in (ms_ssim, ms_dssim):
        before = fn(x, y, mask, data_range=2.0, reduction="none")
        after = fn(x, changed, mask, data_range=2.0, reduction="none")
        assert torch.equal(before, after)
    assert torch.equal(masked_l1(x, y, mask), masked_l1(x, changed, mask))
    torch.testing.assert_close(  # the same loss as the unmasked one when the mask is all 1
        ms_ssim(x, y, torch.ones_like(mask), data_range=2.0), ms_ssim(x, y, data_range=2.0)
    )


def test_an_empty_mask_counts_as_perfect() -> None:
    x, y = _pair((2, 1, 32, 32), seed=8)
    mask = torch.ones(2, 1, 32, 32, dtype=torch.float64)
    mask[1] = 0.0
    x.requires_grad_(True)
    value = ms_ssim(x, y, mask, scales=3, data_range=2.0, reduction="none")
    reference = ms_ssim(x[:1], y[:1], scales=3, data_range=2.0)
    assert float(value[1].detach()) == 1.0
    assert float(value[0].detach()) == pytest.approx(float(reference.detach()))
    value.sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and not x.grad[1].any()
    assert float(masked_l1(x, y, torch.zeros_like(mask)).detach()) == 0.0


def test_masked_l1_and_lsgan_by_hand() -> None:
    x, y = _pair((2, 3, 5, 4), seed=9)
    mask = torch.rand(2, 1, 5, 4, generator=torch.Generator().manual_seed(10), dtype=torch.float64)
    m, d = mask.numpy(), np.abs(x.numpy() - y.numpy())
    expected = (m * d).sum() / (3 * m.sum())
    assert float(masked_l1(x, y, mask)) == pytest.approx(expected, rel=1e-12)
    real = torch.tensor([[0.5, 2.0], [1.0, -1.0]])
    fake = torch.tensor([0.0, 1.0, -0.5])
    assert float(lsgan_discriminator_loss(real, fake)) == pytest.approx(
        0.5 * ((0.25 + 1 + 0 + 4) / 4 + (0 + 1 + 0.25) / 3)
    )
    assert float(lsgan_generator_loss(fake)) == pytest.approx(0.5 * (1 + 0 + 2.25) / 3)


def test_inputs_that_do_not_fit_are_refused() -> None:
    x, y = _pair((1, 3, 32, 32))
    with pytest.raises(LossInputError, match="one shape"):
        ms_ssim(x, y[:, :2])
    with pytest.raises(LossInputError, match=r"mask must be \(1, 1, 32, 32\)"):
        ms_ssim(x, y, torch.ones(1, 3, 32, 32))
    with pytest.raises(LossInputError, match="coarsest of 4 scales"):
        ms_ssim(x, y, scales=4)  # 32 -> 4 pixels, under half the 11-pixel window
    with pytest.raises(LossInputError, match="odd"):
        ssim_map(x, y, window=4)
    with pytest.raises(LossInputError, match="3 scales need 3 weights"):
        ms_ssim(x, y, scales=3, weights=[1.0, 1.0])
    with pytest.raises(LossInputError, match="standard weights cover 5"):
        ms_ssim(x, y, scales=6)
    with pytest.raises(LossInputError, match="mask must be"):
        masked_l1(x, y, torch.ones(1, 1, 16, 32))


def test_masked_cross_entropy_equals_pytorchs_on_hard_labels() -> None:
    """One-hot targets: the per-pixel mean of F.cross_entropy over the weighted pixels."""
    gen = torch.Generator().manual_seed(4)
    logits = torch.randn(2, 5, 6, 7, generator=gen, dtype=torch.float64)
    labels = torch.randint(0, 5, (2, 6, 7), generator=gen)
    onehot = torch.nn.functional.one_hot(labels, 5).permute(0, 3, 1, 2).double()
    mask = (torch.rand(2, 1, 6, 7, generator=gen) > 0.3).double()
    per_pixel = torch.nn.functional.cross_entropy(logits, labels, reduction="none")
    expected = (per_pixel * mask[:, 0]).sum() / mask.sum()
    assert torch.allclose(masked_cross_entropy(logits, onehot, mask), expected)


def test_masked_cross_entropy_closed_forms() -> None:
    """Equal logits cost log K whatever the target; a soft target (p, 1 − p) against the
    logits (log p, log(1 − p)) costs its entropy; an empty mask costs nothing."""
    k = 5
    uniform = torch.zeros(1, k, 3, 3, dtype=torch.float64)
    target = torch.zeros(1, k, 3, 3, dtype=torch.float64)
    target[:, 2] = 1.0
    ones = torch.ones(1, 1, 3, 3, dtype=torch.float64)
    assert torch.allclose(masked_cross_entropy(uniform, target, ones),
                          torch.tensor(np.log(k), dtype=torch.float64))  # fmt: skip
    p = 0.3
    soft = torch.tensor([p, 1 - p], dtype=torch.float64).view(1, 2, 1, 1).expand(1, 2, 3, 3)
    entropy = -(p * np.log(p) + (1 - p) * np.log(1 - p))
    assert abs(float(masked_cross_entropy(soft.log(), soft, ones)) - entropy) < 1e-12
    assert float(masked_cross_entropy(uniform, target, 0 * ones)) == 0.0
