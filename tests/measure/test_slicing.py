"""Plane sections, hull girths and vertical hits against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ellipe

from monoavatar.measure import girth, plane_basis, plane_section, vertical_hits
from tests.measure.primitives import polygon_perimeter, prism


@pytest.mark.parametrize(("a", "b"), [(0.1, 0.1), (0.15, 0.06)])
def test_horizontal_girth_of_a_prism_is_its_polygon(a: float, b: float) -> None:
    v, f = prism(np.array([0.0, 0, 0]), np.array([0.0, 1, 0]), a, b, n=48,
                 up=np.array([1.0, 0, 0]))  # fmt: skip
    for height in (0.05, 0.37, 0.5, 0.93):  # between rings and on a ring
        length, corners = girth(plane_section(v, f, np.array([0.0, height, 0]),
                                              np.array([0.0, 1, 0])))  # fmt: skip
        assert length == pytest.approx(polygon_perimeter(a, b), rel=1e-9)
        np.testing.assert_allclose(corners[:, 1], height, atol=1e-12)


def test_tilted_plane_through_a_cylinder_gives_an_ellipse() -> None:
    r, n, tilt = 0.05, 720, np.radians(35)
    v, f = prism(np.array([0.0, -1, 0]), np.array([0.0, 1, 0]), r, n=n, rings=3)
    normal = np.array([np.sin(tilt), np.cos(tilt), 0.0])
    length, _ = girth(plane_section(v, f, np.zeros(3), normal))
    a = r / np.cos(tilt)  # semi-major axis; semi-minor r
    exact = 4 * a * ellipe(1 - (r / a) ** 2)
    assert length == pytest.approx(exact, rel=1e-4)


def test_section_of_a_plane_missing_the_mesh_is_empty() -> None:
    v, f = prism(np.array([0.0, 0, 0]), np.array([0.0, 1, 0]), 0.1)
    section = plane_section(v, f, np.array([0.0, 2, 0]), np.array([0.0, 1, 0]))
    assert section.segments.shape == (0, 2, 3)
    assert girth(section)[0] == 0.0


def test_plane_basis_is_orthonormal_and_perpendicular() -> None:
    n = np.array([0.3, -0.5, 0.8])
    n /= np.linalg.norm(n)
    basis = plane_basis(n)
    np.testing.assert_allclose(basis @ basis.T, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(basis @ n, 0, atol=1e-12)


def test_vertical_hits_of_a_lying_cylinder() -> None:
    """A cylinder along X, radius r, centre height c: the line at (x, z) crosses it at
    c ± sqrt(r² − z²) (up to the polygon's sag)."""
    r, c, n = 0.1, 0.4, 360
    v, f = prism(np.array([-0.5, c, 0]), np.array([0.5, c, 0]), r, n=n, rings=3)
    z = 0.06
    hits = vertical_hits(v, f, 0.13, z)
    sag = r * (1 - np.cos(np.pi / n))
    np.testing.assert_allclose(hits, [c - np.sqrt(r**2 - z**2), c + np.sqrt(r**2 - z**2)],
                               atol=sag + 1e-9)  # fmt: skip
    assert len(vertical_hits(v, f, 0.7, 0.0)) == 0  # beyond its end


def test_a_vertical_line_along_an_edge_is_a_hit_once() -> None:
    """Two triangles sharing the edge x = 0 (a symmetric mesh's seam), tilted: the line
    x = 0, z = 0.1 runs along their edge and meets the surface once, at the edge's height."""
    v = np.array([[0.0, 0.0, 0.0], [0.0, 0.2, 0.3], [0.3, 0.5, 0.1], [-0.3, 0.5, 0.1]])
    f = np.array([[0, 1, 2], [0, 3, 1]])
    for x in (0.0, 1e-17, -1e-17):
        np.testing.assert_allclose(vertical_hits(v, f, x, 0.1), [0.2 / 3])
