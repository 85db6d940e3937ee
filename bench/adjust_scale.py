"""``aerotri adjust`` at production scale: observation-only blocks of 300 to 10,000 frames, timed as a user runs it.

``make``: a block written as a project folder that ``aerotri adjust P --dem P/dem.tif`` runs on as it stands:
project.toml ([gnss] sigmas and lever arm, [adjust] GNSS shift and drift per strip and self-calibration pp + radial as
the demo), camera.toml (the nominal DMC; the true one has a principal-point offset and radial distortion),
gnss.txt (antenna positions with noise, a shift and drift per strip), at/tiepoints.csv (``point_id,image_id,
x_px,y_px`` as ``aerotri match`` writes it: random ground points seen in three frames or more, 0.3 px noise,
0.1 % blunders of 5-50 px), control/ (full control points spread over the block, surveyed check points),
dem.tif (the truth terrain, float32 GeoTIFF in the project CRS) and truth/eo.txt. No rendering (the
geometry of ``aerotri.sim.observations``: DMC 13824 x 7680 px at 1000 m, 0.10 m GSD, 60 % / 30 % overlap).

``run``: ``aerotri adjust P --dem P/dem.tif --no-exports`` in a child process under ``/usr/bin/time -v`` (wall, CPU,
peak RSS of the whole command: start-up, reading, robust rounds, final solve, covariances of the orientations and
the points, report.txt/json/html with figures), then ``aerotri export P`` (the PATB and COLMAP files the adjust
writes without --no-exports) timed the same way, then the result against the truth: each
projection centre and attitude difference to truth/eo.txt in the sigma eo.txt reports for it (the RMS of those
normalised differences is about 1 when the sigmas are right; share within 3 sigma), and the check points.

    python bench/adjust_scale.py make OUT/b300 --frames 300
    python bench/adjust_scale.py run OUT/b300 --label after [--pythonpath OLD_TREE] [--out bench/results/adjust_scale.json]
    python bench/adjust_scale.py all OUT --sizes 300 1000 3000 10000

Blocks by size (strips x frames per strip): 300 = 10 x 30, 1,000 = 20 x 50, 3,000 = 30 x 100,
10,000 = 50 x 200. ``--pythonpath``: run another source tree's aerotri with this interpreter (the
"before" column). Results go into ``bench/results/adjust_scale.json`` under size and label.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SIZES = {300: (10, 30), 1000: (20, 50), 3000: (30, 100), 10000: (50, 200)}
POINTS_PER_IMAGE = 340  # random ground points drawn per frame (x 1 / 1.5); those seen three times or more are kept (10,000 frames: >= 1 M tie points, >= 5 M image observations)
TIE_SIGMA_PX = 0.3


def layout(frames: int) -> tuple[int, int]:
    """(strips, frames per strip) of a block of about ``frames`` frames."""
    if frames in SIZES:
        return SIZES[frames]
    strips = max(2, int(round(np.sqrt(frames / 4))))
    return strips, max(3, int(round(frames / strips)))


def make_block(out: Path, frames: int, *, points_per_image: int = POINTS_PER_IMAGE, dem_cell_m: float | None = None,
               seed: int = 41, self_calibration: bool = True) -> dict:
    """Write the project folder of a block of about ``frames`` frames; returns its summary (also ``block.json``)."""
    from aerotri.sim.clutter import write_terrain_rasters
    from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

    t0 = time.perf_counter()
    strips, per_strip = layout(frames)
    n = strips * per_strip
    # a DEM cell the size of a LiDAR DEM for small blocks; coarser for large ones (the terrain's shortest
    # wavelength is 1.6 km: a 10 m grid holds it to millimetres) so the 10,000-frame DEM stays ~30 M cells
    cell = dem_cell_m or (2.0 if n <= 1000 else 5.0 if n <= 3000 else 10.0)
    block = geometric_block(strips, per_strip, seed=seed)
    root = write_block_project(block, out, name=f"scale{n}")
    n_control = max(4, n // 250)  # a few full control points over the block (the datum is GNSS + DEM)
    summary = write_truth_observations(root, tie_sigma_px=TIE_SIGMA_PX, n_control=n_control, n_check=60,
                                       points_per_image=points_per_image, blunder_fraction=1e-3, seed=seed + 1)
    write_terrain_rasters(block, root / "dem.tif", cell_m=cell, margin_m=600.0)
    cfg = (root / "project.toml").read_text()
    cal = '["pp", "radial"]' if self_calibration else "[]"
    (root / "project.toml").write_text(cfg + f'\n[adjust]\ngnss_correction = "shift_drift"\nself_calibration = {cal}\n')
    info = {"frames": n, "strips": strips, "frames_per_strip": per_strip,
            "tie_points": summary.n_tie_points, "image_observations": summary.n_tie_observations,
            "tie_blunders": len(summary.tie_blunders), "control_points": n_control, "check_points": 60,
            "dem_cell_m": cell, "points_per_image": points_per_image, "seed": seed,
            "self_calibration": self_calibration, "make_s": round(time.perf_counter() - t0, 1)}
    (root / "block.json").write_text(json.dumps(info, indent=1))
    return info


def _block_summary(root: Path) -> dict:
    """The block's summary: block.json of ``make``, else (a block of ``aerotri sim --observations-only``) the counts
    of its truth/truth.json."""
    if (root / "block.json").exists():
        return json.loads((root / "block.json").read_text())
    truth_path = root / "truth" / "truth.json"
    if not truth_path.exists():
        sys.exit(f"{root}: neither block.json (bench/adjust_scale.py make) nor truth/truth.json (aerotri sim)")
    t = json.loads(truth_path.read_text())
    return {"frames": t["frames"], "strips": t.get("strips"), "frames_per_strip": t.get("frames_per_strip"),
            "tie_points": t.get("tie_points"), "image_observations": t.get("tie_observations"), "seed": t.get("seed"),
            "made_by": f"aerotri sim --preset {t.get('preset')} --observations-only"}


def _time_v(stderr: str) -> dict:
    """Wall, CPU (user + system) and peak RSS from ``/usr/bin/time -v``, and the minor page faults."""
    def field(name):
        m = re.search(rf"{re.escape(name)}: (.+)", stderr)
        return m.group(1).strip() if m else None

    wall = field("Elapsed (wall clock) time (h:mm:ss or m:ss)")
    parts = [float(p) for p in wall.split(":")]
    wall_s = sum(p * 60 ** k for k, p in enumerate(reversed(parts)))
    user, system = float(field("User time (seconds)")), float(field("System time (seconds)"))
    return {"wall_s": round(wall_s, 1), "cpu_s": round(user + system, 1), "user_s": round(user, 1),
            "system_s": round(system, 1), "minor_page_faults": int(field("Minor (reclaiming a frame) page faults")),
            "peak_rss_mb": round(int(field("Maximum resident set size (kbytes)")) / 1024, 0)}


def _angle_diff_deg(a, b):
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def check_truth(root: Path) -> dict:
    """The adjusted orientations (at/eo.txt, with their sigmas) against truth/eo.txt, and the check points."""
    from aerotri.geom.eo import read_eo

    eo, truth = read_eo(root / "at" / "eo.txt"), read_eo(root / "truth" / "eo.txt")
    sel = truth.rows(eo.image_id)
    d = np.column_stack([eo.centre_m - truth.centre_m[sel], _angle_diff_deg(eo.opk_deg, truth.opk_deg[sel])])
    z = d / eo.sigma
    names = ["X", "Y", "Z", "omega", "phi", "kappa"]
    rep = json.loads((root / "at" / "report.json").read_text())
    out = {"frames_adjusted": len(eo.image_id),
           "normalised_rms": {n: round(float(np.sqrt(np.mean(z[:, c] ** 2))), 3) for c, n in enumerate(names)},
           "within_3_sigma_share": {n: round(float(np.mean(np.abs(z[:, c]) <= 3.0)), 4) for c, n in enumerate(names)},
           "max_abs_normalised": {n: round(float(np.abs(z[:, c]).max()), 2) for c, n in enumerate(names)},
           "rms_error": {"centre_xy_m": round(float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2) / 2)), 4),
                         "centre_z_m": round(float(np.sqrt(np.mean(d[:, 2] ** 2))), 4),
                         "attitude_deg": round(float(np.sqrt(np.mean(d[:, 3:] ** 2))), 5)},
           "median_sigma": {"centre_xy_m": round(float(np.median(eo.sigma[:, :2])), 4),
                            "centre_z_m": round(float(np.median(eo.sigma[:, 2])), 4),
                            "attitude_deg": round(float(np.median(eo.sigma[:, 3:])), 5)},
           "sigma0_um": rep["key_statistics"].get("sigma0_um"), "iterations": rep["key_statistics"].get("iterations"),
           "check_rms_m": rep.get("check_rms_m"), "timings_s": rep.get("timings_s")}
    out["within_sigmas"] = bool(all(v < 1.5 for v in out["normalised_rms"].values())
                                and all(v >= 0.98 for v in out["within_3_sigma_share"].values()))
    return out


def _aerotri(args: list, pythonpath: str | None = None, log: Path | None = None) -> dict:
    """``aerotri ARGS`` in a child process under ``/usr/bin/time -v``: wall, CPU, peak RSS, its output; ``log``: its
    console (stderr) written there as it runs (a long run can be followed)."""
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    code = "import sys; from aerotri.cli import main; sys.argv[0] = 'aerotri'; sys.exit(main())"
    load = os.getloadavg()[0]
    # -P: without it ``python -c`` puts the working directory first on sys.path, ahead of PYTHONPATH, and a run from a
    # checkout's root imports that checkout's aerotri instead of the other tree's
    cmd = ["/usr/bin/time", "-v", sys.executable, *(["-P"] if pythonpath else []), "-c", code, *args]
    if log is None:
        p = subprocess.run(cmd, capture_output=True, text=True, env=env)
        stderr = p.stderr
    else:
        with open(log, "w") as f:
            p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=f, text=True, env=env)
        stderr = Path(log).read_text()
    if p.returncode != 0:
        raise RuntimeError(f"aerotri {' '.join(args)} failed ({p.returncode}):\n{p.stdout}\n{stderr[-4000:]}")
    res = _time_v(stderr)
    res["stdout"] = p.stdout.strip().splitlines()
    res["robust_rounds"] = [ln for ln in stderr.splitlines() if ln.startswith("robust round")]
    res["load_average_1min"] = [round(load, 2), round(os.getloadavg()[0], 2)]  # before, after: the machine is shared
    return res


def run_adjust(root: Path, pythonpath: str | None = None, log: Path | None = None) -> dict:
    """``aerotri adjust ROOT --dem ROOT/dem.tif --no-exports``, then ``aerotri export ROOT`` (the PATB and COLMAP
    files ``aerotri adjust`` writes without --no-exports), each timed on its own; ``log``: the adjust's console."""
    res = _aerotri(["adjust", str(root), "--dem", str(root / "dem.tif"), "--no-exports"], pythonpath, log)
    res["export"] = _aerotri(["export", str(root)], pythonpath)
    res["export"]["stdout"] = f"{len(res['export']['stdout'])} files written"
    return res


