"""The few-frame benchmark (Paper D, Table D.1, Fig. D.7): ``reconstruct --fast`` on the
suite's turn-around subjects from 1, 2, 4 and 8 frames spread evenly over the turn, before and
after the top-down refinement, against the full pipeline (``reconstruct``) on the same 8
frames; mediapipe perception on the rendered frames, no height given.

The suite's subjects are drawn by ``synth`` from their own seeds, a stream that the training
subjects of ``train fast`` never use (those come from ``(seed, 11)``-seeded generators), and
the refinement's settings were chosen on other turn-arounds (``docs/decisions.md``): for this
method the suite is a sealed test split.

Per run, against the subject's clothed ground truth: the surface error with the
dissertation's metric (mean bi-directional vertex-to-surface distance after pose and scale
alignment) and after a similarity alone, mm; seconds of the whole run (perception included)
and of the network's forward pass. Written: ``fast.json``, ``fast.md`` and ``fast_refine.png``
(the error of 8-frame runs of every third subject against the seconds of refinement, after
each round of a 40 s budget, Fig. D.7).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TABLE_D1", "render_fast_markdown", "run_fast_bench"]

TABLE_D1: dict[str, float] = {"before_mm": 4.47, "after_mm": 4.00, "gt_poses_after_mm": 3.17}
"""Octopus's mean vertex error with 8 frames before and after 10 s of top-down refinement,
and after it with true poses (Table D.1), mm."""

FRAME_COUNTS = (1, 2, 4, 8)
CURVE_BUDGET = 40.0
"""Seconds of refinement of the 8-frame runs whose rounds give the Fig. D.7 curve."""
CURVE_EVERY = 3
"""The curve is run on every third subject of the suite (minimal and clothed ones)."""


def _errors(body: Any, shape: Any, truth: Any) -> dict[str, float]:
    from monoavatar.bench.ground_truth import ground_truth_error

    gt = ground_truth_error(body, shape, truth)
    return {"surface_mm": gt.surface_error_mm, "similarity_mm": gt.surface_error_rigid_mm}


def run_fast_bench(out_dir: str | Path, *, quick: bool = False, subjects: list[str] | None = None,
                   full: bool = True, progress: bool = True,
                   weights: str | None = None) -> dict[str, Any]:  # fmt: skip
    """Run the few-frame table on the suite (``quick``: its quick subject, 1 and 8 frames, no
    curve) and write it into ``out_dir``. A failing run is recorded with its error and the
    others go on."""
    from monoavatar.bench.suite import ensure_scene, get_suite
    from monoavatar.body import load_body_model
    from monoavatar.datasets.synth_scene import read_synth_scene
    from monoavatar.pipelines.fast import FastConfig, fast_reconstruct
    from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
    from monoavatar.pipelines.stages import InputSettings

    out = Path(out_dir)
    suite = get_suite(quick)
    chosen = [s for s in suite.subjects if not subjects or s.name in subjects]
    body = load_body_model("anny")
    counts = (1, 8) if quick else FRAME_COUNTS
    rows: list[dict[str, Any]] = []
    curves: list[dict[str, Any]] = []
    results = _write(out, suite.to_dict(), rows, curves)
    for subject in chosen:
        scene = ensure_scene(subject, out / "scenes", progress=progress)
        truth = read_synth_scene(scene).ground_truth
        runs: list[tuple[str, int, float]] = [("fast", f, FastConfig().budget) for f in counts]
        if not quick and suite.subjects.index(subject) % CURVE_EVERY == 0:
            runs.append(("curve", 8, CURVE_BUDGET))
        for method, frames, budget in runs:
            row: dict[str, Any] = {"subject": subject.name, "method": method, "frames": frames}
            config = FastConfig(input=InputSettings(frames=frames, perception="mediapipe"),
                                budget=budget, weights=weights, progress=False)  # fmt: skip
            folder = out / "runs" / f"{subject.name}-{method}{frames}"
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    result = fast_reconstruct(scene, _cleared(folder), config)
            except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
                rows.append(row | {"error": f"{type(exc).__name__}: {exc}"})
                continue
            kept = result.steps if method == "curve" else (result.steps[0], result.steps[-1])
            steps = [{"seconds": s.seconds} | _errors(body, s.shape, truth) for s in kept]
            if method == "curve":
                curves.append({"subject": subject.name, "steps": steps})
                continue
            row.update(before=steps[0], after=steps[-1], rounds=len(result.steps) - 1,
                       seconds=result.report.seconds,
                       network_seconds=result.report.timings["network"],
                       refine_seconds=result.report.timings.get("refine", 0.0))  # fmt: skip
            rows.append(row)
        if full:
            row = {"subject": subject.name, "method": "full", "frames": 8}
            base = ReconstructConfig()
            config_full = replace(base, input=replace(base.input, frames=8,
                                                      perception="mediapipe"), progress=False)
            folder = out / "runs" / f"{subject.name}-full8"
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    full_result = reconstruct(scene, _cleared(folder), config_full)
            except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
                rows.append(row | {"error": f"{type(exc).__name__}: {exc}"})
            else:
                rows.append(row | {"after": _errors(body, full_result.shape, truth),
                                   "seconds": full_result.report.seconds})  # fmt: skip
        results = _write(out, suite.to_dict(), rows, curves)  # after each subject
    if curves:
        _curve_plot(out / "fast_refine.png", curves)
    return results


def _write(out: Path, suite: dict[str, Any], rows: list[dict[str, Any]],
           curves: list[dict[str, Any]]) -> dict[str, Any]:  # fmt: skip
    """``fast.json`` and ``fast.md`` of the runs so far (atomically); returns the results."""
    from monoavatar.core.files import atomic_write_text

    results = {"format": "monoavatar-bench-fast-1", "suite": suite, "runs": rows,
               "curves": curves, "published": TABLE_D1}  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "fast.json", json.dumps(results, indent=2))
    atomic_write_text(out / "fast.md", render_fast_markdown(rows))
    return results


def _cleared(folder: Path) -> Path:
    """``folder`` removed (a rerun of the benchmark replaces its runs), its parent made."""
    import shutil

    if folder.exists():
        shutil.rmtree(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    return folder


def _curve_plot(path: Path, curves: list[dict[str, Any]]) -> None:
    """Fig. D.7: each subject's error after each refinement round against its seconds, and
    the mean over subjects per round (at the mean seconds)."""
    from monoavatar.io.plots import line_plot

    series: dict[str, tuple[Sequence[float], Sequence[float]]] = {
        c["subject"]: ([s["seconds"] for s in c["steps"]],
                       [s["surface_mm"] for s in c["steps"]]) for c in curves}  # fmt: skip
    rounds = min(len(c["steps"]) for c in curves)
    series["mean"] = ([float(np.mean([c["steps"][k]["seconds"] for c in curves]))
                       for k in range(rounds)],
                      [float(np.mean([c["steps"][k]["surface_mm"] for c in curves]))
                       for k in range(rounds)])  # fmt: skip
    line_plot(path, series, "seconds of top-down refinement (2 CPU cores)",
              "surface error (mm, pose + scale aligned)",
              "reconstruct --fast, 8 frames: error against refinement time")  # fmt: skip


def _mean(rows: list[dict[str, Any]], stage: str, key: str) -> float:
    return float(np.mean([r[stage][key] for r in rows]))


def render_fast_markdown(rows: list[dict[str, Any]]) -> str:
    """The few-frame table: per method and frame count the mean over subjects, Octopus's
    Table D.1 beside it; then every run."""
    lines = ["| method | frames | subjects | before refinement mm (similarity) | after mm "
             "(similarity) | network s | whole run s |", "|---|---|---|---|---|---|---|"]
    good = [r for r in rows if "error" not in r]
    for method, frames in sorted({(r["method"], r["frames"]) for r in good},
                                 key=lambda k: (k[0] == "full", k[1])):  # fmt: skip
        sel = [r for r in good if r["method"] == method and r["frames"] == frames]
        before = (f"{_mean(sel, 'before', 'surface_mm'):.2f} "
                  f"({_mean(sel, 'before', 'similarity_mm'):.2f})" if "before" in sel[0] else "")
        network = (f"{np.mean([r['network_seconds'] for r in sel]):.2f}"
                   if "network_seconds" in sel[0] else "")  # fmt: skip
        name = "reconstruct --fast" if method == "fast" else "reconstruct (full pipeline)"
        lines.append(f"| {name} | {frames} | {len(sel)} | {before} | "
                     f"{_mean(sel, 'after', 'surface_mm'):.2f} "
                     f"({_mean(sel, 'after', 'similarity_mm'):.2f}) | {network} | "
                     f"{np.mean([r['seconds'] for r in sel]):.1f} |")  # fmt: skip
    lines.append(f"| Octopus (Table D.1, V100) | 8 | 55 | {TABLE_D1['before_mm']} | "
                 f"{TABLE_D1['after_mm']} | 0.05 / view | ≈ 10 (refinement) |")
    lines += ["", "| subject | method | frames | before mm | after mm | similarity after mm "
              "| rounds | s |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['subject']} | {r['method']} | {r['frames']} | failed: "
                         f"{r['error']} | | | | |")  # fmt: skip
            continue
        before = f"{r['before']['surface_mm']:.2f}" if "before" in r else ""
        lines.append(f"| {r['subject']} | {r['method']} | {r['frames']} | {before} | "
                     f"{r['after']['surface_mm']:.2f} | {r['after']['similarity_mm']:.2f} | "
                     f"{r.get('rounds', '')} | {r['seconds']:.1f} |")  # fmt: skip
    return "\n".join(lines) + "\n"
