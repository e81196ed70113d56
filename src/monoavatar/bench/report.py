"""Benchmark results: ``results.json``, the Markdown table ``results.md`` with the
dissertation's published figures beside ours, and per-vertex error heat maps.

Aggregates over subjects: the surface error of a group is the mean of its subjects' means, and
its ± the standard deviation of the equal-weight mixture of the subjects' per-vertex error
distributions (so ± always describes per-vertex spread, as in a single subject's row). Other
measures are plain means over the subjects that have them; peak memory is the maximum.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from monoavatar.bench.heldout import ROOT_OFF_DEG
from monoavatar.bench.metrics import REGIONS, HeatMap, SubjectMetrics
from monoavatar.bench.suite import CATEGORIES, BenchMode, BenchSubject, BenchSuite

__all__ = [
    "FORMAT",
    "PUBLISHED",
    "STAGES",
    "BenchResults",
    "RunResult",
    "aggregate",
    "machine_info",
    "render_heatmap",
    "render_markdown",
    "write_heatmap",
    "write_results",
]

FORMAT = "monoavatar-bench-1"
STAGES: tuple[str, ...] = ("perception", "poses", "refine", "shape", "texture", "flow", "export")

PUBLISHED: dict[str, Any] = {
    "source": "dissertation Paper B, Table B.1 and Sec. B.4 (reference/dissertation.txt)",
    "surface_error_mm": {
        "estimated": {"clothed": 5.37, "minimal": 4.44, "all": 4.5, "KinectCap": 3.97},
        "gt-poses": {"clothed": 3.40, "minimal": 2.86, "all": 3.1},
    },
    "datasets": {"clothed": "BUFF", "minimal": "D-FAUST", "all": "Paper B overall"},
    "runtime": {
        "pose_min_per_frame": 1.0,
        "shape_min": 110.0 / 60.0,
        "note": "≈1 min per frame for pose + 1:50 min for shape on one CPU",
    },  # fmt: skip
}
"""The dissertation's figures that the table quotes beside ours."""


@dataclass
class RunResult:
    """One reconstruction of one subject in one mode, and what was measured.

    Attributes:
        subject: the suite subject.
        mode: the mode's name (:data:`monoavatar.bench.suite.MODES`).
        folder: the reconstruction's output folder.
        status: ``"ok"`` or ``"failed"``.
        metrics: the measurements (None when failed).
        error: what went wrong (None when ok).
        wall_seconds: wall time of the reconstruction call, as the benchmark measured it.
        peak_rss_mb: peak resident memory during the call (Linux; None where unknown).
        heatmap_png: the heat-map image, when written.
        heatmap_ply: the heat-map mesh, when written.
    """

    subject: BenchSubject
    mode: str
    folder: Path
    status: str
    metrics: SubjectMetrics | None = None
    error: str | None = None
    wall_seconds: float = 0.0
    peak_rss_mb: float | None = None
    heatmap_png: Path | None = None
    heatmap_ply: Path | None = None

    def to_dict(self, root: Path) -> dict[str, Any]:
        def rel(p: Path | None) -> str | None:
            if p is None:
                return None
            try:
                return str(p.relative_to(root))
            except ValueError:
                return str(p)

        return {
            "subject": self.subject.name,
            "mode": self.mode,
            "status": self.status,
            "error": self.error,
            "folder": rel(self.folder),
            "wall_seconds": _finite(self.wall_seconds),
            "peak_rss_mb": _finite(self.peak_rss_mb),
            "metrics": None if self.metrics is None else self.metrics.to_dict(),
            "heatmap_png": rel(self.heatmap_png),
            "heatmap_ply": rel(self.heatmap_ply),
        }


