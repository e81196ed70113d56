"""Texel atlas: UV rasterisation, seam edges, the surface texel graph."""

from __future__ import annotations

import numpy as np
import pytest

from monoavatar.texture import TextureError, build_atlas, seam_edges, texel_graph
from tests.texture.scenes import cube, grid_patch, weld


def test_atlas_of_a_square_chart() -> None:
    # one quad filling UV [0.25, 0.75]^2, lying in the plane z = 0 with x = u, y = v
    mesh = weld([grid_patch(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 2,
                            (0.25, 0.25, 0.75, 0.75))])  # fmt: skip
    atlas = build_atlas(mesh.uv, mesh.face_uv, 16)
    assert atlas.num_texels == 8 * 8
    assert atlas.chart[4:12, 4:12].all() and atlas.chart.sum() == 64
    points = atlas.points(mesh.vertices, mesh.faces)
    rows, cols = np.divmod(atlas.texels, 16)
    # texel centre (col + 0.5) / 16 maps linearly to the surface
    np.testing.assert_allclose(points[:, 0], ((cols + 0.5) / 16 - 0.25) / 0.5, atol=1e-6)
    np.testing.assert_allclose(points[:, 1], ((rows + 0.5) / 16 - 0.25) / 0.5, atol=1e-6)
    np.testing.assert_allclose(atlas.bary.sum(axis=1), 1.0, atol=1e-6)
    assert (atlas.index[atlas.texels] == np.arange(atlas.num_texels)).all()


def test_seam_edges_of_a_cube() -> None:
    n = 3
    mesh = cube(n=n)
    seams = seam_edges(mesh.faces, mesh.face_uv)
    assert seams.shape == (12 * n, 2, 2)  # every cube edge, in n segments
    # both sides of a seam are the same two 3D points
    uv_vertex = np.zeros(len(mesh.uv), np.int64)
    uv_vertex[mesh.face_uv.ravel()] = mesh.faces.ravel()
    np.testing.assert_array_equal(uv_vertex[seams[:, 0]], uv_vertex[seams[:, 1]])
    assert (seams[:, 0] != seams[:, 1]).any(axis=1).all()
    # a mesh without UV cuts has none
    flat = weld([grid_patch(np.zeros(3), np.eye(3)[0], np.eye(3)[1], 3, (0, 0, 1, 1))])
    assert seam_edges(flat.faces, flat.face_uv).shape == (0, 2, 2)


def test_texel_graph_links_surface_neighbours_across_seams() -> None:
    mesh = cube(n=4)
    atlas = build_atlas(mesh.uv, mesh.face_uv, 48)
    graph = texel_graph(atlas, mesh.faces, mesh.uv, mesh.face_uv, mesh.vertices).tocoo()
    assert (graph != graph.T).nnz == 0
    points = atlas.points(mesh.vertices, mesh.faces)
    dist = np.linalg.norm(points[graph.row] - points[graph.col], axis=1)
    assert dist.max() < 0.15  # a texel is about 0.07 m x 0.045 m here
    side = mesh.side[atlas.face]
    pairs = {tuple(sorted(p)) for p in zip(side[graph.row], side[graph.col], strict=True)}
    across = {p for p in pairs if p[0] != p[1]}
    # the 12 pairs of cube sides that share an edge, and no opposite sides
    assert len(across) == 12
    assert not {(0, 1), (2, 3), (4, 5)} & across


def test_touching_charts_are_not_linked_unless_adjacent_in_3d() -> None:
    # two squares far apart in 3D whose UV charts touch along u = 0.5
    a = grid_patch(np.zeros(3), np.eye(3)[0], np.eye(3)[1], 2, (0.0, 0.0, 0.5, 1.0))
    b = grid_patch(np.array([5.0, 0, 0]), np.eye(3)[0], np.eye(3)[1], 2, (0.5, 0.0, 1.0, 1.0))
    mesh = weld([a, b])
    atlas = build_atlas(mesh.uv, mesh.face_uv, 16)
    graph = texel_graph(atlas, mesh.faces, mesh.uv, mesh.face_uv, mesh.vertices).tocoo()
    side = mesh.side[atlas.face]
    assert (side[graph.row] == side[graph.col]).all()
    assert graph.nnz > 0


def test_atlas_rejects_bad_sizes() -> None:
    mesh = cube(n=1)
    with pytest.raises(TextureError, match="at least 2"):
        build_atlas(mesh.uv, mesh.face_uv, 1)
    with pytest.raises(TextureError, match="uv must have shape"):
        build_atlas(mesh.uv[:, :1], mesh.face_uv, 8)
