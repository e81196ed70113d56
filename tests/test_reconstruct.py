"""End-to-end ``reconstruct`` on a tiny synthetic turn-around, and its failure modes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from monoavatar.cli import main
from monoavatar.fit.pose import PoseSettings
from monoavatar.fit.shape import ShapeSettings
from monoavatar.io.avatar_folder import AvatarFolder
from monoavatar.io.export_mesh import write_mp4
from monoavatar.perception import PerceptionSettings
from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
from monoavatar.pipelines.stages import InputSettings, PipelineError
from monoavatar.synth.scene import SynthConfig, generate
from monoavatar.texture.backproject import TextureSettings
from tests.io.gltf_reference import (
    Glb,
    rodrigues,
    skin_vertices,
    validate,
    validator_available,
)

pytestmark = pytest.mark.slow  # end-to-end: not in the fast tier

OUTPUTS = ("avatar.glb", "avatar.obj", "avatar.mtl", "texture.png", "params.npz", "report.json")


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("scene") / "turn"
    generate(folder, SynthConfig(kind="turnaround", frames=24, seed=5, width=256, height=256,
                                 texture_size=128, clothing="tight"), progress=False)  # fmt: skip
    return folder


def _fast_config(**kw: object) -> ReconstructConfig:
    return ReconstructConfig(
        input=InputSettings(frames=24), progress=False,
        pose=PoseSettings(iterations=12, init_iterations=20, silhouette_points=300,
                          boundary_points=80),
        shape=ShapeSettings(rounds=2, rays_per_frame=80),
        texture=TextureSettings(size=64, dilation=2), refine_rounds=1, flow_rounds=1,  # once each
        **kw,  # type: ignore[arg-type]
    )  # fmt: skip


@pytest.fixture(scope="module")
def tiny_result(tiny_scene: Path, tmp_path_factory: pytest.TempPathFactory,
                monkeypatch_module: pytest.MonkeyPatch):  # fmt: skip
    out = tmp_path_factory.mktemp("rec") / "avatar"
    return reconstruct(tiny_scene, out, _fast_config())


@pytest.fixture(scope="module")
def monkeypatch_module(tmp_path_factory: pytest.TempPathFactory):
    mp = pytest.MonkeyPatch()
    mp.setenv("MONOAVATAR_CACHE", str(tmp_path_factory.mktemp("cache")))
    yield mp
    mp.undo()


def test_outputs_complete(tiny_result) -> None:
    out = tiny_result.out_dir
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    assert (out / "preview" / "overlays.png").is_file()
    assert (out / "preview" / "turntable.png").is_file()
    assert not list(out.glob(".staging-*")) and not list(out.glob(".*.tmp"))
    report = json.loads((out / "report.json").read_text())
    assert set(report["timings"]) == {"perception", "poses", "shape", "refine", "texture", "flow",
                                      "export"}  # fmt: skip
    assert report["scale"]["known"] is False  # no --height
    assert len(report["fit"]["silhouette_iou"]) == 24
    assert report["input"]["kind"] == "synth"
    folder = AvatarFolder.load(out)  # the folder reads back as what the pipeline computed
    np.testing.assert_array_equal(folder.params.poses, tiny_result.track.poses)
    np.testing.assert_array_equal(folder.params.translations, tiny_result.track.translations)
    assert folder.report.to_json() == tiny_result.report.to_json()


def test_fit_is_plausible(tiny_result) -> None:
    iou = np.asarray(tiny_result.report.fit.silhouette_iou)
    assert np.median(iou) > 0.6


def test_params_pose_the_same_avatar_as_the_glb(tiny_result, anny32) -> None:
    """params.npz posed with the body model == the glb skinned in plain NumPy at the same
    pose (the glb keeps 4 influences: compare where that is exact, and overall)."""
    out = tiny_result.out_dir
    with np.load(out / "params.npz") as p:
        assert str(p["body_model"]) == anny32.identity
        shape, offsets, poses = p["shape"], p["offsets"], p["poses"]
        assert offsets.shape == (anny32.num_vertices, 3)
        assert poses.shape == (24, anny32.num_joints, 3)
    glb = Glb.load(out / "avatar.glb")
    pose = poses[3].copy()
    pose[0] = 0.0
    joints = glb.gltf.skins[0].joints
    posed_glb = skin_vertices(glb, {joints[j]: rodrigues(pose[j]) for j in range(len(joints))})
    rest_glb = glb.attribute("POSITION").astype(np.float64)
    with torch.no_grad():
        rest = anny32(shape=torch.as_tensor(shape, dtype=torch.float32)[None],
                      offsets=torch.as_tensor(offsets, dtype=torch.float32)).vertices[0]
    distance, source = cKDTree(rest.numpy()).query(rest_glb)  # glb vertices split at UV seams
    assert distance.max() < 1e-5
    with torch.no_grad():
        ours = anny32(shape=torch.as_tensor(shape, dtype=torch.float32)[None],
                      pose=torch.as_tensor(pose, dtype=torch.float32)[None],
                      offsets=torch.as_tensor(offsets, dtype=torch.float32)).vertices[0]
    diff = np.linalg.norm(posed_glb - ours.numpy()[source], axis=1)
    assert np.median(diff) < 1e-4
    assert np.percentile(diff, 99) < 5e-3


@pytest.mark.skipif(validator_available() is not None, reason=str(validator_available()))
def test_glb_validates(tiny_result) -> None:
    report = validate(tiny_result.out_dir / "avatar.glb")
    assert report["issues"]["numErrors"] == 0


def test_animate_cli(tiny_result, tmp_path: Path) -> None:
    target = tmp_path / "walk.glb"
    assert main(["animate", str(tiny_result.out_dir), "-o", str(target), "--frames", "8"]) == 0
    glb = Glb.load(target)
    assert len(glb.gltf.animations) == 1


def test_no_person_video_fails_cleanly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setenv("MONOAVATAR_CACHE", str(tmp_path / "cache"))
    video = tmp_path / "empty_room.mp4"
    write_mp4(video, [np.full((96, 96, 3), 128, np.uint8)] * 6, 10.0)
    out = tmp_path / "out"
    code = main(["reconstruct", str(video), "-o", str(out), "--frames", "6", "--quiet"])
    assert code == 2
    assert "person" in capsys.readouterr().err.lower()
    assert not out.exists()  # the folder the run made is gone again


def test_fit_shape_cli_from_a_poses_file(tiny_scene: Path, tiny_result, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    import trimesh

    poses = tmp_path / "poses.npz"
    tiny_result.track.save(poses)
    out = tmp_path / "shape"
    args = ["fit-shape", str(tiny_scene), "-o", str(out), "--frames", "24", "--poses",
            str(poses), "--refine-rounds", "0", "--quiet"]  # fmt: skip
    assert main(args) == 0
    assert "surface error against the ground truth" in capsys.readouterr().out
    data = np.load(out / "shape.npz")
    n = len(tiny_result.track.poses)
    assert data["offsets"].shape == data["vertices"].shape and data["poses"].shape[0] == n
    assert np.abs(data["offsets"]).max() > 1e-3  # offsets were fitted
    mesh = trimesh.load(out / "canonical.obj", process=False)
    np.testing.assert_allclose(mesh.vertices, data["vertices"], atol=1e-5)
    # poses of other key-frames are refused, and nothing is written
    other = tmp_path / "other"
    assert main([*args[:2], "-o", str(other), "--frames", "12", *args[6:]]) == 2
    assert "other frames" in capsys.readouterr().err
    assert not (other / "shape.npz").exists()


def test_fit_poses_cli(tiny_scene: Path, tmp_path: Path, monkeypatch_module,
                      capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    from monoavatar.fit.pose import PoseTrack

    out = tmp_path / "poses"
    assert main(["fit-poses", str(tiny_scene), "-o", str(out), "--frames", "8", "--quiet"]) == 0
    assert "8 frames" in capsys.readouterr().out
    track = PoseTrack.load(out / "poses.npz")
    assert track.poses.shape[0] == 8 and not track.scale_known
    assert np.median(track.silhouette_iou) > 0.6  # a person-shaped fit, not a failure
    assert main(["fit-poses", str(tiny_scene), "-o", str(out), "--height", "170"]) == 2
    assert "metres" in capsys.readouterr().err


def test_unwritable_output_fails_before_work(tiny_scene: Path, tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    with pytest.raises(PipelineError, match="cannot write"):
        reconstruct(tiny_scene, blocker / "out", _fast_config())


def test_bad_options_are_explained(tiny_scene: Path, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    assert main(["reconstruct", str(tiny_scene), "-o", str(tmp_path / "o"), "--height",
                 "175"]) == 2  # fmt: skip
    assert "metres" in capsys.readouterr().err
    assert main(["reconstruct", str(tmp_path / "missing.mp4"), "-o", str(tmp_path / "o")]) == 2
    assert "missing.mp4" in capsys.readouterr().err
    config = _fast_config()
    config.input.frames = 1
    with pytest.raises(PipelineError, match="at least 2"):
        reconstruct(tiny_scene, tmp_path / "o2", config)


def test_shifted_track_applies_the_shape_fits_corrections_to_its_frames(tiny_result) -> None:
    from dataclasses import replace

    from monoavatar.pipelines.stages import shifted_track

    track = tiny_result.track
    n = len(track.poses)
    failed = np.zeros(n, bool)
    failed[[1, 4]] = True  # the shape fit saw the other frames; its frames index those
    track = replace(track, failed=failed)
    shape = replace(tiny_result.shape, frames=np.array([0, 2, 3]),
                    frame_shifts=np.array([[0.01, 0, 0], [0, 0.02, 0], [0, 0, 0.03]]))
    moved = shifted_track(track, shape).translations - track.translations
    expected = np.zeros((n, 3))
    expected[[0, 3, 5]] = shape.frame_shifts  # good frames 0, 2, 3, 5, ... → 0, 3, 5
    np.testing.assert_allclose(moved, expected, atol=1e-12)


def test_no_grabcut_reaches_perception(tiny_scene: Path, tmp_path: Path,
                                       perception_spy: list[PerceptionSettings],
                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``--no-grabcut`` (and its default, on) arrives at :func:`perceive` as its settings."""
    seen = perception_spy
    base = ["reconstruct", str(tiny_scene), "-o", str(tmp_path / "out"), "--frames", "4",
            "--perception", "mediapipe", "--quiet"]  # fmt: skip
    assert main([*base, "--no-grabcut"]) == 2
    assert main(base) == 2
    assert "stopped by the test" in capsys.readouterr().err
    assert [s.grabcut for s in seen] == [False, True]
    assert seen[1] == PerceptionSettings()


