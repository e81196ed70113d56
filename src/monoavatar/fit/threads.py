"""PyTorch's thread count while a fitter runs.

The fitters work on small tensors, where one thread is fastest on a shared 2-core machine
(see ``PoseSettings.threads`` and ``ShapeSettings.threads``); the caller's setting comes back
afterwards.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch


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
