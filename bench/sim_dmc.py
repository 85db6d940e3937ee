"""Benchmark: make the simulator's full-size block (preset ``dmc_block``) and report what it cost.

The block: 120 frames of 13824 x 7680 px (12-bit, one panchromatic band, tiled 16-bit TIFF with ZSTD) at
0.10 m GSD over LiDAR strips of the same area (17 LAZ files, about 250 M points) and the truth (DEM, DSM, a
true orthophoto, NIR and land-cover rasters at the GSD: about 4.3 GP). It is written outside the repository
(``--out``, default ``$AEROTRI_BENCH_BLOCKS/dmc_block``, ``/work/bench_blocks/dmc_block``), replacing what is
there.

Per phase of ``aerotri.sim.simulate`` (scene, frames, lidar, truth_rasters, other): wall and CPU seconds and the
process's peak RSS (``aerotri.core.resources.measure``, reset before each phase), and the unit costs: s per
frame and MP/s of frames (wall; and MP per CPU-second, steadier on a shared machine), s per million LiDAR
points, MP/s of truth rasters. A smaller block of the same preset (``--set flight.strips=2 --set
flight.frames_per_strip=5``: its scene, objects and LiDAR shrink with the flight) gives the unit costs for an
honest projection of the full block when the machine is too loaded to make it: the projection (frames, points
and truth pixels of the full block times the subset's unit costs, plus the subset's scene time scaled by the
area) is written beside the measurement, marked as such. Load averages before and after are recorded: on a
shared machine wall times follow the load, CPU seconds much less.

Writes bench/results/sim_dmc.json (one entry per run name: ``full`` or ``subset_<strips>x<frames>``, kept across
runs of the other).

Usage:
  python bench/sim_dmc.py                                                  # the whole block (about 35 min idle)
  python bench/sim_dmc.py --set flight.strips=2 --set flight.frames_per_strip=5  # a 10-frame subset, projected
  python bench/sim_dmc.py --table-only                                     # print the stored results
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RESULT = ROOT / "bench" / "results" / "sim_dmc.json"
BLOCKS = Path(os.environ.get("AEROTRI_BENCH_BLOCKS", "/work/bench_blocks"))
PRESET = "dmc_block"
LIMIT_WALL_MIN = 45.0  # issue 41: rendered and scanned in under 45 min
TARGET_FRAME_MP_S = 20.0


def _load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _du_gb(path: Path) -> float:
    return round(sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e9, 2) if path.exists() else 0.0


def _run_name(overrides: list[str]) -> str:
    if not overrides:
        return "full"
    from aerotri.sim import load_preset

    f = load_preset(PRESET, overrides).flight
    return f"subset_{f.strips}x{f.frames_per_strip}"


def unit_costs(phases: dict) -> dict:
    """s per frame, frame MP/s (wall) and MP per CPU-second, s per million points, truth MP/s."""
    fr, li, tr = phases["frames"], phases["lidar"], phases["truth_rasters"]
    return dict(
        frame_s=round(fr["wall_s"] / fr["frames"], 2), frame_cpu_s=round(fr["cpu_s"] / fr["frames"], 2),
        frame_mp_per_s=round(fr["megapixels"] / fr["wall_s"], 2),
        frame_mp_per_cpu_s=round(fr["megapixels"] / fr["cpu_s"], 2),
        lidar_s_per_m_points=round(li["wall_s"] / (li["points"] / 1e6), 2),
        lidar_cpu_s_per_m_points=round(li["cpu_s"] / (li["points"] / 1e6), 2),
        truth_mp_per_s=round(tr["megapixels"] / tr["wall_s"], 2),
        truth_mp_per_cpu_s=round(tr["megapixels"] / tr["cpu_s"], 2),
    )


def projection(measured: dict, full: dict) -> dict:
    """The full block's phases from a smaller block's unit costs: frames x s per frame, points x s per M point,
    truth pixels x s per MP, the scene build by the scene area; wall (and CPU) seconds at the measured load."""
    u = measured["unit_costs"]
    ph = measured["phases"]
    area = full["scene_km2"] / measured["block"]["scene_km2"]
    out = {}
    for key in ("wall_s", "cpu_s"):
        frames = full["frames"] * ph["frames"][key] / ph["frames"]["frames"]
        lidar = full["lidar_points_planned"] / ph["lidar"]["points"] * ph["lidar"][key]
        truth = full["truth_megapixels"] / ph["truth_rasters"]["megapixels"] * ph["truth_rasters"][key]
        scene = area * ph["scene"][key]
        other = area * ph["other"][key]
        out[key] = dict(scene=round(scene, 1), frames=round(frames, 1), lidar=round(lidar, 1), truth_rasters=round(truth, 1),
                        other=round(other, 1), total=round(scene + frames + lidar + truth + other, 1))
    out["assumes"] = (f"the full block's {full['frames']} frames, about {full['lidar_points_planned'] / 1e6:.0f} M "
                      f"points (its {full['lidar_pulses'] / 1e6:.0f} M pulses times the subset's points per pulse) "
                      f"and {full['truth_megapixels']:.0f} MP of truth rasters at this run's unit costs "
                      f"({u['frame_s']} s a frame, {u['lidar_s_per_m_points']} s per M points, "
                      f"{u['truth_mp_per_s']} truth MP/s) and load; scene and other phases scaled by the scene area")
    return out


def full_block_numbers(points_per_pulse: float) -> dict:
    """Frames, pulses, planned points (at ``points_per_pulse``), scene area and truth megapixels of the whole
    preset, before any simulation."""
    import math

    from aerotri.sim import lidar_plan, load_preset
    from aerotri.sim.flight import block_layout

    cfg = load_preset(PRESET)
    layout = block_layout(cfg)
    plan = lidar_plan(cfg)
    t = cfg.truth
    raster_mp = 2 * math.floor(layout.width_m / t.raster_res_m) * math.floor(layout.height_m / t.raster_res_m) / 1e6
    ortho_mp = math.floor(layout.width_m / t.ortho_res_m) * math.floor(layout.height_m / t.ortho_res_m) / 1e6
    return dict(frames=cfg.flight.strips * cfg.flight.frames_per_strip, lidar_pulses=plan.pulses,
                lidar_points_planned=plan.pulses * points_per_pulse, scene_km2=plan.scene_km2,
                truth_megapixels=raster_mp + ortho_mp)


# Bytes on disk per unit, measured on the 2 x 5 subset: 12-bit frames with ZSTD (noise and texture: 0.59 of
# the raw 16-bit samples), LAZ points (written twice: lidar/ and truth/lidar/), truth raster pixels (8-bit
# ortho, NIR and classes at the GSD, float32 DEM and DSM at 0.5 m).
BYTES_PER_SAMPLE, BYTES_PER_POINT, BYTES_PER_TRUTH_PX = 1.18, 2 * 5.2, 1.0
DISK_MARGIN_GB = 10.0  # left free for the other work on the machine


def estimated_gb(overrides: list[str]) -> float:
    """The block's size on disk before it is made (``BYTES_PER_*``; 0.8 points a pulse)."""
    from aerotri.sim import lidar_plan, load_preset

    cfg = load_preset(PRESET, overrides)
    c, f = cfg.camera, cfg.flight
    bands = 1 if cfg.render.bands == "pan" else 3
    frames = f.strips * f.frames_per_strip * c.width * c.height * bands * BYTES_PER_SAMPLE
    plan = lidar_plan(cfg)
    truth = plan.scene_km2 * 1e6 / cfg.truth.ortho_res_m ** 2 * BYTES_PER_TRUTH_PX
    return (frames + 0.8 * plan.pulses * BYTES_PER_POINT + truth) / 1e9


