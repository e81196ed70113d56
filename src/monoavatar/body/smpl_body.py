"""SMPL / SMPL-X from the user's own model files, behind the :class:`BodyModel` interface.

SMPL's licence forbids redistribution, so monoavatar ships no SMPL data: pass the path of a
model file you obtained yourself, either

- an ``.npz`` with the arrays below, or
- the official ``.pkl`` (e.g. ``basicmodel_neutral_lbs_10_207_0_v1.1.0.pkl``), read with a
  restricted unpickler that admits only NumPy/SciPy array types and replaces chumpy objects
  by their array value — chumpy is never imported and no other code in the file can run.

Arrays (SMPL layout): ``v_template (V, 3)``, ``shapedirs (V, 3, S)``, ``posedirs (V, 3, 9(J-1))``,
``J_regressor (J, V)`` (dense or scipy sparse), ``weights (V, J)``, ``kintree_table (2, J)``,
``f (F, 3)``; optional ``vt (T, 2)`` and ``ft (F, 3)`` UVs (OpenGL convention, origin at the
bottom-left, converted here). Without UVs a cylindrical fallback mapping is generated.
SMPL's own frame is already Y-up and facing +Z, metres.
"""

from __future__ import annotations

import copyreg
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import labels
from monoavatar.body.model import MEDIAPIPE_LANDMARKS, BodyModel, BodyModelError
from monoavatar.core.errors import InputError
from monoavatar.core.safe_pickle import safe_load

SMPL_HELP = (
    "SMPL and SMPL-X are licensed and cannot be shipped with monoavatar. Register at "
    "https://smpl.is.tue.mpg.de (SMPL) or https://smpl-x.is.tue.mpg.de (SMPL-X), download the "
    "model files (e.g. basicmodel_neutral_lbs_10_207_0_v1.1.0.pkl, SMPLX_NEUTRAL.npz) and pass "
    "the file's path. Without SMPL, use the default Anny model (no registration needed)."
)

SMPL_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "hip_l", "hip_r", "spine1", "knee_l", "knee_r", "spine2", "ankle_l", "ankle_r",
    "spine3", "foot_l", "foot_r", "neck", "collar_l", "collar_r", "head", "shoulder_l",
    "shoulder_r", "elbow_l", "elbow_r", "wrist_l", "wrist_r", "hand_l", "hand_r",
)  # fmt: skip

_REGION_OF_JOINT = {
    "head": "head", "neck": "torso", "hip_l": "legs", "hip_r": "legs", "knee_l": "legs",
    "knee_r": "legs", "ankle_l": "feet", "ankle_r": "feet", "foot_l": "feet", "foot_r": "feet",
    "shoulder_l": "arms", "shoulder_r": "arms", "elbow_l": "arms", "elbow_r": "arms",
    "wrist_l": "hands", "wrist_r": "hands", "hand_l": "hands", "hand_r": "hands",
}  # fmt: skip

#: mediapipe landmark → SMPL joint, for the landmarks SMPL's joints stand for.
_LANDMARK_JOINT = {
    "left_shoulder": "shoulder_l", "right_shoulder": "shoulder_r", "left_elbow": "elbow_l",
    "right_elbow": "elbow_r", "left_wrist": "wrist_l", "right_wrist": "wrist_r",
    "left_hip": "hip_l", "right_hip": "hip_r", "left_knee": "knee_l", "right_knee": "knee_r",
    "left_ankle": "ankle_l", "right_ankle": "ankle_r", "left_foot_index": "foot_l",
    "right_foot_index": "foot_r",
}  # fmt: skip

REQUIRED_KEYS = ("v_template", "shapedirs", "J_regressor", "weights", "kintree_table", "f")


