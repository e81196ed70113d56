import numpy as np
import pytest

from monoavatar.body import Avatar, BodyModelError


def test_avatar_round_trip_and_compatibility(anny32, tmp_path):
    rng = np.random.default_rng(0)
    avatar = Avatar(
        model=anny32.identity,
        shape=rng.normal(size=anny32.shape_dim),
        shape_names=anny32.shape_names,
        offsets=rng.normal(size=(anny32.num_vertices, 3)).astype(np.float32),
    )
    path = tmp_path / "me.npz"
    avatar.save(path)
    assert [p.name for p in tmp_path.iterdir()] == ["me.npz"]  # no temporary left behind
    back = Avatar.load(path)
    back.check_compatible(anny32)
    np.testing.assert_array_equal(back.offsets, avatar.offsets)
    np.testing.assert_allclose(back.shape, avatar.shape)
    assert back.shape_names == anny32.shape_names
    wrong = Avatar("smpl:x.pkl", avatar.shape, avatar.shape_names, avatar.offsets)
    with pytest.raises(BodyModelError, match="avatar is for body model"):
        wrong.check_compatible(anny32)


def test_avatar_bad_files(tmp_path):
    with pytest.raises(BodyModelError, match="not found"):
        Avatar.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(BodyModelError):
        Avatar.load(tmp_path / "junk.npz")
