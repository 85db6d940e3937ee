"""Roofs of a true-ortho DOM, corner by corner (issue 42: roofs in place to at most 1 GSD RMS).

The DOM check's ``roofs`` row (``ortho.check.measure_roof_patches``) measures a 24 m patch centred on every roof corner
against the reference true orthophoto. Until this change it phase-correlated the grey values with a Hanning window,
the DOM's cells without a value set to the patch mean; now it correlates the valid cells only (masked NCC,
``ortho.check.masked_ncc_shift``). This script:

1. **known truth** (``synthetic``): at every measured corner whose DOM patch has holes, the reference's own patch
   there (the simulator's true orthophoto on the DOM grid) moved by a known sub-pixel shift (cubic spline, uniform in
   +-2 px), with the DOM's nodata mask of that patch cut into it (the holes beside that very roof); both methods'
   error against the known shift, with and without the holes;
2. **the DOM, corner by corner** (``corners``): both methods at every corner; the old one must give the DOM check's
   figures of the same DOM (``dom_report.json``), the new one those of ``measure_roof_patches`` now;
3. **the largest displacements** (``largest``): for the ``--top`` corners of the old method's largest displacements,
   the patch's nodata share; ghost cells (ground by the simulator's straight-down ray, taken in the DOM from a frame
   that does not see the ground there but a roof or wall: roof texture on the ground); the DSM's building outline
   against the truth's (cells above 2.5 m in one and not in the other, within the patch and within 3 m of the
   corner); the frame the DOM takes the corner from (by value, as ``bench/eval_true_ortho_occlusion.py``) and whether
   it is the nadir-most frame with a value there; both displacements; and a contact sheet PNG (DOM with its nodata in
   magenta, reference, ghost cells in red). The same for the new method's displacements above 1 GSD
   (``largest_new_over_1_gsd``, at most ``--top``; the sheet ``*_new.png``).

Usage: python bench/eval_true_ortho_roofs.py --project DIR [--dsm lidar_out/dsm.tif] [--top 50] [--sheet PNG]
       [--out bench/results/true_ortho_roofs.json] [--key demo] [--streaming]
``--streaming`` (a DOM too large to hold: full-size DMC frames) reads a window per corner and gives step 2 only;
``--ground-ndsm NDSM`` adds the DOM check's open-ground figures (patches where the nDSM is below 0.5 m).
``DIR`` a project with ``ortho/mosaic.tif``, ``ortho/frames`` and ``truth/`` (e.g. a copy of
``/work/ref/demo_chain/project``: ``cp -a /work/ref/demo_chain/project DIR``). Results go under ``--key`` in the JSON.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from bench.results_json import store_result  # noqa: E402

BUILDING_M = 2.5  # DSM above the truth's DEM: a building cell (as ortho.check.ROOF_HEIGHT_M)
CORNER_DISC_M = 3.0  # the DSM's outline compared within this of the corner too
SYNTH_SHIFT_PX = 2.0  # known shifts drawn uniformly in +-this (x and y)
OLD_MIN_RESPONSE = 0.1  # the phase correlation's response below which a patch was not measured


def phase_shift(a, a_valid, g, g_valid, win):
    """The DOM check's method until this change: DOM cells without a value (and the reference's) set to the patch
    mean, cv2.phaseCorrelate with a Hanning window. (dx, dy, response), DOM minus reference, px."""
    import cv2

    a = np.array(a, np.float64)
    g = np.array(g, np.float64)
    a[~a_valid] = a[a_valid].mean()
    g[~g_valid] = g[g_valid].mean()
    (dx, dy), response = cv2.phaseCorrelate(g, a, win)  # writes into its float64 inputs: copies above
    return dx, dy, response


def ncc_shift(a, a_valid, ref_big, ref_big_valid, win, search_px):
    from ortho.check import masked_ncc_shift

    return masked_ncc_shift(np.where(a_valid, a, 0.0), win * a_valid, ref_big, ref_big_valid, search_px)


class Rasters:
    """The DOM's grey values and mask, and the reference averaged onto the DOM's grid padded by ``pad`` cells."""

    def __init__(self, project: Path, pad: int):
        import rasterio
        from rasterio.enums import Resampling

        from ortho.check import _on_grid
        from ortho.grid import OrthoGrid

        with rasterio.open(project / "ortho" / "mosaic.tif") as ds:
            self.samples = ds.read()
            self.valid = ds.read_masks(1) > 0
            self.crs, t = ds.crs, ds.transform
        self.grey = self.samples[:3].astype(np.float32).mean(axis=0)
        self.res = t.a
        H, W = self.valid.shape
        self.grid = OrthoGrid(self.crs, t.c, t.f, t.a, W, H)
        self.pad = pad
        big = self.grid.window(-pad, -pad, W + 2 * pad, H + 2 * pad)
        with rasterio.open(project / "truth" / "ortho.tif") as ref:
            img, ok = _on_grid(ref, big.transform, (big.height, big.width), self.crs, Resampling.average)
        self.ref = img.mean(axis=0)
        self.ref_valid = ok


def corner_cells(rasters: Rasters, project: Path, n: int):
    from ortho.check import read_roof_corners

    x, y = read_roof_corners(project / "truth" / "roof_corners.csv")
    inv = ~rasters.grid.transform
    cols, rows = inv @ (x, y)
    r0 = np.floor(rows).astype(np.int64) - n // 2
    c0 = np.floor(cols).astype(np.int64) - n // 2
    return x, y, r0, c0


def measure_corners(rasters: Rasters, r0s, c0s, n: int, S: int) -> dict:
    """Both methods at every corner patch (arrays over the corners; NaN where not measured)."""
    from ortho.check import ROOF_MIN_VALID

    H, W = rasters.valid.shape
    P = rasters.pad
    win = np.outer(np.hanning(n), np.hanning(n))
    k = len(r0s)
    out = {name: np.full(k, np.nan) for name in ("old_dx", "old_dy", "old_resp", "new_dx", "new_dy", "new_ncc",
                                                  "nodata_share")}
    out["inside"] = np.zeros(k, bool)
    for i, (r, c) in enumerate(zip(r0s, c0s)):
        if r < 0 or c < 0 or r + n > H or c + n > W:
            continue
        pv = rasters.valid[r:r + n, c:c + n]
        rv = rasters.ref_valid[P + r:P + r + n, P + c:P + c + n]
        out["nodata_share"][i] = 1.0 - pv.mean()
        if pv.mean() < ROOF_MIN_VALID or rv.mean() < ROOF_MIN_VALID:
            continue
        out["inside"][i] = True
        a = rasters.grey[r:r + n, c:c + n]
        g = rasters.ref[P + r:P + r + n, P + c:P + c + n]
        out["old_dx"][i], out["old_dy"][i], out["old_resp"][i] = phase_shift(a, pv, g, rv, win)
        big = (slice(P + r - S, P + r + n + S), slice(P + c - S, P + c + n + S))
        out["new_dx"][i], out["new_dy"][i], out["new_ncc"][i] = ncc_shift(a, pv, rasters.ref[big],
                                                                          rasters.ref_valid[big], win, S)
    return out


def measure_corners_streaming(project: Path, x, y, n: int, S: int) -> dict:
    """``measure_corners`` reading one window of the DOM and of the reference per corner (a DOM of gigapixels)."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.windows import Window

    from ortho.check import ROOF_MIN_VALID, _on_grid

    win = np.outer(np.hanning(n), np.hanning(n))
    k = len(x)
    out = {name: np.full(k, np.nan) for name in ("old_dx", "old_dy", "old_resp", "new_dx", "new_dy", "new_ncc",
                                                  "nodata_share")}
    out["inside"] = np.zeros(k, bool)
    with rasterio.open(project / "ortho" / "mosaic.tif") as dom, rasterio.open(project / "truth" / "ortho.tif") as ref:
        cols, rows = ~dom.transform @ (np.asarray(x), np.asarray(y))
        bands = list(range(1, min(dom.count, 3) + 1))
        for i in range(k):
            r, c = int(np.floor(rows[i])) - n // 2, int(np.floor(cols[i])) - n // 2
            if r < 0 or c < 0 or r + n > dom.height or c + n > dom.width:
                continue
            w = Window(c, r, n, n)
            pv = dom.read_masks(1, window=w) > 0
            a = dom.read(bands, window=w).astype(np.float32).mean(axis=0)
            wide = Window(c - S, r - S, n + 2 * S, n + 2 * S)
            img, ok = _on_grid(ref, dom.window_transform(wide), (n + 2 * S, n + 2 * S), dom.crs, Resampling.average)
            g_big = img.mean(axis=0)
            out["nodata_share"][i] = 1.0 - pv.mean()
            rv = ok[S:S + n, S:S + n]
            if pv.mean() < ROOF_MIN_VALID or rv.mean() < ROOF_MIN_VALID:
                continue
            out["inside"][i] = True
            out["old_dx"][i], out["old_dy"][i], out["old_resp"][i] = phase_shift(a, pv, g_big[S:S + n, S:S + n], rv, win)
            out["new_dx"][i], out["new_dy"][i], out["new_ncc"][i] = ncc_shift(a, pv, g_big, ok, win, S)
    return out


