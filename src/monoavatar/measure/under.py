"""The body under the clothes of an SMPL+D avatar: the body model's shape re-fitted to lie just
inside the clothed surface, and the clothed surface wherever it is tighter still.

With ``c_i`` the clothed vertex i (the body of the avatar's shape plus its offset), ``n_i`` the
normal of that body at i and ``b_i(β)`` the body of shape β, the signed gap
``e_i = (b_i(β) − c_i) · n_i`` is positive where the body would stick out of the clothes. The
shape minimises

    E(β) = mean_i w(e_i) e_i² + κ (h(β) − h₀)² + μ |β − β₀|²,   w(e) = 1 if e > 0 else λ

(``λ = UnderSettings.inside_weight``): sticking out is expensive, lying inside cheap, so the body
shrinks into the clothes and touches them where they fit; ``h`` is the body's height, held at
the avatar's own ``h₀`` (the height the user gave), and ``β₀`` the avatar's shape.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch

from monoavatar.body import BodyModel
from monoavatar.core.geometry import vertex_normals
from monoavatar.measure.measurements import body_under_clothes

__all__ = ["UnderSettings", "fit_body_under_clothes"]


@dataclass(frozen=True)
class UnderSettings:
    """The fit of :func:`fit_body_under_clothes` (the symbols of the module docstring)."""

    inside_weight: float = 0.05  # λ
    height_weight: float = 1.0  # κ, per square metre, relative to the mean squared gap
    shape_weight: float = 1e-7  # μ, per unit of shape, relative to the mean squared gap
    rounds: int = 3  # L-BFGS restarts of up to 100 iterations each


def fit_body_under_clothes(body: BodyModel, shape: np.ndarray, offsets: np.ndarray,
                           settings: UnderSettings | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Fit the body under the clothes of an avatar of ``shape`` (S,) and ``offsets`` (V, 3)
    metres (canonical frame).

    Returns:
        shape (S,) re-fitted; vertices (V, 3) of the body under the clothes (the re-fitted
        body, pulled in to the clothed surface wherever that is tighter,
        :func:`~monoavatar.measure.body_under_clothes`); joints (J, 3) of the re-fitted body.
    """
    s = settings or UnderSettings()
    dtype = torch.float64
    model = body if body.dtype == dtype else copy.deepcopy(body).to(dtype)
    beta0 = torch.as_tensor(np.asarray(shape), dtype=dtype)[None]
    with torch.no_grad():
        rest0, _ = model.rest_shape(beta0)
    rest0 = rest0[0]
    normals = vertex_normals(rest0, model.faces).to(dtype)
    clothed = rest0 + torch.as_tensor(np.asarray(offsets), dtype=dtype)
    height0 = rest0[:, 1].max() - rest0[:, 1].min()
    beta = beta0.clone().requires_grad_(True)
    optimiser = torch.optim.LBFGS([beta], max_iter=100, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        optimiser.zero_grad()
        vertices = model.rest_shape(beta)[0][0]
        gap = ((vertices - clothed) * normals).sum(dim=1)
        weight = torch.where(gap > 0, 1.0, s.inside_weight)
        height = vertices[:, 1].max() - vertices[:, 1].min()
        energy = ((weight * gap**2).mean() + s.height_weight * (height - height0) ** 2
                  + s.shape_weight * ((beta - beta0) ** 2).sum())  # fmt: skip
        (energy * 1e4).backward()  # scaled: gaps are millimetres
        return energy

    for _ in range(s.rounds):
        optimiser.step(closure)
    with torch.no_grad():
        rest, joints = model.rest_shape(beta.detach())
    v = rest[0].numpy()
    under = body_under_clothes(v, vertex_normals(rest[0], model.faces).numpy(),
                               clothed.numpy() - v)  # fmt: skip
    return beta.detach()[0].numpy(), under, joints[0].numpy()
