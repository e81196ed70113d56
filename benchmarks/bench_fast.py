"""Few-frame reconstruction (Paper D, Table D.1): ``reconstruct --fast`` from 1, 2, 4 and 8
frames of each benchmark-suite turn-around, against the full fit (``reconstruct``) from the
same 8 frames; surface error with the dissertation's protocol (after pose and scale
alignment, and after a similarity alone) and seconds per stage.

The suite's subjects are drawn by ``synth`` from their own seeds, a stream the training
subjects of ``train fast`` never use (those come from ``(seed, 11)``-seeded generators), so
this is a test on unseen people. Frames are spread evenly over the turn; ``--perception``
``auto`` uses the scene's exact masks and keypoints, ``mediapipe`` perceives them.

Run: ``python benchmarks/bench_fast.py --out DIR [--frames 1 2 4 8] [--full 8]
[--perception auto] [--weights FILE] [--subjects NAME ...]``; ``OMP_NUM_THREADS=2``.
"""

from __future__ import annotations

import argparse
import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from monoavatar.bench.ground_truth import ground_truth_error
from monoavatar.bench.suite import FULL_SUBJECTS, ensure_scene
from monoavatar.body import load_body_model
from monoavatar.fit.shape import CanonicalShape
from monoavatar.pipelines.fast import FastConfig, fast_reconstruct
from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
from monoavatar.pipelines.stages import InputSettings


def _row(name: str, method: str, frames: int, result, body) -> dict:  # type: ignore[no-untyped-def]
    gt = ground_truth_error(body, result.shape, result.inputs.ground_truth)
    return {"subject": name, "method": method, "frames": frames,
            "surface_mm": gt.surface_error_mm, "similarity_mm": gt.surface_error_rigid_mm,
            "seconds": result.report.seconds,
            "timings": {k: round(v, 2) for k, v in result.report.timings.items()}}  # fmt: skip


def _average(name: str, scene: Path, body) -> dict:  # type: ignore[no-untyped-def]
    """The reference a network must beat: Anny's average body, no offsets."""
    from monoavatar.datasets.synth_scene import read_synth_scene

    truth = read_synth_scene(scene).ground_truth
    beta = body.default_shape()[0]
    with torch.no_grad():
        rest, _ = body.rest_shape(beta[None])
    shape = CanonicalShape(shape=beta, offsets=torch.zeros_like(rest[0]), vertices=rest[0],
                           faces=body.faces, frames=np.zeros(0, int),
                           frame_shifts=np.zeros((0, 3)))  # fmt: skip
    gt = ground_truth_error(body, shape, truth)
    return {"subject": name, "method": "average body", "frames": 0,
            "surface_mm": gt.surface_error_mm, "similarity_mm": gt.surface_error_rigid_mm,
            "seconds": 0.0, "timings": {}}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, nargs="*", default=[1, 2, 4, 8])
    ap.add_argument("--full", type=int, nargs="*", default=[8],
                    help="frame counts for the full fit (none: skip it)")
    ap.add_argument("--perception", default="auto", choices=("auto", "mediapipe"))
    ap.add_argument("--weights", default=None)
    ap.add_argument("--subjects", nargs="*", default=None)
    ap.add_argument("--tag", default="all", help="name of this run's results file")
    args = ap.parse_args()
    out = args.out
    subjects = [s for s in FULL_SUBJECTS if not args.subjects or s.name in args.subjects]
    body = load_body_model("anny")
    rows: list[dict] = []
    results = out / f"results-{args.perception}-{args.tag}.json"
    for subject in subjects:
        scene = ensure_scene(subject, out / "scenes")
        rows.append(_average(subject.name, scene, body))
        print(json.dumps(rows[-1]), flush=True)
        for f in args.frames:
            config = FastConfig(input=InputSettings(frames=f, perception=args.perception),
                                weights=args.weights, progress=False)  # fmt: skip
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = fast_reconstruct(scene, out / "runs" / f"{subject.name}-fast{f}", config)
            rows.append(_row(subject.name, "fast", f, res, body))
            print(json.dumps(rows[-1]), flush=True)
        for f in args.full:
            base = ReconstructConfig()
            config = replace(base, input=replace(base.input, frames=f,
                                                 perception=args.perception), progress=False)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                full = reconstruct(scene, out / "runs" / f"{subject.name}-full{f}", config)
            rows.append(_row(subject.name, "full", f, full, body))
            print(json.dumps(rows[-1]), flush=True)
        results.write_text(json.dumps(rows, indent=1))
    print("\n| method | frames | after pose + scale (mm) | after similarity (mm) | seconds |")
    print("|---|---|---|---|---|")
    for method, f in sorted({(r["method"], r["frames"]) for r in rows}):
        sel = [r for r in rows if r["method"] == method and r["frames"] == f]
        mean = {k: float(np.mean([r[k] for r in sel])) for k in ("surface_mm", "similarity_mm",
                                                                   "seconds")}  # fmt: skip
        print(f"| {method} | {f} | {mean['surface_mm']:.2f} | {mean['similarity_mm']:.2f} "
              f"| {mean['seconds']:.1f} |")


if __name__ == "__main__":
    main()
