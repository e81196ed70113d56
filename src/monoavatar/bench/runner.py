"""``monoavatar bench``: generate (or reuse) the suite's scenes, reconstruct every subject in
every mode, measure, and write the report.

Output folder layout::

    scenes/<subject>/               the synth scenes (cache, reused while valid)
    runs/<subject>/<mode>/          each reconstruction's own output folder
    heatmaps/<subject>-<mode>.png   per-vertex error, front and back (blue 0 → red ≥ 20 mm)
    heatmaps/<subject>-<mode>.ply   the same on the aligned avatar mesh, vertex colours
    results.json                    everything measured (see monoavatar.bench.report)
    results.md                      the table, with the dissertation's figures beside ours

Each reconstruction runs with a fresh, private stage and perception cache
(``$MONOAVATAR_CACHE`` points to a temporary folder during the call), so its timings include
every stage. Peak memory is the process's peak resident set size during the call (Linux:
``VmHWM`` after resetting it through ``/proc/self/clear_refs``; elsewhere the reconstruction's
own ``peak_memory_mb``, a process-lifetime peak).

With ``address`` (``bench --address``) every scene and every run is a Ray task: a run waits
for its scene's task, reserves ``workers`` cores, loads its own body models and ground truth,
and writes its folders itself; the results are gathered as they arrive, so ``results.json``
is the same as one process would write, in the suite's order.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from monoavatar.bench.evaluate import evaluate_reconstruction
from monoavatar.bench.heldout import HELDOUT_TRACK_ROUNDS
from monoavatar.bench.metrics import BodyCache, load_truth
from monoavatar.bench.report import (
    BenchResults,
    RunResult,
    machine_info,
    utc_now,
    write_heatmap,
    write_results,
)
from monoavatar.bench.suite import (
    MODES,
    BenchMode,
    BenchSubject,
    SuiteError,
    ensure_scene,
    get_suite,
)
from monoavatar.datasets.synth_scene import stated_height

__all__ = ["HEIGHT", "MAX_HELDOUT", "ReconstructFn", "run_bench"]

ReconstructFn = Callable[[Path, Path, Any], object]
"""``reconstruct(input, out_dir, config)`` as
:func:`monoavatar.pipelines.reconstruct.reconstruct`."""

MAX_HELDOUT = 20
"""Held-out frames (evenly spread) that the texture PSNR averages over, per run."""

HEIGHT: float | None = None
"""Height given to the reconstruction: None, as a user without a tape measure would run it
(the result is up to scale; the metrics align scale)."""


def _default_reconstruct() -> ReconstructFn:
    from monoavatar.pipelines.reconstruct import reconstruct

    return reconstruct


def _make_config(subject: BenchSubject, mode: BenchMode, progress: bool,
                 workers: int = 2, video: tuple[float, float] | None = None) -> Any:  # fmt: skip
    """The reconstruction's settings for one run; ``video`` (focal length px, height m):
    the run reads the scene's video with these, as a user would."""
    from monoavatar.pipelines.reconstruct import ReconstructConfig
    from monoavatar.pipelines.stages import InputSettings

    base = ReconstructConfig()
    focal, height = video if video is not None else (None, HEIGHT)
    return ReconstructConfig(
        input=InputSettings(frames=subject.keyframes, perception=mode.perception,
                            poses=mode.poses, focal=focal, workers=workers),  # fmt: skip
        progress=progress,
        pose=replace(base.pose, height=height),
        shape=replace(base.shape, fit_offsets=mode.offsets, workers=workers),
        texture=replace(base.texture, size=subject.texture_size, workers=workers),
        flow=replace(base.flow, workers=workers),
    )


def _run_input(subject: BenchSubject, mode: BenchMode, scene: Path
               ) -> tuple[Path, tuple[float, float] | None]:  # fmt: skip
    """What a run reads: the scene folder, or, for a ``from_video`` subject's run on
    estimated poses, its ``video.mp4`` with the focal length (pixels) and the subject's
    height as a person gives it (metres, the unclothed body's: ``stature_m`` of
    ``scene.json``)."""
    if not subject.from_video or mode.poses != "fit":
        return scene, None
    info = json.loads((scene / "scene.json").read_text())
    return scene / "video.mp4", (float(info["camera"]["K"][0][0]),
                                 stated_height(info))  # fmt: skip


