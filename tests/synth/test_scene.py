"""Synthetic scenes: determinism, exact masks, keypoints on the right body parts, files, errors."""

import json
from dataclasses import replace

import av
import numpy as np
import pytest
import torch
from PIL import Image

from monoavatar.body import MEDIAPIPE_LANDMARKS
from monoavatar.cli import main
from monoavatar.core.camera import PinholeCamera
from monoavatar.io.export_mesh import read_obj
from monoavatar.render import rasterize
from monoavatar.synth import scene as scene_mod
from monoavatar.synth.scene import SynthConfig, SynthError, generate

SMALL = {"width": 160, "height": 160, "texture_size": 128, "posed_every": 1}


@pytest.fixture(scope="module")
def turnaround(anny_local, tmp_path_factory):
    out = tmp_path_factory.mktemp("scenes") / "turn"
    generate(out, SynthConfig(kind="turnaround", frames=4, seed=3, noise="none", **SMALL),
             body=anny_local, progress=False)  # fmt: skip
    return out


def test_same_seed_same_scene_other_seed_differs(anny_local, turnaround, tmp_path):
    again = tmp_path / "again"
    generate(again, SynthConfig(kind="turnaround", frames=4, seed=3, noise="none", **SMALL),
             body=anny_local, progress=False)  # fmt: skip
    a = np.asarray(Image.open(turnaround / "frames" / "000002.png"))
    b = np.asarray(Image.open(again / "frames" / "000002.png"))
    assert np.array_equal(a, b)
    other = tmp_path / "other"
    generate(other, SynthConfig(kind="turnaround", frames=1, seed=4, noise="none", **SMALL),
             body=anny_local, progress=False)  # fmt: skip
    c = np.asarray(Image.open(other / "frames" / "000000.png"))
    assert not np.array_equal(np.asarray(Image.open(turnaround / "frames" / "000000.png")), c)


def test_mask_is_the_projection_of_the_posed_ground_truth_mesh(turnaround):
    import trimesh

    cam = PinholeCamera.load_json(turnaround / "camera.json")
    for i in (0, 2):
        mesh = trimesh.load(turnaround / "gt" / "posed" / f"{i:06d}.ply", process=False)
        ys, xs = np.mgrid[0 : cam.height, 0 : cam.width]
        px = torch.tensor(np.stack([xs + 0.5, ys + 0.5], -1).reshape(-1, 2), dtype=torch.float64)
        o, d = cam.pixel_rays(px)
        hit = mesh.ray.intersects_any(o.numpy(), d.numpy()).reshape(cam.height, cam.width)
        mask = np.asarray(Image.open(turnaround / "masks" / f"{i:06d}.png")) > 127
        assert mask.sum() > 0.05 * mask.size
        assert (hit == mask).mean() >= 0.995


EXPECTED_PARTS = {
    "nose": {"head", "neck"},
    "left_shoulder": {"collar_l", "shoulder_l", "spine3"},
    "right_shoulder": {"collar_r", "shoulder_r", "spine3"},
    "left_elbow": {"shoulder_l", "elbow_l"},
    "right_elbow": {"shoulder_r", "elbow_r"},
    "left_wrist": {"elbow_l", "wrist_l"},
    "right_wrist": {"elbow_r", "wrist_r"},
    "left_knee": {"hip_l", "knee_l"},
    "right_knee": {"hip_r", "knee_r"},
    "left_hip": {"pelvis", "spine1", "hip_l"},
    "right_hip": {"pelvis", "spine1", "hip_r"},
    "left_ankle": {"knee_l", "ankle_l"},
    "right_ankle": {"knee_r", "ankle_r"},
}


