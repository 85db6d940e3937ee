"""A trial (issue 42, not the product's way yet): the true ortho's occlusion DSM with its *empty* cells, those with
no first return within ``--radius-spacings`` point spacings of their centre, at the DEM's height instead of the
nearest return's.

Beside a wall the scanner does not see the ground behind it (the LiDAR's shadow); the nearest-return DSM
(``lidarctl.rasters.nearest``, and the crown model's dsm_crowns.tif cut from it) stands the shadow's cells at the
roof's height up to half way to the first ground return, and a camera's line of sight that clears the real wall
is stopped there (``bench/eval_true_ortho_clear_lines.py``). Here those cells take the DEM where it is lower; the
project's frames are rectified again on that DSM (the same footprints and crowns.gpkg) and mosaicked, into a copy:

    python bench/true_ortho_empty_cells_trial.py --work DIR --block demo7 --source SEED7_PROJECT
        --classified 'SEED7_PROJECT/lidar_out/classified/*.laz' --into DIR2 --radius-spacings 1.14 --variant empty114

DIR2/<block>/true_ortho_dsm_<spec>+<variant> is then measured by ``eval_true_ortho_fill_causes.py --work DIR2
--block <block> --specs '<spec>+<variant>'`` (DIR2/<block> links the block's truth from DIR). ``--radius-spacings 0``:
the occlusion DSM unchanged (the same frames made again, to check the comparison). The DEM: the project's
lidar_out/dem.tif, or ``DIR/<block>/lidar_rasters/dem.tif`` (a tall block's), the one on the DSM's grid.
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

NOISE = (7, 18)


def empty_cells(classified: str, transform, shape: tuple[int, int], spacings: float) -> tuple[np.ndarray, float, float]:
    """True at the cells of the grid (``transform``, ``shape``) with no first return (noise left out) within
    ``spacings`` times the returns' point spacing (their bounding box's area over their count, as the crown model
    takes it) of their centre; the spacing and the radius (m)."""
    import laspy
    from scipy.spatial import cKDTree

    xy = []
    for q in sorted(glob.glob(classified)):
        las = laspy.read(q)
        m = (np.asarray(las.return_number) == 1) & ~np.isin(np.asarray(las.classification), NOISE)
        xy.append(np.c_[np.asarray(las.x)[m], np.asarray(las.y)[m]])
    if not xy:
        raise SystemExit(f"--classified {classified}: no LAS/LAZ files")
    xy = np.vstack(xy)
    spacing_m = float(np.sqrt(np.prod(xy.max(0) - xy.min(0)) / len(xy)))
    radius_m = spacings * spacing_m
    kd = cKDTree(xy)
    H, W = shape
    out = np.zeros(shape, bool)
    cx = transform.c + (np.arange(W) + 0.5) * transform.a
    for r in range(0, H, 256):
        rows = np.arange(r, min(r + 256, H))
        X, Y = np.meshgrid(cx, transform.f + (rows + 0.5) * transform.e)
        d, _ = kd.query(np.c_[X.ravel(), Y.ravel()], distance_upper_bound=radius_m)
        out[rows] = ~np.isfinite(d).reshape(len(rows), W)
    return out, spacing_m, radius_m


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
    ap.add_argument("--radius-spacings", type=float, required=True,
                    help="the empty cells' radius in point spacings (0: the occlusion DSM unchanged)")
    ap.add_argument("--variant", required=True)
    a = ap.parse_args()
    dst = a.into / a.block
    dst.mkdir(parents=True, exist_ok=True)
    for n in ("conventional", "truth_on_grid.npz", "surface_clearance.npz"):
        if not (dst / n).exists():
            os.symlink((a.work / a.block / n).resolve(), dst / n)
    orig = a.work / a.block / f"true_ortho_dsm_{a.spec}"
    p = dst / f"true_ortho_dsm_{a.spec}+{a.variant}"
    shutil.rmtree(p, ignore_errors=True)
    shutil.copytree(orig, p, ignore=shutil.ignore_patterns("ortho", "images", "work"))
    os.symlink((a.source / "images").resolve(), p / "images")
    index = json.loads((orig / "ortho" / "frames" / "index.json").read_text())

    def recorded(key):  # recorded relative to the harness's folder, or absolute
        q = Path(index[key])
        return q if q.is_absolute() or q.exists() else a.work.parent / q

    occ, crowns = recorded("occlusion_dsm"), recorded("crowns")
    new = occ
    record = {"radius_spacings": a.radius_spacings, "occlusion_dsm": str(occ)}
    if a.radius_spacings > 0:
        with rasterio.open(occ) as ds:
            D, profile, T, nodata = ds.read(1), ds.profile, ds.transform, ds.nodata
        for f in (p / "lidar_out" / "dem.tif", a.work / a.block / "lidar_rasters" / "dem.tif"):
            if f.exists():
                with rasterio.open(f) as ds:
                    if ds.transform == T and ds.shape == D.shape:
                        dem = ds.read(1)
                        break
        else:
            raise SystemExit(f"no DEM on the grid of {occ}")
        empty, spacing_m, radius_m = empty_cells(a.classified, T, D.shape, a.radius_spacings)
        lower = empty & (D != nodata) & (dem != nodata) & (dem < D)
        D2 = D.copy()
        D2[lower] = dem[lower]
        new = p / "lidar_out" / "dsm_crowns_empty_at_dem.tif"
        with rasterio.open(new, "w", **profile) as ds:
            ds.write(D2, 1)
        record.update(spacing_m=round(spacing_m, 4), radius_m=round(radius_m, 4), cells=int(D.size),
                      empty=int(empty.sum()), lowered=int(lower.sum()),
                      lowered_by_more_than_2m=int((lower & (D - dem > 2)).sum()))
    eo = recorded("eo").resolve()  # the project's own (at/eo.txt) or the truth's (a tall block's)
    eo = p / eo.relative_to(orig.resolve()) if eo.is_relative_to(orig.resolve()) else eo
    camera = index.get("inputs", {}).get("camera", {}).get("file")  # a camera given (a tall block's truth's)
    if camera:
        camera = Path(camera) if Path(camera).is_absolute() else a.work.parent / camera
    made = E.make_dom(p, True, eo_path=eo, camera_path=camera, footprints=p / "truth" / "footprints.gpkg",
                      occlusion_dsm=new, crowns=crowns)
    made["empty_cells_trial"] = record
    (p / "made.json").write_text(json.dumps(made, indent=1, default=str) + "\n")
    os.unlink(p / "images")
    print(a.block, a.variant, json.dumps(record), json.dumps(made["rectify"]), flush=True)


if __name__ == "__main__":
    main()
