import math

import torch

from monoavatar.body import lbs


def test_joint_transforms_two_joint_chain_by_hand():
    # joint 0 at the origin, joint 1 at (1, 0, 0); rotate joint 1 by 90° about z
    joints = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0]]], dtype=torch.float64)
    pose = torch.zeros(1, 2, 3, dtype=torch.float64)
    pose[0, 1, 2] = math.pi / 2
    A = lbs.joint_transforms(lbs.axis_angle_to_matrix(pose), joints, [-1, 0])
    tip = torch.tensor([2.0, 0, 0], dtype=torch.float64)  # a point rigid with joint 1
    posed = lbs.transform_points(A[0, 1], tip)
    assert torch.allclose(posed, torch.tensor([1.0, 1.0, 0.0], dtype=torch.float64), atol=1e-12)
    # joint 0 untouched, translation adds
    A = lbs.joint_transforms(
        lbs.axis_angle_to_matrix(pose), joints, [-1, 0], torch.tensor([[0.0, 0.0, 5.0]])
    )
    assert torch.allclose(
        lbs.transform_points(A[0, 1], tip), torch.tensor([1.0, 1.0, 5.0], dtype=torch.float64)
    )


def test_axis_angle_at_zero_is_identity_with_finite_gradient():
    aa = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    R = lbs.axis_angle_to_matrix(aa)
    assert torch.allclose(R, torch.eye(3, dtype=torch.float64))
    R.sum().backward()
    assert torch.isfinite(aa.grad).all()


def test_invert_affine_round_trip():
    gen = torch.Generator().manual_seed(0)
    M = torch.eye(4, dtype=torch.float64).repeat(5, 1, 1)
    M[:, :3, :] += 0.3 * torch.randn(5, 3, 4, generator=gen, dtype=torch.float64)
    eye = torch.eye(4, dtype=torch.float64).expand(5, 4, 4)
    assert torch.allclose(lbs.invert_affine(M) @ M, eye, atol=1e-12)


def test_skin_equals_per_vertex_blend():
    gen = torch.Generator().manual_seed(1)
    V, J = 7, 3
    w = torch.rand(V, J, generator=gen, dtype=torch.float64)
    w = w / w.sum(1, keepdim=True)
    A = torch.eye(4, dtype=torch.float64).repeat(1, J, 1, 1)
    A[0, :, :3, :] += 0.2 * torch.randn(J, 3, 4, generator=gen, dtype=torch.float64)
    v = torch.randn(1, V, 3, generator=gen, dtype=torch.float64)
    expected = torch.stack(
        [sum(w[i, j] * (A[0, j, :3, :3] @ v[0, i] + A[0, j, :3, 3]) for j in range(J))
         for i in range(V)]
    )  # fmt: skip
    assert torch.allclose(lbs.skin(v, w, A)[0], expected, atol=1e-12)


def test_skin_with_weights_per_batch_entry_equals_separate_calls():
    gen = torch.Generator().manual_seed(2)
    B, V, J = 3, 5, 4
    w = torch.rand(B, V, J, generator=gen, dtype=torch.float64)
    w = w / w.sum(-1, keepdim=True)
    A = torch.eye(4, dtype=torch.float64).repeat(B, J, 1, 1)
    A[:, :, :3, :] += 0.2 * torch.randn(B, J, 3, 4, generator=gen, dtype=torch.float64)
    v = torch.randn(B, V, 3, generator=gen, dtype=torch.float64)
    batched = lbs.skin(v, w, A)
    for b in range(B):
        assert torch.allclose(batched[b], lbs.skin(v[b : b + 1], w[b], A[b : b + 1])[0],
                              atol=1e-12)  # fmt: skip
