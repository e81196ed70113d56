"""Wall-clock of ``monoavatar reconstruct`` as a user runs it, with its per-stage table.

The input is the ``video.mp4`` of a ``monoavatar synth turnaround`` scene (``--frames`` frames,
540 x 540, made on first use in ``--scene``), given with ``--focal`` and ``--height`` from the
scene and otherwise default settings (``--options`` adds more), an empty cache each time. The
command runs ``--repeat`` times in processes of their own; the wall-clock of each (Python's
start and the imports included), the stages' seconds from its ``report.json`` and the surface
error against the scene's truth are printed as a table with the median, and written to
``--out/time.json``.

Run: ``python benchmarks/time_reconstruct.py --scene S --out DIR`` on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

STAGES = ("perception", "poses", "shape", "texture", "flow", "export")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=Path("out/time_scene"))
    ap.add_argument("--frames", type=int, default=120, help="frames of the scene's video")
    ap.add_argument("--seed", type=int, default=0, help="the scene's seed")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--options", default="", help="more reconstruct options, quoted")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if not (args.scene / "scene.json").is_file():
        from monoavatar.synth.scene import SynthConfig, generate

        generate(args.scene, SynthConfig(kind="turnaround", frames=args.frames, seed=args.seed))
    from monoavatar.datasets.synth_scene import stated_height

    info = json.loads((args.scene / "scene.json").read_text())
    focal, height = info["camera"]["K"][0][0], stated_height(info)
    rows = []
    for k in range(args.repeat):
        out, cache = args.out / f"run{k}", args.out / "cache"
        shutil.rmtree(out, ignore_errors=True)
        shutil.rmtree(cache, ignore_errors=True)
        argv = [sys.executable, "-m", "monoavatar.cli", "reconstruct",
                str(args.scene / "video.mp4"), "-o", str(out), "--focal", f"{focal:.3f}",
                "--height", f"{height:.4f}", "--quiet", *shlex.split(args.options)]  # fmt: skip
        start = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL,
                       env=dict(os.environ, MONOAVATAR_CACHE=str(cache)))  # fmt: skip
        wall = time.perf_counter() - start
        report = json.loads((out / "report.json").read_text())
        rows.append({"wall": wall, "timings": report["timings"],
                     "peak_mb": report.get("peak_memory_mb")})  # fmt: skip
        print(f"run {k + 1}: {wall:.1f} s", flush=True)
    scene_truth = _surface_error(args.scene, args.out / "run0")
    print(f"{args.scene / 'video.mp4'} ({args.frames} frames), reconstruct {args.options}".strip())
    print("| run | wall s | " + " | ".join(STAGES) + " | peak MB |")
    print("|---|---|" + "---|" * len(STAGES) + "---|")
    for k, r in enumerate(rows):
        stages = " | ".join(f"{r['timings'].get(s, 0.0):.1f}" for s in STAGES)
        print(f"| {k + 1} | {r['wall']:.1f} | {stages} | {r['peak_mb']:.0f} |")
    median = statistics.median(r["wall"] for r in rows)
    print(f"median wall-clock {median:.1f} s; surface error of run 1: {scene_truth}")
    (args.out / "time.json").write_text(json.dumps({"options": args.options, "runs": rows,
                                                    "median_wall": median,
                                                    "surface_error": scene_truth},
                                                   indent=2))  # fmt: skip


def _surface_error(scene: Path, folder: Path) -> str:
    """The avatar's surface error against the scene's truth (mm, after pose and scale
    alignment / after a similarity alone)."""
    import numpy as np
    import torch

    from monoavatar.bench.ground_truth import ground_truth_error
    from monoavatar.body import load_body_model
    from monoavatar.datasets.synth_scene import read_synth_scene
    from monoavatar.fit.shape import CanonicalShape
    from monoavatar.io.avatar_folder import AvatarFolder

    params = AvatarFolder.load(folder, mesh=False).params
    body = load_body_model("anny")
    beta = torch.as_tensor(params.shape, dtype=body.dtype)
    offsets = torch.as_tensor(params.offsets, dtype=body.dtype)
    with torch.no_grad():
        rest, _ = body.rest_shape(beta[None])
    shape = CanonicalShape(shape=beta, offsets=offsets, vertices=rest[0] + offsets,
                           faces=body.faces, frames=np.zeros(0, np.int64),
                           frame_shifts=np.zeros((0, 3)))  # fmt: skip
    truth = read_synth_scene(scene, frames=[0]).ground_truth
    gt = ground_truth_error(body, shape, truth)
    return f"{gt.surface_error_mm:.2f} / {gt.surface_error_rigid_mm:.2f} mm"


if __name__ == "__main__":
    main()
