"""The few-frame network of ``monoavatar reconstruct --fast`` (Paper D, Octopus, Sec. D.3).

Per frame ``i`` of ``F`` (any number, 1–8 in training), a convolutional encoder of the mask
crop (1, C, C) and a small MLP of the crop-normalised keypoints (33, 3) give a feature
``f_i``. The shape branch pools over the frames, ``g = mean_i s(f_i)`` (Sec. D.3.1: a
pose-invariant code whatever the number of frames), and decodes it into the six phenotypes β
(a linear layer) and an offset code ``z`` (``latent`` numbers) that a linear decoder turns
into per-vertex offsets ``D = W z + b`` (V, 3), its columns initialised from the principal
components of the training offsets (``decoder="linear"``); or, with ``decoder="uv"``, a
convolutional decoder of z into an offset map in the body's UV layout, read back at every
vertex's UVs (:class:`UVOffsetDecoder`; which is better is measured in ``docs/decisions.md``).
The pose branch maps ``[f_i, g]`` to the 20 joints'
rotations in the 6D representation (Zhou et al. 2019, two columns orthonormalised), the root's
in the camera's axes. The body model poses the result (a fixed, differentiable layer, Eq. 3.3).

The translation is not predicted: the crop removes it, and :func:`solve_translation` recovers
it in closed form from the 2D keypoints.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.geometry import camera_rays

__all__ = [
    "FastNetwork",
    "FastNetworkSettings",
    "FastOutput",
    "UVOffsetDecoder",
    "default_fast_weights",
    "load_fast_network",
    "rotation_6d",
    "solve_translation",
    "vertex_uv_samples",
]

KEYPOINTS = 33
PHENOTYPES = 6


class FastModelError(MonoavatarError, ValueError):
    """No usable few-frame network weights, or inputs of the wrong shape."""


@dataclass(frozen=True)
class FastNetworkSettings:
    """The network's architecture (kept in the weights' metadata and checked on load).

    Attributes:
        crop_size: C, side of the mask crop, pixels (a power of two, at least 32).
        base: channels of the first convolution (doubled per level up to 8 × base).
        feature: width of the per-frame feature and the pooled shape code.
        latent: length of the offset code z.
        decoder: ``"linear"`` (D = W z + b) or ``"uv"`` (:class:`UVOffsetDecoder`).
        uv_size: side of the ``"uv"`` decoder's offset map, texels (a power of two ≥ 8).
    """

    crop_size: int = 128
    base: int = 16
    feature: int = 256
    latent: int = 64
    decoder: str = "linear"
    uv_size: int = 128

    def metadata(self) -> dict[str, str]:
        return {"architecture": json.dumps(asdict(self))}

    @staticmethod
    def from_metadata(meta: dict[str, str]) -> FastNetworkSettings:
        try:
            a = json.loads(meta["architecture"])
            return FastNetworkSettings(int(a["crop_size"]), int(a["base"]), int(a["feature"]),
                                       int(a["latent"]), str(a.get("decoder", "linear")),
                                       int(a.get("uv_size", 128)))  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise FastModelError(f"the weights name no few-frame architecture ({exc})"
                                 ) from exc  # fmt: skip


def rotation_6d(x: Tensor) -> Tensor:
    """(..., 6) → (..., 3, 3) rotation matrices: the two 3-vectors orthonormalised
    (Gram–Schmidt) as the first two columns, their cross product the third."""
    a, b = x[..., :3], x[..., 3:]
    c1 = nn.functional.normalize(a, dim=-1)
    c2 = nn.functional.normalize(b - (c1 * b).sum(-1, keepdim=True) * c1, dim=-1)
    return torch.stack([c1, c2, torch.cross(c1, c2, dim=-1)], dim=-1)


def vertex_uv_samples(faces: Tensor, face_uv: Tensor) -> Tensor:
    """Every (vertex, UV) corner pair of a mesh once: (P, 2) long, a vertex on a UV seam
    appearing once per chart it lies in."""
    pairs = torch.stack([faces.reshape(-1), face_uv.reshape(-1)], 1).long()
    return torch.unique(pairs, dim=0)


class UVOffsetDecoder(nn.Module):
    """Offset code z (B, L) → per-vertex offsets (B, V, 3) metres through a map in UV space.

    A linear layer makes a 256-channel 4 × 4 image that nearest-neighbour upsampling and
    3 × 3 convolutions take to (3, S, S) (channels halved per level, at least 16); each vertex
    reads the map bilinearly at each of its UVs (``grid_sample``, UVs in the glTF convention)
    and takes the mean over its UVs. The map is in centimetres, added to a
    per-vertex ``bias`` (V, 3) metres (the linear decoder's b: training sets it to the mean
    offsets). The last convolution starts at zero, so the decoder starts at ``bias``.

    Args:
        latent: L; num_vertices: V; uv: (T, 2) the body's UVs; pairs: (P, 2) long
            (vertex, UV index), from :func:`vertex_uv_samples`; size: S.
    """

    grid: Tensor
    vertex: Tensor
    counts: Tensor

    def __init__(self, latent: int, num_vertices: int, uv: Tensor, pairs: Tensor, size: int
                 ) -> None:  # fmt: skip
        super().__init__()
        if size < 8 or size & (size - 1):
            raise FastModelError(f"uv_size must be a power of two >= 8, got {size}")
        if int(pairs[:, 0].max()) >= num_vertices or len(torch.unique(pairs[:, 0])) != num_vertices:
            raise FastModelError("the UV samples do not cover the body's vertices")
        self.num_vertices = num_vertices
        width = 256
        self.start = nn.Linear(latent, width * 16)
        layers: list[nn.Module] = []
        side, channels = 4, width
        while side < size:
            out = max(16, channels // 2)
            layers += [nn.Upsample(scale_factor=2.0, mode="nearest"),
                       nn.Conv2d(channels, out, 3, padding=1), nn.ReLU(inplace=True)]  # fmt: skip
            side, channels = 2 * side, out
        final = nn.Conv2d(channels, 3, 3, padding=1, bias=False)
        nn.init.zeros_(final.weight)
        self.up = nn.Sequential(*layers, final)
        self.bias = nn.Parameter(torch.zeros(num_vertices, 3))
        self.width = width
        grid = uv[pairs[:, 1]].float() * 2.0 - 1.0  # [0, 1] → grid_sample's [−1, 1]
        self.register_buffer("grid", grid[None, None], persistent=False)  # (1, 1, P, 2)
        self.register_buffer("vertex", pairs[:, 0].clone(), persistent=False)
        counts = torch.bincount(pairs[:, 0], minlength=num_vertices).float()
        self.register_buffer("counts", counts, persistent=False)

    def offset_map(self, z: Tensor) -> Tensor:
        """(B, L) → (B, 3, S, S), centimetres."""
        return self.up(self.start(z).reshape(len(z), self.width, 4, 4))

    def forward(self, z: Tensor) -> Tensor:
        image = self.offset_map(z)
        grid = self.grid.expand(len(z), -1, -1, -1)
        samples = nn.functional.grid_sample(image, grid, mode="bilinear", align_corners=False)
        samples = samples[:, :, 0].transpose(1, 2)  # (B, P, 3)
        total = samples.new_zeros(len(z), self.num_vertices, 3).index_add_(1, self.vertex,
                                                                           samples)  # fmt: skip
        return 0.01 * total / self.counts[None, :, None] + self.bias


@dataclass
class FastOutput:
    """What the network predicts for B captures of F frames each."""

    beta: Tensor  # (B, 6)
    code: Tensor  # (B, latent) offset code z
    offsets: Tensor  # (B, V, 3) metres, canonical frame
    rotations: Tensor  # (B, F, J, 3, 3), the root's in camera axes


class FastNetwork(nn.Module):
    """Masks (B, F, 1, C, C) in [0, 1] and keypoints (B, F, 33, 3) → :class:`FastOutput`.

    ``uv`` (T, 2) and ``pairs`` (P, 2), the body's UVs and its (vertex, UV) pairs
    (:func:`vertex_uv_samples`), are needed by the ``"uv"`` decoder only."""

    def __init__(self, settings: FastNetworkSettings, num_vertices: int, num_joints: int,
                 uv: Tensor | None = None, pairs: Tensor | None = None) -> None:  # fmt: skip
        super().__init__()
        c = settings.crop_size
        if c < 32 or c & (c - 1):
            raise FastModelError(f"crop_size must be a power of two >= 32, got {c}")
        self.settings = settings
        self.num_vertices, self.num_joints = num_vertices, num_joints
        layers: list[nn.Module] = []
        channels, side = 1, c
        while side > 4:
            out = min(settings.base * 2 ** (len(layers) // 3), 8 * settings.base)
            layers += [nn.Conv2d(channels, out, 4, stride=2, padding=1), nn.GroupNorm(4, out),
                       nn.ReLU(inplace=True)]  # fmt: skip
            channels, side = out, side // 2
        head = nn.Linear(channels * 16, settings.feature)
        self.encoder = nn.Sequential(*layers, nn.Flatten(), head)
        self.keypoints = nn.Sequential(nn.Linear(KEYPOINTS * 3, 128), nn.ReLU(inplace=True),
                                       nn.Linear(128, 128))  # fmt: skip
        width = settings.feature
        self.frame = nn.Sequential(nn.ReLU(), nn.Linear(width + 128, width), nn.ReLU())
        self.shape = nn.Sequential(nn.Linear(width, width), nn.ReLU(), nn.Linear(width, width))
        self.beta = nn.Linear(width, PHENOTYPES)
        self.code = nn.Linear(width, settings.latent)
        self.decoder: nn.Module
        if settings.decoder == "linear":
            self.decoder = nn.Linear(settings.latent, num_vertices * 3)
        elif settings.decoder == "uv":
            if uv is None or pairs is None:
                raise FastModelError("the 'uv' decoder needs the body's UVs")
            self.decoder = UVOffsetDecoder(settings.latent, num_vertices, uv, pairs,
                                           settings.uv_size)  # fmt: skip
        else:
            raise FastModelError(f"decoder must be 'linear' or 'uv', got {settings.decoder!r}")
        self.pose = nn.Sequential(nn.Linear(2 * width, width), nn.ReLU(),
                                  nn.Linear(width, num_joints * 6))  # fmt: skip
        with torch.no_grad():  # start from the average body in a camera-facing A-pose
            heads: list[nn.Module] = [self.code, self.beta]
            if settings.decoder == "linear":
                heads.append(self.decoder)
            for module in heads:
                assert isinstance(module, nn.Linear)
                module.weight.zero_()
                module.bias.zero_()
            last = self.pose[-1]
            assert isinstance(last, nn.Linear)
            last.weight.mul_(0.01)
            last.bias.copy_(torch.tensor([1.0, 0, 0, 0, 1, 0]).repeat(num_joints))
            last.bias[4] = -1.0  # the root upright, facing the camera: diag(1, −1, −1)

    def features(self, masks: Tensor, keypoints: Tensor) -> tuple[Tensor, Tensor]:
        """Per-frame features (B, F, W) and the pooled shape code g (B, W)."""
        b, f = masks.shape[:2]
        c = self.settings.crop_size
        if masks.shape[2:] != (1, c, c) or keypoints.shape != (b, f, KEYPOINTS, 3):
            raise FastModelError(f"expected masks (B, F, 1, {c}, {c}) and keypoints "
                                 f"(B, F, {KEYPOINTS}, 3), got {tuple(masks.shape)} and "
                                 f"{tuple(keypoints.shape)}")  # fmt: skip
        image = self.encoder(masks.reshape(b * f, 1, c, c))
        points = self.keypoints(keypoints.reshape(b * f, -1))
        per_frame = self.frame(torch.cat([image, points], 1)).reshape(b, f, -1)
        return per_frame, self.shape(per_frame).mean(1)

    def decode(self, per_frame: Tensor, g: Tensor, code: Tensor | None = None) -> FastOutput:
        """The heads on the features (``code``: an offset code to use instead of g's)."""
        b, f, _ = per_frame.shape
        z = self.code(g) if code is None else code
        offsets = self.decoder(z).reshape(b, self.num_vertices, 3)
        six = self.pose(torch.cat([per_frame, g[:, None].expand(-1, f, -1)], 2))
        rotations = rotation_6d(six.reshape(b, f, self.num_joints, 6))
        return FastOutput(self.beta(g), z, offsets, rotations)

    def forward(self, masks: Tensor, keypoints: Tensor) -> FastOutput:
        return self.decode(*self.features(masks, keypoints))


def solve_translation(points: np.ndarray, keypoints: np.ndarray, K: np.ndarray,
                      min_confidence: float = 0.3) -> np.ndarray:
    """The camera-frame shift u (3,) metres that best puts ``points`` + u on the detections.

    Each detection (x, y) with normalised coordinates (x', y') = K⁻¹ (x, y, 1) and a point P
    give two linear equations, ``P_x + u_x − x' (P_z + u_z) = 0`` and the same in y, weighted
    by the confidence; solved in least squares.

    Args:
        points: (33, 3) the body's landmarks posed without translation, camera frame, metres.
        keypoints: (33, 3) x px, y px, confidence.
        K: (3, 3) intrinsics.
    Raises:
        FastModelError: fewer than 3 confident detections.
    """
    w = np.where(keypoints[:, 2] >= min_confidence, keypoints[:, 2], 0.0)
    if (w > 0).sum() < 3:
        raise FastModelError("fewer than 3 confident keypoints: cannot place the body")
    n = camera_rays(keypoints[:, :2], K)
    rows, rhs = [], []
    for axis in (0, 1):
        a = np.zeros((len(points), 3))
        a[:, axis] = 1.0
        a[:, 2] = -n[:, axis]
        rows.append(a * w[:, None])
        rhs.append((n[:, axis] * points[:, 2] - points[:, axis]) * w)
    u, *_ = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)
    return np.asarray(u)


