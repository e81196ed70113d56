"""glTF export: the skinned mesh re-posed by an independent NumPy reader equals
``BodyModel.forward`` (with the same 4-influence weights); UVs, texture, atomic writes, input
errors, and the Khronos validator."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import torch
import trimesh
from PIL import Image

from monoavatar.body import BodyModel, lbs
from monoavatar.io.gltf import (
    GltfExportError,
    PoseAnimation,
    SkinnedMesh,
    dense_weights,
    limit_influences,
    skinned_mesh_from_body,
    split_uv_seams,
    write_animated_glb,
    write_avatar_glb,
)
from tests.io.gltf_reference import (
    Glb,
    animation_keyframe,
    rodrigues,
    skin_vertices,
    validate,
    validator_available,
)

TOL = 1e-5  # metres


@pytest.fixture(scope="module")
def avatar(anny64: BodyModel) -> tuple[SkinnedMesh, np.ndarray, np.ndarray]:
    """A non-average Anny with smooth offsets and a small texture: (mesh, shape, offsets)."""
    rng = np.random.default_rng(7)
    shape = 0.3 * rng.standard_normal(anny64.shape_dim)
    with torch.no_grad():
        rest = anny64.rest_shape(anny64.default_shape(1))[0][0].numpy()
    offsets = 0.01 * np.sin(9.0 * rest[:, [1, 2, 0]] + rng.uniform(0, 6, 3))  # smooth field
    texture = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    return skinned_mesh_from_body(anny64, shape, offsets, texture), shape, offsets


@pytest.fixture(scope="module")
def static_glb(avatar: tuple[SkinnedMesh, np.ndarray, np.ndarray], tmp_path_factory) -> Path:
    return write_avatar_glb(tmp_path_factory.mktemp("glb") / "avatar.glb", avatar[0])


def _forward4(body: BodyModel, mesh: SkinnedMesh, shape, offsets, pose, translation) -> np.ndarray:
    """BodyModel.forward's posed vertices (N, V, 3), skinned with the 4-influence weights."""
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    out = body(t(shape)[None], t(pose), t(translation), t(offsets))
    joints, weights = limit_influences(mesh.skin_weights)
    dense = t(dense_weights(joints, weights, mesh.num_joints))
    return lbs.skin(out.rest_vertices, dense, out.transforms).numpy()


def test_bind_pose_and_structure(avatar, static_glb: Path) -> None:
    mesh = avatar[0]
    glb = Glb.load(static_glb)
    source_vertex, source_uv, faces = split_uv_seams(mesh.faces, mesh.face_uv)
    np.testing.assert_allclose(glb.attribute("POSITION"), mesh.vertices[source_vertex], atol=1e-6)
    np.testing.assert_array_equal(glb.indices(), faces)
    # each split face is the original face
    np.testing.assert_array_equal(source_vertex[faces], mesh.faces)
    np.testing.assert_array_equal(source_uv[faces], mesh.face_uv)
    # the skin at the rest pose leaves the mesh where it is
    np.testing.assert_allclose(skin_vertices(glb), mesh.vertices[source_vertex], atol=1e-6)
    skin = glb.gltf.skins[0]
    names = [glb.gltf.nodes[n].name for n in skin.joints]
    assert names == list(mesh.joint_names)
    for j, parent in enumerate(mesh.parents):
        if parent >= 0:
            assert skin.joints[j] in glb.gltf.nodes[skin.joints[parent]].children
    assert glb.gltf.scenes[0].nodes == [0, skin.joints[0]]
    normals = glb.attribute("NORMAL")
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    # normals agree with the faces' winding (their area-weighted average)
    pos = glb.attribute("POSITION").astype(np.float64)
    tri = pos[faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    corner_dot = np.einsum("fki,fi->fk", normals[faces], face_n)
    assert (corner_dot > 0).mean() > 0.99
    # ... and are shared across UV seams (smooth shading)
    first = np.full(len(mesh.vertices), -1)
    first[source_vertex[::-1]] = np.arange(len(source_vertex))[::-1]
    np.testing.assert_allclose(normals, normals[first[source_vertex]])


def test_weights_are_four_largest_renormalised(avatar, static_glb: Path) -> None:
    mesh = avatar[0]
    glb = Glb.load(static_glb)
    source_vertex, _, _ = split_uv_seams(mesh.faces, mesh.face_uv)
    joints = glb.attribute("JOINTS_0").astype(np.int64)
    weights = glb.attribute("WEIGHTS_0").astype(np.float64)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-6)
    dense = dense_weights(joints, weights, mesh.num_joints)
    full = mesh.skin_weights[source_vertex]
    k = np.minimum((full > 0).sum(axis=1), 4)
    top = -np.sort(-full, axis=1)[:, :4]
    want = top / top.sum(axis=1, keepdims=True)
    got = -np.sort(-dense, axis=1)[:, :4]
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert ((dense > 0).sum(axis=1) == k).all()
    assert (joints[weights == 0] == 0).all()


