"""The tracking benchmark (Paper A, Table A.1): ``monoavatar track`` on the suite's motion
sequences, ``synth walk`` and ``synth jog`` scenes from fixed seeds, with mediapipe perception
on the rendered frames.

Per sequence: the mean error of 14 joints (:data:`~monoavatar.pipelines.track.EVAL_JOINTS`)
after a similarity per frame (local) and one per sequence (global), the acceleration error,
and seconds per frame (perception included). The seeds are the sealed test split
(``docs/decisions.md``): settings are never chosen by looking at these figures.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

__all__ = ["MOTION_SEQUENCES", "QUICK_SEQUENCES", "TABLE_A1", "MotionSequence",
           "render_tracking_markdown", "run_tracking_bench"]  # fmt: skip

TABLE_A1: dict[str, dict[str, float]] = {
    "walk": {"local_cm": 5.5, "global_cm": 7.6},
    "jog": {"local_cm": 7.9, "global_cm": 9.9},
}
"""The dissertation's Table A.1 (HumanEva-I Walking C1 and Jog C2, 13 joints), centimetres."""


@dataclass(frozen=True)
class MotionSequence:
    """A suite motion sequence: ``kind`` (walk | jog), its seed, frames and image size."""

    kind: str
    seed: int
    frames: int = 120
    size: int = 540

    @property
    def name(self) -> str:
        return f"{self.kind}-s{self.seed}"


MOTION_SEQUENCES: tuple[MotionSequence, ...] = (
    MotionSequence("walk", 101), MotionSequence("walk", 102),
    MotionSequence("jog", 201), MotionSequence("jog", 202),
)  # fmt: skip
QUICK_SEQUENCES: tuple[MotionSequence, ...] = (MotionSequence("walk", 101, frames=24),)


def _scene(sequence: MotionSequence, scenes: Path, progress: bool) -> Path:
    from monoavatar.synth.scene import SynthConfig, generate

    folder = scenes / sequence.name
    config = SynthConfig(kind=sequence.kind, frames=sequence.frames, seed=sequence.seed,
                         width=sequence.size, height=sequence.size)  # fmt: skip
    description = folder / "scene.json"
    if description.is_file():
        from dataclasses import asdict

        if json.loads(description.read_text()).get("config") == asdict(config):
            return folder
        shutil.rmtree(folder)
    generate(folder, config, progress=progress)
    return folder


def run_tracking_bench(out_dir: str | Path, *, quick: bool = False, progress: bool = True,
                       scenes_dir: str | Path | None = None) -> dict[str, Any]:  # fmt: skip
    """Track each motion sequence and write ``tracking.json`` and ``tracking.md`` into
    ``out_dir``. A failing sequence is recorded with its error and the others go on."""
    from monoavatar.datasets.synth_scene import stated_height
    from monoavatar.pipelines.track import TrackConfig, track

    out = Path(out_dir)
    scenes = Path(scenes_dir) if scenes_dir is not None else out / "scenes"
    rows: list[dict[str, Any]] = []
    for sequence in QUICK_SEQUENCES if quick else MOTION_SEQUENCES:
        scene = _scene(sequence, scenes, progress)
        info = json.loads((scene / "scene.json").read_text())
        config = TrackConfig(progress=progress)
        config.input = replace(config.input, perception="mediapipe")  # track's own otherwise
        config.track.pose.height = stated_height(info)
        folder = out / "tracking" / sequence.name
        if folder.exists():
            shutil.rmtree(folder)
        row: dict[str, Any] = {"sequence": sequence.name, "kind": sequence.kind,
                               "frames": sequence.frames}  # fmt: skip
        t0 = time.perf_counter()
        try:
            result = track(scene, folder, config)
        except Exception as exc:  # noqa: BLE001 - recorded, the benchmark goes on
            row["error"] = f"{type(exc).__name__}: {exc}"
        else:
            gt = result.report["ground_truth"]
            row.update(local_mm=gt["local_mm"], global_mm=gt["global_mm"],
                       acceleration_mm_per_frame2=gt["acceleration_mm_per_frame2"],
                       seconds_per_frame=(time.perf_counter() - t0) / sequence.frames,
                       failed_frames=result.report["frames_failed"],
                       timings=result.report["timings"])  # fmt: skip
        rows.append(row)
    results = {"format": "monoavatar-bench-tracking-1", "sequences": rows,
               "published": TABLE_A1}  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    (out / "tracking.json").write_text(json.dumps(results, indent=2))
    (out / "tracking.md").write_text(render_tracking_markdown(rows))
    return results


def _mean(rows: list[dict[str, Any]], key: str) -> float | None:
    values = [r[key] for r in rows if key in r]
    return sum(values) / len(values) if values else None


def render_tracking_markdown(rows: list[dict[str, Any]]) -> str:
    """The tracking table: per sequence and per kind, with Table A.1 beside it (cm)."""

    def cm(value: float | None) -> str:
        return "—" if value is None else f"{value / 10:.1f}"

    lines = ["| sequence | local cm | global cm | accel. mm/frame² | s/frame | "
             "Table A.1 local / global cm |", "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        ref = TABLE_A1[r["kind"]]
        if "error" in r:
            lines.append(f"| {r['sequence']} | failed: {r['error']} | | | | |")
            continue
        lines.append(f"| {r['sequence']} | {cm(r['local_mm'])} | {cm(r['global_mm'])} | "
                     f"{r['acceleration_mm_per_frame2']:.1f} | {r['seconds_per_frame']:.2f} | "
                     f"{ref['local_cm']} / {ref['global_cm']} |")  # fmt: skip
    for kind in ("walk", "jog"):
        group = [r for r in rows if r["kind"] == kind and "error" not in r]
        if group:
            ref = TABLE_A1[kind]
            accel = _mean(group, "acceleration_mm_per_frame2")
            lines.append(f"| **{kind}, mean** | **{cm(_mean(group, 'local_mm'))}** | "
                         f"**{cm(_mean(group, 'global_mm'))}** | {accel:.1f} | "
                         f"{_mean(group, 'seconds_per_frame'):.2f} | "
                         f"{ref['local_cm']} / {ref['global_cm']} |")  # fmt: skip
    return "\n".join(lines) + "\n"
