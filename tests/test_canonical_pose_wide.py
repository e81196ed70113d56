"""The canonical avatar of a wide, loosely dressed subject is in the rest pose (the check of
``test_canonical_pose.py``, in a file of its own so that the two reconstructions run side by
side under ``pytest -n 2 --dist loadfile``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.test_canonical_pose import check_rest_pose

pytestmark = pytest.mark.slow  # end-to-end: not in the fast tier


def test_true_poses_give_a_wide_subject_a_rest_pose_within_a_few_degrees_of_the_truths(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    check_rest_pose(tmp_path, monkeypatch, "loose", "wide")