def test_keypoints_project_onto_the_right_body_parts(anny_local, turnaround):
    """Re-render the posed mesh's dominant-joint labels and look them up at the keypoints."""
    import trimesh

    from monoavatar.body.subdivide import subdivide

    sub = subdivide(anny_local.faces, anny_local.uv, anny_local.face_uv, anny_local.skin_weights)
    parts = sub.weights.argmax(1).numpy()
    cam = PinholeCamera.load_json(turnaround / "camera.json")
    kp = np.load(turnaround / "keypoints.npz")["keypoints"]
    checked = 0
    for i in range(4):
        mesh = trimesh.load(turnaround / "gt" / "posed" / f"{i:06d}.ply", process=False)
        frags = rasterize(np.asarray(mesh.vertices), np.asarray(mesh.faces), cam)
        for name, allowed in EXPECTED_PARTS.items():
            x, y, vis = kp[i, MEDIAPIPE_LANDMARKS.index(name)]
            if vis < 0.5:
                continue
            r, c = int(y), int(x)
            window = frags.face_id[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2].reshape(-1)
            window = window[window >= 0].numpy()
            assert len(window), f"{name} of frame {i} is off the body"
            labels = {anny_local.joint_names[p] for p in parts[sub.faces.numpy()[window]].ravel()}
            assert labels & allowed, f"{name} of frame {i} lands on {labels}"
            checked += 1
    assert checked >= 20


def test_files_and_description(turnaround):
    scene = json.loads((turnaround / "scene.json").read_text())
    assert scene["units"]["length"] == "metre"
    assert scene["config"]["frames"] == 4
    kp = np.load(turnaround / "keypoints.npz")
    assert kp["keypoints"].shape == (4, 33, 3) and kp["keypoints_3d"].shape == (4, 33, 3)
    assert (turnaround / "gt" / "subject_000" / "canonical.obj").is_file()
    assert (turnaround / "gt" / "subject_000" / "canonical.png").is_file()
    params = np.load(turnaround / "gt" / "params.npz")
    # the stature (a person's stated height: the body without hair and shoes) lies under the
    # clothed canonical mesh's height by at most the hair on the crown and the shoes' soles
    canonical, _ = read_obj(turnaround / "gt" / "subject_000" / "canonical.obj")
    subject = scene["subjects"][0]
    assert subject["height_m"] == pytest.approx(float(np.ptp(canonical[:, 1])), abs=1e-5)
    assert 0.0 < subject["height_m"] - subject["stature_m"] <= subject["hair_volume_m"] + 0.01
    assert params["poses"].shape == (4, 20, 3)
    with av.open(str(turnaround / "video.mp4")) as container:
        assert sum(1 for _ in container.decode(video=0)) == 4
    sheet = np.asarray(Image.open(turnaround / "preview" / "contact_sheet.png"))
    assert sheet.ndim == 3 and sheet.std() > 10
    # the person turns: frame 2 (half a turn) shows the back, the nose is hidden
    assert kp["keypoints"][0, 0, 2] == 1 and kp["keypoints"][2, 0, 2] == 0
    # the hips (joints deep inside the pelvis) are seen from the front and from the back, and
    # one of them is hidden in a side view
    hips = [MEDIAPIPE_LANDMARKS.index("left_hip"), MEDIAPIPE_LANDMARKS.index("right_hip")]
    assert kp["keypoints"][[0, 2]][:, hips, 2].all()
    assert kp["keypoints"][[1, 3]][:, hips, 2].sum(axis=1).tolist() == [1, 1]
    # the detector's view (no jitter at noise "none"): every landmark where it projects, the
    # hidden ones (the nose seen from behind) with confidence 0.5
    observed, exact = kp["observed"], kp["keypoints"]
    np.testing.assert_array_equal(observed[..., :2], exact[..., :2])
    np.testing.assert_array_equal(observed[..., 2], np.where(exact[..., 2] > 0, 1.0, 0.5))
    assert observed[2, 0, 2] == 0.5 and 0 < observed[2, 0, 0] < 160


