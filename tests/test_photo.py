"""End-to-end ``photo`` on synthetic photographs, with a small untrained network (the shipped
weights are checked by the benchmark, not here), and its failure modes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from monoavatar.cli import main
from monoavatar.fit.pose import PoseSettings
from monoavatar.io.avatar_folder import AvatarFolder
from monoavatar.learn.photo_data import PhotoDataSettings, render_photo
from monoavatar.learn.photo_model import PhotoNetworkSettings
from monoavatar.learn.training import export_generator
from monoavatar.learn.uvmaps import DISPLACEMENT_SCALE, sample_vertex_values, uv_layout
from monoavatar.pipelines.photo import PhotoConfig, photo
from tests.io.gltf_reference import Glb, validate, validator_available

pytestmark = pytest.mark.slow  # end-to-end: not in the fast tier

FAST_POSE = PoseSettings(init_iterations=30, iterations=15, silhouette_points=400,
                         boundary_points=100)  # fmt: skip


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small class network with random weights (zero class priors), so that the maps
    displace the surface visibly and the garment labels vary."""
    torch.manual_seed(0)
    settings = PhotoNetworkSettings(base=8, depth=5, max_channels=32)
    net = settings.build()
    path = tmp_path_factory.mktemp("weights") / "tiny.safetensors"
    export_generator(net, path, settings.metadata())
    return path


@pytest.fixture(scope="module")
def photo_folder(tmp_path_factory: pytest.TempPathFactory, anny_local) -> Path:  # type: ignore[no-untyped-def]
    scene = render_photo(anny_local, 2_000_001, PhotoDataSettings(
        image_size=384, texture_size=256, distance_m=(2.8, 3.0)))
    folder = tmp_path_factory.mktemp("photo")
    Image.fromarray(scene.image).save(folder / "photo.png")
    scene.camera.save_json(folder / "camera.json")
    return folder


def _config(weights: Path, photo_folder: Path | None = None, **kw: object) -> PhotoConfig:
    config = PhotoConfig(weights=str(weights), texture_size=256, progress=False, pose=FAST_POSE,
                         **kw)  # type: ignore[arg-type]  # fmt: skip
    if photo_folder is not None:
        config.input.camera = str(photo_folder / "camera.json")
    return config


