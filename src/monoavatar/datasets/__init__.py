"""Readers of inputs that come with their own perception or ground truth: People-Snapshot
folders, OpenPose JSON keypoints and ``monoavatar synth`` scenes. Each returns frames (from
:mod:`monoavatar.io`) with :class:`~monoavatar.perception.PrecomputedPerception` or
:class:`~monoavatar.perception.Observations`, so this package sits above perception."""

from monoavatar.datasets.openpose import read_openpose_folder
from monoavatar.datasets.people_snapshot import (
    PeopleSnapshot,
    is_people_snapshot,
    read_people_snapshot,
    read_snapshot_camera,
)
from monoavatar.datasets.synth_scene import (
    SynthGroundTruth,
    SynthScene,
    is_synth_scene,
    read_synth_scene,
)

__all__ = [
    "PeopleSnapshot",
    "SynthGroundTruth",
    "SynthScene",
    "is_people_snapshot",
    "is_synth_scene",
    "read_openpose_folder",
    "read_people_snapshot",
    "read_snapshot_camera",
    "read_synth_scene",
]
