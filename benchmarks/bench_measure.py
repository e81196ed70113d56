"""Body measurements (``monoavatar measure``) against the truth, on ``monoavatar synth``
turn-around scenes reconstructed with ``reconstruct``'s defaults, estimated poses and the
person's height given (the true body's height, as a user would type theirs).

The truth is measured with the same definitions on the generating body model under the clothes
and on the clothed canonical mesh, with trimesh's plane sections and ray casts
(:mod:`monoavatar.bench.measure`). Reported per measurement: the mean absolute error and the
mean signed error (bias) over the subjects, for the body under the clothes and for the clothed
surface; and, as a baseline that uses no image at all, the average body of the model scaled to
the given height.

Subjects: ``--split tune`` (seeds 1, 2, 4, 5, 6, 8: the ones the definitions were looked at on) or
``--split report`` (the nine subjects of the benchmark suite). Scenes are generated into
``--scenes`` and avatars reconstructed into ``--recon`` on first use (about 2.5 minutes a
subject on 2 cores).

Run: ``OMP_NUM_THREADS=2 python benchmarks/bench_measure.py --split report --scenes S
--recon R --out DIR``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from monoavatar.bench.measure import ground_truth_measurements
from monoavatar.bench.suite import FULL_SUBJECTS, BenchSubject, ensure_scene
from monoavatar.body import BodyModel, load_body_model
from monoavatar.datasets.synth_scene import read_synth_scene
from monoavatar.measure import MEASUREMENTS, measure_mesh, vertex_parts
from monoavatar.pipelines.measure import MeasureConfig, measure_folder
from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
from monoavatar.pipelines.stages import InputSettings

TUNE = (BenchSubject("tune-tshirt-shorts-s1", "clothed", 1, "tshirt-shorts"),
        BenchSubject("tune-minimal-s2", "minimal", 2, "minimal"),
        BenchSubject("tune-longsleeve-trousers-s4", "clothed", 4, "longsleeve-trousers"),
        BenchSubject("tune-loose-s5", "clothed", 5, "loose"),
        BenchSubject("tune-skirt-s6", "clothed", 6, "skirt"),
        BenchSubject("tune-tight-s8", "clothed", 8, "tight"))


def _avatar(subject: BenchSubject, scene: Path, recon: Path, height: float) -> Path:
    out = recon / subject.name
    if not (out / "params.npz").is_file():
        base = ReconstructConfig()
        config = ReconstructConfig(input=InputSettings(frames=subject.keyframes),
                                   progress=False, pose=replace(base.pose, height=height),
                                   texture=replace(base.texture, size=256))  # fmt: skip
        reconstruct(scene, out, config)
    return out


def _average_body(body: BodyModel, height: float) -> dict[str, float]:
    """Measurements of the model's average body scaled to ``height``, metres."""
    with torch.no_grad():
        v, j = body.rest_shape(body.default_shape())
    v, j = v[0].double().numpy(), j[0].double().numpy()
    s = height / float(np.ptp(v[:, 1]))
    parts = vertex_parts(body.skin_weights.double().numpy(), body.joint_names)
    m = measure_mesh(v * s, body.faces.numpy(), parts, j * s, body.joint_names)
    return {name: m[name].value for name in MEASUREMENTS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("tune", "report"), required=True)
    ap.add_argument("--scenes", type=Path, required=True)
    ap.add_argument("--recon", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    subjects = TUNE if args.split == "tune" else FULL_SUBJECTS
    local = load_body_model("anny-local")
    anny = load_body_model("anny")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for subject in subjects:
        start = time.perf_counter()
        scene = ensure_scene(subject, args.scenes, body=local)
        truth = read_synth_scene(scene).ground_truth
        gt = ground_truth_measurements(truth, local)
        height = gt["body"]["height"].value
        folder = _avatar(subject, scene, args.recon, height)
        ours = measure_folder(folder, args.out / f"{subject.name}.json").values
        clamp = measure_folder(folder, args.out / f"{subject.name}-clamp.json",
                               MeasureConfig(under="clamp", picture=False)).values
        rows.append({
            "subject": subject.name, "clothing": subject.clothing, "height_m": height,
            "truth": {k: {n: gt[k][n].value for n in MEASUREMENTS} for k in gt},
            "ours": {k: {n: ours[n][k] for n in MEASUREMENTS} for k in ("body", "clothed")},
            "clamp": {"body": {n: clamp[n]["body"] for n in MEASUREMENTS}},
            "average_body": _average_body(anny, height),
        })  # fmt: skip
        print(f"{subject.name}: {time.perf_counter() - start:.0f} s", flush=True)
    summary = {}
    for name in MEASUREMENTS:
        def err(kind: str, source: str, name: str = name) -> np.ndarray:
            value = (lambda r: r[source][name]) if source == "average_body" else (
                lambda r: r[source][kind][name])
            return np.array([np.nan if value(r) is None else value(r) - r["truth"][kind][name]
                             for r in rows], float)  # fmt: skip

        summary[name] = {
            "body_mae_cm": 100 * float(np.nanmean(np.abs(err("body", "ours")))),
            "body_bias_cm": 100 * float(np.nanmean(err("body", "ours"))),
            "clamp_body_mae_cm": 100 * float(np.nanmean(np.abs(err("body", "clamp")))),
            "clothed_mae_cm": 100 * float(np.nanmean(np.abs(err("clothed", "ours")))),
            "clothed_bias_cm": 100 * float(np.nanmean(err("clothed", "ours"))),
            "average_body_mae_cm": 100 * float(np.nanmean(np.abs(err("body", "average_body")))),
            "truth_body_mean_cm": 100 * float(np.mean([r["truth"]["body"][name] for r in rows])),
        }
    (args.out / "results.json").write_text(json.dumps({"split": args.split, "subjects": rows,
                                                       "summary": summary}, indent=2))
    lines = ["| measurement | truth (body), cm | body MAE | body bias | body MAE, clamp | "
             "clothed MAE | clothed bias | average body MAE |", "|---|---|---|---|---|---|---|---|"]
    for name, s in summary.items():
        lines.append(f"| {name} | {s['truth_body_mean_cm']:.1f} | {s['body_mae_cm']:.2f} | "
                     f"{s['body_bias_cm']:+.2f} | {s['clamp_body_mae_cm']:.2f} | "
                     f"{s['clothed_mae_cm']:.2f} | {s['clothed_bias_cm']:+.2f} | "
                     f"{s['average_body_mae_cm']:.2f} |")
    girths = ["chest", "waist", "hip", "neck", "upper_arm", "thigh", "calf"]
    for key, label in (("body_mae_cm", "body (fit)"), ("clamp_body_mae_cm", "body (clamp)"),
                       ("clothed_mae_cm", "clothed"), ("average_body_mae_cm", "average body")):
        lines.append(f"\nmean girth MAE, {label}: "
                     f"{np.mean([summary[g][key] for g in girths]):.2f} cm")
    (args.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
