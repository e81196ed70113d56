"""The pose predictors of Sec. A.3.4 against closed forms: the steady-state covariance of the
discrete Riccati equation, exact constant-velocity motion, and the rotation filter about a
fixed axis reducing to the linear filter on the angle."""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_discrete_are
from scipy.spatial.transform import Rotation

from monoavatar.fit.kalman import RotationFilter, TranslationFilter


def test_translation_covariance_reaches_the_riccati_steady_state() -> None:
    accel, measure = 2e-4, 5e-4
    f = TranslationFilter.start(np.zeros((1, 3)), accel, measure)
    for _ in range(300):
        f = f.predict().update(np.zeros((1, 3)))
    prior = f.predict().cov[0]
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    Q = accel * np.array([[0.25, 0.5], [0.5, 1.0]])
    steady = solve_discrete_are(F.T, H.T, Q, np.array([[measure]]))
    for axis in range(3):  # each axis is the same 1D filter: positions axis, velocities axis+3
        block = prior[np.ix_([axis, axis + 3], [axis, axis + 3])]
        np.testing.assert_allclose(block, steady, rtol=1e-8)
    assert abs(prior[0, 1]) < 1e-15  # the axes stay independent


def test_constant_velocity_is_predicted_exactly_in_the_limit() -> None:
    start, velocity = np.array([0.2, -1.0, 3.0]), np.array([0.01, 0.02, -0.005])
    f = TranslationFilter.start(start[None])
    for t in range(1, 80):
        f = f.predict().update((start + velocity * t)[None])
    predicted = f.predict().position[0]
    np.testing.assert_allclose(predicted, start + velocity * 80, atol=1e-6)
    np.testing.assert_allclose(f.mean[0, 3:], velocity, atol=1e-7)


def test_rotation_about_a_fixed_axis_is_the_linear_filter_on_the_angle() -> None:
    rng = np.random.default_rng(1)
    angles = 0.1 + 0.02 * np.arange(40) + rng.normal(scale=0.01, size=40)
    axis = np.array([1.0, 0.0, 0.0])
    rot = RotationFilter.start((angles[0] * axis)[None], accel_var=3e-4, measure_var=2e-4)
    lin = TranslationFilter.start((angles[0] * axis)[None], accel_var=3e-4, measure_var=2e-4,
                                  velocity_var=1e-1)  # fmt: skip
    for a in angles[1:]:
        rot = rot.predict().update((a * axis)[None])
        lin = lin.predict().update((a * axis)[None])
        np.testing.assert_allclose(rot.axis_angle[0], lin.position[0], atol=1e-12)
    np.testing.assert_allclose(rot.predict().axis_angle[0], lin.predict().position[0], atol=1e-12)


def test_constant_angular_velocity_about_any_axis_is_followed() -> None:
    omega = np.array([0.03, -0.02, 0.04])  # radians per frame, world-side
    r0 = Rotation.from_rotvec([0.3, 0.5, -0.2])
    truth = [Rotation.from_rotvec(omega * t) * r0 for t in range(61)]
    f = RotationFilter.start(truth[0].as_rotvec()[None], accel_var=1e-5, measure_var=1e-4)
    for r in truth[1:60]:
        f = f.predict().update(r.as_rotvec()[None])
    predicted = Rotation.from_matrix(f.predict().rotation[0])
    error = (predicted * truth[60].inv()).magnitude()
    assert error < 1e-4
    np.testing.assert_allclose(f.velocity[0], omega, atol=1e-4)
