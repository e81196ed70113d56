"""``monoavatar track`` end to end on a small synthetic walk: the files, their keys, shapes and
units; the BVH re-read by an independent parser gives the motion's joints; the glb validates;
inputs that cannot be tracked exit with code 2 and leave nothing behind."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from monoavatar.cli import main
from monoavatar.io.export_mesh import write_mp4
from monoavatar.perception import PerceptionSettings
from monoavatar.synth.scene import SynthConfig, generate
from tests.io.gltf_reference import validate, validator_available
from tests.io.test_bvh import _fk, _parse

FRAMES = 12


@pytest.fixture(scope="module")
def walk(anny_local, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("track") / "walk"
    generate(out, SynthConfig(kind="walk", frames=FRAMES, seed=7, width=256, height=256,
                              texture_size=128, noise="none", posed_every=100),
             body=anny_local, progress=False)  # fmt: skip
    return out


@pytest.fixture(scope="module")
def tracked(walk: Path, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("track") / "out"
    height = json.loads((walk / "scene.json").read_text())["subjects"][0]["height_m"]
    assert main(["track", str(walk), "-o", str(out), "--quiet", "--height",
                 f"{height:.3f}"]) == 0  # fmt: skip
    return out


def test_track_writes_the_motion_with_documented_keys_and_units(walk: Path, tracked: Path
                                                                ) -> None:  # fmt: skip
    for name in ("motion.npz", "motion.bvh", "motion.glb", "preview/overlay.mp4", "report.json"):
        assert (tracked / name).is_file(), name
    with np.load(tracked / "motion.npz") as m:
        assert m["poses"].shape == (FRAMES, 20, 3) and m["translations"].shape == (FRAMES, 3)
        assert m["landmarks"].shape == m["landmarks_world"].shape == (FRAMES, 33, 3)
        np.testing.assert_array_equal(m["frames"], np.arange(FRAMES))
        assert m["failed"].dtype == bool and not m["failed"].any()
        landmarks = m["landmarks"]
        up = m["landmarks_world"]
    # camera frame, metres: the person is 3-6 m in front of the camera, and the landmarks lie
    # near the scene's true ones (a mean within 30 cm: a tracked body, up to its depth, not an
    # exact one; another frame or unit would be metres off)
    camera = json.loads((walk / "camera.json").read_text())
    truth = np.load(walk / "keypoints.npz")["keypoints_3d"] @ np.asarray(camera["R"]).T
    truth = truth + np.asarray(camera["t"])
    assert 3.0 < np.median(landmarks[..., 2]) < 6.0
    assert np.linalg.norm(landmarks - truth, axis=-1).mean() < 0.3
    # the upright world: the head above the ankles by about the person's height
    nose, ankles = up[:, 0, 1], up[:, [27, 28], 1].mean(axis=1)
    assert np.all(nose - ankles > 1.2)
    report = json.loads((tracked / "report.json").read_text())
    assert report["input"]["frames"] == FRAMES and report["frames_failed"] == 0
    assert set(report["ground_truth"]) >= {"local_mm", "global_mm", "acceleration_mm_per_frame2"}
    assert report["ground_truth"]["local_mm"] < 150.0
    assert report["landmarks_3d"] == "lifter" and "lift" in report["timings"]
    # a small person is warned about, a large one is not
    masks = [np.asarray(Image.open(f)) > 0 for f in sorted((walk / "masks").glob("*.png"))]
    tall = np.median([np.ptp(np.flatnonzero(m.any(axis=1))) + 1 for m in masks])
    assert any("px tall" in w for w in report["warnings"]) == (tall < 150), (tall, report)


def test_quality_warnings_name_small_people_and_many_failed_frames() -> None:
    from types import SimpleNamespace

    from monoavatar.pipelines.track import quality_warnings

    masks = np.zeros((10, 400, 100), bool)
    masks[:, 50:350, 40:60] = True  # 300 px tall
    failed = np.zeros(10, bool)
    motion = SimpleNamespace(failed=failed, reinitialised=failed.copy())
    obs = SimpleNamespace(masks=masks)
    assert quality_warnings(obs, motion) == []  # type: ignore[arg-type]
    masks[:, 200:] = False  # 150 px tall... and one frame failed: fine
    masks[:, 50:101] = False  # now 99 px
    failed[3] = True
    (small,) = quality_warnings(obs, motion)  # type: ignore[arg-type]
    assert "99 px tall" in small
    failed[:5] = True
    messages = quality_warnings(obs, motion)  # type: ignore[arg-type]
    assert any("5 of 10 frames failed" in m for m in messages)


def test_bvh_reread_independently_gives_the_motions_joints(tracked: Path) -> None:
    names, parents, offsets, channels, rows = _parse(tracked / "motion.bvh")
    assert len(names) == 20 and rows.shape[0] == FRAMES
    with np.load(tracked / "motion.npz") as m:
        joints = m["joints_world"]
    for frame in (0, FRAMES // 2, FRAMES - 1):
        positions = _fk(parents, offsets, channels, rows[frame]) / 100.0  # centimetres
        np.testing.assert_allclose(positions, joints[frame], atol=1e-3)


def test_motion_glb_validates(tracked: Path) -> None:
    reason = validator_available()
    if reason is not None:
        pytest.skip(reason)
    issues = validate(tracked / "motion.glb")["issues"]
    assert issues["numErrors"] == 0, issues["messages"]


def test_untrackable_inputs_exit_2_and_leave_nothing(walk: Path, tmp_path: Path, capsys) -> None:
    image = np.asarray(Image.open(walk / "frames" / "000000.png"))
    Image.fromarray(image).save(tmp_path / "still.png")
    one = tmp_path / "one"
    one.mkdir()
    Image.fromarray(image).save(one / "000000.png")
    empty = tmp_path / "empty.mp4"
    write_mp4(empty, [np.full((128, 128, 3), 90, np.uint8)] * 8, 30.0)
    for source, message in ((tmp_path / "still.png", "at least 2 frames"),
                            (one, "at least 2 frames"), (empty, "person"),
                            (tmp_path / "missing.mp4", "no such file")):  # fmt: skip
        out = tmp_path / f"out-{source.stem}"
        assert main(["track", str(source), "-o", str(out), "--quiet"]) == 2, source
        assert message in capsys.readouterr().err, source
        assert not out.exists(), source
    assert not [p for p in tmp_path.iterdir() if "staging" in p.name]
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "keep.txt").write_text("mine")
    assert main(["track", str(walk), "-o", str(busy), "--quiet"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert (busy / "keep.txt").read_text() == "mine"


def test_an_unknown_landmark_source_is_refused_before_any_work(walk: Path, tmp_path: Path
                                                               ) -> None:  # fmt: skip
    from monoavatar.pipelines.stages import PipelineError
    from monoavatar.pipelines.track import TrackConfig, track

    with pytest.raises(PipelineError, match="landmarks_3d must be one of"):
        track(walk, tmp_path / "out", TrackConfig(landmarks_3d="mediapipe", progress=False))
    assert not (tmp_path / "out").exists()


def test_grabcut_is_off_for_track_unless_asked(
    walk: Path, tmp_path: Path, perception_spy: list[PerceptionSettings],
    capsys: pytest.CaptureFixture[str]
) -> None:
    """track perceives without the GrabCut refinement by default and with it on --grabcut;
    the rest of its perception settings (flow, no face mesh) are kept either way."""
    seen = perception_spy
    base = ["track", str(walk), "-o", str(tmp_path / "out"), "--perception", "mediapipe",
            "--quiet"]  # fmt: skip
    assert main(base) == 2
    assert main([*base, "--grabcut"]) == 2
    assert "stopped by the test" in capsys.readouterr().err
    assert [s.grabcut for s in seen] == [False, True]
    assert all(s.flow == "dis" and not s.face for s in seen)
    assert not (tmp_path / "out").exists()


def test_a_frame_range_tracks_only_those_frames(walk: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "range"
    assert main(["track", str(walk), "-o", str(out), "--quiet", "--frames", "3:9"]) == 0
    with np.load(out / "motion.npz") as m:
        np.testing.assert_array_equal(m["frames"], np.arange(3, 9))
        assert m["poses"].shape[0] == 6
    for bad in ("9:3", "a:b", "-1:4", "5"):
        with pytest.raises(SystemExit) as exc:
            main(["track", str(walk), "-o", str(tmp_path / "x"), "--frames", bad])
        assert exc.value.code == 2, bad
    assert "A:B" in capsys.readouterr().err


def test_view_shows_the_tracked_motion_over_the_frames(tracked: Path, tmp_path: Path) -> None:
    from monoavatar.io.viewer_page import split_atlas, write_page
    from monoavatar.pipelines.view import viewer_page
    from tests.browser import show_page

    page = viewer_page(tracked)
    with np.load(tracked / "motion.npz") as m:
        frames, poses = m["frames"], m["poses"]
    fitted = page.data["clips"][0]
    assert fitted["name"] == "fitted" and len(fitted["times"]) == len(frames)
    assert page.data["keyframes"]["indices"] == frames.tolist()
    assert page.atlas is not None and len(split_atlas(page.atlas, len(frames))) == len(frames)
    assert (page.data["camera"]["width"], page.data["camera"]["height"]) == (256, 256)
    first = np.asarray(fitted["rotations"][next(iter(fitted["rotations"]))]).reshape(-1, 4)
    assert first.shape == (len(poses), 4)
    shot = show_page(write_page(tmp_path / "motion.html", page), "paused=1&t=0.2")
    # the overlay pane shows the frame (not the page's background) with the avatar on it
    assert np.abs(shot[100:, :450].astype(int) - (0x16, 0x18, 0x1B)).max(-1).mean() > 20
