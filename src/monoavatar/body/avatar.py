"""An avatar's identity in memory: body model, shape and per-vertex offsets (SMPL+D). On disk
it lives in an avatar folder (:mod:`monoavatar.io.avatar_folder`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from monoavatar.body.model import BodyModel, BodyModelError


@dataclass
class Avatar:
    """A personalised body: model identity, shape (S,), offsets (V, 3) in canonical space."""

    model: str
    shape: np.ndarray
    shape_names: tuple[str, ...]
    offsets: np.ndarray

    def check_compatible(self, body: BodyModel) -> None:
        """Raise if this avatar was made with another body model than ``body``."""
        if self.model != body.identity:
            raise BodyModelError(f"avatar is for body model {self.model!r}, not {body.identity!r}")
        if self.offsets.shape != (body.num_vertices, 3):
            raise BodyModelError(
                f"avatar offsets have shape {self.offsets.shape}, "
                f"the model has {body.num_vertices} vertices"
            )
