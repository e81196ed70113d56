"""The tracking benchmark's table (Table A.1 beside ours, means per kind, failures shown) and
one quick end-to-end run on a short walk."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from monoavatar.bench.tracking import TABLE_A1, render_tracking_markdown
from monoavatar.cli import main


def test_table_shows_each_sequence_the_means_in_cm_and_table_a1() -> None:
    rows = [
        {"sequence": "walk-s1", "kind": "walk", "local_mm": 40.0, "global_mm": 60.0,
         "acceleration_mm_per_frame2": 5.0, "seconds_per_frame": 0.4},
        {"sequence": "walk-s2", "kind": "walk", "local_mm": 60.0, "global_mm": 80.0,
         "acceleration_mm_per_frame2": 7.0, "seconds_per_frame": 0.6},
        {"sequence": "jog-s3", "kind": "jog", "error": "TrackError: no person"},
    ]  # fmt: skip
    table = render_tracking_markdown(rows)
    assert "| walk-s1 | 4.0 | 6.0 | 5.0 | 0.40 | 5.5 / 7.6 |" in table
    assert "| **walk, mean** | **5.0** | **7.0** | 6.0 | 0.50 | 5.5 / 7.6 |" in table
    assert "| jog-s3 | failed: TrackError: no person |" in table
    assert "jog, mean" not in table  # no jog sequence succeeded
    assert TABLE_A1["jog"] == {"local_cm": 7.9, "global_cm": 9.9}


@pytest.mark.slow
def test_bench_tracking_quick_end_to_end(tmp_path: Path, capsys) -> None:
    assert main(["bench", "--tracking", "--quick", "-o", str(tmp_path), "--quiet"]) == 0
    results = json.loads((tmp_path / "tracking.json").read_text())
    (row,) = results["sequences"]
    assert "error" not in row, row
    assert 0 < row["local_mm"] < 300 and row["global_mm"] >= row["local_mm"] * 0.5
    assert (tmp_path / "tracking" / "walk-s101" / "motion.bvh").is_file()
    assert "walk-s101" in (tmp_path / "tracking.md").read_text()
    assert "walk, mean" in capsys.readouterr().out
