"""Body-model layer: one interface (:class:`BodyModel`), Anny (default) and SMPL back-ends,
linear blend skinning and its inverse, SMPL+D offsets, subdivision, avatar files."""

from __future__ import annotations

from pathlib import Path

import torch

from monoavatar.body.avatar import Avatar
from monoavatar.body.model import (
    MEDIAPIPE_LANDMARKS,
    REGIONS,
    BodyModel,
    BodyModelError,
    BodyOutput,
)


def load_body_model(
    name: str = "anny", dtype: torch.dtype = torch.float32, num_shape: int = 10
) -> BodyModel:
    """A body model by name: ``"anny"`` (default, shipped), ``"anny-local"`` (Anny with its
    256 local shape changes), or a path to a user's SMPL/SMPL-X ``.npz``/``.pkl`` file
    (``num_shape`` of its shape coefficients are used)."""
    if name in ("anny", "anny-local"):
        from monoavatar.body.anny_body import AnnyBody

        return AnnyBody(local_changes="all" if name == "anny-local" else "none", dtype=dtype)
    if name.endswith((".npz", ".pkl")) or Path(name).exists():
        from monoavatar.body.smpl_body import SmplBody

        return SmplBody(name, num_shape=num_shape, dtype=dtype)
    raise BodyModelError(
        f"unknown body model {name!r}: use 'anny', 'anny-local' or a path to an SMPL model file"
    )


def load_body_model_for(identity: str) -> BodyModel:
    """The shipped body model a ``BodyModel.identity`` string names (an avatar's).

    Raises:
        BodyModelError: a model that is not shipped (SMPL: load the user's file instead).
    """
    if identity.startswith("anny-"):
        local = identity.endswith("local_changes=all")
        return load_body_model("anny-local" if local else "anny")
    raise BodyModelError(
        f"cannot load body model {identity!r} by itself; pass the body model (e.g. the user's "
        "SMPL file loaded with load_body_model(path))"
    )


__all__ = [
    "MEDIAPIPE_LANDMARKS",
    "REGIONS",
    "Avatar",
    "BodyModel",
    "BodyModelError",
    "BodyOutput",
    "load_body_model",
    "load_body_model_for",
]
