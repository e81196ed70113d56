"""Throughput of ``monoavatar batch`` against the same inputs run one command after another.

Three ``monoavatar synth turnaround`` scenes (seeds 21, 22, 23; ``--frames`` frames at
``--size`` pixels; made in ``--out/scenes`` on first use), each given as its folder (which
carries its camera), default settings, an empty cache each time:

1. ``sequence``: ``monoavatar reconstruct`` three times, one after another (each command uses
   every core, as it does when run by hand);
2. ``batch (Ray)``: ``monoavatar batch`` of the three (a local Ray cluster, one core a task);
3. ``batch --no-ray``: the same one after another without Ray.

Each batch row's overhead is its wall time over the sequence's. The table is printed and
written to ``--out/batch.json``.

Run: ``python benchmarks/bench_batch.py --out DIR`` (about 10 minutes on 2 cores with the
defaults).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

SEEDS = (21, 22, 23)


def _scene(root: Path, seed: int, frames: int, size: int) -> Path:
    folder = root / f"turn{seed}"
    if not (folder / "scene.json").is_file():
        from monoavatar.synth.scene import SynthConfig, generate

        generate(folder, SynthConfig(kind="turnaround", frames=frames, seed=seed, width=size,
                                     height=size), progress=False)  # fmt: skip
    return folder


def _timed(argv: list[str], cache: Path) -> float:
    shutil.rmtree(cache, ignore_errors=True)
    env = dict(os.environ, MONOAVATAR_CACHE=str(cache))
    start = time.perf_counter()
    subprocess.run(argv, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=24, help="frames of each scene")
    ap.add_argument("--size", type=int, default=384, help="width and height of the frames")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    scenes = [_scene(args.out / "scenes", s, args.frames, args.size) for s in SEEDS]
    cli = [sys.executable, "-m", "monoavatar.cli"]
    cache, runs = args.out / "cache", args.out / "runs"
    shutil.rmtree(runs, ignore_errors=True)
    rows = {"sequence": sum(_timed([*cli, "reconstruct", str(scene), "-o",
                                    str(runs / "sequence" / scene.name), "--quiet"], cache)
                            for scene in scenes)}  # fmt: skip
    for label, name, extra in (("batch (Ray)", "ray", []),
                               ("batch --no-ray", "no-ray", ["--no-ray"])):  # fmt: skip
        folder = runs / name
        rows[label] = _timed([*cli, "batch", *map(str, scenes), "-o", str(folder), "--quiet",
                              *extra], cache)  # fmt: skip
        failed = [i["name"] for i in json.loads((folder / "batch.json").read_text())["items"]
                  if i["status"] != "done"]  # fmt: skip
        if failed:
            raise SystemExit(f"{label}: {failed} did not finish (see {folder})")
    print(f"three {args.frames}-frame {args.size}x{args.size} scenes, {os.cpu_count()} cores")
    print("| run | wall s | over the sequence |\n|---|---|---|")
    for label, seconds in rows.items():
        print(f"| {label} | {seconds:.1f} | {seconds / rows['sequence'] - 1:+.1%} |")
    (args.out / "batch.json").write_text(json.dumps({"frames": args.frames, "size": args.size,
                                                     "cores": os.cpu_count(), "seconds": rows},
                                                    indent=2))  # fmt: skip


if __name__ == "__main__":
    main()
