"""Harmonic filling over a graph and dilation beyond charts."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from monoavatar.texture import dilate_texture, harmonic_fill


def _path(n: int) -> sp.csr_matrix:
    i = np.arange(n - 1)
    return sp.coo_matrix((np.ones(2 * (n - 1)), (np.r_[i, i + 1], np.r_[i + 1, i])),
                         shape=(n, n)).tocsr()  # fmt: skip


def test_harmonic_fill_on_a_path_is_linear() -> None:
    values = np.zeros((6, 2))
    values[0] = (0.0, 1.0)
    values[5] = (1.0, 0.0)
    known = np.array([True, False, False, False, False, True])
    out = harmonic_fill(_path(6), values, known)
    np.testing.assert_allclose(out[:, 0], np.linspace(0, 1, 6), atol=1e-5)
    np.testing.assert_allclose(out[:, 1], np.linspace(1, 0, 6), atol=1e-5)
    assert out[0, 0] == 0.0 and out[5, 0] == 1.0  # known values untouched


def test_unknown_island_gets_the_mean() -> None:
    graph = sp.block_diag([_path(3), _path(2)]).tocsr()  # nodes 3, 4 touch nothing known
    values = np.array([[0.2], [0.0], [0.6], [9.0], [9.0]])
    known = np.array([True, False, True, False, False])
    out = harmonic_fill(graph, values, known)
    np.testing.assert_allclose(out[:, 0], [0.2, 0.4, 0.6, 0.4, 0.4], atol=1e-4)


def test_harmonic_fill_edge_cases() -> None:
    values = np.ones((3, 3))
    np.testing.assert_array_equal(harmonic_fill(_path(3), values, np.ones(3, bool)), values)
    assert (harmonic_fill(_path(3), values, np.zeros(3, bool)) == 0).all()
    with pytest.raises(ValueError, match="agree on N"):
        harmonic_fill(_path(3), values[:2], np.ones(2, bool))


def test_dilate_texture_grows_rings_and_fills_the_rest() -> None:
    image = np.zeros((9, 9, 3), np.float32)
    valid = np.zeros((9, 9), bool)
    image[4, 4] = (1.0, 0.5, 0.25)
    valid[4, 4] = True
    out = dilate_texture(image, valid, iterations=2, fill_rest=False)
    np.testing.assert_allclose(out[2:7, 2:7], np.broadcast_to((1.0, 0.5, 0.25), (5, 5, 3)))
    assert (out[0] == 0).all()
    full = dilate_texture(image, valid, iterations=1)
    np.testing.assert_allclose(full[0, 0], (1.0, 0.5, 0.25))
    np.testing.assert_array_equal(dilate_texture(image, np.zeros((9, 9), bool), 3), image)
