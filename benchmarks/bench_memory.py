"""Peak memory and time of ``reconstruct`` against the number of key-frames.

One ``monoavatar synth turnaround`` video (``--frames`` frames, 540 x 540, made on first use in
``--scene``) is reconstructed with 30, 60, 120 and 240 key-frames (``--keyframes``; never more
than the video has), each in a fresh process with an empty cache, default settings, ``--focal``
and ``--height`` from the scene. The process's peak resident memory (``getrusage``) and wall
time are printed as a table and written to ``--out/memory.json``.

Run: ``OMP_NUM_THREADS=2 python benchmarks/bench_memory.py --scene S --out DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

CHILD = """
import json, resource, sys, time
from dataclasses import replace
from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
from monoavatar.pipelines.stages import InputSettings
video, out = sys.argv[1], sys.argv[2]
frames, focal, height = int(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5])
base = ReconstructConfig()
config = replace(base, progress=False, input=InputSettings(frames=frames, focal=focal),
                 pose=replace(base.pose, height=height))
start = time.perf_counter()
reconstruct(video, out, config)
print(json.dumps({"seconds": time.perf_counter() - start,
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=Path("out/memory_scene"))
    ap.add_argument("--frames", type=int, default=240, help="frames of the video")
    ap.add_argument("--keyframes", type=int, nargs="+", default=[30, 60, 120, 240])
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if not (args.scene / "scene.json").is_file():
        from monoavatar.synth.scene import SynthConfig, generate

        generate(args.scene, SynthConfig(kind="turnaround", frames=args.frames, seed=0))
    from monoavatar.datasets.synth_scene import stated_height

    info = json.loads((args.scene / "scene.json").read_text())
    focal, height = info["camera"]["K"][0][0], stated_height(info)
    rows = []
    for k in sorted(set(min(k, args.frames) for k in args.keyframes)):
        with tempfile.TemporaryDirectory(dir=args.out) as tmp:
            env_cache = {"MONOAVATAR_CACHE": str(Path(tmp) / "cache")}
            run = subprocess.run(
                [sys.executable, "-c", CHILD, str(args.scene / "video.mp4"),
                 str(Path(tmp) / "avatar"), str(k), str(focal), str(height)],
                capture_output=True, text=True, check=True,
                env={**os.environ, **env_cache})  # fmt: skip
        result = json.loads(run.stdout.strip().splitlines()[-1])
        rows.append({"keyframes": k, **result})
        print(f"{k} key-frames: {result['seconds']:.0f} s, peak {result['peak_mb']:.0f} MB",
              flush=True)  # fmt: skip
    (args.out / "memory.json").write_text(json.dumps(rows, indent=2))
    print("| key-frames | wall (s) | peak RSS (MB) | MB per key-frame above the first row |")
    print("|---|---|---|---|")
    first = rows[0]
    for r in rows:
        extra = ((r["peak_mb"] - first["peak_mb"]) / (r["keyframes"] - first["keyframes"])
                 if r is not first else float("nan"))  # fmt: skip
        print(f"| {r['keyframes']} | {r['seconds']:.0f} | {r['peak_mb']:.0f} | {extra:.1f} |")


if __name__ == "__main__":
    main()
