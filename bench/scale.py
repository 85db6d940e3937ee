"""Benchmark: the whole chain on a production-size block, per stage: wall and CPU time, peak RSS, throughput.

The block is the simulator preset ``scale`` (300 frames of 1728 x 960 px, 13 LiDAR strips, about 120 million
points over 21 km2), generated once outside the repository (``--generate``; the quarter block took 6.6 min
and 1.5 GB at load 1-2, so the full one should take about half an hour) and reused: every run links the block's inputs (project.toml, camera.toml, gnss.txt, images/, lidar/; hard links,
the chain never modifies its inputs) into a fresh run folder next to it and runs ``aerotri run`` there with
the true orthophoto and the surveyed targets for the final checks. Smaller blocks of the same preset, so the
LiDAR stages' peak RSS can be compared at two or three block sizes (tiled stages: nearly equal):
``--size quarter`` (5 strips x 15 frames = 75 frames, 6.2 km2, 45 M pulses, about 35 M points) and
``--size eighth`` (3 strips x 10 frames = 30 frames, 2.9 km2, 20 M pulses, about 16 M points); their
buildings, trees, bushes and ponds scaled with the scene area, so the scene looks alike. ``--size tiny``
(the simulator's ``tiny`` preset, seconds) checks the benchmark itself.

The numbers come from the chain's own stage records (``work/run_summary.json``: wall and CPU seconds of the
process and its Dask workers, peak RSS reset before every stage: the most the process held during the
stage, including what it still holds of earlier stages); stage names are read from the record, so
the table follows whatever stages the chain has. Throughput: frames/min for the frame stages, LiDAR points/s
for the LiDAR stages (the block's points, whatever the stage read), MP/s of input frames for rectify and of
mosaic pixels for mosaic. Load averages are recorded before and after: other work on the machine slows the
wall times; CPU seconds are steadier.

Full-size Z/I DMC frames (issue 41): ``--size dmc`` (the ``dmc_block`` preset: 120 frames of 13824 x 7680 px,
12-bit in ZSTD tiles, about 250 M points; made by bench/sim_dmc.py into $AEROTRI_BENCH_BLOCKS/dmc_block) and
``--size dmc_3x8`` (its 3 strips x 8 frames subset, dmc_block_subset_3x8) write bench/results/scale_dmc.json with, beside
the table, each stage's per-unit costs (s per frame, per GP of frames, per GP of DOM, per M points), their
projection to 3,000 frames and 2 billion points, the AT and DOM accuracy against the simulator's truth in GSD,
and, once both sizes ran, the ratio of their per-unit CPU costs (limits: 3 h, 12 GB). ``--size dmc_2x6``,
``dmc_2x4`` and ``dmc_2x2`` (2 strips of 6, 4, 2 frames; dmc_block_subset_2x6 ...) are smaller sizes of the same
preset; ``--key`` stores a run under its own entry (a run of other code kept beside it) and ``--compare SMALL
LARGE`` sets any two entries side by side: per stage the per-unit CPU ratio, the CPU split into a fixed and a
per-unit part by the line through both runs, and the 3,000-frame projection from the larger with the fixed part
counted once (the DOM at a frame's base x strip spacing). The run's load average is sampled every 10 s and each
stage gets the mean over its interval (column "load").

Writes bench/results/scale.json (one entry per block size, kept across runs of the other size).

Usage:
  python bench/scale.py --generate-only                # once: simulate the block into /work/bench_blocks/scale
  python bench/scale.py                                # run the chain on it, print the table
  python bench/scale.py --size quarter --generate      # a smaller block (generated unless it exists), run
  python bench/scale.py --size eighth --table-only     # the table of the last run of that size, run nothing
  python bench/scale.py --size full --print-command    # the generation command, to run it elsewhere
  python bench/scale.py --size dmc_3x8                 # the chain on the DMC subset -> bench/results/scale_dmc.json
  python bench/scale.py --size dmc_3x8 --table-only --run-dir DIR  # tabulate a run made by hand (aerotri run DIR)
  python bench/scale.py --size dmc_2x4 --key dmc_2x4_f0d557a   # a run kept under its own entry
  python bench/scale.py --size dmc_2x4 --run-dir DIR --resume --key K  # resume a run folder (stamps removed: re-run)
  python bench/scale.py --compare dmc_2x4_f0d557a dmc_3x8_f0d557a  # per-unit costs of two entries
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
sys.path.insert(0, str(ROOT))

from aerotri.core.resources import measure  # noqa: E402
import numpy as np  # noqa: E402

BLOCKS = Path(os.environ.get("AEROTRI_BENCH_BLOCKS", "/work/bench_blocks"))
# --size: the simulator preset and the flight of each block (the scene's object counts follow its area)
SIZES = {"full": ("scale", []), "quarter": ("scale", ["flight.strips=5", "flight.frames_per_strip=15"]),
         "eighth": ("scale", ["flight.strips=3", "flight.frames_per_strip=10"]), "tiny": ("tiny", []),
         # full-size Z/I DMC frames (13824 x 7680 px, 12-bit, ZSTD tiles; issue 41): the whole block and the 3 x 8
         # subset bench/sim_dmc.py makes (the dmc_block preset shrinks its scene, objects and LiDAR with the flight)
         "dmc": ("dmc_block", []), "dmc_3x8": ("dmc_block", ["flight.strips=3", "flight.frames_per_strip=8"]),
         "dmc_2x4": ("dmc_block", ["flight.strips=2", "flight.frames_per_strip=4"]),
         "dmc_2x2": ("dmc_block", ["flight.strips=2", "flight.frames_per_strip=2"]),
         "dmc_2x6": ("dmc_block", ["flight.strips=2", "flight.frames_per_strip=6"])}
DMC_SIZES = ("dmc", "dmc_3x8", "dmc_2x6", "dmc_2x4", "dmc_2x2")
# folder names of bench/sim_dmc.py
DMC_BLOCKS = {"dmc": "dmc_block", "dmc_3x8": "dmc_block_subset_3x8", "dmc_2x4": "dmc_block_subset_2x4",
              "dmc_2x2": "dmc_block_subset_2x2", "dmc_2x6": "dmc_block_subset_2x6"}
DMC_LIMIT_WALL_MIN, DMC_LIMIT_PEAK_GB = 180.0, 12.0  # issue 41: the whole chain under 3 hours and 12 GB
PROJECT_FRAMES, PROJECT_POINTS = 3000, 2e9  # the production block the per-unit costs are projected to
SCENE_COUNTS = ("buildings", "single_trees", "tree_clusters", "slope_trees", "bushes", "ponds")
LIMIT_WALL_MIN = 60.0
LIMIT_PEAK_GB = 6.0

# Throughput columns and what each stage is counted in. Stages not named here (a stage added to the chain):
# LiDAR points/s when the stage's record counts points, else none. MP/s: of the input frames for rectify, of
# the mosaic for mosaic.
FRAMES, POINTS, MP = "frames/min", "points/s", "MP/s"
UNITS = {
    "strips": [POINTS], "classify": [POINTS], "rasters": [POINTS], "corners": [POINTS], "height_check": [POINTS],
    "lidar_eval": [POINTS],
    "match": [FRAMES], "adjust_first": [FRAMES], "control": [FRAMES], "adjust_final": [FRAMES],
    "rectify": [FRAMES, MP], "mosaic": [MP],
}
COLUMNS = (FRAMES, POINTS, MP)
# Final checks: they read the LiDAR too, but run after the frame stages, whose heap the process still holds
# (their peak is the chain's, not the LiDAR's); left out of the LiDAR peak compared between block sizes.
CHECKS = ("dom_check", "height_check", "lidar_eval", "report")
INPUTS = ("project.toml", "camera.toml", "gnss.txt", "images", "lidar")
LOAD_SAMPLE_S = 10.0  # how often the run's load average is sampled


def _load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _link_tree(src: Path, dst: Path) -> None:
    """Hard links of the block's inputs (a copy across file systems)."""
    for name in INPUTS:
        s = src / name
        if s.is_dir():
            shutil.copytree(s, dst / name, copy_function=_link_or_copy)
        else:
            _link_or_copy(s, dst / name)


