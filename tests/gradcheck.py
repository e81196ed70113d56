"""A directional finite-difference check of autograd gradients, cheap for large outputs."""

from __future__ import annotations

from collections.abc import Callable

import torch


def directional_gradcheck(
    fn: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, eps: float = 1e-6, seed: int = 0
) -> tuple[float, float]:
    """Compare d/dε <g, fn(x + ε u)> by central differences with <∇_x <g, fn(x)>, u> for random
    g and u (float64). Returns (finite difference, autograd)."""
    gen = torch.Generator().manual_seed(seed)
    x = x.detach().clone().requires_grad_(True)
    out = fn(x)
    g = torch.randn(out.shape, generator=gen, dtype=out.dtype)
    u = torch.randn(x.shape, generator=gen, dtype=x.dtype)
    (grad,) = torch.autograd.grad((out * g).sum(), x)
    with torch.no_grad():
        plus = (fn(x + eps * u) * g).sum()
        minus = (fn(x - eps * u) * g).sum()
    return float((plus - minus) / (2 * eps)), float((grad * u).sum())
