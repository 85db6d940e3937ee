"""Roof pits of the LiDAR-shadow rule on real data (issue 42, i42-shadow2): AHN3 Delft's occlusion DSM
(``lidarctl rasters``' dsm_nearest.tif, 0.5 m) with ``bench/true_ortho_shadow_rule.py``'s cells at the DEM, against the
160 surveyed BGT building footprints: the cells at least ``INSIDE_M`` inside a footprint that the rule lowers by
more than 2 m (roofs that returned no pulse; the target is 0). The reverted rule (i42-shadow: no first return within
1.14 bounding-box point spacings) beside it.

    lidarctl rasters /work/shared/data/ahn3_delft/ahn3_cropped_1.laz DIR --res-m 0.5 --crs EPSG:28992
    python bench/eval_shadow_ahn3.py --rasters DIR [--key shadow2_ahn3]

Writes bench/results/true_ortho_fill.json key ``--key`` (the other keys kept).
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from results_json import git_commit, store_result  # noqa: E402

DATA = Path("/work/shared/data/ahn3_delft")
INSIDE_M = 2.0
DROP_M = 2.0


def main() -> None:
    import laspy
    import rasterio
    import shapely.wkb
    from rasterio.features import rasterize
    from scipy import ndimage
    from scipy.spatial import cKDTree

    import true_ortho_shadow_rule as shadow
    from lidarctl.rasters.nearest import first_return_mask
    from lidarctl.strips.overlap import scan_angle_deg

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rasters", type=Path, required=True, help="lidarctl rasters' output folder of the AHN3 crop")
    ap.add_argument("--key", default="shadow2_ahn3")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_fill.json")
    a = ap.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"{DATA}: the AHN3 Delft reference data is not here")
    rd = lambda p: rasterio.open(p).read(1, masked=True).astype(float).filled(np.nan)  # noqa: E731
    D, dem = rd(a.rasters / "dsm_nearest.tif"), rd(a.rasters / "dem.tif")
    T = rasterio.open(a.rasters / "dsm_nearest.tif").transform
    las = laspy.read(DATA / "ahn3_cropped_1.laz")
    m = first_return_mask(np.asarray(las.classification), np.asarray(las.return_number))
    x, y, z = np.asarray(las.x)[m], np.asarray(las.y)[m], np.asarray(las.z)[m]
    scan, missing = shadow.scan_geometry(x, y, np.asarray(las.gps_time)[m], np.asarray(las.point_source_id)[m],
                                         scan_angle_deg(las)[m])
    con = sqlite3.connect(DATA / "bgt_pand.sqlite")
    polys = [shapely.wkb.loads(g) for (g,) in con.execute("select GEOMETRY from buildingpart")]
    inside = rasterize([(p, 1) for p in polys], out_shape=D.shape, transform=T).astype(bool)
    inner = ndimage.binary_erosion(inside, iterations=int(round(INSIDE_M / T.a)))

    def score(low):
        drop = np.where(low, D - dem, 0.0)
        pit = low & inner & (drop > DROP_M)
        return {"lowered": int(low.sum()), "lowered_by_more_than_2m": int((low & (drop > DROP_M)).sum()),
                "inside_bgt_2m_lowered_by_more_than_2m": int(pit.sum()),
                "inside_bgt_2m_drop_m_median": round(float(np.median(drop[pit])), 2) if pit.any() else None}

    out = {"radius_spacings": {}, "reverted_rule_1.14_bbox_spacings": None}
    # the reverted rule: no first return within 1.14 spacings of the bounding box
    sp = float(np.sqrt((np.ptp(x) * np.ptp(y)) / len(x)))
    rows, cols = np.mgrid[0:D.shape[0], 0:D.shape[1]]
    cxy = np.column_stack([(T.c + (cols + 0.5) * T.a).ravel(), (T.f + (rows + 0.5) * T.e).ravel()])
    d = cKDTree(np.column_stack([x, y])).query(cxy)[0].reshape(D.shape)
    with np.errstate(invalid="ignore"):
        old = (d > 1.14 * sp) & (dem < D)
    out["reverted_rule_1.14_bbox_spacings"] = dict(score(old), spacing_m=round(sp, 4))
    for k, block_m in ((shadow.EMPTY_RADIUS_SPACINGS, 10.0), (0.8, 10.0), (1.14, 10.0),
                       (shadow.EMPTY_RADIUS_SPACINGS, 30.0)):
        shadow.SPACING_BLOCK_M = block_m
        cells = shadow.shadow_cells(D, dem, x0_m=T.c, y_top_m=T.f, res_m=T.a, x_m=x, y_m=y, z_m=z, scan=scan,
                                    radius_spacings=k, strips_without_line=missing)
        out["radius_spacings"][str(k) if block_m == 10.0 else f"{k}_spacing_block_{block_m:g}m"] = dict(
            score(cells.lower), empty=int(cells.empty.sum()), touching_seen_ground=int(cells.touches_ground.sum()),
            spacing_m_5_50_95=[round(float(v), 3) for v in np.nanpercentile(cells.spacing_m, [5, 50, 95])])
    out["strips_without_flight_line"] = list(missing)
    out["inside_m"], out["drop_m"], out["footprints"] = INSIDE_M, DROP_M, len(polys)
    out["command"] = "python bench/eval_shadow_ahn3.py --rasters DIR (lidarctl rasters ahn3_cropped_1.laz DIR --res-m 0.5 --crs EPSG:28992)"
    out["commit"] = git_commit(REPO)
    print(out)
    store_result(a.out, out, key=a.key)


if __name__ == "__main__":
    main()