def test_detector_keypoints_guess_hidden_landmarks_with_twice_the_error():
    rng = np.random.default_rng(0)
    exact = np.zeros((4000, 33, 3))
    exact[..., :2] = rng.uniform(0, 500, (4000, 33, 2))
    exact[:, :10, 2] = 1.0  # landmarks 0-9 visible, the rest hidden
    known = np.ones(33, bool)
    known[32] = False  # one the body model lacks
    out = scene_mod.detector_keypoints(exact, 3.0, np.random.default_rng(1), known)
    error = out[..., :2] - exact[..., :2]
    assert error[:, :10].std() == pytest.approx(3.0, rel=0.02)
    assert error[:, 10:32].std() == pytest.approx(3.0 * scene_mod.HIDDEN_JITTER, rel=0.02)
    assert abs(error[:, :32].mean()) < 0.02  # unbiased
    np.testing.assert_array_equal(out[:, :10, 2], 1.0)
    np.testing.assert_array_equal(out[:, 10:32, 2], scene_mod.HIDDEN_CONFIDENCE)
    np.testing.assert_array_equal(out[:, 32], 0.0)


def test_clothing_is_real_displacement(anny_local, turnaround):
    params = np.load(turnaround / "gt" / "params.npz")
    disp = params["displacements"][0]
    assert disp.max() > 0.003  # at least hair or garments stand off the skin
    assert params["shapes"].shape[1] == anny_local.shape_dim
    assert np.count_nonzero(params["shapes"][0, 6:]) > 10  # local changes beyond the phenotypes


def test_failure_leaves_nothing_behind(anny_local, tmp_path, monkeypatch):
    def boom(*args, **kwargs):
        raise RuntimeError("renderer exploded")

    monkeypatch.setattr(scene_mod, "render_frame", boom)
    with pytest.raises(RuntimeError):
        generate(tmp_path / "x", SynthConfig(frames=2, **SMALL), body=anny_local, progress=False)
    assert list(tmp_path.iterdir()) == []


def test_bad_settings_and_folders(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "a.txt").write_text("x")
    with pytest.raises(SynthError, match="not empty"):
        generate(tmp_path / "full", SynthConfig(frames=1, **SMALL))
    with pytest.raises(SynthError, match="unknown sequence kind"):
        SynthConfig(kind="dance").validate()
    with pytest.raises(SynthError, match="even"):
        SynthConfig(width=101).validate()
    assert main(["synth", "turnaround", "-o", str(tmp_path / "full"), "--frames", "1"]) == 2


def test_cli_photo_and_motion(tmp_path, capsys):
    args = ["--size", "96", "96", "--texture-size", "64", "--frames", "2", "--seed", "1"]
    assert main(["synth", "photo", "-o", str(tmp_path / "p"), *args]) == 0
    assert main(["synth", "motion", "-o", str(tmp_path / "m"), *args]) == 0
    assert "contact_sheet.png" in capsys.readouterr().out
    scene = json.loads((tmp_path / "p" / "scene.json").read_text())
    assert len(scene["subjects"]) == 2  # one person per photo
    assert not (tmp_path / "p" / "video.mp4").exists()


