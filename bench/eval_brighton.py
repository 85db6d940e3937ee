"""Real data: the Brighton Beach drone block (../shared/data/brighton_beach, 18 DJI FC300S frames, EXIF GNSS,
no control) self-calibrated with and without the DEM of its own point cloud -> bench/results/brighton.json.

Issue 39: ``aerotri adjust P --self-cal focal,pp,radial`` took the focal length from 2121 to 2841 px (+34 %,
reported sigma 14 px), put the tie points 10.5 m below the DEM of the block's ODM point cloud and said
"Solution Successful". Flat terrain, near-nadir frames and a datum from GNSS alone confound the focal
length with the flying height; this script shows what the adjustment says now. Steps, as a user runs them:

1. ``aerotri import P --format exif images/`` (a project with ``[project] crs = "EPSG:32615"`` and the frames
   linked into ``images/``): GNSS positions, gimbal attitudes and the camera from EXIF (the pixel size from
   the FC300S's sensor width, 6.16 mm / 4000 px: 2344 px, where the 35 mm equivalent gave 2121 px);
2. ``aerotri match P --terrain-height-m 158.5`` (the EXIF altitude minus the height above take-off);
3. the DEM and nDSM of ``model.laz`` (the ODM point cloud, a peer's product, not truth):
   ``lidarctl classify model.laz cls.laz`` and ``lidarctl rasters cls.laz lidar --res-m 0.5``;
4. adjustments (library ``aerotri.adjust.pipeline.run_adjustment``, as ``aerotri adjust``), each with
   ``--self-cal focal,pp,radial``:
   - ``no_dem``: nothing else (the issue's run);
   - ``no_dem_check``: the same with the DEM as a check only (``[adjust] check_dem``, with the nDSM): the
     tie points against the DEM fail the solution beyond 3 sigma;
   - ``dem``: the DEM and nDSM as surface control (``--dem --ndsm``);
5. measures per run: the verdict and message, the focal length a priori / adjusted / refused, each group's
   determinability (correlations, corner sigma), tie point height - DEM height (median, NMAD, count; the
   adjusted tie points of ``at/object_points.csv`` on the ground by the nDSM (< 1 m), bilinear DEM sample,
   measured here independently of the adjustment's own check), sigma naught, seconds.

``--before FILE``: the same numbers measured on main before this change (recorded, not reproduced here).

Usage: python bench/eval_brighton.py [--data $AEROTRI_SHARED_DATA/brighton_beach, default ../shared/data/...] [--out /tmp/brighton]
       [--results bench/results/brighton.json] [--reuse]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

TERRAIN_HEIGHT_M = 158.5  # exif_positions.csv: abs_alt_m - rel_alt_m (the take-off point)
GROUPS = ("focal", "pp", "radial")


def run(cmd_main, args: list[str]) -> None:
    from click.testing import CliRunner

    r = CliRunner().invoke(cmd_main, args, catch_exceptions=False)
    if r.exit_code != 0:
        raise SystemExit(f"{' '.join(args)}: exit {r.exit_code}\n{r.output}")


def tie_minus_dem(points_csv: Path, dem: Path, ndsm: Path) -> dict:
    """Tie point height - DEM height at the tie points on the ground (nDSM < 1 m), bilinear DEM sample."""
    import rasterio

    rows = np.genfromtxt(points_csv, delimiter=",", names=True, dtype=None, encoding="utf-8")
    rows = rows[rows["kind"] == "tie"]
    xyz = np.column_stack([rows["x"], rows["y"], rows["z"]])
    with rasterio.open(dem) as d, rasterio.open(ndsm) as n:
        z = _bilinear(d, xyz[:, 0], xyz[:, 1])
        nd = _bilinear(n, xyz[:, 0], xyz[:, 1])
    ok = np.isfinite(z) & np.isfinite(nd) & (nd < 1.0)
    e = xyz[ok, 2] - z[ok]
    med = float(np.median(e))
    return {"n": int(ok.sum()), "median_m": round(med, 4), "nmad_m": round(float(1.4826 * np.median(np.abs(e - med))), 4)}


def _bilinear(ds, x, y) -> np.ndarray:
    a = ds.read(1).astype(float)
    if ds.nodata is not None:
        a[a == ds.nodata] = np.nan
    inv = ~ds.transform
    c, r = inv * (np.asarray(x), np.asarray(y))
    c, r = c - 0.5, r - 0.5
    c0, r0 = np.floor(c).astype(int), np.floor(r).astype(int)
    fc, fr = c - c0, r - r0
    out = np.full(len(c), np.nan)
    ok = (c0 >= 0) & (r0 >= 0) & (c0 + 1 < a.shape[1]) & (r0 + 1 < a.shape[0])
    i, j, u, v = r0[ok], c0[ok], fc[ok], fr[ok]
    out[ok] = (a[i, j] * (1 - u) * (1 - v) + a[i, j + 1] * u * (1 - v) + a[i + 1, j] * (1 - u) * v
               + a[i + 1, j + 1] * u * v)
    return out


def measure(name: str, root: Path, lidar: Path, settings) -> dict:
    from aerotri.adjust.pipeline import run_adjustment
    from aerotri.core.errors import SolveError

    t = time.perf_counter()
    failed = None
    try:
        res = run_adjustment(root, settings, html=False)
        ba, rep = res.adjustment, json.loads(res.report_path.read_text())
    except SolveError as exc:
        failed = str(exc)
        rep = json.loads((root / "work" / "adjust_failed" / "report.json").read_text())
        ba = None
    seconds = time.perf_counter() - t
    ks = rep["key_statistics"]
    sc = rep["self_calibration"] or {}
    out = {"seconds": round(seconds, 1), "verdict": ks["verdict"], "message": ks["message"],
           "sigma0_px": ks["sigma0_px"], "points_behind_camera": ks.get("points_behind_camera"),
           "focal_px": {"apriori": round(0.5 * (sc["apriori"]["fx_px"] + sc["apriori"]["fy_px"]), 2),
                        "adjusted": round(0.5 * (sc["adjusted"]["fx_px"] + sc["adjusted"]["fy_px"]), 2)},
           "estimated": sc.get("estimated"), "fixed": sc.get("fixed"),
           "determinability": [{k: c.get(k) for k in ("group", "action", "estimate", "sigma", "correlations",
                                                      "corner_sigma_px", "corner_sigma_fraction", "sigma_fraction",
                                                      "gnss_height_fraction", "image_field_fraction", "reason")}
                               for c in sc.get("determinability") or []],
           "geometry_modes": [{k: g[k] for k in ("mode", "sigma_m", "shares", "weak", "correlation_with_height")}
                              for g in rep.get("geometry_modes") or []],
           "dem_checks": rep.get("dem_checks")}
    refused = [c for c in out["determinability"] if c["group"] == "focal" and c["action"] == "fixed"]
    if refused:
        est = refused[0]["estimate"]
        out["focal_px"]["refused_estimate"] = round(0.5 * (est["fx_px"] + est["fy_px"]), 2)
        out["focal_px"]["refused_sigma"] = round(0.5 * sum(refused[0]["sigma"].values()), 2)
    if failed is None:
        out["tie_minus_dem"] = tie_minus_dem(root / "at" / "object_points.csv", lidar / "dem.tif", lidar / "ndsm.tif")
    else:
        out["solve_error"] = failed
    print(f"{name}: {out['verdict']}, focal {out['focal_px']}, tie - DEM {out.get('tie_minus_dem')}, "
          f"{out['seconds']} s", flush=True)
    return out


def main():
    ap = argparse.ArgumentParser()
    shared = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
    ap.add_argument("--data", type=Path, default=shared / "brighton_beach")
    ap.add_argument("--out", type=Path, default=Path("/tmp/eval_brighton"))
    ap.add_argument("--results", type=Path, default=REPO / "bench" / "results" / "brighton.json")
    ap.add_argument("--before", type=Path, default=None, help="JSON of the numbers measured on main before")
    ap.add_argument("--reuse", action="store_true", help="keep the matched project and the DEM of an earlier run")
    args = ap.parse_args()
    from aerotri.adjust.settings import AdjustSettings
    from aerotri.cli import main as aerotri_cli
    from aerotri.geom.camera import read_camera
    from lidarctl.cli.main import main as lidar_cli

    out, res = args.out, {"data": "brighton_beach", "timings_s": {}}
    root, lidar = out / "project", out / "lidar"
    matched = out / "matched"
    if not (args.reuse and (matched / "at" / "tiepoints.csv").exists()):
        shutil.rmtree(out, ignore_errors=True)
        matched.mkdir(parents=True)
        (matched / "project.toml").write_text('[project]\nname = "brighton"\ncrs = "EPSG:32615"\n')
        (matched / "images").symlink_to(args.data / "images")
        t = time.perf_counter()
        run(aerotri_cli, ["import", str(matched), "--format", "exif", str(matched / "images")])
        res["timings_s"]["import"] = round(time.perf_counter() - t, 1)
        t = time.perf_counter()
        run(aerotri_cli, ["match", str(matched), "--terrain-height-m", str(TERRAIN_HEIGHT_M)])
        res["timings_s"]["match"] = round(time.perf_counter() - t, 1)
        t = time.perf_counter()
        run(lidar_cli, ["classify", str(args.data / "model.laz"), str(out / "model_classified.laz"), "-q"])
        run(lidar_cli, ["rasters", str(out / "model_classified.laz"), str(lidar), "--res-m", "0.5", "-q"])
        res["timings_s"]["dem_from_model_laz"] = round(time.perf_counter() - t, 1)
    cam = read_camera(matched / "camera.toml")
    res["camera_apriori"] = {"focal_px": round(cam.focal_px, 2), "pixel_um": cam.pixel_um, "name": cam.name,
                             "focal_px_from_35mm_equivalent": 2121.45}
    base = AdjustSettings(self_calibration=GROUPS)
    runs = {"no_dem": base,
            "no_dem_check": dataclasses.replace(base, check_dem=lidar / "dem.tif", ndsm=lidar / "ndsm.tif"),
            "dem": dataclasses.replace(base, dem=lidar / "dem.tif", ndsm=lidar / "ndsm.tif")}
    res["runs"] = {}
    for name, st in runs.items():
        shutil.rmtree(root, ignore_errors=True)
        shutil.copytree(matched, root, symlinks=True, ignore=shutil.ignore_patterns("work"))
        res["runs"][name] = measure(name, root, lidar, st)
    if args.before is not None:
        res["before_main"] = json.loads(args.before.read_text())
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(res, indent=1) + "\n")
    print(f"-> {args.results}")


if __name__ == "__main__":
    main()
