"""The single-mode A-pose prior of Sec. B.3.2, learned from the rough A-poses of the
turn-around motion generator (:func:`monoavatar.body.motion.turnaround`, the one
``monoavatar synth turnaround`` uses; the dissertation learns it from SMPL poses fitted to scans
of people in A-pose).

The generator's pose variation is small (a few degrees), so a Gaussian fitted to it alone would
forbid the poses of real people; the covariance is widened by a floor (``min_std``) that stands
for the spread of real A-poses. It is computed from fixed seeds: deterministic, no stored data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel
from monoavatar.body.motion import turnaround


@dataclass(frozen=True)
class PosePrior:
    """Gaussian over the body joints' axis-angle parameters (the root excluded).

    Attributes:
        mean: (3 (J − 1),) radians.
        precision: (3 (J − 1), 3 (J − 1)) inverse covariance.
    """

    mean: Tensor
    precision: Tensor

    def to(self, dtype: torch.dtype) -> PosePrior:
        return PosePrior(self.mean.to(dtype), self.precision.to(dtype))


def apose_prior(
    body: BodyModel,
    sequences: int = 64,
    frames: int = 60,
    min_std: float = 0.25,
    twist_std: float = 0.1,
    seed: int = 0,
) -> PosePrior:
    """Learn the A-pose prior from ``sequences`` synthetic turn-arounds of the body's skeleton.

    Args:
        body: gives the skeleton (joint names) the synthetic poses use.
        sequences, frames: how many turn-around sequences and frames each to sample.
        min_std: radians added in quadrature to every joint parameter's standard deviation.
        twist_std: the same for the twist of the spine and neck about the vertical: people
            standing in an A-pose hardly twist their trunk, and a free twist lets the trunk
            hide an error of the body's heading (the tracker then drifts).
    """
    rng = np.random.default_rng(seed)
    poses = np.concatenate([turnaround(body, frames, rng) for _ in range(sequences)])
    body_params = poses[:, 1:].reshape(len(poses), -1)
    mean = body_params.mean(axis=0)
    floor = np.full((body.num_joints - 1, 3), min_std)
    for name in ("spine1", "spine2", "spine3", "neck"):
        if name in body.joint_names:
            floor[body.joint_index(name) - 1, 1] = twist_std
    cov = np.cov(body_params, rowvar=False) + np.diag(floor.reshape(-1) ** 2)
    return PosePrior(torch.from_numpy(mean), torch.from_numpy(np.linalg.inv(cov)))
