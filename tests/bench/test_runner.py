"""run_bench end to end on a tiny suite with a fake reconstruction."""

import contextlib
import io
import json
import shutil
from dataclasses import replace

import pytest

from monoavatar.bench import runner
from monoavatar.bench.suite import SUITE_VERSION, BenchSuite, SuiteError

from .fake import FakeReconstruct


@pytest.fixture
def tiny_suite(tiny_scene, monkeypatch):
    """The tiny scene's subject as the whole suite: (subject, scenes folder, scene folder)."""
    subject = tiny_scene[0]
    tiny = BenchSuite(SUITE_VERSION, "tiny", (subject,))
    monkeypatch.setattr(runner, "get_suite", lambda *args, **kw: tiny)
    return tiny_scene


@pytest.fixture(scope="module")
def fake_bench(tiny_scene, anny32, anny_local, tmp_path_factory):
    """One fake benchmark run shared by the tests below: (fake, out folder, results, what it
    printed). The fine avatar; the ground-truth-poses run fails."""
    subject = tiny_scene[0]
    tiny = BenchSuite(SUITE_VERSION, "tiny", (subject,))
    fake = FakeReconstruct(anny32, anny_local, avatar="fine", fail_modes=("ground-truth",))
    out = tmp_path_factory.mktemp("fake-bench") / "bench"
    printed = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(printed):
        mp.setattr(runner, "get_suite", lambda *args, **kw: tiny)
        results = runner.run_bench(out, reconstruct=fake, scenes_dir=tiny_scene[1],
                                   progress=True, track_rounds=0)  # fmt: skip
    return fake, out, results, printed.getvalue()


@pytest.mark.slow
def test_run_bench_with_fake_reconstruction(tiny_scene, fake_bench):
    subject, _, scene_folder = tiny_scene
    fake, out, results, printed = fake_bench

    # every mode was asked for, with the subject's key-frames and a private cache
    assert len(fake.calls) == 3
    (scene_in, run_dir, config), (_, _, config_base), (_, _, config_gt) = fake.calls
    assert scene_in == scene_folder and run_dir == out / "runs" / subject.name / "estimated"
    assert (config.input.frames, config.input.perception,
            config.input.poses) == (subject.keyframes, "mediapipe", "fit")  # fmt: skip
    assert config.shape.fit_offsets and not config_base.shape.fit_offsets
    assert (config_base.input.perception, config_base.input.poses) == ("mediapipe", "fit")
    assert (config_gt.input.perception, config_gt.input.poses) == ("ground-truth", "ground-truth")
    assert config.texture.size == subject.texture_size and config.pose.height is None

    failed = results.run(subject.name, "gt-poses")
    assert failed is not None and failed.status == "failed" and "fake failure" in failed.error

    # The fake wrote the true clothed mesh as avatar.obj, the true pose of each key-frame and
    # the true albedo: zero surface error, a body-only error of the clothing's size, high IoU.
    ok = results.run(subject.name, "estimated")
    assert ok is not None and ok.status == "ok" and ok.metrics is not None
    m = ok.metrics
    assert m.surface.mean_mm < 1e-6 and m.surface.std_mm < 1e-6
    assert m.surface.scale == pytest.approx(1.0, abs=1e-9)
    assert m.body_only_mm is not None and 2.0 < m.body_only_mm < 20.0  # t-shirt and shorts
    # the shape-only run (the fake writes the same mesh) fills the estimated run's baseline
    assert m.shape_only_mm is not None and m.shape_only_mm < 1e-6
    assert m.pa_mpjpe_mm < 30.0  # skeletons of Anny with and without local changes differ
    assert m.silhouette_iou > 0.85 and m.silhouette_iou_min <= m.silhouette_iou
    assert m.texture_lighting == "estimated"  # albedo with the fake's (true) lighting_sh
    assert m.heldout_frames == subject.frames - subject.keyframes
    assert m.psnr_db is not None and m.psnr_db > 18.0
    assert m.psnr_overlap_db is not None and m.psnr_overlap_db >= m.psnr_db
    # no flow rounds: the tracked poses are the interpolated ones; the true poses transferred
    # onto the fake's skeleton (Anny without local changes) read lower
    assert m.psnr_interpolated_db == pytest.approx(m.psnr_db)
    assert m.psnr_true_poses_db is not None and m.psnr_true_poses_db > 18.0
    # missed person pixels: the two PSNRs' MSE ratio is (1 - error share) / (1 - pixel share)
    frac, share = m.missed_fraction, m.missed_error_share
    assert frac is not None and share is not None and 0.0 < frac < 0.2 and frac < share < 1.0
    ratio = 10.0 ** ((m.psnr_db - m.psnr_overlap_db) / 10.0)
    assert ratio == pytest.approx((1.0 - share) / (1.0 - frac), rel=1e-6)
    assert m.keyframes == subject.keyframes
    assert m.timings["shape"] == 2.5 and m.peak_memory_mb == 321.0
    assert m.warnings == ["UserWarning: fake"]
    assert ok.wall_seconds > 0 and ok.peak_rss_mb is not None and ok.peak_rss_mb > 0

    for name in ("results.json", "results.md"):
        assert (out / name).is_file()
    assert ok.heatmap_png is not None and ok.heatmap_png.is_file()
    assert ok.heatmap_ply is not None and ok.heatmap_ply.is_file()
    data = json.loads((out / "results.json").read_text())
    assert data["suite"]["version"] == SUITE_VERSION
    run = data["subjects"][0]["runs"]["estimated"]
    assert run["heatmap_png"] == f"heatmaps/{subject.name}-estimated.png"
    assert run["metrics"]["texture_psnr_db"] == pytest.approx(m.psnr_db)
    assert data["aggregate"]["estimated"]["all"]["surface_error_mm"] < 1e-6
    assert data["aggregate"]["gt-poses"]["all"]["failed"] == 1
    assert not (out / ".cache").exists()
    assert "5.37 (BUFF)" in printed and printed.strip() == results.table.strip()


