"""Spherical-harmonics (SH) Lambertian shading (dissertation Sec. 3.2.4 and E.4.2).

Distant lighting is described by its radiance ``L(w) = sum_j L_j Y_j(w)`` over directions ``w``
on the unit sphere, truncated to bands l <= 2: nine coefficients per colour channel.

Basis (Ramamoorthi & Hanrahan 2001, "An efficient representation for irradiance environment
maps"): real, orthonormal on the sphere (``∫ Y_i Y_j dw = δ_ij``), no Condon-Shortley phase.
For a unit direction (x, y, z), index ``j = l(l+1) + m``:

====  ======  ===========================================
 j    (l, m)  Y_j(x, y, z)
====  ======  ===========================================
 0    (0, 0)  0.282095                      = 1 / (2 sqrt(pi))
 1    (1,-1)  0.488603 y                    = sqrt(3 / (4 pi)) y
 2    (1, 0)  0.488603 z
 3    (1, 1)  0.488603 x
 4    (2,-2)  1.092548 x y                  = sqrt(15 / (4 pi)) x y
 5    (2,-1)  1.092548 y z
 6    (2, 0)  0.315392 (3 z^2 - 1)          = sqrt(5 / (16 pi)) (3 z^2 - 1)
 7    (2, 1)  1.092548 x z
 8    (2, 2)  0.546274 (x^2 - y^2)          = sqrt(15 / (16 pi)) (x^2 - y^2)
====  ======  ===========================================

Irradiance at a surface with unit normal n is the clamped-cosine convolution
``E(n) = ∫ L(w) max(0, n·w) dw = sum_j A_l L_j Y_j(n)`` with ``A_0 = pi``, ``A_1 = 2 pi / 3``,
``A_2 = pi / 4`` — exact for lighting of bands <= 2. A Lambertian surface of albedo ``rho``
then reflects radiance ``rho E(n) / pi`` (:func:`sh_shading` returns ``E / pi``), so a uniform
environment of radiance 1 (``L_0 = 2 sqrt(pi)``) shades a white surface to exactly 1.

Coefficients live in the frame of the normals they are evaluated with (world, Y-up, for the
renders of :mod:`monoavatar.render.renders`). Units: radiance in arbitrary linear units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "SH_BAND_FACTORS",
    "SampledLighting",
    "directional_light_sh",
    "sample_sh_lighting",
    "sh_basis",
    "sh_irradiance",
    "sh_shading",
]

_C0 = 0.5 / math.sqrt(math.pi)
_C1 = math.sqrt(3.0 / (4.0 * math.pi))
_C2 = math.sqrt(15.0 / (4.0 * math.pi))
_C20 = math.sqrt(5.0 / (16.0 * math.pi))
_C22 = math.sqrt(15.0 / (16.0 * math.pi))

# Clamped-cosine convolution factor A_l of each of the nine coefficients (R&H 2001, Eq. 8).
SH_BAND_FACTORS = (
    math.pi,
    *(2.0 * math.pi / 3.0,) * 3,
    *(math.pi / 4.0,) * 5,
)


def sh_basis(directions: Tensor) -> Tensor:
    """The nine real SH basis functions (order and normalisation in the module docstring).

    Args:
        directions: (..., 3) unit vectors (x, y, z).
    Returns:
        (..., 9) basis values, same dtype and device.
    """
    if directions.shape[-1:] != (3,):
        raise ValueError(f"directions must have shape (..., 3), got {tuple(directions.shape)}")
    x, y, z = directions.unbind(-1)
    return torch.stack(
        [
            torch.full_like(x, _C0),
            _C1 * y,
            _C1 * z,
            _C1 * x,
            _C2 * x * y,
            _C2 * y * z,
            _C20 * (3.0 * z * z - 1.0),
            _C2 * x * z,
            _C22 * (x * x - y * y),
        ],
        dim=-1,
    )


def _sh_matrix(sh: Tensor, like: Tensor) -> Tensor:
    """(3, 9) or (9,) coefficients → (3, 9) in ``like``'s dtype/device."""
    sh = torch.as_tensor(sh, dtype=like.dtype, device=like.device)
    if sh.shape == (9,):
        sh = sh.expand(3, 9)
    if sh.shape != (3, 9):
        raise ValueError(f"sh must have shape (3, 9) or (9,), got {tuple(sh.shape)}")
    return sh


