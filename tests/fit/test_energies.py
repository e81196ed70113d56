"""Energy terms of pose fitting, each on a tiny synthetic case whose minimum is known.

References are independent of the code under test: plain-Python bilinear interpolation, the
exact Euclidean distance to a rectangle, scipy rotations, brute-force segment distances and
closed forms written out here.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from monoavatar.fit import energies
from monoavatar.fit.energies import SilhouetteTargets

DT = torch.float64


def _t(values: object) -> torch.Tensor:
    return torch.as_tensor(np.asarray(values, dtype=np.float64), dtype=DT)


# -- Geman-McClure ------------------------------------------------------------------------


def test_geman_mcclure_hand_values_and_bounds() -> None:
    sigma = 2.0
    squared = _t([0.0, 4.0, 1e-6, 1e8])
    rho = energies.geman_mcclure(squared, sigma)
    assert rho[0] == 0.0
    assert float(rho[1]) == pytest.approx(4.0 * 4.0 / (4.0 + 4.0))  # σ² r² / (σ² + r²) = 2
    assert float(rho[2]) == pytest.approx(1e-6, rel=1e-6)  # ≈ r² for small residuals
    assert float(rho[3]) < sigma**2 and float(rho[3]) == pytest.approx(sigma**2, rel=1e-6)
    grid = torch.linspace(0, 100, 1001, dtype=DT)
    values = energies.geman_mcclure(grid, sigma)
    assert bool((values.diff() > 0).all()) and bool((values < sigma**2).all())


# -- keypoints ------------------------------------------------------------------------------


def _keypoint_case(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Two frames, five keypoints, confidences in (0.2, 1), scale ~ 200 px."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 300, (2, 5, 2))
    conf = rng.uniform(0.2, 1.0, (2, 5, 1))
    return _t(xy), _t(np.concatenate([xy, conf], -1)), _t([180.0, 240.0])


def test_keypoint_energy_is_zero_exactly_at_the_detections_and_positive_elsewhere() -> None:
    projected, observed, scale = _keypoint_case()
    np.testing.assert_array_equal(energies.keypoint_energy(projected, observed, scale), 0.0)
    gen = torch.Generator().manual_seed(1)
    for _ in range(5):
        moved = projected + torch.randn(projected.shape, generator=gen, dtype=DT)
        assert bool((energies.keypoint_energy(moved, observed, scale) > 0).all())
    x = projected.clone().requires_grad_(True)
    energies.keypoint_energy(x, observed, scale).sum().backward()
    assert x.grad is not None
    np.testing.assert_allclose(x.grad.numpy(), 0.0, atol=1e-12)


def test_keypoint_energy_matches_its_closed_form() -> None:
    projected, observed, scale = _keypoint_case()
    projected = projected + 7.0 * torch.arange(10, dtype=DT).reshape(2, 5, 1) / 10
    sigma = 0.1
    p, o, s = projected.numpy(), observed.numpy(), scale.numpy()
    expected = []
    for b in range(2):
        total = 0.0
        for k in range(5):
            r2 = ((p[b, k, 0] - o[b, k, 0]) ** 2 + (p[b, k, 1] - o[b, k, 1]) ** 2) / s[b] ** 2
            total += o[b, k, 2] * sigma**2 * r2 / (sigma**2 + r2)
        expected.append(total / o[b, :, 2].sum())
    got = energies.keypoint_energy(projected, observed, scale, sigma)
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-12)


def test_keypoint_energy_ignores_absent_keypoints() -> None:
    projected, observed, scale = _keypoint_case()
    observed[0, 2, 2] = 0.0  # absent: its x, y are meaningless
    observed[0, 2, :2] = _t([1e5, -1e5])
    np.testing.assert_array_equal(energies.keypoint_energy(projected, observed, scale), 0.0)
    # a frame without any keypoint gives 0, not NaN
    observed[1, :, 2] = 0.0
    out = energies.keypoint_energy(projected + 5.0, observed, scale)
    assert float(out[1]) == 0.0 and bool(torch.isfinite(out).all())


def test_keypoint_energy_outlier_contribution_is_bounded_by_sigma_squared() -> None:
    projected, observed, scale = _keypoint_case()
    sigma = 0.1
    conf = observed[..., 2]
    bounds = []
    for distance in (1e2, 1e4, 1e7):
        moved = projected.clone()
        moved[:, 3] += distance  # one wild keypoint per frame, the others exact
        value = energies.keypoint_energy(moved, observed, scale, sigma)
        bound = conf[:, 3] * sigma**2 / conf.sum(-1)
        assert bool((value < bound).all())
        bounds.append(value)
    np.testing.assert_allclose(bounds[-1].numpy(), bound.numpy(), rtol=1e-9)


def test_keypoint_energy_does_not_depend_on_the_image_scale() -> None:
    projected, observed, scale = _keypoint_case()
    projected = projected + 3.0
    factor = 2.5
    scaled = observed.clone()
    scaled[..., :2] *= factor
    a = energies.keypoint_energy(projected, observed, scale)
    b = energies.keypoint_energy(projected * factor, scaled, scale * factor)
    np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=1e-12)


def test_keypoint_energy_gradcheck() -> None:
    projected, observed, scale = _keypoint_case()
    x = (projected + 9.0).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: energies.keypoint_energy(p, observed, scale), (x,))


# -- silhouette: distance pyramid, boundary samples, targets -----------------------------------

H, W = 96, 128
ROWS, COLS = (30, 69), (40, 89)  # inclusive pixel ranges of the rectangle mask


def _rectangle() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[ROWS[0] : ROWS[1] + 1, COLS[0] : COLS[1] + 1] = True
    return mask


def _exact_distance() -> np.ndarray:
    """Euclidean distance from each pixel centre to the nearest pixel centre of the
    rectangle (0 inside)."""
    rows, cols = np.mgrid[0:H, 0:W]
    dy = np.maximum(np.maximum(ROWS[0] - rows, rows - ROWS[1]), 0)
    dx = np.maximum(np.maximum(COLS[0] - cols, cols - COLS[1]), 0)
    return np.hypot(dx, dy)


def test_mask_pyramid_level_0_is_the_exact_distance_to_a_rectangle() -> None:
    dist = energies.mask_pyramid_distances(_rectangle(), levels=4)
    assert dist.shape == (4, H, W) and dist.dtype == np.float32
    np.testing.assert_allclose(dist[0], _exact_distance(), atol=1e-3)


def test_mask_pyramid_coarse_levels_are_in_level_0_pixels() -> None:
    """Each level is zero well inside the mask and, straight out from an edge, equals the
    level-0 distance up to the coarse pixel's half-size (a level measured in its own pixels
    would be 2^l times too small; one not corrected for the coarse pixel's centre would be
    biased by (2^l - 1) / 2 pixels)."""
    dist = energies.mask_pyramid_distances(_rectangle(), levels=4)
    exact = _exact_distance()
    row = (ROWS[0] + ROWS[1]) // 2
    for level in range(1, 4):
        factor = 2**level
        inner = dist[level, ROWS[0] + 2 * factor : ROWS[1] - 2 * factor,
                     COLS[0] + 2 * factor : COLS[1] - 2 * factor]  # fmt: skip
        np.testing.assert_array_equal(inner, 0.0)
        left = slice(2, COLS[0] - 2 * factor)
        error = dist[level, row, left] - exact[row, left]
        assert np.all(np.abs(error) <= factor / 2), (level, error)
        assert abs(float(np.mean(error))) < 0.25 * factor, (level, error)
    assert np.all(dist >= 0)


def test_mask_pyramid_of_a_full_mask_is_zero() -> None:
    np.testing.assert_array_equal(energies.mask_pyramid_distances(np.ones((32, 40), bool)), 0.0)


def test_boundary_samples_lie_on_the_rectangle_outline() -> None:
    mask = _rectangle()
    perimeter = 2 * (ROWS[1] - ROWS[0] + COLS[1] - COLS[0])  # outline pixels of the rectangle
    rng = np.random.default_rng(0)
    every = energies.boundary_samples(mask, 10_000, rng)
    assert every.shape == (perimeter, 2) and every.dtype == np.float32
    x, y = every[:, 0] - 0.5, every[:, 1] - 0.5  # back to pixel indices (x = column)
    on_x_edge = np.isin(x, COLS) & (y >= ROWS[0]) & (y <= ROWS[1])
    on_y_edge = np.isin(y, ROWS) & (x >= COLS[0]) & (x <= COLS[1])
    assert np.all(on_x_edge | on_y_edge)
    assert len(np.unique(every, axis=0)) == perimeter
    some = energies.boundary_samples(mask, 40, rng)
    assert some.shape == (40, 2)
    assert {tuple(p) for p in some} <= {tuple(p) for p in every}
    # spread along the outline: every edge gets samples
    for edge in (x == COLS[0], x == COLS[1], y == ROWS[0], y == ROWS[1]):
        assert edge.any()
    sx, sy = some[:, 0] - 0.5, some[:, 1] - 0.5
    for edge in (sx == COLS[0], sx == COLS[1], sy == ROWS[0], sy == ROWS[1]):
        assert edge.sum() >= 3
    assert energies.boundary_samples(np.zeros((8, 8), bool), 10, rng).shape == (0, 2)


def test_silhouette_targets_pad_and_measure_height() -> None:
    small = np.zeros((H, W), bool)
    small[10:20, 10:15] = True
    targets = energies.silhouette_targets(np.stack([_rectangle(), small, np.zeros((H, W), bool)]),
                                          levels=3, boundary_count=50)  # fmt: skip
    assert targets.outside.shape == (3, 3, H, W)
    assert targets.boundary.shape == (3, 50, 2)
    np.testing.assert_array_equal(targets.boundary_valid.sum(-1).numpy(), [50, 26, 0])
    np.testing.assert_array_equal(targets.scale.numpy(), [ROWS[1] - ROWS[0] + 1, 10, 1])


# -- bilinear sampling ------------------------------------------------------------------------


def _bilinear(image: np.ndarray, x: float, y: float) -> float:
    """Bilinear interpolation with pixel centres at (col + 0.5, row + 0.5), clamped at the
    border: a plain reference."""
    h, w = image.shape
    u = min(max(x - 0.5, 0.0), w - 1.0)
    v = min(max(y - 0.5, 0.0), h - 1.0)
    c0, r0 = int(np.floor(u)), int(np.floor(v))
    c1, r1 = min(c0 + 1, w - 1), min(r0 + 1, h - 1)
    fx, fy = u - c0, v - r0
    top = (1 - fx) * image[r0, c0] + fx * image[r0, c1]
    bottom = (1 - fx) * image[r1, c0] + fx * image[r1, c1]
    return float((1 - fy) * top + fy * bottom)


def test_sample_image_is_bilinear_with_pixel_centres_at_half_integers() -> None:
    rng = np.random.default_rng(3)
    image = rng.uniform(0, 10, (2, 3, 4))  # two channels, 3 rows, 4 columns
    points = np.array([[0.5, 0.5], [3.5, 2.5], [1.0, 1.0], [2.25, 1.8], [0.9, 2.1],
                       [-3.0, 1.2], [9.0, 7.0], [1.7, -2.0]])  # fmt: skip
    got = energies.sample_image(_t(image[None]), _t(points[None]))
    assert got.shape == (1, 2, len(points))
    expected = [[_bilinear(image[c], *p) for p in points] for c in range(2)]
    np.testing.assert_allclose(got[0].numpy(), expected, atol=1e-12)
    # a pixel centre returns the pixel; halfway between four centres, their mean
    assert float(got[0, 0, 0]) == pytest.approx(image[0, 0, 0])
    assert float(got[0, 0, 2]) == pytest.approx(image[0, :2, :2].mean())


def test_sample_image_gradient_matches_finite_differences() -> None:
    rng = np.random.default_rng(4)
    image = _t(rng.uniform(0, 10, (2, 3, 6, 7)))
    # interior points away from the pixel-centre lines where bilinear interpolation has kinks
    points = rng.integers(1, 5, (2, 5, 2)) + 0.5 + rng.uniform(0.1, 0.9, (2, 5, 2))
    x = _t(points).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: energies.sample_image(image, p), (x,))


# -- silhouette energies ----------------------------------------------------------------------


def test_outside_energy_is_zero_for_points_inside_the_mask() -> None:
    targets = energies.silhouette_targets(_rectangle()[None], levels=4)
    rng = np.random.default_rng(5)
    margin = 16  # coarse levels blur the outline by a few pixels
    inside = np.stack([rng.uniform(COLS[0] + margin, COLS[1] + 1 - margin, 200),
                       rng.uniform(ROWS[0] + margin, ROWS[1] + 1 - margin, 200)], -1)  # fmt: skip
    assert float(energies.outside_energy(_t(inside[None]), targets)) == 0.0


def test_outside_energy_equals_the_distance_to_a_rectangle_at_level_0() -> None:
    targets = energies.silhouette_targets(_rectangle()[None], levels=1)
    scale = ROWS[1] - ROWS[0] + 1
    exact = _exact_distance()
    cells = np.array([[5, 50], [100, 31], [20, 8], [120, 90], [64, 50]])  # (col, row)
    points = cells + 0.5  # pixel centres, where level 0 is exact
    distance = exact[cells[:, 1], cells[:, 0]]
    assert distance[-1] == 0.0 and distance[:-1].min() > 5
    value = energies.outside_energy(_t(points[None]), targets)
    assert float(value) == pytest.approx(((distance / scale) ** 2).mean(), rel=1e-5)
    # the gradient pulls a point left of the rectangle to the right, straight towards it
    x = _t([[[20.3, 50.5]]]).requires_grad_(True)
    energies.outside_energy(x, targets).sum().backward()
    assert x.grad is not None
    gx, gy = x.grad[0, 0].tolist()
    assert gx < 0 and abs(gy) < 1e-6 * abs(gx)


def _one_frame_targets(boundary: list[list[float]], valid: list[bool],
                       scale: float) -> SilhouetteTargets:  # fmt: skip
    return SilhouetteTargets(
        outside=torch.zeros(1, 1, 4, 4, dtype=DT),
        boundary=_t([boundary]),
        boundary_valid=torch.tensor([valid]),
        scale=_t([scale]),
    )


def test_coverage_energy_is_zero_when_model_points_cover_the_boundary() -> None:
    targets = energies.silhouette_targets(_rectangle()[None], boundary_count=60)
    boundary = targets.boundary[:, targets.boundary_valid[0]].to(DT)
    rng = np.random.default_rng(6)
    interior = _t(rng.uniform([COLS[0] + 5, ROWS[0] + 5], [COLS[1] - 5, ROWS[1] - 5], (1, 50, 2)))
    model = torch.cat([boundary, interior], dim=1).requires_grad_(True)
    value = energies.coverage_energy(model, targets)
    assert float(value.detach()) == 0.0
    value.sum().backward()  # a model point exactly on a sample: the gradient stays finite
    assert model.grad is not None and bool(torch.isfinite(model.grad).all())
    # without the model points of the left half of the outline, coverage is missed
    keep = boundary[0, :, 0] > (COLS[0] + COLS[1]) / 2
    partial = torch.cat([boundary[:, keep], interior], dim=1)
    assert float(energies.coverage_energy(partial, targets)) > 0.0


def test_coverage_energy_closed_form_and_padding() -> None:
    sigma, scale = 0.1, 100.0
    targets = _one_frame_targets([[10, 10], [20, 10], [500, 500]], [True, True, False], scale)
    model = _t([[[10, 13], [40, 40]]])
    r2 = np.array([9.0, 10.0**2 + 3.0**2]) / scale**2  # nearest model point: (10, 13) for both
    expected = (sigma**2 * r2 / (sigma**2 + r2)).mean()  # the padded sample does not count
    got = energies.coverage_energy(model, targets, sigma)
    assert float(got) == pytest.approx(expected, rel=1e-12)
    x = _t([[[10.7, 13.2], [40, 40]]]).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: energies.coverage_energy(p, targets, sigma), (x,))


def test_padding_model_points_count_in_neither_silhouette_term() -> None:
    """A frame padded with model points marked invalid (``points_valid``) has the energies of
    the frame without them, although the padding lies far outside the mask and right on the
    boundary samples."""
    targets = energies.silhouette_targets(_rectangle()[None], levels=2, boundary_count=40)
    boundary = targets.boundary[:, targets.boundary_valid[0]].to(DT)
    rng = np.random.default_rng(7)
    real = _t(rng.uniform([COLS[0] - 20, ROWS[0] - 20], [COLS[1] + 20, ROWS[1] + 20], (1, 30, 2)))
    padded = torch.cat([real, boundary + 0.25, _t([[[1.5, 1.5]]])], dim=1)
    valid = torch.zeros(1, padded.shape[1], dtype=torch.bool)
    valid[0, :30] = True
    assert float(energies.outside_energy(padded, targets, valid)) == pytest.approx(
        float(energies.outside_energy(real, targets)), rel=1e-6)
    assert float(energies.coverage_energy(padded, targets, 0.1, valid)) == pytest.approx(
        float(energies.coverage_energy(real, targets, 0.1)), rel=1e-6)
    # and the padding would have changed both
    assert float(energies.outside_energy(padded, targets)) != pytest.approx(
        float(energies.outside_energy(real, targets)), rel=1e-3)
    assert float(energies.coverage_energy(padded, targets, 0.1)) < 0.5 * float(
        energies.coverage_energy(real, targets, 0.1))


def test_correspondence_energy_point_to_point_and_point_to_line_closed_forms() -> None:
    sigma, scale = 1.0, 50.0
    projected = _t([[[10.0, 10.0], [20.0, 5.0], [0.0, 0.0]]])
    targets = _t([[[13.0, 14.0], [20.0, 5.0], [9.0, 9.0]]])
    valid = torch.tensor([[True, True, False]])
    r2 = np.array([25.0, 0.0]) / scale**2  # |(−3, −4)| = 5 px; the invalid point does not count
    expected = (sigma**2 * r2 / (sigma**2 + r2)).mean()
    got = energies.correspondence_energy(projected, targets, valid, _t([scale]), sigma)
    assert float(got) == pytest.approx(expected, rel=1e-12)
    # along unit normals only: the first offset (−3, −4) has −4 along (0, 1), none along (1, 0)
    for normal, along in (([0.0, 1.0], 4.0), ([1.0, 0.0], 3.0), ([0.6, 0.8], 5.0)):
        normals = _t([[normal, [1.0, 0.0], [1.0, 0.0]]])
        r2 = np.array([along**2, 0.0]) / scale**2
        expected = (sigma**2 * r2 / (sigma**2 + r2)).mean()
        got = energies.correspondence_energy(projected, targets, valid, _t([scale]), sigma,
                                             normals)  # fmt: skip
        assert float(got) == pytest.approx(expected, rel=1e-12), normal
    # sliding along the line costs nothing
    slid = projected + _t([[[1.0, 0.0], [7.0, 0.0], [0.0, 0.0]]]) * 3.0
    normals = _t([[[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]]])
    a = energies.correspondence_energy(projected, targets, valid, _t([scale]), sigma, normals)
    b = energies.correspondence_energy(slid, targets, valid, _t([scale]), sigma, normals)
    assert float(a) == pytest.approx(float(b), rel=1e-12)
    x = projected.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda p: energies.correspondence_energy(p, targets, valid, _t([scale]), sigma, normals),
        (x,),
    )


# -- pose prior, limits -----------------------------------------------------------------------


def test_gaussian_prior_is_zero_at_the_mean_and_mahalanobis_elsewhere() -> None:
    rng = np.random.default_rng(7)
    d = 6
    a = rng.normal(size=(d, d))
    precision = a @ a.T + np.eye(d)
    mean = rng.normal(size=d)
    poses = np.stack([mean, mean + rng.normal(size=d), mean - 0.3])
    got = energies.gaussian_prior_energy(_t(poses), _t(mean), _t(precision))
    expected = [(p - mean) @ precision @ (p - mean) for p in poses]
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-12)
    assert float(got[0]) == 0.0 and bool((got[1:] > 0).all())
    # a diagonal precision gives Σ ((θ − μ) / σ)²
    std = rng.uniform(0.1, 1.0, d)
    diag = energies.gaussian_prior_energy(_t(poses), _t(mean), _t(np.diag(std**-2)))
    np.testing.assert_allclose(diag.numpy(), (((poses - mean) / std) ** 2).sum(-1), rtol=1e-12)
    x = _t(poses).requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda p: energies.gaussian_prior_energy(p, _t(mean), _t(precision)), (x,)
    )


def test_hinge_limits_are_zero_inside_the_range_and_quadratic_outside() -> None:
    limits = [(1, 0, -0.1, 2.6), (2, 2, -0.4, 0.4)]
    pose = torch.zeros(4, 3, 3, dtype=DT)
    pose[0, 1, 0], pose[0, 2, 2] = 2.5, -0.39  # inside both ranges
    pose[1, 1, 0] = 2.9  # 0.3 above
    pose[2, 1, 0], pose[2, 2, 2] = -0.3, 0.6  # 0.2 below, 0.2 above
    pose[3, 0], pose[3, 1, 1], pose[3, 2, 0] = 5.0, 7.0, -9.0  # only limited entries count
    got = energies.hinge_limit_energy(pose, limits)
    np.testing.assert_allclose(got.numpy(), [0.0, 0.09, 0.08, 0.0], atol=1e-12)
    x = (pose + 0.01).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: energies.hinge_limit_energy(p, limits), (x,))


# -- rotations and temporal smoothness ----------------------------------------------------------


def test_small_rotation_vector_is_axis_times_sin_angle() -> None:
    rng = np.random.default_rng(8)
    axes = rng.normal(size=(6, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.array([0.0, 1e-4, 0.1, 0.9, 2.0, np.pi])
    matrices = Rotation.from_rotvec(axes * angles[:, None]).as_matrix()
    got = energies.small_rotation_vector(_t(matrices))
    np.testing.assert_allclose(got.numpy(), axes * np.sin(angles)[:, None], atol=1e-12)
    # to first order it is the rotation vector
    tiny = Rotation.from_rotvec(axes[2] * 1e-3).as_matrix()
    np.testing.assert_allclose(energies.small_rotation_vector(_t(tiny)).numpy(), axes[2] * 1e-3,
                               rtol=1e-6)  # fmt: skip


def _steady_turn(
    frames: int, step: float, speed: float = 1.0, seed: int = 9
) -> tuple[torch.Tensor, ...]:
    """Roots turning at a constant rate about a fixed tilted axis, a constant body pose and a
    translation moving at constant velocity."""
    rng = np.random.default_rng(seed)
    axis = np.array([0.2, 1.0, -0.1])
    axis /= np.linalg.norm(axis)
    start = Rotation.from_rotvec(rng.normal(size=3))
    roots = np.stack([(Rotation.from_rotvec(axis * step * k) * start).as_matrix()
                      for k in range(frames)])  # fmt: skip
    body = np.repeat(rng.normal(size=(1, 4, 3)), frames, 0)
    velocity = speed * np.array([0.01, -0.02, 0.03])
    translation = rng.normal(size=3) + velocity * np.arange(frames)[:, None]
    return _t(roots), _t(body), _t(translation), _t(axis), _t(velocity)


def test_smoothness_is_zero_for_a_constant_pose() -> None:
    roots, body, translation, *_ = _steady_turn(5, 0.0, speed=0.0)
    got = energies.smoothness_energy(roots, body, translation)
    assert got.shape == (5,)
    np.testing.assert_allclose(got.numpy(), 0.0, atol=1e-24)
    one = energies.smoothness_energy(roots[:1], body[:1], translation[:1])
    np.testing.assert_array_equal(one.numpy(), [0.0])


def test_smoothness_is_zero_for_a_steady_turn_after_the_second_frame() -> None:
    step, ts = 0.2, 0.1
    roots, body, translation, axis, velocity = _steady_turn(6, step)
    got = energies.smoothness_energy(roots, body, translation, translation_scale=ts)
    omega = axis.numpy() * np.sin(step)  # the angular velocity as small_rotation_vector sees it
    first = 0.1 * ((omega**2).sum() + ((velocity.numpy() / ts) ** 2).sum())
    np.testing.assert_allclose(got.numpy(), [0.0, first, 0, 0, 0, 0], atol=1e-12)
    # after two fitted frames of the same motion, every new frame costs nothing
    history = (roots[:2], body[:2], translation[:2])
    tail = energies.smoothness_energy(roots[2:], body[2:], translation[2:], history, ts)
    assert tail.shape == (4,)
    np.testing.assert_allclose(tail.numpy(), 0.0, atol=1e-12)


def test_smoothness_penalises_a_jerk_on_the_three_frames_it_touches() -> None:
    roots, body, translation, *_ = _steady_turn(8, 0.15)
    jerked = roots.clone()
    k = 4
    jerked[k] = _t(Rotation.from_rotvec([0.0, 0.05, 0.0]).as_matrix()) @ roots[k]
    got = energies.smoothness_energy(jerked, body, translation)
    base = energies.smoothness_energy(roots, body, translation)
    changed = (got - base).abs() > 1e-10
    np.testing.assert_array_equal(changed.numpy(), [i in (k, k + 1, k + 2) for i in range(8)])
    assert bool((got[k : k + 3] > 1e-4).all())
    # with history the same frames are penalised
    tail = energies.smoothness_energy(jerked[3:], body[3:], translation[3:],
                                      (jerked[:3], body[:3], translation[:3]))  # fmt: skip
    np.testing.assert_allclose(tail.numpy(), got[3:].numpy(), atol=1e-12)


def test_smoothness_of_body_joints_and_translation_closed_forms() -> None:
    roots, body, translation, *_ = _steady_turn(5, 0.0, speed=0.0)
    stepped = body.clone()
    delta = _t(np.arange(12).reshape(4, 3) * 0.01)
    stepped[3:] += delta  # the body changes once, between frames 2 and 3
    got = energies.smoothness_energy(roots, stepped, translation)
    expected = np.zeros(5)
    expected[3] = float((delta**2).sum())
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-12)
    # a velocity change of dv metres per frame costs (dv / translation_scale)²
    moved = translation.clone()
    moved[4] += _t([0.0, 0.03, 0.0])
    got = energies.smoothness_energy(roots, body, moved, translation_scale=0.1)
    assert float(got[4]) == pytest.approx((0.03 / 0.1) ** 2, rel=1e-9)
    np.testing.assert_allclose(got[2:4].numpy(), 0.0, atol=1e-12)


def test_smoothness_gradcheck() -> None:
    roots, body, translation, *_ = _steady_turn(4, 0.1)
    gen = torch.Generator().manual_seed(0)
    noisy = translation + 0.01 * torch.randn(translation.shape, generator=gen, dtype=DT)
    history = (roots[:1], body[:1], translation[:1])
    args = (roots[1:].clone().requires_grad_(True), (body[1:] + 0.02).requires_grad_(True),
            noisy[1:].clone().requires_grad_(True))  # fmt: skip
    assert torch.autograd.gradcheck(
        lambda r, b, t: energies.smoothness_energy(r, b, t, history), args
    )


# -- self-penetration -----------------------------------------------------------------------


def test_segment_distance_matches_brute_force() -> None:
    rng = np.random.default_rng(10)
    points, a, b = rng.normal(size=(3, 50, 3))
    b[0] = a[0]  # a degenerate segment: the distance to its single point
    got = energies.segment_distance(_t(points), _t(a), _t(b)).numpy()
    t = np.linspace(0.0, 1.0, 20001)[:, None, None]
    samples = a + t * (b - a)  # (T, 50, 3)
    brute = np.linalg.norm(samples - points, axis=-1).min(axis=0)
    np.testing.assert_allclose(got, brute, atol=1e-6)
    assert got[0] == pytest.approx(np.linalg.norm(points[0] - a[0]))


def test_penetration_energy_is_zero_beyond_the_radius() -> None:
    a = _t([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b = _t([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    radius = 0.1
    points = _t([[[0.15, 0.5, 0.0], [0.0, 1.2, 0.0], [0.0, -0.101, 0.0]],
                 [[0.04, 0.5, 0.0], [0.0, 0.3, 0.07], [0.5, 0.5, 0.5]]])  # fmt: skip
    got = energies.penetration_energy(points, a, b, radius)
    expected = [0.0, (6.0) ** 2 + (3.0) ** 2]  # ((r − d) in cm)², d = 4 cm and 7 cm
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-9)
    # the gradient pushes a penetrating point away from the axis
    x = points.clone().requires_grad_(True)
    energies.penetration_energy(x, a, b, radius).sum().backward()
    assert x.grad is not None
    assert float(x.grad[1, 0, 0]) < 0 and float(x.grad[1, 1, 2]) < 0
    np.testing.assert_array_equal(x.grad[0].numpy(), 0.0)
    assert torch.autograd.gradcheck(
        lambda p: energies.penetration_energy(p, a, b, radius), (points.clone().requires_grad_(),)
    )


def test_nearest_points_agree_with_brute_force_and_skip_invalid_points() -> None:
    rng = np.random.default_rng(8)
    queries = _t(rng.uniform(0, 100, (3, 40, 2)))
    points = _t(rng.uniform(0, 100, (3, 70, 2)))
    brute = ((queries[:, :, None] - points[:, None]) ** 2).sum(-1).argmin(-1)
    assert torch.equal(energies.nearest_points(queries, points), brute)
    valid = torch.from_numpy(rng.random((3, 70)) < 0.3)
    masked = ((queries[:, :, None] - points[:, None]) ** 2).sum(-1)
    masked = masked.masked_fill(~valid[:, None, :], float("inf")).argmin(-1)
    got = energies.nearest_points(queries, points, valid)
    assert torch.equal(got, masked)
    assert bool(valid.gather(1, got).all())