def make_block(out: Path, overrides: list[str]) -> dict:
    from aerotri.core.log import configure
    from aerotri.core.resources import measure
    from aerotri.sim import lidar_plan, load_preset, simulate

    configure(0)
    cfg = load_preset(PRESET, overrides)
    plan = lidar_plan(cfg)
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    need, free = estimated_gb(overrides), shutil.disk_usage(out.parent).free / 1e9
    if free < need + DISK_MARGIN_GB:
        sys.exit(f"{out}: the block needs about {need:.0f} GB and {out.parent} has {free:.0f} GB free; making it would "
                 f"leave less than {DISK_MARGIN_GB:.0f} GB for other work (measure a smaller block: --set "
                 f"flight.strips=2 --set flight.frames_per_strip=5)")
    phases = {}
    load0 = _load()
    with measure() as total:
        truth = simulate(cfg, out, on_phase=lambda cost: phases.__setitem__(cost.phase, dataclasses.asdict(cost)))
    peak = max(p["peak_rss_mb"] or 0.0 for p in phases.values())
    cam = cfg.camera
    return dict(
        block=dict(path=str(out), frames=truth.frames, image_width_px=truth.image_width_px,
                   image_height_px=truth.image_height_px, bands=cfg.render.bands,
                   bits=cfg.render.bits, tile_px=cfg.render.tile_px,
                   compression=cfg.render.compress, gsd_m=round(truth.gsd_m, 4),
                   focal_mm=cam.focal_mm, pixel_um=truth.pixel_um, lidar_strips=truth.lidar_strips,
                   lidar_points=truth.lidar_points, lidar_pulses=plan.pulses,
                   lidar_format=cfg.lidar.format, scene_km2=plan.scene_km2,
                   truth_ortho_res_m=cfg.truth.ortho_res_m,
                   disk_gb=dict(images=_du_gb(out / "images"), lidar=_du_gb(out / "lidar"),
                                truth=_du_gb(out / "truth"), total=_du_gb(out))),
        command=f"aerotri sim --preset {PRESET} " + "".join(f"--set {o} " for o in overrides) + str(out),
        wall_s=round(total.wall_s, 1), cpu_s=round(total.cpu_s, 1), peak_rss_mb=round(peak, 1),
        phases=phases, unit_costs=unit_costs(phases), load_avg_before=load0, load_avg_after=_load(),
        cpus=os.cpu_count())


