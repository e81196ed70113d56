"""Photo (Paper E): is the fitted body wider where the subject is clothed?

Reads a ``monoavatar bench --photo --split dev`` output folder (never a sealed split) and, per
photo, compares the fitted six-phenotype body with the subject's true six-phenotype body (same
topology, so vertex to vertex) after a similarity that carries the fitted onto the true one:
the mean signed offset along the true body's vertex normals of the fitted body (``fitted``) and
of the clothed truth (``truth``: garments, hair and the 256 local shape changes), over skin
vertices and over clothed ones (top and bottom), mm, and their per-vertex correlation; then the
benchmark's surface error (after pose and scale alignment, mm) of the predicted maps on the
*true* body, beside the true body alone: what a perfect shape fit would give the maps. Run::

    python benchmarks/bench_photo_fit_bias.py out/bench_photo_dev
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from monoavatar.bench.metrics import Rig, surface_metrics
from monoavatar.body import load_body_model
from monoavatar.core.geometry import vertex_normals
from monoavatar.eval.alignment import align_similarity
from monoavatar.learn.photo_data import base_fine_vertices, photo_rng
from monoavatar.learn.uvmaps import sample_vertex_values, uv_layout
from monoavatar.synth.subjects import build_subject, sample_subject


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bench", type=Path, help="a 'bench --photo --split dev' output folder")
    args = parser.parse_args()
    local, body = load_body_model("anny-local"), load_body_model("anny")
    layout = uv_layout(body, 256)
    faces = layout.subdivision.faces.numpy()
    print("| photo | clothing | fitted: skin | fitted: clothed | truth: skin | truth: clothed "
          "| correlation | true body mm | true body + maps mm |\n|---|---|---|---|---|---|---|---|"
          "---|")  # fmt: skip
    for folder in sorted(args.bench.glob("photos/dev-*")):
        params = folder / "avatar" / "params.npz"
        if not params.is_file():
            continue
        seed = int(folder.name.split("-")[1])
        spec = sample_subject(photo_rng(seed), local)
        subject = build_subject(local, spec, 64)
        with np.load(params) as p:
            shape = p["shape"]
        with np.load(folder / "avatar" / "maps" / "displacement.npz") as d:
            displacement = sample_vertex_values(layout, d["displacement"])
        true_base = base_fine_vertices(body, layout, spec.shape[:6]).double().numpy()
        fitted = base_fine_vertices(body, layout, shape).double().numpy()
        a = align_similarity(fitted, true_base)
        fitted = a.scale * fitted @ a.rotation.T + a.translation
        truth = subject.rest_vertices.double().numpy()
        normals = vertex_normals(true_base, faces).double().numpy()
        w = 1000 * ((fitted - true_base) * normals).sum(1)
        t = 1000 * ((truth - true_base) * normals).sum(1)
        skin, cloth = subject.garment == 0, np.isin(subject.garment, (1, 2))
        both = skin | cloth
        with torch.no_grad():
            _, joints = body.rest_shape(torch.as_tensor(spec.shape[:6], dtype=body.dtype)[None])
        rig = Rig(layout.subdivision.weights.double().numpy(), joints[0].double().numpy(),
                  tuple(body.parents))  # fmt: skip
        alone, _ = surface_metrics(true_base, faces, truth, faces, rig=rig)
        mapped, _ = surface_metrics(true_base + displacement, faces, truth, faces, rig=rig)
        print(f"| {seed} | {spec.clothing} | {w[skin].mean():+.1f} | {w[cloth].mean():+.1f} | "
              f"{t[skin].mean():+.1f} | {t[cloth].mean():+.1f} | "
              f"{np.corrcoef(w[both], t[both])[0, 1]:+.2f} | {alone.mean_mm:.2f} | "
              f"{mapped.mean_mm:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