@contextmanager
def _private_cache(root: Path) -> Iterator[None]:
    """Point ``$MONOAVATAR_CACHE`` at a fresh temporary folder for the duration."""
    root.mkdir(parents=True, exist_ok=True)
    old = os.environ.get("MONOAVATAR_CACHE")
    with tempfile.TemporaryDirectory(dir=root, prefix="cache-") as tmp:
        os.environ["MONOAVATAR_CACHE"] = tmp
        try:
            yield
        finally:
            if old is None:
                os.environ.pop("MONOAVATAR_CACHE", None)
            else:
                os.environ["MONOAVATAR_CACHE"] = old


def _reset_peak_rss() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _peak_rss_mb() -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def _say(progress: bool, message: str) -> None:
    if progress:
        print(message, file=sys.stderr, flush=True)


def _short_error(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}"
    return text if len(text) < 2000 else text[:2000] + "…"


@dataclass(frozen=True)
class _RunOptions:
    """What every run of one benchmark shares (sent to Ray tasks as it is)."""

    out: Path
    measure_only: bool
    track_rounds: int
    workers: int
    progress: bool


def run_bench(
    out_dir: str | Path,
    *,
    quick: bool = False,
    subjects: Sequence[str] | None = None,
    gt_poses: bool = True,
    suite_name: str = "v1",
    split: str = "test",
    reconstruct: ReconstructFn | None = None,
    progress: bool = True,
    scenes_dir: str | Path | None = None,
    measure_only: bool = False,
    track_rounds: int = HELDOUT_TRACK_ROUNDS,
    workers: int = 2,
    address: str | None = None,
) -> BenchResults:
    """Run the benchmark and write ``results.json``, ``results.md`` and heat maps.

    Args:
        out_dir: output folder (created).
        quick: the one-subject smoke-test suite instead of the full one.
        subjects: names of suite subjects to run (default all; unknown names raise
            :class:`~monoavatar.bench.suite.SuiteError` listing the valid ones).
        gt_poses: also reconstruct with ground-truth poses (the second column of Table B.1).
        suite_name: ``"v1"`` (the full suite, or the quick one) or ``"v2"``, the harder suite
            of phone takes of wide subjects, whose ``split`` (``"dev"`` or ``"test"``) is run.
        reconstruct: the reconstruction function (default
            :func:`monoavatar.pipelines.reconstruct.reconstruct`); called as
            ``reconstruct(scene_folder, run_folder, ReconstructConfig(...))``.
        progress: progress lines on stderr, the reconstruction's progress bars, and the
            final table on stdout.
        scenes_dir: where scenes are generated and reused (default ``out_dir/scenes``).
        measure_only: reconstruct nothing; measure the run folders an earlier benchmark left
            in ``out_dir/runs`` again (after a change of the metrics). Times and memory are
            then the reconstructions' own (``report.json``); a missing folder is a failed run.
        track_rounds: flow rounds of the tracker that poses the avatar in the held-out frames
            for the texture PSNR (0: the key-frames' poses interpolated).
        workers: threads of the reconstructions' flow and texture stages and of the tracker
            (results vary between runs by float rounding); with Ray, the cores each run
            reserves.
        address: run every scene and every (subject, mode) run as a Ray task: ``"local"``
            starts a cluster on this machine's cores, ``"auto"`` or ``host:port`` /
            ``ray://host:10001`` joins an existing one (``out_dir`` and ``scenes_dir`` must
            then be folders every node sees). None: one run after another in this process.

    Returns:
        :class:`~monoavatar.bench.report.BenchResults`; ``.table`` is the Markdown that
        ``results.md`` holds (the CLI prints it). A failing reconstruction or measurement is
        recorded as a failed run and the benchmark goes on.
    """
    start = time.perf_counter()
    out = Path(out_dir)
    suite = get_suite(quick, suite_name, split).select(
        list(subjects) if subjects is not None else None)
    modes = tuple(m for m in MODES if gt_poses or m.poses != "ground-truth")
    scenes = Path(scenes_dir) if scenes_dir is not None else out / "scenes"
    fn = reconstruct if reconstruct is not None else _default_reconstruct()
    out.mkdir(parents=True, exist_ok=True)
    results = BenchResults(out_dir=out, suite=suite, modes=modes, machine=machine_info(),
                           date=utc_now())  # fmt: skip
    options = _RunOptions(out=out, measure_only=measure_only, track_rounds=track_rounds,
                          workers=workers, progress=progress and address is None)  # fmt: skip
    total = len(suite.subjects) * len(modes)

    def record(run: RunResult) -> None:
        _record(results, run, modes)
        results.seconds = time.perf_counter() - start
        write_results(results)
        label = next(m.label for m in modes if m.name == run.mode)
        head = f"bench [{len(results.runs)}/{total}] {run.subject.name}, {label}:"
        if run.status == "ok" and run.metrics is not None:
            m = run.metrics
            _say(progress, f"{head} {m.surface.mean_mm:.2f} mm surface, "
                           f"{m.pa_mpjpe_mm:.1f} mm PA-MPJPE, IoU {m.silhouette_iou:.3f}, "
                           f"{run.wall_seconds:.0f} s")  # fmt: skip
        else:
            _say(progress, f"{head} failed: {run.error}")

    if address is None:
        bodies = BodyCache()
        for subject in suite.subjects:
            _say(progress, f"bench: scene {subject.name} ({subject.frames} frames, "
                           f"{subject.width}x{subject.height})")  # fmt: skip
            scene = ensure_scene(subject, scenes, progress=progress)
            truth = load_truth(scene, bodies)
            for mode in modes:
                _say(progress, f"bench: {subject.name}, {mode.label}: "
                               + ("measuring the earlier output" if measure_only else
                                  f"reconstructing {subject.keyframes} key-frames"))  # fmt: skip
                record(_one_run(subject, mode, scene, truth, bodies, fn, options))
            del truth
    else:
        _run_on_ray(address, suite.subjects, modes, scenes, fn, options, record, progress)
    results.seconds = time.perf_counter() - start
    write_results(results)
    shutil.rmtree(out / ".cache", ignore_errors=True)
    if progress:
        print(results.table, flush=True)
    return results


