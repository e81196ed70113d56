"""Training photos for the photo network: the rendered photo, the fitter-like perturbation,
the partial texture (checked against a render of known texture) and a whole sample."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from monoavatar.body import lbs
from monoavatar.core.camera import PinholeCamera
from monoavatar.learn.photo_data import (
    CLASS_CHANNELS,
    INPUT_CHANNELS,
    TARGET_CHANNELS,
    FitError,
    PhotoDataset,
    PhotoDataSettings,
    PhotoSample,
    network_input,
    partial_texture,
    photo_sample,
    placed_body,
    render_photo,
    template_positions,
    write_shard,
)
from monoavatar.learn.uvmaps import uv_layout
from monoavatar.render import rasterize, render_textured

SETTINGS = PhotoDataSettings(map_size=128, image_size=256, texture_size=256)


@pytest.fixture(scope="module")
def layout(anny32):  # type: ignore[no-untyped-def]
    return uv_layout(anny32, 128)


@pytest.fixture(scope="module")
def scene(anny_local):  # type: ignore[no-untyped-def]
    return render_photo(anny_local, 7, SETTINGS)


def test_photo_is_reproducible_and_within_the_drawn_ranges(anny_local, scene) -> None:  # type: ignore[no-untyped-def]
    again = render_photo(anny_local, 7, SETTINGS)
    assert np.array_equal(again.image, scene.image)
    assert abs(scene.yaw) <= np.deg2rad(SETTINGS.yaw_deg)
    assert SETTINGS.distance_m[0] <= scene.distance <= SETTINGS.distance_m[1]
    assert scene.mask.sum() > 500
    other = render_photo(anny_local, 8, SETTINGS)
    assert not np.array_equal(other.image, scene.image)


def test_no_error_perturbs_nothing(anny32, scene) -> None:  # type: ignore[no-untyped-def]
    none = FitError.none(anny32.num_joints)
    shape = scene.subject.spec.shape[:6]
    pose, s, root = none.perturb(np.random.default_rng(0), scene.pose, shape)
    np.testing.assert_allclose(pose, scene.pose, atol=1e-9)
    assert np.array_equal(s, shape) and np.array_equal(root, np.zeros(3))


def test_perturbation_has_the_stated_spread(anny32) -> None:  # type: ignore[no-untyped-def]
    """The residual rotation R_true^T R_pert of many draws has the stated std per axis."""
    J = anny32.num_joints
    std = np.full((J, 3), 0.1)
    error = FitError(std, np.array([0.01, 0.02, 0.05]), np.full(6, 0.2))
    rng = np.random.default_rng(1)
    pose = 0.3 * rng.standard_normal((J, 3))
    draws = [error.perturb(rng, pose, np.zeros(6)) for _ in range(400)]
    r0 = lbs.axis_angle_to_matrix(torch.as_tensor(pose))
    residual = np.stack([lbs.matrix_to_axis_angle(r0.transpose(-1, -2) @ lbs.axis_angle_to_matrix(
        torch.as_tensor(d[0]))).numpy() for d in draws])  # fmt: skip
    np.testing.assert_allclose(residual.std(axis=0), std, rtol=0.2)
    roots = np.stack([d[2] for d in draws])
    np.testing.assert_allclose(roots.std(axis=0), [0.01, 0.02, 0.05], rtol=0.2)


def test_placed_body_keeps_the_image_of_the_root(anny32, scene) -> None:  # type: ignore[no-untyped-def]
    """With the true shape and no offset the body is posed as in the photo; a taller body is
    moved away from the camera so that its root projects to the same pixel."""
    shape = np.asarray(scene.subject.spec.shape[:6])
    v = placed_body(anny32, scene, scene.pose, shape, shape, np.zeros(3))
    with torch.no_grad():
        out = anny32(
            shape=torch.as_tensor(shape, dtype=anny32.dtype)[None],
            pose=torch.as_tensor(scene.pose, dtype=anny32.dtype)[None],
        )
    np.testing.assert_allclose(v, out.vertices[0].double().numpy(), atol=1e-5)
    taller = shape.copy()
    taller[4] += 0.5  # Anny's height phenotype
    v2 = placed_body(anny32, scene, scene.pose, shape, taller, np.zeros(3))
    cam = scene.camera
    with torch.no_grad():
        _, j1 = anny32.rest_shape(torch.as_tensor(shape, dtype=anny32.dtype)[None])
    assert np.ptp(v2[:, 1]) > np.ptp(v[:, 1]) * 1.02
    # the mean of all vertices projects to nearly the same pixel (the body scaled about the
    # camera centre)
    p1, _ = cam.project(torch.as_tensor(v.mean(0, keepdims=True)))
    p2, _ = cam.project(torch.as_tensor(v2.mean(0, keepdims=True)))
    assert float((p1 - p2).norm()) < 2.0


def test_partial_texture_reads_back_a_known_texture(anny32, layout) -> None:  # type: ignore[no-untyped-def]
    """Render the body with a texture that encodes each texel's UV, unlit; the partial texture
    of that render holds, on its visible texels, the colour of those UVs."""
    S = 256
    u, v = np.meshgrid((np.arange(S) + 0.5) / S, (np.arange(S) + 0.5) / S)
    texture = np.stack([u, v, np.full_like(u, 0.5)], axis=2)
    with torch.no_grad():
        verts = anny32(pose=anny32.zero_pose()).vertices[0].double()
    cam = PinholeCamera.look_at(np.array([0.3, 0.2, 3.0]), np.zeros(3), np.array([0, 1.0, 0]),
                                400.0, 320, 320)  # fmt: skip
    frags = rasterize(verts, anny32.faces, cam)
    image = render_textured(
        verts,
        anny32.faces,
        frags,
        anny32.uv,
        anny32.face_uv,
        torch.as_tensor(texture),
        background=torch.zeros(320, 320, 3),
    )
    image8 = (np.clip(image.numpy(), 0, 1) * 255 + 0.5).astype(np.uint8)
    mask = (frags.face_id >= 0).numpy()
    colour, visible = partial_texture(verts.numpy(), anny32, image8, mask, cam, 128)
    assert 0.2 < visible[layout.chart].mean() < 0.65  # the front, not the back
    assert not visible[~layout.chart].any()
    uu, vv = np.meshgrid((np.arange(128) + 0.5) / 128, (np.arange(128) + 0.5) / 128)
    err = np.abs(colour[visible][:, :2] - np.stack([uu, vv], 2)[visible])
    assert np.median(err) < 0.01 and np.mean(err) < 0.02
    assert np.all(colour[~visible] == 0)


def test_network_input_layout() -> None:
    rng = np.random.default_rng(0)
    colour = rng.uniform(0, 1, (32, 32, 3)).astype(np.float32)
    visible = rng.random((32, 32)) < 0.5
    template = rng.normal(size=(32, 32, 3)).astype(np.float32)
    x = network_input(colour, visible, template)
    assert x.shape == (INPUT_CHANNELS, 32, 32) and x.dtype == np.float32
    np.testing.assert_allclose(x[:3].transpose(1, 2, 0)[visible], 2 * colour[visible] - 1)
    assert np.all(x[:3].transpose(1, 2, 0)[~visible] == 0)
    assert np.array_equal(x[3] > 0.5, visible)
    np.testing.assert_allclose(x[4:].transpose(1, 2, 0), template)


def test_sample_targets_and_weights(anny_local, anny32, layout) -> None:  # type: ignore[no-untyped-def]
    template = template_positions(anny32, layout)
    sample = photo_sample(anny_local, anny32, layout, template, 7, SETTINGS,
                          FitError.none(anny32.num_joints))  # fmt: skip
    assert sample.input.shape == (INPUT_CHANNELS, 128, 128)
    assert sample.target.shape == (TARGET_CHANNELS, 128, 128)
    assert np.array_equal(sample.weight[0] > 0, layout.chart)
    visible = sample.input[3] > 0.5
    assert not visible[~layout.chart].any() and 0.1 < sample.visible_fraction < 0.7
    # clothing and hair lie outside the body: the displacement along the normal is mostly >= 0
    disp, normals = sample.target[:3], sample.target[3:]
    along = (disp * normals).sum(0)[layout.chart]
    assert np.mean(along > -0.05) > 0.8
    assert 0.2 < sample.fill < 1.0

    # garment classes: probabilities on the chart, none off it; hair on the head (the
    # template's highest texels), skin or shoes at the lowest
    classes = sample.classes
    assert classes.shape == (CLASS_CHANNELS, 128, 128)
    np.testing.assert_allclose(classes.sum(0)[layout.chart], 1.0, atol=1e-5)
    assert np.all(classes[:, ~layout.chart] == 0)
    height = template[..., 1][layout.chart]
    label = classes.argmax(0)[layout.chart]
    assert np.median(height[label == 3]) > np.quantile(height, 0.9)
    assert np.all(np.isin(label[height < np.quantile(height, 0.01)], [0, 4]))


def _sample(target: np.ndarray, classes: np.ndarray, seed: int) -> PhotoSample:
    size = target.shape[-1]
    return PhotoSample(np.zeros((INPUT_CHANNELS, size, size), np.float32), target,
                       np.ones((1, size, size), np.float32), classes, seed, 0.0, 0.5, 0.5)


def test_class_means_by_hand(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Two shards, three samples of 2×2 texels: each class's mean target per texel is the
    class-probability-weighted mean over the samples; a class that covers a texel in less
    than half a sample falls back to the overall mean; with_classes appends the classes."""
    k, size = CLASS_CHANNELS, 2
    targets = [np.full((6, size, size), v, np.float32) for v in (1.0, 2.0, 4.0)]
    classes = [np.zeros((k, size, size), np.float32) for _ in range(3)]
    classes[0][0], classes[1][0] = 1.0, 1.0  # samples 0 and 1: skin everywhere
    classes[2][1] = 1.0  # sample 2: top everywhere ...
    classes[2][1, 0, 0], classes[2][0, 0, 0] = 0.75, 0.25  # ... but a quarter skin at (0, 0)
    write_shard(tmp_path / "train-0000.npz", [_sample(targets[0], classes[0], 0)])
    write_shard(tmp_path / "train-0001.npz", [_sample(targets[i], classes[i], i)
                                              for i in (1, 2)])  # fmt: skip
    data = PhotoDataset(sorted(tmp_path.glob("train-*.npz")))
    means = data.class_means().numpy()
    assert means.shape == (k, 6, size, size)
    assert np.allclose(means[0, :, 0, 1], 1.5)  # skin: samples 0 and 1
    assert np.allclose(means[0, :, 0, 0], (1.0 + 2.0 + 0.25 * 4.0) / 2.25)
    assert np.allclose(means[1], 4.0)  # top: sample 2 only (0.75 of it at (0, 0))
    overall = (1.0 + 2.0 + 4.0) / 3
    assert np.allclose(means[2:], overall, atol=1e-3)  # never seen: the overall mean
    assert data[2]["target"].shape == (6, size, size)
    with_classes = PhotoDataset(sorted(tmp_path.glob("train-*.npz")), with_classes=True)
    assert torch.equal(with_classes[2]["target"][6:], torch.from_numpy(classes[2]))
