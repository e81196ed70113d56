"""Error heat-map colours (blue 0 mm → red ≥ 20 mm) and the PLY writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from monoavatar.eval import error_to_rgb, write_heatmap_ply

BLUE, CYAN, GREEN, YELLOW, RED = (0, 0, 1), (0, 1, 1), (0, 1, 0), (1, 1, 0), (1, 0, 0)


def test_endpoints_are_blue_and_red() -> None:
    rgb = error_to_rgb([0.0, 0.02, 0.5])
    np.testing.assert_allclose(rgb, [BLUE, RED, RED])


def test_ramp_passes_cyan_green_yellow_at_quarters() -> None:
    rgb = error_to_rgb([0.005, 0.010, 0.015, 0.0025])
    np.testing.assert_allclose(rgb, [CYAN, GREEN, YELLOW, (0, 0.5, 1)], atol=1e-12)


def test_max_error_is_configurable_and_nan_is_grey() -> None:
    np.testing.assert_allclose(error_to_rgb([0.01, 0.005], max_error=0.01), [RED, GREEN])
    np.testing.assert_allclose(error_to_rgb([np.nan]), [(0.5, 0.5, 0.5)])
    with pytest.raises(ValueError, match="non-negative"):
        error_to_rgb([-0.001])
    with pytest.raises(ValueError, match="max_error"):
        error_to_rgb([0.001], max_error=0.0)


def test_ply_round_trip(tmp_path: Path) -> None:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    errors = np.array([0.0, 0.01, 0.02, 0.04])
    path = tmp_path / "heat.ply"
    rgb = write_heatmap_ply(path, vertices, faces, errors)
    np.testing.assert_allclose(rgb, [BLUE, GREEN, RED, RED])

    mesh = trimesh.load(path, process=False)
    np.testing.assert_allclose(mesh.vertices, vertices)
    np.testing.assert_array_equal(mesh.faces, faces)
    colors = np.asarray(mesh.visual.vertex_colors)[:, :3]
    np.testing.assert_array_equal(colors, [[0, 0, 255], [0, 255, 0], [255, 0, 0], [255, 0, 0]])
