"""End-to-end ``reconstruct --fast`` with the shipped few-frame network on a turn-around of an
unseen subject, and its failure modes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from monoavatar.bench.ground_truth import ground_truth_error
from monoavatar.body import load_body_model
from monoavatar.cli import main
from monoavatar.datasets.synth_scene import read_synth_scene
from monoavatar.fit.shape import CanonicalShape
from monoavatar.io.avatar_folder import AvatarFolder
from monoavatar.learn.fast_model import default_fast_weights
from monoavatar.synth.scene import SynthConfig, generate
from tests.io.gltf_reference import Glb, validate, validator_available

pytestmark = pytest.mark.slow  # end-to-end: not in the fast tier


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("scene") / "turn"
    generate(folder, SynthConfig(kind="turnaround", frames=16, seed=2_000_003, width=320,
                                 height=320, texture_size=128, clothing="tshirt-shorts"),
             progress=False)  # fmt: skip
    return folder


@pytest.fixture(scope="module")
def fast_out(scene: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fast") / "avatar"
    assert main(["reconstruct", str(scene), "-o", str(out), "--fast", "--frames", "4",
                 "--texture-size", "256", "--quiet"]) == 0  # fmt: skip
    return out


def test_shipped_weights_are_in_the_package() -> None:
    path = default_fast_weights()
    assert path.is_file()
    assert path.stat().st_size < 40e6


def test_fast_writes_reconstructs_avatar_folder(fast_out: Path) -> None:
    folder = AvatarFolder.load(fast_out)
    report = json.loads((fast_out / "report.json").read_text())
    assert report["settings"]["fast"] is True
    assert set(report["timings"]) >= {"perception", "network", "refine", "texture", "export"}
    assert report["input"]["frames"] == 4
    assert not any(report["fit"]["failed"])
    # refined top-down, the avatar lies on the person: its outline covers the masks
    assert report["fit"]["median_silhouette_iou"] > 0.75
    assert folder.params.offsets.shape == (load_body_model("anny").num_vertices, 3)
    assert len(folder.params.poses) == 4
    glb = Glb.load(fast_out / "avatar.glb")
    assert glb.gltf.skins and len(glb.gltf.skins[0].joints) == len(folder.params.poses[0])


@pytest.mark.skipif(validator_available() is not None, reason=str(validator_available()))
def test_fast_glb_validates(fast_out: Path) -> None:
    assert validate(fast_out / "avatar.glb")["issues"]["numErrors"] == 0


def test_fast_beats_the_average_body(scene: Path, fast_out: Path) -> None:
    """The avatar is closer to the truth than Anny's average body is (the dissertation's
    metric, after pose and scale alignment)."""
    report = json.loads((fast_out / "report.json").read_text())
    body = load_body_model("anny")
    beta = body.default_shape()[0]
    with torch.no_grad():
        rest, _ = body.rest_shape(beta[None])
    average = CanonicalShape(shape=beta, offsets=torch.zeros_like(rest[0]), vertices=rest[0],
                             faces=body.faces, frames=np.zeros(0, int),
                             frame_shifts=np.zeros((0, 3)))  # fmt: skip
    truth = read_synth_scene(scene).ground_truth
    assert truth is not None
    base = ground_truth_error(body, average, truth)
    assert report["ground_truth"]["surface_error_mm"] < 0.8 * base.surface_error_mm


def test_refinement_puts_the_avatar_onto_the_frames(scene: Path, fast_out: Path,
                                                    tmp_path: Path) -> None:
    """The network's guess (--budget 0) overlaps the person; the refinement against the
    silhouettes and keypoints makes it cover them."""
    out = tmp_path / "guess"
    assert main(["reconstruct", str(scene), "-o", str(out), "--fast", "--frames", "4",
                 "--budget", "0", "--texture-size", "128", "--quiet"]) == 0  # fmt: skip
    guess = json.loads((out / "report.json").read_text())
    refined = json.loads((fast_out / "report.json").read_text())
    assert guess["timings"].get("refine", 0.0) < 0.5
    assert guess["fit"]["median_silhouette_iou"] > 0.35
    # the refinement covers most of what the guess misses
    iou_guess, iou = guess["fit"]["median_silhouette_iou"], refined["fit"]["median_silhouette_iou"]
    assert iou > 0.9 and 1.0 - iou < 0.6 * (1.0 - iou_guess)
    assert (np.nanmedian(refined["fit"]["keypoint_error_px"])
            < np.nanmedian(guess["fit"]["keypoint_error_px"]))  # fmt: skip


def test_fast_height_is_the_given_height(scene: Path, tmp_path: Path) -> None:
    """(Two of the scene's frames as image files: no ground truth to score against.)"""
    files = sorted((scene / "frames").glob("*.png"))[::8]
    focal = read_synth_scene(scene).camera.K[0, 0]
    out = tmp_path / "tall"
    assert main(["reconstruct", *map(str, files), "-o", str(out), "--fast", "--focal",
                 f"{focal:.3f}", "--height", "1.9", "--texture-size", "128",
                 "--quiet"]) == 0  # fmt: skip
    report = json.loads((out / "report.json").read_text())
    assert report["scale"]["known"] is True
    assert report["scale"]["height_m"] == pytest.approx(1.9, abs=0.01)


def test_fast_from_several_image_files(scene: Path, tmp_path: Path) -> None:
    """INPUT as image files (the scene's frames, in shuffled order, with its focal length):
    the frames are read in name order, perceived with mediapipe, and the avatar lies on them."""
    files = sorted((scene / "frames").glob("*.png"))[::4]  # 4 frames over the turn
    focal = read_synth_scene(scene).camera.K[0, 0]
    out = tmp_path / "files"
    assert main(["reconstruct", *map(str, files[::-1]), "-o", str(out), "--fast", "--focal",
                 f"{focal:.3f}", "--texture-size", "128", "--quiet"]) == 0  # fmt: skip
    report = json.loads((out / "report.json").read_text())
    assert report["input"]["kind"] == "images"
    assert report["input"]["frames"] == 4
    assert report["input"]["path"].endswith("(4 image files)")
    assert report["fit"]["median_silhouette_iou"] > 0.75
    folder = AvatarFolder.load(out)
    assert len(folder.params.poses) == 4


@pytest.mark.parametrize(("args", "message"), [
    (["--fast", "--frames", "9"], "--frames must lie in [1, 8]"),
    (["--weights", "w.safetensors"], "--weights applies to --fast only"),
    (["--fast", "--weights", "missing.safetensors"], "no few-frame network weights"),
    (["--fast", "--height", "180"], "height must be in metres"),
    (["--budget", "5"], "--budget applies to --fast only"),
    (["--fast", "--budget", "-1"], "--budget is seconds of refinement"),
])  # fmt: skip
def test_fast_bad_options_exit_2_and_write_nothing(scene: Path, tmp_path: Path, args: list[str],
                                                   message: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["reconstruct", str(scene), "-o", str(out), "--quiet", *args]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
