"""The few-frame network (Paper D): its inputs (crops), its geometry (6D rotations, the
closed-form translation, posing about the root), its training data checked against a render
of the truth, its losses, and a deterministic, resumable training run."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from monoavatar.body import lbs
from monoavatar.core.camera import PinholeCamera
from monoavatar.learn.fast_data import FastDataSettings, crop_views, fast_sample
from monoavatar.learn.fast_model import (
    FastModelError,
    FastNetwork,
    FastNetworkSettings,
    FastOutput,
    UVOffsetDecoder,
    load_fast_network,
    rotation_6d,
    solve_translation,
    vertex_uv_samples,
)
from monoavatar.learn.fast_train import FastTrainConfig, fast_losses, posed_about_root, train_fast
from monoavatar.learn.weights import load_weights
from monoavatar.render import rasterize

TINY_DATA = FastDataSettings(views=4, image_size=96, crop_size=32)
TINY_NET = FastNetworkSettings(crop_size=32, base=4, feature=32, latent=4)


def test_crop_maps_the_box_to_the_unit_square_and_back() -> None:
    mask = np.zeros((1, 100, 80), bool)
    mask[0, 20:80, 30:50] = True  # 60 tall, 20 wide: centre (40, 50)
    kp = np.zeros((1, 33, 3))
    kp[0, :2, :2] = [[40, 20], [40, 80]]  # top and bottom of the box
    kp[0, :, 2] = 1.0
    crops, norm, boxes = crop_views(mask, kp, 32, margin=1.2)
    side = boxes[0, 2]
    assert side == pytest.approx(72, abs=0.5)
    np.testing.assert_allclose(boxes[0, :2], [40, 50], atol=0.5)
    np.testing.assert_allclose(norm[0, :2, 1], [-1 / 1.2, 1 / 1.2], atol=0.02)
    back = norm[0, :, :2] * side / 2 + boxes[0, :2]
    np.testing.assert_allclose(back, kp[0, :, :2], atol=1e-4)
    # the mask fills 20/72 of the width and 60/72 of the height, centred
    frac = crops[0].astype(float).sum() / 255 / 32**2
    assert frac == pytest.approx(20 * 60 / 72**2, rel=0.05)
    assert crops[0, 16, 16] == 255 and crops[0, 16, 2] == 0


def test_crop_of_a_person_at_the_edge_is_padded() -> None:
    mask = np.zeros((1, 50, 50), bool)
    mask[0, 0:40, 0:10] = True
    crops, _, boxes = crop_views(mask, np.zeros((1, 33, 3)), 16)
    assert boxes[0, 0] - boxes[0, 2] / 2 < 0  # the crop reaches past the left edge
    assert crops[0].max() == 255 and crops[0][:, 0].max() == 0


def test_rotation_6d_is_a_rotation_and_inverts_its_columns() -> None:
    rng = torch.Generator().manual_seed(0)
    x = torch.randn(50, 6, generator=rng, dtype=torch.float64)
    r = rotation_6d(x)
    eye = torch.eye(3, dtype=torch.float64).expand(50, 3, 3)
    torch.testing.assert_close(r.transpose(-1, -2) @ r, eye)
    torch.testing.assert_close(torch.linalg.det(r), torch.ones(50, dtype=torch.float64))
    true = lbs.axis_angle_to_matrix(torch.randn(50, 3, generator=rng, dtype=torch.float64))
    six = torch.cat([true[..., 0], true[..., 1]], -1)
    torch.testing.assert_close(rotation_6d(six), true)


def test_translation_is_recovered_in_closed_form() -> None:
    rng = np.random.default_rng(1)
    K = np.array([[500.0, 0, 160], [0, 510, 120], [0, 0, 1]])
    points = rng.normal(0, 0.4, (33, 3))
    u = np.array([0.3, -0.2, 3.1])
    p = (points + u) @ K.T
    kp = np.concatenate([p[:, :2] / p[:, 2:], rng.uniform(0.5, 1, (33, 1))], 1)
    np.testing.assert_allclose(solve_translation(points, kp, K), u, atol=1e-9)
    kp[2:, 2] = 0.0
    with pytest.raises(FastModelError, match="fewer than 3"):
        solve_translation(points, kp, K)


def test_posing_about_the_root_matches_the_body_model(anny64) -> None:  # type: ignore[no-untyped-def]
    rng = torch.Generator().manual_seed(2)
    shape = 0.3 * torch.randn(2, 6, generator=rng, dtype=torch.float64)
    pose = 0.3 * torch.randn(2, 3, anny64.num_joints, 3, generator=rng, dtype=torch.float64)
    rest, joints = anny64.rest_shape(shape)
    got = posed_about_root(anny64, rest, joints, lbs.axis_angle_to_matrix(pose))
    for b in range(2):
        out = anny64(shape=shape[b : b + 1].expand(3, -1), pose=pose[b])
        want = out.vertices - out.joints[:, :1]
        torch.testing.assert_close(got[b], want)


@pytest.fixture(scope="module")
def sample(anny_local, anny32):  # type: ignore[no-untyped-def]
    return fast_sample(anny_local, anny32, 5, FastDataSettings(views=4))


def test_sample_truth_renders_onto_its_masks(anny32, sample) -> None:  # type: ignore[no-untyped-def]
    """The six-phenotype body with the sample's β, offsets, rotations (root in camera axes)
    and root position, rendered through the sample's intrinsics and cropped by its boxes,
    covers the stored mask crops (IoU > 0.93; the truth has finer detail than the body)."""
    settings = FastDataSettings(views=4)
    size = settings.image_size
    camera = PinholeCamera(K=sample.K.astype(np.float64), R=np.eye(3), t=np.zeros(3),
                           width=size, height=size)  # fmt: skip
    beta = torch.as_tensor(sample.beta, dtype=torch.float32)[None]
    pose = lbs.matrix_to_axis_angle(torch.as_tensor(sample.rotations))
    with torch.no_grad():
        out = anny32(shape=beta.expand(4, -1), pose=pose,
                     offsets=torch.as_tensor(sample.offsets))  # fmt: skip
    for i in range(4):
        v = out.vertices[i] - out.joints[i, 0] + torch.as_tensor(sample.root[i])
        mask = (rasterize(v.double(), anny32.faces, camera).face_id >= 0).numpy()
        box = sample.boxes[i]
        kp = np.zeros((1, 33, 3))
        crops, _, _ = crop_views(mask[None], kp, settings.crop_size, settings.margin)
        # the crop of the render is taken around the render's own box: compare the boxes too
        rows = np.flatnonzero(mask.any(1))
        assert abs((rows[-1] - rows[0] + 1) * settings.margin - box[2]) < 0.06 * box[2]
        a, b = crops[0] > 127, sample.masks[i] > 127
        assert (a & b).sum() / (a | b).sum() > 0.93


def test_sample_keypoints_and_truth_are_consistent(sample) -> None:  # type: ignore[no-untyped-def]
    r = sample.rotations
    np.testing.assert_allclose(np.swapaxes(r, -1, -2) @ r, np.broadcast_to(np.eye(3), r.shape),
                               atol=1e-5)  # fmt: skip
    assert (sample.root[:, 2] > 1.5).all()  # in front of the camera
    seen = sample.keypoints[..., 2] > 0
    assert seen.mean() > 0.5
    assert np.abs(sample.keypoints[..., :2][seen]).max() < 1.0  # inside the crop
    assert 0.004 < np.abs(sample.offsets).mean() < 0.05  # garments and local changes: mm–cm


def test_losses_vanish_at_the_truth_and_grow_away_from_it(anny32, sample) -> None:  # type: ignore[no-untyped-def]
    batch = {
        "beta": torch.as_tensor(sample.beta, dtype=torch.float32)[None],
        "offsets": torch.as_tensor(sample.offsets)[None],
        "rotations": torch.as_tensor(sample.rotations)[None],
    }
    truth = FastOutput(batch["beta"], torch.zeros(1, 4), batch["offsets"], batch["rotations"])
    terms = fast_losses(anny32, truth, batch)
    for key in ("vertices_cm", "posed_cm", "rotations", "beta", "loss"):
        assert float(terms[key]) < 1e-4, key
    moved = FastOutput(batch["beta"], truth.code, batch["offsets"] + 0.01, batch["rotations"])
    terms = fast_losses(anny32, moved, batch)
    assert float(terms["vertices_cm"]) == pytest.approx(100 * 0.01 * np.sqrt(3), rel=1e-3)


def test_network_takes_any_number_of_frames() -> None:
    net = FastNetwork(TINY_NET, 50, 20)
    for f in (1, 3):
        out = net(torch.rand(2, f, 1, 32, 32), torch.rand(2, f, 33, 3))
        assert out.beta.shape == (2, 6) and out.offsets.shape == (2, 50, 3)
        assert out.rotations.shape == (2, f, 20, 3, 3)
    root = out.rotations[0, 0, 0].detach()  # untrained: upright, facing the camera
    torch.testing.assert_close(root, torch.diag(torch.tensor([1.0, -1.0, -1.0])), atol=0.05,
                               rtol=0)  # fmt: skip
    with pytest.raises(FastModelError, match="expected masks"):
        net(torch.rand(2, 1, 1, 16, 16), torch.rand(2, 1, 33, 3))


# Two triangles sharing the edge 0–2; vertex 0 lies on a UV seam (UV 0 in the first face,
# UV 4 in the second).
SQUARE_FACES = torch.tensor([[0, 1, 2], [0, 2, 3]])
SQUARE_FACE_UV = torch.tensor([[0, 1, 2], [4, 2, 3]])
SQUARE_UV = torch.tensor([[0.1, 0.2], [0.8, 0.15], [0.7, 0.9], [0.2, 0.6], [0.4, 0.3]])


def test_uv_decoder_reads_each_vertex_at_its_uvs() -> None:
    """A map linear in the texel centres, read back: each vertex gets 0.01 · (u, v, 1) at
    its UVs (the mean of the two on the seam) plus the bias; a closed form."""
    pairs = vertex_uv_samples(SQUARE_FACES, SQUARE_FACE_UV)
    assert pairs.tolist() == [[0, 0], [0, 4], [1, 1], [2, 2], [3, 3]]
    dec = UVOffsetDecoder(4, 4, SQUARE_UV, pairs, 16)
    centres = (torch.arange(16) + 0.5) / 16
    image = torch.stack([centres[None].expand(16, -1), centres[:, None].expand(-1, 16),
                         torch.ones(16, 16)])  # (3, S, S): column, row, 1  # fmt: skip
    dec.offset_map = lambda z: image[None].expand(len(z), -1, -1, -1)  # type: ignore[method-assign]
    with torch.no_grad():
        dec.bias.copy_(torch.arange(12.0).reshape(4, 3) * 1e-3)
    out = dec(torch.zeros(2, 4))
    uv = SQUARE_UV.numpy()
    at = np.stack([(uv[0] + uv[4]) / 2, uv[1], uv[2], uv[3]])
    expected = 0.01 * np.c_[at, np.ones(4)] + np.arange(12.0).reshape(4, 3) * 1e-3
    np.testing.assert_allclose(out[1].detach().numpy(), expected, atol=1e-6)


def test_uv_decoder_network_starts_at_its_bias_and_loads_back(tmp_path: Path) -> None:
    from monoavatar.learn.weights import module_tensors, save_weights

    pairs = vertex_uv_samples(SQUARE_FACES, SQUARE_FACE_UV)
    settings = replace(TINY_NET, decoder="uv", uv_size=8)
    with pytest.raises(FastModelError, match="needs the body's UVs"):
        FastNetwork(settings, 4, 20)
    with pytest.raises(FastModelError, match="do not cover"):
        FastNetwork(settings, 5, 20, SQUARE_UV, pairs)
    net = FastNetwork(settings, 4, 20, SQUARE_UV, pairs)
    masks, kp = torch.rand(2, 3, 1, 32, 32), torch.rand(2, 3, 33, 3)
    assert torch.equal(net(masks, kp).offsets, torch.zeros(2, 4, 3))  # the last layer is zero
    with torch.no_grad():
        for p in net.decoder.parameters():
            p.add_(0.01 * torch.randn_like(p))
    path = tmp_path / "uv.safetensors"
    save_weights(path, module_tensors(net, "network."), settings.metadata())
    back = load_fast_network(4, 20, path, uv=SQUARE_UV, pairs=pairs)
    assert back.settings == settings
    with torch.no_grad():
        torch.testing.assert_close(back(masks, kp).offsets, net.eval()(masks, kp).offsets)
    with pytest.raises(FastModelError, match="needs the body's UVs"):
        load_fast_network(4, 20, path)


def _tiny(**changes: object) -> FastTrainConfig:
    base = FastTrainConfig(subjects=6, val=2, workers=1, steps=4, batch=3, max_views=3,
                           checkpoint_every=2, validate_every=2, progress=False,
                           data=TINY_DATA, network=TINY_NET)  # fmt: skip
    return replace(base, **changes)  # type: ignore[arg-type]


@pytest.mark.slow
def test_training_is_deterministic_and_resumes_bit_for_bit(tmp_path: Path) -> None:
    whole = train_fast(tmp_path / "a", _tiny())
    assert whole.finished and whole.steps_done == 4
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "data").symlink_to(tmp_path / "a" / "data")
    first = train_fast(tmp_path / "b", _tiny(max_minutes=0.0))
    assert not first.finished and first.steps_done == 1
    second = train_fast(tmp_path / "b", _tiny())
    assert second.finished
    a, meta = load_weights(whole.weights)
    b, _ = load_weights(second.weights)
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key
    assert meta["content"] == "fast-network"
    log = (tmp_path / "b" / "train" / "log.jsonl").read_text().splitlines()
    assert [int(line.split('"step": ')[1].split(",")[0]) for line in log] == [1, 2, 4]
    net = load_fast_network(13718, 20, whole.weights)
    assert net.settings == TINY_NET
    with pytest.raises(FastModelError, match="another body"):
        load_fast_network(100, 20, whole.weights)
    with pytest.raises(FastModelError, match="train fast"):
        load_fast_network(100, 20, tmp_path / "none.safetensors")
