"""Spherical-harmonics shading against quadrature and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from monoavatar.render import (
    directional_light_sh,
    sample_sh_lighting,
    sh_basis,
    sh_irradiance,
    sh_shading,
)


def sphere_quadrature(n_theta: int = 400, n_phi: int = 800) -> tuple[torch.Tensor, torch.Tensor]:
    """Midpoint rule on a latitude-longitude grid: directions (N, 3) and solid angles (N,)."""
    theta = (torch.arange(n_theta, dtype=torch.float64) + 0.5) * math.pi / n_theta
    phi = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * 2.0 * math.pi / n_phi
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    dirs = torch.stack([t.sin() * p.cos(), t.sin() * p.sin(), t.cos()], dim=-1).reshape(-1, 3)
    weights = (t.sin() * (math.pi / n_theta) * (2.0 * math.pi / n_phi)).reshape(-1)
    return dirs, weights


def random_unit(n: int, seed: int) -> torch.Tensor:
    v = torch.randn(n, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
    return v / v.norm(dim=-1, keepdim=True)


def test_basis_is_orthonormal() -> None:
    dirs, w = sphere_quadrature(200, 400)
    Y = sh_basis(dirs)
    gram = Y.T @ (Y * w[:, None])
    torch.testing.assert_close(gram, torch.eye(9, dtype=torch.float64), atol=1e-4, rtol=0)


def test_basis_order_and_sign() -> None:
    """Documented order: 1, y, z, x, xy, yz, 3z^2 - 1, xz, x^2 - y^2 (all positive factors)."""
    x, y, z = 0.48, -0.6, 0.64
    Y = sh_basis(torch.tensor([x, y, z], dtype=torch.float64))
    expected = torch.tensor([1, y, z, x, x * y, y * z, 3 * z * z - 1, x * z, x * x - y * y])
    ratio = Y / expected.double()
    torch.testing.assert_close(ratio[1:4], torch.full((3,), ratio[1].item(), dtype=torch.float64))
    assert bool((ratio > 0).all())


def test_irradiance_equals_numerical_integration() -> None:
    """E(n) = ∫ L(w) max(0, n·w) dw for a random band-2 environment, integrated numerically."""
    dirs, w = sphere_quadrature()
    sh = torch.randn(3, 9, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    radiance = sh_basis(dirs) @ sh.T  # (N, 3)
    normals = random_unit(16, seed=3)
    cosine = (normals @ dirs.T).clamp_min(0.0)  # (16, N)
    numeric = cosine @ (radiance * w[:, None])
    torch.testing.assert_close(sh_irradiance(normals, sh), numeric, atol=2e-4, rtol=1e-4)


def test_constant_lighting_gives_uniform_shading() -> None:
    sh = torch.zeros(3, 9, dtype=torch.float64)
    sh[:, 0] = torch.tensor([0.2, 0.5, 0.9]) * 2.0 * math.sqrt(math.pi)  # uniform radiance
    shading = sh_shading(random_unit(100, seed=4), sh)
    expected = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64).expand(100, 3)
    torch.testing.assert_close(shading, expected)


def test_directional_light_is_the_band_limited_clamped_cosine() -> None:
    light = np.array([0.3, 0.8, -0.52])
    light /= np.linalg.norm(light)
    sh = torch.as_tensor(directional_light_sh(light, 1.0))
    normals = random_unit(2000, seed=5)
    E = sh_irradiance(normals, sh)
    c = normals @ torch.as_tensor(light)
    # Addition theorem: sum_m Y_lm(l) Y_lm(n) = (2l + 1) / (4 pi) P_l(n·l).
    closed = 0.25 + 0.5 * c + (5.0 / 16.0) * (3.0 * c * c - 1.0) / 2.0
    torch.testing.assert_close(E, closed[:, None].expand(-1, 3))
    # ... which approximates max(0, n·l) to within 3/32 (the band-2 truncation error).
    err = (E[:, 0] - c.clamp_min(0.0)).abs()
    assert float(err.max()) <= 3.0 / 32.0 + 1e-9
    assert float(err.max()) > 0.08  # and that bound is nearly reached (grazing normals)


def test_shared_coefficients_broadcast_to_three_channels() -> None:
    sh9 = torch.randn(9, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    normals = random_unit(10, seed=7)
    torch.testing.assert_close(
        sh_irradiance(normals, sh9), sh_irradiance(normals, sh9.expand(3, 9))
    )


def test_gradients() -> None:
    normals = random_unit(5, seed=8).requires_grad_()
    sh = torch.randn(3, 9, dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(sh_irradiance, (normals, sh))


def test_invalid_input() -> None:
    with pytest.raises(ValueError, match="sh must have shape"):
        sh_irradiance(torch.zeros(2, 3), torch.zeros(4, 9))
    with pytest.raises(ValueError, match="directions"):
        sh_basis(torch.zeros(2, 4))
    with pytest.raises(ValueError, match="direction"):
        directional_light_sh(np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="n must be"):
        sample_sh_lighting(np.random.default_rng(0), -1)


def test_sampled_lighting_is_plausible_and_deterministic() -> None:
    a = sample_sh_lighting(np.random.default_rng(11), 64)
    b = sample_sh_lighting(np.random.default_rng(11), 64)
    np.testing.assert_array_equal(a.sh, b.sh)
    assert a.sh.shape == (64, 3, 9) and a.key_direction.shape == (64, 3)
    np.testing.assert_allclose(np.linalg.norm(a.key_direction, axis=1), 1.0)
    assert (a.key_direction[:, 1] > 0.15).all()  # from above the horizon
    assert (a.key_direction[:, 2] > 0).mean() > 0.6  # mostly from the front (+Z)
    normals = random_unit(500, seed=9)
    for i in range(64):
        shading = sh_shading(normals, torch.as_tensor(a.sh[i])).numpy()
        assert shading.min() > 0.25 and shading.max() < 1.7
        # Facing the key light: ambient plus the key light's 17/16 (band-2 value at n·l = 1).
        facing = sh_shading(torch.as_tensor(a.key_direction[i]), torch.as_tensor(a.sh[i]))
        expected = a.ambient[i] + 17.0 / 16.0 * a.key_shading[i]
        np.testing.assert_allclose(facing.numpy(), expected, rtol=1e-12)
    assert len({tuple(np.round(s[:, 0], 6)) for s in a.sh}) == 64
