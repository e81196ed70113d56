"""The batched L-BFGS against closed-form minima, and the independence of its rows."""

from __future__ import annotations

import pytest
import torch

from monoavatar.fit.batched_lbfgs import minimize_rows


def _quadratics(b: int, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    m = torch.randn(b, n, n, generator=g, dtype=torch.float64)
    a = m @ m.transpose(1, 2) + 0.5 * torch.eye(n, dtype=torch.float64)
    return a, torch.randn(b, n, generator=g, dtype=torch.float64)


def test_quadratics_reach_their_closed_form_minima() -> None:
    a, c = _quadratics(6, 8)

    def energy(x: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:  # ½ xᵀAx − cᵀx per row
        return 0.5 * torch.einsum("bi,bij,bj->b", x, a[rows], x) - (c[rows] * x).sum(-1)

    result = minimize_rows(energy, torch.zeros_like(c), 200, tolerance_change=1e-14)
    torch.testing.assert_close(result.x, torch.linalg.solve(a, c), atol=1e-6, rtol=0)
    assert bool((result.iterations < 200).all())  # each row stopped on its own test


def _rosenbrock(x: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
    return (1 - x[:, 0]) ** 2 + 100 * (x[:, 1] - x[:, 0] ** 2) ** 2


def test_rosenbrock_rows_converge_each_on_its_own_path() -> None:
    starts = torch.tensor([[-1.2, 1.0], [0.0, 0.0], [2.0, 2.0], [-0.5, 2.0]], dtype=torch.float64)
    batched = minimize_rows(_rosenbrock, starts, 300)
    torch.testing.assert_close(batched.x, torch.ones_like(starts), atol=1e-4, rtol=0)
    # a row's path does not depend on the other rows: alone it takes the same steps
    for k in range(len(starts)):
        alone = minimize_rows(_rosenbrock, starts[k : k + 1], 300)
        assert int(alone.iterations[0]) == int(batched.iterations[k])
        torch.testing.assert_close(alone.x[0], batched.x[k], atol=1e-12, rtol=0)


def test_iterations_bound_the_steps_and_a_minimum_stays_put() -> None:
    starts = torch.tensor([[-1.2, 1.0], [1.0, 1.0]], dtype=torch.float64)
    result = minimize_rows(_rosenbrock, starts, 3)
    assert int(result.iterations[0]) == 3
    assert float(result.value[0]) < float(_rosenbrock(starts[:1])[0])  # it descended
    assert int(result.iterations[1]) == 0  # the gradient is zero at the minimum
    torch.testing.assert_close(result.x[1], starts[1])


def test_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="x0"):
        minimize_rows(_rosenbrock, torch.zeros(2), 5)
    with pytest.raises(ValueError, match="history"):
        minimize_rows(_rosenbrock, torch.zeros(1, 2), 5, history=0)