def _link_or_copy(s, d) -> None:
    try:
        os.link(s, d)
    except OSError:
        shutil.copy2(s, d)


def size_overrides(size: str) -> tuple[str, list[str]]:
    """The preset and ``--set`` overrides of a block size: its flight, and the preset's counts of buildings,
    trees, bushes and ponds times its scene area over the full block's (at least one of each)."""
    from aerotri.sim import lidar_plan, load_preset

    preset, flight = SIZES[size]
    if not flight or size in DMC_SIZES:  # dmc_block shrinks its scene, objects and LiDAR with the flight itself
        return preset, flight
    full = load_preset(preset)
    ratio = lidar_plan(load_preset(preset, flight)).scene_km2 / lidar_plan(full).scene_km2
    return preset, flight + [f"scene.{k}={max(1, round(getattr(full.scene, k) * ratio))}" for k in SCENE_COUNTS]


def generate_command(block: Path, size: str) -> list[str]:
    preset, overrides = size_overrides(size)
    return [str(BIN / "aerotri"), "sim", "--preset", preset, *[a for o in overrides for a in ("--set", o)], str(block)]


def generate(block: Path, size: str) -> dict:
    """Simulate the block (``aerotri sim``) in a child process; its time and peak RSS."""
    from aerotri.sim import lidar_plan, load_preset

    preset, overrides = size_overrides(size)
    plan = lidar_plan(load_preset(preset, overrides))
    print(f"generating {block}: LiDAR {plan.strips} strips, {plan.pulses / 1e6:.1f} M pulses over "
          f"{plan.scene_km2} km2 (about 0.8 points a pulse)", flush=True)
    cmd = generate_command(block, size)
    load0 = _load()
    with measure() as u:
        subprocess.run(cmd, check=True)
    truth = json.loads((block / "truth" / "truth.json").read_text())
    # the simulator's peak: the largest child reaped (RUSAGE_CHILDREN), not this process's
    return dict(wall_s=round(u.wall_s, 1), cpu_s=round(u.cpu_s, 1), peak_rss_mb=round(u.workers_peak_rss_mb, 1),
                lidar_plan=dataclasses.asdict(plan), frames=truth["frames"], lidar_points=truth["lidar_points"], load_avg_before=load0,
                load_avg_after=_load(), command=" ".join(Path(cmd[0]).name if i == 0 else c for i, c in enumerate(cmd)))


def block_numbers(block: Path) -> dict:
    """Frames, frame size and LiDAR points of the block (from the simulator's truth summary)."""
    truth = json.loads((block / "truth" / "truth.json").read_text())
    return dict(frames=truth["frames"], image_width_px=truth["image_width_px"],
                image_height_px=truth["image_height_px"], lidar_points=truth["lidar_points"],
                lidar_strips=truth["lidar_strips"], scene_km2=round(truth["scene_width_m"] * truth["scene_height_m"] / 1e6, 2))


