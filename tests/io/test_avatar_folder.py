"""The avatar folder: a round trip of every file, nothing half-written on failure, and clear
errors for older, foreign and broken folders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from monoavatar.core.errors import InputNotFoundError
from monoavatar.io.avatar_folder import (
    FORMAT,
    AvatarFolder,
    AvatarFolderError,
    AvatarParams,
    GroundTruthSummary,
    Report,
    ShapeFile,
)
from tests.avatar_folders import make_params, make_report


def _folder(rng: np.random.Generator) -> AvatarFolder:
    vertices = rng.normal(size=(4, 3))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    params = make_params("anny-test", rng.normal(size=6), rng.normal(size=(4, 3)),
                         rng.normal(size=(3, 5, 3)), rng.normal(size=(3, 3)),
                         lighting_sh=rng.normal(size=(3, 9)), scale_known=False)  # fmt: skip
    report = make_report(3, timings={"poses": 1.5}, seconds=2.0, warnings=["UserWarning: x"])
    report.ground_truth = GroundTruthSummary(1.25, 2.5)
    return AvatarFolder(
        params, report, vertices, faces, uv=rng.uniform(size=(4, 2)), face_uv=faces,
        texture=rng.integers(0, 256, (8, 8, 3), dtype=np.uint8),
        previews={"overlays": np.zeros((4, 6, 3), np.uint8)},
    )  # fmt: skip


def test_round_trip(tmp_path: Path) -> None:
    folder = _folder(np.random.default_rng(0))
    files = folder.save(tmp_path / "avatar")
    assert set(files) == {"avatar.obj", "avatar.mtl", "texture.png", "params.npz", "report.json",
                          "preview/overlays.png"}  # fmt: skip
    assert sorted(p.name for p in (tmp_path / "avatar").iterdir()) == sorted(
        ["avatar.obj", "avatar.mtl", "texture.png", "params.npz", "report.json", "preview"])
    back = AvatarFolder.load(tmp_path / "avatar")
    a, b = folder.params, back.params
    for name in ("shape", "offsets", "poses", "translations", "frame_indices", "world_up",
                 "lighting_sh"):  # fmt: skip
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name))
    np.testing.assert_array_equal(b.camera.K, a.camera.K)
    assert (b.body_model, b.height_m, b.scale_known) == (a.body_model, a.height_m, False)
    assert back.report == folder.report
    np.testing.assert_allclose(back.vertices, folder.vertices, atol=1e-6)  # OBJ: 6 decimals
    np.testing.assert_array_equal(back.faces, folder.faces)
    np.testing.assert_array_equal(back.texture, folder.texture)
    mtl = (tmp_path / "avatar" / "avatar.mtl").read_text()
    assert "map_Kd texture.png" in mtl


def test_a_failed_save_leaves_the_old_folder_alone(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "avatar"
    folder = _folder(np.random.default_rng(1))
    folder.save(out)
    before = (out / "params.npz").read_bytes()

    def broken(self: Report, path: str | Path) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(Report, "write", broken)
    with pytest.raises(OSError, match="disk full"):
        _folder(np.random.default_rng(2)).save(out)
    assert (out / "params.npz").read_bytes() == before  # nothing of the new one moved in
    assert not list(out.glob(".staging-*"))


def test_older_foreign_and_broken_folders_are_explained(tmp_path: Path) -> None:
    out = tmp_path / "avatar"
    _folder(np.random.default_rng(3)).save(out)
    params = dict(np.load(out / "params.npz"))
    with pytest.raises(InputNotFoundError, match="no such avatar folder"):
        AvatarFolder.load(tmp_path / "missing")
    np.savez(out / "params.npz", **{k: v for k, v in params.items() if k != "format"})
    with pytest.raises(AvatarFolderError, match="older monoavatar"):
        AvatarFolder.load(out)
    np.savez(out / "params.npz", **{**params, "format": np.array("someone-else-3")})
    with pytest.raises(AvatarFolderError, match="someone-else-3"):
        AvatarFolder.load(out)
    np.savez(out / "params.npz", **{k: v for k, v in params.items() if k != "poses"})
    with pytest.raises(AvatarFolderError, match="poses"):
        AvatarFolder.load(out)
    np.savez(out / "params.npz", **{**params, "translations": np.zeros((2, 3))})
    with pytest.raises(AvatarFolderError, match="translations"):
        AvatarFolder.load(out)
    (out / "params.npz").write_bytes(b"not a zip")
    with pytest.raises(AvatarFolderError, match="not an npz"):
        AvatarParams.load(out / "params.npz")
    np.savez(out / "params.npz", **params)
    report = json.loads((out / "report.json").read_text())
    (out / "report.json").write_text(json.dumps({**report, "format": "old-1"}))
    with pytest.raises(AvatarFolderError, match="old-1"):
        AvatarFolder.load(out)
    del report["fit"]
    (out / "report.json").write_text(json.dumps(report))
    with pytest.raises(AvatarFolderError, match="malformed report"):
        AvatarFolder.load(out)
    assert report["format"] == FORMAT


def test_shape_file_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    shape = ShapeFile("anny-test", rng.normal(size=6), rng.normal(size=(4, 3)),
                      rng.normal(size=(4, 3)), np.array([[0, 1, 2]]), np.array([0, 2]),
                      rng.normal(size=(2, 3)), rng.normal(size=(3, 5, 3)),
                      rng.normal(size=(3, 3)))  # fmt: skip
    shape.save(tmp_path / "shape.npz")
    back = ShapeFile.load(tmp_path / "shape.npz")
    assert back.body_model == "anny-test"
    np.testing.assert_array_equal(back.frame_shifts, shape.frame_shifts)
    np.testing.assert_array_equal(back.poses, shape.poses)
    np.savez(tmp_path / "other.npz", shape=shape.shape)
    with pytest.raises(AvatarFolderError, match="not a shape.npz"):
        ShapeFile.load(tmp_path / "other.npz")


def test_a_dead_runs_staging_folder_is_cleaned_by_the_next_save(tmp_path: Path) -> None:
    import os
    import time

    from monoavatar.io.avatar_folder import STALE_STAGING_S

    out = tmp_path / "avatar"
    (out / ".staging-dead").mkdir(parents=True)
    (out / ".staging-dead" / "params.npz").write_bytes(b"half")
    old = time.time() - STALE_STAGING_S - 60
    os.utime(out / ".staging-dead", (old, old))
    (out / ".staging-running").mkdir()  # another run's, still young: left alone
    _folder(np.random.default_rng(5)).save(out)
    assert not (out / ".staging-dead").exists()
    assert (out / ".staging-running").exists()
