"""bench/scale.py without the chain: block sizes, the stage table from a run's records, the verdict on the
issue's limits and bench/results/scale.json keyed by size. (The whole benchmark on the ``tiny`` preset:
``bench/scale.py --size tiny --generate``, about 2 minutes.)"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import pytest

from aerotri.chain.results import StageResult
from aerotri.chain.runner import Stage, run_stages


@dataclasses.dataclass(frozen=True, kw_only=True)
class Points(StageResult):
    points: int

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def scale():
    spec = importlib.util.spec_from_file_location("bench_scale", ROOT / "bench" / "scale.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_smaller_blocks_keep_the_scene_density(scale):
    from aerotri.sim import lidar_plan, load_preset

    full = load_preset("scale")
    full_km2 = lidar_plan(full).scene_km2
    for size, frames in (("quarter", 75), ("eighth", 30)):
        preset, overrides = scale.size_overrides(size)
        cfg = load_preset(preset, overrides)
        assert cfg.flight.strips * cfg.flight.frames_per_strip == frames
        km2 = lidar_plan(cfg).scene_km2
        assert km2 < full_km2 / 3
        # buildings and trees per km2 as on the full block (to rounding)
        for key in ("buildings", "single_trees", "bushes"):
            assert getattr(cfg.scene, key) / km2 == pytest.approx(getattr(full.scene, key) / full_km2, rel=0.01)
    assert scale.size_overrides("full") == ("scale", [])
    assert scale.size_overrides("tiny") == ("tiny", [])


BLOCK = dict(frames=30, image_width_px=1000, image_height_px=500, lidar_points=6_000_000, lidar_strips=4,
             scene_width_m=2000.0, scene_height_m=1000.0)


def _fake_run(scale, run_dir: Path, records: list[dict]) -> None:
    (run_dir / "work").mkdir(parents=True)
    (run_dir / "work" / "run_summary.json").write_text(json.dumps(dict(stages=records, load_avg_start=[1.0, 1.0, 1.0],
                                                                       load_avg_end=[2.0, 1.5, 1.0])))


def test_table_throughput_and_limits_from_stage_records(scale):
    records = [
        dict(stage="classify", status="done", seconds=60.0, cpu_s=90.0, peak_rss_mb=900.0, workers_peak_rss_mb=300.0,
             points=6_000_000),
        dict(stage="tile_dem", status="done", seconds=30.0, cpu_s=30.0, peak_rss_mb=800.0, points=6_000_000),
        dict(stage="match", status="done", seconds=120.0, cpu_s=200.0, peak_rss_mb=2000.0),
        dict(stage="control", status="skipped", seconds=0.0, why="no usable roof corner"),
        dict(stage="rectify", status="done", seconds=50.0, cpu_s=60.0, peak_rss_mb=1500.0, frames=30),
        dict(stage="mosaic", status="done", seconds=10.0, cpu_s=9.0, peak_rss_mb=7000.0, width_px=4000, height_px=3000),
        dict(stage="height_check", status="done", seconds=2.0, cpu_s=2.0, peak_rss_mb=2500.0),
    ]
    rows = {r["stage"]: r for r in scale.stage_rows(records, dict(BLOCK, scene_km2=2.0))}
    assert rows["classify"]["peak_rss_mb"] == 1200.0  # the process and its workers
    assert rows["classify"]["points/s"] == 100_000.0
    assert rows["tile_dem"]["points/s"] == 200_000.0  # a stage the table does not know, counting points
    assert rows["match"]["frames/min"] == 15.0 and rows["match"]["points/s"] is None
    assert rows["control"]["frames/min"] is None and rows["control"]["cpu_s"] is None
    assert rows["rectify"]["frames/min"] == 36.0 and rows["rectify"]["MP/s"] == 0.3  # 15 MP of frames in 50 s
    assert rows["mosaic"]["MP/s"] == 1.2
    v = scale.verdict(list(rows.values()), dict(returncode=0, wall_s=300.0))
    assert v["wall_min"] == 5.0 and v["under_60_min"]
    assert v["peak_stage"] == "mosaic" and not v["under_6_gb"]  # 7000 MB
    # the LiDAR peak is of the LiDAR stages, not of the final checks run after the frame stages
    assert v["lidar_peak_stage"] == "classify" and v["lidar_peak_rss_mb"] == 1200.0
    line = scale.verdict_line("eighth", v)
    assert "NOT within the limits" in line and "limit 6 GB: NOT within" in line and "limit 60 min: within" in line
    assert "did NOT complete" in scale.verdict_line("eighth", scale.verdict(list(rows.values()),
                                                                             dict(returncode=1, wall_s=10.0)))
    table = scale.format_table(list(rows.values())).splitlines()
    assert table[0].split()[:5] == ["stage", "status", "wall", "s", "CPU"]
    assert "frames/min" in table[0] and "points/s" in table[0] and "MP/s" in table[0]
    classify = table[2].split()
    assert classify[:6] == ["classify", "done", "60.0", "90.0", "1200", "-"] and classify[6] == "100,000"


def test_table_only_reads_the_last_run_and_keeps_other_sizes(scale, tmp_path, capsys):
    block = tmp_path / "scale_eighth"
    (block / "truth").mkdir(parents=True)
    (block / "truth" / "truth.json").write_text(json.dumps(BLOCK))
    run_dir = tmp_path / "scale_eighth_run"
    run_dir.mkdir()
    # the records of a real (if tiny) run of the runner: two stages, one holding 100 MB
    import numpy as np

    def lidar(r):
        a = np.ones(100 * 1024 * 1024 // 8)
        (r / "l.txt").write_text(str(a.sum()))
        return Points(points=6_000_000)

    stages = [Stage("classify", lambda r: [], lambda r: [r / "l.txt"], lidar),
              Stage("match", lambda r: [], lambda r: [r / "m.txt"], lambda r: (r / "m.txt").write_text("m") and StageResult())]
    run_stages(run_dir, stages, log=lambda m: None)
    out = tmp_path / "scale.json"
    out.write_text(json.dumps({"quarter": {"verdict": {"lidar_peak_rss_mb": 2000.0, "lidar_peak_stage": "classify"},
                                           "block_numbers": {"lidar_points": 33_000_000}}}))
    assert scale.main(["--size", "eighth", "--block", str(block), "--table-only", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "eighth block: 30 frames of 1000 x 500 px, 6.00 M LiDAR points in 4 strips, 2.0 km2" in printed
    assert "LiDAR stages' peak RSS by block size: quarter 2000 MB" in printed
    results = json.loads(out.read_text())
    assert set(results) == {"quarter", "eighth"}
    e = results["eighth"]
    assert [r["stage"] for r in e["stages"]] == ["classify", "match"]
    assert e["stages"][0]["peak_rss_mb"] >= 100 and e["verdict"]["lidar_peak_stage"] == "classify"
    assert e["chain_load_avg"]["load_avg_start"] and "run" not in e
    # a block not run yet: said so, nothing written
    other = tmp_path / "scale_quarter"
    (other / "truth").mkdir(parents=True)
    (other / "truth" / "truth.json").write_text(json.dumps(BLOCK))
    with pytest.raises(SystemExit, match="no run of the quarter block"):
        scale.main(["--size", "quarter", "--block", str(other), "--table-only", "--out", str(out)])
    assert json.loads(out.read_text()) == results


def test_dmc_unit_costs_projection_and_constancy(scale):
    """Full-size DMC blocks: per-unit costs per stage, their projection to 3,000 frames / 2 G points, the ratio of
    two block sizes' costs."""
    blk = dict(frames=24, image_width_px=13824, image_height_px=7680, lidar_points=69_000_000)
    records = [
        dict(stage="classify", status="done", seconds=690.0, cpu_s=1380.0, peak_rss_mb=4000.0, points=69_000_000),
        dict(stage="match", status="done", seconds=240.0, cpu_s=60.0, peak_rss_mb=1300.0),
        dict(stage="rectify", status="done", seconds=254.8, cpu_s=127.4, peak_rss_mb=1500.0, frames=24),
        dict(stage="mosaic", status="done", seconds=100.0, cpu_s=50.0, peak_rss_mb=2000.0, width_px=40000,
             height_px=25000),
        dict(stage="report", status="done", seconds=5.0, cpu_s=5.0, peak_rss_mb=900.0),
    ]
    rows = scale.stage_rows(records, dict(blk, scene_km2=10.0))
    costs = scale.unit_costs(rows, blk, dom_gp=1.0)
    assert costs["classify"]["unit"] == "M points" and costs["classify"]["cpu_s"] == 20.0
    assert costs["match"]["unit"] == "frame" and costs["match"]["cpu_s"] == 2.5
    assert costs["rectify"]["unit"] == "GP of frames" and costs["rectify"]["cpu_s"] == pytest.approx(50.0, rel=1e-3)
    assert costs["mosaic"]["unit"] == "GP of DOM" and costs["mosaic"]["wall_s"] == 100.0
    assert "report" not in costs
    p = scale.projection(costs, blk, dom_gp=1.0)
    assert p["dom_gp"] == 125.0  # 1 GP for 24 frames, 3,000 frames
    assert p["stages"]["classify"]["cpu_h"] == pytest.approx(20.0 * 2000 / 3600, abs=0.01)
    assert p["stages"]["match"]["cpu_h"] == pytest.approx(2.5 * 3000 / 3600, abs=0.01)
    assert p["cpu_h"] == pytest.approx(sum(s["cpu_h"] for s in p["stages"].values()), abs=0.1)
    # two sizes: the larger block's CPU per unit over the smaller's, within 25 % or not
    big = {k: dict(v, cpu_s=v["cpu_s"] * (1.1 if k != "mosaic" else 1.5)) for k, v in costs.items()}
    c = scale.constancy({"dmc": {"unit_costs": big}, "dmc_3x8": {"unit_costs": costs}})
    assert c["cpu_ratio_full_over_3x8"]["match"] == 1.1 and c["within_25_pct"]["match"]
    assert not c["within_25_pct"]["mosaic"]
    assert scale.constancy({"dmc_3x8": {"unit_costs": costs}}) is None
    # the DMC limits: 3 hours, 12 GB
    v = scale.verdict(rows, dict(returncode=0, wall_s=3600.0), scale.DMC_LIMIT_WALL_MIN, scale.DMC_LIMIT_PEAK_GB)
    assert v["under_180_min"] and v["under_12_gb"]
    assert "limit 180 min: within" in scale.verdict_line("dmc_3x8", v)