def run_chain(block: Path, run_dir: Path, scheduler: str | None, workers: int | None, resume: bool = False) -> dict:
    """A fresh run folder with the block's inputs, ``aerotri run`` over it; the run's record. ``resume``: the run
    folder as it is (``aerotri run`` skips the stages whose stamps are current, e.g. a copy of an earlier run with
    the stamps of the stages to re-run removed)."""
    if resume:
        if not (run_dir / "project.toml").exists():
            sys.exit(f"{run_dir}: no project to resume (--resume runs the chain in an existing run folder)")
    else:
        if run_dir.exists():
            shutil.rmtree(run_dir)
        run_dir.mkdir(parents=True)
        _link_tree(block, run_dir)
    cmd = [str(BIN / "aerotri"), "run", str(run_dir), "--reference", str(block / "truth" / "ortho.tif"),
           "--points", str(block / "truth" / "checkpoints.csv")]
    if scheduler:
        cmd += ["--scheduler", scheduler]
    if workers:
        cmd += ["--workers", str(workers)]
    load0 = _load()
    samples = []  # [epoch s, 1, 5, 15 min load] every LOAD_SAMPLE_S: each stage's load from its interval
    with measure() as u:
        proc = subprocess.Popen(cmd)
        while True:
            samples.append([round(time.time(), 1), *_load()])
            try:
                proc.wait(timeout=LOAD_SAMPLE_S)
                break
            except subprocess.TimeoutExpired:
                continue
    samples.append([round(time.time(), 1), *_load()])
    # the largest process of the run (RUSAGE_CHILDREN; None when an earlier child of this script was larger)
    largest = round(u.workers_peak_rss_mb, 1) if u.workers_peak_rss_mb else None
    return dict(returncode=proc.returncode, wall_s=round(u.wall_s, 1), cpu_s=round(u.cpu_s, 1),
                largest_process_peak_rss_mb=largest, load_avg_before=load0, load_avg_after=_load(),
                command=" ".join(["aerotri"] + cmd[1:]), load_samples=samples)


def stage_load(rows: list[dict], run_dir: Path, samples: list | None) -> None:
    """Each done stage's mean 1-min load average over its interval (its stamp's time minus its wall time) from
    the run's load samples, into the row as ``load_1min``: the other work on the machine while it ran."""
    if not samples:
        return
    t = np.array([s[0] for s in samples])
    load1 = np.array([s[1] for s in samples])
    for r in rows:
        stamp = run_dir / "work" / "stages" / f"{r['stage']}.json"
        if r["status"] != "done" or not stamp.exists() or r.get("earlier_run"):  # not in this run's samples
            continue
        end = stamp.stat().st_mtime
        inside = (t >= end - r["wall_s"]) & (t <= end)
        if not inside.any():  # a stage shorter than the sampling step: the sample nearest its end
            inside = np.abs(t - end) == np.abs(t - end).min()
        r["load_1min"] = round(float(load1[inside].mean()), 2)


def stage_records(run_dir: Path) -> list[dict]:
    """The run's stage rows (``work/run_summary.json``); of an interrupted run, the stamps of the stages that
    finished, in the order they finished."""
    summary_path = run_dir / "work" / "run_summary.json"
    if summary_path.exists():
        # a resumed run skips the stages an earlier run made: their rows come from those stages' stamps
        return [dict(_stamp_record(run_dir, r["stage"]), earlier_run=True)
                if str(r.get("status", "")).startswith("skipped (up to date)") and _stamp_record(run_dir, r["stage"])
                else r for r in json.loads(summary_path.read_text())["stages"]]
    records = []
    for p in sorted((run_dir / "work" / "stages").glob("*.json"), key=lambda p: p.stat().st_mtime):
        records.append(_stamp_record(run_dir, p.stem))
    return records


def _stamp_record(run_dir: Path, stage: str) -> dict | None:
    """A stage's row from its stamp (``work/stages/<stage>.json``: time, CPU, peak RSS, key numbers of the run
    that made it); None without a stamp or without its usage."""
    p = run_dir / "work" / "stages" / f"{stage}.json"
    if not p.exists():
        return None
    s = json.loads(p.read_text())
    if not s.get("usage"):
        return None
    usage = {k: v for k, v in s["usage"].items() if k not in ("wall_s", "rss_reset")}
    return dict(stage=stage, status="done", seconds=s.get("seconds", 0.0), **usage, **s.get("result", {}))


def stage_rows(records: list[dict], blk: dict) -> list[dict]:
    """Per stage: wall, CPU, peak RSS (the process + its workers) and throughput."""
    frame_mp = blk["frames"] * blk["image_width_px"] * blk["image_height_px"] / 1e6
    rows = []
    for r in records:
        units = UNITS.get(r["stage"], [POINTS] if "points" in r else [])
        row = dict(stage=r["stage"], status=r["status"], wall_s=r.get("seconds", 0.0), cpu_s=r.get("cpu_s"),
                   peak_rss_mb=None, lidar=POINTS in units and r["stage"] not in CHECKS,
                   **{c: None for c in COLUMNS})
        if r.get("earlier_run"):  # a resumed run skipped it: the figures are of the run that made it
            row["earlier_run"] = True
        if "peak_rss_mb" in r:
            row["peak_rss_mb"] = round(r["peak_rss_mb"] + r.get("workers_peak_rss_mb", 0.0), 1)
        dt = row["wall_s"]
        if r["status"] != "done" or dt <= 0:
            rows.append(row)
            continue
        for unit in units:
            if unit == FRAMES:
                v = blk["frames"] / (dt / 60.0)
            elif unit == POINTS:
                v = blk["lidar_points"] / dt
            elif r["stage"] == "mosaic" and "width_px" in r and "height_px" in r:
                v = r["width_px"] * r["height_px"] / 1e6 / dt
            elif r["stage"] != "mosaic":
                v = frame_mp / dt
            else:
                continue
            row[unit] = round(v, 3 if v < 10 else 1)
        rows.append(row)
    return rows


