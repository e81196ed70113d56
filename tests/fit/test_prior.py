"""The A-pose prior learned from ``monoavatar synth`` turn-arounds."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from monoavatar.body.model import BodyModel
from monoavatar.body.motion import turnaround
from monoavatar.fit.energies import gaussian_prior_energy
from monoavatar.fit.prior import PosePrior, apose_prior


@pytest.fixture(scope="module")
def prior(anny32: BodyModel) -> PosePrior:
    return apose_prior(anny32)


def test_prior_shapes_and_dtype(anny32: BodyModel, prior: PosePrior) -> None:
    d = 3 * (anny32.num_joints - 1)  # the root is excluded
    assert prior.mean.shape == (d,) and prior.precision.shape == (d, d)
    assert prior.mean.dtype == torch.float64 and prior.precision.dtype == torch.float64
    as32 = prior.to(torch.float32)
    assert as32.mean.dtype == torch.float32 and as32.precision.dtype == torch.float32
    np.testing.assert_allclose(as32.precision.numpy(), prior.precision.numpy(), rtol=1e-6)


def test_prior_precision_is_symmetric_positive_definite(prior: PosePrior) -> None:
    p = prior.precision.numpy()
    np.testing.assert_allclose(p, p.T, atol=1e-9 * np.abs(p).max())
    assert np.linalg.eigvalsh(p).min() > 0


def test_prior_mean_is_an_a_pose(anny32: BodyModel, prior: PosePrior) -> None:
    """Near zero for every joint parameter except the shoulders' abduction (arms held a
    little away from the body, mirrored between the sides)."""
    mean = prior.mean.reshape(-1, 3).numpy()
    left = anny32.joint_index("shoulder_l") - 1
    right = anny32.joint_index("shoulder_r") - 1
    abduction = {(left, 2), (right, 2)}
    others = [mean[j, a] for j in range(len(mean)) for a in range(3) if (j, a) not in abduction]
    assert np.abs(others).max() < 0.01
    assert 0.02 < mean[left, 2] < 0.2 and mean[right, 2] == pytest.approx(-mean[left, 2], abs=0.01)


def test_prior_covariance_has_the_documented_floor(anny32: BodyModel, prior: PosePrior) -> None:
    """Every parameter's variance is at least ``min_std²``, except the trunk's twist, which is
    held to about ``twist_std²``."""
    variance = np.diag(np.linalg.inv(prior.precision.numpy())).reshape(-1, 3)
    twist = [anny32.joint_index(n) - 1 for n in ("spine1", "spine2", "spine3", "neck")]
    for j in range(len(variance)):
        for a in range(3):
            if j in twist and a == 1:
                assert 0.1**2 <= variance[j, a] < 0.15**2
            else:
                assert variance[j, a] >= 0.25**2


def test_prior_scores_generated_a_poses_low_and_bent_limbs_high(
    anny32: BodyModel, prior: PosePrior
) -> None:
    poses = turnaround(anny32, 30, np.random.default_rng(123))  # not a training seed
    body = torch.as_tensor(poses[:, 1:].reshape(len(poses), -1))
    typical = gaussian_prior_energy(body, prior.mean, prior.precision)
    assert float(typical.max()) < 1.0  # well within the widened Gaussian
    odd = body.clone()
    odd[:, 3 * (anny32.joint_index("elbow_l") - 1)] += 1.5  # a forearm bent the wrong way
    odd[:, 3 * (anny32.joint_index("spine2") - 1) + 1] += 0.6  # a twisted trunk
    bent = gaussian_prior_energy(odd, prior.mean, prior.precision)
    assert bool((bent > 50 * typical.max()).all())


def test_prior_is_deterministic(anny32: BodyModel, prior: PosePrior) -> None:
    again = apose_prior(anny32)
    np.testing.assert_array_equal(again.mean.numpy(), prior.mean.numpy())
    np.testing.assert_array_equal(again.precision.numpy(), prior.precision.numpy())
    other = apose_prior(anny32, seed=1)
    assert not np.array_equal(other.mean.numpy(), prior.mean.numpy())