def default_fast_weights() -> Path:
    """The shipped weights, inside the installed package."""
    return Path(str(resources.files("monoavatar.learn") / "weights" / "fast.safetensors"))


def load_fast_network(num_vertices: int, num_joints: int, path: str | Path | None = None,
                      device: str = "cpu", uv: Tensor | None = None,
                      pairs: Tensor | None = None) -> FastNetwork:  # fmt: skip
    """Load the few-frame network (default: the shipped weights); ``uv`` and ``pairs`` as
    for :class:`FastNetwork` (needed by weights of the ``"uv"`` decoder).

    Raises:
        FastModelError: no weights file, or weights of another architecture or body.
    """
    from monoavatar.learn.weights import WeightsError, load_module_tensors, load_weights

    p = Path(path) if path is not None else default_fast_weights()
    if not p.is_file():
        raise FastModelError(f"no few-frame network weights at {p}; train them with "
                             "'monoavatar train fast -o DIR' or pass --weights")  # fmt: skip
    tensors, meta = load_weights(p)
    net = FastNetwork(FastNetworkSettings.from_metadata(meta), num_vertices, num_joints, uv,
                      pairs)  # fmt: skip
    try:
        load_module_tensors(net, tensors, prefix="network.")
    except WeightsError as exc:
        raise FastModelError(f"{p}: {exc} (weights of another body model?)") from exc
    return net.eval().to(device)
