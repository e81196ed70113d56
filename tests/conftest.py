"""Shared fixtures: body models are built once per test session (Anny's first build compiles
and caches kernels; later builds take about half a second)."""

from __future__ import annotations

import pytest
import torch

from monoavatar.body import load_body_model
from monoavatar.body.model import BodyModel


@pytest.fixture(scope="session")
def anny64() -> BodyModel:
    """Anny without local changes, float64 (for tight numerical comparisons)."""
    return load_body_model("anny", dtype=torch.float64)


@pytest.fixture(scope="session")
def anny32() -> BodyModel:
    """Anny without local changes, float32 (what the pipeline uses)."""
    return load_body_model("anny", dtype=torch.float32)


@pytest.fixture(scope="session")
def anny_local() -> BodyModel:
    """Anny with its 256 local changes, float32 (ground-truth subjects use it)."""
    return load_body_model("anny-local", dtype=torch.float32)
