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
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
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
from monoavatar.bench.suite import MODES, BenchMode, BenchSubject, ensure_scene, get_suite

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
                 workers: int = 2) -> Any:  # fmt: skip
    from monoavatar.pipelines.reconstruct import ReconstructConfig
    from monoavatar.pipelines.stages import InputSettings

    base = ReconstructConfig()
    return ReconstructConfig(
        input=InputSettings(frames=subject.keyframes, perception=mode.perception,
                            poses=mode.poses),  # fmt: skip
        progress=progress,
        pose=replace(base.pose, height=HEIGHT),
        shape=replace(base.shape, fit_offsets=mode.offsets),
        texture=replace(base.texture, size=subject.texture_size, workers=workers),
        flow=replace(base.flow, workers=workers),
    )


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


def run_bench(
    out_dir: str | Path,
    *,
    quick: bool = False,
    subjects: Sequence[str] | None = None,
    gt_poses: bool = True,
    reconstruct: ReconstructFn | None = None,
    progress: bool = True,
    scenes_dir: str | Path | None = None,
    measure_only: bool = False,
    track_rounds: int = HELDOUT_TRACK_ROUNDS,
    workers: int = 2,
) -> BenchResults:
    """Run the benchmark and write ``results.json``, ``results.md`` and heat maps.

    Args:
        out_dir: output folder (created).
        quick: the one-subject smoke-test suite instead of the full one.
        subjects: names of suite subjects to run (default all; unknown names raise
            :class:`~monoavatar.bench.suite.SuiteError` listing the valid ones).
        gt_poses: also reconstruct with ground-truth poses (the second column of Table B.1).
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
            (results vary between runs by float rounding).

    Returns:
        :class:`~monoavatar.bench.report.BenchResults`; ``.table`` is the Markdown that
        ``results.md`` holds (the CLI prints it). A failing reconstruction or measurement is
        recorded as a failed run and the benchmark goes on.
    """
    start = time.perf_counter()
    out = Path(out_dir)
    suite = get_suite(quick).select(list(subjects) if subjects is not None else None)
    modes = tuple(m for m in MODES if gt_poses or m.poses != "ground-truth")
    scenes = Path(scenes_dir) if scenes_dir is not None else out / "scenes"
    fn = reconstruct if reconstruct is not None else _default_reconstruct()
    out.mkdir(parents=True, exist_ok=True)
    results = BenchResults(out_dir=out, suite=suite, modes=modes, machine=machine_info(),
                           date=utc_now())  # fmt: skip
    bodies = BodyCache()
    total = len(suite.subjects) * len(modes)
    count = 0
    for subject in suite.subjects:
        _say(progress, f"bench: scene {subject.name} ({subject.frames} frames, "
                       f"{subject.width}x{subject.height})")  # fmt: skip
        scene = ensure_scene(subject, scenes, progress=progress)
        truth = load_truth(scene, bodies)
        for mode in modes:
            count += 1
            folder = out / "runs" / subject.name / mode.name
            run = RunResult(subject=subject, mode=mode.name, folder=folder, status="failed")
            measured_peak = False
            if measure_only:
                _say(progress, f"bench [{count}/{total}] {subject.name}, {mode.label}: "
                               "measuring the earlier output")  # fmt: skip
            else:
                if folder.exists():
                    shutil.rmtree(folder)
                folder.mkdir(parents=True)
                _say(progress, f"bench [{count}/{total}] {subject.name}, {mode.label}: "
                               f"reconstructing {subject.keyframes} key-frames")  # fmt: skip
                config = _make_config(subject, mode, progress, workers)
                measured_peak = _reset_peak_rss()
                t0 = time.perf_counter()
                try:
                    with _private_cache(out / ".cache"):
                        fn(scene, folder, config)
                except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
                    run.error = _short_error(exc)
                    run.wall_seconds = time.perf_counter() - t0
                    _say(progress, f"  failed: {run.error}")
                    if progress:
                        traceback.print_exc(file=sys.stderr)
                    results.runs.append(run)
                    write_results(results)
                    continue
                run.wall_seconds = time.perf_counter() - t0
                run.peak_rss_mb = _peak_rss_mb() if measured_peak else None
            try:
                metrics, heat = evaluate_reconstruction(folder, truth, bodies,
                                                        max_heldout=MAX_HELDOUT,
                                                        perception=mode.perception,
                                                        track_rounds=track_rounds,
                                                        workers=workers)  # fmt: skip
            except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
                run.error = "evaluation: " + _short_error(exc)
                _say(progress, f"  failed: {run.error}")
                results.runs.append(run)
                write_results(results)
                continue
            if run.peak_rss_mb is None:
                run.peak_rss_mb = metrics.peak_memory_mb
            if measure_only:
                run.wall_seconds = metrics.reconstruct_seconds or 0.0
            run.metrics = metrics
            run.status = "ok"
            estimated = results.run(subject.name, "estimated")
            if mode.name == "shape-only" and estimated is not None and estimated.metrics:
                # the baseline column of the estimated run
                estimated.metrics = replace(estimated.metrics,
                                            shape_only_mm=metrics.surface.mean_mm)  # fmt: skip
            stem = f"{subject.name}-{mode.name}"
            run.heatmap_png = out / "heatmaps" / f"{stem}.png"
            run.heatmap_ply = out / "heatmaps" / f"{stem}.ply"
            title = (f"{subject.name}, {mode.label}: {metrics.surface.mean_mm:.2f} mm "
                     f"± {metrics.surface.std_mm:.2f}")  # fmt: skip
            write_heatmap(heat, run.heatmap_png, run.heatmap_ply, title=title)
            results.runs.append(run)
            results.seconds = time.perf_counter() - start
            write_results(results)
            _say(progress, f"  {metrics.surface.mean_mm:.2f} mm surface, "
                           f"{metrics.pa_mpjpe_mm:.1f} mm PA-MPJPE, IoU "
                           f"{metrics.silhouette_iou:.3f}, {run.wall_seconds:.0f} s")  # fmt: skip
        del truth
    results.seconds = time.perf_counter() - start
    write_results(results)
    shutil.rmtree(out / ".cache", ignore_errors=True)
    if progress:
        print(results.table, flush=True)
    return results