def stats_px(dx, dy, res: float) -> dict:
    d = np.hypot(dx, dy)
    d = d[np.isfinite(d)]
    if not len(d):
        return {"count": 0}
    return {"count": int(len(d)), "rms_m": float(np.sqrt(np.mean(d ** 2)) * res), "rms_gsd": float(np.sqrt(np.mean(d ** 2))),
            "median_gsd": float(np.median(d)), "p90_gsd": float(np.percentile(d, 90)), "max_gsd": float(d.max()),
            "over_1_gsd": int((d > 1).sum()), "over_3_gsd": int((d > 3).sum())}


def synthetic(rasters: Rasters, r0s, c0s, inside, nodata_share, n: int, S: int, seed: int = 42,
              same_corner: bool = True) -> dict:
    """Known truth: the reference's own patches moved by a known shift, with the DOM's hole masks cut in."""
    from scipy import ndimage

    P = rasters.pad
    rng = np.random.default_rng(seed)
    win = np.outer(np.hanning(n), np.hanning(n))
    holes = [i for i in np.flatnonzero(inside) if nodata_share[i] > 0]
    textures = np.flatnonzero(inside)  # same_corner=False: a texture drawn from any corner (not the hole's)
    cases = []
    for j, i in enumerate(holes):
        t = i if same_corner else textures[rng.integers(len(textures))]
        r, c = r0s[t], c0s[t]
        m = 4  # spline margin
        src = rasters.ref[P + r - S - m:P + r + n + S + m, P + c - S - m:P + c + n + S + m].astype(np.float64)
        src_ok = rasters.ref_valid[P + r - S - m:P + r + n + S + m, P + c - S - m:P + c + n + S + m]
        if not src_ok.all():
            continue
        dx, dy = rng.uniform(-SYNTH_SHIFT_PX, SYNTH_SHIFT_PX, 2)
        moved = ndimage.shift(src, (dy, dx), order=3, mode="nearest")  # content moved by +dx right, +dy down
        dom = moved[m + S:m + S + n, m + S:m + S + n]
        ref_big = src[m:m + n + 2 * S, m:m + n + 2 * S]
        g = ref_big[S:S + n, S:S + n]
        hole = rasters.valid[r0s[i]:r0s[i] + n, c0s[i]:c0s[i] + n]
        full = np.ones((n, n), bool)
        row = {"dx": dx, "dy": dy, "nodata_share": float(1 - hole.mean())}
        for tag, pv in (("holes", hole), ("no_holes", full)):
            ox, oy, _ = phase_shift(dom, pv, g, full, win)
            nx, ny, _ = ncc_shift(dom, pv, ref_big, np.ones_like(ref_big, bool), win, S)
            row[f"old_{tag}"] = (ox - dx, oy - dy)
            row[f"new_{tag}"] = (nx - dx, ny - dy)
        cases.append(row)
    out = {"cases": len(cases), "shift_px": f"uniform in +-{SYNTH_SHIFT_PX:g} px, x and y",
           "textures": "the reference (truth/ortho.tif on the DOM grid) at the corner " + (
               "of the hole" if same_corner else "drawn at random"),
           "holes": "the DOM's nodata masks of its corner patches that have any (measured ones, < 20 %)",
           "nodata_share_median": float(np.median([c["nodata_share"] for c in cases])) if cases else None}
    for key in ("old_holes", "new_holes", "old_no_holes", "new_no_holes"):
        e = np.array([c[key] for c in cases], float).reshape(-1, 2)
        err = np.hypot(e[:, 0], e[:, 1])
        fin = np.isfinite(err)
        out[key] = {"measured": int(fin.sum()), "rms_error_px": float(np.sqrt(np.mean(err[fin] ** 2))),
                    "median_error_px": float(np.median(err[fin])), "p95_error_px": float(np.percentile(err[fin], 95)),
                    "max_error_px": float(err[fin].max()), "over_0.5_px": int((err[fin] > 0.5).sum()),
                    "mean_error_px": [float(e[fin, 0].mean()), float(e[fin, 1].mean())]}
    # does the old method's error grow with the hole? (error against the share of nodata)
    share = np.array([c["nodata_share"] for c in cases])
    err_old = np.array([np.hypot(*c["old_holes"]) for c in cases])
    for lo, hi in ((0, 0.05), (0.05, 0.1), (0.1, 0.2)):
        sel = (share > lo) & (share <= hi) & np.isfinite(err_old)
        out[f"old_holes_rms_error_px_nodata_{lo:g}_{hi:g}"] = float(np.sqrt(np.mean(err_old[sel] ** 2))) if sel.any() \
            else None
    return out


