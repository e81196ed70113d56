"""Motion as BVH (Biovision Hierarchy), the skeleton-animation format Blender, Maya, Unity and
MotionBuilder import.

The skeleton is the body model's fitting skeleton: each joint's ``OFFSET`` is its rest position
minus its parent's (the rest pose is the canonical pose, whose joint frames are aligned with
the canonical axes: Y up, facing +Z), and its channels are ``Zrotation Xrotation Yrotation``
in degrees, the local rotation ``R_j = Rz · Rx · Ry`` of the body model's pose (per-joint
axis-angle in canonical axes). The root also has ``Xposition Yposition Zposition``: the
posed root joint, rest position plus translation (its ``OFFSET`` is zero). Forward kinematics
of the file then gives the body model's posed joints:
``p_j = p_parent + G_parent · OFFSET_j``, ``G_j = G_parent · R_j``.

Lengths are written in centimetres (``scale``, BVH's usual unit); a leaf joint gets an
``End Site`` a quarter of its bone beyond it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from monoavatar.core.files import atomic_write_text

__all__ = ["write_bvh"]


def write_bvh(
    path: str | Path,
    joint_names: Sequence[str],
    parents: Sequence[int],
    rest_joints: np.ndarray,
    poses: np.ndarray,
    translations: np.ndarray,
    fps: float = 30.0,
    scale: float = 100.0,
) -> Path:
    """Write a motion as BVH, atomically.

    Args:
        joint_names: J names (no white space); parents: J parent indices, ``parents[0] = -1``
            and ``parents[j] < j``.
        rest_joints: (J, 3) rest joint positions, canonical frame, metres.
        poses: (N, J, 3) per-frame local rotations, axis-angle radians in canonical axes
            (joint 0: the global orientation).
        translations: (N, 3) metres.
        fps: frames per second; scale: file units per metre (100: centimetres).
    Returns:
        ``path``.
    Raises:
        ValueError: inconsistent shapes, a bad skeleton or a name with white space.
    """
    names = list(joint_names)
    rest = np.asarray(rest_joints, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    trans = np.asarray(translations, dtype=np.float64)
    j = len(names)
    if len(parents) != j or parents[0] != -1 or any(parents[k] >= k for k in range(1, j)):
        raise ValueError("parents must give -1 for joint 0 and an earlier joint for the others")
    if rest.shape != (j, 3) or poses.ndim != 3 or poses.shape[1:] != (j, 3):
        raise ValueError(f"rest_joints must be ({j}, 3) and poses (N, {j}, 3), got "
                         f"{rest.shape} and {poses.shape}")  # fmt: skip
    if trans.shape != (len(poses), 3) or len(poses) == 0:
        raise ValueError(f"translations must be ({len(poses)}, 3) for N >= 1 frames")
    if any(not n or any(c.isspace() for c in n) for n in names):
        raise ValueError("joint names must be non-empty and without white space")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    children: list[list[int]] = [[] for _ in range(j)]
    for k in range(1, j):
        children[parents[k]].append(k)
    lines = ["HIERARCHY"]

    def emit(k: int, depth: int) -> None:
        pad = "  " * depth
        offset = np.zeros(3) if k == 0 else (rest[k] - rest[parents[k]]) * scale
        head = "ROOT" if k == 0 else "JOINT"
        lines.append(f"{pad}{head} {names[k]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}")
        channels = ("6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if k == 0
                    else "3 Zrotation Xrotation Yrotation")  # fmt: skip
        lines.append(f"{pad}  CHANNELS {channels}")
        for c in children[k]:
            emit(c, depth + 1)
        if not children[k]:
            tip = 0.25 * offset if k else np.array([0.0, 0.1 * scale, 0.0])
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET {tip[0]:.6f} {tip[1]:.6f} {tip[2]:.6f}")
            lines.append(f"{pad}  }}")
        lines.append(f"{pad}}}")

    emit(0, 0)
    order = []

    def walk(k: int) -> None:  # channel order of the MOTION rows: depth first, as written
        order.append(k)
        for c in children[k]:
            walk(c)

    walk(0)
    euler = Rotation.from_rotvec(poses.reshape(-1, 3)).as_euler("ZXY", degrees=True)
    euler = euler.reshape(len(poses), j, 3)
    root = (rest[0] + trans) * scale
    lines += ["MOTION", f"Frames: {len(poses)}", f"Frame Time: {1.0 / fps:.8f}"]
    for n in range(len(poses)):
        values = [*root[n], *np.concatenate([euler[n, k] for k in order])]
        lines.append(" ".join(f"{v:.6f}" for v in values))
    path = Path(path)
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