@dataclass
class BenchResults:
    """Everything one ``monoavatar bench`` run produced.

    Attributes:
        out_dir: the output folder.
        suite: the suite (after subject selection).
        modes: the modes run.
        runs: one :class:`RunResult` per subject and mode, in run order.
        machine: :func:`machine_info`.
        date: ISO 8601 time the run started (UTC).
        aggregate: :func:`aggregate` of the runs.
        files: the files written (``results.json``, ``results.md``).
        table: the Markdown of ``results.md``.
        seconds: wall time of the whole run, scene generation included.
    """

    out_dir: Path
    suite: BenchSuite
    modes: tuple[BenchMode, ...]
    runs: list[RunResult] = field(default_factory=list)
    machine: dict[str, Any] = field(default_factory=dict)
    date: str = ""
    aggregate: dict[str, Any] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)
    table: str = ""
    seconds: float = 0.0

    def run(self, subject: str, mode: str) -> RunResult | None:
        """The run of a subject (by name) in a mode (by name), if any."""
        for r in self.runs:
            if r.subject.name == subject and r.mode == mode:
                return r
        return None

    def to_dict(self) -> dict[str, Any]:
        by_subject: dict[str, dict[str, Any]] = {}
        for s in self.suite.subjects:
            by_subject[s.name] = {**s.to_dict(), "runs": {}}
        for r in self.runs:
            by_subject[r.subject.name]["runs"][r.mode] = r.to_dict(self.out_dir)
        return {
            "format": FORMAT,
            "suite": {"version": self.suite.version, "name": self.suite.name},
            "date": self.date,
            "seconds": _finite(self.seconds),
            "machine": self.machine,
            "modes": [m.to_dict() for m in self.modes],
            "subjects": list(by_subject.values()),
            "aggregate": self.aggregate,
            "published": PUBLISHED,
        }


def _finite(value: float | None) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return float(value)


# -- machine ------------------------------------------------------------------------------------


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict[str, Any]:
    """CPU model, cores (all and usable), torch threads, Python, torch and monoavatar
    versions, OS."""
    import torch

    import monoavatar

    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = os.cpu_count() or 0
    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "usable_cores": usable,
        "torch_threads": torch.get_num_threads(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "monoavatar": monoavatar.__version__,
        "os": platform.platform(),
    }


# -- aggregation --------------------------------------------------------------------------------


def _mean(values: list[float | None]) -> float | None:
    got = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(got)) if got else None