def format_table(rows: list[dict]) -> str:
    head = (f"{'stage':<14} {'status':<22} {'wall s':>8} {'CPU s':>8} {'peak RSS MB':>11} "
            f"{FRAMES:>10} {POINTS:>12} {MP:>8} {'load':>5}")
    lines = [head, "-" * len(head)]

    def num(v, width, fmt):
        return f"{'-':>{width}}" if v is None else f"{v:>{width}{fmt}}"

    for r in rows:
        status = r["status"] + (" (earlier run)" if r.get("earlier_run") else "")
        lines.append(f"{r['stage']:<14} {status[:22]:<22} {r['wall_s']:>8.1f} {num(r['cpu_s'], 8, '.1f')} "
                     f"{num(r['peak_rss_mb'], 11, '.0f')} {num(r[FRAMES], 10, ',.1f')} {num(r[POINTS], 12, ',.0f')} "
                     f"{num(r[MP], 8, '.2f')} {num(r.get('load_1min'), 5, '.1f')}")
    return "\n".join(lines)


def verdict(rows: list[dict], run: dict | None, limit_wall_min: float = LIMIT_WALL_MIN,
            limit_peak_gb: float = LIMIT_PEAK_GB, finished: bool = True) -> dict:
    """The whole chain against the issue's limits (60 min, 6 GB peak; DMC blocks 3 h, 12 GB) and what bounds it."""
    done = [r for r in rows if r["status"] == "done"]
    stages_s = sum(r["wall_s"] for r in done)
    wall_min = (run["wall_s"] if run else stages_s) / 60.0  # the run's own wall time includes start-up
    peaks = [r for r in done if r["peak_rss_mb"] is not None]
    top = max(peaks, key=lambda r: r["peak_rss_mb"]) if peaks else None
    slow = max(done, key=lambda r: r["wall_s"]) if done else None
    lidar = [r for r in peaks if r["lidar"]]
    lidar_top = max(lidar, key=lambda r: r["peak_rss_mb"]) if lidar else None
    complete = run["returncode"] == 0 if run else finished  # a table of a run still going: not complete
    return dict(
        wall_min=round(wall_min, 1), stages_wall_min=round(stages_s / 60.0, 1),
        cpu_min=round(sum(r["cpu_s"] or 0.0 for r in done) / 60.0, 1),
        peak_rss_gb=round(top["peak_rss_mb"] / 1024.0, 2) if top else None, peak_stage=top["stage"] if top else None,
        slowest_stage=slow["stage"] if slow else None,
        slowest_stage_share=round(slow["wall_s"] / stages_s, 2) if slow and stages_s > 0 else None,
        lidar_peak_rss_mb=lidar_top["peak_rss_mb"] if lidar_top else None,
        lidar_peak_stage=lidar_top["stage"] if lidar_top else None,
        complete=complete, limit_wall_min=limit_wall_min, limit_peak_gb=limit_peak_gb,
        **{f"under_{limit_wall_min:.0f}_min": complete and wall_min < limit_wall_min,
           f"under_{limit_peak_gb:.0f}_gb": complete and top is not None and top["peak_rss_mb"] / 1024.0 < limit_peak_gb})


def verdict_line(size: str, v: dict) -> str:
    """The limits, stated plainly: within or not, and what bounds the run."""
    if not v["complete"]:
        return f"{size} block: the chain did NOT complete: no verdict on the limits"
    lw, lg = v["limit_wall_min"], v["limit_peak_gb"]
    in_wall, in_peak = v[f"under_{lw:.0f}_min"], v[f"under_{lg:.0f}_gb"]
    share = "-" if v["slowest_stage_share"] is None else f"{v['slowest_stage_share']:.0%}"
    return (f"{size} block: whole chain {v['wall_min']} min (limit {lw:.0f} min: "
            f"{'within' if in_wall else 'NOT within'}; slowest stage {v['slowest_stage']}, "
            f"{share} of the stages' time), CPU {v['cpu_min']} min, peak RSS {v['peak_rss_gb']} GB "
            f"in {v['peak_stage']} (limit {lg:.0f} GB: {'within' if in_peak else 'NOT within'})"
            f" -> {'within both limits' if in_wall and in_peak else 'NOT within the limits'}")


# -- full-size DMC blocks: per-unit costs, their projection, accuracy against the simulator's truth -------------
FRAME_STAGES = ("match", "adjust_first", "control", "adjust_final")


def unit_costs(rows: list[dict], blk: dict, dom_gp: float | None) -> dict:
    """Per stage, wall and CPU seconds per unit of what it works on: per frame (tie points, adjustments,
    control), per GP of frames (rectify), per GP of DOM (mosaic, DOM check), per million LiDAR points (the
    LiDAR stages and their checks); None for stages without one (the report)."""
    frames_gp = blk["frames"] * blk["image_width_px"] * blk["image_height_px"] / 1e9
    out = {}
    for r in rows:
        if r["status"] != "done":
            continue
        st = r["stage"]
        if st in FRAME_STAGES:
            unit, n = "frame", blk["frames"]
        elif st == "rectify":
            unit, n = "GP of frames", frames_gp
        elif st in ("mosaic", "dom_check") and dom_gp:
            unit, n = "GP of DOM", dom_gp
        elif r["lidar"] or st in ("height_check", "lidar_eval"):
            unit, n = "M points", blk["lidar_points"] / 1e6
        else:
            continue
        out[st] = dict(unit=unit, units=round(n, 4), wall_s=round(r["wall_s"] / n, 3),
                       cpu_s=round((r["cpu_s"] or 0.0) / n, 3), peak_rss_mb=r["peak_rss_mb"],
                       **({"earlier_run": True} if r.get("earlier_run") else {}))
    return out


