"""Pinhole camera in the OpenCV convention, projection, and camera rays.

Conventions (DESIGN.md):
- camera axes: x right, y down, z forward (OpenCV);
- world-to-camera extrinsics: ``x_cam = R @ x_world + t``;
- pixel coordinates with the origin at the top-left *corner* of the top-left pixel, so the
  centre of pixel (col, row) is at (col + 0.5, row + 0.5);
- units: metres for geometry, pixels for the image.

Rays are returned as origins and unit directions in world space; :func:`plucker` turns them
into Plücker coordinates (Eq. 3.11): moment ``m = o × n`` and direction ``n``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from monoavatar.core.errors import MonoavatarError


class CameraError(MonoavatarError, ValueError):
    """A camera file or camera parameters are invalid."""


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera.

    Attributes:
        K: (3, 3) intrinsics in pixels.
        R: (3, 3) world-to-camera rotation.
        t: (3,) world-to-camera translation, metres.
        width, height: image size in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        R = np.asarray(self.R, dtype=np.float64)
        t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        if K.shape != (3, 3):
            raise CameraError(f"K must be 3x3, got shape {K.shape}")
        if R.shape != (3, 3):
            raise CameraError(f"R must be 3x3, got shape {R.shape}")
        if t.shape != (3,):
            raise CameraError(f"t must have 3 entries, got shape {t.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise CameraError("R must be a rotation matrix (orthonormal, det +1)")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CameraError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # -- construction -------------------------------------------------------------------
    @staticmethod
    def from_focal(
        focal_px: float,
        width: int,
        height: int,
        R: np.ndarray | None = None,
        t: np.ndarray | None = None,
    ) -> PinholeCamera:
        """A camera with square pixels and the principal point at the image centre."""
        K = np.array([[focal_px, 0.0, width / 2.0], [0.0, focal_px, height / 2.0], [0.0, 0.0, 1.0]])
        return PinholeCamera(
            K=K,
            R=np.eye(3) if R is None else R,
            t=np.zeros(3) if t is None else t,
            width=width,
            height=height,
        )

    @staticmethod
    def look_at(
        eye: np.ndarray,
        target: np.ndarray,
        up: np.ndarray,
        focal_px: float,
        width: int,
        height: int,
    ) -> PinholeCamera:
        """A camera at ``eye`` (world, metres) looking at ``target`` with world ``up`` upwards
        in the image."""
        eye = np.asarray(eye, dtype=np.float64)
        z = np.asarray(target, dtype=np.float64) - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, np.asarray(up, dtype=np.float64))  # right = forward × up
        if np.linalg.norm(x) < 1e-9:
            raise CameraError("up is parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        return PinholeCamera.from_focal(focal_px, width, height, R=R, t=-R @ eye)

    # -- properties ---------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, metres."""
        return np.asarray(-self.R.T @ self.t)

    def scaled(self, factor: float) -> PinholeCamera:
        """The same camera for an image resized by ``factor`` (e.g. 0.5 for half size)."""
        S = np.diag([factor, factor, 1.0])
        return PinholeCamera(
            K=S @ self.K,
            R=self.R,
            t=self.t,
            width=max(1, round(self.width * factor)),
            height=max(1, round(self.height * factor)),
        )

    # -- geometry -----------------------------------------------------------------------
    def world_to_camera(self, points: Tensor) -> Tensor:
        """points: (..., 3) world → (..., 3) camera coordinates (metres)."""
        R = torch.as_tensor(self.R, dtype=points.dtype, device=points.device)
        t = torch.as_tensor(self.t, dtype=points.dtype, device=points.device)
        return points @ R.T + t

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Project world points.

        Args:
            points: (..., 3) world coordinates, metres.
        Returns:
            pixels: (..., 2) pixel coordinates (x, y), origin at the top-left corner.
            depth: (...,) camera-space z, metres.
        """
        cam = self.world_to_camera(points)
        K = torch.as_tensor(self.K, dtype=points.dtype, device=points.device)
        z = cam[..., 2]
        uvw = cam @ K.T
        pixels = uvw[..., :2] / z.clamp_min(1e-9).unsqueeze(-1)
        return pixels, z

    def pixel_rays(self, pixels: Tensor) -> tuple[Tensor, Tensor]:
        """Rays through pixel coordinates.

        Args:
            pixels: (..., 2) pixel coordinates (x, y); a pixel's centre is at (col+0.5, row+0.5).
        Returns:
            origins: (..., 3) the camera centre, world coordinates.
            directions: (..., 3) unit directions, world coordinates.
        """
        K_inv = torch.as_tensor(np.linalg.inv(self.K), dtype=pixels.dtype, device=pixels.device)
        R = torch.as_tensor(self.R, dtype=pixels.dtype, device=pixels.device)
        homo = torch.cat([pixels, torch.ones_like(pixels[..., :1])], dim=-1)
        d_cam = homo @ K_inv.T
        d_world = d_cam @ R  # R^T @ d for row vectors
        d_world = d_world / d_world.norm(dim=-1, keepdim=True)
        origin = torch.as_tensor(self.center, dtype=pixels.dtype, device=pixels.device)
        return origin.expand_as(d_world), d_world

    # -- serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict[str, object]:
        return {
            "K": self.K.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "width": self.width,
            "height": self.height,
            "convention": "opencv: x right, y down, z forward; x_cam = R x_world + t; metres",
        }

    @staticmethod
    def from_dict(data: dict[str, object]) -> PinholeCamera:
        missing = {"K", "R", "t", "width", "height"} - set(data)
        if missing:
            raise CameraError(f"camera description lacks {sorted(missing)}")
        return PinholeCamera(
            K=np.asarray(data["K"], dtype=np.float64),
            R=np.asarray(data["R"], dtype=np.float64),
            t=np.asarray(data["t"], dtype=np.float64),
            width=int(data["width"]),  # type: ignore[call-overload]
            height=int(data["height"]),  # type: ignore[call-overload]
        )

    def save_json(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2))

    @staticmethod
    def load_json(path: str | Path) -> PinholeCamera:
        path = Path(path)
        if not path.is_file():
            raise CameraError(f"camera file not found: {path}")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise CameraError(f"{path} is not valid JSON: {exc}") from exc
        return PinholeCamera.from_dict(data)


def plucker(origins: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
    """Plücker coordinates of rays (Eq. 3.11).

    Args:
        origins: (..., 3) a point on each ray.
        directions: (..., 3) ray directions (normalised here).
    Returns:
        moment: (..., 3) ``m = o × n``; direction: (..., 3) unit ``n``.
    """
    n = directions / directions.norm(dim=-1, keepdim=True)
    return torch.cross(origins, n, dim=-1), n


def point_line_distance(points: Tensor, moment: Tensor, direction: Tensor) -> Tensor:
    """Distance of points to lines in Plücker form (Eq. B.8): ``|x × n − m|`` for unit ``n``.

    Args:
        points: (..., 3); moment, direction: (..., 3) with unit directions.
    Returns:
        (...,) distances in the points' units.
    """
    return (torch.cross(points, direction, dim=-1) - moment).norm(dim=-1)