def record(out: Path, size: int, label: str, entry: dict) -> None:
    doc = json.loads(out.read_text()) if out.exists() else {}
    doc.setdefault("blocks", {}).setdefault(str(size), {})[label] = entry
    doc["machine"] = {"cores": os.cpu_count(), "note": "2 cores shared with other jobs: wall is at their mercy, CPU less so"}
    doc["command"] = "aerotri adjust P --dem P/dem.tif --no-exports; aerotri export P (bench/adjust_scale.py run)"
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make")
    m.add_argument("root", type=Path)
    m.add_argument("--frames", type=int, default=300)
    m.add_argument("--points-per-image", type=int, default=POINTS_PER_IMAGE)
    m.add_argument("--no-self-cal", action="store_true")
    r = sub.add_parser("run")
    r.add_argument("root", type=Path)
    r.add_argument("--label", default="after")
    r.add_argument("--pythonpath", default=None)
    r.add_argument("--out", type=Path, default=Path("bench/results/adjust_scale.json"))
    r.add_argument("--log", type=Path, default=None, help="write the adjust's console there as it runs")
    a_ = sub.add_parser("all")
    a_.add_argument("root", type=Path)
    a_.add_argument("--sizes", type=int, nargs="+", default=[300, 1000, 3000, 10000])
    a_.add_argument("--label", default="after")
    a_.add_argument("--pythonpath", default=None)
    a_.add_argument("--out", type=Path, default=Path("bench/results/adjust_scale.json"))
    a = ap.parse_args(argv)
    if a.cmd == "make":
        print(json.dumps(make_block(a.root, a.frames, points_per_image=a.points_per_image,
                                    self_calibration=not a.no_self_cal), indent=1))
        return
    todo = [a.root] if a.cmd == "run" else []
    if a.cmd == "all":
        for size in a.sizes:
            root = a.root / f"b{size}"
            if not (root / "block.json").exists():
                print(f"making {root}", flush=True)
                make_block(root, size)
            todo.append(root)
    for root in todo:
        block = _block_summary(root)
        res = run_adjust(root, a.pythonpath, getattr(a, "log", None))
        res["truth"] = check_truth(root)
        res["block"] = block
        print(json.dumps({k: v for k, v in res.items() if k != "block"}, indent=1), flush=True)
        record(a.out, block["frames"], a.label, res)


if __name__ == "__main__":
    main()