def _record(results: BenchResults, run: RunResult, modes: Sequence[BenchMode]) -> None:
    """Add a finished run, keep the runs in suite and mode order, and fill the estimated run's
    baseline column (the shape-only run's surface error) once both are there."""
    results.runs.append(run)
    subjects = [s.name for s in results.suite.subjects]
    order = [m.name for m in modes]
    results.runs.sort(key=lambda r: (subjects.index(r.subject.name), order.index(r.mode)))
    estimated = results.run(run.subject.name, "estimated")
    shape_only = results.run(run.subject.name, "shape-only")
    if (estimated is not None and estimated.metrics is not None and shape_only is not None
            and shape_only.metrics is not None):  # fmt: skip
        estimated.metrics = replace(estimated.metrics,
                                    shape_only_mm=shape_only.metrics.surface.mean_mm)  # fmt: skip


def _one_run(subject: BenchSubject, mode: BenchMode, scene: Path, truth: Any,
             bodies: BodyCache, fn: ReconstructFn, options: _RunOptions) -> RunResult:  # fmt: skip
    """Reconstruct (unless ``measure_only``) and measure one subject in one mode; a failure
    is recorded in the result, never raised."""
    progress, workers = options.progress, options.workers
    folder = options.out / "runs" / subject.name / mode.name
    run = RunResult(subject=subject, mode=mode.name, folder=folder, status="failed")
    measured_peak = False
    if not options.measure_only:
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        source, video = _run_input(subject, mode, scene)
        config = _make_config(subject, mode, progress, workers, video)
        measured_peak = _reset_peak_rss()
        t0 = time.perf_counter()
        try:
            with _private_cache(options.out / ".cache"):
                fn(source, folder, config)
        except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
            run.error = _short_error(exc)
            run.wall_seconds = time.perf_counter() - t0
            if progress:
                traceback.print_exc(file=sys.stderr)
            return run
        run.wall_seconds = time.perf_counter() - t0
        run.peak_rss_mb = _peak_rss_mb() if measured_peak else None
    try:
        metrics, heat = evaluate_reconstruction(folder, truth, bodies, max_heldout=MAX_HELDOUT,
                                                perception=mode.perception,
                                                track_rounds=options.track_rounds,
                                                workers=workers)  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
        run.error = "evaluation: " + _short_error(exc)
        return run
    if run.peak_rss_mb is None:
        run.peak_rss_mb = metrics.peak_memory_mb
    if options.measure_only:
        run.wall_seconds = metrics.reconstruct_seconds or 0.0
    run.metrics = metrics
    run.status = "ok"
    stem = f"{subject.name}-{mode.name}"
    run.heatmap_png = options.out / "heatmaps" / f"{stem}.png"
    run.heatmap_ply = options.out / "heatmaps" / f"{stem}.ply"
    title = (f"{subject.name}, {mode.label}: {metrics.surface.mean_mm:.2f} mm "
             f"± {metrics.surface.std_mm:.2f}")  # fmt: skip
    write_heatmap(heat, run.heatmap_png, run.heatmap_ply, title=title)
    return run