@pytest.mark.parametrize("kind", ["walk", "jog"])
def test_gait_moves_along_an_oblique_path_in_view_with_camera_frame_joints(anny_local, kind,
                                                                          tmp_path):  # fmt: skip
    out = tmp_path / kind
    generate(out, SynthConfig(kind=kind, frames=40, seed=5, noise="none", **SMALL),
             body=anny_local, progress=False)  # fmt: skip
    params = np.load(out / "gt" / "params.npz")
    camera = PinholeCamera.load_json(out / "camera.json")
    joints, joints_cam = params["joints"], params["joints_camera"]
    # the camera-frame joints are the world joints moved by the camera's extrinsics
    np.testing.assert_allclose(joints_cam, joints @ camera.R.T + camera.t, atol=1e-9)
    # and the world joints are the body model's, posed by the scene's parameters
    with torch.no_grad():
        posed = anny_local(shape=torch.as_tensor(params["shapes"][:1]).expand(40, -1),
                           pose=torch.as_tensor(params["poses"], dtype=anny_local.dtype),
                           translation=torch.as_tensor(params["translations"],
                                                       dtype=anny_local.dtype))  # fmt: skip
    np.testing.assert_allclose(joints, posed.joints.double().numpy(), atol=1e-5)
    # the person travels 35-65 degrees off the camera's axis (towards or away from it)
    travel = params["translations"][-1] - params["translations"][0]
    travel_cam = camera.R @ travel
    off_axis = np.degrees(np.arctan2(abs(travel_cam[0]), abs(travel_cam[2])))
    assert 25.0 < off_axis < 75.0 and np.linalg.norm(travel) > 0.2
    # every frame shows the whole person: the mask stays off the image border
    for i in (0, 20, 39):
        mask = np.asarray(Image.open(out / "masks" / f"{i:06d}.png")) > 0
        assert mask.sum() > 200
        assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def test_painted_eyes_sit_on_the_subjects_own_eyes(anny_local):
    """A short subject's eyes (white and pupil) are painted where its own eye landmarks are,
    not where an average body's would be (3 cm higher and more)."""
    from monoavatar.body.subdivide import subdivide
    from monoavatar.synth.subjects import build_subject, sample_subject

    spec = sample_subject(np.random.default_rng(5), anny_local, "minimal")
    shape = spec.shape.copy()
    shape[4] = -0.35  # short
    subject = build_subject(anny_local, replace(spec, shape=shape), texture_size=512)
    sub = subdivide(anny_local.faces, anny_local.uv, anny_local.face_uv, anny_local.skin_weights)
    with torch.no_grad():
        own = anny_local.keypoints(anny_local.rest_shape(subject.shape)[0])[0].numpy()
        average = anny_local.keypoints(anny_local.rest_shape(anny_local.default_shape())[0])[0]
        average = average.numpy()
        fine = sub.apply(anny_local.rest_shape(subject.shape)[0])[0].numpy()
    faces, face_uv, uv = sub.faces.numpy(), sub.face_uv.numpy(), sub.uv.numpy()
    centroids = fine[faces].mean(axis=1)
    tex = subject.texture
    for side in ("left", "right"):
        eye = own[MEDIAPIPE_LANDMARKS.index(f"{side}_eye")]
        assert np.linalg.norm(eye - average[MEDIAPIPE_LANDMARKS.index(f"{side}_eye")]) > 0.03
        nearest = np.argsort(np.linalg.norm(centroids - eye, axis=1))[:3]
        texel = (uv[face_uv[nearest]].mean(axis=1) * tex.shape[0]).astype(int)
        colour = tex[texel[:, 1], texel[:, 0]]
        eye_colours = np.array([[0.92, 0.92, 0.9], [0.25, 0.18, 0.12]])  # white, pupil
        gap = np.abs(colour[:, None] - eye_colours[None]).max(axis=2).min(axis=1)
        assert (gap < 0.01).all(), colour


# -- capture profiles ---------------------------------------------------------------------


def test_uneven_progress_never_runs_backwards_and_ends_one_turn_on():
    from monoavatar.body.motion import uneven_progress

    n = 400
    p = uneven_progress(n, 0.35, np.random.default_rng(2))
    speed = np.diff(p) * n  # frames per turn → relative speed, mean 1
    assert p[0] == 0.0 and np.all(speed > 0)
    assert 0.65 - 1e-3 <= speed.min() and speed.max() <= 1.35 + 1e-3
    assert speed.max() - speed.min() > 0.3  # it does vary
    # p(1) = 1: the sinusoids' integrals vanish over whole periods
    assert p[-1] + (p[-1] - p[-2]) == pytest.approx(1.0, abs=2e-3)
    np.testing.assert_array_equal(uneven_progress(5, 0.0, np.random.default_rng(0)),
                                  np.arange(5) / 5)  # fmt: skip
    with pytest.raises(ValueError, match="wobble"):
        uneven_progress(5, 1.0, np.random.default_rng(0))


