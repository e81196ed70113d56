"""``monoavatar bench --quick`` with the real reconstruction: a smoke test with loose bounds
(one small subject, few frames; the figures of record come from the full suite)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from monoavatar.cli import main

pytestmark = pytest.mark.slow  # end-to-end: not in the fast tier


def test_bench_quick_end_to_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setenv("MONOAVATAR_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "bench"
    assert main(["bench", "--quick", "-o", str(out), "--quiet"]) == 0
    results = json.loads((out / "results.json").read_text())
    table = (out / "results.md").read_text()
    assert "5.37 (BUFF)" in table and "3.40 (BUFF)" in table  # the dissertation beside us
    (subject,) = results["subjects"]
    assert set(subject["runs"]) == {"estimated", "shape-only", "gt-poses"}
    for run in subject["runs"].values():
        assert run["status"] == "ok", run.get("error")
        metrics = run["metrics"]
        assert 0.0 < metrics["surface_error_mm"] < 40.0  # a person-shaped avatar
        assert metrics["silhouette_iou"] > 0.5
        assert metrics["timings_s"]["shape"] > 0.0
    # the shape-only run is the estimated run's baseline column
    runs = subject["runs"]
    assert runs["estimated"]["metrics"]["shape_only_error_mm"] == pytest.approx(
        runs["shape-only"]["metrics"]["surface_error_mm"]
    )
    assert list((out / "heatmaps").glob("*.png"))
    assert "results.md" in capsys.readouterr().out
