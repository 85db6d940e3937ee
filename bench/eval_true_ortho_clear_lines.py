"""The over-masked misses whose line of sight clears the true 2.5D surface (``eval_true_ortho_fill_causes``'
``over_masked_clears_*``), line by line: which cell of the occlusion DSM stops the line and what the truth and the
LiDAR have there (issue 42, diagnosis).

For each such miss, the line from the ground point (the truth's terrain) to the first seeing frame that clears the
2.5D surface (its true projection centre), walked in 2.5 cm steps over the true-ortho project's occlusion DSM
(``occlusion_dsm`` of its frame index, e.g. the crown model's ``dsm_crowns.tif``, 0.5 m columns): the first cell
whose top stands more than the march's tolerance (0.3 m) above the line where it crosses. That cell:

- ``cell_holds_a_taller_object``: the truth (a 10 x 10 lattice over the cell) has a roof, wall or crown above the line
  somewhere in the cell, the line crosses the cell's ground part: the DSM's cell size (a column over the whole cell);
- ``cell_all_ground``: the truth is terrain over the whole cell, the DSM stands there at an object's height: by the
  block's classified first returns (``--classified``, noise 7/18 left out as ``lidarctl rasters`` does), the nearest
  return to the cell's centre, its class, whether any return lies within 0.5 m of the centre (none: a hole in the
  returns beside a wall or crown, which the nearest-return DSM fills with the roof's or crown's height);
- ``no_dsm_cell``: no cell of the DSM stops the line (the crowns' disks, the footprints' slabs, or the mask's
  margin do).

A what-if on the lines only (not a re-rectification): the DSM's cells with no first return within 0.5 m of their
centre (``--empty-radius-m``) at the DEM's height; how many of the lines then meet no cell of the DSM above them. Usage:

    python bench/eval_true_ortho_clear_lines.py --work DIR --block demo7 --spec 'lidar+occn+fp10+crowns'
        --classified 'SEED7/lidar_out/classified/*.laz' [--key K] [--out JSON]

Writes ``--key`` (``fill_clear_lines`` by default, the 2026-11-30 run), block NAME, of
bench/results/true_ortho_fill.json.
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, read_results, store_result  # noqa: E402

TOLERANCE_M = 0.3  # the march's (ortho.rectify.occlusion_mask)
STEP_M = 0.025
EMPTY_RADIUS_M = 0.5  # a cell with no first return this near its centre: a hole in the returns
NOISE = (7, 18)


def first_returns(pattern: str) -> np.ndarray:
    """(N, 4) x, y, z, class of the first returns of the classified strips ``pattern`` (noise left out)."""
    import laspy

    parts = []
    for q in sorted(glob.glob(pattern)):
        las = laspy.read(q)
        cls = np.asarray(las.classification)
        m = (np.asarray(las.return_number) == 1) & ~np.isin(cls, NOISE)
        parts.append(np.c_[np.asarray(las.x)[m], np.asarray(las.y)[m], np.asarray(las.z)[m], cls[m]])
    if not parts:
        raise SystemExit(f"--classified {pattern}: no LAS/LAZ files")
    return np.vstack(parts)


def pct(v, q=(5, 25, 50, 75, 95)):
    return [round(float(x), 2) for x in np.percentile(v, q)] if len(v) else None


def clear_lines(work: Path, name: str, spec: str, classified: str, empty_radius_m: float = EMPTY_RADIUS_M) -> dict:
    import rasterio
    from scipy.spatial import cKDTree

    import eval_true_ortho_occlusion as E
    from eval_true_ortho_dsm_cell import CLEAR, cached_truth
    from eval_true_ortho_fill import measure_block

    from aerotri.sim.scene import KIND_TERRAIN
    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    project = work / name / f"true_ortho_dsm_{spec}"
    conv = work / name / "conventional"
    grid = OrthoGrid.union(read_index(conv).grids)
    arrays = cached_truth(E, work / name, conv, grid)
    truth = E.Truth(conv)
    cells = {}
    measure_block(work, name, true_ortho=project, truth=truth, truth_arrays=arrays, cells_out=cells)
    codes = np.load(work / name / "surface_clearance.npz")["codes"]
    rr, cc = np.nonzero(cells["over"])
    seeing = codes[:, rr, cc]
    clear = (seeing == CLEAR).any(0)
    k_clear = np.argmax(seeing == CLEAR, 0)
    ids = [e.image_id for e in read_index(conv).frames]
    index = json.loads((project / "ortho" / "frames" / "index.json").read_text())
    occ = project / (index.get("occlusion_dsm") or index["dsm"])  # relative to the project unless absolute
    with rasterio.open(occ) as ds:
        D = ds.read(1).astype(np.float64)
        if ds.nodata is not None:
            D[D == ds.nodata] = np.nan
        T = ds.transform
    dem_path = project / index["dem"]
    dem = None
    for f in (dem_path, work / name / "lidar_rasters" / "dem.tif"):  # the project's, a tall block's LiDAR's
        if f.exists():
            with rasterio.open(f) as ds:
                if ds.transform == T and ds.shape == D.shape:
                    dem = ds.read(1).astype(np.float64)
                    break
    if dem is None:
        raise SystemExit(f"{dem_path}: not on the occlusion DSM's grid")
    pts = first_returns(classified)
    kd = cKDTree(pts[:, :2])
    xs, ys = grid.centres()
    org = truth.origin
    sub = (np.arange(10) + 0.5) / 10
    around = np.arange(-15, 16) * 0.1
    AX, AY = (a.ravel() for a in np.meshgrid(around, around))
    empty_cache: dict = {}

    def empty(r, c):  # no first return within EMPTY_RADIUS_M of the cell's centre
        key = (r, c)
        if key not in empty_cache:
            x, y = T.c + (c + 0.5) * T.a, T.f + (r + 0.5) * T.e
            empty_cache[key] = not kd.query_ball_point((x, y), empty_radius_m)
        return empty_cache[key]

    rows = []
    for i in np.flatnonzero(clear):
        C = truth.centres[ids[k_clear[i]]] + org
        x, y = xs[cc[i]], ys[rr[i]]
        zg = truth.scene.terrain_height(np.array([x - org[0]]), np.array([y - org[1]]))[0] + org[2]
        v = C - np.array([x, y, zg])
        hd = np.hypot(v[0], v[1])
        rise = v[2] / hd
        S = np.arange(1, int((np.nanmax(D) + 1 - zg) / rise / STEP_M) + 2) * STEP_M
        px, py = x + v[0] / hd * S, y + v[1] / hd * S
        col, row = ~T * (px, py)
        row, col = np.floor(row).astype(int), np.floor(col).astype(int)
        ok = (row >= 0) & (row < D.shape[0]) & (col >= 0) & (col < D.shape[1])
        line = zg + rise * S
        ex = np.full(len(S), -np.inf)
        ex[ok] = D[row[ok], col[ok]] - line[ok]
        hits = np.flatnonzero(ex > TOLERANCE_M)
        # the what-if: the cells with no return near their centre at the DEM's height
        ex2 = ex.copy()
        for j in hits:
            if empty(row[j], col[j]):
                ex2[j] = dem[row[j], col[j]] - line[j]
        frees = bool(len(hits)) and not (ex2 > TOLERANCE_M).any()
        if not len(hits):
            rows.append(dict(blocked=False, frees=False, rise=rise))
            continue
        m = int(hits[0])
        r0, c0 = row[m], col[m]
        GX, GY = np.meshgrid(T.c + (c0 + sub) * T.a, T.f + (r0 + sub) * T.e)
        tk, tz, _ = truth.surface(GX.ravel() - org[0], GY.ravel() - org[1])
        tz = tz + org[2]
        taller = (tk != KIND_TERRAIN) & (tz > line[m])
        nk, nz, _ = truth.surface(px[m] - org[0] + AX, py[m] - org[1] + AY)
        near_tall = (nk != KIND_TERRAIN) & (nz + org[2] > line[m])
        d_obj = float(np.hypot(AX, AY)[near_tall].min()) if near_tall.any() else np.inf
        cx, cy = T.c + (c0 + 0.5) * T.a, T.f + (r0 + 0.5) * T.e
        d_ret, j_ret = kd.query((cx, cy))
        rows.append(dict(blocked=True, frees=frees, rise=rise, above_line_m=float(ex[m]), along_m=float(S[m]),
                         taller_share=float(taller.mean()), all_ground=bool((tk == KIND_TERRAIN).all()),
                         dsm_minus_truth_top_m=float(D[r0, c0] - tz.max()), object_m=d_obj,
                         return_m=float(d_ret), return_class=int(pts[j_ret, 3]), empty=bool(empty(r0, c0))))
    blocked = [q for q in rows if q["blocked"]]
    holds = [q for q in blocked if q["taller_share"] > 0]
    ground = [q for q in blocked if q["taller_share"] == 0 and q["all_ground"]]
    other = len(blocked) - len(holds) - len(ground)
    classes = {2: "ground", 5: "vegetation", 6: "building"}
    out = {
        "lines": len(rows), "no_dsm_cell": len(rows) - len(blocked),
        "rise_5_50_95": pct([q["rise"] for q in rows], (5, 50, 95)),
        "dsm_cell_above_the_line_m_5_25_50_75_95": pct([q["above_line_m"] for q in blocked]),
        "cell_holds_a_taller_object": len(holds),
        "cell_holds_a_taller_object_share_of_the_cell_5_25_50_75_95": pct([q["taller_share"] for q in holds]),
        "cell_holds_a_taller_object_dsm_minus_truth_top_m_25_50_75": pct(
            [q["dsm_minus_truth_top_m"] for q in holds], (25, 50, 75)),
        "cell_holds_a_taller_object_line_from_it_m_5_25_50_75_95": pct([q["object_m"] for q in holds]),
        "cell_all_ground": len(ground),
        "cell_all_ground_dsm_above_the_truth_m_25_50_75": pct([q["dsm_minus_truth_top_m"] for q in ground],
                                                              (25, 50, 75)),
        "cell_all_ground_taller_object_within_1_5m_m_5_25_50_75_95": pct(
            [q["object_m"] for q in ground if np.isfinite(q["object_m"])]),
        "cell_all_ground_no_taller_object_within_1_5m": sum(not np.isfinite(q["object_m"]) for q in ground),
        "cell_all_ground_nearest_return_m_5_25_50_75_95": pct([q["return_m"] for q in ground]),
        "cell_all_ground_no_return_within_the_radius": sum(q["empty"] for q in ground),
        "cell_all_ground_nearest_return_class": {
            classes.get(k, str(k)): sum(q["return_class"] == k for q in ground)
            for k in sorted({q["return_class"] for q in ground})},
        "cell_holds_a_taller_object_no_return_within_the_radius": sum(q["empty"] for q in holds),
        "cell_partly_other": other,
        "what_if_empty_cells_at_the_dem_lines_freed": sum(q["frees"] for q in rows),
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--block", required=True)
    ap.add_argument("--spec", default="lidar+occn+fp10+crowns")
    ap.add_argument("--classified", required=True, help="a glob of the block's classified strips")
    ap.add_argument("--key", default="fill_clear_lines")
    ap.add_argument("--empty-radius-m", type=float, default=EMPTY_RADIUS_M,
                    help="a cell with no first return this near its centre is empty (the what-if)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_fill.json")
    a = ap.parse_args()
    got = clear_lines(a.work, a.block, a.spec, a.classified, a.empty_radius_m)
    got["empty_radius_m"] = a.empty_radius_m
    print(a.block, json.dumps(got, indent=1), flush=True)
    entry = read_results(a.out).get(a.key, {})
    entry.setdefault("blocks", {}).setdefault(a.block, {})[a.spec] = got
    entry.setdefault("commands", {})[a.block] = {
        "command": f"python bench/eval_true_ortho_clear_lines.py --work DIR --block {a.block} --spec '{a.spec}' "
                   f"--classified 'BLOCK/lidar_out/classified/*.laz' --key {a.key} "
                   f"--empty-radius-m {a.empty_radius_m:g}", "commit": git_commit(REPO)}
    store_result(a.out, entry, key=a.key)


if __name__ == "__main__":
    main()