def sh_irradiance(normals: Tensor, sh: Tensor) -> Tensor:
    """Irradiance ``E(n) = sum_j A_l L_j Y_j(n)`` for each normal and colour channel.

    Args:
        normals: (..., 3) unit surface normals, in the lighting's frame.
        sh: (3, 9) radiance coefficients per RGB channel, or (9,) shared by all channels.
    Returns:
        (..., 3) irradiance (not clamped; band-limited lighting can dip slightly below zero).
        Differentiable in ``normals`` and ``sh``.
    """
    if not normals.is_floating_point():
        raise ValueError("normals must be a floating-point tensor")
    coeffs = _sh_matrix(sh, normals)
    factors = torch.tensor(SH_BAND_FACTORS, dtype=normals.dtype, device=normals.device)
    return sh_basis(normals) @ (coeffs * factors).T


def sh_shading(normals: Tensor, sh: Tensor) -> Tensor:
    """Radiance reflected by a white Lambertian surface: ``E(n) / pi``, shape (..., 3).

    Multiply by albedo to get a colour; uniform unit radiance gives 1. Arguments as in
    :func:`sh_irradiance`.
    """
    return sh_irradiance(normals, sh) / math.pi


def directional_light_sh(direction: np.ndarray, irradiance: np.ndarray | float) -> np.ndarray:
    """SH coefficients of a distant point light (a delta in direction), shape (3, 9).

    Args:
        direction: (3,) direction *towards* the light (normalised here).
        irradiance: scalar or (3,) RGB irradiance the light delivers to a surface facing it.
    Returns:
        (3, 9) float64 coefficients ``irradiance * Y_j(direction)``; the resulting
        :func:`sh_irradiance` is the band-2 approximation of ``irradiance * max(0, n·l)``
        (largest error 3/32 * irradiance, at grazing incidence n·l = 0).
    """
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(d)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"direction must be a finite non-zero vector, got {d}")
    rgb = np.broadcast_to(np.asarray(irradiance, dtype=np.float64), (3,))
    basis = sh_basis(torch.from_numpy(d / norm)).numpy()
    return rgb[:, None] * basis[None, :]


@dataclass(frozen=True)
class SampledLighting:
    """Lighting environments drawn by :func:`sample_sh_lighting` (world frame, Y-up, the
    person facing +Z).

    Attributes:
        sh: (N, 3, 9) float64 radiance coefficients per RGB channel.
        ambient: (N, 3) shading (``E / pi``) the uniform part gives on its own.
        key_direction: (N, 3) unit direction towards the key light.
        key_shading: (N, 3) shading the key light adds to a surface facing it.
    """

    sh: np.ndarray
    ambient: np.ndarray
    key_direction: np.ndarray
    key_shading: np.ndarray


def sample_sh_lighting(rng: np.random.Generator, n: int = 1) -> SampledLighting:
    """Draw ``n`` plausible indoor lighting environments: a tinted ambient term plus a key light.

    The ambient shading is 0.35-0.75 with a slight colour tint; the key light comes from
    10-60 degrees above the horizon at any azimuth, though mostly from the front (+Z), and adds
    0.2-0.7 shading at normal incidence with its own warm or cool tint. A white surface is
    shaded between about 0.28 (facing away from the key light) and 1.7 (facing it).

    Args:
        rng: numpy random generator (the only source of randomness).
        n: number of environments (>= 0).
    Returns:
        :class:`SampledLighting` with N = n.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    ambient_level = rng.uniform(0.35, 0.75, size=(n, 1))
    ambient = ambient_level * rng.uniform(0.9, 1.1, size=(n, 3))
    front = rng.random(n) < 0.75
    azimuth = np.where(
        front, rng.uniform(-0.4 * np.pi, 0.4 * np.pi, n), rng.uniform(-np.pi, np.pi, n)
    )
    elevation = rng.uniform(np.deg2rad(10.0), np.deg2rad(60.0), n)
    key_direction = np.stack(
        [
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
            np.cos(elevation) * np.cos(azimuth),
        ],
        axis=-1,
    )
    key_shading = rng.uniform(0.2, 0.7, size=(n, 1)) * rng.uniform(0.85, 1.15, size=(n, 3))
    sh = np.zeros((n, 3, 9))
    # Uniform radiance a has L_0 = a * 2 sqrt(pi) and shades to exactly a.
    sh[:, :, 0] = ambient * 2.0 * math.sqrt(math.pi)
    for i in range(n):
        sh[i] += directional_light_sh(key_direction[i], math.pi * key_shading[i])
    return SampledLighting(
        sh=sh, ambient=ambient, key_direction=key_direction, key_shading=key_shading
    )
