"""The brute-force reference used by other tests, against closed forms."""

import numpy as np

from tests.geometry import point_triangle_distance


def test_point_triangle_distance_closed_forms():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    pts = np.array([[0.2, 0.2, 0.5], [2, 0, 0], [0.5, -1, 0], [-1, -1, 0], [0.6, 0.6, 0]])
    expected = [0.5, 1.0, 1.0, np.sqrt(2), np.sqrt(0.02)]  # face, vertex, edge, vertex, edge
    np.testing.assert_allclose(point_triangle_distance(pts, tri), expected, atol=1e-12)
