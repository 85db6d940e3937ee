"""The DOM check with and without its texture test (the aperture problem), on the same files in one process.

``ortho check`` leaves out the open-ground patches whose reference patch has texture in one direction only (the
ratio of the small to the large eigenvalue of its gradient structure tensor below ``MIN_TEXTURE_RATIO``: a road's
NCC peak slides along the road). This script runs the DOM check's open-ground measure
(``ortho.check.check_against_reference``, the run's mosaic against the simulator's ``truth/ortho.tif``, the run's
nDSM) once per ratio (0: the test off, as before) and reports per ratio the patches measured and left out, the share
of roads (``truth/classes.tif`` class 11) among those left out, the RMS / median / share above 3 GSD of the
displacements, on and off roads; and the CPU seconds of each pass. Writes ``bench/results/dmc_dom_measure.json``
under ``aperture_test`` / ``--key``. The run folder is only read.

Usage: python bench/eval_dom_aperture.py RUN_DIR BLOCK_DIR --key dmc_2x6_cccbc0a [--ratios 0 0.1]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import rasterio

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.results_json import store_result  # noqa: E402

from ortho.check import check_against_reference  # noqa: E402
from ortho.patches import MIN_TEXTURE_RATIO  # noqa: E402

ROAD = 11


def _classes_at(classes_path: Path, dom_transform, row_px, col_px) -> np.ndarray:
    with rasterio.open(classes_path) as ds:
        a, t = ds.read(1), ds.transform
    x, y = dom_transform * (np.asarray(col_px) + 0.5, np.asarray(row_px) + 0.5)
    r, c = rasterio.transform.rowcol(t, x, y)
    return a[np.clip(r, 0, a.shape[0] - 1), np.clip(c, 0, a.shape[1] - 1)]


def _gsd_stats(d) -> dict:
    d = np.asarray(d, float)
    if not len(d):
        return dict(patches=0)
    return dict(patches=int(len(d)), rms_gsd=round(float(np.sqrt(np.mean(d ** 2))), 3),
                median_gsd=round(float(np.median(d)), 3), above_3_gsd_pct=round(100.0 * float((d > 3).mean()), 2))


def measure(run_dir: Path, block: Path, ratio: float) -> dict:
    dom = run_dir / "ortho" / "mosaic.tif"
    ndsm = run_dir / "lidar_out" / "ndsm.tif"
    with rasterio.open(dom) as ds:
        t, gsd = ds.transform, abs(ds.transform.a)
    t0 = time.process_time()
    p, _ = check_against_reference(dom, block / "truth" / "ortho.tif", ndsm if ndsm.is_file() else None,
                                   min_texture_ratio=ratio)
    cpu = time.process_time() - t0
    d = np.hypot(p.dx_px, p.dy_px) * p.res_m / gsd
    k = _classes_at(block / "truth" / "classes.tif", t, p.row_px, p.col_px)
    ko = _classes_at(block / "truth" / "classes.tif", t, p.one_direction_row_px, p.one_direction_col_px)
    n_out = len(ko)
    return dict(min_texture_ratio=ratio, **_gsd_stats(d), off_roads=_gsd_stats(d[k != ROAD]),
                roads=_gsd_stats(d[k == ROAD]), left_out_one_direction=n_out,
                left_out_pct=round(100.0 * n_out / max(n_out + len(d), 1), 2),
                left_out_on_roads_pct=round(100.0 * float((ko == ROAD).mean()), 1) if n_out else None,
                cpu_s=round(cpu, 1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path, help="a run (or demo project) folder: ortho/mosaic.tif, lidar_out/ndsm.tif")
    ap.add_argument("block", type=Path, help="the simulated block (its truth/ortho.tif and truth/classes.tif)")
    ap.add_argument("--key", required=True)
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.0, MIN_TEXTURE_RATIO])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "dmc_dom_measure.json")
    args = ap.parse_args(argv)
    passes = [measure(args.run_dir, args.block, r) for r in args.ratios]
    entry = dict(run_dir=str(args.run_dir), block=str(args.block), passes=passes,
                 measured_utc=time.strftime("%Y-%m-%d %H:%M", time.gmtime()))
    store_result(args.out, entry, key=args.key, section="aperture_test")
    print(json.dumps(entry, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