def test_a_rolled_off_centre_camera_shows_the_person_rolled_and_shifted():
    rng = lambda: np.random.default_rng(7)  # noqa: E731 - the same draws for every camera
    level = scene_mod.make_camera(rng(), 320, 240)
    roll = np.deg2rad(4.0)
    rolled = scene_mod.make_camera(rng(), 320, 240, roll=roll)
    # rolling the camera turns the whole image by the roll about the principal point
    points = torch.tensor([[0.0, 0.0, 0.0], [0.1, 1.0, 0.2], [-0.3, -0.8, 0.1]],
                          dtype=torch.float64)  # fmt: skip
    p_level = level.project(points)[0].numpy() - level.K[:2, 2]
    p_rolled = rolled.project(points)[0].numpy() - rolled.K[:2, 2]
    c, s = np.cos(roll), np.sin(roll)
    np.testing.assert_allclose(p_rolled, p_level @ np.array([[c, -s], [s, c]]).T, atol=1e-9)
    # aimed beside the person: they appear about the asked fraction of the image right of
    # and above where a camera aimed at them shows them, the focal length shortened to keep
    # the margin
    moved = scene_mod.make_camera(rng(), 320, 240, shift=(0.1, -0.03))
    shift = (moved.project(points[:1])[0].numpy()[0] - moved.K[:2, 2]
             - p_level[0] * moved.K[0, 0] / level.K[0, 0]) / np.array([320, 240])  # fmt: skip
    assert shift[0] == pytest.approx(0.1, abs=0.01) and shift[1] == pytest.approx(-0.03, abs=0.01)
    assert moved.K[0, 0] < level.K[0, 0]


def test_phone_take_blurs_drifts_and_encodes_coarser(anny_local, tmp_path):
    from monoavatar.synth.options import CAPTURES

    studio = scene_mod._phone_take(CAPTURES["studio"], 50, np.random.default_rng(0))
    assert studio.turns == 1.0 and studio.progress is None and studio.roll == 0.0
    assert studio.shift == (0.0, 0.0) and np.all(studio.gain == 1.0)
    phone = scene_mod._phone_take(CAPTURES["phone"], 50, np.random.default_rng(0))
    assert 0.85 <= phone.turns <= 1.15 and abs(phone.roll) <= np.deg2rad(4.0)
    assert np.all(np.abs(phone.gain - 1.0) <= 0.12 + 1e-6) and np.ptp(phone.gain) > 0.01
    assert studio.sun is None and phone.sun is not None and phone.sun.share == 0.5
    assert np.linalg.norm(phone.sun.direction) == pytest.approx(1.0)
    assert np.sin(np.deg2rad(20)) - 1e-9 <= phone.sun.direction[1] <= np.sin(np.deg2rad(60))

    out = tmp_path / "phone"
    generate(out, SynthConfig(kind="turnaround", frames=6, seed=3, noise="none",
                              capture="phone", **SMALL), body=anny_local, progress=False)
    info = json.loads((out / "scene.json").read_text())
    assert info["config"]["capture"] == "phone" and info["capture"]["video_crf"] == 30.0
    # motion blur: the frame is the mean of renders over the shutter, so it differs from the
    # sharp render near the moving outline only (the exact mask is the sharp render's)
    from monoavatar.body.motion import turnaround

    poses = turnaround(anny_local, 120, np.random.default_rng(1))
    still = np.zeros((120, 3))
    camera = PinholeCamera.load_json(out / "camera.json")
    subject = scene_mod.build_subject(
        anny_local, scene_mod.sample_subject(np.random.default_rng(3), anny_local, None), 128)
    background = np.zeros((160, 160, 3), np.float32)
    sh = np.load(out / "gt" / "params.npz")["sh"][0]
    sharp = scene_mod.render_frame(anny_local, subject, poses[30], still[30], camera, sh,
                                   background)  # fmt: skip
    blurred = scene_mod._exposed(sharp["image"], anny_local, subject, poses, still, 30, 0.5,
                                 camera, sh, background)  # fmt: skip
    moved = np.abs(blurred - sharp["image"]).max(-1) > 2e-3
    assert moved.any() and moved.sum() < 0.5 * sharp["mask"].sum()
    frozen = np.repeat(poses[30:31], 120, 0)
    same = scene_mod._exposed(sharp["image"], anny_local, subject, frozen, still, 30, 0.5,
                              camera, sh, background)  # fmt: skip
    np.testing.assert_allclose(same, sharp["image"], atol=1e-6)


