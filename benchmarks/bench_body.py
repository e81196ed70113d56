"""Body-model speed and memory: forward + backward of the posed Anny body, batch 1 and 8.

Run: ``python benchmarks/bench_body.py`` (each configuration runs in a fresh process so that
the peak resident memory it reports is its own).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time


def run_one(batch: int, threads: int, repeats: int) -> dict[str, float]:
    import torch

    from monoavatar.body import load_body_model

    torch.set_num_threads(threads)
    body = load_body_model("anny")
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    shape = torch.zeros(batch, body.shape_dim, requires_grad=True)
    pose = torch.zeros(batch, body.num_joints, 3, requires_grad=True)
    transl = torch.zeros(batch, 3, requires_grad=True)
    fwd, bwd = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = body(shape=shape, pose=pose, translation=transl)
        t1 = time.perf_counter()
        out.vertices.square().sum().backward()
        t2 = time.perf_counter()
        fwd.append(t1 - t0)
        bwd.append(t2 - t1)
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "batch": batch,
        "threads": threads,
        "forward_ms": 1000 * statistics.median(fwd[2:]),
        "backward_ms": 1000 * statistics.median(bwd[2:]),
        "peak_rss_mb": rss1 / 1024,
        "rss_growth_mb": (rss1 - rss0) / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=12)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(run_one(args.batch[0], args.threads, args.repeats)))
        return
    print(f"{'batch':>5} {'threads':>7} {'forward ms':>11} {'backward ms':>12} {'peak RSS MB':>12}")
    for batch in args.batch:
        cmd = [sys.executable, __file__, "--child", "--batch", str(batch),
               "--threads", str(args.threads), "--repeats", str(args.repeats)]  # fmt: skip
        line = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
        r = json.loads(line.strip().splitlines()[-1])
        print(f"{r['batch']:>5} {r['threads']:>7} {r['forward_ms']:>11.1f} "
              f"{r['backward_ms']:>12.1f} {r['peak_rss_mb']:>12.0f}")  # fmt: skip


if __name__ == "__main__":
    main()
