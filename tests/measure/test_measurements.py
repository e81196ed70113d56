"""Body measurements on a body of prisms whose girths and lengths are known in closed form, and
their invariance to how the avatar's canonical frame is oriented."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from monoavatar.measure import MEASUREMENTS, measure_mesh, transfer_parts, vertex_parts
from tests.measure import primitives as P


@pytest.fixture(scope="module")
def prisms() -> dict:
    v, f, parts, joints = P.primitive_body()
    return {"mesh": (v, f, parts, joints), "m": measure_mesh(v, f, parts, joints, P.JOINT_NAMES)}


def test_girths_of_the_prism_body(prisms: dict) -> None:
    m = prisms["m"]
    torso = P.polygon_perimeter(*P.TORSO)
    for name in ("chest", "waist", "hip"):  # the legs lie inside the torso's outline
        assert m[name].value == pytest.approx(torso, rel=1e-9), name
    assert m["neck"].value == pytest.approx(P.polygon_perimeter(P.NECK, P.NECK), rel=1e-9)
    # planes perpendicular to the bones: the arms at 45 degrees give their own cross-section
    assert m["upper_arm"].value == pytest.approx(P.polygon_perimeter(P.ARM, P.ARM), rel=1e-9)
    for name in ("thigh", "calf"):
        assert m[name].value == pytest.approx(P.polygon_perimeter(P.LEG, P.LEG), rel=1e-9)


def test_lengths_of_the_prism_body(prisms: dict) -> None:
    m = prisms["m"]
    assert m["height"].value == pytest.approx(P.TOP - P.FLOOR, abs=1e-12)
    assert m["inseam"].value == pytest.approx(P.CROTCH - P.FLOOR, abs=1e-12)
    assert list(m) == list(MEASUREMENTS)
    for name in ("chest", "hip", "inseam"):
        assert m[name].drawing and all(np.isfinite(d).all() for d in m[name].drawing)


def test_an_arm_beside_the_chest_is_not_wrapped_in(prisms: dict) -> None:
    """Label the arms as torso and the chest girth grows: the part filter is what keeps it."""
    v, f, parts, joints = prisms["mesh"]
    merged = np.where(np.isin(parts, [3, 4]), 0, parts)
    m = measure_mesh(v, f, merged, joints, P.JOINT_NAMES)
    assert m["chest"].value > prisms["m"]["chest"].value + 0.05


@pytest.fixture(scope="module")
def anny() -> tuple:
    import torch

    from monoavatar.body import load_body_model

    body = load_body_model("anny")
    with torch.no_grad():
        v, j = body.rest_shape(body.default_shape())
    parts = vertex_parts(body.skin_weights.double().numpy(), body.joint_names)
    return v[0].double().numpy(), body.faces.numpy(), parts, j[0].double().numpy(), body


def test_measurements_do_not_depend_on_the_canonical_orientation(anny: tuple) -> None:
    v, f, parts, joints, body = anny
    before = measure_mesh(v, f, parts, joints, body.joint_names)
    R = Rotation.from_euler("xyz", [25, -70, 40], degrees=True).as_matrix()
    t = np.array([0.3, -1.2, 2.0])
    after = measure_mesh(v @ R.T + t, f, parts, joints @ R.T + t, body.joint_names)
    for name in MEASUREMENTS:
        assert np.isfinite(before[name].value), name
        assert after[name].value == pytest.approx(before[name].value, rel=1e-6, abs=1e-7), name
    # the drawings move with the mesh: the same corners (qhull may list them from another one)
    from scipy.spatial import cKDTree

    expected = before["chest"].drawing[0] @ R.T + t
    got = after["chest"].drawing[0]
    assert got.shape == expected.shape
    assert cKDTree(got).query(expected)[0].max() < 1e-9
    assert cKDTree(expected).query(got)[0].max() < 1e-9


def test_clothing_a_body_uniformly_adds_two_pi_d_to_its_torso_girths(anny: tuple) -> None:
    """Offsetting a convex outline by d lengthens it by 2 pi d; a body inflated along its
    normals by d has its torso girths lengthened by about that much (the slice of the offset
    surface is not exactly the offset of the slice)."""
    from monoavatar.core.geometry import vertex_normals

    v, f, parts, joints, body = anny
    d = 0.01
    clothed = v + d * vertex_normals(v, f).numpy()
    m0 = measure_mesh(v, f, parts, joints, body.joint_names)
    m1 = measure_mesh(clothed, f, transfer_parts(v, parts, clothed), joints, body.joint_names)
    for name in ("chest", "waist", "hip"):
        assert m1[name].value - m0[name].value == pytest.approx(2 * np.pi * d, rel=0.15), name
    assert m1["height"].value - m0["height"].value == pytest.approx(2 * d, rel=0.1)


def test_body_under_clothes_keeps_inward_offsets_only() -> None:
    from monoavatar.measure import body_under_clothes

    rest = np.zeros((3, 3))
    normals = np.array([[0.0, 0, 1], [0.0, 0, 1], [1.0, 0, 0]])
    offsets = np.array([[0.0, 0, 0.02], [0.01, 0, -0.03], [-0.01, 0.005, 0]])
    np.testing.assert_allclose(body_under_clothes(rest, normals, offsets),
                               [[0, 0, 0], [0.01, 0, -0.03], [-0.01, 0.005, 0]])  # fmt: skip
