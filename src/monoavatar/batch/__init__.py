"""Many captures at once: one ``monoavatar`` command per input, as tasks of a Ray cluster (a
local one by default, an existing one by address) or, without Ray, one after another.

Entry point: :func:`run_batch` (inputs → :class:`BatchResult`, ``OUT/batch.json``).
"""

from monoavatar.batch.runner import (
    COMMANDS,
    BatchError,
    BatchItem,
    BatchResult,
    BatchSettings,
    expand_inputs,
    is_complete,
    plan_items,
    run_batch,
)

__all__ = [
    "COMMANDS",
    "BatchError",
    "BatchItem",
    "BatchResult",
    "BatchSettings",
    "expand_inputs",
    "is_complete",
    "plan_items",
    "run_batch",
]
