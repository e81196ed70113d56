"""The benchmark's trimesh-based measurement of the truth agrees with the measure stage's own
slicing on the same mesh, so either one's error would show."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from monoavatar.bench.measure import trimesh_slicer
from monoavatar.body import load_body_model
from monoavatar.measure import MEASUREMENTS, measure_mesh, vertex_parts


def test_trimesh_and_own_slicing_agree_on_a_body() -> None:
    body = load_body_model("anny")
    shape = body.default_shape()
    shape[0, :4] += torch.tensor([0.2, -0.1, 0.15, 0.1], dtype=shape.dtype)  # not the average
    with torch.no_grad():
        rest, joints = body.rest_shape(shape)
    v, j = rest[0].double().numpy(), joints[0].double().numpy()
    parts = vertex_parts(body.skin_weights.double().numpy(), body.joint_names)
    ours = measure_mesh(v, body.faces.numpy(), parts, j, body.joint_names)
    theirs = measure_mesh(v, body.faces.numpy(), parts, j, body.joint_names,
                          slicer=trimesh_slicer())  # fmt: skip
    for name in MEASUREMENTS:
        assert np.isfinite(ours[name].value), name
        assert theirs[name].value == pytest.approx(ours[name].value, abs=1e-6), name