def test_texture_option_reaches_the_config(tmp_path: Path) -> None:
    from monoavatar.cli import _config, build_parser

    parser = build_parser(only="reconstruct")
    args = parser.parse_args(["reconstruct", "video.mp4", "-o", str(tmp_path / "o"),
                              "--texture", "graphcut"])  # fmt: skip
    assert _config(args).texture.method == "graphcut"
    args = parser.parse_args(["reconstruct", "video.mp4", "-o", str(tmp_path / "o")])
    assert _config(args).texture.method == "median"
    with pytest.raises(SystemExit):
        parser.parse_args(["reconstruct", "video.mp4", "-o", "o", "--texture", "mean"])


def test_face_weight_option_reaches_the_config(tmp_path: Path) -> None:
    from monoavatar.cli import CliError, _config, build_parser

    parser = build_parser(only="reconstruct")
    base = ["reconstruct", "video.mp4", "-o", str(tmp_path / "o")]
    assert _config(parser.parse_args(base)).shape.w_face == 0.0  # off by default
    assert _config(parser.parse_args([*base, "--face-weight", "0.5"])).shape.w_face == 0.5
    with pytest.raises(CliError, match="w_face must be >= 0"):
        _config(parser.parse_args([*base, "--face-weight", "-1"]))


def test_large_video_is_reconstructed_at_max_side_with_its_focal_scaled(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    import monoavatar.perception as perception
    from monoavatar.core.errors import InputWarning
    from monoavatar.pipelines.stages import InputSettings, load_inputs
    from tests.io.media_helpers import write_video

    seen = {}

    class Stop(Exception):
        pass

    def fake_perceive(frames, camera, settings, **kw):  # type: ignore[no-untyped-def]
        seen["frames"], seen["camera"] = frames, camera
        raise Stop

    monkeypatch.setattr(perception, "perceive", fake_perceive)
    video = write_video(tmp_path / "big.mp4", n=4, width=640, height=360)
    with pytest.warns(InputWarning, match=r"640x360 are reconstructed at 256x144"), \
            pytest.raises(Stop):  # fmt: skip
        load_inputs(video, InputSettings(frames=4, focal=500.0, max_side=256))
    assert seen["frames"].images.shape[1:3] == (144, 256)
    assert seen["camera"].K[0, 0] == pytest.approx(500.0 * 256 / 640)
    with pytest.raises(Stop):
        load_inputs(video, InputSettings(frames=4, focal=500.0, max_side=None))
    assert seen["frames"].images.shape[1:3] == (360, 640)
    assert seen["camera"].K[0, 0] == pytest.approx(500.0)


def test_workers_option_reaches_every_threaded_stage(tmp_path: Path) -> None:
    from monoavatar.cli import _config, build_parser

    parser = build_parser(only="reconstruct")
    args = parser.parse_args(["reconstruct", "video.mp4", "-o", str(tmp_path / "o"),
                              "--workers", "3"])  # fmt: skip
    config = _config(args)
    assert (config.input.workers, config.shape.workers, config.texture.workers,
            config.flow.workers) == (3, 3, 3, 3)