def projection(costs: dict, blk: dict, dom_gp: float | None) -> dict:
    """The chain on a 3,000-frame block with 2 billion points: every stage's units (frames, frame GP, DOM GP at
    this block's DOM per frame, points) times its per-unit cost. Linear in the units: the adjustment's solver
    grows faster than linearly with the block (measured apart: bench/adjust_scale.py, 10,000 frames)."""
    per_frame_gp = blk["image_width_px"] * blk["image_height_px"] / 1e9
    units = {"frame": PROJECT_FRAMES, "GP of frames": PROJECT_FRAMES * per_frame_gp,
             "GP of DOM": PROJECT_FRAMES * (dom_gp or 0.0) / blk["frames"], "M points": PROJECT_POINTS / 1e6}
    stages = {st: dict(units=round(units[c["unit"]], 1), wall_h=round(c["wall_s"] * units[c["unit"]] / 3600, 2),
                       cpu_h=round(c["cpu_s"] * units[c["unit"]] / 3600, 2)) for st, c in costs.items()}
    return dict(frames=PROJECT_FRAMES, lidar_points=PROJECT_POINTS, dom_gp=round(units["GP of DOM"], 1),
                stages=stages, wall_h=round(sum(v["wall_h"] for v in stages.values()), 1),
                cpu_h=round(sum(v["cpu_h"] for v in stages.values()), 1),
                assumes="each stage's per-unit cost of this run, at its load, linear in frames, frame GP, DOM GP "
                        "(this block's DOM per frame) and LiDAR points")


def _angle_diff_deg(a, b):
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def accuracy(block: Path, run_dir: Path, rows: list[dict]) -> dict:
    """AT and DOM against the simulator's truth, in metres and in GSD: projection centres and attitudes of
    at/eo.txt against truth/eo.txt (and normalised by their reported sigmas), the check points of the final
    adjustment (at/report.json), the DOM check (the dom_check stage against truth/ortho.tif)."""
    from aerotri.geom.eo import read_eo

    gsd = json.loads((block / "truth" / "truth.json").read_text())["gsd_m"]
    out: dict = {"gsd_m": gsd}
    eo_path = run_dir / "at" / "eo.txt"
    if eo_path.exists():
        eo, truth = read_eo(eo_path), read_eo(block / "truth" / "eo.txt")
        sel = truth.rows(eo.image_id)
        d = np.column_stack([eo.centre_m - truth.centre_m[sel], _angle_diff_deg(eo.opk_deg, truth.opk_deg[sel])])
        xy = float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2) / 2))
        z = float(np.sqrt(np.mean(d[:, 2] ** 2)))
        out["orientations"] = dict(
            frames=len(eo.image_id), centre_rms_xy_m=round(xy, 4), centre_rms_z_m=round(z, 4),
            centre_rms_xy_gsd=round(xy / gsd, 2), centre_rms_z_gsd=round(z / gsd, 2),
            attitude_rms_deg=round(float(np.sqrt(np.mean(d[:, 3:] ** 2))), 5),
            normalised_rms=dict(zip(("X", "Y", "Z", "omega", "phi", "kappa"),
                                    (round(float(v), 2) for v in np.sqrt(np.mean((d / eo.sigma) ** 2, axis=0))))))
    rep_path = run_dir / "at" / "report.json"
    if rep_path.exists():
        chk = json.loads(rep_path.read_text()).get("check_rms_m")
        if chk and None not in chk:
            xy = float(np.hypot(chk[0], chk[1]))
            out["check_points"] = dict(rms_xy_m=round(xy, 4), rms_z_m=chk[2], rms_xy_gsd=round(xy / gsd, 2),
                                       rms_z_gsd=round(chk[2] / gsd, 2))
    dom = next((r for r in rows if r["stage"] == "dom_check" and r["status"] == "done"), None)
    summary = run_dir / "work" / "run_summary.json"
    rec = ({r["stage"]: r for r in json.loads(summary.read_text())["stages"]} if summary.exists() else {})
    if dom and "rms_xy_m" in rec.get("dom_check", {}):
        m = rec["dom_check"]["rms_xy_m"]
        out["dom"] = dict(rms_xy_m=round(m, 4), rms_xy_gsd=round(m / gsd, 2), patches=rec["dom_check"].get("count"))
    qa = run_dir / "reports" / "summary.json"
    if qa.exists():  # the chain's QA verdict and the items that failed it
        q = json.loads(qa.read_text())
        out["qa_verdict"] = dict(overall=q.get("overall"), passed=q.get("passed"), failed=[
            {k: c.get(k) for k in ("id", "value", "limit", "unit", "note")}
            for c in q.get("checks", []) if c.get("verdict") == "fail"])
    return out


