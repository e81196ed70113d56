"""A tiny SMPL-format model written by the tests themselves (no SMPL data is shipped).

24 joints in SMPL's kinematic tree; around each joint a small octahedron of vertices, rigidly
skinned to it except for a few blended vertices; random shape and pose blend shapes."""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path

import numpy as np
import scipy.sparse

PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
JOINTS = np.array([
    [0, 0.9, 0], [0.1, 0.85, 0], [-0.1, 0.85, 0], [0, 1.0, 0], [0.1, 0.5, 0], [-0.1, 0.5, 0],
    [0, 1.15, 0], [0.1, 0.1, 0], [-0.1, 0.1, 0], [0, 1.25, 0], [0.1, 0.02, 0.1],
    [-0.1, 0.02, 0.1], [0, 1.45, 0], [0.08, 1.4, 0], [-0.08, 1.4, 0], [0, 1.6, 0.02],
    [0.18, 1.4, 0], [-0.18, 1.4, 0], [0.45, 1.4, 0], [-0.45, 1.4, 0], [0.7, 1.4, 0],
    [-0.7, 1.4, 0], [0.8, 1.4, 0], [-0.8, 1.4, 0],
])  # fmt: skip
OCTA = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
OCTA_FACES = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5],
                       [3, 1, 5], [0, 3, 5]])  # fmt: skip


def make_smpl_arrays(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    J = len(PARENTS)
    verts = (JOINTS[:, None, :] + 0.04 * OCTA[None]).reshape(-1, 3)
    faces = (OCTA_FACES[None] + 6 * np.arange(J)[:, None, None]).reshape(-1, 3)
    V = len(verts)
    weights = np.zeros((V, J))
    weights[np.arange(V), np.repeat(np.arange(J), 6)] = 1.0
    for j in range(1, J):  # blend the first vertex of each cluster with the parent
        weights[6 * j] = 0.0
        weights[6 * j, j] = 0.6
        weights[6 * j, PARENTS[j]] = 0.4
    regressor = np.zeros((J, V))
    for j in range(J):
        regressor[j, 6 * j : 6 * j + 6] = 1 / 6
    return {
        "v_template": verts,
        "shapedirs": 0.01 * rng.standard_normal((V, 3, 10)),
        "posedirs": 0.005 * rng.standard_normal((V, 3, 9 * (J - 1))),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.stack([np.array(PARENTS) % (2**32), np.arange(J)]),
        "f": faces,
    }


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    np.savez(path, **arrays)
    return path


def write_pkl(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    """The official files hold chumpy objects and a scipy sparse J_regressor; imitate both with
    a stand-in ``chumpy.ch.Ch`` class registered only while pickling."""
    ch_mod = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

    Ch.__module__ = "chumpy.ch"
    Ch.__qualname__ = "Ch"
    ch_mod.Ch = Ch
    saved = {k: sys.modules.get(k) for k in ("chumpy", "chumpy.ch")}
    sys.modules["chumpy"] = types.ModuleType("chumpy")
    sys.modules["chumpy.ch"] = ch_mod
    try:
        data = dict(arrays)
        data["shapedirs"] = Ch(arrays["shapedirs"])
        data["J_regressor"] = scipy.sparse.csc_matrix(arrays["J_regressor"])
        with path.open("wb") as fh:
            pickle.dump(data, fh, protocol=2)
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    return path
