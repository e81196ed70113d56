"""A tiny benchmark subject and its scene, generated once per test session."""

from __future__ import annotations

import pytest

from monoavatar.bench.suite import BenchSubject, ensure_scene

TINY = BenchSubject(name="tiny-tshirt-shorts-s14", category="clothed", seed=14,
                    clothing="tshirt-shorts", frames=6, width=96, height=96, keyframes=4,
                    texture_size=128)  # fmt: skip


@pytest.fixture(scope="session")
def tiny_scene(anny_local, tmp_path_factory):
    """(subject, scenes folder, scene folder) of a 6-frame 96 x 96 turn-around: 60° a frame,
    key-frames 0, 2, 3 and 5 (close enough for the held-out frames' poses to be interpolated)."""
    scenes = tmp_path_factory.mktemp("bench-scenes")
    folder = ensure_scene(TINY, scenes, body=anny_local)
    return TINY, scenes, folder
