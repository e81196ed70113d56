"""L-BFGS on many independent problems at once: one tensor operation per step for all of them.

The flow rounds re-fit every key-frame's pose alone (no term ties two frames together); their
energies are evaluated for all frames in one batched pass, and this optimiser keeps one L-BFGS
state per frame (its own curvature pairs, step length and stopping test), so each frame follows
its own path as if it were fitted alone, while Python's per-operation cost is paid once per
step instead of once per frame; a backtracking step evaluates only the frames still searching.

Search direction: the two-loop recursion of Nocedal & Wright (Algorithm 7.4) with the initial
Hessian ``γ I``, ``γ = sᵀy / yᵀy`` of the newest pair; step length: backtracking from 1 (from
``min(1, 1 / ‖g‖₁)`` on the first step, as PyTorch's L-BFGS) until the Armijo condition
``f(x + t d) ≤ f(x) + c₁ t gᵀd`` holds; a pair is kept only when ``sᵀy > 0`` (Armijo alone does
not guarantee the curvature condition), so the inverse Hessian stays positive definite.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["RowResult", "minimize_rows"]


@dataclass(frozen=True)
class RowResult:
    """The minimiser of :func:`minimize_rows`.

    Attributes:
        x: (B, n) the last accepted point of each row.
        value: (B,) the energy there.
        iterations: (B,) accepted steps per row.
        evaluations: batched energy evaluations (the first of each step evaluates every row
            not yet done, a backtrack only the rows still searching).
    """

    x: Tensor
    value: Tensor
    iterations: Tensor
    evaluations: int


Energy = Callable[[Tensor, Tensor], Tensor]
"""``energy(x, rows)``: the values (R,) of rows ``rows`` (R,) int64 at their points x (R, n)."""


def _value_and_grad(energy: Energy, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
    with torch.enable_grad():
        xg = x.detach().requires_grad_(True)
        value = energy(xg, rows)
        (grad,) = torch.autograd.grad(value.sum(), xg)
    return value.detach(), grad.detach()


def _direction(grad: Tensor, pairs: list[tuple[Tensor, Tensor, Tensor]], gamma: Tensor) -> Tensor:
    """−H g by the two-loop recursion; pairs (s, y, ρ) oldest first, each (B, n), (B, n), (B,)
    (ρ = 0 for a row that kept no pair at that step, which makes the pair a no-op)."""
    q = -grad
    alphas = []
    for s, y, rho in reversed(pairs):
        alpha = rho * (s * q).sum(-1)
        q = q - alpha[:, None] * y
        alphas.append(alpha)
    r = gamma[:, None] * q
    for (s, y, rho), alpha in zip(pairs, reversed(alphas), strict=True):
        beta = rho * (y * r).sum(-1)
        r = r + (alpha - beta)[:, None] * s
    return r


def minimize_rows(
    energy: Energy,
    x0: Tensor,
    iterations: int,
    history: int = 20,
    c1: float = 1.0e-4,
    max_backtracks: int = 12,
    tolerance_grad: float = 1.0e-7,
    tolerance_change: float = 1.0e-9,
) -> RowResult:
    """Minimise B independent functions of n variables each with one L-BFGS state per row.

    Args:
        energy: ``energy(x, rows)`` → (R,) values of the rows ``rows`` (R,) int64 at x (R, n),
            each row's value depending on its own row of x alone (differentiable); the line
            search evaluates only the rows still searching.
        x0: (B, n) the starting points.
        iterations: accepted steps per row at most.
        history: curvature pairs kept per row.
        c1: the Armijo constant.
        max_backtracks: halvings of the step before a row gives up (it is then done).
        tolerance_grad: a row is done when its gradient's largest entry is below this.
        tolerance_change: a row is done when a step changes its value or its variables by
            less than this.
    Returns:
        :class:`RowResult`.
    """
    if x0.dim() != 2:
        raise ValueError(f"x0 must be (B, n), got shape {tuple(x0.shape)}")
    if iterations < 0 or history < 1 or max_backtracks < 1:
        raise ValueError("iterations must be >= 0, history and max_backtracks >= 1")
    x = x0.detach().clone()
    b = x.shape[0]
    value, grad = _value_and_grad(energy, x, torch.arange(b))
    evaluations = 1
    done = grad.abs().amax(-1) <= tolerance_grad
    steps = torch.zeros(b, dtype=torch.long)
    pairs: list[tuple[Tensor, Tensor, Tensor]] = []
    gamma = torch.ones(b, dtype=x.dtype)
    has_pair = torch.zeros(b, dtype=torch.bool)
    for _ in range(iterations):
        if bool(done.all()):
            break
        direction = _direction(grad, pairs, gamma)
        slope = (grad * direction).sum(-1)
        # a row without curvature information (or a direction that does not descend, which
        # rounding can make) steps along −g, scaled as PyTorch's first step
        fallback = ~has_pair | (slope >= 0)
        direction = torch.where(fallback[:, None], -grad, direction)
        slope = torch.where(fallback, -(grad * grad).sum(-1), slope)
        first = (1.0 / grad.abs().sum(-1).clamp_min(1e-30)).clamp(max=1.0)
        t = torch.where(fallback, first, torch.ones_like(first))
        searching = ~done
        new_x, new_value, new_grad = x.clone(), value.clone(), grad.clone()
        for _ in range(max_backtracks):
            rows = torch.nonzero(searching).flatten()
            trial = x[rows] + t[rows, None] * direction[rows]
            v, g = _value_and_grad(energy, trial, rows)
            evaluations += 1
            ok = v <= value[rows] + c1 * t[rows] * slope[rows]
            accept = rows[ok]
            new_x[accept], new_value[accept], new_grad[accept] = trial[ok], v[ok], g[ok]
            searching[accept] = False
            if not bool(searching.any()):
                break
            t = torch.where(searching, 0.5 * t, t)
        # rows whose line search failed made no progress: they are done
        moved = ~done & ~searching
        done = done | searching
        s = new_x - x
        y = new_grad - grad
        sy = (s * y).sum(-1)
        keep = moved & (sy > 1e-10)
        rho = torch.where(keep, 1.0 / sy.clamp_min(1e-30), torch.zeros_like(sy))
        pairs.append((torch.where(keep[:, None], s, 0.0), torch.where(keep[:, None], y, 0.0), rho))
        if len(pairs) > history:
            pairs.pop(0)
        gamma = torch.where(keep, sy / (y * y).sum(-1).clamp_min(1e-30), gamma)
        has_pair = has_pair | keep
        change = (new_value - value).abs()
        done = done | (moved & ((change < tolerance_change)
                                | (s.abs().amax(-1) <= tolerance_change)
                                | (new_grad.abs().amax(-1) <= tolerance_grad)))  # fmt: skip
        steps = steps + moved.long()
        x, value, grad = new_x, new_value, new_grad
    return RowResult(x, value, steps, evaluations)
