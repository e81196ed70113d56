"""Ablations of the photo network (Paper E, Sec. E.6): the same small training budget for each
variant, then the photo benchmark on sealed test photos with each variant's weights.

Variants: ``full`` (L1 + MS-DSSIM, partial textures from poses perturbed as our fitter errs),
``no-dssim`` (L1 only), ``gan`` (plus the PatchGAN term, weight 0.01) and ``true-poses``
(partial textures from the exact poses and phenotypes). To fit a CPU budget the ablation trains
on 128² maps (the shipped network uses 256²), 400 photos and 800 steps per variant; every
variant shares the data of its pose kind, and the test photos are the benchmark's. Run::

    python benchmarks/bench_photo_ablation.py -o out/photo-ablation [--photos 6]

Writes ``ablation.json`` and ``ablation.md`` in the output folder.
"""

from __future__ import annotations

import argparse
import json
import shutil
from dataclasses import replace
from pathlib import Path

from monoavatar.bench.photo import run_photo_bench
from monoavatar.learn.photo_data import PhotoDataSettings
from monoavatar.learn.photo_model import PhotoNetworkSettings
from monoavatar.learn.photo_train import PhotoTrainConfig, train_photo

VARIANTS = {
    "full": {},
    "no-dssim": {"dssim_weight": 0.0},
    "gan": {"gan_weight": 0.01},
    "true-poses": {"fit_photos": 0},
}


def _config(variant: str, samples: int, steps: int) -> PhotoTrainConfig:
    change = dict(VARIANTS[variant])
    config = PhotoTrainConfig(samples=samples, val=50, data=PhotoDataSettings(map_size=128),
                              network=PhotoNetworkSettings(map_size=128),
                              fit_photos=int(change.pop("fit_photos", 16)))  # fmt: skip
    config.train = replace(config.train, steps=steps, **change)  # type: ignore[arg-type]
    return config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--steps", type=int, default=800)
    parser.add_argument("--photos", type=int, default=6,
                        help="test photos per variant for the surface error (0: validation "
                        "errors of the maps only)")
    parser.add_argument("--workers", type=int, default=2, help="processes making the data")
    parser.add_argument("--fit-error", type=Path, default=None,
                        help="a fit_error.json to reuse (else measured)")
    args = parser.parse_args()
    rows = {}
    for variant in args.variants:
        config = _config(variant, args.samples, args.steps)
        config.workers = args.workers
        config.progress = False
        kind = "true" if config.fit_photos == 0 else "perturbed"
        folder = args.output / variant
        folder.mkdir(parents=True, exist_ok=True)
        shared = args.output / f"data-{kind}"
        shared.mkdir(parents=True, exist_ok=True)
        if not (folder / "data").exists():
            (folder / "data").symlink_to(shared.resolve(), target_is_directory=True)
        if kind == "perturbed" and args.fit_error is not None and not (
                folder / "fit_error.json").exists():  # fmt: skip
            shutil.copy(args.fit_error, folder / "fit_error.json")
        result = train_photo(folder, config)
        good = []
        if args.photos > 0:
            bench = run_photo_bench(folder / "bench", weights=str(result.weights),
                                    photos=args.photos, progress=False)  # fmt: skip
            good = [r for r in bench["photos"] if "error" not in r]

        def mean(key: str, good: list[dict[str, float]] = good) -> float:
            return sum(r[key] for r in good) / len(good) if good else float("nan")

        rows[variant] = {
            "val": result.train.val, "steps": result.train.steps_done,
            "train_seconds": result.train.seconds, "photos": len(good),
            **{k: mean(k) for k in ("body_mm", "maps_mm", "maps_similarity_mm", "map_seen_mm",
                                    "map_unseen_mm")},
        }  # fmt: skip
        (args.output / "ablation.json").write_text(json.dumps(rows, indent=2))
    lines = ["| variant | steps | train min | val L1 | val MS-DSSIM | body mm | body + maps mm "
             "| similarity mm | map seen / unseen mm |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for name, r in rows.items():
        val = r["val"] or {}
        lines.append(f"| {name} | {r['steps']} | {r['train_seconds'] / 60:.1f} | "
                     f"{val.get('l1', float('nan')):.4f} | "
                     f"{val.get('ms_dssim', float('nan')):.4f} | {r['body_mm']:.2f} | "
                     f"{r['maps_mm']:.2f} | {r['maps_similarity_mm']:.2f} | "
                     f"{r['map_seen_mm']:.1f} / {r['map_unseen_mm']:.1f} |")  # fmt: skip
    (args.output / "ablation.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