def diagnose(project: Path, rasters: Rasters, dsm_path: Path, x, y, r0s, c0s, m: dict, n: int, order) -> list:
    """Per corner of ``order``: what is in and around its patch."""
    if not len(order):
        return []
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    from eval_true_ortho_occlusion import ROOF, WALL, TREE, Truth, frame_masks, nadir_most, source_by_value
    from aerotri.sim.scene import KIND_ROOF, KIND_TERRAIN

    d_old = np.hypot(m["old_dx"], m["old_dy"])
    grid = rasters.grid
    masks, nadir = frame_masks(project, grid)
    src, _ = source_by_value(project, grid, masks, rasters.samples, rasters.valid)
    nadir_idx = nadir_most(masks, nadir, grid)
    truth = Truth(project)

    def on_grid(path, resampling):
        out = np.full((grid.height, grid.width), np.nan, np.float32)
        with rasterio.open(path) as ds:
            reproject(rasterio.band(ds, 1), out, dst_transform=grid.transform, dst_crs=grid.crs,
                      resampling=resampling, dst_nodata=np.nan)
        return out

    truth_dem = on_grid(project / "truth" / "dem.tif", Resampling.bilinear)
    truth_bld = on_grid(project / "truth" / "dsm.tif", Resampling.nearest) - truth_dem > BUILDING_M
    dsm_bld = on_grid(dsm_path, Resampling.nearest) - truth_dem > BUILDING_M
    rows = []
    for i in order:
        r, c = int(r0s[i]), int(c0s[i])
        sl = (slice(r, r + n), slice(c, c + n))
        xs, ys = grid.centres(np.arange(r, r + n), np.arange(c, c + n))
        X, Y = np.meshgrid(xs - truth.origin[0], ys - truth.origin[1])
        kind, _, _ = truth.surface(X.ravel(), Y.ravel())
        ground = (kind == KIND_TERRAIN).reshape(n, n)
        valid, s = rasters.valid[sl], src[sl]
        code = np.zeros((n, n), np.uint8)
        for k in np.unique(s[ground & valid & (s >= 0)]):
            sel = ground & valid & (s == k)
            z = truth.scene.terrain_height(X[sel], Y[sel])
            code[sel] = truth.visibility(masks[k][0], X[sel], Y[sel], z)
        ghost = np.isin(code, (ROOF, WALL))
        rr, cc = np.mgrid[r:r + n, c:c + n]
        cr, cc0 = r + n // 2, c + n // 2
        disc = np.hypot(rr - cr, cc - cc0) * grid.res_m <= CORNER_DISC_M
        out_diff = dsm_bld[sl] != truth_bld[sl]
        # the frame of the roof at the corner: the most common source of the truth's roof cells within 3 m
        near = disc & (kind.reshape(n, n) == KIND_ROOF) & valid & (s >= 0)
        k_src = int(np.bincount(s[near]).argmax()) if near.any() else None
        k_nadir = int(np.bincount(nadir_idx[sl][near]).argmax()) if near.any() else None
        frames_in_patch = np.unique(s[valid & (s >= 0)])
        rows.append({
            "corner": int(i), "x_m": float(x[i]), "y_m": float(y[i]),
            "old_gsd": float(d_old[i]), "old_dx_dy_px": [float(m["old_dx"][i]), float(m["old_dy"][i])],
            "old_response": float(m["old_resp"][i]),
            "new_gsd": float(np.hypot(m["new_dx"][i], m["new_dy"][i])),
            "new_dx_dy_px": [float(m["new_dx"][i]), float(m["new_dy"][i])], "new_ncc": float(m["new_ncc"][i]),
            "nodata_share": float(m["nodata_share"][i]),
            "ghost_cells": int(ghost.sum()), "ghost_share_of_ground": float(ghost.sum() / max(1, (ground & valid).sum())),
            "tree_ghost_cells": int((code == TREE).sum()),
            "dsm_outline_differs_share": float(out_diff.mean()),
            "dsm_outline_differs_within_3m": float(out_diff[disc].mean()),
            "frame_at_corner": masks[k_src][0] if k_src is not None else None,
            "nadir_most_at_corner": masks[k_nadir][0] if k_nadir is not None else None,
            "frames_in_patch": len(frames_in_patch),
            "_ghost": ghost, "_ground": ground,
        })
    return rows