class _Opaque:
    """Stand-in for a pickled chumpy object: keeps its state so its array can be read."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        self.state: Any = None

    def __setstate__(self, state: Any) -> None:
        self.state = state


_SPARSE = {"csc_matrix", "csr_matrix", "coo_matrix"}
MAX_DENSE = 50_000_000
"""Elements a sparse matrix of a model file may have when made dense (SMPL's J_regressor has
24 × 6890); a larger one is refused."""


class _SparseState:
    """Stand-in for a pickled scipy sparse matrix: keeps its state, never a scipy object (whose
    unchecked index arrays could make ``toarray`` write out of bounds); :func:`_sparse_to_dense`
    rebuilds it from checked arrays."""

    kind = ""

    def __init__(self, *args: object, **kwargs: object) -> None:
        self.state: Any = None

    def __setstate__(self, state: Any) -> None:
        self.state = state


_SPARSE_STANDINS = {name: type(f"_Sparse_{name}", (_SparseState,), {"kind": name})
                    for name in _SPARSE}  # fmt: skip


def _index_array(state: dict[str, Any], key: str, bound: int) -> np.ndarray:
    """``state[key]`` as a 1-D int64 array with every entry in [0, bound)."""
    value = np.asarray(state[key])
    if value.ndim != 1 or value.dtype.kind not in "iu":
        raise ValueError(f"{key} must be a 1-D integer array, got {value.dtype} {value.shape}")
    value = value.astype(np.int64)
    if value.size and (int(value.min()) < 0 or int(value.max()) >= bound):
        raise ValueError(f"{key} has entries outside [0, {bound})")
    return value


def _sparse_to_dense(value: _SparseState) -> np.ndarray:
    """The dense array of a pickled sparse matrix, rebuilt from validated ``data``, indices and
    shape. Raises ValueError for anything malformed or out of range."""
    state = value.state
    if not isinstance(state, dict):
        raise ValueError("no matrix state")
    shape = state.get("_shape", state.get("shape"))
    if (not isinstance(shape, tuple | list) or len(shape) != 2
            or not all(isinstance(x, int | np.integer) for x in shape)):  # fmt: skip
        raise ValueError(f"shape must be two integers, got {shape!r}")
    rows, cols = int(shape[0]), int(shape[1])
    if rows < 0 or cols < 0 or rows * cols > MAX_DENSE:
        raise ValueError(f"shape {shape!r} out of range (at most {MAX_DENSE} elements)")
    data = np.asarray(state["data"])
    if data.ndim != 1 or data.dtype.kind not in "biuf":
        raise ValueError(f"data must be a 1-D numeric array, got {data.dtype} {data.shape}")
    dense = np.zeros((rows, cols), dtype=np.float64)
    if value.kind == "coo_matrix":
        if "coords" in state:  # scipy >= 1.13 keeps (row, col) as one tuple
            coords = state["coords"]
            if not isinstance(coords, tuple | list) or len(coords) != 2:
                raise ValueError("coords must be (row, col)")
            state = {"row": coords[0], "col": coords[1]}
        row = _index_array(state, "row", rows)
        col = _index_array(state, "col", cols)
        if not len(row) == len(col) == len(data):
            raise ValueError("row, col and data differ in length")
        np.add.at(dense, (row, col), data.astype(np.float64))
        return dense
    major, minor = (cols, rows) if value.kind == "csc_matrix" else (rows, cols)
    indptr = _index_array(state, "indptr", len(data) + 1)
    indices = _index_array(state, "indices", minor)
    if len(indptr) != major + 1 or indptr[0] != 0 or indptr[-1] != len(data) \
            or len(indices) != len(data) or np.any(np.diff(indptr) < 0):  # fmt: skip
        raise ValueError("indptr does not partition the entries")
    lines = np.repeat(np.arange(major), np.diff(indptr))
    r, c = (indices, lines) if value.kind == "csc_matrix" else (lines, indices)
    np.add.at(dense, (r, c), data.astype(np.float64))
    return dense


def _smpl_globals(module: str, name: str) -> Any:
    """What official SMPL pickles need beyond plain arrays: chumpy objects (read as their
    array, chumpy is never imported) and scipy sparse matrices."""
    if module == "chumpy" or module.startswith("chumpy."):
        return _Opaque
    if module.startswith("scipy.sparse") and name in _SPARSE:
        return _SPARSE_STANDINS[name]
    if (module, name) == ("copyreg", "_reconstructor"):
        return copyreg._reconstructor  # type: ignore[attr-defined]
    if (module, name) == ("builtins", "object"):
        return object
    return None


def _to_array(value: Any) -> Any:
    if isinstance(value, _SparseState):
        try:
            return _sparse_to_dense(value)
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise BodyModelError(f"a sparse matrix in the model file is malformed: {exc}") \
                from exc
    if isinstance(value, _Opaque):
        state = value.state
        if isinstance(state, dict) and "x" in state:
            return np.asarray(state["x"])
        raise BodyModelError("a chumpy object in the model file has no array value")
    return value


def load_smpl_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """Read an SMPL-format model file (.npz or .pkl) into plain arrays (see module docs)."""
    path = Path(path)
    if not path.is_file():
        raise BodyModelError(f"SMPL model file not found: {path}. {SMPL_HELP}")
    raw: dict[str, Any]
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                raw = {k: data[k] for k in data.files}
        elif path.suffix == ".pkl":
            loaded = safe_load(path, _smpl_globals)
            if not isinstance(loaded, dict):
                raise BodyModelError(f"{path}: expected a dict of arrays, got {type(loaded)}")
            raw = loaded
        else:
            raise BodyModelError(f"{path}: unsupported model file type (use .npz or .pkl)")
    except (InputError, zipfile.BadZipFile, EOFError, ValueError, OSError) as exc:
        if isinstance(exc, BodyModelError):
            raise
        raise BodyModelError(f"{path} is not a readable SMPL model file: {exc}") from exc
    out: dict[str, np.ndarray] = {}
    for key, value in raw.items():
        value = _to_array(value)
        if isinstance(value, np.ndarray):
            out[key] = value
    missing = [k for k in REQUIRED_KEYS if k not in out]
    if missing:
        raise BodyModelError(f"{path} lacks {missing}; is it an SMPL/SMPL-X model file?")
    return out


def _cylindrical_uv(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fallback UV map: u = angle around the vertical axis, v = height; one UV per face corner
    so that faces across the seam do not wrap (they are clipped to the seam)."""
    c = vertices.mean(axis=0)
    u = np.arctan2(vertices[:, 0] - c[0], vertices[:, 2] - c[2]) / (2 * np.pi) + 0.5
    y = vertices[:, 1]
    v = 1.0 - (y - y.min()) / max(float(np.ptp(y)), 1e-9)
    fu = u[faces]
    wraps = fu.max(axis=1) - fu.min(axis=1) > 0.5
    fu[wraps] = np.where(fu[wraps] < 0.5, 0.0, fu[wraps])
    corner_uv = np.stack([fu, v[faces]], axis=-1).reshape(-1, 2)
    return np.clip(corner_uv, 0.0, 1.0), np.arange(len(faces) * 3).reshape(-1, 3)


