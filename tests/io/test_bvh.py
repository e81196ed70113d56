"""BVH export read back by an independent parser (written here from the format's grammar):
forward kinematics of the file gives the body model's posed joints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from monoavatar.body import BodyModel
from monoavatar.io.bvh import write_bvh

AXES = {"X": 0, "Y": 1, "Z": 2}


def _parse(path: Path) -> tuple[list[str], list[int], np.ndarray, list[list[str]], np.ndarray]:
    """Joint names, parents, offsets (J, 3), each joint's channel names, and the motion rows."""
    tokens = path.read_text().split()
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    stack: list[int] = []
    i = tokens.index("HIERARCHY") + 1
    pending_end = False
    while tokens[i] != "MOTION":
        t = tokens[i]
        if t in ("ROOT", "JOINT"):
            names.append(tokens[i + 1])
            parents.append(stack[-1] if stack else -1)
            i += 2
        elif t == "End":
            pending_end = True
            i += 2
        elif t == "{":
            stack.append(-2 if pending_end else len(names) - 1)
            i += 1
        elif t == "}":
            stack.pop()
            pending_end = False
            i += 1
        elif t == "OFFSET":
            if stack[-1] != -2:
                offsets.append([float(x) for x in tokens[i + 1 : i + 4]])
            i += 4
        elif t == "CHANNELS":
            n = int(tokens[i + 1])
            channels.append(tokens[i + 2 : i + 2 + n])
            i += 2 + n
        else:
            raise AssertionError(f"unexpected token {t!r}")
    frames = int(tokens[tokens.index("Frames:") + 1])
    start = tokens.index("Time:") + 2
    values = np.asarray([float(x) for x in tokens[start:]]).reshape(frames, -1)
    return names, parents, np.asarray(offsets), channels, values


def _fk(parents: list[int], offsets: np.ndarray, channels: list[list[str]],
        row: np.ndarray) -> np.ndarray:  # fmt: skip
    """Joint positions of one motion row (file units)."""
    j = len(parents)
    glob = [np.eye(3)] * j
    pos = np.zeros((j, 3))
    col = 0
    for k in range(j):  # joints appear depth-first, parents before children
        local, position = np.eye(3), np.zeros(3)
        for name in channels[k]:
            value = row[col]
            col += 1
            axis = AXES[name[0]]
            if name.endswith("position"):
                position[axis] = value
            else:
                local = local @ Rotation.from_euler(name[0].lower(), value,
                                                    degrees=True).as_matrix()  # fmt: skip
        if parents[k] < 0:
            glob[k], pos[k] = local, offsets[k] + position
        else:
            p = parents[k]
            glob[k] = glob[p] @ local
            pos[k] = pos[p] + glob[p] @ offsets[k]
    return pos


def test_bvh_joints_are_the_posed_joints(anny32: BodyModel, tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n, j = 5, anny32.num_joints
    poses = rng.normal(scale=0.4, size=(n, j, 3))
    translations = rng.normal(scale=0.3, size=(n, 3))
    shape = torch.zeros(1, anny32.shape_dim)
    with torch.no_grad():
        _, rest = anny32.rest_shape(shape)
        out = anny32(shape=shape.expand(n, -1), pose=torch.as_tensor(poses, dtype=torch.float32),
                     translation=torch.as_tensor(translations, dtype=torch.float32))  # fmt: skip
    path = write_bvh(tmp_path / "motion.bvh", anny32.joint_names, anny32.parents,
                     rest[0].double().numpy(), poses, translations, fps=25.0)  # fmt: skip
    names, parents, offsets, channels, rows = _parse(path)
    order = [list(anny32.joint_names).index(name) for name in names]
    assert sorted(order) == list(range(j)) and len(rows) == n
    assert "Frame Time: 0.04" in path.read_text()
    for f in (0, 2, 4):
        joints_cm = _fk(parents, offsets, channels, rows[f])
        expected = out.joints[f].double().numpy()[order] * 100.0
        assert np.abs(joints_cm - expected).max() < 0.1  # within 1 mm


def test_bad_skeletons_and_shapes_are_refused(tmp_path: Path) -> None:
    rest = np.zeros((2, 3))
    with pytest.raises(ValueError, match="parents"):
        write_bvh(tmp_path / "x.bvh", ["a", "b"], [-1, 1], rest, np.zeros((1, 2, 3)),
                  np.zeros((1, 3)))  # fmt: skip
    with pytest.raises(ValueError, match="white space"):
        write_bvh(tmp_path / "x.bvh", ["a", "b c"], [-1, 0], rest, np.zeros((1, 2, 3)),
                  np.zeros((1, 3)))  # fmt: skip
    with pytest.raises(ValueError, match="translations"):
        write_bvh(tmp_path / "x.bvh", ["a", "b"], [-1, 0], rest, np.zeros((1, 2, 3)),
                  np.zeros((2, 3)))  # fmt: skip
    assert not (tmp_path / "x.bvh").exists()
