"""The U-Net and the PatchGAN: shapes, the errors for inputs that do not fit, parameter counts
against the layer formulas, the PatchGAN's 70-pixel receptive field, and a U-Net that can
learn one example by heart."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import torch
from torch import nn
from torch.nn import functional as F

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.threads import torch_threads
from monoavatar.learn.networks import (
    ClassMixture,
    NetworkConfigError,
    NetworkInputError,
    PatchDiscriminator,
    UNet,
    count_parameters,
)


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """Tiny tensors: one PyTorch thread (a second one would only wait for a busy core)."""
    with torch_threads(1):
        yield


@pytest.mark.parametrize(
    ("depth", "shape"),
    [(1, (1, 3, 2, 2)), (3, (2, 3, 8, 8)), (3, (1, 3, 16, 24)), (2, (3, 3, 20, 12))],
)
def test_unet_keeps_the_image_size(depth: int, shape: tuple[int, int, int, int]) -> None:
    net = UNet(3, 5, base=4, depth=depth)
    out = net(torch.randn(shape))
    assert out.shape == (shape[0], 5, shape[2], shape[3])
    assert out.is_contiguous()
    assert torch.isfinite(out).all()


def test_the_default_unet_takes_multiples_of_64() -> None:
    net = UNet(3, 6)
    assert net(torch.randn(1, 3, 64, 128)).shape == (1, 6, 64, 128)
    with pytest.raises(NetworkInputError, match="multiples of 64, got 96×128"):
        net(torch.randn(1, 3, 96, 128))


def test_unet_errors_say_what_does_not_fit() -> None:
    net = UNet(3, 1, base=4, depth=3)
    with pytest.raises(NetworkInputError, match="multiples of 8, got 12×16") as info:
        net(torch.randn(1, 3, 12, 16))
    assert isinstance(info.value, MonoavatarError) and isinstance(info.value, ValueError)
    with pytest.raises(NetworkInputError, match="3 input channels, got 4"):
        net(torch.randn(1, 4, 16, 16))
    with pytest.raises(NetworkInputError, match=r"\(B, C, H, W\)"):
        net(torch.randn(3, 16, 16))
    with pytest.raises(NetworkConfigError, match="depth must be at least 1"):
        UNet(3, 1, depth=0)


def _conv(cin: int, cout: int, k: int) -> int:
    return k * k * cin * cout + cout


def test_parameter_count_follows_the_layer_formulas() -> None:
    """The default U-Net counted layer by layer from the architecture: 4×4 encoder
    convolutions (GroupNorm's scale and shift on all but the first), 3×3 decoder
    convolutions into the skip widths, the full-resolution convolutions of the input and of the
    last upsampled features, then the 3×3 head; under 10 M."""
    c_in, c_out, base, depth, cap = 3, 6, 32, 6, 256
    widths = [min(base * 2**i, cap) for i in range(depth)]
    expected, previous = 0, c_in
    for i, w in enumerate(widths):
        expected += _conv(previous, w, 4) + (2 * w if i else 0)
        previous = w
    features = widths[-1]
    for i in range(depth - 1, 0, -1):
        expected += _conv(features, widths[i - 1], 3) + 2 * widths[i - 1]
        features = 2 * widths[i - 1]
    full = base // 2
    expected += _conv(c_in, full, 3)  # full-resolution convolution of the input
    expected += _conv(features, full, 3) + 2 * full  # last upsampled features
    expected += _conv(2 * full, c_out, 3)
    net = UNet(c_in, c_out)
    assert count_parameters(net) == expected
    assert count_parameters(net) < 10_000_000
    assert count_parameters(nn.Conv2d(3, 4, 3)) == 3 * 4 * 9 + 4


def test_patch_discriminator_output_size_and_parameters() -> None:
    d = PatchDiscriminator(9)
    assert d(torch.randn(2, 9, 256, 256)).shape == (2, 1, 30, 30)
    assert d(torch.randn(1, 9, 64, 96)).shape == (1, 1, 6, 10)
    # 4×4 convolutions 9→32→64→128→256→1, GroupNorm on the middle three.
    widths = [9, 32, 64, 128, 256, 1]
    expected = sum(_conv(a, b, 4) for a, b in zip(widths, widths[1:], strict=False))
    expected += 2 * (64 + 128 + 256)
    assert count_parameters(d) == expected
    with pytest.raises(NetworkInputError, match="at least 24×24, got 16×16"):
        d(torch.randn(1, 9, 16, 16))
    with pytest.raises(NetworkInputError, match="9 input channels, got 3"):
        d(torch.randn(1, 3, 64, 64))


def test_patch_discriminator_sees_70_by_70_pixels() -> None:
    """Receptive field of one logit, from the gradient of a network without its GroupNorms
    (which couple all pixels through their statistics)."""
    torch.manual_seed(0)
    d = PatchDiscriminator(2, base=8)
    for i, layer in enumerate(d.net):
        if isinstance(layer, nn.GroupNorm):
            d.net[i] = nn.Identity()
    x = torch.randn(1, 2, 128, 128, requires_grad=True)
    out = d(x)
    out[0, 0, 7, 7].backward()
    assert x.grad is not None
    seen = x.grad.abs().sum(dim=(0, 1)) > 0
    rows = seen.any(dim=1).nonzero()
    cols = seen.any(dim=0).nonzero()
    assert int(rows.max() - rows.min()) + 1 == 70
    assert int(cols.max() - cols.min()) + 1 == 70


def test_unet_learns_one_example_by_heart() -> None:
    """A smooth field plus a pixel-level copy of one input channel: 150 Adam steps bring the
    L1 error down more than tenfold."""
    torch.manual_seed(0)
    net = UNet(3, 2, base=8, depth=3)
    x = torch.randn(1, 3, 32, 32)
    smooth = F.interpolate(torch.randn(1, 2, 4, 4), size=(32, 32), mode="bicubic")
    target = smooth + 0.3 * x[:, 1:]
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    losses = []
    for _ in range(150):
        loss = (net(x) - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] / 10


class _Fixed(nn.Module):
    """A 'network' that answers a fixed output whatever its input."""

    def __init__(self, out: torch.Tensor) -> None:
        super().__init__()
        self.out = nn.Parameter(out.clone())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out.expand(x.shape[0], *self.out.shape[1:])


def test_class_mixture_answers_the_recognised_classs_means() -> None:
    """Logits sure of class j at a pixel and no residual give M_j there; equal logits give the
    classes' average; the residual adds scale · r; the logits come out after the maps."""
    k, c, h, w = 3, 2, 4, 5
    means = torch.randn(k, c, h, w, generator=torch.Generator().manual_seed(0))
    out = torch.zeros(1, c + k, h, w)
    out[0, c + 1, :, :3] = 50.0  # class 1 on the left, equal logits on the right
    net = ClassMixture(_Fixed(out), means, scale=0.5)
    y = net(torch.zeros(2, 1, h, w))
    assert y.shape == (2, c + k, h, w)
    assert torch.allclose(y[:, :c, :, :3], means[1, :, :, :3].expand(2, c, h, 3), atol=1e-6)
    assert torch.allclose(y[:, :c, :, 3:], means[:, :, :, 3:].mean(0).expand(2, c, h, 2),
                          atol=1e-6)  # fmt: skip
    assert torch.equal(y[:, c:], out.expand(2, -1, -1, -1)[:, c:])
    out2 = out.clone()
    out2[0, :c] = 2.0
    y2 = ClassMixture(_Fixed(out2), means, scale=0.5)(torch.zeros(1, 1, h, w))
    assert torch.allclose(y2[:, :c] - y[:1, :c], torch.ones(1, c, h, w), atol=1e-6)


def test_class_mixture_gradient_reaches_the_logits_and_checks_shapes() -> None:
    k, c, h, w = 2, 1, 2, 2
    means = torch.stack([torch.zeros(c, h, w), torch.ones(c, h, w)])
    fixed = _Fixed(torch.zeros(1, c + k, h, w))
    net = ClassMixture(fixed, means)
    net(torch.zeros(1, 1, h, w))[:, :c].sum().backward()
    grad = fixed.out.grad
    assert grad is not None
    # d/dl1 of softmax(l)_1 at l = 0 is 1/4 per pixel; d/dl0 is −1/4
    assert torch.allclose(grad[0, c + 1], torch.full((h, w), 0.25))
    assert torch.allclose(grad[0, c], torch.full((h, w), -0.25))
    with pytest.raises(NetworkInputError, match="does not match"):
        ClassMixture(_Fixed(torch.zeros(1, c + k + 1, h, w)), means)(torch.zeros(1, 1, h, w))
    with pytest.raises(NetworkConfigError):
        ClassMixture(fixed, torch.zeros(c, h, w))
