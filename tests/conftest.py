"""Shared fixtures: body models are built once per test session (Anny's first build compiles
and caches kernels; later builds take about half a second)."""

from __future__ import annotations

import os

if os.environ.get("PYTEST_XDIST_WORKER"):  # one process per core: one thread each
    for _name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(_name, "1")

import pytest  # noqa: E402
import torch  # noqa: E402

if os.environ.get("PYTEST_XDIST_WORKER"):
    torch.set_num_threads(1)

from monoavatar.body import load_body_model  # noqa: E402
from monoavatar.body.model import BodyModel  # noqa: E402


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


@pytest.fixture
def perception_spy(monkeypatch: pytest.MonkeyPatch) -> list[object]:
    """Replace :func:`monoavatar.perception.perceive` by a spy that records the settings it
    is called with and stops the command with a PerceptionError ("stopped by the test")."""
    import monoavatar.perception as perception
    from monoavatar.perception.errors import PerceptionError

    seen: list[object] = []

    def spy(frames, camera=None, settings=None, **kwargs):  # type: ignore[no-untyped-def]
        seen.append(settings)
        raise PerceptionError("stopped by the test")

    monkeypatch.setattr(perception, "perceive", spy)
    return seen
