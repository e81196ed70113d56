"""Photo oracles (Paper E): which part of the map target does the surface metric need?

For each photo of a split (the dev split by default: never a sealed one for this), the photo
pipeline runs as shipped, then its fitted six-phenotype body is given maps that are *exact* for
part of the truth, and each result is scored with the benchmark's metric (bi-directional
vertex-to-surface distance after pose and scale alignment, mm):

* ``body``: the fitted body alone, no maps;
* ``maps``: the shipped network's maps (what ``monoavatar photo`` gives);
* ``exact``: the exact training target (the subject's whole surface: its 256 local shape
  changes, garments and hair);
* ``exact_clothing``: garments and hair only, on the subject's six-phenotype body;
* ``exact_local``: the local shape changes only, no garments or hair;
* ``coverage_mean_thick``: where the subject is clothed, exactly, but with the mean thickness of
  its clothing everywhere (what a garment-coverage classifier could give at best);
* ``mean``: the mean target of ``--prior-subjects`` training subjects (what a network that
  learns nothing from its input answers);
* ``class_means``: per texel, the mean target of those training subjects *over the texels of
  the same garment class* (skin, top, bottom, hair, shoes), chosen by the subject's exact
  classes: what a network that only recognised each texel's garment class could give at best.

Every oracle map is made as the training targets are (``learn.uvmaps.displacement_targets``)
against the subject's true six-phenotype body, then added to the *fitted* body, so the fitter's
own shape error stays in every figure. Run::

    python benchmarks/bench_photo_oracles.py -o out/photo-oracles [--photos 12]
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from monoavatar.bench.metrics import Rig, surface_metrics
from monoavatar.body import BodyModel, load_body_model
from monoavatar.core.geometry import vertex_normals
from monoavatar.learn.photo_data import (
    PhotoDataSettings,
    PhotoScene,
    base_fine_vertices,
    photo_rng,
    render_photo,
)
from monoavatar.learn.photo_model import load_photo_network
from monoavatar.learn.shards import iter_seeds
from monoavatar.learn.uvmaps import (
    DISPLACEMENT_SCALE,
    UVLayout,
    displacement_targets,
    rasterise_vertex_values,
    sample_vertex_values,
)
from monoavatar.pipelines.photo import PhotoConfig, PhotoResult, photo

ORACLES = ("body", "maps", "exact", "exact_clothing", "exact_local", "coverage_mean_thick",
           "mean", "class_means")
CLASSES = 5  # synth.subjects.Subject.garment: skin, top, bottom, hair, shoes
#: Displacements (m) above this count as clothed for ``coverage_mean_thick``.
CLOTHED = 0.004


def class_priors(local_body: BodyModel, body: BodyModel, layout: UVLayout, count: int
                 ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The mean displacement map (S, S, 3) of ``count`` training subjects (seeds of the train
    split, drawn as ``render_photo`` draws them) and per garment class (CLASSES, S, S, 3),
    both in DISPLACEMENT_SCALE units; a class never seen at a texel falls back to the mean."""
    from monoavatar.synth.subjects import build_subject, sample_subject

    S = layout.size
    total = np.zeros((S, S, 3))
    per_class = np.zeros((CLASSES, S, S, 3))
    weight = np.zeros((CLASSES, S, S, 1))
    for seed in iter_seeds("train", count):
        spec = sample_subject(photo_rng(seed), local_body)
        subject = build_subject(local_body, spec, 64)
        base = base_fine_vertices(body, layout, np.asarray(spec.shape[:6]))
        disp = displacement_targets(layout, base, subject.rest_vertices.double())[..., :3]
        onehot = rasterise_vertex_values(layout, np.eye(CLASSES)[subject.garment])
        total += disp
        for k in range(CLASSES):
            per_class[k] += onehot[..., k : k + 1] * disp
            weight[k] += onehot[..., k : k + 1]
    mean = total / count
    seen = weight > 0.5
    per_class = np.where(seen, per_class / np.maximum(weight, 1e-9), mean[None])
    return mean.astype(np.float32), per_class.astype(np.float32)