def _group(runs: list[RunResult]) -> dict[str, Any]:
    ok = [r for r in runs if r.status == "ok" and r.metrics is not None]
    out: dict[str, Any] = {"subjects": len(runs), "failed": len(runs) - len(ok)}
    if not ok:
        return out
    ms = [r.metrics for r in ok if r.metrics is not None]
    means = np.array([m.surface.mean_mm for m in ms])
    stds = np.array([m.surface.std_mm for m in ms])
    overall = float(means.mean())
    out["surface_error_mm"] = overall
    out["surface_error_std_mm"] = float(np.sqrt(np.mean(stds**2 + (means - overall) ** 2)))
    out["surface_error_min_mm"] = float(means.min())
    out["surface_error_max_mm"] = float(means.max())
    out["surface_error_rigid_mm"] = _mean([m.surface.rigid_mean_mm for m in ms])
    bones = [m.surface.bone_angles_deg for m in ms if m.surface.bone_angles_deg is not None]
    if bones:  # the rest skeleton against the truth's: subjects' median bones and worst bone
        out["bone_angle_median_deg"] = float(np.mean([np.nanmedian(b) for b in bones]))
        out["bone_angle_worst_median_deg"] = float(max(np.nanmedian(b) for b in bones))
        out["bone_angle_max_deg"] = float(max(np.nanmax(b) for b in bones))
    out["normal_error_deg"] = _mean([m.surface.normal_error_deg for m in ms])
    out["normal_error_rigid_deg"] = _mean([m.surface.rigid_normal_error_deg for m in ms])
    out["regions"] = {
        region: {"surface_error_mm": _mean([m.surface.regions.get(region, (None, None))[0]
                                            for m in ms]),
                 "normal_error_deg": _mean([m.surface.regions.get(region, (None, None))[1]
                                            for m in ms])}
        for region in REGIONS
    }  # fmt: skip
    out["body_only_error_mm"] = _mean([m.body_only_mm for m in ms])
    shape_only = [m.shape_only_mm for m in ms]
    out["shape_only_error_mm"] = (
        _mean(shape_only) if all(v is not None for v in shape_only) else None
    )
    out["pa_mpjpe_mm"] = _mean([m.pa_mpjpe_mm for m in ms])
    out["silhouette_iou"] = _mean([m.silhouette_iou for m in ms])
    out["texture_psnr_db"] = _mean([m.psnr_db for m in ms])
    out["texture_psnr_overlap_db"] = _mean([m.psnr_overlap_db for m in ms])
    out["texture_psnr_union_db"] = _mean([m.psnr_union_db for m in ms])
    out["texture_psnr_rigid_db"] = _mean([m.psnr_rigid_db for m in ms])
    out["texture_psnr_true_poses_db"] = _mean([m.psnr_true_poses_db for m in ms])
    out["texture_psnr_interpolated_db"] = _mean([m.psnr_interpolated_db for m in ms])
    out["heldout_track_seconds"] = _mean([m.heldout_track_seconds for m in ms])
    out["heldout_pa_mpjpe_mm"] = _mean([m.heldout_pa_mpjpe_mm for m in ms])
    out["heldout_pa_mpjpe_interpolated_mm"] = _mean([m.heldout_pa_mpjpe_interpolated_mm
                                                     for m in ms])  # fmt: skip
    out["heldout_root_error_deg"] = _mean([m.heldout_root_error_deg for m in ms])
    out["heldout_root_error_interpolated_deg"] = _mean([m.heldout_root_error_interpolated_deg
                                                        for m in ms])  # fmt: skip
    out["texture_missed_fraction"] = _mean([m.missed_fraction for m in ms])
    out["texture_missed_error_share"] = _mean([m.missed_error_share for m in ms])
    out["root_error_deg"] = _mean([m.root_error_deg for m in ms])
    out["root_error_max_deg"] = max((m.root_error_max_deg for m in ms
                                     if m.root_error_max_deg is not None), default=None)
    out["root_off_frames"] = sum(m.root_off_frames or 0 for m in ms)
    out["keyframes"] = _mean([float(m.keyframes) for m in ms])
    out["timings_s"] = {s: _mean([m.timings.get(s) for m in ms]) for s in STAGES}
    out["reconstruct_seconds"] = _mean([m.reconstruct_seconds for m in ms])
    out["wall_seconds"] = _mean([r.wall_seconds for r in ok])
    peaks = [r.peak_rss_mb for r in ok if r.peak_rss_mb is not None]
    out["peak_rss_mb"] = max(peaks) if peaks else None
    return out


def aggregate(runs: list[RunResult], modes: tuple[BenchMode, ...]) -> dict[str, Any]:
    """Per mode: per category (:data:`~monoavatar.bench.suite.CATEGORIES`) and ``"all"``."""
    out: dict[str, Any] = {}
    for mode in modes:
        mine = [r for r in runs if r.mode == mode.name]
        groups = {c: _group([r for r in mine if r.subject.category == c]) for c in CATEGORIES}
        groups = {c: g for c, g in groups.items() if g["subjects"]}
        groups["all"] = _group(mine)
        out[mode.name] = groups
    return out


# -- Markdown -----------------------------------------------------------------------------------


def _fmt(value: Any, digits: int = 2, unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.{digits}f}{unit}"


def _pm(group: dict[str, Any]) -> str:
    if "surface_error_mm" not in group:
        return "failed" if group.get("failed") else "–"
    return f"{group['surface_error_mm']:.2f} ± {group['surface_error_std_mm']:.2f}"


def _group_label(name: str) -> str:
    if name == "all":
        return "all subjects"
    return CATEGORIES[name]


def _suite_label(name: str) -> str:
    """How the report names a suite: ``full`` and ``quick`` are suite v1's, ``v2-dev`` and
    ``v2-test`` suite v2's splits."""
    if name.startswith("v2-"):
        return f"v2, {name[3:]} split"
    return f"v1 ({name})"


