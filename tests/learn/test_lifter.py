"""The landmark lifter: its frames against closed forms, its inputs round-tripped through
pixels, its training deterministic and resumable, and the shipped weights on fresh motions."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from monoavatar.body import load_body_model
from monoavatar.body.motion import LIMB_RANGES, limb_motion
from monoavatar.core.geometry import ray_rotations
from monoavatar.learn.lifter import (
    LifterError,
    LifterNetwork,
    LifterSettings,
    hip_ray_coordinates,
    hip_ray_targets,
    lift_landmarks,
    load_lifter,
    normalise_windows,
    window_indices,
)
from monoavatar.learn.lifter_train import (
    LIMBS,
    LifterTrainConfig,
    lifter_batch,
    sequence_landmarks,
    train_lifter,
)
from monoavatar.learn.weights import load_weights, module_tensors, save_weights


def _person(seed: int = 0, depth: float = 4.0) -> torch.Tensor:
    """(33, 3) landmark-like points about a hip midpoint on the optical axis at ``depth``."""
    g = torch.Generator().manual_seed(seed)
    pts = 0.4 * torch.randn(33, 3, generator=g, dtype=torch.float64)
    pts[23], pts[24] = torch.tensor([0.1, 0.0, 0.0]), torch.tensor([-0.1, 0.0, 0.0])
    return pts + torch.tensor([0.0, 0.0, depth], dtype=torch.float64)


def test_ray_rotations_take_the_axis_to_each_direction_orthonormally() -> None:
    d = torch.randn(50, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    d[0] = torch.tensor([0.0, 0.0, -2.0])  # backwards: a half turn
    R = ray_rotations(d)
    unit = d / d.norm(dim=-1, keepdim=True)
    assert torch.allclose(R[..., :, 2], unit, atol=1e-12)  # R (0, 0, 1) = d / |d|
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(50, dtype=torch.float64))
    # the smallest rotation: its axis is perpendicular to both the optical axis and d
    k = torch.stack([R[1:, 2, 1] - R[1:, 1, 2], R[1:, 0, 2] - R[1:, 2, 0],
                     R[1:, 1, 0] - R[1:, 0, 1]], -1)  # fmt: skip
    assert torch.allclose(k[:, 2], torch.zeros(49, dtype=torch.float64), atol=1e-12)


def test_a_person_off_the_axis_is_seen_as_on_it() -> None:
    """Turning the whole person about the camera's centre (as if they stood elsewhere in the
    image) by the ray rotation of their hips changes neither the input nor the target."""
    pts = _person()
    turn = ray_rotations(torch.tensor([0.5, -0.3, 1.0], dtype=torch.float64))
    moved = pts @ turn.T
    assert torch.allclose(hip_ray_coordinates(moved), hip_ray_coordinates(pts), atol=1e-12)
    assert torch.allclose(hip_ray_targets(moved), hip_ray_targets(pts), atol=1e-12)
    # on the axis the frame is the camera's: pinhole coordinates about the hips, and the points
    # about the hips
    planar = pts[:, :2] / pts[:, 2:]
    assert torch.allclose(hip_ray_coordinates(pts), planar - 0.5 * (planar[23] + planar[24]),
                          atol=1e-12)  # fmt: skip
    assert torch.allclose(hip_ray_targets(pts), pts - 0.5 * (pts[23] + pts[24]), atol=1e-12)


def test_targets_map_back_to_the_camera_frame() -> None:
    pts = _person(3) + torch.tensor([1.2, -0.4, 0.0], dtype=torch.float64)
    hips = 0.5 * (pts[23] + pts[24])
    unit = pts / pts.norm(dim=-1, keepdim=True)
    turn = ray_rotations(0.5 * (unit[23] + unit[24]))  # the ray bisecting the hips' rays
    assert torch.allclose(hip_ray_targets(pts) @ turn.T + hips, pts, atol=1e-12)


def test_window_indices_clamp_and_skip_frames_without_a_person() -> None:
    valid = np.array([True, True, False, True, True])
    idx = window_indices(valid, 3)
    assert idx.tolist() == [[0, 0, 1], [0, 1, 1], [1, 2, 3], [3, 3, 4], [3, 4, 4]]


def test_normalised_windows_are_independent_of_the_person_s_size_in_the_image() -> None:
    planar = hip_ray_coordinates(torch.stack([_person(s) for s in range(5)]))[None]
    a = normalise_windows(planar)
    assert a.shape == (1, 5 * 66)
    assert torch.allclose(normalise_windows(3.0 * planar), a, atol=1e-12)
    centre = a.reshape(5, 33, 2)[2]
    assert float(centre.pow(2).sum(-1).mean()) == pytest.approx(1.0)


def _tiny_net(seed: int = 0) -> LifterNetwork:
    torch.manual_seed(seed)
    return LifterNetwork(LifterSettings(window=3, width=16, blocks=1))


def test_lifting_reads_pixels_as_the_training_reads_points(tmp_path: Path) -> None:
    """lift_landmarks from projected pixels gives what the network gives on the training
    input made from the same camera-frame points; NaN rows where no person."""
    seq = torch.stack([_person(s) + torch.tensor([0.3 * s, 0.1, 0.0], dtype=torch.float64)
                       for s in range(4)])  # fmt: skip
    K = np.array([[800.0, 0, 320], [0, 820.0, 250], [0, 0, 1]])
    px = seq.numpy() @ K.T
    px = px[..., :2] / px[..., 2:]
    keypoints = np.concatenate([px, np.full((4, 33, 1), 0.8)], -1)
    present = np.array([True, True, True, False])
    net = _tiny_net()
    out = lift_landmarks(net, keypoints, K, present, 1.7)
    assert out.shape == (4, 33, 4) and out.dtype == np.float32
    assert np.isnan(out[3]).all() and np.isfinite(out[:3]).all()
    assert np.allclose(out[:3, :, 3], 0.8)
    planar = hip_ray_coordinates(seq)
    idx = torch.as_tensor(window_indices(present, 3))
    with torch.no_grad():
        expected = net(normalise_windows(planar[idx]).float()).numpy() * 1.7
    assert np.allclose(out[:3, :, :3], expected[:3], atol=1e-4)
    with pytest.raises(LifterError, match="shape"):
        lift_landmarks(net, keypoints[:, :20], K, present, 1.7)


def test_weights_load_back_and_are_checked(tmp_path: Path) -> None:
    net = _tiny_net(4)
    path = tmp_path / "l.safetensors"
    save_weights(path, module_tensors(net, "network."),
                 {"content": "lifter"} | net.settings.metadata())  # fmt: skip
    loaded = load_lifter(path)
    x = torch.randn(2, 3 * 66)
    assert loaded.settings == net.settings
    assert torch.equal(loaded(x), net.eval()(x))
    save_weights(tmp_path / "other.safetensors", module_tensors(net, "network."),
                 {"content": "fast-network"} | net.settings.metadata())  # fmt: skip
    with pytest.raises(LifterError, match="not a lifter"):
        load_lifter(tmp_path / "other.safetensors")
    with pytest.raises(LifterError, match="train lifter"):
        load_lifter(tmp_path / "none.safetensors")
    with pytest.raises(LifterError, match="odd"):
        LifterNetwork(LifterSettings(window=4))


def test_limb_motion_stays_inside_its_ranges() -> None:
    body = load_body_model("anny")
    poses, transl = limb_motion(body, 90, np.random.default_rng(5))
    assert poses.shape == (90, body.num_joints, 3) and transl.shape == (90, 3)
    for joint, axis, lo, hi in LIMB_RANGES:
        angle = poses[:, body.joint_index(joint), axis]
        assert lo - 1e-12 <= angle.min() and angle.max() <= hi + 1e-12, joint
    assert np.ptp(poses[:, body.joint_index("knee_l"), 0]) > 0.0  # it moves


def _config(**changes: object) -> LifterTrainConfig:
    base = LifterTrainConfig(sequences=3, val=2, frames=12, steps=4, batch=8,
                             checkpoint_every=2, validate_every=2, progress=False,
                             network=LifterSettings(window=3, width=16, blocks=1))  # fmt: skip
    return replace(base, **changes)  # type: ignore[arg-type]


def test_a_batch_without_augmentation_is_the_truth_in_the_hip_ray_frame() -> None:
    body = load_body_model("anny")
    points, height = sequence_landmarks(body, 12, np.random.default_rng(0))
    assert points.shape == (12, 33, 3) and (points[..., 2] > 0.3).all()
    assert 1.2 < height < 2.4
    pts, heights = torch.as_tensor(points)[None], torch.tensor([height])
    config = _config(noise=(0.0, 0.0), swap=0.0)
    x, y = lifter_batch(pts, heights, np.array([0, 0]), np.array([0, 5]), config,
                        np.random.default_rng(1))  # fmt: skip
    planar = hip_ray_coordinates(pts[0].double())
    assert torch.allclose(x[1], normalise_windows(planar[4:7][None])[0].float(), atol=1e-5)
    assert torch.allclose(x[0], normalise_windows(planar[[0, 0, 1]][None])[0].float(),
                          atol=1e-5)  # fmt: skip
    assert torch.allclose(y[1] * height, hip_ray_targets(pts[0, 5].double()).float(), atol=1e-5)
    # every frame swapped: one of the pairs exchanged in each
    xs, _ = lifter_batch(pts, heights, np.array([0]), np.array([5]), _config(noise=(0.0, 0.0),
                         swap=1.0), np.random.default_rng(2))  # fmt: skip
    frames = xs.reshape(3, 33, 2)
    clean = x[1].reshape(3, 33, 2)
    assert all(int((frames[f] != clean[f]).any(-1).sum()) == 2 for f in range(3))


@pytest.mark.slow
def test_lifter_training_is_deterministic_and_resumes_bit_for_bit(tmp_path: Path) -> None:
    whole = train_lifter(tmp_path / "a", _config())
    assert whole.finished and whole.steps_done == 4
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "data").symlink_to(tmp_path / "a" / "data")
    first = train_lifter(tmp_path / "b", _config(max_minutes=0.0))
    assert not first.finished and first.steps_done == 1
    second = train_lifter(tmp_path / "b", _config())
    a, meta = load_weights(whole.weights)
    b, _ = load_weights(second.weights)
    assert second.finished and a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key
    assert meta["content"] == "lifter"
    assert set(whole.validation) == {"val_mm", "val_limbs_mm"}
    assert (tmp_path / "a" / "curve.png").is_file()
    with pytest.raises(ValueError, match="other training settings"):
        train_lifter(tmp_path / "a", _config(lr=0.5))


def test_shipped_lifter_beats_a_mean_pose_on_fresh_motions() -> None:
    """On sequences of seeds the training never drew, the shipped lifter's limb landmarks
    (about the hips) are far closer to the truth than the best constant pose (the mean of
    the truth itself), and within 8 cm on average."""
    body = load_body_model("anny-local")
    net = load_lifter()
    errors, baseline = [], []
    for seed in (9001, 9002, 9003):
        points, height = sequence_landmarks(body, 60, np.random.default_rng([seed, 0]))
        K = np.array([[900.0, 0, 270], [0, 900.0, 270], [0, 0, 1]])
        px = points.astype(np.float64) @ K.T
        keypoints = np.concatenate([px[..., :2] / px[..., 2:], np.ones((60, 33, 1))], -1)
        keypoints[..., :2] += np.random.default_rng(seed).normal(0, 1.5, (60, 33, 2))
        lifted = lift_landmarks(net, keypoints, K, np.ones(60, bool), height)[..., :3]
        truth = hip_ray_targets(torch.as_tensor(points, dtype=torch.float64)).numpy()
        errors.append(np.linalg.norm(lifted - truth, axis=-1)[:, list(LIMBS)].mean())
        mean_pose = truth.mean(axis=0, keepdims=True)
        baseline.append(np.linalg.norm(mean_pose - truth, axis=-1)[:, list(LIMBS)].mean())
    assert np.mean(errors) < 0.08
    assert np.mean(errors) < 0.65 * np.mean(baseline)


@pytest.mark.slow
def test_train_lifter_command_writes_weights_that_track_loads(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from monoavatar.cli import main

    out = tmp_path / "t"
    assert main(["train", "lifter", "-o", str(out), "--sequences", "2", "--val", "1",
                 "--steps", "3", "--batch", "4", "--quiet"]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    assert "finished after 3 steps" in printed and "val_limbs_mm" in printed
    net = load_lifter(out / "lifter.safetensors")
    assert net.settings == LifterSettings()
    with np.load(out / "data" / "train.npz") as data:
        assert data["points"].shape == (2, 120, 33, 3)
