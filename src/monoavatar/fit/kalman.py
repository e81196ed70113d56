"""Kalman filters that predict a pose for the next frame (Sec. A.3.4): a linear Kalman filter on
the root translation and an extended Kalman filter per joint rotation, both with a
constant-velocity motion model. The prediction starts the next frame's fit; the update takes
the fitted pose as the measurement.

Translation (per axis): state ``(x, v)``, metres and metres per frame;
``x' = x + v``, ``v' = v`` plus white-acceleration noise of variance ``accel_var``
(m²/frame⁴); measurement ``x`` with variance ``measure_var`` (m²).

Rotation (per joint, on SO(3)): mean rotation ``R`` (3, 3) and angular velocity ``ω``
(3,) radians per frame (world-side: ``R' = exp(ω) R``); the covariance (6, 6) lives on the
error state ``(δθ, δω)`` with ``R_true = exp(δθ) R``. The measurement is a rotation ``Z``;
the innovation is ``log(Z Rᵀ)``, linearised at ``δθ = 0`` (the extended filter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["RotationFilter", "TranslationFilter"]


def _cv_matrices(dims: int, accel_var: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition F (2d, 2d) and process noise Q of ``dims`` independent constant-velocity
    axes, state ordered (positions, velocities), one frame per step."""
    eye = np.eye(dims)
    F = np.block([[eye, eye], [np.zeros((dims, dims)), eye]])
    q = accel_var * np.array([[0.25, 0.5], [0.5, 1.0]])  # white acceleration, dt = 1
    Q = np.kron(q, eye)
    return F, Q


def _update(cov: np.ndarray, innovation: np.ndarray, measure_var: float
            ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The Kalman update of N (6, 6) covariances on (position, velocity) states measured in
    their first three components: the state corrections (N, 6) and the new covariances."""
    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    S = H @ cov @ H.T + measure_var * np.eye(3)
    K = cov @ H.T @ np.linalg.inv(S)
    return np.einsum("nij,nj->ni", K, innovation), (np.eye(6) - K @ H) @ cov


@dataclass
class TranslationFilter:
    """Linear Kalman filter on (N, 3) translations (one filter per row, e.g. one person).

    Attributes:
        mean: (N, 6) positions (m) then velocities (m/frame).
        cov: (N, 6, 6).
        accel_var: process noise, m²/frame⁴; measure_var: measurement noise, m².
    """

    mean: np.ndarray
    cov: np.ndarray
    accel_var: float = 1e-4
    measure_var: float = 1e-4

    @classmethod
    def start(cls, position: np.ndarray, accel_var: float = 1e-4, measure_var: float = 1e-4,
              velocity_var: float = 1e-2) -> TranslationFilter:  # fmt: skip
        """At ``position`` (N, 3), velocity zero with variance ``velocity_var``."""
        p = np.atleast_2d(np.asarray(position, dtype=np.float64))
        mean = np.concatenate([p, np.zeros_like(p)], axis=1)
        cov = np.diag([measure_var] * 3 + [velocity_var] * 3)
        return cls(mean, np.repeat(cov[None], len(p), axis=0), accel_var, measure_var)

    def predict(self) -> TranslationFilter:
        """One frame ahead."""
        F, Q = _cv_matrices(3, self.accel_var)
        mean = self.mean @ F.T
        cov = F @ self.cov @ F.T + Q
        return TranslationFilter(mean, cov, self.accel_var, self.measure_var)

    def update(self, position: np.ndarray) -> TranslationFilter:
        """Fold in a measured position (N, 3)."""
        z = np.atleast_2d(np.asarray(position, dtype=np.float64))
        delta, cov = _update(self.cov, z - self.mean[:, :3], self.measure_var)
        return TranslationFilter(self.mean + delta, cov, self.accel_var, self.measure_var)

    @property
    def position(self) -> np.ndarray:
        """(N, 3) metres."""
        return self.mean[:, :3]


@dataclass
class RotationFilter:
    """Extended Kalman filter on J joint rotations.

    Attributes:
        rotation: (J, 3, 3) mean rotations.
        velocity: (J, 3) angular velocities, radians per frame (world-side).
        cov: (J, 6, 6) on the error state (δθ, δω).
        accel_var: process noise, rad²/frame⁴; measure_var: measurement noise, rad².
    """

    rotation: np.ndarray
    velocity: np.ndarray
    cov: np.ndarray
    accel_var: float = 1e-3
    measure_var: float = 1e-3

    @classmethod
    def start(cls, axis_angle: np.ndarray, accel_var: float = 1e-3, measure_var: float = 1e-3,
              velocity_var: float = 1e-1) -> RotationFilter:  # fmt: skip
        """At the rotations ``axis_angle`` (J, 3) radians, velocity zero."""
        aa = np.atleast_2d(np.asarray(axis_angle, dtype=np.float64))
        cov = np.diag([measure_var] * 3 + [velocity_var] * 3)
        return cls(Rotation.from_rotvec(aa).as_matrix(), np.zeros_like(aa),
                   np.repeat(cov[None], len(aa), axis=0), accel_var, measure_var)  # fmt: skip

    def predict(self) -> RotationFilter:
        """One frame ahead: ``R' = exp(ω) R``."""
        F, Q = _cv_matrices(3, self.accel_var)
        step = Rotation.from_rotvec(self.velocity).as_matrix()
        return RotationFilter(step @ self.rotation, self.velocity.copy(),
                              F @ self.cov @ F.T + Q, self.accel_var, self.measure_var)  # fmt: skip

    def update(self, axis_angle: np.ndarray) -> RotationFilter:
        """Fold in measured rotations (J, 3) axis-angle radians."""
        Z = Rotation.from_rotvec(np.atleast_2d(axis_angle)).as_matrix()
        innovation = Rotation.from_matrix(Z @ np.transpose(self.rotation, (0, 2, 1))).as_rotvec()
        delta, cov = _update(self.cov, innovation, self.measure_var)
        rotation = Rotation.from_rotvec(delta[:, :3]).as_matrix() @ self.rotation
        return RotationFilter(rotation, self.velocity + delta[:, 3:], cov, self.accel_var,
                              self.measure_var)  # fmt: skip

    @property
    def axis_angle(self) -> np.ndarray:
        """(J, 3) radians."""
        return Rotation.from_matrix(self.rotation).as_rotvec()