def test_unknown_subject_is_refused_before_any_work(tmp_path):
    def never(*args):
        raise AssertionError("reconstruct must not run")

    with pytest.raises(SuiteError, match="nobody"):
        runner.run_bench(tmp_path, subjects=["nobody"], reconstruct=never, progress=False)


@pytest.mark.slow
def test_measure_only_remeasures_earlier_runs_without_reconstructing(tiny_suite, fake_bench,
                                                                     tmp_path):
    subject, scenes, _ = tiny_suite
    _, first_out, first, _ = fake_bench
    out = tmp_path / "bench"
    shutil.copytree(first_out, out)

    def never(*args):
        raise AssertionError("reconstruct must not run")

    # a run folder that is gone becomes a failed run, not a crash
    shutil.rmtree(out / "runs" / subject.name / "shape-only")
    again = runner.run_bench(out, reconstruct=never, scenes_dir=scenes, progress=False,
                             gt_poses=False, measure_only=True, track_rounds=0)  # fmt: skip
    a, b = first.run(subject.name, "estimated"), again.run(subject.name, "estimated")
    assert a is not None and b is not None and b.status == "ok" and b.metrics is not None
    assert a.metrics is not None
    assert b.metrics.surface.mean_mm == pytest.approx(a.metrics.surface.mean_mm, abs=1e-9)
    assert b.metrics.psnr_db == pytest.approx(a.metrics.psnr_db)
    assert b.metrics.silhouette_iou == pytest.approx(a.metrics.silhouette_iou)
    assert b.wall_seconds == pytest.approx(12.5)  # the fake's report.json "seconds"
    gone = again.run(subject.name, "shape-only")
    assert gone is not None and gone.status == "failed"
    assert "no such avatar folder" in (gone.error or "")
    assert again.run(subject.name, "gt-poses") is None  # not asked for this time


def test_track_rounds_reach_the_bench_from_the_cli(tmp_path, monkeypatch, capsys):
    """``--track-rounds`` defaults to the metrics' rounds, is passed on, and must not be
    negative."""
    from monoavatar.bench.heldout import HELDOUT_TRACK_ROUNDS
    from monoavatar.cli import main

    calls = []
    monkeypatch.setattr(runner, "run_bench", lambda out, **kw: calls.append(kw))
    assert main(["bench", "-o", str(tmp_path), "--quiet"]) == 0
    assert main(["bench", "-o", str(tmp_path), "--quiet", "--track-rounds", "0"]) == 0
    assert main(["bench", "-o", str(tmp_path), "--quiet", "--address", "local"]) == 0
    assert [c["track_rounds"] for c in calls] == [HELDOUT_TRACK_ROUNDS, 0, HELDOUT_TRACK_ROUNDS]
    assert [c["address"] for c in calls] == [None, None, "local"]
    assert main(["bench", "-o", str(tmp_path), "--track-rounds", "-1"]) == 2
    assert "--track-rounds must be >= 0" in capsys.readouterr().err
    assert main(["bench", "-o", str(tmp_path), "--photo", "--address", "local"]) == 2
    assert "--address runs the reconstruction suite" in capsys.readouterr().err
    assert len(calls) == 3


