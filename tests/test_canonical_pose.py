"""The canonical (rest-pose) avatar is in the rest pose: reconstructed with the true poses
and perception, each of its bones lies within a few degrees of the truth's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from monoavatar.bench.metrics import BodyCache, Rig, load_truth, surface_metrics
from monoavatar.io.avatar_folder import AvatarFolder
from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
from monoavatar.pipelines.stages import InputSettings
from monoavatar.synth.scene import SynthConfig, generate

pytestmark = pytest.mark.slow  # end-to-end: not in the fast tier


def test_true_poses_give_a_rest_pose_within_a_few_degrees_of_the_truths(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the wide, loosely dressed subject is in test_canonical_pose_wide.py: one reconstruction
    # per file, so that the two run side by side under ``--dist loadfile``
    check_rest_pose(tmp_path, monkeypatch, "tight", "standard")


def check_rest_pose(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, clothing: str,
                    variety: str) -> None:  # fmt: skip
    """Reconstruct a 30-frame turn-around of a ``clothing``/``variety`` subject with the true
    poses and perception, and check its rest-pose bones against the truth's."""
    monkeypatch.setenv("MONOAVATAR_CACHE", str(tmp_path / "cache"))
    scene = tmp_path / "scene"
    generate(scene, SynthConfig(kind="turnaround", frames=30, seed=11, width=384, height=384,
                                clothing=clothing, variety=variety), progress=False)  # fmt: skip
    truth_in = InputSettings(frames=30, perception="ground-truth", poses="ground-truth")
    config = ReconstructConfig(input=truth_in, progress=False)
    reconstruct(scene, tmp_path / "avatar", config)

    bodies = BodyCache()
    truth = load_truth(scene, bodies)
    avatar = AvatarFolder.load(tmp_path / "avatar")
    body = bodies.get(avatar.params.body_model)
    with torch.no_grad():
        shape = torch.as_tensor(avatar.params.shape, dtype=body.dtype).reshape(1, -1)
        rest_joints = body.rest_shape(shape)[1][0].double().numpy()
    rig = Rig(body.skin_weights.double().numpy(), rest_joints, tuple(body.parents))
    metrics, _ = surface_metrics(avatar.vertices, avatar.faces, truth.vertices, truth.faces,
                                 rig=rig)  # fmt: skip
    bones = metrics.bone_angles_deg
    assert bones is not None
    angles = np.asarray(bones)[np.isfinite(bones)]
    assert len(angles) >= 15
    assert np.median(angles) <= 3.0 and angles.max() <= 8.0, np.round(angles, 1)
