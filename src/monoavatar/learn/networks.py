"""Image-to-image networks in the style of Tex2Shape (Sec. E.5.1–E.5.2), after pix2pix
(Isola et al. 2017): a U-Net generator and a PatchGAN discriminator.

:class:`UNet` maps a (B, C_in, H, W) image to a (B, C_out, H, W) image of the same size.
Encoder: ``depth`` 4×4 convolutions of stride 2, channels ``min(base · 2^i, max_channels)``
at level i (level i has size H / 2^(i+1)); GroupNorm after every one but the first;
LeakyReLU (slope 0.2). Decoder: at every level, bilinear ×2 upsampling followed by a 3×3
convolution (resize-convolution: no checkerboard pattern, unlike strided transposed
convolutions), GroupNorm and ReLU, then concatenation with the encoder's features of the
same size. At full resolution the last upsampled features (3×3 convolution, GroupNorm, ReLU,
``base / 2`` channels) are concatenated with a 3×3 convolution of the input (LeakyReLU,
``base / 2`` channels: bilinear upsampling alone cannot carry pixel-level detail), and a 3×3
convolution gives the output, with no activation (targets are real-valued, e.g.
displacements and normals). GroupNorm (8 groups, fewer where the channel count is not a
multiple of 8) rather than BatchNorm: batches are small, and an image's result does not
depend on the rest of its batch. With no dropout and no batch statistic, ``train()`` and
``eval()`` compute the same function. On the CPU the layers run in channels-last layout
(oneDNN's fast one); the output is contiguous either way.

:class:`PatchDiscriminator` is the 70×70 PatchGAN (with ``layers=3``): a stack of 4×4
convolutions whose every output logit sees a 70×70 window of the input.
"""

from __future__ import annotations

import math
from typing import cast

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from monoavatar.core.errors import MonoavatarError

__all__ = [
    "ClassMixture",
    "NetworkConfigError",
    "NetworkInputError",
    "PatchDiscriminator",
    "UNet",
    "count_parameters",
]

_SLOPE = 0.2  # LeakyReLU slope of the encoder and the discriminator (pix2pix)
_GROUPS = 8  # GroupNorm groups (fewer where the channel count is not a multiple)


class NetworkConfigError(MonoavatarError, ValueError):
    """A network was asked for with impossible sizes (e.g. zero channels)."""


class NetworkInputError(MonoavatarError, ValueError):
    """An input tensor does not fit the network: wrong rank, channel count or image size."""


def count_parameters(module: nn.Module) -> int:
    """Number of scalar parameters of ``module`` (all of them, trainable or not; no buffers)."""
    return sum(p.numel() for p in module.parameters())


def _norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(math.gcd(channels, _GROUPS), channels)


def _check_positive(**values: int) -> None:
    for name, value in values.items():
        if value < 1:
            raise NetworkConfigError(f"{name} must be at least 1, got {value}")


def _check_image(x: Tensor, channels: int, network: str) -> None:
    if x.ndim != 4:
        raise NetworkInputError(
            f"{network} takes a (B, C, H, W) tensor, got shape {tuple(x.shape)}"
        )
    if x.shape[1] != channels:
        raise NetworkInputError(
            f"{network} takes {channels} input channels, got {x.shape[1]} (shape {tuple(x.shape)})"
        )