# -- Ray --------------------------------------------------------------------------------------


def _scene_task(subject: BenchSubject, scenes: Path) -> Path:
    """A Ray task: the subject's scene, generated unless valid."""
    return ensure_scene(subject, scenes)


def _run_task(subject: BenchSubject, mode: BenchMode, scene: Path, fn: ReconstructFn,
              options: _RunOptions) -> RunResult:  # fmt: skip
    """A Ray task: one run in a worker of its own, with its own body models and threads."""
    import torch

    torch.set_num_threads(options.workers)
    bodies = BodyCache()
    try:
        truth = load_truth(scene, bodies)
    except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
        folder = options.out / "runs" / subject.name / mode.name
        return RunResult(subject=subject, mode=mode.name, folder=folder, status="failed",
                         error="ground truth: " + _short_error(exc))  # fmt: skip
    return _one_run(subject, mode, scene, truth, bodies, fn, options)


def _run_on_ray(address: str, subjects: Sequence[BenchSubject], modes: Sequence[BenchMode],
                scenes: Path, fn: ReconstructFn, options: _RunOptions,
                record: Callable[[RunResult], None], progress: bool) -> None:  # fmt: skip
    """Every scene a Ray task, every run a task that waits for its scene; results recorded as
    they arrive. A scene that cannot be made fails its subject's runs."""
    try:
        import ray
    except ImportError:
        raise SuiteError("bench --address needs Ray: pip install 'monoavatar[ray]'") from None
    import logging

    started = not ray.is_initialized()
    pending: dict[Any, tuple[BenchSubject, BenchMode]] = {}
    if started:
        ray.init(address=address, include_dashboard=False, log_to_driver=False,
                 logging_level=logging.ERROR)  # fmt: skip
    try:
        cpus = int(ray.cluster_resources().get("CPU", 0))
        need = min(options.workers, max(cpus, 1))
        scenes_said = "1 scene" if len(subjects) == 1 else f"{len(subjects)} scenes"
        _say(progress, f"bench: {scenes_said} and {len(subjects) * len(modes)} runs as Ray "
                       f"tasks on {cpus} CPUs ({need} a run)")  # fmt: skip
        scene_task = ray.remote(num_cpus=1, max_retries=0)(_scene_task)
        run_task = ray.remote(num_cpus=need, max_retries=0)(_run_task)
        for subject in subjects:
            scene = scene_task.remote(subject, scenes)
            for mode in modes:
                pending[run_task.remote(subject, mode, scene, fn, options)] = (subject, mode)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                subject, mode = pending.pop(ref)
                try:
                    run = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - its scene failed, or the worker died
                    folder = options.out / "runs" / subject.name / mode.name
                    cause = getattr(exc, "cause", None) or exc
                    run = RunResult(subject=subject, mode=mode.name, folder=folder,
                                    status="failed", error=_short_error(cause))  # fmt: skip
                record(run)
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()