def test_skinning_matches_forward(anny64: BodyModel, avatar, static_glb: Path) -> None:
    mesh, shape, offsets = avatar
    rng = np.random.default_rng(3)
    pose = 0.5 * rng.standard_normal((mesh.num_joints, 3))
    translation = np.array([0.3, -0.1, 1.2])
    glb = Glb.load(static_glb)
    nodes = glb.gltf.skins[0].joints
    root = nodes[0]
    rotations = {nodes[j]: rodrigues(pose[j]) for j in range(mesh.num_joints)}
    translations = {root: np.asarray(glb.gltf.nodes[root].translation) + translation}
    posed = skin_vertices(glb, rotations, translations)
    want = _forward4(anny64, mesh, shape, offsets, pose[None], translation[None])[0]
    source_vertex, _, _ = split_uv_seams(mesh.faces, mesh.face_uv)
    assert np.abs(posed - want[source_vertex]).max() < TOL
    # and the 4-influence limit is a small change from the full weights at this pose
    full = (
        anny64(
            torch.as_tensor(shape)[None],
            torch.as_tensor(pose)[None],
            torch.as_tensor(translation)[None],
            torch.as_tensor(offsets),
        )
        .vertices[0]
        .numpy()
    )
    err = np.linalg.norm(full[source_vertex] - posed, axis=1)
    assert np.median(err) < 1e-6 and err.max() < 0.05


def test_animation_keyframes_match_forward(anny64: BodyModel, avatar, tmp_path: Path) -> None:
    mesh, shape, offsets = avatar
    rng = np.random.default_rng(5)
    n = 5
    poses = 0.6 * rng.standard_normal((n, mesh.num_joints, 3))
    poses[2] = poses[1] + 0.05  # near-identical neighbours and sign continuity
    poses[3, 0] = [0.0, 3.0, 0.0]  # nearly half a turn
    translations = 0.2 * rng.standard_normal((n, 3))
    path = write_animated_glb(
        tmp_path / "anim.glb", mesh, PoseAnimation.from_fps(poses, translations, fps=25.0)
    )
    glb = Glb.load(path)
    anim = glb.gltf.animations[0]
    times = glb.accessor(anim.samplers[0].input)
    np.testing.assert_allclose(times, np.arange(n) / 25.0, atol=1e-7)
    assert len(anim.channels) == mesh.num_joints + 1
    want = _forward4(anny64, mesh, shape, offsets, poses, translations)
    source_vertex, _, _ = split_uv_seams(mesh.faces, mesh.face_uv)
    for k in range(n):
        posed = skin_vertices(glb, *animation_keyframe(glb, k))
        assert np.abs(posed - want[k, source_vertex]).max() < TOL, k
    # rotations stay on one hemisphere from keyframe to keyframe (slerp takes the short way)
    for s in anim.samplers[1:]:
        q = glb.accessor(s.output)
        assert ((q[1:] * q[:-1]).sum(axis=1) >= 0).all()
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)


def test_uv_and_texture_round_trip(avatar, static_glb: Path) -> None:
    mesh = avatar[0]
    glb = Glb.load(static_glb)
    _, source_uv, _ = split_uv_seams(mesh.faces, mesh.face_uv)
    np.testing.assert_allclose(glb.attribute("TEXCOORD_0"), mesh.uv[source_uv], atol=1e-7)
    image = glb.gltf.images[glb.gltf.textures[0].source]
    assert image.mimeType == "image/png"
    png = Image.open(io.BytesIO(glb.buffer_view_bytes(image.bufferView)))
    np.testing.assert_array_equal(np.asarray(png.convert("RGB")), mesh.texture)
    material = glb.gltf.materials[glb.primitive().material]
    assert material.pbrMetallicRoughness.baseColorTexture.index == 0
    # trimesh, an independent reader, flips v to OpenGL's convention (v up) on import
    scene = trimesh.load(static_glb, process=False)
    geom = next(iter(scene.geometry.values()))
    np.testing.assert_allclose(1.0 - geom.visual.uv[:, 1], mesh.uv[source_uv, 1], atol=1e-6)
    np.testing.assert_allclose(geom.vertices, glb.attribute("POSITION"))
    np.testing.assert_array_equal(
        np.asarray(geom.visual.material.baseColorTexture.convert("RGB")), mesh.texture
    )


def test_float_texture_and_no_texture(avatar, tmp_path: Path) -> None:
    mesh = avatar[0]
    ramp = np.linspace(-0.2, 1.2, 16 * 8 * 3).reshape(16, 8, 3)
    from dataclasses import replace

    glb = Glb.load(write_avatar_glb(tmp_path / "f.glb", replace(mesh, texture=ramp)))
    png = Image.open(io.BytesIO(glb.buffer_view_bytes(glb.gltf.images[0].bufferView)))
    np.testing.assert_array_equal(
        np.asarray(png), (np.clip(ramp, 0, 1) * 255 + 0.5).astype(np.uint8)
    )
    glb = Glb.load(write_avatar_glb(tmp_path / "n.glb", replace(mesh, texture=None)))
    assert not glb.gltf.images and not glb.gltf.textures
    assert glb.gltf.materials[0].pbrMetallicRoughness.baseColorTexture is None


