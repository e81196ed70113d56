from __future__ import annotations

import numpy as np
import pytest

from monoavatar.core.landmarks import (
    BODY25_TO_MEDIAPIPE,
    COCO18_TO_MEDIAPIPE,
    FACE68_TO_MEDIAPIPE468,
    MEDIAPIPE_LANDMARKS,
    OPENPOSE_BODY25,
    OPENPOSE_COCO18,
    mediapipe_face_to_68,
    openpose_to_mediapipe_body,
    openpose_to_mediapipe_face,
)


def test_body_tables_pair_same_named_joints() -> None:
    assert len(MEDIAPIPE_LANDMARKS) == 33
    for table, names in ((COCO18_TO_MEDIAPIPE, OPENPOSE_COCO18),
                         (BODY25_TO_MEDIAPIPE, OPENPOSE_BODY25)):
        for src, dst in table:
            source, target = names[src], MEDIAPIPE_LANDMARKS[dst]
            expected = source.replace("big_toe", "foot_index")
            assert target == expected, (source, target)
        assert len(set(table[:, 1])) == len(table)  # one source per landmark
    assert len(COCO18_TO_MEDIAPIPE) == 17 and len(BODY25_TO_MEDIAPIPE) == 21
    unmapped = {OPENPOSE_BODY25[i] for i in set(range(25)) - set(BODY25_TO_MEDIAPIPE[:, 0])}
    assert unmapped == {"neck", "mid_hip", "left_small_toe", "right_small_toe"}


def test_body_conversion_batches_and_shifts() -> None:
    kp = np.zeros((2, 4, 18, 3))
    kp[..., 0] = 10.0
    kp[..., 1] = 20.0
    kp[..., 2] = 0.7
    kp[1, 2, OPENPOSE_COCO18.index("nose")] = 0.0  # missing
    out = openpose_to_mediapipe_body(kp, "coco18")
    assert out.shape == (2, 4, 33, 3) and out.dtype == np.float32
    nose = MEDIAPIPE_LANDMARKS.index("nose")
    np.testing.assert_allclose(out[0, 0, nose], [10.5, 20.5, 0.7], rtol=1e-6)
    assert np.all(out[1, 2, nose] == 0)
    assert np.count_nonzero(out[0, 0, :, 2]) == 17
    with pytest.raises(ValueError, match=r"body25 keypoints must have shape \(\.\.\., 25, 3\)"):
        openpose_to_mediapipe_body(kp, "body25")
    with pytest.raises(ValueError, match="unknown OpenPose body format"):
        openpose_to_mediapipe_body(kp, "h36m")


def test_face_table_and_conversion() -> None:
    table = np.asarray(FACE68_TO_MEDIAPIPE468)
    assert table.shape == (68,) and len(set(table.tolist())) == 68
    assert table.min() >= 0 and table.max() < 468
    face = np.zeros((70, 3))
    face[:, 0] = np.arange(70)
    face[:, 1] = 5.0
    face[:, 2] = 0.9
    out = openpose_to_mediapipe_face(face)
    assert out.shape == (468, 3)
    np.testing.assert_allclose(mediapipe_face_to_68(out)[:, 0], np.arange(68) + 0.5)
    assert np.isnan(out[np.setdiff1d(np.arange(468), table)]).all()
    with pytest.raises(ValueError, match="70 or 68"):
        openpose_to_mediapipe_face(np.zeros((5, 3)))


def test_face_table_matches_the_mesh_geometry(astronaut_observations) -> None:
    """On a real frontal face, the 68 mapped vertices are laid out as dlib's 68 points."""
    obs = astronaut_observations
    pts = mediapipe_face_to_68(obs.face[0])[:, :2]
    assert np.isfinite(pts).all()
    x, y = pts[:, 0], pts[:, 1]
    jaw = slice(0, 17)
    assert np.all(np.diff(x[jaw][:9]) > 0) and np.all(np.diff(x[jaw][8:]) > 0)  # left to right
    assert np.argmax(y[jaw]) == 8  # the chin is the jaw's lowest point
    brows, eyes = slice(17, 27), slice(36, 48)
    assert y[brows].max() < y[eyes].mean()
    assert x[36:42].mean() < x[42:48].mean()  # the person's right eye is on the image's left
    assert x[36] < x[39] < x[42] < x[45]  # eye corners, outer right to outer left
    assert np.all(np.diff(y[27:31]) > 0)  # the nose bridge runs downwards
    assert y[eyes].mean() < y[30] < y[48:68].mean() < y[8]
    assert x[48] < x[51] < x[54] and x[60] < x[62] < x[64]
    assert y[51] < y[62] < y[66] < y[57]  # outer top, inner top, inner bottom, outer bottom
