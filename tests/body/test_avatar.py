import numpy as np
import pytest

from monoavatar.body import Avatar, BodyModelError


def test_avatar_compatibility(anny32):
    rng = np.random.default_rng(0)
    avatar = Avatar(
        model=anny32.identity,
        shape=rng.normal(size=anny32.shape_dim),
        shape_names=anny32.shape_names,
        offsets=rng.normal(size=(anny32.num_vertices, 3)).astype(np.float32),
    )
    avatar.check_compatible(anny32)
    wrong = Avatar("smpl:x.pkl", avatar.shape, avatar.shape_names, avatar.offsets)
    with pytest.raises(BodyModelError, match="avatar is for body model"):
        wrong.check_compatible(anny32)
    short = Avatar(anny32.identity, avatar.shape, avatar.shape_names, avatar.offsets[:-1])
    with pytest.raises(BodyModelError, match="vertices"):
        short.check_compatible(anny32)