@pytest.fixture(scope="module")
def result(photo_folder: Path, weights: Path, tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    return photo(photo_folder / "photo.png", tmp_path_factory.mktemp("out") / "avatar",
                 _config(weights, photo_folder))  # fmt: skip


def test_outputs_complete(result) -> None:  # type: ignore[no-untyped-def]
    out = result.folder
    for name in ("avatar.glb", "avatar.obj", "texture.png", "params.npz", "report.json",
                 "maps/normal.png", "maps/displacement.npz", "maps/garments.png",
                 "preview/input.png", "preview/partial_texture.png", "preview/maps.png",
                 "preview/turntable.png"):
        assert (out / name).is_file(), name
    assert not list(out.glob(".staging-*"))
    report = json.loads((out / "report.json").read_text())
    assert {"perception", "fit", "partial texture", "maps", "surface", "texture",
            "export"} <= set(report["timings"])  # fmt: skip
    assert report["fit"]["silhouette_iou"][0] > 0.7
    assert report["input"]["kind"] == "image"


def test_garment_map_written_with_its_labels(result) -> None:  # type: ignore[no-untyped-def]
    """A class network's labels: in maps/displacement.npz (class index on the charts, 255
    outside), as maps/garments.png in the documented colours, and as the preview's 4th panel."""
    from monoavatar.pipelines.stages import GARMENT_COLOURS
    from monoavatar.synth.subjects import GARMENTS

    with np.load(result.folder / "maps" / "displacement.npz") as d:
        labels, chart, names = d["garments"], d["chart"], list(d["garment_names"])
    assert names == list(GARMENTS)
    np.testing.assert_array_equal(labels, result.garments)
    assert labels[chart].max() < len(GARMENTS) and np.all(labels[~chart] == 255)
    picture = np.asarray(Image.open(result.folder / "maps" / "garments.png"))
    np.testing.assert_array_equal(picture[chart], GARMENT_COLOURS[labels[chart]])
    assert np.all(picture[~chart] == 128)
    preview = np.asarray(Image.open(result.folder / "preview" / "maps.png"))
    np.testing.assert_array_equal(preview[:, 3 * 256:], picture)


def test_surface_is_the_body_displaced_by_the_map(result, anny32) -> None:  # type: ignore[no-untyped-def]
    """avatar.obj = the fitted body subdivided + the displacement map read at each vertex;
    params.npz's offsets are the same displacement at the body's own vertices."""
    folder = AvatarFolder.load(result.folder)
    layout = uv_layout(anny32, 256)
    with np.load(result.folder / "maps" / "displacement.npz") as d:
        disp = d["displacement"]
    np.testing.assert_allclose(disp, result.maps[..., :3] * DISPLACEMENT_SCALE, atol=1e-6)
    with torch.no_grad():
        rest, _ = anny32.rest_shape(torch.as_tensor(folder.params.shape,
                                                    dtype=anny32.dtype)[None])  # fmt: skip
        base = layout.subdivision.apply(rest.double())[0].numpy()
    expected = base + sample_vertex_values(layout, disp)
    np.testing.assert_allclose(folder.vertices, expected, atol=1e-4)
    np.testing.assert_allclose(folder.params.offsets, (expected - base)[: anny32.num_vertices],
                               atol=1e-4)  # fmt: skip
    assert np.abs(folder.params.offsets).max() > 1e-4  # the map did move the surface


def test_glb_is_skinned_and_textured(result) -> None:  # type: ignore[no-untyped-def]
    glb = Glb.load(result.folder / "avatar.glb")
    assert len(glb.gltf.skins) == 1 and len(glb.gltf.skins[0].joints) == 20
    assert glb.gltf.materials[0].pbrMetallicRoughness.baseColorTexture is not None
    if validator_available() is None:
        assert validate(result.folder / "avatar.glb")["issues"]["numErrors"] == 0


def test_animate_takes_a_photo_avatar(result, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    target = tmp_path / "walk.glb"
    assert main(["animate", str(result.folder), "-o", str(target), "--frames", "6"]) == 0
    assert len(Glb.load(target).gltf.animations) == 1


def test_cut_off_huge_photo_is_downscaled_and_warned(photo_folder: Path, weights: Path,
                                                      tmp_path: Path) -> None:  # fmt: skip
    """The upper 60 % of the photo, enlarged to 2400 px: downscaled to --max-side (the focal
    length with it), and a warning that the legs are not all visible."""
    image = np.asarray(Image.open(photo_folder / "photo.png"))
    crop = image[: int(0.6 * image.shape[0])]
    big = Image.fromarray(crop).resize((2400 * crop.shape[1] // crop.shape[0], 2400))
    big.save(tmp_path / "big.jpg", quality=90)
    config = _config(weights, max_side=640)
    result = photo(tmp_path / "big.jpg", tmp_path / "out", config)
    folder = AvatarFolder.load(result.folder, mesh=False)
    assert max(folder.params.camera.width, folder.params.camera.height) == 640
    assert any("legs are not all visible" in w for w in result.report.warnings)


def test_bad_inputs_fail_cleanly(weights: Path, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    blank = tmp_path / "blank.png"
    Image.fromarray(np.full((320, 240, 3), 200, np.uint8)).save(blank)
    for path, message in ((empty, "not a readable image"), (blank, "no person"),
                          (tmp_path / "missing.jpg", "no such")):  # fmt: skip
        out = tmp_path / f"out-{path.stem}"
        code = main(["photo", str(path), "-o", str(out), "--weights", str(weights), "--quiet"])
        assert code == 2
        assert message in capsys.readouterr().err
        assert not out.exists()  # nothing left behind
    code = main(["photo", str(blank), "-o", str(tmp_path / "o"), "--height", "175"])
    assert code == 2 and "metres" in capsys.readouterr().err


def test_transfer_keeps_a_face_and_takes_b_clothes(result, photo_folder: Path, weights: Path,
                                                   tmp_path: Path, anny32) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
    """A's maps on the face, B's elsewhere (away from the blend), A's body shape; a folder
    without maps (reconstruct's) is brought to maps from its offsets."""
    import shutil

    from monoavatar.pipelines.transfer import face_weight, transfer

    b_dir = tmp_path / "b"
    shutil.copytree(result.folder, b_dir)
    # B: the same avatar with a made-up constant 1 cm displacement along +Z, and no maps file
    # (as a reconstruct folder): its maps then come from the offsets
    folder_b = AvatarFolder.load(b_dir, mesh=False)
    folder_b.params.offsets = np.tile([0.0, 0.0, 0.01], (anny32.num_vertices, 1))
    folder_b.params.save(b_dir / "params.npz")
    (b_dir / "maps" / "displacement.npz").unlink()
    out = transfer(result.folder, b_dir, tmp_path / "ab")
    layout = uv_layout(anny32, 256)
    w = face_weight(anny32, layout, 256, 3)
    face = layout.chart & (w > 0.999)
    body = layout.chart & (w < 0.001)
    assert face.sum() > 100 and body.sum() > 1000
    # within the blend's 0.1 % of the other side
    np.testing.assert_allclose(out.maps[face, :3], result.maps[face, :3], atol=1e-3)
    np.testing.assert_allclose(out.maps[body, :3], np.tile([0, 0, 0.2], (body.sum(), 1)),
                               atol=1e-3)  # 1 cm / DISPLACEMENT_SCALE  # fmt: skip
    written = AvatarFolder.load(out.folder, mesh=False)
    np.testing.assert_allclose(written.params.shape, result.track.shape)
    assert (out.folder / "avatar.glb").is_file() and (out.folder / "maps" / "normal.png").is_file()


def test_a_real_upper_body_photo_runs_with_a_warning(weights: Path, tmp_path: Path) -> None:
    """scikit-image's astronaut (a public-domain NASA portrait, head and shoulders): no crash,
    an avatar folder, and the warning that the legs are not visible."""
    from skimage import data

    path = tmp_path / "astronaut.png"
    Image.fromarray(data.astronaut()).save(path)
    result = photo(path, tmp_path / "out", _config(weights))
    assert (result.folder / "avatar.glb").is_file()
    assert any("legs are not all visible" in w for w in result.report.warnings)


def test_reconstruct_points_a_single_photo_to_the_photo_command(
        photo_folder: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    out = tmp_path / "rec"
    assert main(["reconstruct", str(photo_folder / "photo.png"), "-o", str(out), "--quiet"]) == 2
    assert "monoavatar photo" in capsys.readouterr().err
    assert not out.exists()


def test_view_shows_a_photo_avatar_over_its_photo(result, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from monoavatar.io.viewer_page import write_page
    from monoavatar.pipelines.view import ViewConfig, viewer_page
    from tests.browser import show_page

    page = viewer_page(result.folder, ViewConfig(motions=()))
    assert page.data["keyframes"]["indices"] == [0]
    assert page.data["clips"][0]["times"] == [0.0, 1.0]  # the one pose, held
    shot = show_page(write_page(tmp_path / "photo.html", page), "paused=1")
    # the overlay pane shows the photo (not the page's background)
    assert np.abs(shot[100:, :450].astype(int) - (0x16, 0x18, 0x1B)).max(-1).mean() > 20