class SmplBody(BodyModel):
    """SMPL or SMPL-X (body joints) from a user's model file."""

    v_template: Tensor
    shapedirs: Tensor
    J_regressor: Tensor
    posedirs: Tensor

    def __init__(self, path: str | Path, num_shape: int = 10, dtype: torch.dtype = torch.float32):
        super().__init__()
        arrays = load_smpl_arrays(path)
        v_template = arrays["v_template"].astype(np.float64)
        shapedirs = arrays["shapedirs"][:, :, :num_shape].astype(np.float64)
        weights = arrays["weights"].astype(np.float64)
        regressor = arrays["J_regressor"].astype(np.float64)
        faces = arrays["f"].astype(np.int64)
        V, J = weights.shape
        if v_template.shape != (V, 3) or shapedirs.shape[:2] != (V, 3) or regressor.shape != (J, V):
            raise BodyModelError(
                f"{path}: inconsistent array shapes (v_template {v_template.shape}, "
                f"shapedirs {shapedirs.shape}, weights {weights.shape}, "
                f"J_regressor {regressor.shape})"
            )
        if faces.min() < 0 or faces.max() >= V:
            raise BodyModelError(f"{path}: face indices out of range [0, {V})")
        parents = arrays["kintree_table"][0].astype(np.int64).tolist()
        parents[0] = -1
        if any(p >= j for j, p in enumerate(parents) if j > 0):
            raise BodyModelError(f"{path}: kintree_table is not in parents-first order")
        self.identity = f"smpl:{Path(path).name}"
        self.parents = tuple(int(p) for p in parents)
        self.joint_names = (
            SMPL_JOINT_NAMES if J == len(SMPL_JOINT_NAMES) else tuple(f"joint{j}" for j in range(J))
        )
        self.shape_names = tuple(f"beta{i}" for i in range(shapedirs.shape[2]))

        def buf(name: str, value: np.ndarray, as_dtype: torch.dtype = dtype) -> None:
            self.register_buffer(name, torch.as_tensor(value, dtype=as_dtype), persistent=False)

        buf("v_template", v_template)
        buf("shapedirs", shapedirs)
        buf("J_regressor", regressor)
        buf("skin_weights", weights / weights.sum(axis=1, keepdims=True))
        buf("faces", faces, torch.long)
        posedirs = arrays.get("posedirs")
        self.has_correctives = posedirs is not None and posedirs.shape[:2] == (V, 3)
        if posedirs is not None and self.has_correctives:
            buf("posedirs", posedirs.reshape(V * 3, -1).T.astype(np.float64))  # (9(J-1), 3V)
        if "vt" in arrays and "ft" in arrays:
            vt = arrays["vt"].astype(np.float64).copy()
            vt[:, 1] = 1.0 - vt[:, 1]
            buf("uv", vt)
            buf("face_uv", arrays["ft"].astype(np.int64), torch.long)
        else:
            uv, face_uv = _cylindrical_uv(v_template, faces)
            buf("uv", uv)
            buf("face_uv", face_uv, torch.long)

        names = [_REGION_OF_JOINT.get(self.joint_names[j], "torso") for j in weights.argmax(axis=1)]
        buf("regions", labels.regions_from_parts(v_template, names), torch.long)
        mirror, self.mirror_error = labels.mirror_pairs(v_template)
        buf("mirror", mirror, torch.long)
        kw, valid = self._keypoint_regressor(v_template, regressor, names)
        buf("keypoint_weights", kw)
        buf("keypoint_valid", valid, torch.bool)

    def _keypoint_regressor(
        self, rest: np.ndarray, regressor: np.ndarray, parts: list[str]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Landmarks from SMPL's joint regressor where a joint stands for one; the nose is the
        most forward face vertex. Other face and hand landmarks are not provided."""
        out = np.zeros((len(MEDIAPIPE_LANDMARKS), rest.shape[0]))
        valid = np.zeros(len(MEDIAPIPE_LANDMARKS), dtype=bool)
        if self.joint_names[: len(SMPL_JOINT_NAMES)] == SMPL_JOINT_NAMES:
            for landmark, joint in _LANDMARK_JOINT.items():
                k = MEDIAPIPE_LANDMARKS.index(landmark)
                out[k] = regressor[self.joint_names.index(joint)]
                valid[k] = True
        head = np.flatnonzero(np.array(parts) == "head")
        if len(head):
            k = MEDIAPIPE_LANDMARKS.index("nose")
            out[k, head[np.argmax(rest[head, 2])]] = 1.0
            valid[k] = True
        return out, valid

    def rest_shape(self, shape: Tensor) -> tuple[Tensor, Tensor]:
        """shape (B, S) betas → rest vertices (B, V, 3), joints (B, J, 3) (Eq. B.2 without
        B_p)."""
        vertices = self.v_template + torch.einsum("vcs,bs->bvc", self.shapedirs, shape)
        joints = torch.einsum("jv,bvc->bjc", self.J_regressor, vertices)
        return vertices, joints

    def pose_correctives(self, rotations: Tensor) -> Tensor | None:
        """B_p(θ): posedirs applied to (R_j − I) of the non-root joints (SMPL's pose feature)."""
        if not self.has_correctives:
            return None
        eye = torch.eye(3, dtype=rotations.dtype, device=rotations.device)
        feature = (rotations[:, 1:] - eye).reshape(rotations.shape[0], -1)
        if feature.shape[1] != self.posedirs.shape[0]:
            return None
        return (feature @ self.posedirs).reshape(rotations.shape[0], -1, 3)
