from __future__ import annotations

import numpy as np
import pytest

from monoavatar.perception import DeepFlow, DISFlow, estimate_flow
from monoavatar.perception.flow import flow_sequence, make_flow_estimator


def _texture(shape: tuple[int, int], dx: float, dy: float) -> np.ndarray:
    """A band-limited texture (a sum of sinusoids) translated by (dx, dy) px, exactly."""
    rng = np.random.default_rng(0)
    freqs = rng.uniform(0.02, 0.15, (40, 2)) * rng.choice([-1, 1], (40, 2))
    phases = rng.uniform(0, 2 * np.pi, 40)
    y, x = np.mgrid[: shape[0], : shape[1]].astype(np.float64)
    value = sum(
        np.sin(2 * np.pi * (f[0] * (x - dx) + f[1] * (y - dy)) + p)
        for f, p in zip(freqs, phases, strict=True)
    )
    grey = np.clip(128 + 14 * value, 0, 255).round().astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


@pytest.mark.parametrize(("method", "size"), [("dis", 256), ("deepflow", 128)])
def test_recovers_a_subpixel_translation(method: str, size: int) -> None:
    shift = np.array([2.3, -1.6])  # content moves right 2.3 px, up 1.6 px
    a = _texture((size, size), 0.0, 0.0)
    b = _texture((size, size), *shift)
    flow = estimate_flow(a, b, method=method)  # type: ignore[arg-type]
    assert flow.shape == (size, size, 2) and flow.dtype == np.float32
    inner = flow[16:-16, 16:-16].reshape(-1, 2)
    error = np.linalg.norm(inner - shift, axis=1)
    assert np.median(error) < 0.1
    np.testing.assert_allclose(np.median(inner, axis=0), shift, atol=0.1)


def test_sequence_and_errors() -> None:
    images = np.stack([_texture((64, 64), k * 1.0, 0.0) for k in range(3)])
    flows = flow_sequence(images, DISFlow("fast"))
    assert flows.shape == (2, 64, 64, 2)
    assert flow_sequence(images[:1], DISFlow()).shape == (0, 64, 64, 2)
    with pytest.raises(ValueError, match="one size"):
        DISFlow().estimate(images[0], images[0, :32])
    with pytest.raises(ValueError, match="DIS preset"):
        DISFlow("slow")
    with pytest.raises(ValueError, match="flow method"):
        make_flow_estimator("farneback")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        DeepFlow().estimate(images[0].astype(np.float32), images[1])
    assert "dis-medium" in DISFlow().name and "deepflow" in DeepFlow().name


def test_default_names_match_the_estimators() -> None:
    from monoavatar.perception.flow import flow_estimator_name

    for method in ("dis", "deepflow"):
        assert flow_estimator_name(method) == make_flow_estimator(method).name


def test_flow_near_a_region_recovers_the_translation_inside_its_box() -> None:
    # a 96 x 64 px patch of moving texture in a 256 px image: the flow is computed on the
    # patch's box grown by the margin, zero outside that box
    shift = np.array([1.7, 0.8])
    a = _texture((256, 256), 0.0, 0.0)
    b = _texture((256, 256), *shift)
    region = np.zeros((256, 256), bool)
    region[100:196, 120:184] = True
    flow = DISFlow().estimate_near(a, b, region, margin=24)
    assert flow.shape == (256, 256, 2) and flow.dtype == np.float32
    error = np.linalg.norm(flow[region] - shift, axis=1)
    assert np.median(error) < 0.1
    outside = np.ones((256, 256), bool)
    outside[100 - 24 : 196 + 24, 120 - 24 : 184 + 24] = False
    assert not flow[outside].any()
    assert not DISFlow().estimate_near(a, b, np.zeros((256, 256), bool)).any()
    with pytest.raises(ValueError, match="region must have shape"):
        DISFlow().estimate_near(a, b, region[:10])


def test_region_box_grows_by_the_margin_and_clips_to_the_image() -> None:
    from monoavatar.perception.masks import region_box

    region = np.zeros((50, 40), bool)
    region[10:20, 30:35] = True
    assert region_box(region, 5) == (slice(5, 25), slice(25, 40))
    assert region_box(region, 0) == (slice(10, 20), slice(30, 35))
    assert region_box(np.zeros((5, 5), bool), 3) is None
