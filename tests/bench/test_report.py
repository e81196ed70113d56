"""Benchmark report: aggregation, the Markdown table with the published figures, results.json,
heat maps."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from monoavatar.bench.metrics import HeatMap, SubjectMetrics, SurfaceMetrics
from monoavatar.bench.report import (
    BenchResults,
    RunResult,
    aggregate,
    render_heatmap,
    render_markdown,
    write_heatmap,
    write_results,
)
from monoavatar.bench.suite import MODES, SUITE_VERSION, BenchSubject, BenchSuite

MINIMAL = BenchSubject("minimal-a", "minimal", 1, "minimal")
CLOTHED = BenchSubject("clothed-b", "clothed", 2, "loose")
CLOTHED2 = BenchSubject("clothed-c", "clothed", 3, "skirt")


def metrics(mean: float, std: float, psnr: float | None = 26.0) -> SubjectMetrics:
    return SubjectMetrics(
        surface=SurfaceMetrics(mean, std, mean - 0.1, mean + 0.1, 1.0),
        body_only_mm=mean + 3.0,
        shape_only_mm=None,
        pa_mpjpe_mm=20.0,
        silhouette_iou=0.95,
        silhouette_iou_min=0.9,
        psnr_db=psnr,
        psnr_overlap_db=None if psnr is None else psnr + 1,
        heldout_frames=20,
        texture_lighting="unlit",
        keyframes=30,
        timings={"perception": 3.0, "poses": 60.0, "shape": 5.0, "texture": 4.0, "export": 2.0},
        reconstruct_seconds=80.0,
        peak_memory_mb=900.0,
    )


def make_results(tmp_path: Path) -> BenchResults:
    suite = BenchSuite(SUITE_VERSION, "full", (MINIMAL, CLOTHED, CLOTHED2))
    res = BenchResults(out_dir=tmp_path, suite=suite, modes=MODES,
                       machine={"cpu": "Test CPU", "usable_cores": 2, "torch_threads": 2,
                                "python": "3.11", "torch": "2.x", "monoavatar": "0"},
                       date="2026-11-30T12:00:00+00:00", seconds=600.0)  # fmt: skip
    runs = [
        (MINIMAL, "estimated", metrics(4.0, 3.0)),
        (CLOTHED, "estimated", metrics(6.0, 4.0)),
        (CLOTHED2, "estimated", metrics(8.0, 2.0)),
        (MINIMAL, "gt-poses", metrics(3.0, 2.0)),
        (CLOTHED, "gt-poses", metrics(3.5, 2.0, psnr=None)),
    ]
    for subject, mode, m in runs:
        res.runs.append(RunResult(subject, mode, tmp_path / "runs" / subject.name / mode, "ok",
                                  metrics=m, wall_seconds=90.0, peak_rss_mb=1000.0))  # fmt: skip
    res.runs.append(RunResult(CLOTHED2, "gt-poses", tmp_path / "x", "failed",
                              error="RuntimeError: boom\nmore", wall_seconds=1.0))  # fmt: skip
    return res


def test_aggregate_by_category(tmp_path):
    res = make_results(tmp_path)
    agg = aggregate(res.runs, MODES)
    est = agg["estimated"]
    assert set(est) == {"minimal", "clothed", "all"}
    assert est["clothed"]["surface_error_mm"] == pytest.approx(7.0)
    # mixture std of two subjects (6 ± 4, 8 ± 2) around 7: sqrt(((16 + 1) + (4 + 1)) / 2)
    assert est["clothed"]["surface_error_std_mm"] == pytest.approx(math.sqrt(11.0))
    assert est["all"]["surface_error_mm"] == pytest.approx(6.0)
    assert est["all"]["subjects"] == 3 and est["all"]["failed"] == 0
    assert est["clothed"]["body_only_error_mm"] == pytest.approx(10.0)
    assert est["all"]["shape_only_error_mm"] is None
    assert est["all"]["timings_s"]["poses"] == pytest.approx(60.0)
    gt = agg["gt-poses"]
    assert gt["clothed"]["subjects"] == 2 and gt["clothed"]["failed"] == 1
    assert gt["clothed"]["surface_error_mm"] == pytest.approx(3.5)
    assert gt["clothed"]["texture_psnr_db"] is None  # the only ok run had no PSNR
    assert gt["minimal"]["texture_psnr_db"] == pytest.approx(26.0)


def test_table_has_published_columns(tmp_path):
    res = make_results(tmp_path)
    res.aggregate = aggregate(res.runs, MODES)
    table = render_markdown(res)
    for figure in ("5.37 (BUFF)", "4.44 (D-FAUST)", "3.97", "3.40 (BUFF)", "2.86 (D-FAUST)"):
        assert figure in table
    assert "dissertation, estimated poses" in table
    assert "dissertation, ground-truth poses" in table
    assert "1 min per frame" in table and "1:50 min" in table
    assert "7.00 ± 3.32" in table  # clothed, estimated
    assert "Test CPU" in table and "2 usable cores" in table
    assert "failed: RuntimeError: boom" in table
    rows = [line for line in table.splitlines() if line.startswith("| clothed (like BUFF)")]
    assert rows and "5.37" in rows[0] and "3.40" in rows[0]
    assert table.startswith(f"# monoavatar bench: suite v1 (full), version {SUITE_VERSION},")
    res.suite = BenchSuite(1, "v2-test", res.suite.subjects)
    assert render_markdown(res).startswith("# monoavatar bench: suite v2, test split, version 1,")


def test_table_shows_the_root_orientation_error(tmp_path):
    res = make_results(tmp_path)
    for i, (median, worst, off) in enumerate(((4.0, 12.0, 0), (8.0, 45.0, 2))):
        r = res.runs[i]
        r.metrics = replace(r.metrics, root_error_deg=median, root_error_max_deg=worst,
                            root_off_frames=off)  # fmt: skip
    res.aggregate = aggregate(res.runs, MODES)
    table = render_markdown(res)
    def split(line: str) -> list[str]:
        return [c.strip() for c in line.strip().strip("|").split("|")]

    header = split(next(line for line in table.splitlines() if "| root (°) |" in line))
    column = header.index("root (°)")
    cells = {}
    for line in table.splitlines():
        parts = split(line)
        if line.startswith("| estimated poses |") and len(parts) == len(header):
            cells[parts[1]] = parts[column]
    assert cells["minimal clothing (like D-FAUST)"] == "4.0 (12.0, 0)", cells
    assert cells["all subjects"] == "6.0 (45.0, 2)", cells


def test_results_files(tmp_path):
    res = make_results(tmp_path)
    files = write_results(res)
    data = json.loads(files["results.json"].read_text())
    assert data["suite"] == {"version": SUITE_VERSION, "name": "full"}
    assert data["machine"]["cpu"] == "Test CPU"
    assert data["date"].startswith("2026-11-30")
    assert [m["name"] for m in data["modes"]] == ["estimated", "shape-only", "gt-poses"]
    subjects = {s["name"]: s for s in data["subjects"]}
    assert set(subjects) == {"minimal-a", "clothed-b", "clothed-c"}
    run = subjects["clothed-b"]["runs"]["estimated"]
    assert run["status"] == "ok" and run["metrics"]["surface_error_mm"] == 6.0
    assert run["folder"] == "runs/clothed-b/estimated"
    assert subjects["clothed-c"]["runs"]["gt-poses"]["status"] == "failed"
    assert data["aggregate"]["estimated"]["minimal"]["surface_error_mm"] == 4.0
    assert data["published"]["surface_error_mm"]["gt-poses"]["clothed"] == 3.40
    assert files["results.md"].read_text() == res.table


def test_only_estimated_mode(tmp_path):
    res = make_results(tmp_path)
    res.modes = MODES[:1]
    res.runs = [r for r in res.runs if r.mode == "estimated"]
    write_results(res)
    assert "gt-poses" not in res.aggregate
    assert "5.37 (BUFF)" in res.table and "3.40" not in res.table


def test_heatmap_colours_and_files(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    v = np.asarray(sphere.vertices)
    errors = np.where(v[:, 1] > 0, 0.03, 0.0)  # top: ≥ 20 mm (red), bottom: 0 (blue)
    heat = HeatMap(v, np.asarray(sphere.faces), errors)
    image = render_heatmap(heat, size=128, title="sphere")
    assert image.dtype == np.uint8 and image.shape[1] == 256
    body = image[20 : 20 + 128].reshape(-1, 3).astype(int)
    reddish = (body[:, 0] > 100) & (body[:, 1] < 60) & (body[:, 2] < 60)
    bluish = (body[:, 2] > 100) & (body[:, 0] < 60) & (body[:, 1] < 60)
    assert reddish.sum() > 500 and bluish.sum() > 500
    write_heatmap(heat, tmp_path / "h" / "s.png", tmp_path / "h" / "s.ply", title="sphere")
    assert Image.open(tmp_path / "h" / "s.png").size[0] == 960  # two 480-pixel views
    ply = trimesh.load(tmp_path / "h" / "s.ply", process=False)
    assert len(ply.vertices) == len(v)


def test_table_shows_the_errors_by_region(tmp_path):
    from dataclasses import replace

    res = make_results(tmp_path)
    for i, face in enumerate((2.0, 4.0)):  # the minimal and clothed estimated runs
        m = res.runs[i].metrics
        assert m is not None
        surface = replace(m.surface, normal_error_deg=10.0 + i, rigid_normal_error_deg=20.0,
                          regions={"face": (face, 6.0 + 2 * i), "garments": (1.0, 5.0)})
        res.runs[i] = replace(res.runs[i], metrics=replace(m, surface=surface))
    res.aggregate = aggregate(res.runs, MODES)
    assert res.aggregate["estimated"]["all"]["regions"]["face"]["surface_error_mm"] == 3.0
    table = render_markdown(res)
    section = table.split("## By region")[1].split("##")[0]
    row = next(line for line in section.splitlines() if line.startswith("| estimated |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    # whole: surface mean of 4, 6, 8 mm; normal mean of the two runs that have it
    assert cells[1] == "6.00 / 10.5" and cells[2].endswith("/ 20.0")
    assert cells[3] == "3.00 / 7.0" and cells[4] == "1.00 / 5.0" and cells[5] == "– / –"
