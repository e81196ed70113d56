"""SMPL back-end: file reading (safely), and posing against an independent NumPy SMPL."""

import os
import pickle

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from monoavatar.body import BodyModelError, load_body_model
from monoavatar.body.smpl_body import SmplBody
from tests.body.smpl_fixture import PARENTS, make_smpl_arrays, write_npz, write_pkl


def numpy_smpl(arrays, betas, pose, transl):
    """SMPL written out directly (Loper et al. 2015), independent of monoavatar's code."""
    v = arrays["v_template"] + arrays["shapedirs"] @ betas
    J = arrays["J_regressor"] @ v
    R = Rotation.from_rotvec(pose).as_matrix()
    feat = (R[1:] - np.eye(3)).reshape(-1)
    v = v + arrays["posedirs"] @ feat
    G = []
    for j, p in enumerate(PARENTS):
        local = np.eye(4)
        local[:3, :3] = R[j]
        local[:3, 3] = J[j] if p < 0 else J[j] - J[p]
        G.append(local if p < 0 else G[p] @ local)
    G = np.stack(G)
    for j in range(len(PARENTS)):  # remove the rest joint position
        G[j, :3, 3] -= G[j, :3, :3] @ J[j]
    T = np.einsum("vj,jab->vab", arrays["weights"], G)
    posed = np.einsum("vab,vb->va", T[:, :3, :3], v) + T[:, :3, 3]
    return posed + transl


@pytest.fixture(scope="module")
def smpl_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("smpl")
    arrays = make_smpl_arrays()
    return arrays, write_npz(d / "model.npz", arrays), write_pkl(d / "model.pkl", arrays)


def test_npz_and_pkl_give_the_same_model(smpl_files):
    arrays, npz, pkl = smpl_files
    a = load_body_model(str(npz), dtype=torch.float64)
    b = load_body_model(str(pkl), dtype=torch.float64)
    assert isinstance(a, SmplBody) and isinstance(b, SmplBody)
    pose = 0.3 * torch.randn(1, 24, 3, dtype=torch.float64)
    assert torch.allclose(a(pose=pose).vertices, b(pose=pose).vertices, atol=1e-12)
    assert a.joint_names[18] == "elbow_l"


def test_posing_matches_independent_numpy_smpl(smpl_files):
    arrays, npz, _ = smpl_files
    body = SmplBody(npz, dtype=torch.float64)
    rng = np.random.default_rng(1)
    betas, pose, transl = rng.normal(size=10), 0.5 * rng.normal(size=(24, 3)), rng.normal(size=3)
    out = body(
        shape=torch.as_tensor(betas)[None],
        pose=torch.as_tensor(pose)[None],
        translation=torch.as_tensor(transl)[None],
    )
    expected = numpy_smpl(arrays, betas, pose, transl)
    assert np.abs(out.vertices[0].numpy() - expected).max() < 1e-10
    assert out.correctives.abs().max() > 0  # pose correctives were applied


def test_unpose_with_correctives_round_trip(smpl_files):
    _, npz, _ = smpl_files
    body = SmplBody(npz, dtype=torch.float64)
    pose = 0.5 * torch.randn(2, 24, 3, dtype=torch.float64)
    out = body(pose=pose)
    ids = torch.arange(body.num_vertices)
    back = body.unpose_points(out.vertices, ids, out.transforms, out.correctives)
    rest = body.rest_shape(body.default_shape(2))[0]
    assert (back - rest).abs().max() < 1e-9


def test_missing_file_names_where_to_get_it(tmp_path):
    with pytest.raises(BodyModelError, match="smpl.is.tue.mpg.de"):
        load_body_model(str(tmp_path / "basicmodel_neutral.pkl"))


def test_corrupt_files_raise(tmp_path):
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(np.random.default_rng(0).bytes(200))
    with pytest.raises(BodyModelError):
        load_body_model(str(bad))
    bad_npz = tmp_path / "bad.npz"
    bad_npz.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(BodyModelError):
        load_body_model(str(bad_npz))
    partial = tmp_path / "partial.npz"
    np.savez(partial, v_template=np.zeros((3, 3)))
    with pytest.raises(BodyModelError, match="lacks"):
        load_body_model(str(partial))


def test_pickle_cannot_run_code(tmp_path):
    class Evil:
        def __reduce__(self):
            return (os.system, ("touch " + str(tmp_path / "pwned"),))

    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"v_template": Evil()}))
    with pytest.raises(BodyModelError, match="refusing"):
        load_body_model(str(path))
    assert not (tmp_path / "pwned").exists()


def test_fallback_uvs_inside_unit_square(smpl_files):
    _, npz, _ = smpl_files
    body = SmplBody(npz)
    uv = body.uv[body.face_uv]
    assert uv.min() >= 0 and uv.max() <= 1
