"""UV maps: rasterising per-vertex values and sampling them back, and the exact targets."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from monoavatar.learn.uvmaps import (
    DISPLACEMENT_SCALE,
    UVMapError,
    displacement_targets,
    from_normal_frame,
    rasterise_vertex_values,
    sample_vertex_values,
    texel_frames,
    to_normal_frame,
    uv_layout,
)


@pytest.fixture(scope="module")
def layout(anny32):  # type: ignore[no-untyped-def]
    return uv_layout(anny32, 128)


@pytest.fixture(scope="module")
def fine_rest(anny32, layout):  # type: ignore[no-untyped-def]
    with torch.no_grad():
        rest, _ = anny32.rest_shape(anny32.default_shape(1))
        return layout.subdivision.apply(rest.double())[0]


def test_layout_covers_the_fine_mesh(layout, anny32) -> None:  # type: ignore[no-untyped-def]
    assert layout.num_coarse == anny32.num_vertices
    assert layout.num_vertices > 3 * anny32.num_vertices
    assert 0.3 < layout.chart.mean() < 0.9  # charts fill much, not all, of the atlas


def test_constant_map_samples_to_the_constant(layout) -> None:  # type: ignore[no-untyped-def]
    """Every vertex reads exactly a constant map's value: the dilation keeps texels outside
    the charts from leaking into border vertices."""
    image = np.zeros((128, 128, 2), np.float32)
    image[layout.chart] = [0.25, -1.5]
    values = sample_vertex_values(layout, image)
    np.testing.assert_allclose(values, np.tile([0.25, -1.5], (layout.num_vertices, 1)), atol=1e-6)
    coarse = sample_vertex_values(layout, image, coarse=True)
    assert coarse.shape == (layout.num_coarse, 2)


def test_round_trip_of_a_smooth_field(layout, fine_rest) -> None:  # type: ignore[no-untyped-def]
    """Rasterise the vertices' own positions, sample them back: the error is a small fraction
    of a texel's size on the body (a 128² map: about 1 cm per texel)."""
    v = fine_rest.numpy()
    image = rasterise_vertex_values(layout, v)
    back = sample_vertex_values(layout, image)
    error = np.linalg.norm(back - v, axis=1)
    assert np.median(error) < 2e-3
    assert np.mean(error) < 6e-3
    # any map resolution reads the same field
    big = rasterise_vertex_values(layout, v)
    assert np.allclose(sample_vertex_values(layout, big), back)


def test_targets_of_a_known_displacement(layout, fine_rest) -> None:  # type: ignore[no-untyped-def]
    """A surface shifted by a constant vector: displacement channels equal it / scale on the
    charts, 0 elsewhere; normal channels are unit vectors on the charts."""
    shift = torch.tensor([0.02, -0.01, 0.005], dtype=torch.float64)
    maps = displacement_targets(layout, fine_rest, fine_rest + shift)
    chart = layout.chart
    np.testing.assert_allclose(
        maps[chart, :3], np.tile(shift.numpy() / DISPLACEMENT_SCALE, (chart.sum(), 1)), atol=1e-5
    )
    assert np.all(maps[~chart] == 0)
    norms = np.linalg.norm(maps[chart, 3:], axis=1)
    assert np.median(norms) > 0.98  # interpolated unit normals: unit up to the curvature


def test_wrong_shapes_are_refused(layout, fine_rest) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(UVMapError, match="values"):
        rasterise_vertex_values(layout, np.zeros((10, 3)))
    with pytest.raises(UVMapError, match="map"):
        sample_vertex_values(layout, np.zeros((16, 8, 3)))
    with pytest.raises(UVMapError, match="base"):
        displacement_targets(layout, fine_rest[:10], fine_rest[:10])


def test_normal_frames(layout, fine_rest) -> None:  # type: ignore[no-untyped-def]
    """Orthonormal right-handed frames whose first axis is the surface normal of the exact
    targets; a surface pushed 1 cm along its vertex normals has normal component 1 cm and
    (almost) no tangential one; to and from the frame is the identity."""
    from monoavatar.core.geometry import vertex_normals

    frames = texel_frames(layout, fine_rest.numpy())
    chart = layout.chart
    f = frames[chart].astype(np.float64)
    np.testing.assert_allclose(f @ f.transpose(0, 2, 1), np.tile(np.eye(3), (len(f), 1, 1)),
                               atol=1e-5)  # fmt: skip
    np.testing.assert_allclose(np.linalg.det(f), 1.0, atol=1e-5)
    assert np.all(frames[~chart] == 0)
    normals = vertex_normals(fine_rest, layout.subdivision.faces)
    pushed = displacement_targets(layout, fine_rest, fine_rest + 0.01 * normals)
    target_normals = pushed[chart, 3:] / np.linalg.norm(pushed[chart, 3:], axis=1, keepdims=True)
    assert np.median((f[:, 0] * target_normals).sum(1)) > 0.999
    local = to_normal_frame(pushed[..., :3], frames, 0.25)[chart] * DISPLACEMENT_SCALE
    assert np.median(np.abs(local[:, 0] - 0.01)) < 2e-4
    assert np.median(np.abs(local[:, 1:])) < 2e-4
    rng = np.random.default_rng(0)
    disp = rng.normal(size=(2, 128, 128, 3)).astype(np.float32)
    back = from_normal_frame(to_normal_frame(disp, frames, 0.25), frames, 0.25)
    np.testing.assert_allclose(back[:, chart], disp[:, chart], atol=1e-5)
