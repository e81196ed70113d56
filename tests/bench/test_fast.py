"""The few-frame table: means per method and frame count, failures listed, Table D.1 beside."""

from __future__ import annotations

from monoavatar.bench.fast import TABLE_D1, render_fast_markdown


def _fast(subject: str, frames: int, before: float, after: float) -> dict:  # type: ignore[type-arg]
    return {"subject": subject, "method": "fast", "frames": frames,
            "before": {"surface_mm": before, "similarity_mm": 2 * before},
            "after": {"surface_mm": after, "similarity_mm": 2 * after}, "rounds": 2,
            "seconds": 12.0, "network_seconds": 0.1, "refine_seconds": 9.0}  # fmt: skip


def test_table_means_per_method_and_frames() -> None:
    rows = [
        _fast("a", 8, 4.0, 3.0), _fast("b", 8, 6.0, 4.0), _fast("a", 1, 7.0, 6.0),
        {"subject": "a", "method": "full", "frames": 8, "seconds": 80.0,
         "after": {"surface_mm": 3.5, "similarity_mm": 7.5}},
        {"subject": "b", "method": "full", "frames": 8, "error": "PipelineError: no person"},
    ]  # fmt: skip
    text = render_fast_markdown(rows)
    lines = text.splitlines()
    # fast rows first, by frame count, then the full pipeline; means over the subjects
    assert lines[2] == "| reconstruct --fast | 1 | 1 | 7.00 (14.00) | 6.00 (12.00) | 0.10 | 12.0 |"
    assert lines[3] == "| reconstruct --fast | 8 | 2 | 5.00 (10.00) | 3.50 (7.00) | 0.10 | 12.0 |"
    assert lines[4] == "| reconstruct (full pipeline) | 8 | 1 |  | 3.50 (7.50) |  | 80.0 |"
    assert f"| {TABLE_D1['before_mm']} | {TABLE_D1['after_mm']} |" in lines[5]
    assert "| b | full | 8 | failed: PipelineError: no person |" in text
