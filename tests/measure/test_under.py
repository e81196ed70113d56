"""The body under the clothes: re-fitted into a clothed surface that is tighter than the
avatar's own body, it lies inside it, keeps its height and loses the tightness in girth."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from monoavatar.body import load_body_model
from monoavatar.core.geometry import vertex_normals
from monoavatar.measure import measure_mesh, vertex_parts
from monoavatar.measure.under import fit_body_under_clothes


def test_a_tight_torso_shrinks_the_body_into_it() -> None:
    body = load_body_model("anny")
    shape = body.default_shape()
    with torch.no_grad():
        rest, joints = body.rest_shape(shape)
    v = rest[0].double().numpy()
    n = vertex_normals(v, body.faces).numpy()
    torso = (v[:, 1] > -0.05) & (v[:, 1] < 0.45)
    d = 0.01
    offsets = np.where(torso[:, None], -d * n, 0.005 * n)  # tighter at the torso, loose elsewhere
    fitted, under, under_joints = fit_body_under_clothes(body, shape[0].numpy(), offsets)
    assert body.dtype == torch.float32  # the caller's model is left as it was
    clothed = v + offsets
    assert ((under - clothed) * n).sum(axis=1).max() < 1e-6  # nowhere outside the clothes
    assert np.ptp(under[:, 1]) == pytest.approx(np.ptp(v[:, 1]), abs=2e-3)  # height held
    assert fitted[body.shape_names.index("weight")] < -0.02  # a thinner body
    parts = vertex_parts(body.skin_weights.double().numpy(), body.joint_names)
    names = body.joint_names
    before = measure_mesh(v, body.faces.numpy(), parts, joints[0].double().numpy(), names)
    after = measure_mesh(under, body.faces.numpy(), parts, under_joints, names)
    for name in ("chest", "waist"):  # the torso's outline moved in by d
        assert after[name].value - before[name].value == pytest.approx(-2 * np.pi * d, rel=0.25)