def test_two_sizes_fixed_and_per_unit_parts(scale, tmp_path, capsys):
    """--compare: two runs whose stage CPU is fixed + per unit x units give back both parts, the ratio of their
    per-unit costs and the projection with the fixed part counted once."""
    def entry(frames, points_m, dom_gp):
        blk = dict(frames=frames, image_width_px=13824, image_height_px=7680, lidar_points=points_m * 1e6)
        cpu = {"classify": 300.0 + 12.0 * points_m, "match": 40.0 + 2.0 * frames, "mosaic": 30.0 + 200.0 * dom_gp}
        records = [dict(stage=st, status="done", seconds=c, cpu_s=c, peak_rss_mb=1000.0) for st, c in cpu.items()]
        rows = scale.stage_rows(records, dict(blk, scene_km2=1.0))
        return dict(block_numbers=blk, dom_gp=dom_gp, unit_costs=scale.unit_costs(rows, blk, dom_gp))

    small, large = entry(8, 25, 0.4), entry(24, 69, 1.2)
    c = scale.compare_sizes(small, large)["stages"]
    assert c["classify"]["fixed_cpu_s"] == pytest.approx(300.0, abs=1.0)
    assert c["classify"]["marginal_cpu_s_per_unit"] == pytest.approx(12.0, abs=0.01)
    assert c["match"]["fixed_cpu_s"] == pytest.approx(40.0, abs=0.1) and c["match"]["units"] == [8, 24]
    # per frame 7 s against 3.67 s: the fixed part makes the small block's unit cost 1.9 x the large one's
    assert c["match"]["ratio"] == pytest.approx((40 / 24 + 2) / (40 / 8 + 2), abs=0.01) and not c["match"]["within_25_pct"]
    assert c["match"]["projected_cpu_h"] == pytest.approx((40 + 2 * 3000) / 3600, abs=0.01)
    # the DOM of 3,000 frames at the larger block's DOM per frame: 150 GP
    assert c["mosaic"]["projected_cpu_h"] == pytest.approx((30 + 200 * 150) / 3600, abs=0.01)
    # inside a large block a DMC frame adds its base (40 % of 7680 px) times the strip spacing (70 % of 13824 px)
    assert scale.interior_dom_gp_per_frame() == pytest.approx(0.4 * 7680 * 0.7 * 13824 / 1e9)
    c = scale.compare_sizes(small, large, dom_gp_per_frame=0.03)["stages"]
    assert c["mosaic"]["projected_cpu_h"] == pytest.approx((30 + 200 * 90) / 3600, abs=0.01)
    out = tmp_path / "scale_dmc.json"
    out.write_text(json.dumps({"a": small, "b": large, "constancy": {"kept": 1}}))
    assert scale.main(["--compare", "a", "b", "--out", str(out)]) == 0
    results = json.loads(out.read_text())
    assert results["constancy"] == {"kept": 1} and results["constancy_b_over_a"]["stages"]["match"]["ratio"] < 0.75
    assert "match" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="no DMC entry 'c'"):
        scale.main(["--compare", "a", "c", "--out", str(out)])