def dmc_entry(block: Path, run_dir: Path, blk: dict, rows: list[dict]) -> dict:
    """Per-unit costs, the 3,000-frame projection and the accuracy of a DMC block's run."""
    summary = run_dir / "work" / "run_summary.json"
    rec = ({r["stage"]: r for r in json.loads(summary.read_text())["stages"]} if summary.exists() else {})
    mos = rec.get("mosaic", {})
    dom_gp = mos["width_px"] * mos["height_px"] / 1e9 if "width_px" in mos else None
    costs = unit_costs(rows, blk, dom_gp)
    return dict(frames_gp=round(blk["frames"] * blk["image_width_px"] * blk["image_height_px"] / 1e9, 3),
                dom_gp=None if dom_gp is None else round(dom_gp, 3), unit_costs=costs,
                projection=projection(costs, blk, dom_gp), accuracy=accuracy(block, run_dir, rows))


def constancy(results: dict) -> dict | None:
    """The per-unit CPU costs of the two DMC block sizes side by side: the larger over the smaller, per stage
    (within 25 %: 0.75-1.25)."""
    if not all(s in results and "unit_costs" in results[s] for s in ("dmc", "dmc_3x8")):
        return None
    big, small = results["dmc"]["unit_costs"], results["dmc_3x8"]["unit_costs"]
    ratio = {st: round(big[st]["cpu_s"] / small[st]["cpu_s"], 2) for st in big
             if st in small and small[st]["cpu_s"] > 0}
    return dict(cpu_ratio_full_over_3x8=ratio, within_25_pct={st: 0.75 <= r <= 1.25 for st, r in ratio.items()})


def interior_dom_gp_per_frame(preset: str = "dmc_block") -> float:
    """The DOM a frame adds inside a large block, in GP at the frame's GSD: its forward base times the strip
    spacing (the edges of a small block add more per frame: its DOM per frame overstates a 3,000-frame block's)."""
    from aerotri.sim import load_preset

    cfg = load_preset(preset)
    f, c = cfg.flight, cfg.camera
    return (1 - f.forward_overlap) * c.height * (1 - f.side_overlap) * c.width / 1e9


def compare_sizes(small: dict, large: dict, dom_gp_per_frame: float | None = None) -> dict:
    """Two DMC runs of the same code at two block sizes, per stage: the larger's per-unit CPU cost over the
    smaller's (constant within 25 %: 0.75-1.25), and the stage's CPU split into a fixed part and a per-unit part
    by the line through both (cpu = fixed + per_unit x units; a fixed part below zero: the cost grows faster than
    the units); the projection to 3,000 frames and 2 G points from the larger run with its fixed part counted
    once, beside the plain per-unit one (``projection``); the DOM at ``dom_gp_per_frame`` (default: the larger
    block's DOM per frame). Two runs of one block (two codes: a recheck) have no line through them: the ratio of
    their per-unit costs alone, the fixed part and the marginal cost None, the projection the plain one."""
    su, lu = small["unit_costs"], large["unit_costs"]
    blk = large["block_numbers"]
    per_frame_gp = blk["image_width_px"] * blk["image_height_px"] / 1e9
    dom_per_frame = dom_gp_per_frame if dom_gp_per_frame is not None else (large.get("dom_gp") or 0.0) / blk["frames"]
    target = {"frame": PROJECT_FRAMES, "GP of frames": PROJECT_FRAMES * per_frame_gp,
              "GP of DOM": PROJECT_FRAMES * dom_per_frame, "M points": PROJECT_POINTS / 1e6}
    stages = {}
    for st, c in lu.items():
        if st not in su or su[st]["cpu_s"] <= 0 or su[st]["unit"] != c["unit"]:
            continue
        ns, nl = su[st]["units"], c["units"]
        cs, cl = su[st]["cpu_s"] * ns, c["cpu_s"] * nl  # the stage's CPU seconds at each size
        n = target[c["unit"]]
        plain_h = c["cpu_s"] * n / 3600
        if nl != ns:
            per_unit = (cl - cs) / (nl - ns)
            fixed = cl - per_unit * nl
        else:  # one block run by two codes: no line through the runs
            per_unit = fixed = None
        stages[st] = dict(unit=c["unit"], units=[ns, nl], cpu_s=[round(cs, 1), round(cl, 1)],
                          cpu_per_unit_s=[su[st]["cpu_s"], c["cpu_s"]], ratio=round(c["cpu_s"] / su[st]["cpu_s"], 2),
                          within_25_pct=bool(0.75 <= c["cpu_s"] / su[st]["cpu_s"] <= 1.25),
                          fixed_cpu_s=None if fixed is None else round(fixed, 1),
                          marginal_cpu_s_per_unit=None if per_unit is None else round(per_unit, 3),
                          fixed_share_of_large=round(fixed / cl, 2) if fixed is not None and cl > 0 else None,
                          projected_cpu_h=round(plain_h if fixed is None else (fixed + per_unit * n) / 3600, 2),
                          projected_cpu_h_plain=round(plain_h, 2))
    if ("mosaic" in stages and small.get("frames_gp") and large.get("frames_gp")
            and large["frames_gp"] != small["frames_gp"]):
        # the mosaic reads every frame ortho over a DOM pixel (3.6 of them inside a 60/30 % block, fewer at a
        # small block's edges): its cost per GP of frames, beside the one per GP of DOM; not in the sums
        ns, nl = small["frames_gp"], large["frames_gp"]
        cs, cl = stages["mosaic"]["cpu_s"]
        per_unit = (cl - cs) / (nl - ns)
        stages_extra = {"mosaic per GP of frames": dict(
            unit="GP of frames", units=[ns, nl], ratio=round((cl / nl) / (cs / ns), 2),
            cpu_per_unit_s=[round(cs / ns, 3), round(cl / nl, 3)], fixed_cpu_s=round(cl - per_unit * nl, 1),
            marginal_cpu_s_per_unit=round(per_unit, 3),
            projected_cpu_h=round((cl - per_unit * nl + per_unit * target["GP of frames"]) / 3600, 2))}
    else:
        stages_extra = {}
    return dict(stages=stages, alternatives=stages_extra,
                projected_cpu_h=round(sum(v["projected_cpu_h"] for v in stages.values()), 1),
                projected_cpu_h_plain=round(sum(v["projected_cpu_h_plain"] for v in stages.values()), 1),
                frames=PROJECT_FRAMES, lidar_points=PROJECT_POINTS, dom_gp=round(target["GP of DOM"], 1),
                assumes="each stage's CPU linear in its units (frames, frame GP, DOM GP at the larger block's DOM per "
                        "frame, LiDAR points) through the two runs; the fixed part once; CPU, not wall (the load)")