class UNet(nn.Module):
    """U-Net image-to-image generator (see the module docstring for the layers).

    Args:
        in_channels: C_in.
        out_channels: C_out.
        base: channels of the first encoder level.
        depth: number of stride-2 levels; H and W must be multiples of 2^depth.
        max_channels: cap on any level's channels.

    ``forward(x)``: x (B, C_in, H, W) -> (B, C_out, H, W).

    Raises:
        NetworkConfigError: a size below 1.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        base: int = 32,
        depth: int = 6,
        max_channels: int = 256,
    ) -> None:
        super().__init__()
        _check_positive(
            in_channels=in_channels,
            out_channels=out_channels,
            base=base,
            depth=depth,
            max_channels=max_channels,
        )
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.depth = depth
        widths = [min(base * 2**i, max_channels) for i in range(depth)]

        self.down = nn.ModuleList()
        previous = in_channels
        for i, width in enumerate(widths):
            layers: list[nn.Module] = [nn.Conv2d(previous, width, 4, stride=2, padding=1)]
            if i > 0:
                layers.append(_norm(width))
            layers.append(nn.LeakyReLU(_SLOPE))
            self.down.append(nn.Sequential(*layers))
            previous = width

        # up[j] takes the features at level depth-1-j to level depth-2-j (the size of that
        # encoder level), whose features are then concatenated.
        self.up = nn.ModuleList()
        features = widths[-1]
        for i in range(depth - 1, 0, -1):
            width = widths[i - 1]
            self.up.append(
                nn.Sequential(nn.Conv2d(features, width, 3, padding=1), _norm(width), nn.ReLU())
            )
            features = 2 * width
        # Full resolution: the decoder's last upsampling is smooth, so pixel-level detail of
        # the input comes through a 3×3 convolution of the input itself.
        full = max(base // 2, 1)
        self.stem = nn.Sequential(nn.Conv2d(in_channels, full, 3, padding=1), nn.LeakyReLU(_SLOPE))
        self.fuse = nn.Sequential(nn.Conv2d(features, full, 3, padding=1), _norm(full), nn.ReLU())
        self.head = nn.Conv2d(2 * full, out_channels, 3, padding=1)

    def forward(self, x: Tensor) -> Tensor:
        """(B, C_in, H, W) -> (B, C_out, H, W).

        Raises:
            NetworkInputError: wrong rank or channels, or H, W not multiples of 2^depth.
        """
        _check_image(x, self.in_channels, "UNet")
        multiple = 2**self.depth
        height, width = x.shape[-2:]
        if height % multiple or width % multiple:
            raise NetworkInputError(
                f"UNet of depth {self.depth} takes images whose height and width are "
                f"multiples of {multiple}, got {height}×{width}"
            )
        skips: list[Tensor] = []
        if x.device.type == "cpu":  # oneDNN's faster layout for these convolutions
            x = x.contiguous(memory_format=torch.channels_last)
        h = x
        for layer in self.down:
            h = layer(h)
            skips.append(h)
        skips.pop()  # the innermost level is the decoder's start, not a skip
        for layer in self.up:
            h = layer(_upsample(h))
            h = torch.cat([h, skips.pop()], dim=1)
        h = torch.cat([self.fuse(_upsample(h)), self.stem(x)], dim=1)
        out: Tensor = self.head(h)
        return out.contiguous()


def _upsample(x: Tensor) -> Tensor:
    return F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)


class PatchDiscriminator(nn.Module):
    """PatchGAN discriminator (pix2pix): real/fake logits per overlapping patch.

    ``layers`` 4×4 convolutions of stride 2 (channels ``base · min(2^i, 8)``, no norm on the
    first), one of stride 1, then a stride-1 convolution to one channel; all padded by 1,
    GroupNorm and LeakyReLU (0.2) between them. With ``layers=3`` the receptive field of a
    logit is 70×70 pixels and an H×W input gives ``(H/8 − 2) × (W/8 − 2)`` logits.

    Args:
        in_channels: channels of the judged image (for pix2pix, input and output together).
        base: channels of the first layer.
        layers: number of stride-2 layers.

    ``forward(x)``: x (B, C, H, W) -> logits (B, 1, H', W'), with
    ``H' = ⌊H / 2^layers⌋ − 2``; unbounded (no sigmoid: the losses take logits).
    """

    def __init__(self, in_channels: int, base: int = 32, layers: int = 3) -> None:
        super().__init__()
        _check_positive(in_channels=in_channels, base=base, layers=layers)
        self.in_channels = in_channels
        self.layers = layers
        stack: list[nn.Module] = [
            nn.Conv2d(in_channels, base, 4, stride=2, padding=1),
            nn.LeakyReLU(_SLOPE),
        ]
        width = base
        for i in range(1, layers + 1):
            new = base * min(2**i, 8)
            stride = 2 if i < layers else 1
            stack += [
                nn.Conv2d(width, new, 4, stride=stride, padding=1),
                _norm(new),
                nn.LeakyReLU(_SLOPE),
            ]
            width = new
        stack.append(nn.Conv2d(width, 1, 4, stride=1, padding=1))
        self.net = nn.Sequential(*stack)

    def output_size(self, height: int, width: int) -> tuple[int, int]:
        """(H', W') of the logits for an H×W input (either may be below 1: too small)."""

        def size(n: int) -> int:
            for _ in range(self.layers):
                n //= 2
            return n - 2

        return size(height), size(width)

    def forward(self, x: Tensor) -> Tensor:
        """(B, C, H, W) -> (B, 1, H', W') logits.

        Raises:
            NetworkInputError: wrong rank or channels, or an image too small for one logit.
        """
        _check_image(x, self.in_channels, "PatchDiscriminator")
        out_h, out_w = self.output_size(x.shape[-2], x.shape[-1])
        if out_h < 1 or out_w < 1:
            least = 3 * 2**self.layers
            raise NetworkInputError(
                f"PatchDiscriminator with {self.layers} layers needs images of at least "
                f"{least}×{least}, got {x.shape[-2]}×{x.shape[-1]}"
            )
        out: Tensor = self.net(x)
        return out


class ResidualOverMean(nn.Module):
    """``y = mean + scale · net(x)``: a generator that predicts the deviation of each sample from
    the training set's mean target (a per-pixel prior, the buffer ``mean`` (C_out, H, W),
    saved with the weights); at initialisation it answers about the mean.

    Args:
        net: (B, C_in, H, W) → (B, C_out, H, W).
        mean: (C_out, H, W) the prior.
        scale: the residual's scale at initialisation.
    """

    def __init__(self, net: nn.Module, mean: Tensor, scale: float = 0.1) -> None:
        super().__init__()
        if mean.ndim != 3:
            raise NetworkConfigError(f"mean must be (C, H, W), got {tuple(mean.shape)}")
        self.net = net
        self.scale = float(scale)
        self.register_buffer("mean", mean.detach().clone().float())

    def forward(self, x: Tensor) -> Tensor:
        """(B, C_in, H, W) -> (B, C_out, H, W)."""
        out: Tensor = self.net(x)
        mean = cast(Tensor, self.mean)
        if out.shape[1:] != mean.shape:
            raise NetworkInputError(f"the network's output {tuple(out.shape[1:])} does not "
                                    f"match the mean {tuple(mean.shape)}")  # fmt: skip
        return mean + self.scale * out


class ClassMixture(nn.Module):
    """A generator that recognises each pixel's class and answers that class's mean target:
    ``net(x)`` gives C residual channels ``r`` and K class logits ``l`` per pixel, and

    ``y = Σ_k softmax(l)_k · M_k + scale · r``

    with ``M_k`` (C, H, W) the per-pixel mean target over the training pixels of class k (the
    buffer ``class_means`` (K, C, H, W), saved with the weights). The output is ``y`` followed
    by the logits, (B, C + K, H, W), so that a loss can also be put on the classes
    (:class:`~monoavatar.learn.training.TrainSettings` ``class_channels``).

    Args:
        net: (B, C_in, H, W) → (B, C + K, H, W).
        class_means: (K, C, H, W) the per-class prior.
        scale: the residual's scale at initialisation.
    """

    def __init__(self, net: nn.Module, class_means: Tensor, scale: float = 0.1) -> None:
        super().__init__()
        if class_means.ndim != 4:
            raise NetworkConfigError(f"class_means must be (K, C, H, W), got "
                                     f"{tuple(class_means.shape)}")  # fmt: skip
        self.net = net
        self.scale = float(scale)
        self.register_buffer("class_means", class_means.detach().clone().float())

    @property
    def classes(self) -> int:
        """K."""
        return int(cast(Tensor, self.class_means).shape[0])

    def forward(self, x: Tensor) -> Tensor:
        """(B, C_in, H, W) -> (B, C + K, H, W): the maps, then the class logits."""
        out: Tensor = self.net(x)
        means = cast(Tensor, self.class_means)
        k, c = means.shape[:2]
        if out.shape[1] != c + k or out.shape[2:] != means.shape[2:]:
            raise NetworkInputError(f"the network's output {tuple(out.shape[1:])} does not "
                                    f"match {c} maps and {k} classes of size "
                                    f"{tuple(means.shape[2:])}")  # fmt: skip
        residual, logits = out[:, :c], out[:, c:]
        prior = torch.einsum("bkhw,kchw->bchw", torch.softmax(logits, dim=1), means)
        return torch.cat([prior + self.scale * residual, logits], dim=1)
