"""Where ``reconstruct`` spends its time: a per-stage table (the report's timings) and the
functions that take the most cumulative and own time (cProfile), for one input.

By default the input is what a user gives: the ``video.mp4`` of a ``monoavatar synth
turnaround`` scene (120 frames, 540 x 540, made on first use in ``--scene``) with ``--focal``
and ``--height`` from the scene, default settings, and an empty perception cache (a private
one under ``--out``), so that perception is measured too.

Run: ``OMP_NUM_THREADS=2 python benchmarks/profile_reconstruct.py --scene S --out DIR``;
``--input PATH`` profiles another input (a video, an image or synth folder) instead.
Writes ``DIR/profile.txt`` (the tables) and ``DIR/reconstruct.prof`` (for snakeviz and
friends) and prints the tables.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import shutil
import time
from dataclasses import replace
from pathlib import Path


def _profile_worker_threads() -> list[cProfile.Profile]:
    """Profile the threads of ``core.threads.frame_pool`` too (cProfile sees only the thread
    that enabled it): its pool class is replaced by one whose threads each start a profiler,
    returned in the list as they start."""
    from concurrent.futures import ThreadPoolExecutor

    import monoavatar.core.threads as threads

    profilers: list[cProfile.Profile] = []

    class ProfiledPool(ThreadPoolExecutor):
        def __init__(self, max_workers: int, initializer=None, initargs=()):  # type: ignore[no-untyped-def]
            def start(*a: object) -> None:
                profiler = cProfile.Profile()
                profilers.append(profiler)
                profiler.enable()
                if initializer is not None:
                    initializer(*a)

            super().__init__(max_workers=max_workers, initializer=start, initargs=initargs)

    threads.ThreadPoolExecutor = ProfiledPool  # type: ignore[misc]
    return profilers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=Path("out/profile_scene"),
                    help="synth turn-around folder (made if missing)")  # fmt: skip
    ap.add_argument("--input", type=Path, default=None, help="profile this input instead")
    ap.add_argument("--frames", type=int, default=120, help="frames of the scene and key-frames")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--top", type=int, default=30, help="rows of each function table")
    ap.add_argument("--workers", type=int, default=None,
                    help="threads of the flow and texture stages (default: reconstruct's)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cache = args.out / "cache"
    shutil.rmtree(cache, ignore_errors=True)
    os.environ["MONOAVATAR_CACHE"] = str(cache)  # an empty perception and stage cache

    from monoavatar.datasets.synth_scene import stated_height
    from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
    from monoavatar.pipelines.stages import InputSettings
    from monoavatar.synth.scene import SynthConfig, generate

    base = ReconstructConfig()
    config = replace(base, input=replace(base.input, frames=args.frames), progress=False)
    if args.input is None:
        if not (args.scene / "scene.json").is_file():
            generate(args.scene, SynthConfig(kind="turnaround", frames=args.frames, seed=0))
        info = json.loads((args.scene / "scene.json").read_text())
        focal = float(info["camera"]["K"][0][0])
        height = stated_height(info)
        source: Path = args.scene / "video.mp4"
        config = replace(config, input=InputSettings(frames=args.frames, focal=focal),
                         pose=replace(base.pose, height=height))  # fmt: skip
    else:
        source = args.input
    if args.workers is not None:
        config = replace(config, flow=replace(config.flow, workers=args.workers),
                         texture=replace(config.texture, workers=args.workers))  # fmt: skip
    out = args.out / "avatar"
    shutil.rmtree(out, ignore_errors=True)
    profiler = cProfile.Profile()
    workers = _profile_worker_threads()
    start = time.perf_counter()
    profiler.enable()
    result = reconstruct(source, out, config)
    profiler.disable()
    wall = time.perf_counter() - start
    stats = pstats.Stats(profiler)
    for worker in workers:
        stats.add(worker)
    stats.dump_stats(args.out / "reconstruct.prof")

    lines = [f"input: {source}  ({args.frames} key-frames, {config.flow.workers} worker "
             "thread(s), their functions included)",
             f"wall clock: {wall:.1f} s (under the profiler)", "",
             "| stage | seconds | share |", "|---|---|---|"]  # fmt: skip
    for stage, seconds in result.report.timings.items():
        lines.append(f"| {stage} | {seconds:.1f} | {100 * seconds / wall:.0f} % |")
    for key, title in (("cumulative", "cumulative time"), ("tottime", "own time")):
        text = io.StringIO()
        pstats.Stats(str(args.out / "reconstruct.prof"), stream=text).strip_dirs().sort_stats(
            key).print_stats(args.top)
        body = text.getvalue()
        lines += ["", f"## functions by {title}", "", body[body.find("ncalls"):].rstrip()]
    report = "\n".join(lines) + "\n"
    (args.out / "profile.txt").write_text(report)
    print(report)


if __name__ == "__main__":
    main()