def test_limit_influences_small_cases() -> None:
    w = np.array([[0.1, 0.2, 0.3, 0.15, 0.25], [0.0, 1.0, 0.0, 0.0, 0.0]])
    joints, weights = limit_influences(w)
    np.testing.assert_array_equal(joints, [[2, 4, 1, 3], [1, 0, 0, 0]])
    np.testing.assert_allclose(weights[0], np.array([0.3, 0.25, 0.2, 0.15]) / 0.9)
    np.testing.assert_allclose(weights[1], [1, 0, 0, 0])
    joints, weights = limit_influences(np.array([[0.4, 0.6]]))  # fewer joints than slots
    np.testing.assert_array_equal(joints, [[1, 0, 0, 0]])
    np.testing.assert_allclose(weights, [[0.6, 0.4, 0, 0]])
    with pytest.raises(GltfExportError, match="no positive"):
        limit_influences(np.zeros((1, 3)))


def test_input_errors(avatar, tmp_path: Path) -> None:
    from dataclasses import replace

    mesh = avatar[0]
    cases = {
        "skin_weights": replace(mesh, skin_weights=mesh.skin_weights[:, :5]),
        "face_uv": replace(mesh, face_uv=mesh.face_uv[:10]),
        "parents": replace(mesh, parents=(0,) + mesh.parents[1:]),
        "texture": replace(mesh, texture=np.zeros((4, 4))),
        "non-finite": replace(mesh, vertices=np.full_like(mesh.vertices, np.nan)),
    }
    for message, bad in cases.items():
        with pytest.raises(GltfExportError, match=message):
            write_avatar_glb(tmp_path / "bad.glb", bad)
    bad_anim = PoseAnimation.from_fps(np.zeros((3, mesh.num_joints - 1, 3)))
    with pytest.raises(GltfExportError, match=r"poses: expected shape \(3, 20, 3\)"):
        write_animated_glb(tmp_path / "bad.glb", mesh, bad_anim)
    bad_times = PoseAnimation(np.zeros((2, 20, 3)), np.zeros((2, 3)), np.array([0.0, 0.0]))
    with pytest.raises(GltfExportError, match="increasing"):
        write_animated_glb(tmp_path / "bad.glb", mesh, bad_times)
    assert not list(tmp_path.iterdir())


def test_atomic_write_on_failure(avatar, tmp_path: Path, monkeypatch) -> None:
    mesh = avatar[0]
    path = tmp_path / "avatar.glb"
    path.write_bytes(b"previous")
    original = pygltflib.GLTF2.save_to_bytes

    def half_then_fail(self):  # the first chunks get written, then writing fails
        chunks = original(self)
        return [*chunks[:5], None]

    monkeypatch.setattr(pygltflib.GLTF2, "save_to_bytes", half_then_fail)
    with pytest.raises(TypeError):
        write_avatar_glb(path, mesh)
    assert path.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == ["avatar.glb"]


@pytest.mark.parametrize("animated", [False, True], ids=["static", "animated"])
def test_khronos_validator(avatar, tmp_path: Path, animated: bool) -> None:
    reason = validator_available()
    if reason is not None:
        pytest.skip(reason)
    mesh = avatar[0]
    path = tmp_path / "a.glb"
    if animated:
        rng = np.random.default_rng(0)
        poses = 0.4 * rng.standard_normal((6, mesh.num_joints, 3))
        write_animated_glb(path, mesh, PoseAnimation.from_fps(poses, np.zeros((6, 3)), 30.0))
    else:
        write_avatar_glb(path, mesh)
    report = validate(path)
    issues = report["issues"]
    assert issues["numErrors"] == 0, issues["messages"]
    assert issues["numWarnings"] == 0, issues["messages"]
    info = report["info"]
    assert info["hasSkins"] and info["hasTextures"] and info["maxInfluences"] == 4
    assert info["animationCount"] == int(animated)


def test_skinned_mesh_from_body_inputs(anny64: BodyModel) -> None:
    shape = torch.zeros(anny64.shape_dim, dtype=torch.float64, requires_grad=True)
    offsets = torch.full((anny64.num_vertices, 3), 0.01, dtype=torch.float64)
    mesh = skinned_mesh_from_body(anny64, shape, offsets)
    plain = skinned_mesh_from_body(anny64)
    np.testing.assert_allclose(mesh.vertices, plain.vertices + 0.01)
    np.testing.assert_array_equal(mesh.rest_joints, plain.rest_joints)
    assert mesh.texture is None and mesh.joint_names == anny64.joint_names
    with pytest.raises(GltfExportError, match="shape: expected 6 values"):
        skinned_mesh_from_body(anny64, np.zeros(3))
    with pytest.raises(GltfExportError, match="offsets: expected shape"):
        skinned_mesh_from_body(anny64, None, np.zeros((4, 3)))
