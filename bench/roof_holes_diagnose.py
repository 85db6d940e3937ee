"""Issue 41/42: the DOM check's roof corners in the DOM's nodata holes, corner by corner against the simulator's truth.

For every roof corner the check measures (``ortho.check.measure_roof_patches``'s patches: 24 m, masked NCC, search
+- half a patch), the same measurement with what could tell a wrong match: the hole's share of the patch, of its
Hanning weight and of squares of 1-8 m around the corner, whether the corner point and the roof side of it lie in
the hole (roof cells from the truth's DSM minus DEM), the share of the reference chip's structure (windowed gradient
energy) that lies in the DOM's hole, the NCC peak, the best NCC farther than 1 m from it, the peak's distance to
the search's edge, and the best NCC farther than 1 m from no shift of the reference's own chip against the
reference, masked by the DOM's valid cells and whole (what ``ortho.check.roof_evidence_in_nodata`` compares). The
DOM was made with the adjusted orientation and the LiDAR DSM: a displacement beyond 1 m is a wrong match, not the
DOM's error.

    python bench/roof_holes_diagnose.py --run B/dmc_block_subset_2x2_run_d0d98f7 --truth B/dmc_block_subset_2x2/truth \
        --out /tmp/corners_2x2.csv [--only 12,40,...]
(about 4 min on the 2 x 2's 1,911 corners; the self-correlations triple the FFTs: run them on a list of corners)
"""

from __future__ import annotations

import argparse
import csv
import math

import numpy as np


def ncc_surface(dom, dom_weight, reference, reference_valid, S):
    """``ortho.check.masked_ncc_surface`` (-1 everywhere where it has none)."""
    from ortho.check import masked_ncc_surface

    ncc = masked_ncc_surface(dom, dom_weight, reference, reference_valid, S)
    return np.full((2 * S + 1, 2 * S + 1), -1.0) if ncc is None else ncc


