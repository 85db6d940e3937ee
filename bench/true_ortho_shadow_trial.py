"""The LiDAR's shadow in the true ortho's occlusion DSM (issue 42, i42-shadow2): ``bench/true_ortho_shadow_rule.py``'s cells
(empty in local point spacings, touching seen ground, the line to the scanner blocked, not in a crown disk) at the
DEM, the frames rectified again on it (the same footprints and crowns.gpkg) and mosaicked, into a copy:

    python bench/true_ortho_shadow_trial.py --work DIR --block demo7 --source SEED7_PROJECT
        --classified 'SEED7_PROJECT/lidar_out/classified/*.laz' --into DIR2 --radius-spacings 1.14 --variant shadow2

as ``bench/true_ortho_empty_cells_trial.py`` (the reverted rule's trial; DIR the folders of
``eval_true_ortho_dsm_cell.py``); DIR2/<block>/true_ortho_dsm_<spec>+<variant> is then measured by
``eval_true_ortho_fill_causes.py``. Records what the rule lowered against the simulator's truth (the scene's kind at
each lowered cell's centre: terrain, roof, tree), so roof pits are counted: ``--no-rectify`` stops there.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))


def first_returns(classified: str):
    """The first returns (noise out) of the strips: x, y, z, gps time, point source, scan angle (degrees)."""
    import laspy

    from lidarctl.rasters.nearest import first_return_mask
    from lidarctl.strips.overlap import scan_angle_deg

    cols = []
    for q in sorted(glob.glob(classified)):
        las = laspy.read(q)
        m = first_return_mask(np.asarray(las.classification), np.asarray(las.return_number))
        cols.append([np.asarray(las.x)[m], np.asarray(las.y)[m], np.asarray(las.z)[m],
                     np.asarray(las.gps_time)[m], np.asarray(las.point_source_id)[m], scan_angle_deg(las)[m]])
    if not cols:
        raise SystemExit(f"--classified {classified}: no LAS/LAZ files")
    return [np.concatenate(c) for c in zip(*cols)]


def crown_mask(crowns_path, transform, shape) -> np.ndarray:
    """Cells whose centre lies in a crown disk of crowns.gpkg."""
    import pyogrio

    import true_ortho_shadow_rule as shadow

    meta, _, _, fields = pyogrio.raw.read(str(crowns_path), read_geometry=False, columns=["x_m", "y_m", "radius_m"])
    col = {n: np.asarray(fields[list(meta["fields"]).index(n)], float) for n in ("x_m", "y_m", "radius_m")}
    return shadow.disk_cells(col["x_m"], col["y_m"], col["radius_m"], shape, x0_m=transform.c, y_top_m=transform.f,
                             res_m=transform.a)


def apply_rule(D, dem, T, nodata, classified, crowns, radius_spacings):
    import true_ortho_shadow_rule as shadow

    x, y, z, t, sid, ang = first_returns(classified)
    scan, missing = shadow.scan_geometry(x, y, t, sid, ang)
    f = lambda a: np.where(a == nodata, np.nan, a).astype(float)  # noqa: E731
    Df, demf = f(D), f(dem)
    keep = crown_mask(crowns, T, D.shape) if crowns else None
    cells = shadow.shadow_cells(Df, demf, x0_m=T.c, y_top_m=T.f, res_m=T.a, x_m=x, y_m=y, z_m=z, scan=scan,
                                keep=keep, radius_spacings=radius_spacings, strips_without_line=missing)
    return cells, Df, demf, keep


def truth_kinds(work_block: Path, T, rows, cols):
    import eval_true_ortho_occlusion as E
    from aerotri.sim.scene import KIND_ROOF, KIND_TERRAIN, KIND_TREE

    truth = E.Truth(work_block / "conventional")
    X, Y = T.c + (cols + 0.5) * T.a, T.f + (rows + 0.5) * T.e
    k, _, _ = truth.surface(X - truth.origin[0], Y - truth.origin[1])
    return {"terrain": int((k == KIND_TERRAIN).sum()), "roof": int((k == KIND_ROOF).sum()),
            "tree": int((k == KIND_TREE).sum())}


def main() -> None:
    import rasterio

    import eval_true_ortho_occlusion as E

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True, help="the folders of eval_true_ortho_dsm_cell.py")
    ap.add_argument("--block", required=True)
    ap.add_argument("--spec", default="lidar+occn+fp10+crowns")
    ap.add_argument("--source", type=Path, required=True, help="the block's project (its images)")
    ap.add_argument("--classified", required=True, help="a glob of the block's classified strips")
    ap.add_argument("--into", type=Path, required=True)
    ap.add_argument("--radius-spacings", type=float, default=None, help="shadow.EMPTY_RADIUS_SPACINGS if not given")
    ap.add_argument("--spacing-block-m", type=float, default=None,
                    help="the block the local spacing is pooled over (shadow.SPACING_BLOCK_M if not given)")
    ap.add_argument("--variant", required=True)
    ap.add_argument("--no-rectify", action="store_true", help="only what the rule lowers (the truth's kinds)")
    a = ap.parse_args()
    import true_ortho_shadow_rule as shadow

    k_sp = shadow.EMPTY_RADIUS_SPACINGS if a.radius_spacings is None else a.radius_spacings
    if a.spacing_block_m is not None:
        shadow.SPACING_BLOCK_M = a.spacing_block_m
    dst = a.into / a.block
    dst.mkdir(parents=True, exist_ok=True)
    for n in ("conventional", "truth_on_grid.npz", "surface_clearance.npz"):
        if not (dst / n).exists():
            os.symlink((a.work / a.block / n).resolve(), dst / n)
    orig = a.work / a.block / f"true_ortho_dsm_{a.spec}"
    index = json.loads((orig / "ortho" / "frames" / "index.json").read_text())

    def recorded(key):  # recorded relative to the harness's folder, or absolute
        q = Path(index[key])
        return q if q.is_absolute() or q.exists() else a.work.parent / q

    occ, crowns = recorded("occlusion_dsm"), recorded("crowns")
    with rasterio.open(occ) as ds:
        D, profile, T, nodata = ds.read(1), ds.profile, ds.transform, ds.nodata
    for f in (orig / "lidar_out" / "dem.tif", a.work / a.block / "lidar_rasters" / "dem.tif"):
        if f.exists():
            with rasterio.open(f) as ds:
                if ds.transform == T and ds.shape == D.shape:
                    dem = ds.read(1)
                    break
    else:
        raise SystemExit(f"no DEM on the grid of {occ}")
    cells, Df, demf, keep = apply_rule(D, dem, T, nodata, a.classified, crowns, k_sp)
    low = cells.lower
    drop = np.where(low, Df - demf, 0)
    big = low & (drop > 2)
    rr, cc = np.nonzero(big)
    record = {"radius_spacings": k_sp, "spacing_block_m": shadow.SPACING_BLOCK_M, "occlusion_dsm": str(occ), "cells": int(D.size),
              "spacing_m_5_50_95": [round(float(v), 4) for v in np.nanpercentile(cells.spacing_m, [5, 50, 95])],
              "empty": int(cells.empty.sum()), "empty_touching_seen_ground": int(cells.touches_ground.sum()),
              "blocked_towards_scanner": int(cells.blocked.sum()),
              "in_crown_disks_kept": int((cells.touches_ground & cells.blocked & keep).sum()) if keep is not None else 0,
              "lowered": int(low.sum()), "lowered_by_more_than_2m": int(big.sum()),
              "strips_without_flight_line": list(cells.strips_without_line)}
    if (a.work / a.block / "conventional").exists():
        record["lowered_by_more_than_2m_truth_kind"] = truth_kinds(a.work / a.block, T, rr, cc)
    print(a.block, a.variant, json.dumps(record), flush=True)
    p = dst / f"true_ortho_dsm_{a.spec}+{a.variant}"
    shutil.rmtree(p, ignore_errors=True)
    shutil.copytree(orig, p, ignore=shutil.ignore_patterns("ortho", "images", "work"))
    new = p / "lidar_out" / "dsm_crowns_shadow.tif"
    D2 = D.copy()
    D2[low] = dem[low]
    with rasterio.open(new, "w", **profile) as ds:
        ds.write(D2, 1)
    if a.no_rectify:
        (p / "made.json").write_text(json.dumps({"shadow_trial": record}, indent=1) + "\n")
        return
    os.symlink((a.source / "images").resolve(), p / "images")
    eo = recorded("eo").resolve()  # the project's own (at/eo.txt) or the truth's (a tall block's)
    eo = p / eo.relative_to(orig.resolve()) if eo.is_relative_to(orig.resolve()) else eo
    camera = index.get("inputs", {}).get("camera", {}).get("file")  # a camera given (a tall block's truth's)
    if camera:
        camera = Path(camera) if Path(camera).is_absolute() else a.work.parent / camera
    made = E.make_dom(p, True, eo_path=eo, camera_path=camera, footprints=p / "truth" / "footprints.gpkg",
                      occlusion_dsm=new, crowns=crowns)
    made["shadow_trial"] = record
    (p / "made.json").write_text(json.dumps(made, indent=1, default=str) + "\n")
    os.unlink(p / "images")
    print(a.block, a.variant, json.dumps(made["rectify"]), flush=True)


if __name__ == "__main__":
    main()