@pytest.mark.slow
def test_runs_as_ray_tasks_on_a_local_cluster(tiny_suite, anny32, anny_local, tmp_path):
    """``address="local"``: a real local Ray cluster (started and stopped by the benchmark)
    runs the scene and the three runs as tasks in its own worker processes; the results come
    back in the suite's order with the baseline column filled, as one process would write
    them, and a failing run is recorded, not raised."""
    pytest.importorskip("ray")
    subject, scenes, _ = tiny_suite
    fake = FakeReconstruct(anny32, anny_local, avatar="fine", fail_modes=("ground-truth",))
    out = tmp_path / "bench"
    results = runner.run_bench(out, reconstruct=fake, scenes_dir=scenes, progress=False,
                               track_rounds=0, workers=1, address="local")  # fmt: skip
    assert fake.calls == []  # the fake was called in the workers, on copies of it
    assert [r.mode for r in results.runs] == ["estimated", "shape-only", "gt-poses"]
    ok, gt = results.run(subject.name, "estimated"), results.run(subject.name, "gt-poses")
    assert ok is not None and ok.status == "ok" and ok.metrics is not None
    assert ok.metrics.surface.mean_mm < 1e-6 and ok.metrics.shape_only_mm is not None
    assert ok.peak_rss_mb is not None and ok.peak_rss_mb > 0
    assert gt is not None and gt.status == "failed" and "fake failure" in (gt.error or "")
    assert ok.heatmap_png is not None and ok.heatmap_png.is_file()
    data = json.loads((out / "results.json").read_text())
    assert data["aggregate"]["estimated"]["all"]["surface_error_mm"] < 1e-6
    assert data["aggregate"]["gt-poses"]["all"]["failed"] == 1
    assert not (out / ".cache").exists()
    import ray

    assert not ray.is_initialized()  # stopped again


def test_photo_split_reaches_the_photo_bench(tmp_path, monkeypatch, capsys):
    """``--split`` picks the photo bench's photos (sealed test by default) and is refused
    without ``--photo``."""
    from monoavatar.bench import photo as photo_bench
    from monoavatar.cli import main

    real = photo_bench.run_photo_bench
    calls = []
    monkeypatch.setattr(photo_bench, "run_photo_bench",
                        lambda out, **kw: calls.append(kw) or {"photos": []})  # fmt: skip
    assert main(["bench", "-o", str(tmp_path), "--photo", "--quiet"]) == 0
    assert main(["bench", "-o", str(tmp_path), "--photo", "--quiet", "--split", "dev"]) == 0
    assert [c["split"] for c in calls] == ["test", "dev"]
    assert main(["bench", "-o", str(tmp_path), "--split", "dev"]) == 2
    assert "--split dev goes with --photo or --suite v2" in capsys.readouterr().err
    assert len(calls) == 2
    with pytest.raises(ValueError, match="unknown split"):
        real(tmp_path, split="train", photos=1, progress=False)


def test_suite_v2_and_its_split_reach_the_bench_from_the_cli(tmp_path, monkeypatch, capsys):
    from monoavatar.cli import main

    calls = []
    monkeypatch.setattr(runner, "run_bench", lambda out, **kw: calls.append(kw))
    assert main(["bench", "-o", str(tmp_path), "--quiet"]) == 0
    assert main(["bench", "-o", str(tmp_path), "--quiet", "--suite", "v2", "--split", "dev"]) == 0
    assert main(["bench", "-o", str(tmp_path), "--quiet", "--suite", "v2"]) == 0
    assert [(c["suite_name"], c["split"]) for c in calls] == [("v1", "test"), ("v2", "dev"),
                                                              ("v2", "test")]  # fmt: skip
    assert main(["bench", "-o", str(tmp_path), "--suite", "v2", "--quick"]) == 2
    assert "does not go with --quick" in capsys.readouterr().err
    assert len(calls) == 3


def test_a_video_subject_is_reconstructed_from_its_video_with_focal_and_height(tmp_path):
    from monoavatar.bench.suite import MODES, V2_SUBJECTS

    subject = V2_SUBJECTS["dev"][0]
    scene = tmp_path / subject.name
    scene.mkdir()
    (scene / "scene.json").write_text(json.dumps({
        "camera": {"K": [[512.5, 0, 270], [0, 512.5, 270], [0, 0, 1]]},
        "subjects": [{"height_m": 1.86, "stature_m": 1.83}]}))  # fmt: skip
    estimated, shape_only, gt = MODES
    for mode in (estimated, shape_only):
        source, video = runner._run_input(subject, mode, scene)
        assert source == scene / "video.mp4" and video == (512.5, 1.83)
        config = runner._make_config(subject, mode, False, 3, video)
        assert (config.input.focal, config.pose.height) == (512.5, 1.83)
        assert (config.input.workers, config.shape.workers, config.texture.workers,
                config.flow.workers) == (3, 3, 3, 3)  # fmt: skip
    assert runner._run_input(subject, gt, scene) == (scene, None)  # true poses: the folder
    v1 = runner._make_config(replace(subject, from_video=False), estimated, False, 2, None)
    assert (v1.input.focal, v1.pose.height) == (None, runner.HEIGHT)
