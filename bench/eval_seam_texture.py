"""The seam misalignment's texture floor: every seam patch's reading against an independent, truth-based estimate.

``ortho.mosaic.seam_misalignment`` matches a patch of frame ortho a in frame ortho b on each seam. Both are aliased
renderings of the ground: a road's thin edge lines break into steps that move along the road with the rendering's
sub-pixel phase, and the NCC reads that as a shift along the road (docs/true-ortho.md, "The DOM check's sub-pixel peak
on roads"). To tell that from a real misalignment, every seam patch (its own texture test off) is read as
``seam_misalignment`` reads it (frame a minus frame b, px) and set beside an estimate that does not match the two
frames with each other: (frame a against the simulator's truth ortho) minus (frame b against it), each the median
of that frame's DOM-check patches (``ortho.check.check_against_reference``, the run's nDSM) within ``--radius`` px
of the seam patch. Per texture floor (the ratio of the reference patch's, frame b's, gradient structure tensor
eigenvalues, ``ortho.patches.texture_ratio``): the patches kept, the RMS of their reading (the seam measure) and of
its difference from the estimate, and the estimate's own RMS. Writes ``bench/results/seam_texture.json`` under
``--key``. The run folder is only read.

Usage: python bench/eval_seam_texture.py RUN_DIR BLOCK_DIR --key demo [--radius 120] [--floors 0.1 0.3 0.5]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.results_json import git_commit, store_result  # noqa: E402

import ortho.mosaic as M  # noqa: E402
from ortho.check import check_against_reference  # noqa: E402
from ortho.patches import match_patches, texture_ratio, to_gray  # noqa: E402


def seam_patches(root: Path, patch_px: int = 32, search_px: int = 4, spacing_cells: int = 4, min_ncc: float = 0.7,
                 max_ndsm_m: float = 0.5) -> list[tuple]:
    """(frame a, frame b, mosaic row, col, dx_px, dy_px, texture ratio) of every seam patch ``seam_misalignment``
    would measure with its texture test off (the same windows, nDSM and matcher)."""
    index = M.read_index(root)
    grids, names = index.grids, list(index.image_ids)
    mos = M.OrthoGrid.union(grids)
    with rasterio.open(root / "ortho" / "seams.tif") as ds:
        labels, factor = ds.read(1), int(round(ds.transform.a / mos.res_m))
    ndsm_path = root / "lidar_out" / "ndsm.tif"
    to_project = M.index_operation(index)
    half = patch_px // 2 + search_px
    size = 2 * half
    out = []
    for (i, j), rc in M.seam_samples(labels, spacing_cells):
        R = ((rc[:, 0] + 0.5) * factor).astype(int) - half
        C = ((rc[:, 1] + 0.5) * factor).astype(int) - half
        with M._open_frame(root / "ortho" / "frames" / f"{names[i]}.tif") as fa, \
                M._open_frame(root / "ortho" / "frames" / f"{names[j]}.tif") as fb:
            group = (R // M._SEAM_GROUP_PX) * (1 << 20) + C // M._SEAM_GROUP_PX
            for g in np.unique(group):
                sel = np.flatnonzero(group == g)
                r0, c0 = int(R[sel].min()), int(C[sel].min())
                h, w = int(R[sel].max()) - r0 + size, int(C[sel].max()) - c0 + size
                imgs = []
                for k, ds in ((i, fa), (j, fb)):
                    fc, fr = grids[k].offset_in(mos)
                    imgs.append(M.read_window(ds, c0 - fc, r0 - fr, w, h))
                keep = None
                if ndsm_path.is_file():
                    t = Affine(mos.res_m, 0, mos.x_left_m + c0 * mos.res_m, 0, -mos.res_m,
                               mos.y_top_m - r0 * mos.res_m)
                    nd = M._read_ndsm_on(ndsm_path, t, (h, w), mos.crs, to_project)
                    keep = np.nan_to_num(nd, nan=1e9) <= max_ndsm_m
                for s in sel:
                    win = (slice(R[s] - r0, R[s] - r0 + size), slice(C[s] - c0, C[s] - c0 + size))
                    p = match_patches(imgs[0][0][win], imgs[1][0][win], imgs[0][1][win], imgs[1][1][win],
                                      res_m=mos.res_m, patch_px=patch_px, step_px=patch_px, search_px=search_px,
                                      min_ncc=min_ncc, keep=None if keep is None else keep[win],
                                      min_texture_ratio=0.0)
                    if len(p):
                        ref = to_gray(imgs[1][0][win])[search_px:search_px + patch_px, search_px:search_px + patch_px]
                        out.append((i, j, float(R[s] + p.row_px[0]), float(C[s] + p.col_px[0]), float(p.dx_px[0]),
                                    float(p.dy_px[0]), texture_ratio(ref)))
    return out, names, grids, mos


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path, help="a run (or demo project) folder: ortho/frames, ortho/seams.tif")
    ap.add_argument("block", type=Path, help="the simulated block (its truth/ortho.tif)")
    ap.add_argument("--key", required=True)
    ap.add_argument("--radius", type=float, default=120.0, help="px of the truth-based estimate's neighbourhood")
    ap.add_argument("--floors", type=float, nargs="+", default=[0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "seam_texture.json")
    args = ap.parse_args(argv)
    t0 = time.process_time()
    recs, names, grids, mos = seam_patches(args.run_dir)
    ndsm = args.run_dir / "lidar_out" / "ndsm.tif"
    fields = {}
    for k in sorted({r[0] for r in recs} | {r[1] for r in recs}):
        p, _ = check_against_reference(args.run_dir / "ortho" / "frames" / f"{names[k]}.tif",
                                       args.block / "truth" / "ortho.tif", ndsm if ndsm.is_file() else None)
        fc, fr = grids[k].offset_in(mos)
        fields[k] = (p.row_px + fr, p.col_px + fc, p.dx_px, p.dy_px)

    def local(k, r, c):
        rr, cc, dx, dy = fields[k]
        m = np.hypot(rr - r, cc - c) <= args.radius
        return (float(np.median(dx[m])), float(np.median(dy[m]))) if m.sum() >= 5 else None

    rows = []
    for i, j, r, c, dx, dy, ratio in recs:
        a, b = local(i, r, c), local(j, r, c)
        if a is not None and b is not None:
            ex, ey = a[0] - b[0], a[1] - b[1]
            rows.append((ratio, math.hypot(dx, dy), math.hypot(dx - ex, dy - ey), math.hypot(ex, ey)))
    A = np.array(rows).reshape(-1, 4)
    rms = lambda v: round(float(np.sqrt(np.mean(np.square(v)))), 3) if len(v) else None  # noqa: E731
    floors = []
    for f in args.floors:
        k = A[:, 0] >= f
        floors.append(dict(min_texture_ratio=f, patches=int(k.sum()), left_out=int((~k).sum()),
                           reading_rms_px=rms(A[k, 1]), error_rms_px=rms(A[k, 2]), estimate_rms_px=rms(A[k, 3]),
                           left_out_reading_rms_px=rms(A[~k, 1]), left_out_error_rms_px=rms(A[~k, 2])))
    entry = dict(run_dir=str(args.run_dir), block=str(args.block), commit=git_commit(ROOT), radius_px=args.radius,
                 seam_patches=len(recs), with_estimate=int(len(A)), floors=floors,
                 cpu_s=round(time.process_time() - t0, 1), measured_utc=time.strftime("%Y-%m-%d %H:%M", time.gmtime()))
    store_result(args.out, entry, key=args.key)
    print(json.dumps(entry, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
