"""An avatar's identity — body model, shape, offsets — saved and loaded as ``.npz``.

Keys of the file (all float arrays in metres where lengths):
- ``model``: the body model's identity string (e.g. ``anny-0.6.2:local_changes=none``);
- ``shape``: (S,) shape parameters; ``shape_names``: (S,) their names;
- ``offsets``: (V, 3) per-vertex offsets D in the canonical frame (SMPL+D);
- ``format``: ``monoavatar-avatar-1``.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from monoavatar.body.model import BodyModel, BodyModelError

FORMAT = "monoavatar-avatar-1"


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

    def save(self, path: str | Path) -> None:
        """Write atomically (temporary file, then rename): no half-written avatar on failure."""
        path = Path(path)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".npz")
        os.close(fd)
        try:
            np.savez(
                tmp,
                format=np.array(FORMAT),
                model=np.array(self.model),
                shape=np.asarray(self.shape, dtype=np.float64),
                shape_names=np.array(self.shape_names, dtype=str),
                offsets=np.asarray(self.offsets, dtype=np.float32),
            )
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @staticmethod
    def load(path: str | Path) -> Avatar:
        path = Path(path)
        if not path.is_file():
            raise BodyModelError(f"avatar file not found: {path}")
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data["format"]) != FORMAT:
                    raise BodyModelError(f"{path}: unknown avatar format {data['format']}")
                return Avatar(
                    model=str(data["model"]),
                    shape=data["shape"].astype(np.float64),
                    shape_names=tuple(str(s) for s in data["shape_names"]),
                    offsets=data["offsets"].astype(np.float32),
                )
        except (OSError, ValueError, KeyError) as exc:
            raise BodyModelError(f"{path} is not a monoavatar avatar file: {exc}") from exc