def test_a_higher_rate_factor_makes_a_smaller_video(tmp_path):
    from monoavatar.io.export_mesh import write_mp4

    rng = np.random.default_rng(0)
    frames = [np.clip(rng.normal(128, 40, (64, 64, 3)), 0, 255).astype(np.uint8)
              for _ in range(4)]  # fmt: skip
    write_mp4(tmp_path / "fine.mp4", frames, crf=18)
    write_mp4(tmp_path / "coarse.mp4", frames, crf=35)
    assert (tmp_path / "coarse.mp4").stat().st_size < 0.7 * (tmp_path / "fine.mp4").stat().st_size
    with av.open(str(tmp_path / "coarse.mp4")) as container:
        assert sum(1 for _ in container.decode(video=0)) == 4


def test_cli_capture_option(tmp_path, capsys):
    args = ["--size", "96", "96", "--texture-size", "64", "--frames", "2"]
    assert main(["synth", "turnaround", "-o", str(tmp_path / "t"), *args, "--capture",
                 "phone"]) == 0  # fmt: skip
    assert json.loads((tmp_path / "t" / "scene.json").read_text())["config"]["capture"] == "phone"
    with pytest.raises(SystemExit):
        main(["synth", "turnaround", "-o", str(tmp_path / "u"), *args, "--capture", "cinema"])
    with pytest.raises(SynthError, match="unknown capture"):
        SynthConfig(capture="cinema").validate()


# -- the wide subject distribution (suite v2) -------------------------------------------------


def test_wide_subjects_span_the_heights_and_garments_asked(anny_local):
    from monoavatar.synth.options import HAIR_STYLES
    from monoavatar.synth.subjects import WIDE_HEIGHTS, sample_subject

    heights = []
    for seed in range(6):
        spec = sample_subject(np.random.default_rng(seed), anny_local, "loose", "wide")
        with torch.no_grad():
            rest, _ = anny_local.rest_shape(torch.as_tensor(spec.shape, dtype=torch.float32)[None])
        heights.append(float(np.ptp(rest[0, :, 1].numpy())))
        assert 0.006 <= spec.top_thickness <= 0.025 and 0.006 <= spec.bottom_thickness <= 0.025
        assert 0.006 <= spec.shoe_height <= 0.02 and spec.hair_style in HAIR_STYLES
        assert np.mean(spec.shape[6:] != 0) > 0.3  # denser local changes than standard's 0.25
        # people are nearly symmetric: each right-side local change within 0.1 of its left
        names = anny_local.local_change_names
        pairs = [(6 + i, 6 + names.index("r-" + n[2:])) for i, n in enumerate(names)
                 if n.startswith("l-") and "r-" + n[2:] in names]  # fmt: skip
        left = np.array([spec.shape[i] for i, _ in pairs])
        right = np.array([spec.shape[j] for _, j in pairs])
        assert len(pairs) > 50 and np.all(np.abs(right - left) <= 0.1 + 1e-12)
        assert np.count_nonzero(left) > 10 and np.all((left == 0) == (right == 0))
    assert all(WIDE_HEIGHTS[0] <= h <= WIDE_HEIGHTS[1] for h in heights)
    assert max(heights) - min(heights) > 0.1
    standard = sample_subject(np.random.default_rng(0), anny_local, "loose")
    assert (standard.hair_style, standard.shoe_height) == ("cropped", 0.008)
    with pytest.raises(ValueError, match="variety"):
        sample_subject(np.random.default_rng(0), anny_local, "loose", "narrow")
    with pytest.raises(SynthError, match="unknown variety"):
        SynthConfig(variety="narrow").validate()