def main():
    from rasterio.enums import Resampling
    from rasterio.windows import Window

    from ortho.check import (ROOF_PATCH_M, ROOF_PATCH_PX, _on_grid, masked_ncc_shift, metres_per_unit,
                             read_roof_corners)
    from aerotri.geom.crs.raster_warp import open_north_up

    ap = argparse.ArgumentParser()
    ap.add_argument("--run", required=True)
    ap.add_argument("--truth", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--only", default=None, help="comma-separated corner indices")
    a = ap.parse_args()
    dom_path, ref_path = f"{a.run}/ortho/mosaic.tif", f"{a.truth}/ortho.tif"
    x_m, y_m = read_roof_corners(f"{a.truth}/roof_corners.csv")
    rows_out = []
    with open_north_up(dom_path, "DOM") as dom, open_north_up(ref_path, "ref") as ref, \
            open_north_up(f"{a.truth}/dsm.tif", "dsm") as dsm, open_north_up(f"{a.truth}/dem.tif", "dem") as dem:
        res = abs(dom.transform.a) * metres_per_unit(dom)
        patch_m = max(ROOF_PATCH_M, ROOF_PATCH_PX * res)
        n = max(16, int(round(patch_m / res)))
        S = n // 2
        win = np.outer(np.hanning(n), np.hanning(n))
        cols, rows = ~dom.transform @ (x_m, y_m)
        r0s, c0s = np.floor(rows).astype(np.int64) - n // 2, np.floor(cols).astype(np.int64) - n // 2
        inside = (r0s >= 0) & (c0s >= 0) & (r0s + n <= dom.height) & (c0s + n <= dom.width)
        idx = np.flatnonzero(inside)
        if a.only:
            idx = np.array([int(v) for v in a.only.split(",")])
        for k, i in enumerate(idx):
            w = Window(int(c0s[i]), int(r0s[i]), n, n)
            pv = dom.read_masks(1, window=w) > 0
            grey = dom.read([1], window=w).astype(np.float32).mean(axis=0)
            wide = Window(int(c0s[i]) - S, int(r0s[i]) - S, n + 2 * S, n + 2 * S)
            wt = dom.window_transform(wide)
            refimg, refok = _on_grid(ref, wt, (n + 2 * S, n + 2 * S), dom.crs, Resampling.average)
            rg = refimg.mean(axis=0)
            zs, _ = _on_grid(dsm, dom.window_transform(w), (n, n), dom.crs, Resampling.bilinear)
            zt, _ = _on_grid(dem, dom.window_transform(w), (n, n), dom.crs, Resampling.bilinear)
            roof = (zs[0] - zt[0]) > 2.5
            rv = refok[S:S + n, S:S + n]
            rec = dict(i=int(i), x=float(x_m[i]), y=float(y_m[i]), hole_patch=1 - pv.mean(), ref_valid=rv.mean(),
                       hole_weight=float((win * ~pv).sum() / win.sum()), centre_in_hole=int(not pv[n // 2, n // 2]))
            c = n // 2
            for half_m in (0.5, 1.0, 2.0, 4.0):
                h = max(1, int(round(half_m / res)))
                sq = ~pv[c - h:c + h, c - h:c + h]
                rf = roof[c - h:c + h, c - h:c + h]
                rec[f"hole_{2 * half_m:g}m"] = float(sq.mean())
                rec[f"roofhole_{2 * half_m:g}m"] = float(sq[rf].mean()) if rf.any() else math.nan
                rec[f"groundhole_{2 * half_m:g}m"] = float(sq[~rf].mean()) if (~rf).any() else math.nan
            gy, gx = np.gradient(np.where(rv, rg[S:S + n, S:S + n], 0.0))
            g2 = (gx * gx + gy * gy) * win * rv
            rec["ref_structure_in_hole"] = float(g2[~pv].sum() / max(g2.sum(), 1e-12))
            h = int(round(2.0 / res))
            g2c = g2[c - h:c + h, c - h:c + h]
            rec["ref_structure_in_hole_4m"] = float(g2c[~pv[c - h:c + h, c - h:c + h]].sum() / max(g2c.sum(), 1e-12))
            if pv.mean() < 0.8 or rv.mean() < 0.8:
                rec.update(status="outside_or_invalid")
                rows_out.append(rec)
                continue
            dom_p = np.where(pv, grey, 0.0)
            dx, dy, peak = masked_ncc_shift(dom_p, win * pv, rg, refok, S)
            surf = ncc_surface(dom_p, win * pv, rg, refok, S)
            py, px = np.unravel_index(int(np.argmax(surf)), surf.shape)
            yy, xx = np.mgrid[:2 * S + 1, :2 * S + 1]
            far = np.hypot(yy - py, xx - px) > 1.0 / res
            second = float(surf[far].max())
            # the reference's own chip, masked by the DOM's valid cells, against the reference: can the cells the
            # DOM has tell the corner's place at all (its best match farther than 1 m from zero shift)?
            near0 = np.hypot(yy - S, xx - S) <= 1.0 / res
            ref_chip = np.where(pv & rv, rg[S:S + n, S:S + n], 0.0)
            sm = ncc_surface(ref_chip, win * pv * rv, rg, refok, S)
            sf = ncc_surface(np.where(rv, rg[S:S + n, S:S + n], 0.0), win * rv, rg, refok, S)
            rec.update(self_second_masked=float(sm[~near0].max()), self_second_full=float(sf[~near0].max()))
            # NCC at zero shift (the truth: the DOM is where the reference is, to a few GSD)
            rec.update(status="measured" if (peak >= 0.5 and math.isfinite(dx)) else "weak", peak=peak,
                       second=second, at_zero=float(surf[S, S]),
                       edge_px=int(min(px, py, 2 * S - px, 2 * S - py)), de_m=dx * res, dn_m=-dy * res,
                       err_m=float(math.hypot(dx, dy) * res) if math.isfinite(dx) else math.nan)
            rows_out.append(rec)
            if k % 100 == 0:
                print(k, len(idx), flush=True)
    keys = sorted({kk for r in rows_out for kk in r}, key=lambda s: list(rows_out[0]).index(s) if s in rows_out[0] else 99)
    with open(a.out, "w", newline="") as f:
        wr = csv.DictWriter(f, keys)
        wr.writeheader()
        wr.writerows(rows_out)


if __name__ == "__main__":
    main()