def test_one_block_run_by_two_codes(scale, tmp_path, capsys):
    """``--compare`` of two runs of one block (a recheck of newer code): the per-unit CPU ratio per stage, no line
    through the runs (it divided by zero), the projection the plain one."""
    blk = dict(frames=8, image_width_px=13824, image_height_px=7680, lidar_points=30_000_000)

    def entry(classify_cpu):
        cpu = dict(classify=classify_cpu, match=12.0, mosaic=30.0)
        records = [dict(stage=st, status="done", seconds=c, cpu_s=c, peak_rss_mb=1000.0) for st, c in cpu.items()]
        rows = scale.stage_rows(records, dict(blk, scene_km2=1.0))
        return dict(block_numbers=blk, dom_gp=0.4, frames_gp=0.849, unit_costs=scale.unit_costs(rows, blk, 0.4))

    before, now = entry(200.0), entry(260.0)
    c = scale.compare_sizes(before, now)
    assert c["stages"]["classify"]["ratio"] == pytest.approx(1.3) and not c["stages"]["classify"]["within_25_pct"]
    assert c["stages"]["match"]["ratio"] == pytest.approx(1.0) and c["stages"]["match"]["within_25_pct"]
    assert c["stages"]["classify"]["fixed_cpu_s"] is None and c["stages"]["classify"]["marginal_cpu_s_per_unit"] is None
    # 260 CPU-s for 30 M points: 2 G points take 260 / 30 x 2,000 CPU-s
    assert c["stages"]["classify"]["projected_cpu_h"] == pytest.approx(260 / 30 * 2000 / 3600, abs=0.01)
    assert c["alternatives"] == {}
    out = tmp_path / "scale_dmc.json"
    out.write_text(json.dumps({"old": before, "new": now}))
    assert scale.main(["--compare", "old", "new", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["constancy_new_over_old"]["stages"]["classify"]["ratio"] == pytest.approx(1.3)
    assert "1.30*" in capsys.readouterr().out


def test_stage_load_from_the_samples_over_its_interval(scale, tmp_path):
    import os

    stages = tmp_path / "work" / "stages"
    stages.mkdir(parents=True)
    for name, end in (("strips", 1000.0), ("classify", 1100.0), ("report", 1103.0)):
        (stages / f"{name}.json").write_text("{}")
        os.utime(stages / f"{name}.json", (end, end))
    rows = [dict(stage="strips", status="done", wall_s=95.0), dict(stage="classify", status="done", wall_s=95.0),
            dict(stage="report", status="done", wall_s=1.0), dict(stage="control", status="skipped", wall_s=0.0)]
    samples = [[t, 1.0 if t <= 1000 else 3.0, 0.0, 0.0] for t in range(900, 1101, 10)]
    scale.stage_load(rows, tmp_path, samples)
    assert rows[0]["load_1min"] == 1.0 and rows[1]["load_1min"] == 3.0
    assert rows[2]["load_1min"] == 3.0  # shorter than the sampling step: the sample nearest its end
    assert "load_1min" not in rows[3]


def test_a_resumed_run_marks_the_stages_an_earlier_run_made(scale, tmp_path):
    """``--resume``: the stages the chain skipped keep their earlier run's figures, marked as such in the rows, the
    table and the unit costs, and get no load from this run's samples."""
    import os

    stages = tmp_path / "work" / "stages"
    stages.mkdir(parents=True)
    usage = dict(cpu_s=50.0, peak_rss_mb=900.0)
    (stages / "classify.json").write_text(json.dumps(dict(seconds=120.0, usage=usage, result=dict(points=6_000_000))))
    (stages / "match.json").write_text(json.dumps(dict(seconds=10.0, usage=dict(cpu_s=8.0, peak_rss_mb=500.0))))
    for name, end in (("classify", 500.0), ("match", 1100.0)):
        os.utime(stages / f"{name}.json", (end, end))
    (tmp_path / "work" / "run_summary.json").write_text(json.dumps({"stages": [
        dict(stage="classify", status="skipped (up to date)", seconds=0.0),
        dict(stage="match", status="done", seconds=10.0, cpu_s=8.0, peak_rss_mb=500.0)]}))
    records = scale.stage_records(tmp_path)
    rows = scale.stage_rows(records, BLOCK)
    assert rows[0]["earlier_run"] and rows[0]["cpu_s"] == 50.0 and rows[0]["wall_s"] == 120.0
    assert "earlier_run" not in rows[1]
    scale.stage_load(rows, tmp_path, [[t, 2.0, 0.0, 0.0] for t in range(1000, 1101, 10)])
    assert "load_1min" not in rows[0] and rows[1]["load_1min"] == 2.0
    assert "done (earlier run)" in scale.format_table(rows)
    costs = scale.unit_costs(rows, BLOCK, None)
    assert costs["classify"]["earlier_run"] and "earlier_run" not in costs["match"]
    with pytest.raises(SystemExit, match="no project to resume"):
        scale.run_chain(tmp_path, tmp_path / "nothing", None, None, resume=True)


def test_the_chains_qa_verdict_and_its_failed_items(scale, tmp_path):
    """A DMC entry's accuracy carries the chain's QA verdict (reports/summary.json) with the items that failed it."""
    (tmp_path / "block" / "truth").mkdir(parents=True)
    (tmp_path / "block" / "truth" / "truth.json").write_text(json.dumps(dict(BLOCK, gsd_m=0.1)))
    (tmp_path / "run" / "reports").mkdir(parents=True)
    checks = [dict(id="seam_misalignment_rms_px", value=0.33, limit=1.0, unit="px", verdict="pass", note="1151"),
              dict(id="flight_forward_overlap_min_pct", value=53.1, limit=56.0, unit="%", verdict="fail",
                   note="worst at s02_003")]
    (tmp_path / "run" / "reports" / "summary.json").write_text(json.dumps(dict(overall="fail", passed=1, checks=checks)))
    a = scale.accuracy(tmp_path / "block", tmp_path / "run", [])
    assert a["gsd_m"] == 0.1 and a["qa_verdict"] == dict(overall="fail", passed=1, failed=[dict(
        id="flight_forward_overlap_min_pct", value=53.1, limit=56.0, unit="%", note="worst at s02_003")])
    lines = scale.dmc_lines(dict(frames_gp=1.0, dom_gp=None, unit_costs={}, accuracy=a, projection=dict(
        frames=3000, lidar_points=2e9, dom_gp=0, wall_h=0, cpu_h=0, stages={}, assumes="")))
    assert "QA verdict fail: flight_forward_overlap_min_pct 53.1 (limit 56.0)" in lines
