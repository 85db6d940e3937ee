"""Benchmark: the image stages one command at a time on full-size Z/I DMC frames (13824 x 7680 px, 12-bit in
16-bit ZSTD tiles), each under ``/usr/bin/time -v`` (wall, CPU, peak RSS of that command alone, unlike the chain's
stage records whose peak includes what the process still holds of earlier stages).

Stages (``--stages``, in this order): ``match`` (``aerotri match``: pairs from GNSS), ``adjust`` (``aerotri adjust
--no-exports``: tie points and GNSS, no LiDAR control), ``control`` (``aerotri control --corners``: the roof corners
measured in the frames at full resolution; the corners are the simulator's true roof corners with LiDAR-like
noise, 0.10 m in plan and 0.05 m in height, ``aerotri.sim.evaluate.write_truth_corners_csv``, standing in for
``lidarctl corners``), ``adjust_final`` (``aerotri adjust --dem DEM --ndsm``: with that control and the DEM as
surface control, the truth nDSM telling ground tie points from roofs and trees; standing in for the LiDAR's),
``rectify`` (``ortho rectify --dem DEM``), ``mosaic``
(``ortho mosaic``), ``peer_mosaic`` (the peer of the mosaic on the same frame orthos, right after it: ``gdalwarp -of COG
-co COMPRESS=ZSTD -co NUM_THREADS=2 -wo NUM_THREADS=2 -multi``, no seamlines or balancing; its DOM is removed after,
for the disk; needs Debian's gdal-bin), ``check`` (``ortho check --reference truth/ortho.tif``). The DEM is the simulator's
truth/dem.tif unless ``--dem`` names another (the chain uses lidar_out/dem.tif of its LiDAR stages; this bench
leaves the LiDAR stages out to measure the image stages alone). The block's inputs (project.toml, camera.toml,
gnss.txt, images/) are hard-linked into ``--work`` (kept when it exists, so later stages can run on earlier ones'
outputs). After the adjustment the orientations against truth/eo.txt (in GSD); after the check, the DOM's RMS
against the truth orthophoto in GSD.

Writes bench/results/dmc_stages.json (entry per block folder name; stages kept across runs).

Usage:
  python bench/eval_dmc_stages.py                                   # all stages on dmc_block_subset_3x8
  python bench/eval_dmc_stages.py --stages rectify,mosaic,check --work /work/tmp/dmc_stages
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
sys.path.insert(0, str(ROOT))

RESULT = ROOT / "bench" / "results" / "dmc_stages.json"
BLOCKS = Path(os.environ.get("AEROTRI_BENCH_BLOCKS", "/work/bench_blocks"))
STAGES = ("match", "adjust", "control", "adjust_final", "rectify", "mosaic", "peer_mosaic", "check")
from mosaic_speed import PEER  # noqa: E402 - the mosaic's peer command, one definition (bench/ is sys.path[0])


def _time_v(stderr: str) -> dict:
    """Wall, CPU and peak RSS from ``/usr/bin/time -v``."""
    def field(name):
        m = re.search(rf"{re.escape(name)}: (.+)", stderr)
        return m.group(1).strip() if m else None

    wall_s = sum(float(p) * 60 ** k for k, p in enumerate(reversed(field("Elapsed (wall clock) time (h:mm:ss or m:ss)").split(":"))))
    return dict(wall_s=round(wall_s, 1),
                cpu_s=round(float(field("User time (seconds)")) + float(field("System time (seconds)")), 1),
                peak_rss_mb=round(int(field("Maximum resident set size (kbytes)")) / 1024, 1))


def command(stage: str, work: Path, block: Path, dem: Path) -> list[str]:
    return {"match": ["aerotri", "match", str(work)],
            "adjust": ["aerotri", "adjust", str(work), "--no-exports"],
            "control": ["aerotri", "control", str(work), "--corners", str(work / "truth_corners.csv")],
            "adjust_final": ["aerotri", "adjust", str(work), "--no-exports", "--dem", str(dem), "--ndsm",
                             str(work / "truth_ndsm.tif")],
            "rectify": ["ortho", "rectify", str(work), "--dem", str(dem)],
            "mosaic": ["ortho", "mosaic", str(work)],
            "peer_mosaic": PEER + ["--optfile", str(work / "peer_inputs.txt"), str(work / "peer_mosaic.tif")],
            "check": ["ortho", "check", str(work), "--reference", str(block / "truth" / "ortho.tif")]}[stage]


def write_truth_ndsm(block: Path, out: Path) -> None:
    """The truth nDSM (truth/dsm.tif - truth/dem.tif, one grid), standing in for lidar_out/ndsm.tif: without it
    ``aerotri adjust --dem`` holds roof and tree tie points to the ground too (robust rounds only; on this
    built-up block: check points 5.2 GSD in plan, 25 GSD in height, bench/results/dmc_stages_control.json)."""
    import rasterio

    with rasterio.open(block / "truth" / "dem.tif") as a, rasterio.open(block / "truth" / "dsm.tif") as b:
        ndsm, prof = (b.read(1) - a.read(1)).astype(np.float32), a.profile
    prof.update(compress="deflate", predictor=3, tiled=True, blockxsize=512, blockysize=512)
    with rasterio.open(out, "w", **prof) as dst:
        dst.write(ndsm, 1)


def orientations_vs_truth(work: Path, block: Path, gsd_m: float) -> dict:
    from aerotri.geom.eo import read_eo

    eo, truth = read_eo(work / "at" / "eo.txt"), read_eo(block / "truth" / "eo.txt")
    sel = truth.rows(eo.image_id)
    d = eo.centre_m - truth.centre_m[sel]
    att = (eo.opk_deg - truth.opk_deg[sel] + 180.0) % 360.0 - 180.0
    xy, z = float(np.sqrt(np.mean(d[:, :2] ** 2))), float(np.sqrt(np.mean(d[:, 2] ** 2)))
    return dict(frames=len(sel), centre_rms_xy_m=round(xy, 4), centre_rms_z_m=round(z, 4),
                centre_rms_xy_gsd=round(xy / gsd_m, 2), centre_rms_z_gsd=round(z / gsd_m, 2),
                attitude_rms_deg=round(float(np.sqrt(np.mean(att ** 2))), 5))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--block", type=Path, default=BLOCKS / "dmc_block_subset_3x8")
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/dmc_stages"))
    ap.add_argument("--dem", type=Path, help="DEM of the orthophotos (default: the block's truth/dem.tif)")
    ap.add_argument("--stages", default=",".join(STAGES), help=f"comma-separated, of {', '.join(STAGES)}")
    ap.add_argument("--out", type=Path, default=RESULT, help="results file (another one for stages run side by side)")
    args = ap.parse_args()
    stages = [s for s in args.stages.split(",") if s]
    if bad := [s for s in stages if s not in STAGES]:
        sys.exit(f"--stages: unknown stage(s) {', '.join(bad)} (expected {', '.join(STAGES)})")
    dem = args.dem or args.block / "truth" / "dem.tif"
    truth = json.loads((args.block / "truth" / "truth.json").read_text())
    if not args.work.exists():
        args.work.mkdir(parents=True)
        for name in ("project.toml", "camera.toml", "gnss.txt"):
            os.link(args.block / name, args.work / name)
        shutil.copytree(args.block / "images", args.work / "images", copy_function=os.link)
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    entry = results.setdefault(args.block.name, dict(block=str(args.block), frames=truth["frames"],
                                                      image_width_px=truth["image_width_px"],
                                                      image_height_px=truth["image_height_px"], gsd_m=truth["gsd_m"],
                                                      stages={}))
    entry["dem"] = str(dem)
    for stage in stages:
        cmd = command(stage, args.work, args.block, dem)
        if stage == "adjust_final" and not (args.work / "truth_ndsm.tif").exists():
            write_truth_ndsm(args.block, args.work / "truth_ndsm.tif")
        if stage == "control" and not (args.work / "truth_corners.csv").exists():
            from aerotri.sim.evaluate import write_truth_corners_csv

            write_truth_corners_csv(args.block, args.work / "truth_corners.csv", noise=True, seed=41)
        if stage == "peer_mosaic":
            frames = sorted((args.work / "ortho" / "frames").glob("*.tif"))
            (args.work / "peer_inputs.txt").write_text("\n".join(str(f) for f in frames) + "\n")
        load0 = [round(v, 2) for v in os.getloadavg()]
        print(f"[{stage}] {' '.join(cmd)}", flush=True)
        exe = shutil.which(cmd[0]) if stage == "peer_mosaic" else str(BIN / cmd[0])
        if exe is None:
            sys.exit("gdalwarp not found: the peer of the mosaic is Debian's gdal-bin (make bench installs it)")
        p = subprocess.run(["/usr/bin/time", "-v", exe, *cmd[1:]], capture_output=True, text=True)
        if p.returncode != 0:
            sys.exit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-3000:]}")
        rec = dict(command=" ".join(cmd), **_time_v(p.stderr), load_avg_before=load0,
                   load_avg_after=[round(v, 2) for v in os.getloadavg()],
                   measured_utc=time.strftime("%Y-%m-%d %H:%M", time.gmtime()))
        if stage in ("adjust", "adjust_final"):
            rec["orientations_vs_truth"] = orientations_vs_truth(args.work, args.block, truth["gsd_m"])
        if stage == "mosaic":
            import rasterio

            with rasterio.open(args.work / "ortho" / "mosaic.tif") as ds:
                rec["dom_gp"] = round(ds.width * ds.height / 1e9, 3)
                rec["dom_mp_per_s"] = round(ds.width * ds.height / 1e6 / rec["wall_s"], 2)
        if stage == "peer_mosaic":
            import rasterio

            peer = args.work / "peer_mosaic.tif"
            with rasterio.open(peer) as ds:
                rec["dom_gp"] = round(ds.width * ds.height / 1e9, 3)
                rec["file_gb"] = round(peer.stat().st_size / 1e9, 2)
            peer.unlink()
            ours = entry["stages"].get("mosaic")
            if ours:
                rec["ratio_peer_over_ours_wall"] = round(rec["wall_s"] / ours["wall_s"], 2)
                rec["ratio_peer_over_ours_cpu"] = round(rec["cpu_s"] / ours["cpu_s"], 2)
        if stage == "adjust_final":
            chk = json.loads((args.work / "at" / "report.json").read_text()).get("check_rms_m")
            if chk and None not in chk:
                xy = float(np.hypot(chk[0], chk[1]))
                rec["check_points"] = dict(rms_xy_m=round(xy, 4), rms_z_m=chk[2],
                                           rms_xy_gsd=round(xy / truth["gsd_m"], 2),
                                           rms_z_gsd=round(chk[2] / truth["gsd_m"], 2))
        if stage == "check":
            rep = args.work / "ortho" / "dom_report.json"
            if rep.exists():
                r = json.loads(rep.read_text())
                rec["dom_report"] = {k: v for k, v in r.items() if isinstance(v, (int, float, str))}
        entry["stages"][stage] = rec
        print(f"[{stage}] {rec['wall_s']} s wall, {rec['cpu_s']} s CPU, peak RSS {rec['peak_rss_mb']:.0f} MB", flush=True)
        args.out.parent.mkdir(exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