def _num(v, width: int, digits: int) -> str:
    return f"{'-':>{width}}" if v is None else f"{v:>{width}.{digits}f}"


def print_comparison(results: dict, out: Path, small: str, large: str) -> int:
    """``--compare SMALL LARGE``: ``compare_sizes`` of two entries, stored as ``constancy_LARGE_over_SMALL``."""
    for k in (small, large):
        if "unit_costs" not in results.get(k, {}):
            sys.exit(f"{out}: no DMC entry {k!r} with unit costs (entries: {', '.join(results)})")
    c = results[f"constancy_{large}_over_{small}"] = compare_sizes(results[small], results[large],
                                                                   interior_dom_gp_per_frame())
    out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"per-unit CPU costs, {large} over {small}; CPU = fixed + per unit x units through both runs")
    print(f"{'stage':<14} {'unit':<13} {'CPU/unit small':>14} {'large':>9} {'ratio':>6} {'fixed CPU s':>11} "
          f"{'per unit':>9} {'fixed share':>11} {'3,000 fr h':>10} {'plain h':>8}")
    for st, v in c["stages"].items():
        print(f"{st:<14} {v['unit']:<13} {v['cpu_per_unit_s'][0]:>14.3f} {v['cpu_per_unit_s'][1]:>9.3f} "
              f"{v['ratio']:>6.2f}{' ' if v['within_25_pct'] else '*'}{_num(v['fixed_cpu_s'], 10, 1)} "
              f"{_num(v['marginal_cpu_s_per_unit'], 9, 3)} {v['fixed_share_of_large']!s:>11} {v['projected_cpu_h']:>10.2f} "
              f"{v['projected_cpu_h_plain']:>8.2f}")
    for st, v in c["alternatives"].items():
        print(f"  {st}: {v['cpu_per_unit_s'][0]:.3f} / {v['cpu_per_unit_s'][1]:.3f} CPU-s, ratio {v['ratio']:.2f}, "
              f"fixed {v['fixed_cpu_s']:.1f} CPU-s, projected {v['projected_cpu_h']:.2f} CPU-h (not in the sum)")
    print(f"projected to {c['frames']} frames, {c['lidar_points'] / 1e9:.0f} G points, {c['dom_gp']} GP of DOM "
          f"(a frame's base x strip spacing): "
          f"{c['projected_cpu_h']} CPU-h with the fixed parts once ({c['projected_cpu_h_plain']} CPU-h per unit "
          f"of the larger run); * outside 25 %")
    return 0


