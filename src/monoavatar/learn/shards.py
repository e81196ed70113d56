"""Sharded synthetic training data: disjoint seed ranges per split, shards ``SPLIT-NNNN.npz``
written atomically by worker processes, and a ``data.json`` that names the format and the
settings the data was made with (a folder made with other settings is refused, so a resumed
generation never mixes two kinds of data).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_write_text

__all__ = ["ShardError", "generate_shards", "iter_seeds", "shard_paths"]

SPLITS = ("train", "val", "test")


class ShardError(MonoavatarError, ValueError):
    """A data folder made with other settings, or a split that does not exist."""


def iter_seeds(split: str, count: int) -> Iterator[int]:
    """Disjoint seed ranges: train from 0, validation from 10⁶, test from 2·10⁶."""
    if split not in SPLITS:
        raise ShardError(f"unknown split {split!r}; choose from {SPLITS}")
    base = {"train": 0, "val": 1_000_000, "test": 2_000_000}[split]
    return iter(range(base, base + count))


def shard_paths(folder: Path, split: str) -> list[Path]:
    """The shards of ``split`` in ``folder``, in order."""
    return sorted(Path(folder).glob(f"{split}-*.npz"))


def generate_shards(folder: str | Path, record: Mapping[str, Any], counts: Mapping[str, int],
                    make_shard: Callable[..., str], args: tuple[Any, ...], *, shard: int,
                    workers: int = 2, progress: bool = True, desc: str = "data"
                    ) -> dict[str, list[Path]]:  # fmt: skip
    """Write ``counts[split]`` samples of each split as shards of ``shard`` samples.

    ``make_shard(folder, split, index, seeds, *args)`` makes and writes shard ``index`` (a
    top-level function: it runs in a spawned worker process) and returns its path. ``record``
    (JSON-able: ``format`` and ``settings``) goes to ``data.json``; shards already in
    ``folder`` (an interrupted run) are kept, so generation resumes.

    Raises:
        ShardError: ``folder`` holds data made with another ``record``.
    """
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from tqdm import tqdm

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    meta = out / "data.json"
    wanted = json.loads(json.dumps(record))
    if meta.is_file():
        if json.loads(meta.read_text()) != wanted:
            raise ShardError(f"{out} holds data made with other settings; use another folder "
                             "or delete it")  # fmt: skip
    else:
        atomic_write_text(meta, json.dumps(wanted, indent=1))
    jobs = []
    for split, count in counts.items():
        seeds = list(iter_seeds(split, count))
        for k in range(0, count, shard):
            if not (out / f"{split}-{k // shard:04d}.npz").is_file():
                jobs.append((split, k // shard, seeds[k : k + shard]))
    bar = tqdm(total=sum(len(j[2]) for j in jobs), desc=desc, unit="sample",
               disable=not progress)  # fmt: skip
    if jobs:
        with ProcessPoolExecutor(max(1, workers), mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(make_shard, str(out), split, index, seeds, *args)
                       for split, index, seeds in jobs]  # fmt: skip
            for future, job in zip(futures, jobs, strict=True):
                future.result()
                bar.update(len(job[2]))
    bar.close()
    return {split: shard_paths(out, split) for split in counts}