def table(name: str, r: dict) -> str:
    if "block" not in r:  # a run stopped before the block was written: its note only
        return f"{name}: {r.get('command', '')}: stopped, not made ({r.get('note', r.get('wall_s', ''))})"
    b, u = r["block"], r["unit_costs"]
    lines = [f"{name}: {b['frames']} frames of {b['image_width_px']} x {b['image_height_px']} px ({b['bands']}, "
             f"{b['bits']}-bit, {b['tile_px']} px tiles, {b['compression']}), {b['lidar_points'] / 1e6:.1f} M points in "
             f"{b['lidar_strips']} {b['lidar_format'].upper()} strips, {b['scene_km2']} km2; {b['disk_gb']['total']} GB",
             f"  total {r['wall_s'] / 60:.1f} min wall, {r['cpu_s'] / 60:.1f} min CPU, peak RSS {r['peak_rss_mb'] / 1024:.2f} GB; "
             f"load {r['load_avg_before']} -> {r['load_avg_after']} on {r['cpus']} CPUs",
             f"  {'phase':<14}{'wall s':>9}{'CPU s':>9}{'peak MB':>9}"]
    for k, p in r["phases"].items():
        lines.append(f"  {k:<14}{p['wall_s']:>9.1f}{p['cpu_s']:>9.1f}{(p['peak_rss_mb'] or 0):>9.0f}")
    lines.append(f"  frames: {u['frame_s']} s ({u['frame_cpu_s']} CPU-s) a frame, {u['frame_mp_per_s']} MP/s, "
                 f"{u['frame_mp_per_cpu_s']} MP per CPU-s; LiDAR: {u['lidar_s_per_m_points']} s ({u['lidar_cpu_s_per_m_points']} "
                 f"CPU-s) per M points; truth rasters: {u['truth_mp_per_s']} MP/s")
    if "projection_full" in r:
        p = r["projection_full"]
        lines.append(f"  projected full block: {p['wall_s']['total'] / 60:.1f} min wall, {p['cpu_s']['total'] / 60:.1f} min "
                     f"CPU ({p['assumes']})")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="block folder (default $AEROTRI_BENCH_BLOCKS/dmc_block)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="preset override, e.g. flight.strips=2 (a smaller block: unit costs and a projection)")
    ap.add_argument("--table-only", action="store_true", help="print the stored results, run nothing")
    args = ap.parse_args()
    results = json.loads(RESULT.read_text()) if RESULT.exists() else {}
    if not args.table_only:
        name = _run_name(args.overrides)
        out = args.out or BLOCKS / ("dmc_block" if name == "full" else f"dmc_block_{name}")
        r = make_block(out, args.overrides)
        ppp = r["block"]["lidar_points"] / r["block"]["lidar_pulses"]
        full = full_block_numbers(ppp)
        if name != "full":
            r["projection_full"] = projection(r, full)
        r["limits"] = dict(wall_min=LIMIT_WALL_MIN, frame_mp_per_s=TARGET_FRAME_MP_S)
        results[name] = r
        RESULT.parent.mkdir(exist_ok=True)
        RESULT.write_text(json.dumps(results, indent=1) + "\n")
    for name, r in results.items():
        print(table(name, r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