def contact_sheet(path: Path, rasters: Rasters, rows: list, r0s, c0s, n: int, by: str) -> None:
    """Per corner three tiles: DOM (nodata magenta, ghost cells red), reference, |DOM - reference|; caption."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    P = rasters.pad
    per_row = 5
    nrow = (len(rows) + per_row - 1) // per_row
    fig, axes = plt.subplots(nrow, per_row * 3, figsize=(per_row * 3 * 1.3, nrow * 1.55), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for j, row in enumerate(rows):
        i = row["corner"]
        r, c = int(r0s[i]), int(c0s[i])
        a = rasters.grey[r:r + n, c:c + n]
        g = rasters.ref[P + r:P + r + n, P + c:P + c + n]
        v = rasters.valid[r:r + n, c:c + n]
        lo, hi = np.percentile(g, [1, 99])
        norm = lambda z: np.clip((z - lo) / max(hi - lo, 1), 0, 1)
        dom_rgb = np.repeat(norm(a)[:, :, None], 3, axis=2)
        dom_rgb[~v] = (1, 0, 1)
        dom_rgb[row["_ghost"]] = (1, 0, 0)
        diff = np.where(v, np.abs(a - g), 0)
        ax0 = axes[j // per_row, (j % per_row) * 3]
        ax0.imshow(dom_rgb, interpolation="nearest")
        ax0.plot([n // 2 + row["old_dx_dy_px"][0]], [n // 2 + row["old_dx_dy_px"][1]], "c+", ms=5)
        ax0.plot([n // 2 + row["new_dx_dy_px"][0]], [n // 2 + row["new_dx_dy_px"][1]], "gx", ms=4)
        ax0.plot([n // 2], [n // 2], "y+", ms=5)
        ax0.set_title(f"#{j + 1} {row['frame_at_corner']}", fontsize=5)
        ax1 = axes[j // per_row, (j % per_row) * 3 + 1]
        ax1.imshow(norm(g), cmap="gray", interpolation="nearest")
        ax1.set_title(f"old {row['old_gsd']:.1f} new {row['new_gsd']:.1f} GSD", fontsize=5)
        ax2 = axes[j // per_row, (j % per_row) * 3 + 2]
        ax2.imshow(diff, cmap="magma", vmin=0, vmax=max(hi - lo, 1) / 2, interpolation="nearest")
        ax2.set_title(f"nodata {100 * row['nodata_share']:.0f}% ghost {row['ghost_cells']}", fontsize=5)
    fig.suptitle(f"largest roof-corner displacements ({by} method): DOM (nodata magenta, ghost red; yellow + corner, "
                 "cyan + old shift, green x new) | reference | |DOM - reference|", fontsize=7)
    fig.tight_layout(pad=0.2)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, required=True)
    ap.add_argument("--dsm", default="lidar_out/dsm.tif", help="the true ortho's DSM, relative to the project")
    ap.add_argument("--top", type=int, default=50)
    ap.add_argument("--sheet", type=Path, help="contact sheet PNG of the largest displacements")
    ap.add_argument("--key", default="demo")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_roofs.json")
    ap.add_argument("--ground-ndsm", type=Path,
                    help="also the DOM check's open ground (ortho.check.check_against_reference) with this nDSM")
    ap.add_argument("--streaming", action="store_true",
                    help="a window per corner (a large DOM): both methods only, no known-truth cases, no diagnosis")
    args = ap.parse_args()
    from ortho.check import ROOF_MIN_NCC, ROOF_PATCH_M, ROOF_PATCH_PX, measure_roof_patches, read_roof_corners

    project = args.project
    t0, c0 = time.perf_counter(), time.process_time()
    import rasterio

    with rasterio.open(project / "ortho" / "mosaic.tif") as ds:
        res = ds.transform.a
    n = max(16, int(round(max(ROOF_PATCH_M, ROOF_PATCH_PX * res) / res)))
    S = n // 2
    if args.streaming:
        x, y = read_roof_corners(project / "truth" / "roof_corners.csv")
        m = measure_corners_streaming(project, x, y, n, S)
    else:
        rasters = Rasters(project, pad=n + S)
        x, y, r0s, c0s = corner_cells(rasters, project, n)
        m = measure_corners(rasters, r0s, c0s, n, S)
    inside = m["inside"]
    old_ok = inside & (m["old_resp"] >= OLD_MIN_RESPONSE)
    result = {"project": str(project), "dom": "ortho/mosaic.tif", "reference": "truth/ortho.tif",
              "corners": len(x), "patch_px": n, "search_px": S, "gsd_m": res,
              "measured_patches_at_least_80pc_valid": int(inside.sum())}
    result["old_phase_correlation"] = stats_px(np.where(old_ok, m["old_dx"], np.nan), m["old_dy"], res)
    new_ok = inside & (m["new_ncc"] >= ROOF_MIN_NCC)
    result["new_masked_ncc"] = stats_px(np.where(new_ok, m["new_dx"], np.nan), m["new_dy"], res)
    both = old_ok & new_ok & np.isfinite(m["new_dx"])
    result["both_measured"] = {"old": stats_px(np.where(both, m["old_dx"], np.nan), m["old_dy"], res),
                               "new": stats_px(np.where(both, m["new_dx"], np.nan), m["new_dy"], res)}
    report = project / "ortho" / "dom_report.json"
    if report.exists():
        roofs = json.loads(report.read_text()).get("roofs", {})
        result["dom_report_roofs"] = {k: roofs.get(k) for k in ("count", "rms_xy_m", "rms_xy_gsd", "median_xy_gsd")}
    xs, ys = read_roof_corners(project / "truth" / "roof_corners.csv")
    check = measure_roof_patches(project / "ortho" / "mosaic.tif", project / "truth" / "ortho.tif", xs, ys)
    result["measure_roof_patches"] = stats_px(check.de_m / res, check.dn_m / res, res)
    result["measure_roof_patches"].update(weak=check.weak, outside_or_invalid=check.outside_or_invalid)
    if args.ground_ndsm:
        from ortho.check import check_against_reference

        ground, _ = check_against_reference(project / "ortho" / "mosaic.tif", project / "truth" / "ortho.tif",
                                            args.ground_ndsm)
        result["open_ground"] = stats_px(ground.dx_px, ground.dy_px, res)
        result["open_ground"].update(mean_dx_dy_px=[float(ground.dx_px.mean()), float(ground.dy_px.mean())])
    ok = new_ok & np.isfinite(m["new_dx"])
    result["new_masked_ncc"]["mean_dx_dy_px"] = [float(m["new_dx"][ok].mean()), float(m["new_dy"][ok].mean())]
    result["old_phase_correlation"]["mean_dx_dy_px"] = [float(m["old_dx"][old_ok].mean()),
                                                        float(m["old_dy"][old_ok].mean())]
    print(json.dumps(result, indent=1), flush=True)
    if not args.streaming:
        result["synthetic"] = synthetic(rasters, r0s, c0s, inside, m["nodata_share"], n, S)
        print(json.dumps(result["synthetic"], indent=1), flush=True)
        diagnosis(result, args, project, rasters, x, y, r0s, c0s, m, n, old_ok, new_ok)
    result["cpu_s"] = round(time.process_time() - c0, 1)
    result["wall_s"] = round(time.perf_counter() - t0, 1)
    result["command"] = "python bench/eval_true_ortho_roofs.py " + " ".join(sys.argv[1:])
    result["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                      text=True).stdout.strip()
    store_result(args.out, result, key=args.key)
    print(json.dumps(result.get("largest_summary"), indent=1))
    print(f"wrote {args.out}")


def diagnosis(result: dict, args, project: Path, rasters: Rasters, x, y, r0s, c0s, m: dict, n: int, old_ok, new_ok):
    """The ``largest`` and ``largest_new_over_1_gsd`` rows, their contact sheets and the summary, into ``result``."""
    d_old = np.where(old_ok, np.hypot(m["old_dx"], m["old_dy"]), -1)
    d_new = np.where(new_ok & np.isfinite(m["new_dx"]), np.hypot(m["new_dx"], m["new_dy"]), -1)
    orders = {"largest": [int(i) for i in np.argsort(-d_old)[:args.top] if d_old[i] >= 0],
              "largest_new_over_1_gsd": [int(i) for i in np.argsort(-d_new) if d_new[i] > 1][:args.top]}
    for key, order in orders.items():
        rows = diagnose(project, rasters, project / args.dsm, x, y, r0s, c0s, m, n, order)
        if args.sheet:
            contact_sheet(args.sheet.with_name(args.sheet.stem + ("" if key == "largest" else "_new") + ".png"),
                          rasters, rows, r0s, c0s, n, "old" if key == "largest" else "new")
        for row in rows:
            row.pop("_ghost")
            row.pop("_ground")
        result[key] = rows
    rows = result["largest"]
    top = np.array([[r["old_gsd"], r["new_gsd"], r["nodata_share"], r["ghost_cells"]] for r in rows]).reshape(-1, 4)
    result["largest_summary"] = {
        "corners": len(rows), "with_nodata": int((top[:, 2] > 0).sum()), "with_ghost_cells": int((top[:, 3] > 0).sum()),
        "new_within_1_gsd": int((top[:, 1] <= 1).sum()), "frame_is_nadir_most": sum(
            r["frame_at_corner"] == r["nadir_most_at_corner"] for r in rows)}


if __name__ == "__main__":
    main()
