"""``monoavatar view``: the page's data against the folder it shows, and the page itself in a
real headless Chromium (software WebGL): it loads without console errors, shows the avatar in
its texture's colour, moves when a motion plays, draws the fitted avatar over the input frame
where the input camera puts it (checked against our own rasteriser), shows the heat map, and
does the same served on the loopback address."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from scipy.spatial.transform import Rotation

from monoavatar.body import BodyModel
from monoavatar.cli import main
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.files import atomic_write_npz
from monoavatar.eval.heatmap import error_to_rgb
from monoavatar.io.avatar_folder import GROUND_TRUTH_FILE, KEYFRAMES_FILE, AvatarFolder
from monoavatar.io.gltf import read_glb_skin, skinned_mesh_from_body
from monoavatar.io.viewer_page import (
    atlas_grid,
    keyframe_atlas,
    serve_in_background,
    split_atlas,
    write_page,
)
from monoavatar.pipelines.view import ViewConfig, viewer_page
from monoavatar.render import rasterize
from tests.avatar_folders import make_params, make_report
from tests.browser import CHROMIUM, Browser

SKIN = (200, 120, 60)
BACKGROUND = (0x20, 0x24, 0x28)
WIDTH, HEIGHT = 400, 600  # the input camera's image


def _camera(body: BodyModel) -> PinholeCamera:
    """A camera 3.5 m in front of the body (which faces +Z), image y down, at mid-height."""
    with torch.no_grad():
        rest = body(shape=body.default_shape(1)).vertices[0].numpy()
    mid = 0.5 * (rest[:, 1].min() + rest[:, 1].max())
    R = np.diag([1.0, -1.0, -1.0])
    t = -R @ np.array([0.0, mid, 3.5])
    K = np.array([[600.0, 0, WIDTH / 2], [0, 600.0, HEIGHT / 2], [0, 0, 1]])
    return PinholeCamera(K, R, t, WIDTH, HEIGHT)


def _poses(body: BodyModel) -> np.ndarray:
    poses = np.zeros((2, body.num_joints, 3))
    poses[:, 0] = [0.0, 0.5, 0.0]  # turned a little
    poses[1, body.joint_index("shoulder_l"), 2] = 1.0  # left arm raised in the second
    poses[1, body.joint_index("elbow_l"), 1] = 0.8
    return poses


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory, anny64: BodyModel) -> Path:
    """An avatar folder as ``reconstruct`` writes it: glb, obj, texture of one colour, two
    key-frames (black pictures), and a ground-truth error of zero everywhere."""
    body = anny64
    out = tmp_path_factory.mktemp("view") / "avatar"
    shape = np.zeros(body.shape_dim)
    offsets = np.zeros((body.num_vertices, 3))
    texture = np.empty((64, 64, 3), np.uint8)
    texture[:] = SKIN
    params = make_params(body.identity, shape, offsets, _poses(body), camera=_camera(body),
                         translations=np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0]]))  # fmt: skip
    with torch.no_grad():
        rest = body(shape=torch.as_tensor(shape)[None], offsets=torch.as_tensor(offsets))
    frames = np.zeros((2, HEIGHT, WIDTH, 3), np.uint8)
    avatar = AvatarFolder(params, make_report(2), rest.rest_vertices[0].numpy(),
                          body.faces.numpy(), uv=body.uv.numpy(), face_uv=body.face_uv.numpy(),
                          texture=texture,
                          extras={KEYFRAMES_FILE: keyframe_atlas(frames)})  # fmt: skip
    avatar.save(out, glb=skinned_mesh_from_body(body, shape, offsets, texture))
    atomic_write_npz(out / GROUND_TRUTH_FILE, vertex_error_m=np.zeros(body.num_vertices))
    return out


# -- the page's data (no browser) -------------------------------------------------------------


def test_atlas_round_trip() -> None:
    rng = np.random.default_rng(0)
    frames = np.repeat(np.repeat(rng.integers(0, 256, (5, 12, 9, 3), dtype=np.uint8), 8, 1), 8, 2)
    assert atlas_grid(5) == (3, 2)
    tiles = split_atlas(keyframe_atlas(frames, tile_height=96), 5)
    assert tiles.shape == (5, 96, 72, 3)
    # blocks of 8 pixels survive JPEG within a few levels away from their edges
    assert np.abs(tiles[:, 4::8, 4::8].astype(int) - frames[:, 4::8, 4::8]).mean() < 6


def test_page_data_matches_the_folder(folder: Path, anny64: BodyModel) -> None:
    page = viewer_page(folder)
    params = AvatarFolder.load(folder, mesh=False).params
    names = [c["name"] for c in page.data["clips"]]
    assert names == ["fitted", "walk", "wave"]
    fitted = page.data["clips"][0]
    assert fitted["world"] and fitted["root"] == anny64.joint_names[0]
    for j, name in enumerate(anny64.joint_names):
        quats = np.asarray(fitted["rotations"][name]).reshape(-1, 4)
        back = Rotation.from_quat(quats).as_rotvec()
        np.testing.assert_allclose(back, params.poses[:, j], atol=1e-4)
    np.testing.assert_allclose(fitted["translations"], params.translations, atol=1e-5)
    assert page.data["keyframes"]["indices"] == [0, 1]
    assert page.data["camera"]["width"] == WIDTH
    # heat colours: one per glb vertex, the colour of zero error
    skin = read_glb_skin(page.glb)
    assert page.heat is not None and page.heat.shape == (len(skin.positions), 3)
    zero = np.round(255 * error_to_rgb(np.zeros(1)))
    np.testing.assert_array_equal(page.heat, np.broadcast_to(zero, page.heat.shape))
    # without built-in motions no body model is needed
    assert [c["name"] for c in viewer_page(folder, ViewConfig(motions=())).data["clips"]] == [
        "fitted"
    ]


def test_not_an_avatar_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "bad.glb").write_bytes(b"not a glb")
    for path, words in [(tmp_path / "empty", "not an avatar folder"),
                        (tmp_path / "notes.txt", "not a glb"),
                        (tmp_path / "bad.glb", "not a glTF binary"),
                        (tmp_path / "missing", "no such")]:  # fmt: skip
        assert main(["view", str(path), "--html", str(tmp_path / "page.html")]) == 2
        assert words in capsys.readouterr().err
    assert not (tmp_path / "page.html").exists()


# -- in the browser ---------------------------------------------------------------------------

needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium on PATH (the README's test command installs it)"
)


@pytest.fixture(scope="module")
def page_file(folder: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("page") / "avatar.html"
    assert main(["view", str(folder), "--html", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def browser() -> Browser:
    if CHROMIUM is None:
        pytest.skip("no chromium on PATH (the README's test command installs it)")
    with Browser(900, 700) as b:
        yield b


def _figure(image: np.ndarray, top: int = 80) -> np.ndarray:
    """(H, W) bool: pixels below the controls that are not the background."""
    diff = np.abs(image.astype(int) - BACKGROUND).max(axis=-1) > 12
    diff[:top] = False
    return diff


def _show(browser: Browser, url: str) -> np.ndarray:
    assert browser.open(url) == "ready", browser.evaluate("document.getElementById('status')"
                                                          ".textContent")  # fmt: skip
    errors = [c for c in browser.console if c[0] in ("error", "exception", "assert")]
    assert not errors, errors
    return browser.screenshot()


@needs_chromium
def test_page_shows_the_avatar_in_its_texture_colour(browser: Browser, page_file: Path) -> None:
    image = _show(browser, f"{page_file.as_uri()}#layout=orbit&paused=1&shading=albedo&floor=0")
    figure = _figure(image)
    assert figure.sum() > 5000
    inner = figure.copy()  # away from the antialiased outline
    inner[1:-1, 1:-1] &= figure[:-2, 1:-1] & figure[2:, 1:-1] & figure[1:-1, :-2] & figure[1:-1, 2:]
    np.testing.assert_allclose(np.median(image[inner], axis=0), SKIN, atol=8)


@needs_chromium
def test_playing_a_motion_moves_the_avatar(browser: Browser, page_file: Path) -> None:
    base = f"{page_file.as_uri()}#layout=orbit&paused=1&floor=0&clip=wave"
    still = _figure(_show(browser, base + "&t=0"))
    waving = _figure(_show(browser, base + "&t=1.0"))
    assert browser.evaluate("document.body.dataset.clip") == "wave"
    assert (still ^ waving).sum() > 800
    # the page plays by itself: unpaused, its clock runs and each frame is drawn at the
    # clock's time (the pixels of a time are checked above; comparing two screenshots of the
    # walk instead is flaky: from the front, half a gait cycle apart, the walk looks alike)
    _show(browser, f"{page_file.as_uri()}#layout=orbit&floor=0&clip=walk")
    assert browser.evaluate("document.getElementById('play').textContent") == "pause"
    start = float(browser.evaluate("document.body.dataset.played"))
    played = browser.evaluate(
        f"new Promise((done) => {{ const t0 = performance.now(); (function poll() {{"
        f" const p = parseFloat(document.body.dataset.played);"
        f" if (p >= {start} + 0.4 || performance.now() - t0 > 30000) done(p);"
        f" else setTimeout(poll, 50); }})(); }})"
    )
    assert played >= start + 0.4


@needs_chromium
def test_heat_map_toggle(browser: Browser, page_file: Path) -> None:
    image = _show(browser, f"{page_file.as_uri()}#layout=orbit&paused=1&heat=1&floor=0")
    figure = _figure(image)
    blue = np.round(255 * error_to_rgb(np.zeros(1)))[0]  # zero error
    np.testing.assert_allclose(np.median(image[figure], axis=0), blue, atol=12)


@needs_chromium
def test_overlay_matches_the_input_camera(browser: Browser, page_file: Path,
                                          anny64: BodyModel, folder: Path) -> None:  # fmt: skip
    image = _show(browser, f"{page_file.as_uri()}#layout=overlay&paused=1&t=0")
    rect = browser.evaluate("JSON.stringify(document.querySelector('#overlay canvas')"
                            ".getBoundingClientRect())")  # fmt: skip
    import json

    r = json.loads(rect)
    crop = image[round(r["top"]):round(r["top"] + r["height"]),
                 round(r["left"]):round(r["left"] + r["width"])]  # fmt: skip
    seen = np.asarray(Image.fromarray(crop).resize((WIDTH, HEIGHT), Image.Resampling.NEAREST))
    drawn = seen.max(axis=-1) > 40  # black frames; the avatar's normal colours are bright
    params = AvatarFolder.load(folder, mesh=False).params
    with torch.no_grad():
        posed = anny64(shape=torch.as_tensor(params.shape)[None],
                       pose=torch.as_tensor(params.poses[:1]),
                       translation=torch.as_tensor(params.translations[:1]))  # fmt: skip
    truth = rasterize(posed.vertices[0], anny64.faces, params.camera).face_id.numpy() >= 0
    iou = (drawn & truth).sum() / (drawn | truth).sum()
    assert truth.sum() > 5000 and iou > 0.9, iou


@needs_chromium
def test_served_page_and_motion_glb(browser: Browser, folder: Path, tmp_path: Path) -> None:
    from monoavatar.io.viewer_page import page_html

    server, _ = serve_in_background(page_html(viewer_page(folder, ViewConfig(motions=()))))
    try:
        port = server.server_address[1]
        image = _show(browser, f"http://127.0.0.1:{port}/#layout=orbit&paused=1&floor=0")
        assert _figure(image).sum() > 5000
    finally:
        server.shutdown()
        server.server_close()
    # a glb written by animate, on its own
    assert main(["animate", str(folder), "-o", str(tmp_path / "wave.glb"), "--motion", "wave",
                 "--frames", "12"]) == 0  # fmt: skip
    page = write_page(tmp_path / "wave.html", viewer_page(tmp_path / "wave.glb"))
    still = _figure(_show(browser, f"{page.as_uri()}#paused=1&t=0&floor=0"))
    moved = _figure(_show(browser, f"{page.as_uri()}#paused=1&t=0.2&floor=0"))
    assert still.sum() > 5000 and (still ^ moved).sum() > 300


def test_view_serves_the_page_until_stopped(folder: Path, tmp_path: Path) -> None:
    """``monoavatar view OUT --port 0`` prints its address and answers / with the page (and
    other paths with 404); an older folder without keyframes.jpg shows the orbit view alone."""
    import shutil
    import signal
    import subprocess
    import sys
    import urllib.error
    import urllib.request

    older = tmp_path / "older"
    shutil.copytree(folder, older)
    (older / KEYFRAMES_FILE).unlink()
    assert viewer_page(older, ViewConfig(motions=())).data["keyframes"] is None
    proc = subprocess.Popen([sys.executable, "-m", "monoavatar.cli", "view", str(older),
                             "--port", "0", "--no-motions"],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("monoavatar view: http://127.0.0.1:"), line
        url = line.split()[2]
        html = urllib.request.urlopen(url, timeout=30).read().decode()
        assert 'id="data-glb"' in html and "window.MONOAVATAR" in html
        assert 'id="data-atlas"' not in html
        with pytest.raises(urllib.error.HTTPError):
            urllib.request.urlopen(url + "elsewhere", timeout=30)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
    assert proc.returncode == 130


@needs_chromium
def test_a_paused_page_redraws_when_a_control_changes(browser: Browser, page_file: Path) -> None:
    image = _show(browser, f"{page_file.as_uri()}#layout=orbit&paused=1&floor=0")
    browser.evaluate("(() => { const s = document.getElementById('heat'); s.checked = true;"
                     " s.dispatchEvent(new Event('change')); })()")  # fmt: skip
    # two animation frames: the page's own loop, registered first, has drawn once since
    browser.evaluate("new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r)))")
    after = browser.screenshot()
    figure = _figure(image)
    blue = np.round(255 * error_to_rgb(np.zeros(1)))[0]
    assert np.abs(np.median(image[figure], axis=0) - blue).max() > 40  # shaded before
    np.testing.assert_allclose(np.median(after[_figure(after)], axis=0), blue, atol=12)


@needs_chromium
def test_a_large_mesh_moves_as_a_coarse_stand_in(browser: Browser, page_file: Path) -> None:
    """Above ``lod`` vertices the page draws a clustered copy while the avatar moves: fewer
    vertices, the same figure (silhouettes agree), no errors."""
    base = f"{page_file.as_uri()}#layout=orbit&paused=1&t=0&floor=0&clip=wave"
    full = _figure(_show(browser, base))
    assert browser.evaluate("document.body.dataset.proxyVertices") is None  # 15k: no stand-in
    coarse = _figure(_show(browser, base + "&lod=5000&proxy=1"))
    vertices = int(browser.evaluate("document.body.dataset.proxyVertices"))
    assert 3000 < vertices < 12000
    assert (full & coarse).sum() / (full | coarse).sum() > 0.9
