"""The Anny back-end against Anny's own forward pass, and the interface's invariants."""

import numpy as np
import pytest
import torch

from monoavatar.body import REGIONS, BodyModelError
from monoavatar.body.anny_body import ANNY_TO_CANONICAL
from monoavatar.body.model import MEDIAPIPE_LANDMARKS
from tests.gradcheck import directional_gradcheck


def random_inputs(body, batch=2, seed=0, scale=0.4):
    gen = torch.Generator().manual_seed(seed)
    dt = body.dtype
    shape = 0.8 * (torch.rand(batch, body.shape_dim, generator=gen, dtype=dt) - 0.5)
    pose = scale * torch.randn(batch, body.num_joints, 3, generator=gen, dtype=dt)
    transl = torch.randn(batch, 3, generator=gen, dtype=dt)
    return shape, pose, transl


def test_posing_matches_annys_own_forward(anny64):
    body = anny64
    anny = body.anny
    shape, pose, transl = random_inputs(body)
    ours = body(shape=shape, pose=pose, translation=transl)

    # Anny's 'world-orient' parameterisation: each bone's posed world orientation; Anny chains
    # the bone heads and skins the mesh itself, with its own (uncollapsed) weights.
    C = torch.as_tensor(ANNY_TO_CANONICAL, dtype=torch.float64)
    coeffs = body.blendshape_coefficients(shape)
    rest_poses = anny.get_rest_model(coeffs)["rest_bone_poses"]  # (B, 104, 4, 4) Anny frame
    from monoavatar.body.anny_body import FIT_JOINTS, _fit_ancestor_map

    ancestor = _fit_ancestor_map(list(anny.bone_labels), [int(p) for p in anny.bone_parents])
    rot_ours = ours.transforms[:, ancestor, :3, :3]  # (B, 104, 3, 3) canonical frame
    rot_anny = C.T @ rot_ours @ C
    deltas = torch.eye(4, dtype=torch.float64).repeat(2, len(ancestor), 1, 1)
    deltas[:, :, :3, :3] = rot_anny @ rest_poses[:, :, :3, :3]
    root_head = ours.joints[:, 0]  # posed root joint, canonical
    deltas[:, 0, :3, 3] = root_head @ C  # = C^T x
    out = anny(
        pose_parameters=deltas,
        phenotype_kwargs=shape[:, :6] + 0.5,
        pose_parameterization="world-orient",
    )
    theirs = out["vertices"] @ C.T
    assert FIT_JOINTS[0][1] == "root"
    err = (ours.vertices - theirs).norm(dim=-1).max().item()
    assert err <= 1e-5, f"max vertex disagreement {err} m"


def test_zero_pose_is_rest_shape(anny64):
    shape, _, _ = random_inputs(anny64, batch=1)
    out = anny64(shape=shape)
    assert torch.allclose(out.vertices, out.rest_vertices, atol=1e-12)
    rest, joints = anny64.rest_shape(shape)
    assert torch.allclose(out.rest_vertices, rest)
    assert torch.allclose(out.joints, joints, atol=1e-12)


def test_canonical_frame_is_y_up_facing_plus_z(anny64):
    v = anny64().vertices[0]
    kp = anny64.keypoints(anny64().vertices)[0]
    name = MEDIAPIPE_LANDMARKS.index
    height = (v[:, 1].max() - v[:, 1].min()).item()
    assert 1.4 < height < 2.0  # metres
    assert kp[name("nose"), 2] > kp[name("left_ear"), 2]  # faces +Z
    assert kp[name("left_shoulder"), 0] > 0 > kp[name("right_shoulder"), 0]  # left = +X
    ys = [kp[name(n), 1].item() for n in ("nose", "left_shoulder", "left_hip", "left_knee",
                                          "left_ankle")]  # fmt: skip
    assert ys == sorted(ys, reverse=True)


def test_unpose_inverts_pose_for_points_normals_rays(anny64):
    body = anny64
    shape, pose, transl = random_inputs(body, seed=3, scale=0.6)
    out = body(shape=shape, pose=pose, translation=transl)
    gen = torch.Generator().manual_seed(4)
    ids = torch.randint(0, body.num_vertices, (2, 500), generator=gen)
    pts = torch.gather(out.rest_vertices, 1, ids.unsqueeze(-1).expand(-1, -1, 3))
    pts = pts + 0.01 * torch.randn(pts.shape, generator=gen, dtype=pts.dtype)
    posed = body.pose_points(pts, ids, out.transforms)
    assert (body.unpose_points(posed, ids, out.transforms) - pts).norm(dim=-1).max() <= 1e-6
    # posed vertices themselves unpose to the rest vertices
    posed_v = torch.gather(out.vertices, 1, ids.unsqueeze(-1).expand(-1, -1, 3))
    back = body.unpose_points(posed_v, ids, out.transforms)
    rest_v = torch.gather(out.rest_vertices, 1, ids.unsqueeze(-1).expand(-1, -1, 3))
    assert (back - rest_v).norm(dim=-1).max() <= 1e-6

    normals = torch.nn.functional.normalize(
        torch.randn(2, 500, 3, generator=gen, dtype=pts.dtype), dim=-1
    )
    posed_n = body.pose_normals(normals, ids, out.transforms)
    assert (body.unpose_normals(posed_n, ids, out.transforms) - normals).norm(dim=-1).max() <= 1e-6

    # a ray through a rest point, posed, then unposed, passes through that point again
    d = torch.nn.functional.normalize(
        torch.randn(2, 500, 3, generator=gen, dtype=pts.dtype), dim=-1
    )
    origin_rest = pts - 0.7 * d
    origin = body.pose_points(origin_rest, ids, out.transforms)
    direction = posed - origin
    o2, d2 = body.unpose_rays(origin, direction, ids, out.transforms)
    from monoavatar.core.camera import plucker, point_line_distance

    m, n = plucker(o2, d2)
    assert point_line_distance(pts, m, n).max() <= 1e-6
    assert (torch.cross(d2, d, dim=-1)).norm(dim=-1).max() <= 1e-6  # same direction


