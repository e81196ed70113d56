"""The pose stage's cache: a damaged or foreign entry is discarded with a warning and the poses
are fitted again; a good entry is reused."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from monoavatar.core.camera import PinholeCamera
from monoavatar.fit.pose import PoseSettings, PoseTrack
from monoavatar.pipelines import stages


def _inputs(n: int = 3) -> SimpleNamespace:
    camera = PinholeCamera(np.diag([50.0, 50.0, 1.0]), np.eye(3), np.zeros(3), 32, 32)
    obs = SimpleNamespace(masks=np.zeros((n, 32, 32), bool), keypoints=np.zeros((n, 33, 3)),
                          camera=camera, frame_indices=np.arange(n))  # fmt: skip
    return SimpleNamespace(observations=obs)


def _track(inputs: SimpleNamespace, identity: str) -> PoseTrack:
    n = len(inputs.observations.frame_indices)
    return PoseTrack(
        body_model=identity, shape=np.zeros(4), poses=np.zeros((n, 5, 3)),
        translations=np.zeros((n, 3)), camera=inputs.observations.camera,
        frame_indices=inputs.observations.frame_indices, keypoint_error=np.zeros(n),
        silhouette_iou=np.ones(n), energy=np.zeros(n), failed=np.zeros(n, bool), height=1.7,
        scale_known=False, seconds=1.0,
    )  # fmt: skip


def test_damaged_cache_entries_are_refitted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                            ) -> None:  # fmt: skip
    monkeypatch.setenv("MONOAVATAR_CACHE", str(tmp_path))
    body = SimpleNamespace(identity="anny:test")
    inputs = _inputs()
    fits: list[int] = []

    def fake_fit(body_, obs, settings, progress=False):  # type: ignore[no-untyped-def]
        fits.append(1)
        return _track(inputs, body.identity)

    monkeypatch.setattr(stages, "fit_poses", fake_fit)
    settings = PoseSettings()
    stages.pose_stage(body, inputs, settings)  # type: ignore[arg-type]
    (entry,) = (tmp_path / "stages").glob("poses-*.npz")
    stages.pose_stage(body, inputs, settings)  # type: ignore[arg-type]
    assert len(fits) == 1  # reused
    entry.write_bytes(entry.read_bytes()[:100])  # truncated
    with pytest.warns(UserWarning, match="damaged cache entry"):
        stages.pose_stage(body, inputs, settings)  # type: ignore[arg-type]
    assert len(fits) == 2 and PoseTrack.load(entry).body_model == "anny:test"
    _track(_inputs(5), "anny:test").save(entry)  # another input's poses under this key
    with pytest.warns(UserWarning, match="another input"):
        track = stages.pose_stage(body, inputs, settings)  # type: ignore[arg-type]
    assert len(fits) == 3 and len(track.poses) == 3
