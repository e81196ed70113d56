"""The photo network (Paper E, Tex2Shape) as shipped: a U-Net from the partial texture to the
UV displacement and normal maps, its weights in ``weights/photo.safetensors`` (no pickle, no
network), and inference on one photo's partial texture."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import torch
from torch import nn

from monoavatar.body import BodyModel
from monoavatar.core.errors import MonoavatarError
from monoavatar.learn.networks import ClassMixture, ResidualOverMean, UNet
from monoavatar.learn.photo_data import (
    CLASS_CHANNELS,
    INPUT_CHANNELS,
    TARGET_CHANNELS,
    network_input,
    template_frames,
    template_positions,
)
from monoavatar.learn.training import load_generator
from monoavatar.learn.uvmaps import UVLayout, from_normal_frame, uv_layout

__all__ = ["PhotoNetwork", "PhotoNetworkSettings", "default_weights", "load_photo_network"]


class PhotoModelError(MonoavatarError, ValueError):
    """No usable photo network weights."""


@dataclass(frozen=True)
class PhotoNetworkSettings:
    """The generator's architecture (stored in the weights' metadata and checked on load).

    Attributes:
        base: channels of the first encoder level.
        depth: encoder levels (the map side must be divisible by 2**depth).
        max_channels: channel cap of the deepest levels.
        map_size: S, side of the UV maps, texels.
        residual_scale: the U-Net predicts the maps' deviation from the training set's mean
            maps, times this (:class:`~monoavatar.learn.networks.ResidualOverMean`).
        tangential_scale: None: the displacement channels are canonical x, y, z; a number
            ``s``: they are the components along the average body's normal frame at each texel,
            tangential ones times ``s`` (:func:`~monoavatar.learn.uvmaps.to_normal_frame`), so
            the losses weigh tangential error, which hardly moves the surface, by ``s``.
        classes: the network also recognises each texel's garment class and starts from that
            class's mean maps (:class:`~monoavatar.learn.networks.ClassMixture`, trained with a
            cross-entropy on the classes) instead of the overall mean maps.
    """

    base: int = 32
    depth: int = 6
    max_channels: int = 256
    map_size: int = 256
    residual_scale: float = 0.1
    tangential_scale: float | None = None
    classes: bool = True

    @property
    def class_channels(self) -> int:
        """K, the class logits after the maps in the generator's output (0: none)."""
        return CLASS_CHANNELS if self.classes else 0

    def build(self, mean: torch.Tensor | None = None) -> nn.Module:
        """The generator; ``mean`` the prior maps, (6, S, S) — with ``classes`` the per-class
        ones, (K, 6, S, S) — zeros until loaded."""
        net = UNet(INPUT_CHANNELS, TARGET_CHANNELS + self.class_channels, base=self.base,
                   depth=self.depth, max_channels=self.max_channels)  # fmt: skip
        if self.classes:
            if mean is None:
                mean = torch.zeros(CLASS_CHANNELS, TARGET_CHANNELS, self.map_size,
                                   self.map_size)  # fmt: skip
            return ClassMixture(net, mean, self.residual_scale)
        if mean is None:
            mean = torch.zeros(TARGET_CHANNELS, self.map_size, self.map_size)
        return ResidualOverMean(net, mean, self.residual_scale)

    def metadata(self) -> dict[str, str]:
        return {"architecture": json.dumps(asdict(self))}

    @staticmethod
    def from_metadata(meta: dict[str, str]) -> PhotoNetworkSettings:
        try:
            a = json.loads(meta["architecture"])
            tangential = a.get("tangential_scale")  # absent: canonical x, y, z
            return PhotoNetworkSettings(
                int(a["base"]), int(a["depth"]), int(a["max_channels"]), int(a["map_size"]),
                float(a["residual_scale"]), None if tangential is None else float(tangential),
                bool(a.get("classes", False)))  # absent: no classes
        except (KeyError, TypeError, ValueError) as exc:
            raise PhotoModelError(f"the weights name no photo-network architecture ({exc})"
                                  ) from exc  # fmt: skip


def default_weights() -> Path:
    """The shipped weights, inside the installed package."""
    return Path(str(resources.files("monoavatar.learn") / "weights" / "photo.safetensors"))


@dataclass
class PhotoNetwork:
    """A loaded photo network with the UV layout and template its inputs need."""

    generator: nn.Module
    settings: PhotoNetworkSettings
    layout: UVLayout
    template: np.ndarray  # (S, S, 3) metres
    metadata: dict[str, str]
    path: Path
    frames: np.ndarray | None = None  # (S, S, 3, 3) when the network predicts in normal frames

    def predict(self, colour: np.ndarray, visible: np.ndarray) -> np.ndarray:
        """(S, S, 6) float32 maps (displacement / DISPLACEMENT_SCALE, normals; canonical frame)
        from a partial texture (S, S, 3) in [0, 1] and its visibility (S, S) bool."""
        return self.infer(colour, visible)[0]

    def infer(self, colour: np.ndarray, visible: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray | None]:  # fmt: skip
        """The maps of :meth:`predict` and, for a network with ``classes``, each texel's garment
        class probabilities (S, S, K) float32 in the order of
        :data:`~monoavatar.synth.subjects.GARMENTS` (zero outside the charts); else None."""
        x = torch.from_numpy(network_input(colour, visible, self.template))[None]
        with torch.no_grad():
            y = self.generator(x.to(next(self.generator.parameters()).device))
        maps = y[0, :TARGET_CHANNELS].float().cpu().numpy().transpose(1, 2, 0)
        if self.frames is not None and self.settings.tangential_scale is not None:
            maps[..., :3] = from_normal_frame(maps[..., :3], self.frames,
                                              self.settings.tangential_scale)  # fmt: skip
        maps[~self.layout.chart] = 0.0
        probabilities = None
        if self.settings.classes:
            logits = y[0, TARGET_CHANNELS:].float()
            probabilities = torch.softmax(logits, 0).cpu().numpy().transpose(1, 2, 0)
            probabilities[~self.layout.chart] = 0.0
            probabilities = np.ascontiguousarray(probabilities)
        return np.ascontiguousarray(maps), probabilities


def load_photo_network(body: BodyModel, path: str | Path | None = None,
                       device: str = "cpu") -> PhotoNetwork:  # fmt: skip
    """Load the photo network's weights (default: the shipped ones) for ``body``'s UV layout.

    Raises:
        PhotoModelError: no weights file, or weights of another architecture.
    """
    p = Path(path) if path is not None else default_weights()
    if not p.is_file():
        raise PhotoModelError(f"no photo-network weights at {p}; train them with "
                              "'monoavatar train photo -o DIR' or pass --weights")  # fmt: skip
    from monoavatar.learn.weights import load_weights

    _, meta = load_weights(p)
    settings = PhotoNetworkSettings.from_metadata(meta)
    generator = settings.build()
    load_generator(generator, p)
    generator.eval().to(device)
    layout = uv_layout(body, settings.map_size)
    frames = template_frames(body, layout) if settings.tangential_scale is not None else None
    return PhotoNetwork(generator, settings, layout, template_positions(body, layout), meta, p,
                        frames)  # fmt: skip