def _score(scene: PhotoScene, result: PhotoResult, body: BodyModel, local_body: BodyModel,
           layout: UVLayout, priors: tuple[np.ndarray, np.ndarray], oracles: list[str]
           ) -> dict[str, float]:  # fmt: skip
    """Each oracle's surface error (mm) for one photo's ``scene`` and its ``photo`` result."""
    faces = layout.subdivision.faces.numpy()
    truth = scene.subject.rest_vertices.double().numpy()
    with torch.no_grad():
        _, joints = body.rest_shape(torch.as_tensor(result.track.shape, dtype=body.dtype)[None])
    rig = Rig(layout.subdivision.weights.double().numpy(), joints[0].double().numpy(),
              tuple(body.parents))  # fmt: skip
    fitted = base_fine_vertices(body, layout, result.track.shape).numpy()
    true_base = base_fine_vertices(body, layout, scene.subject.spec.shape[:6])

    def error(vertices: np.ndarray) -> float:
        return surface_metrics(vertices, faces, truth, faces, rig=rig)[0].mean_mm

    def exact_maps(surface: torch.Tensor) -> np.ndarray:
        """``surface`` (V, 3) as maps against the true base, added to the fitted body."""
        target = displacement_targets(layout, true_base, surface)
        return fitted + sample_vertex_values(layout, target[..., :3] * DISPLACEMENT_SCALE)

    normals = vertex_normals(true_base, layout.subdivision.faces).double()
    thickness = torch.as_tensor(scene.subject.displacement, dtype=torch.float64)
    with torch.no_grad():
        rest_local, _ = local_body.rest_shape(scene.subject.shape)
        fine_local = layout.subdivision.apply(rest_local)[0].double()
    clothed = thickness > CLOTHED
    flat = (clothed * thickness[clothed].mean())[:, None] * normals
    mean, per_class = priors
    onehot = rasterise_vertex_values(layout, np.eye(CLASSES)[scene.subject.garment])
    by_class = np.einsum("hwk,khwc->hwc", onehot, per_class)

    def prior_maps(disp: np.ndarray) -> np.ndarray:
        return fitted + sample_vertex_values(layout, disp * DISPLACEMENT_SCALE)
    vertices = {
        "body": lambda: fitted, "maps": lambda: result.vertices,
        "exact": lambda: exact_maps(scene.subject.rest_vertices.double()),
        "exact_clothing": lambda: exact_maps(true_base + thickness[:, None] * normals),
        "exact_local": lambda: exact_maps(fine_local),
        "coverage_mean_thick": lambda: exact_maps(true_base + flat),
        "mean": lambda: prior_maps(mean), "class_means": lambda: prior_maps(by_class)}
    return {name: error(vertices[name]()) for name in oracles}


def run(out: Path, split: str, count: int, prior_subjects: int, oracles: list[str]
        ) -> list[dict]:  # fmt: skip
    local_body, body = load_body_model("anny-local"), load_body_model("anny")
    layout = load_photo_network(body, None).layout
    priors = class_priors(local_body, body, layout, prior_subjects)
    rows = []
    for seed in iter_seeds(split, count):
        scene = render_photo(local_body, seed, PhotoDataSettings())
        folder = out / f"{split}-{seed}"
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        Image.fromarray(scene.image).save(folder / "photo.png")
        scene.camera.save_json(folder / "camera.json")
        config = PhotoConfig(progress=False)
        config.input.camera = str(folder / "camera.json")
        try:
            result = photo(folder / "photo.png", folder / "avatar", config)
        except Exception as error:  # a photo the pipeline refuses is reported, not scored
            print(json.dumps({"seed": seed, "failed": str(error)}), flush=True)
            continue
        row = {"seed": seed, "clothing": scene.subject.spec.clothing,
               **_score(scene, result, body, local_body, layout, priors, oracles)}  # fmt: skip
        print(json.dumps({k: round(v, 2) if isinstance(v, float) else v
                          for k, v in row.items()}), flush=True)  # fmt: skip
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("-o", "--out", type=Path, required=True)
    parser.add_argument("--split", choices=("train", "val"), default="val",
                        help="photos to score (never the sealed test split)")  # fmt: skip
    parser.add_argument("--photos", type=int, default=12)
    parser.add_argument("--prior-subjects", type=int, default=300,
                        help="training subjects the mean and class-mean maps are taken over")
    parser.add_argument("--oracles", nargs="+", choices=ORACLES, default=list(ORACLES),
                        help="which columns to score (each costs a surface metric per photo)")
    args = parser.parse_args()
    rows = run(args.out, args.split, args.photos, args.prior_subjects, args.oracles)
    mean = {k: round(float(np.mean([r[k] for r in rows])), 2) for k in args.oracles}
    print("| photos | " + " | ".join(args.oracles) + " |")
    print("|---|" + "---|" * len(args.oracles))
    print(f"| {len(rows)} | " + " | ".join(f"{mean[k]:.2f}" for k in args.oracles) + " |")
    (args.out / "oracles.json").write_text(json.dumps({"rows": rows, "mean": mean}, indent=1))


if __name__ == "__main__":
    main()
