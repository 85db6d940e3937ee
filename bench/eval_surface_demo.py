"""Surface control on the simulator's demo block: the final adjustment with corners only, surface (DEM) only,
corners plus surface, surface with the roof planes (DEM + roof planes) only, corners plus DEM plus roof planes,
against the surveyed targets (check points) of the simulator's truth.

Runs on a project that ``make demo`` (``aerotri run``) has taken through the control transfer (LiDAR DEM,
nDSM, roof planes, transferred corners). Each variant adjusts a copy of the project (GNSS with shift corrections per
strip when corners are used, no corrections for surface only); the check points are the simulator's
surveyed targets (``truth/checkpoints.csv`` and their image points, added to the copy as check points, never
control). Writes ``bench/results/surface_demo.json``.

    .venv/bin/python bench/eval_surface_demo.py [--project out/demo/project]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.adjust.pipeline import adjust_project  # noqa: E402
from aerotri.adjust.settings import AdjustSettings  # noqa: E402
from aerotri.core.project import Project  # noqa: E402


def _with_targets(root: Path, corners_as_check: bool) -> None:
    """Add the truth's surveyed targets to control/ as check points (never control); with
    ``corners_as_check`` the transferred LiDAR corners become check points too (a block without control)."""
    import csv

    pts = root / "control" / "points.csv"
    rows = list(csv.DictReader(open(pts)))
    if corners_as_check:
        for r in rows:
            r["kind"] = "check"
    seen = {r["point_id"] for r in csv.DictReader(open(root / "truth" / "checkpoint_image_points.csv"))}
    for r in csv.DictReader(open(root / "truth" / "checkpoints.csv")):
        if r["id"] not in seen:  # a target no frame sees
            continue
        rows.append(dict(id=r["id"], kind="check", x=r["x"], y=r["y"], z=r["z"], sx_m="0.01", sy_m="0.01", sz_m="0.01"))
    with open(pts, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["id", "kind", "x", "y", "z", "sx_m", "sy_m", "sz_m"])
        w.writeheader()
        w.writerows(rows)
    with open(root / "control" / "image_points.csv", "a") as f, open(root / "truth" / "checkpoint_image_points.csv") as g:
        next(g)
        f.write(g.read())


def _target_errors(ba, root: Path) -> dict:
    """Check-point errors (adjusted - surveyed) at the truth's targets."""
    import csv

    ids = {r["id"] for r in csv.DictReader(open(root / "truth" / "checkpoints.csv"))}
    d = np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for k, c in ba.check.items() if k in ids])
    d = d[np.isfinite(d).all(axis=1)]  # targets with fewer than two rays are not intersected
    return dict(n=len(d), rms_xy_m=float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))),
                rms_z_m=float(np.sqrt(np.mean(d[:, 2] ** 2))), mean_z_m=float(np.mean(d[:, 2])))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--project", type=Path, default=REPO / "out" / "demo" / "project")
    ap.add_argument("--results", type=Path, default=REPO / "bench" / "results" / "surface_demo.json")
    ap.add_argument("--vce", action="store_true", help="also each variant with variance-component reweighting")
    a = ap.parse_args()
    src = a.project
    p = Project.open(src)
    gsd = json.loads((src / "truth" / "truth.json").read_text())["gsd_m"]
    base = AdjustSettings(gnss_correction="shift", self_calibration=("pp", "radial"), point_covariances=False)
    variants = {
        "corners_only": dataclasses.replace(base),
        "surface_only": dataclasses.replace(base, gnss_correction="none", dem=p.dem_path, ndsm=p.ndsm_path),
        "corners_and_surface": dataclasses.replace(base, dem=p.dem_path, ndsm=p.ndsm_path),
        # the LiDAR roof planes next to the DEM (lidarctl corners' roof_planes.geojson)
        "surface_planes_only": dataclasses.replace(base, gnss_correction="none", dem=p.dem_path, ndsm=p.ndsm_path,
                                                   planes=p.roof_planes_path),
        "corners_and_surface_planes": dataclasses.replace(base, dem=p.dem_path, ndsm=p.ndsm_path,
                                                          planes=p.roof_planes_path),
    }
    if a.vce:
        variants.update({f"{k}_vce": dataclasses.replace(v, point_covariances=True, variance_components=True)
                         for k, v in list(variants.items())})
    out = {"project": str(src), "gsd_m": gsd, "variants": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name, st in variants.items():
            root = Path(tmp) / name
            shutil.copytree(src, root, symlinks=True, ignore=shutil.ignore_patterns("ortho", "reports"))
            _with_targets(root, corners_as_check=name.startswith("surface"))
            t0 = time.perf_counter()
            ba = adjust_project(root, st)
            row = _target_errors(ba, root) | {"seconds": round(time.perf_counter() - t0, 1),
                                                      "sigma0": float(ba.result.sigma0),
                                                      "tie_residual_rms_px": float(np.sqrt(np.mean(
                                                          ba.result.residual_px[ba.result.obs_active] ** 2))),
                                                      "control_points": int(ba.result.control_active.sum())}
            if ba.result.surface is not None:
                row["surface"] = dataclasses.asdict(ba.result.surface)
            if ba.result.weight_factors:
                row["weight_factors"] = ba.result.weight_factors
            row["rms_xy_gsd"], row["rms_z_gsd"] = row["rms_xy_m"] / gsd, row["rms_z_m"] / gsd
            out["variants"][name] = row
            print(f"{name:22s} check targets n={row['n']} plan {row['rms_xy_m']:.3f} m, height {row['rms_z_m']:.3f} m "
                  f"(mean {row['mean_z_m']:+.3f}) = {row['rms_xy_gsd']:.2f} / {row['rms_z_gsd']:.2f} GSD")
    a.results.write_text(json.dumps(out, indent=1, default=str) + "\n")
    print(f"-> {a.results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