def dmc_lines(e: dict) -> list[str]:
    lines = [f"frames {e['frames_gp']} GP, DOM {e['dom_gp']} GP; per-unit costs (wall / CPU s):"]
    for st, c in e["unit_costs"].items():
        lines.append(f"  {st:<14} {c['wall_s']:>10.3f} {c['cpu_s']:>10.3f}  s per {c['unit']}")
    p = e["projection"]
    lines.append(f"projected to {p['frames']} frames, {p['lidar_points'] / 1e9:.0f} G points, {p['dom_gp']} GP of DOM: "
                 f"{p['wall_h']} h wall, {p['cpu_h']} h CPU, of the stages {', '.join(p['stages'])} ({p['assumes']})")
    a = e["accuracy"]
    if "orientations" in a:
        o = a["orientations"]
        lines.append(f"AT against truth ({o['frames']} frames, GSD {a['gsd_m']} m): centres RMS XY {o['centre_rms_xy_m']} m "
                     f"({o['centre_rms_xy_gsd']} GSD), Z {o['centre_rms_z_m']} m ({o['centre_rms_z_gsd']} GSD), attitude "
                     f"{o['attitude_rms_deg']} deg; normalised by their sigmas {o['normalised_rms']}")
    if "check_points" in a:
        c = a["check_points"]
        lines.append(f"check points: RMS XY {c['rms_xy_m']} m ({c['rms_xy_gsd']} GSD), Z {c['rms_z_m']} m ({c['rms_z_gsd']} GSD)")
    if "dom" in a:
        lines.append(f"DOM against truth/ortho.tif: RMS XY {a['dom']['rms_xy_m']} m ({a['dom']['rms_xy_gsd']} GSD), "
                     f"{a['dom']['patches']} patches")
    if "qa_verdict" in a:
        v = a["qa_verdict"]
        lines.append(f"QA verdict {v['overall']}: " + ("; ".join(f"{c['id']} {c['value']} (limit {c['limit']})"
                                                           for c in v["failed"]) or "no item failed"))
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", choices=list(SIZES), default="full", help="the block (default: full)")
    ap.add_argument("--block", type=Path, help="the generated block (default: $AEROTRI_BENCH_BLOCKS/scale[_SIZE])")
    ap.add_argument("--generate", action="store_true", help="simulate the block first unless it exists")
    ap.add_argument("--generate-only", action="store_true", help="simulate the block, do not run the chain")
    ap.add_argument("--print-command", action="store_true", help="print the generation command, run nothing")
    ap.add_argument("--table-only", action="store_true", help="tabulate the last run of this size, run nothing")
    ap.add_argument("--scheduler", help="passed to aerotri run (default: its own)")
    ap.add_argument("--workers", type=int, help="passed to aerotri run")
    ap.add_argument("--run-dir", type=Path, help="the run folder (default: the block's folder name + _run beside it)")
    ap.add_argument("--resume", action="store_true",
                    help="run the chain in the run folder as it is (its current stages skipped) instead of a fresh one")
    ap.add_argument("--out", type=Path, help="results file (default bench/results/scale.json; DMC sizes bench/results/scale_dmc.json)")
    ap.add_argument("--key", help="the run's entry in the results file (default: the size), e.g. to keep an older run")
    ap.add_argument("--compare", nargs=2, metavar=("SMALL", "LARGE"),
                    help="two DMC entries of the results file: their per-unit CPU costs side by side, each stage's "
                         "fixed and per-unit part, the projection from the larger without its fixed part")
    args = ap.parse_args(argv)
    dmc = args.size in DMC_SIZES or bool(args.compare)
    args.out = args.out or ROOT / "bench" / "results" / ("scale_dmc.json" if dmc else "scale.json")
    if args.compare:
        return print_comparison(json.loads(args.out.read_text()) if args.out.exists() else {}, args.out, *args.compare)

    block = args.block or BLOCKS / (DMC_BLOCKS[args.size] if dmc else
                                    "scale" if args.size == "full" else f"scale_{args.size}")
    if args.print_command:
        print(" ".join(generate_command(block, args.size)))
        return 0
    run_dir = args.run_dir or block.parent / f"{block.name}_run"
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    key = args.key or args.size
    entry = dict(results.get(key, {})) if args.table_only else {}
    if args.generate or args.generate_only:
        if (block / "truth" / "truth.json").exists():
            print(f"{block}: block exists, reusing it", flush=True)
        else:
            entry["generation"] = g = generate(block, args.size)
            print(f"generated in {g['wall_s'] / 60:.1f} min, CPU {g['cpu_s'] / 60:.1f} min, peak RSS "
                  f"{g['peak_rss_mb']:.0f} MB, load {g['load_avg_before']} -> {g['load_avg_after']}", flush=True)
        if args.generate_only:
            results[key] = dict(results.get(key, {}), **entry)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(results, indent=1) + "\n")
            return 0
    if not (block / "truth" / "truth.json").exists():
        sys.exit(f"{block}: no generated block (bench/scale.py --size {args.size} --generate; "
                 f"or run `bench/scale.py --size {args.size} --print-command` elsewhere)")
    if args.table_only and not (run_dir / "work").is_dir():
        sys.exit(f"{run_dir}: no run of the {args.size} block yet")
    blk = block_numbers(block)
    run = None if args.table_only else run_chain(block, run_dir, args.scheduler, args.workers, args.resume)
    rows = stage_rows(stage_records(run_dir), blk)
    stage_load(rows, run_dir, (run or entry.get("run") or {}).get("load_samples"))
    summary = run_dir / "work" / "run_summary.json"
    chain_load = ({k: v for k, v in json.loads(summary.read_text()).items() if k.startswith("load_avg")}
                  if summary.exists() else {})
    run = run or entry.get("run")
    limits = (DMC_LIMIT_WALL_MIN, DMC_LIMIT_PEAK_GB) if dmc else (LIMIT_WALL_MIN, LIMIT_PEAK_GB)
    entry.update(block=str(block), run_dir=str(run_dir), block_numbers=blk, stages=rows,
                 verdict=verdict(rows, run, *limits, finished=summary.exists()), chain_load_avg=chain_load, cpu_count=os.cpu_count())
    if dmc:
        entry.update(dmc_entry(block, run_dir, blk, rows))
    if run:
        entry["run"] = run
    if not args.table_only:
        entry["measured_utc"] = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    results[key] = dict(results.get(key, {}), **entry)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")

    print(f"\n{key} block: {blk['frames']} frames of {blk['image_width_px']} x {blk['image_height_px']} px, "
          f"{blk['lidar_points'] / 1e6:.2f} M LiDAR points in {blk['lidar_strips']} strips, {blk['scene_km2']} km2")
    print(format_table(rows))
    print(verdict_line(key, entry["verdict"]))
    if dmc:
        print("\n".join(dmc_lines(entry)))
        results["constancy"] = constancy(results)
        args.out.write_text(json.dumps(results, indent=1) + "\n")
        if results["constancy"]:
            print(f"per-unit CPU costs, full block over the 3 x 8 subset: {results['constancy']['cpu_ratio_full_over_3x8']}")
    if run:
        print(f"load average (1, 5, 15 min) {run['load_avg_before']} before, {run['load_avg_after']} after "
              f"on {os.cpu_count()} cores; aerotri run exit code {run['returncode']}")
    lidar = {s: e["verdict"] for s, e in results.items() if (e or {}).get("verdict", {}).get("lidar_peak_rss_mb")}
    if len(lidar) > 1:
        print("LiDAR stages' peak RSS by block size: " + ", ".join(
            f"{s} {v['lidar_peak_rss_mb']:.0f} MB ({v['lidar_peak_stage']}, {results[s]['block_numbers']['lidar_points'] / 1e6:.1f} M points)"
            for s, v in lidar.items()))
    return 0 if run is None or run["returncode"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
