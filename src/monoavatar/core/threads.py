"""PyTorch's thread count while a fitter runs, and thread pools for per-frame work.

The fitters work on small tensors, for which extra PyTorch threads cost more than they save
(see ``PoseSettings.threads`` and ``ShapeSettings.threads``); the caller's setting comes back
afterwards. Work that is independent per frame (the flow rounds' renders and flow, the texture's
views) runs frames side by side instead, each frame on one thread (:func:`frame_pool`).
"""

from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import cv2
import torch
from threadpoolctl import threadpool_limits


@contextmanager
def torch_threads(count: int | None) -> Iterator[None]:
    """Run the block with ``count`` PyTorch intra-op threads (None: unchanged), then restore
    the previous count."""
    previous = torch.get_num_threads()
    if count is not None:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


@contextmanager
def frame_pool(workers: int) -> Iterator[ThreadPoolExecutor]:
    """A pool of ``workers`` threads for independent per-frame work; while it is open, every
    thread computes with one thread of its own in PyTorch, the BLAS libraries (numpy's and
    scipy's OpenBLAS) and OpenCV, so that the frames are the parallelism and the libraries'
    own pools do not compete for the cores (counts restored after). Each worker sets
    PyTorch's count itself, as OpenMP keeps it per thread.

    Results can differ between runs by float32 rounding (a sum's value depends on where its
    arrays lie in memory), with any number of workers; ``docs/decisions.md`` has the figures.
    """
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    previous_cv = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with torch_threads(1), threadpool_limits(limits=1), ThreadPoolExecutor(
            max_workers=workers, initializer=torch.set_num_threads, initargs=(1,)
        ) as pool:  # fmt: skip
            yield pool
    finally:
        cv2.setNumThreads(previous_cv)