@pytest.mark.parametrize("which", ["shape", "pose", "translation", "offsets"])
def test_gradients_agree_with_finite_differences(anny64, which):
    body = anny64
    shape, pose, transl = random_inputs(body, batch=1, seed=5)
    offsets = 0.01 * torch.randn(body.num_vertices, 3, dtype=torch.float64)
    args = {"shape": shape, "pose": pose, "translation": transl, "offsets": offsets}

    def fn(x):
        return body(**{**args, which: x}).vertices

    fd, ad = directional_gradcheck(fn, args[which])
    assert abs(fd - ad) <= 1e-5 * max(1.0, abs(ad)), (fd, ad)


def test_symmetric_pairs_mirror_each_other(anny64):
    for seed in range(3):
        shape, _, _ = random_inputs(anny64, batch=1, seed=seed)
        rest = anny64.rest_shape(shape)[0][0]
        mirrored = rest[anny64.mirror] * torch.tensor([-1.0, 1.0, 1.0], dtype=rest.dtype)
        assert (mirrored - rest).norm(dim=-1).max() < 1e-3  # metres
    assert torch.equal(anny64.mirror[anny64.mirror], torch.arange(anny64.num_vertices))


def test_uvs_inside_unit_square_for_every_face(anny64):
    assert anny64.face_uv.shape == anny64.faces.shape
    assert anny64.face_uv.min() >= 0 and anny64.face_uv.max() < anny64.uv.shape[0]
    corner_uv = anny64.uv[anny64.face_uv]
    assert corner_uv.min() >= 0.0 and corner_uv.max() <= 1.0
    # seams exist: more UV vertices than mesh vertices
    assert anny64.uv.shape[0] > anny64.num_vertices


def test_faces_are_outward_oriented(anny64):
    v = anny64().vertices[0]
    f = anny64.faces
    signed = torch.einsum("fi,fi->f", v[f[:, 0]], torch.cross(v[f[:, 1]], v[f[:, 2]], dim=-1))
    assert signed.sum() / 6 > 0.03  # enclosed volume in m³, positive for outward normals


def test_regions_are_where_the_body_parts_are(anny64):
    v = anny64().vertices[0]
    r = anny64.regions
    y = {name: v[r == i, 1].mean().item() for i, name in enumerate(REGIONS)}
    assert all((r == i).any() for i in range(len(REGIONS)))
    assert y["hair"] > y["face"] > y["torso"] > y["legs"] > y["feet"]
    assert v[r == REGIONS.index("hands"), 0].abs().min() > 0.3


def test_keypoint_regressor_rows_are_convex(anny64):
    w = anny64.keypoint_weights[anny64.keypoint_valid]
    assert anny64.keypoint_valid.all()
    assert torch.allclose(w.sum(1), torch.ones(len(w), dtype=w.dtype), atol=1e-6)
    assert (w >= 0).all()


def test_bad_inputs_raise_clear_errors(anny32):
    with pytest.raises(BodyModelError, match="pose: expected shape"):
        anny32(pose=torch.zeros(1, 5, 3))
    with pytest.raises(BodyModelError, match="shape: expected shape"):
        anny32(shape=torch.zeros(1, 99))
    with pytest.raises(BodyModelError, match="offsets"):
        anny32(offsets=torch.zeros(10, 3))
    with pytest.raises(BodyModelError, match="batch sizes disagree"):
        anny32(shape=torch.zeros(2, 6), pose=torch.zeros(3, anny32.num_joints, 3))
    with pytest.raises(BodyModelError, match="unknown joint 'elbow'"):
        anny32.joint_index("elbow")
    assert anny32.joint_index("elbow_l") == anny32.joint_names.index("elbow_l")


def test_local_changes_shape_space():
    from monoavatar.body import load_body_model

    body = load_body_model("anny-local")
    assert body.shape_dim == 6 + 256
    shape = torch.zeros(1, body.shape_dim)
    base = body.rest_shape(shape)[0]
    shape[0, 6 + body.local_change_names.index("l-upperarm-fat-incr")] = 1.0
    changed = body.rest_shape(shape)[0]
    moved = (changed - base).norm(dim=-1)[0]
    assert moved.max() > 0.005
    # the change is local: the most-moved vertices are on the left arm (+X)
    top = moved.topk(50).indices
    assert (changed[0, top, 0] > 0.15).all()
    np.testing.assert_allclose(body.skin_weights.sum(1).numpy(), 1.0, atol=1e-5)
