"""Consensus shape (Sec. B.3.3) on synthetic turn-arounds with ground-truth poses: accuracy with
and without offsets, time and memory, and per-vertex error heat maps (Fig. B.6 style).

Run::

    python benchmarks/bench_shape.py /work/scenes/turn0 /work/scenes/turn1 --out bench_out

For each scene (a ``monoavatar synth turnaround`` folder) the fit gets the scene's masks,
camera and ground-truth poses, translations and phenotype shape parameters (the first 6 of the
subject's Anny-with-local-changes parameters), and reconstructs with plain Anny + offsets. The
error is :func:`monoavatar.eval.surface_error_after_alignment` between the fitted canonical
mesh and the ground-truth clothed canonical mesh (mean bi-directional vertex-to-surface
distance after a similarity alignment), in millimetres. ``--transforms`` poses with the
ground-truth skeleton's joint transforms instead of the ground-truth poses on Anny's own
skeleton (whose joints sit centimetres away from the local-changes model's), which isolates
the shape step from skeleton mismatch.

The heat map (blue 0 mm → red ≥ 20 mm) colours each vertex of the aligned reconstruction by
its distance to the ground-truth surface, rendered from the front and the back.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def render_heatmap(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Front and back views (side by side) of a Y-up, +Z-facing mesh with per-vertex colours,
    lightly shaded by the normals. Returns (H, 2W, 3) uint8."""
    from monoavatar.core.camera import PinholeCamera
    from monoavatar.render import interpolate, rasterize, vertex_normals

    width, height = 400, 600
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    extent = float(np.ptp(vertices[:, 1]))
    distance = 3.0
    focal = 0.9 * height * distance / extent
    faces_t = torch.as_tensor(faces)
    normals = vertex_normals(torch.as_tensor(vertices), faces_t)
    colours = torch.as_tensor(colors)
    views = []
    for side in (1.0, -1.0):
        eye = centre + np.array([0.0, 0.0, side * distance])
        camera = PinholeCamera.look_at(eye, centre, np.array([0.0, 1.0, 0.0]), focal, width, height)
        fragments = rasterize(vertices, faces, camera)
        rgb = interpolate(colours, faces_t, fragments, fill=1.0).numpy()
        n = interpolate(normals, faces_t, fragments).numpy()
        shade = 0.55 + 0.45 * np.abs(n[..., 2:3])
        views.append(np.where(fragments.mask.numpy()[..., None], rgb * shade, 1.0))
    return (np.clip(np.hstack(views), 0.0, 1.0) * 255).round().astype(np.uint8)


def run_scene(folder: Path, args: argparse.Namespace) -> dict[str, object]:
    from PIL import Image

    from monoavatar.body import load_body_model
    from monoavatar.datasets.synth_scene import read_synth_scene
    from monoavatar.eval import error_to_rgb, surface_error_after_alignment
    from monoavatar.fit.shape import ShapeSettings, fit_consensus_shape

    scene = read_synth_scene(folder)
    gt = scene.ground_truth
    body = load_body_model("anny")
    transforms = None
    if args.transforms:
        name = "anny-local" if "local_changes=all" in gt.body_model else "anny"
        transforms = gt.body_output(load_body_model(name)).transforms
    gt_mesh = gt.canonical_mesh(0)
    settings = ShapeSettings(max_frames=args.max_frames)
    runs = [("offsets", settings)]
    if not args.no_baseline:
        runs.append(("shape-only", replace(settings, fit_offsets=False)))
    out: dict[str, object] = {
        "scene": str(folder),
        "frames": len(gt.poses),
        "clothing": [s.get("clothing") for s in scene.info["subjects"]],
    }
    faces = body.faces.numpy()
    for label, s in runs:
        rss0 = _rss_mb()
        t0 = time.perf_counter()
        result = fit_consensus_shape(
            body,
            scene.observations.masks,
            scene.camera,
            gt.poses,
            gt.translations,
            gt.shapes[0][:6],
            s,
            transforms=transforms,
        )
        seconds = time.perf_counter() - t0
        rss1 = _rss_mb()
        vertices = result.vertices.double().numpy()
        t1 = time.perf_counter()
        error = surface_error_after_alignment(
            (vertices, faces), gt_mesh, icp_iterations=args.icp_iterations
        )
        out[label] = {
            "error_mm": error.error.mean_mm,
            "pred_to_gt_mm": 1000 * error.error.pred_to_gt_mean,
            "gt_to_pred_mm": 1000 * error.error.gt_to_pred_mean,
            "fit_seconds": seconds,
            "metric_seconds": time.perf_counter() - t1,
            "peak_rss_mb": rss1,
            "rss_growth_mb": rss1 - rss0,
            "rounds": [d.median_distance_mm for d in result.diagnostics],
        }
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            colours = error_to_rgb(error.error.pred_to_gt)
            image = render_heatmap(error.aligned_pred_vertices, faces, colours)
            path = args.out / f"{folder.name}_{label}_heatmap.png"
            Image.fromarray(image).save(path)
            out[label]["heatmap"] = str(path)  # type: ignore[index]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("scenes", nargs="+", type=Path, help="synthetic turn-around folders")
    parser.add_argument(
        "--transforms",
        action="store_true",
        help="pose with the ground-truth skeleton's joint transforms",
    )
    parser.add_argument("--max-frames", type=int, default=None, help="key frames (all)")
    parser.add_argument("--no-baseline", action="store_true", help="skip the shape-only fit")
    parser.add_argument(
        "--icp-iterations",
        type=int,
        default=100,
        help="ICP iterations of the metric's alignment (100 = the protocol)",
    )
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    parser.add_argument("--out", type=Path, default=None, help="folder for heat maps + JSON")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    results = []
    print(
        f"{'scene':>10} {'run':>10} {'error mm':>9} {'p→gt':>6} {'gt→p':>6} "
        f"{'fit s':>6} {'peak MB':>8} {'+MB':>6}"
    )
    for folder in args.scenes:
        res = run_scene(folder, args)
        results.append(res)
        for label in ("offsets", "shape-only"):
            r = res.get(label)
            if isinstance(r, dict):
                print(
                    f"{folder.name:>10} {label:>10} {r['error_mm']:9.2f} "
                    f"{r['pred_to_gt_mm']:6.2f} {r['gt_to_pred_mm']:6.2f} "
                    f"{r['fit_seconds']:6.1f} {r['peak_rss_mb']:8.0f} "
                    f"{r['rss_growth_mb']:6.0f}",
                    flush=True,
                )
    if args.out is not None:
        (args.out / "bench_shape.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