def test_hair_styles_put_hair_where_they_say(anny_local):
    from monoavatar.synth.subjects import build_subject, sample_subject

    spec = replace(sample_subject(np.random.default_rng(5), anny_local, "tshirt-shorts", "wide"),
                   hair_volume=0.02)  # fmt: skip
    built = {style: build_subject(anny_local, replace(spec, hair_style=style), 64)
             for style in ("cropped", "full", "bun", "long")}  # fmt: skip
    hair = {k: b.displacement * (b.garment == 3) for k, b in built.items()}
    scalp = built["cropped"].garment == 3
    np.testing.assert_allclose(hair["cropped"][scalp], 0.02)  # even on the scalp
    assert hair["full"].max() > 1.5 * 0.02 and hair["bun"].max() > 0.02 + 0.035
    # long hair covers the nape, below the scalp, which the cropped style leaves bare
    nape = (built["long"].garment == 3) & ~scalp
    hang = built["long"].displacement[nape]
    assert nape.sum() > 100 and (hang > 0.01).all() and (hang > 0.02).sum() > 50
    assert np.array_equal(built["bun"].garment == 3, scalp)  # a bun stays on the scalp


def test_the_sun_lights_what_faces_it_and_casts_shadows():
    # a 2 m floor (y = 0, normal +y) and a 0.4 m square 0.5 m above it, the sun straight up
    def quad(half: float, y: float) -> np.ndarray:
        return np.array([[-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half]])

    vertices = torch.as_tensor(np.concatenate([quad(1.0, 0.0), quad(0.2, 0.5)]))
    faces = torch.tensor([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]])  # both facing +y
    camera = PinholeCamera.look_at(np.array([0.0, 3.0, 1.5]), np.zeros(3),
                                   np.array([0, 0, -1.0]), 150.0, 160, 120)  # fmt: skip
    frags = rasterize(vertices, faces, camera)
    tilt = np.deg2rad(10.0)
    sun = scene_mod.Sun(np.array([0.0, np.cos(tilt), np.sin(tilt)]), np.array([1.0, 0.9, 0.8]),
                        0.5)  # fmt: skip
    light = scene_mod.sun_shading(vertices.float(), faces, frags, sun)
    face = frags.face_id.numpy()[frags.face_id.numpy() >= 0]
    rows, cols = np.nonzero(frags.face_id.numpy() >= 0)
    rays = camera.pixel_rays(torch.as_tensor(np.stack([cols + 0.5, rows + 0.5], 1)))
    origin, direction = (r.numpy() for r in rays)
    floor = face < 2
    hit = origin + direction * (-origin[:, 1:2] / direction[:, 1:2])  # the floor point seen
    # where the square's shadow falls: the floor point moved towards the sun to y = 0.5
    up = hit + sun.direction[None] * (0.5 / sun.direction[1])
    shadow = floor & (np.abs(up[:, 0]) < 0.18) & (np.abs(up[:, 2]) < 0.18)
    sunny = floor & ((np.abs(up[:, 0]) > 0.25) | (np.abs(up[:, 2]) > 0.25))
    assert shadow.sum() > 30 and sunny.sum() > 300
    np.testing.assert_allclose(light[shadow], 0.0)
    np.testing.assert_allclose(light[sunny], np.cos(tilt) * sun.colour[None].repeat(sunny.sum(), 0),
                               rtol=1e-5)  # fmt: skip
    np.testing.assert_allclose(light[face >= 2], np.cos(tilt) * sun.colour[None].repeat(
        (face >= 2).sum(), 0), rtol=1e-5)  # the square's top is lit
