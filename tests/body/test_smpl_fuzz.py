"""Fuzzing the SMPL loader with crafted sparse matrices: every mutated file either loads the
matrix scipy itself accepts, to the same values, or is refused with a BodyModelError; none
crashes the process or loads out-of-range data."""

from __future__ import annotations

import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from monoavatar.body import BodyModelError
from monoavatar.body.smpl_body import MAX_DENSE, load_smpl_arrays
from tests.body.smpl_fixture import make_smpl_arrays

BAD_INDICES = (-1, -(2**31), 2**30, 2**31 - 1, 10**12)


def _mutate(m: sp.spmatrix, rng: np.random.Generator) -> tuple[object, str]:
    """A mutated copy of ``m`` (or a container holding it) and what was done."""
    m = m.copy()
    kind = rng.integers(9)
    if kind == 0 and m.format != "coo":  # an index out of range
        idx = np.array(m.indices, dtype=rng.choice([np.int32, np.int64]))
        value = int(rng.choice(BAD_INDICES + (m.shape[0 if m.format == "csc" else 1],)))
        info = np.iinfo(idx.dtype)
        idx[rng.integers(len(idx))] = np.clip(value, info.min, info.max)
        m.indices = idx
        return m, "indices"
    if kind == 1 and m.format != "coo":  # indptr broken
        ptr = m.indptr.copy()
        how = rng.integers(4)
        if how == 0:
            rng.shuffle(ptr)
        elif how == 1:
            ptr = ptr[: rng.integers(1, len(ptr))]
        elif how == 2:
            ptr[rng.integers(1, len(ptr))] = int(rng.choice(BAD_INDICES[2:]))
        else:
            ptr[-1] -= 1
        m.indptr = ptr
        return m, "indptr"
    if kind == 2:  # data of the wrong length or type
        how = rng.integers(3)
        if how == 0:
            m.data = m.data[: rng.integers(0, len(m.data))]
        elif how == 1:
            m.data = np.array(["x"] * len(m.data))
        else:
            m.data = m.data.reshape(-1, 1)
        return m, "data"
    if kind == 3:  # the shape
        m._shape = [(10**6, 10**6), (-1, 5), (2.5, 3), (1, 2, 3), None, (m.shape[0], 10**9)][
            rng.integers(6)]
        return m, "shape"
    if kind == 4:  # a key missing
        key = rng.choice(["data", "indices", "indptr", "_shape", "row", "col"])
        if key in m.__dict__:
            del m.__dict__[key]
        return m, "missing"
    if kind == 5 and m.format == "coo":  # coordinates out of range
        which = "row" if rng.integers(2) else "col"
        arr = getattr(m, which).copy()
        arr[rng.integers(len(arr))] = int(rng.choice(BAD_INDICES))
        setattr(m, which, arr)
        return m, "coo"
    if kind == 6:  # index arrays of another type
        target = "indices" if m.format != "coo" else "row"
        setattr(m, target, getattr(m, target).astype(rng.choice([np.float64, np.uint8])))
        return m, "dtype"
    if kind == 7:  # nested in a container
        return [m], "nested"
    return m, "valid"


def _scipy_accepts(m: object) -> bool:
    """Whether scipy's own checks pass and the dense matrix is within the loader's bound."""
    if not isinstance(m, sp.spmatrix):
        return False
    try:
        if m.shape[0] * m.shape[1] > MAX_DENSE:
            return False
        if m.format == "coo":
            r, c = m.row, m.col
            return bool(len(r) == len(c) == len(m.data) and (r >= 0).all() and (c >= 0).all()
                        and (r < m.shape[0]).all() and (c < m.shape[1]).all()
                        and m.data.dtype.kind in "biuf")  # fmt: skip
        m.check_format(full_check=True)  # type: ignore[attr-defined]
        return m.data.dtype.kind in "biuf" and m.data.ndim == 1
    except Exception:  # noqa: BLE001 - any refusal by scipy counts as invalid
        return False


def test_mutated_sparse_regressors_never_crash_or_load_out_of_range(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    arrays = make_smpl_arrays()
    reference = arrays["J_regressor"]
    counts = {"refused": 0, "loaded": 0}
    case = 0
    while counts["refused"] + counts["loaded"] < 520:
        case += 1
        fmt = ("csc", "csr", "coo")[case % 3]
        base = {"csc": sp.csc_matrix, "csr": sp.csr_matrix, "coo": sp.coo_matrix}[fmt](reference)
        path = tmp_path / f"case{case}.pkl"
        try:  # some mutations scipy refuses already while we make or pickle them
            mutated, what = _mutate(base, rng)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # scipy warns about index dtypes it refuses
                accepts = _scipy_accepts(mutated)
            expected = mutated.toarray() if accepts else None  # type: ignore[union-attr]
            with path.open("wb") as fh:
                pickle.dump({**arrays, "J_regressor": mutated}, fh,
                            protocol=int(rng.integers(2, 6)))  # fmt: skip
        except ValueError:
            continue
        try:
            loaded = load_smpl_arrays(path)
        except BodyModelError:
            counts["refused"] += 1
            continue
        counts["loaded"] += 1
        assert accepts, f"case {case} ({fmt}, {what}) loaded a matrix scipy refuses"
        np.testing.assert_array_equal(loaded["J_regressor"], expected)
    assert counts["refused"] > 200 and counts["loaded"] > 50, counts


@pytest.mark.parametrize("fmt", ["csc", "csr", "coo"])
def test_a_valid_sparse_regressor_loads_to_its_dense_values(tmp_path: Path, fmt: str) -> None:
    arrays = make_smpl_arrays()
    m = {"csc": sp.csc_matrix, "csr": sp.csr_matrix, "coo": sp.coo_matrix}[fmt](
        arrays["J_regressor"])
    path = tmp_path / "ok.pkl"
    with path.open("wb") as fh:
        pickle.dump({**arrays, "J_regressor": m}, fh, protocol=2)
    np.testing.assert_array_equal(load_smpl_arrays(path)["J_regressor"], arrays["J_regressor"])