def render_markdown(results: BenchResults) -> str:
    """The ``results.md`` table (also printed by ``monoavatar bench``)."""
    agg = results.aggregate
    m = results.machine
    names = [mode.name for mode in results.modes]
    pub = PUBLISHED["surface_error_mm"]
    lines = [
        f"# monoavatar bench: suite {_suite_label(results.suite.name)}, version "
        f"{results.suite.version}, {results.date[:10]}",
        "",
        f"Measured on {m.get('cpu', '?')}, {m.get('usable_cores', '?')} usable cores, "
        f"{m.get('torch_threads', '?')} torch threads; Python {m.get('python', '?')}, "
        f"torch {m.get('torch', '?')}, monoavatar {m.get('monoavatar', '?')}. "
        f"Whole run: {results.seconds / 60:.1f} min.",
    ]
    if results.suite.name == "quick":
        lines += ["", "**Quick smoke test** (one subject, few small frames): not comparable "
                  "with the dissertation's figures."]  # fmt: skip
    lines += [
        "",
        "## Surface error (mm)",
        "",
        "Mean ± std of the bi-directional vertex-to-surface distance between the canonical "
        "avatar and the ground-truth clothed canonical mesh, after aligning pose and scale "
        "(Table B.1's protocol: a similarity transform, then the avatar's articulated pose "
        "fitted to the ground truth, which separates pose from shape error; the shape is "
        "never changed). Our subjects are synthetic analogues of the datasets, not the "
        "datasets.",
        "",
    ]
    header = ["subjects", "n"]
    for name in ("estimated", "gt-poses"):
        if name in names:
            label = "estimated poses" if name == "estimated" else "ground-truth poses"
            header += [f"ours, {label}", f"dissertation, {label}"]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    groups = [c for c in CATEGORIES if any(c in agg.get(n, {}) for n in names)] + ["all"]
    for g in groups:
        n = max((agg.get(name, {}).get(g, {}).get("subjects", 0) for name in names), default=0)
        row = [_group_label(g), str(n)]
        for name in ("estimated", "gt-poses"):
            if name in names:
                value = pub[name].get(g)
                dataset = PUBLISHED["datasets"][g]
                row += [_pm(agg[name].get(g, {})),
                        "–" if value is None else f"{value:.2f} ({dataset})"]  # fmt: skip
        lines.append("| " + " | ".join(row) + " |")
    kinect = ["KinectCap (real captures; no synthetic analogue)", "–"]
    for name in ("estimated", "gt-poses"):
        if name in names:
            kinect += ["–", f"{pub['estimated']['KinectCap']:.2f}" if name == "estimated" else "–"]
    lines.append("| " + " | ".join(kinect) + " |")

    lines += [
        "",
        "## By region: surface error (mm) / normal angular error (°)",
        "",
        "After the same alignment; the normal error is the bi-directional angle between each "
        "vertex's normal and the other surface's at its closest point "
        "(`monoavatar.eval.compare_surfaces`). Regions are ground-truth vertex sets: the face "
        "(skin of the head in front of the ears), the garments (top and bottom), hair, and the "
        "rest of the skin; all subjects.",
        "",
        "| mode | whole | whole, similarity only | " + " | ".join(REGIONS) + " |",
        "|" + "---|" * (3 + len(REGIONS)),
    ]
    for name in names:
        a = agg.get(name, {}).get("all", {})
        if "normal_error_deg" not in a:
            continue
        cells = [f"{_fmt(a.get('surface_error_mm'))} / {_fmt(a.get('normal_error_deg'), 1)}",
                 f"{_fmt(a.get('surface_error_rigid_mm'))} / "
                 f"{_fmt(a.get('normal_error_rigid_deg'), 1)}"]  # fmt: skip
        for region in REGIONS:
            r = a.get("regions", {}).get(region, {})
            cells.append(f"{_fmt(r.get('surface_error_mm'))} / "
                         f"{_fmt(r.get('normal_error_deg'), 1)}")  # fmt: skip
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "## Other measures",
        "",
        "Rigid only: the surface error after the similarity alignment alone, without the "
        "articulated pose alignment (a canonical pose that differs from the truth's, e.g. "
        "arms held 5° higher, then counts as shape error). "
        "Body only: the fitted body with its offsets removed (same alignment protocol). "
        "Shape-only baseline: a body fitted without offsets, when the reconstruction reports "
        "one. PA-MPJPE: fitted vs true skeleton joints at the key-frames. IoU: posed avatar vs "
        "exact masks at the key-frames. PSNR: the textured avatar (as reconstructed, never "
        "changed) in the held-out frames, posed there by our tracker (the key-frames' poses "
        "interpolated in time, then refined by flow rounds from the avatar's render to the "
        "held-out frame, its outline and its perception: only the poses are fitted), vs the "
        "frame, on the true person mask (on pixels covered by both in brackets). PSNR ∪: the "
        "same renders on the pixels of the person or the avatar (spilled avatar pixels count "
        "against the frame's background, as missed person pixels count against grey). "
        "Interpolated: the key-frames' poses interpolated alone (no held-out image used). True "
        "poses: the true joint rotations of the frame transferred onto the avatar's skeleton "
        "(applied on top of the canonical pose the surface alignment found, and placed by "
        "it; results.json also holds texture_psnr_rigid_db, without the aligned canonical "
        "pose). Missed: the "
        "share of true person pixels the held-out renders do not cover, and (after the slash) "
        "the share of the PSNR's squared error that lies on them. Root: the angle between the "
        "fitted and the true root (pelvis) orientation at the key-frames in camera axes "
        "(PA-MPJPE cannot see a body facing the wrong way): the mean of the subjects' "
        "medians, in brackets the worst key-frame and how many key-frames are more than "
        f"{ROOT_OFF_DEG:.0f}° off.",
        "",
        "| mode | subjects | surface (mm) | rigid only (mm) | body only (mm) | "
        "shape-only baseline (mm) | PA-MPJPE (mm) | silhouette IoU | texture PSNR (dB) | "
        "PSNR ∪ (dB) | PSNR, interpolated (dB) | PSNR, true poses (dB) | "
        "missed (% px / % error) | root (°) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for mode in results.modes:
        for g in groups:
            a = agg.get(mode.name, {}).get(g)
            if not a:
                continue
            psnr = _fmt(a.get("texture_psnr_db"), 1)
            if a.get("texture_psnr_overlap_db") is not None:
                psnr += f" ({_fmt(a.get('texture_psnr_overlap_db'), 1)})"
            missed = "–"
            frac, share = a.get("texture_missed_fraction"), a.get("texture_missed_error_share")
            if frac is not None and share is not None:
                missed = f"{100 * frac:.1f} / {100 * share:.0f}"
            root = _fmt(a.get("root_error_deg"), 1)
            if a.get("root_error_max_deg") is not None:
                root += f" ({_fmt(a.get('root_error_max_deg'), 1)}, {a.get('root_off_frames', 0)})"
            lines.append(
                f"| {mode.label} | {_group_label(g)} | {_pm(a)} | "
                f"{_fmt(a.get('surface_error_rigid_mm'))} | "
                f"{_fmt(a.get('body_only_error_mm'))} | {_fmt(a.get('shape_only_error_mm'))} | "
                f"{_fmt(a.get('pa_mpjpe_mm'), 1)} | {_fmt(a.get('silhouette_iou'), 3)} | {psnr} | "
                f"{_fmt(a.get('texture_psnr_union_db'), 1)} | "
                f"{_fmt(a.get('texture_psnr_interpolated_db'), 1)} | "
                f"{_fmt(a.get('texture_psnr_true_poses_db'), 1)} | {missed} | {root} |"
            )

    held = []
    for mode in results.modes:
        a = agg.get(mode.name, {}).get("all") or {}
        if a.get("heldout_pa_mpjpe_mm") is not None:
            held.append(f"{mode.label} {_fmt(a.get('heldout_pa_mpjpe_mm'), 1)} mm and "
                        f"{_fmt(a.get('heldout_root_error_deg'), 1)}° (interpolated "
                        f"{_fmt(a.get('heldout_pa_mpjpe_interpolated_mm'), 1)} mm and "
                        f"{_fmt(a.get('heldout_root_error_interpolated_deg'), 1)}°)")  # fmt: skip
    if held:
        lines += [
            "",
            "The tracker's held-out poses against the truth's (all subjects: PA-MPJPE of the "
            "joints, and the median root orientation error as in the root column): "
            + "; ".join(held) + ".",
        ]

    rt = PUBLISHED["runtime"]
    lines += [
        "",
        "## Runtime (seconds per subject, mean) and memory",
        "",
        f"Dissertation: {rt['note']}, i.e. about K + 1.8 min for K key-frames.",
        "",
        "| mode | key-frames | " + " | ".join(STAGES) + " | total | per key-frame | "
        "peak memory (MB) | dissertation for K frames |",
        "|" + "---|" * (len(STAGES) + 6),
    ]
    for mode in results.modes:
        a = agg.get(mode.name, {}).get("all")
        if not a or "keyframes" not in a:
            continue
        k = a["keyframes"] or 0.0
        total = a.get("wall_seconds")
        per = None if total is None or not k else total / k
        minutes = k * rt["pose_min_per_frame"] + rt["shape_min"]
        stages = " | ".join(_fmt(a["timings_s"].get(s), 1) for s in STAGES)
        lines.append(
            f"| {mode.label} | {k:.0f} | {stages} | {_fmt(total, 1)} | {_fmt(per, 2)} | "
            f"{_fmt(a.get('peak_rss_mb'), 0)} | ≈ {minutes:.0f} min |"
        )
    tracking = [(m.label, agg.get(m.name, {}).get("all", {}).get("heldout_track_seconds"))
                for m in results.modes]  # fmt: skip
    if any(t is not None for _, t in tracking):
        lines += [
            "",
            "Not part of the reconstruction: the tracker that poses the avatar in the held-out "
            "frames for the PSNR (perception included), seconds per subject: "
            + ", ".join(f"{label} {_fmt(t, 1)}" for label, t in tracking if t is not None)
            + ".",
        ]

    lines += [
        "",
        "## Per subject",
        "",
        "| subject | clothing | mode | surface (mm) | rigid only (mm) | body only (mm) | "
        "rest bones, median / worst (°) | PA-MPJPE (mm) | IoU | PSNR (dB) | "
        "PSNR, true poses (dB) | time (s) | heat map |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results.runs:
        s = r.subject
        if r.status != "ok" or r.metrics is None:
            lines.append(f"| {s.name} | {s.clothing} | {r.mode} | failed: "
                         f"{(r.error or '').splitlines()[0][:80] if r.error else ''} "
                         "| | | | | | | | | |")  # fmt: skip
            continue
        mt = r.metrics
        bones = mt.surface.bone_angles_deg
        bone_cell = ("–" if bones is None else
                     f"{np.nanmedian(bones):.1f} / {np.nanmax(bones):.1f}")  # fmt: skip
        heat = "–"
        if r.heatmap_png is not None:
            try:
                heat = f"[png]({r.heatmap_png.relative_to(results.out_dir)})"
            except ValueError:
                heat = f"[png]({r.heatmap_png})"
        lines.append(
            f"| {s.name} | {s.clothing} | {r.mode} | {mt.surface.mean_mm:.2f} ± "
            f"{mt.surface.std_mm:.2f} | {_fmt(mt.surface.rigid_mean_mm)} | "
            f"{_fmt(mt.body_only_mm)} | {bone_cell} | {mt.pa_mpjpe_mm:.1f} | "
            f"{mt.silhouette_iou:.3f} | {_fmt(mt.psnr_db, 1)} | "
            f"{_fmt(mt.psnr_true_poses_db, 1)} | {r.wall_seconds:.0f} | {heat} |"
        )
    lines.append("")
    return "\n".join(lines)


# -- heat maps ----------------------------------------------------------------------------------


def render_heatmap(heat: HeatMap, size: int = 480, max_error: float = 0.02,
                   title: str = "") -> np.ndarray:  # fmt: skip
    """Front and back views of the error-coloured avatar, side by side, with a colour bar
    (blue 0 mm → red ≥ ``max_error``). Returns (H, W, 3) uint8."""
    import torch

    from monoavatar.core.camera import PinholeCamera
    from monoavatar.eval import error_to_rgb
    from monoavatar.render import interpolate, rasterize, vertex_normals

    v = np.asarray(heat.vertices, dtype=np.float64)
    faces = torch.as_tensor(np.asarray(heat.faces, dtype=np.int64))
    colours = torch.as_tensor(error_to_rgb(heat.errors, max_error))
    normals = vertex_normals(torch.as_tensor(v), faces)
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = 0.5 * (lo + hi)
    extent = float(max(hi[1] - lo[1], hi[0] - lo[0], 1e-6))
    distance = 4.0 * extent
    focal = 0.88 * size * (distance - 0.5 * float(hi[2] - lo[2])) / extent
    views = []
    for side in (1.0, -1.0):  # front (the body faces +Z), back
        eye = centre + np.array([0.0, 0.0, side * distance])
        cam = PinholeCamera.look_at(eye, centre, np.array([0.0, 1.0, 0.0]), focal, size, size)
        frags = rasterize(v, faces, cam)
        col = interpolate(colours, faces, frags, fill=1.0)
        nrm = interpolate(normals, faces, frags)
        nrm = nrm / nrm.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        light = (0.45 + 0.55 * (nrm[..., 2] * side).abs()).unsqueeze(-1)
        img = torch.where(frags.mask.unsqueeze(-1), col * light, torch.ones_like(col))
        views.append((img.numpy().clip(0, 1) * 255 + 0.5).astype(np.uint8))
    body = np.concatenate(views, axis=1)
    bar_h, pad = 18, 30
    canvas = Image.new("RGB", (body.shape[1], body.shape[0] + bar_h + 2 * pad + 20), "white")
    canvas.paste(Image.fromarray(body), (0, 20))
    ramp = error_to_rgb(np.linspace(0.0, max_error, body.shape[1] - 80), max_error)
    bar = (np.repeat(ramp[None], bar_h, axis=0) * 255 + 0.5).astype(np.uint8)
    top = body.shape[0] + 20 + pad // 2
    canvas.paste(Image.fromarray(bar), (40, top))
    draw = ImageDraw.Draw(canvas)
    draw.text((4, 4), title, fill=(0, 0, 0))
    draw.text((4, top + 2), "0", fill=(0, 0, 0))
    draw.text((body.shape[1] - 38, top + 2), f"{max_error * 1000:g}+", fill=(0, 0, 0))
    draw.text((body.shape[1] // 2 - 40, top + bar_h + 2), "error (mm)  front | back",
              fill=(0, 0, 0))  # fmt: skip
    return np.asarray(canvas)


def write_heatmap(heat: HeatMap, png: Path, ply: Path, title: str = "") -> None:
    """Write the heat-map image and the vertex-coloured PLY mesh of one run."""
    from monoavatar.eval import write_heatmap_ply

    png.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(render_heatmap(heat, title=title)).save(png)
    write_heatmap_ply(ply, heat.vertices, heat.faces, heat.errors)


# -- files --------------------------------------------------------------------------------------


def write_results(results: BenchResults) -> dict[str, Path]:
    """(Re)compute the aggregate and write ``results.json`` and ``results.md`` atomically."""
    results.aggregate = aggregate(results.runs, results.modes)
    results.table = render_markdown(results)
    out = results.out_dir
    out.mkdir(parents=True, exist_ok=True)
    files = {"results.json": out / "results.json", "results.md": out / "results.md"}
    payloads = {
        "results.json": json.dumps(results.to_dict(), indent=2, allow_nan=False),
        "results.md": results.table,
    }
    for name, text in payloads.items():
        tmp = files[name].with_name(f".{name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, files[name])
    results.files.update(files)
    return files


def utc_now() -> str:
    """The current time, ISO 8601, UTC, seconds."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
