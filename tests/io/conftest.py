"""Fixtures for the io tests."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests.io.media_helpers import write_video


@pytest.fixture
def make_video(tmp_path: Path) -> Callable[..., Path]:
    """``make_video(name="clip.mp4", **write_video_kwargs)`` → path of a small video."""

    def make(name: str = "clip.mp4", **kwargs: object) -> Path:
        return write_video(tmp_path / name, **kwargs)  # type: ignore[arg-type]

    return make
