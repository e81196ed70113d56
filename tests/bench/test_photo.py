"""The photo benchmark's measures, checked on a prediction that is exactly the truth, and its
table."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from monoavatar.bench.photo import _photo_metrics, render_photo_markdown
from monoavatar.learn.photo_data import PhotoDataSettings, base_fine_vertices, render_photo
from monoavatar.learn.uvmaps import displacement_targets, uv_layout


def test_a_perfect_prediction_scores_zero(anny32, anny_local, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The true phenotypes and the exact maps: the avatar is the truth (surface error ≈ 0, map
    error 0), while the body alone is off by the clothing (several mm)."""
    scene = render_photo(anny_local, 11, PhotoDataSettings(image_size=128, texture_size=64))
    layout = uv_layout(anny32, 128)
    shape = np.asarray(scene.subject.spec.shape[:6])
    truth = displacement_targets(layout, base_fine_vertices(anny32, layout, shape),
                                 scene.subject.rest_vertices.double())  # fmt: skip
    (tmp_path / "maps").mkdir()
    visible = np.zeros((128, 128), bool)
    visible[:64] = True
    np.savez(tmp_path / "maps" / "displacement.npz", visible=visible)
    result = SimpleNamespace(track=SimpleNamespace(shape=shape), folder=tmp_path, maps=truth,
                             vertices=scene.subject.rest_vertices.double().numpy())  # fmt: skip
    with torch.no_grad():
        m = _photo_metrics(anny32, layout, scene, result)
    assert m["maps_mm"] < 0.3 and m["maps_similarity_mm"] < 0.3
    # the exact maps read back at the vertices from 128² texels: the resampling costs < 1 mm
    assert m["exact_maps_mm"] < 1.0 and m["exact_maps_mm"] < m["body_mm"] / 2
    assert m["map_seen_mm"] == 0 and m["map_unseen_mm"] == 0
    assert m["body_mm"] > 2.0


def test_markdown_table_has_the_mean_and_the_reduction() -> None:
    rows = [
        {"seed": 1, "yaw_deg": 10.0, "fill": 0.8, "body_mm": 10.0, "maps_mm": 6.0,
         "exact_maps_mm": 3.0, "body_similarity_mm": 12.0, "maps_similarity_mm": 8.0,
         "map_seen_mm": 3.0, "map_unseen_mm": 5.0, "maps_seconds": 0.2, "seconds": 9.0},
        {"seed": 2, "yaw_deg": -20.0, "fill": 0.5, "body_mm": 8.0, "maps_mm": 4.8,
         "exact_maps_mm": 2.0, "body_similarity_mm": 9.0, "maps_similarity_mm": 6.0,
         "map_seen_mm": 2.0, "map_unseen_mm": 4.0, "maps_seconds": 0.3, "seconds": 11.0},
        {"seed": 3, "yaw_deg": 0.0, "fill": 0.4, "error": "PoseFitError: no person"},
    ]  # fmt: skip
    text = render_photo_markdown(rows)
    assert "| **mean of 2** | | | **9.00** | **5.40** (40 % less) | 2.50 |" in text
    assert "failed: PoseFitError: no person" in text
    assert "10.57" in text and "5.19" in text
