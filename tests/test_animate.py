"""animate: built-in motions, motions from params.npz, and the animated glb they give, re-skinned
independently at every keyframe and compared with ``BodyModel.forward``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from monoavatar.body import Avatar, BodyModel, BodyModelError, lbs
from monoavatar.cli import main
from monoavatar.core.errors import InputFormatError, InputNotFoundError
from monoavatar.io.gltf import dense_weights, limit_influences, split_uv_seams
from monoavatar.pipelines.animate import (
    MOTIONS,
    animate,
    animate_folder,
    load_motion,
    resolve_motion,
    walk_motion,
    wave_motion,
)
from tests.avatar_folders import make_params, make_report, write_params_and_report
from tests.io.gltf_reference import (
    Glb,
    animation_keyframe,
    skin_vertices,
    validate,
    validator_available,
)


@pytest.fixture(scope="module")
def avatar(anny64: BodyModel) -> Avatar:
    rng = np.random.default_rng(11)
    with torch.no_grad():
        rest = anny64.rest_shape(anny64.default_shape(1))[0][0].numpy()
    return Avatar(
        model=anny64.identity,
        shape=0.3 * rng.standard_normal(anny64.shape_dim),
        shape_names=anny64.shape_names,
        offsets=0.01 * np.sin(8.0 * rest[:, [2, 0, 1]]),
    )


def _check_keyframes(body: BodyModel, avatar: Avatar, path: Path, poses, translations) -> None:
    """Every keyframe of the glb, re-skinned in NumPy, equals forward (4-influence weights)."""
    glb = Glb.load(path)
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    out = body(t(avatar.shape)[None], t(poses), t(translations), t(avatar.offsets))
    joints, weights = limit_influences(body.skin_weights.double().numpy())
    dense = t(dense_weights(joints, weights, body.num_joints))
    want = lbs.skin(out.rest_vertices, dense, out.transforms).numpy()
    source_vertex, _, _ = split_uv_seams(body.faces.numpy(), body.face_uv.numpy())
    for k in range(len(poses)):
        posed = skin_vertices(glb, *animation_keyframe(glb, k))
        assert np.abs(posed - want[k, source_vertex]).max() < 1e-5, f"keyframe {k}"


@pytest.mark.parametrize("make", [walk_motion, wave_motion])
def test_builtin_motions(anny64: BodyModel, make) -> None:
    motion = make(anny64, 40, 20.0)
    assert motion.poses.shape == (40, anny64.num_joints, 3)
    assert motion.translations.shape == (40, 3)
    np.testing.assert_allclose(motion.times, np.arange(40) / 20.0)
    assert np.isfinite(motion.poses).all() and np.abs(motion.poses).max() < np.pi
    # a loop: the step from the last frame back to the first is like any other step
    steps = np.abs(np.diff(motion.poses, axis=0)).max()
    assert np.abs(motion.poses[0] - motion.poses[-1]).max() <= 1.5 * steps
    assert motion.name in MOTIONS


def test_walk_keeps_feet_on_the_floor(anny64: BodyModel) -> None:
    motion = walk_motion(anny64, 30, 30.0)
    out = anny64(
        pose=torch.as_tensor(motion.poses), translation=torch.as_tensor(motion.translations)
    )
    lowest = out.vertices[..., 1].amin(dim=1)
    np.testing.assert_allclose(lowest.numpy(), float(out.rest_vertices[0, :, 1].min()), atol=1e-9)
    right = anny64.joint_index("wrist_r")
    wave = wave_motion(anny64, 30, 30.0)
    top = anny64(pose=torch.as_tensor(wave.poses[15:16])).joints[0]
    assert top[right, 1] > top[anny64.joint_index("head"), 1]  # the waving hand is up high


def test_animate_walk_matches_forward(anny64: BodyModel, avatar: Avatar, tmp_path: Path) -> None:
    texture = np.full((16, 16, 3), 200, np.uint8)
    path = animate(
        anny64, avatar, "walk", tmp_path / "walk.glb", texture=texture, frames=12, fps=24.0
    )
    glb = Glb.load(path)
    anim = glb.gltf.animations[0]
    assert anim.name == "walk"
    times = glb.accessor(anim.samplers[0].input)
    np.testing.assert_allclose(times, np.arange(12) / 24.0, atol=1e-7)
    for sampler in anim.samplers:
        assert glb.gltf.accessors[sampler.output].count == 12
    motion = walk_motion(anny64, 12, 24.0)
    _check_keyframes(anny64, avatar, path, motion.poses, motion.translations)


def test_animate_with_poses_from_params(anny64: BodyModel, avatar: Avatar, tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    poses = 0.3 * rng.standard_normal((4, anny64.num_joints, 3))
    translations = np.array([[1.0, 0.2, 3.0]]) + 0.1 * rng.standard_normal((4, 3))
    np.savez(tmp_path / "params.npz", poses=poses, translations=translations, shape=np.zeros(6))
    motion = load_motion(tmp_path / "params.npz", fps=10.0)
    np.testing.assert_allclose(motion.translations, translations - translations[0])
    path = animate(anny64, avatar, tmp_path / "params.npz", tmp_path / "m.glb", fps=10.0)
    _check_keyframes(anny64, avatar, path, poses, translations - translations[0])


def _rot(axis_angle) -> np.ndarray:
    return lbs.axis_angle_to_matrix(torch.as_tensor(axis_angle, dtype=torch.float64)).numpy()


@pytest.mark.parametrize("key", ["world_up", "camera_R", "failed"])
def test_motion_from_a_camera_world_is_turned_upright(tmp_path: Path, key: str) -> None:
    # An upright motion (Y up), expressed in another world by a rotation G, as fitted poses of
    # a real video are (the camera's frame: y down). Loading it must undo G up to a turn
    # about the vertical (the heading is free), the same for every frame.
    rng = np.random.default_rng(5)
    n, joints = 6, 20
    poses = 0.3 * rng.standard_normal((n, joints, 3))
    translations = 0.2 * rng.standard_normal((n, 3))
    if key == "world_up":
        G = _rot([0.4, -0.2, 2.5])  # a generic world
        extra = {"world_up": G @ [0.0, 1.0, 0.0]}
    else:  # a camera at the world's origin looking along +z (OpenCV): world up is -y
        G = np.diag([1.0, -1.0, -1.0])
        extra = {"camera_R": np.eye(3)}
    if key == "failed":
        extra["failed"] = np.array([False, False, True, False, False, False])
    stored = poses.copy()
    for k in range(n):
        stored[k, 0] = lbs.matrix_to_axis_angle(torch.as_tensor(G @ _rot(poses[k, 0]))).numpy()
    np.savez(tmp_path / "poses.npz", poses=stored, translations=translations @ G.T, **extra)
    motion = load_motion(tmp_path / "poses.npz")
    keep = np.ones(n, bool) if key != "failed" else ~extra["failed"]
    assert len(motion.poses) == keep.sum()
    original, moved = poses[keep], translations[keep]
    np.testing.assert_allclose(motion.poses[:, 1:], original[:, 1:], atol=1e-12)
    turns = [_rot(motion.poses[k, 0]) @ _rot(original[k, 0]).T for k in range(keep.sum())]
    H = turns[0]
    np.testing.assert_allclose(H @ [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], atol=1e-9)  # upright
    for turn in turns:
        np.testing.assert_allclose(turn, H, atol=1e-9)
    np.testing.assert_allclose(motion.translations, (moved - moved[0]) @ H.T, atol=1e-12)


def test_animate_folder(anny64: BodyModel, avatar: Avatar, tmp_path: Path) -> None:
    folder = tmp_path / "out"
    params = make_params(anny64.identity, avatar.shape, avatar.offsets.astype(np.float32),
                         np.zeros((2, anny64.num_joints, 3)))  # fmt: skip
    write_params_and_report(folder, params, make_report(2))
    texture = np.random.default_rng(0).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    Image.fromarray(texture).save(folder / "texture.png")
    # body None: the shipped model named in params.npz is loaded
    path = animate_folder(folder, "wave", tmp_path / "wave.glb", frames=8)
    glb = Glb.load(path)
    assert glb.gltf.animations[0].name == "wave"
    assert glb.gltf.accessors[glb.gltf.animations[0].samplers[0].input].count == 8
    assert len(glb.gltf.images) == 1
    motion = wave_motion(anny64, 8, 30.0)
    with_offsets = Avatar(
        avatar.model,
        avatar.shape,
        avatar.shape_names,
        avatar.offsets.astype(np.float32).astype(np.float64),
    )
    _check_keyframes(anny64, with_offsets, path, motion.poses, motion.translations)


def test_errors(anny64: BodyModel, avatar: Avatar, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="dance: unknown motion"):
        resolve_motion(anny64, "dance")
    with pytest.raises(InputNotFoundError):
        animate(anny64, avatar, tmp_path / "missing.npz", tmp_path / "x.glb")
    np.savez(tmp_path / "few.npz", poses=np.zeros((3, 5, 3)))
    with pytest.raises(InputFormatError, match="5 joints"):
        animate(anny64, avatar, tmp_path / "few.npz", tmp_path / "x.glb")
    with pytest.raises(ValueError, match="2 to 36000 frames"):
        walk_motion(anny64, 1)
    other = Avatar("smpl:neutral", avatar.shape, avatar.shape_names, avatar.offsets)
    with pytest.raises(BodyModelError, match="smpl:neutral"):
        animate(anny64, other, "walk", tmp_path / "x.glb")
    with pytest.raises(InputNotFoundError, match="params.npz"):
        animate_folder(tmp_path, "walk", tmp_path / "x.glb")
    # an older folder (no format key) is refused with a message that says so
    np.savez(tmp_path / "params.npz", body_model=np.array(anny64.identity), shape=avatar.shape,
             offsets=avatar.offsets)  # fmt: skip
    with pytest.raises(InputFormatError, match="older monoavatar"):
        animate_folder(tmp_path, "walk", tmp_path / "x.glb")
    smpl = make_params("smpl:neutral", np.zeros(10), np.zeros((6890, 3)), np.zeros((1, 24, 3)))
    write_params_and_report(tmp_path, smpl, make_report(1))
    with pytest.raises(BodyModelError, match="pass the body model"):
        animate_folder(tmp_path, "walk", tmp_path / "x.glb")
    assert not (tmp_path / "x.glb").exists()


def test_animated_glb_validates(anny64: BodyModel, avatar: Avatar, tmp_path: Path) -> None:
    reason = validator_available()
    if reason is not None:
        pytest.skip(reason)
    path = animate(
        anny64, avatar, "wave", tmp_path / "wave.glb", frames=10, texture=np.zeros((8, 8, 3))
    )
    issues = validate(path)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


def test_outputs_that_would_destroy_or_mislead_are_refused(anny64: BodyModel, avatar: Avatar,
                                                           tmp_path: Path, capsys) -> None:
    """``animate -o`` must be a new .glb outside the avatar's own files (``--force`` replaces
    an existing one); a motion of absurd length is refused before any work."""
    folder = tmp_path / "out"
    params = make_params(anny64.identity, avatar.shape, avatar.offsets.astype(np.float32),
                         np.zeros((2, anny64.num_joints, 3)))  # fmt: skip
    write_params_and_report(folder, params, make_report(2))
    before = (folder / "params.npz").read_bytes()
    for target, message in ((folder / "params.npz", ".glb"), (folder / "avatar.glb", "own file"),
                            (tmp_path / "walk.txt", ".glb")):  # fmt: skip
        assert main(["animate", str(folder), "-o", str(target), "--frames", "4"]) == 2
        assert message in capsys.readouterr().err
    assert (folder / "params.npz").read_bytes() == before
    assert main(["animate", str(folder), "-o", str(tmp_path / "w.glb"), "--frames",
                 "10000000"]) == 2  # fmt: skip
    assert "2 to 36000 frames" in capsys.readouterr().err
    existing = tmp_path / "walk.glb"
    existing.write_bytes(b"mine")
    assert main(["animate", str(folder), "-o", str(existing), "--frames", "4"]) == 2
    assert "exists already" in capsys.readouterr().err and existing.read_bytes() == b"mine"
    assert main(["animate", str(folder), "-o", str(existing), "--frames", "4", "--force"]) == 0
    assert Glb.load(existing).gltf.animations
