"""The block adjustment on real DMC frames against the national AT (issue 19) -> bench/results/ngi_surface.json.

Data: ../shared/data/ngi_dmc (4 Z/I DMC frames of NGI South Africa, 2 strips x 2, the national aerial
triangulation's orientations, a 24 m SUDEM in Lo25 + EGM2008 heights; its README.md). The project is
built by tests/realdata_ngi.py (images and DEM linked, never copied) in ``--out``; then

1. ``aerotri match`` with no options (library: aerotri.match.pipeline.match_project; the portrait frames'
   top, 90 degrees from the flight direction, comes from the sensor's shape);
2. ``aerotri adjust --no-control`` (aerotri.adjust.pipeline.run_adjustment) with the reference projection
   centres as GNSS (sigma 0.05 m), plus any ``--adjust-option KEY=VALUE`` (fields of AdjustSettings,
   e.g. ``--adjust-option dem=PATH`` for the DEM height observations of issue 19);
3. measures: omega/phi/kappa differences to the reference (RMS and largest, degrees), projection centre
   differences; (tie point height - DEM height) of the adjusted tie points (at/object_points.csv, bilinear
   DEM sampling; both in EGM2008 heights), and of the same tie measurements intersected with the
   reference orientation; with ``--ortho``: the frames rectified on the DEM with the adjusted and with the
   reference orientation, and the shift between overlapping frame orthos by phase correlation (px).

The data's README: tie points intersected with the reference lie within a few metres of the DEM (the
issue reports 1.6 m below it, and 15.1 m below with our orientation).

Usage: python bench/eval_ngi_surface.py [--data ../shared/data/ngi_dmc] [--out out/ngi] [--ortho]
       [--adjust-option dem=PATH ...] [--variant NAME] [--results bench/results/ngi_surface.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


from ngi_common import load_ngi  # noqa: E402

ngi = load_ngi()


def parse_adjust_options(items: list[str], base_dir: Path):
    """``KEY=VALUE`` pairs -> {field: value} of AdjustSettings, each value read as a TOML value when it is
    one (true, 0.3, [..], "..") and as text otherwise (a file name, pp,radial), then checked like
    ``[adjust]`` in project.toml (aerotri.core.settings.from_table): an unknown key or a bad value stops
    with the list of fields."""
    from aerotri.adjust.settings import AdjustSettings
    from aerotri.core.errors import ConfigError
    from aerotri.core.settings import from_table

    table = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise SystemExit(f"--adjust-option {item!r}: expected KEY=VALUE (a field of AdjustSettings)")
        try:
            table[key] = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            table[key] = text
    try:
        parsed = from_table(AdjustSettings, table, "--adjust-option", base_dir=base_dir)
    except ConfigError as exc:
        raise SystemExit(f"error: {exc}") from None
    return {k: getattr(parsed, k) for k in table}


def adjust_settings(options: dict):
    """The settings of this evaluation: no control (GNSS carries the datum), then ``options``."""
    from aerotri.adjust.settings import AdjustSettings

    return dataclasses.replace(AdjustSettings(use_control=False), **options)


def tie_height_measures(root: Path, data_dir: Path, ref) -> dict:
    """(tie - DEM) of the adjusted tie points and of the ties intersected with the reference orientation."""
    dem = data_dir / ngi.DEM_FILE
    _, xyz = ngi.read_object_points(root / "at" / "object_points.csv", "tie")
    adj = ngi.height_stats(xyz[:, 2], ngi.sample_dem_bilinear(dem, xyz[:, 0], xyz[:, 1]))
    pid, img, xy = ngi.read_tiepoints(root / "at" / "tiepoints.csv")
    _, X, rms_px = ngi.intersect_with_orientation(root, ref.image_id, ref.centre_m, ref.opk_deg, pid, img, xy)
    refd = ngi.height_stats(X[:, 2], ngi.sample_dem_bilinear(dem, X[:, 0], X[:, 1]))
    return {
        "tie_points_n": adj["n"],
        "tie_minus_dem_median_m": adj["median_m"],
        "tie_minus_dem_rms_m": adj["rms_m"],
        "tie_minus_dem_nmad_m": adj["nmad_m"],
        "reference_tie_points_n": refd["n"],
        "reference_tie_minus_dem_median_m": refd["median_m"],
        "reference_tie_minus_dem_rms_m": refd["rms_m"],
        "reference_tie_minus_dem_nmad_m": refd["nmad_m"],
        "reference_tie_reprojection_median_px": float(np.median(rms_px)),
    }


def overlap_shifts(frames_dir: Path, min_valid_px: int = 2000) -> dict:
    """Shift (dx, dy px of the ortho grid) between every two overlapping frame orthos, by phase
    correlation (cv2.phaseCorrelate, Hann window) over the common valid rectangle. The frame orthos share
    one grid (same cell size, origins on whole cells), so their windows line up cell for cell."""
    import cv2
    import rasterio

    idx = json.loads((frames_dir / "index.json").read_text())
    res = idx["res_m"]
    frames = []
    for f in idx["frames"]:
        with rasterio.open(frames_dir / f["file"]) as ds:
            rgb = ds.read().astype(np.float32)
            mask = ds.read_masks(1) > 0
            x0, y0 = ds.transform.c, ds.transform.f
        frames.append((f["image_id"], rgb.mean(axis=0), mask, x0, y0))
    out = {}
    for a in range(len(frames)):
        for b in range(a + 1, len(frames)):
            ia, ga, ma, xa, ya = frames[a]
            ib, gb, mb, xb, yb = frames[b]
            left, top = max(xa, xb), min(ya, yb)
            right = min(xa + ga.shape[1] * res, xb + gb.shape[1] * res)
            bottom = max(ya - ga.shape[0] * res, yb - gb.shape[0] * res)
            if right <= left or top <= bottom:
                continue
            ca, ra = round((left - xa) / res), round((ya - top) / res)
            cb, rb = round((left - xb) / res), round((yb - top) / res)
            w, h = round((right - left) / res), round((top - bottom) / res)
            wa, wb = ga[ra:ra + h, ca:ca + w], gb[rb:rb + h, cb:cb + w]
            both = ma[ra:ra + h, ca:ca + w] & mb[rb:rb + h, cb:cb + w]
            if both.sum() < min_valid_px:
                continue
            rows, cols = np.flatnonzero(both.any(axis=1)), np.flatnonzero(both.any(axis=0))
            sl = np.s_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
            pa, pb, m = wa[sl], wb[sl], both[sl]
            # outside the common area: each window's mean, so the edge of the footprint does not correlate
            pa = np.where(m, pa, pa[m].mean()).astype(np.float64)
            pb = np.where(m, pb, pb[m].mean()).astype(np.float64)
            win = cv2.createHanningWindow((pa.shape[1], pa.shape[0]), cv2.CV_64F)
            (dx, dy), response = cv2.phaseCorrelate(pa, pb, win)
            out[f"{ia}|{ib}"] = {"dx_px": round(float(dx), 3), "dy_px": round(float(dy), 3),
                                 "shift_px": round(float(np.hypot(dx, dy)), 3), "response": round(float(response), 3),
                                 "common_px": int(m.sum())}
    return out


def ortho_measures(root: Path, ref) -> dict:
    """Frame orthos with the adjusted and with the reference orientation; the overlap shifts of each."""
    from aerotri.geom.eo import ExteriorOrientations, format_eo
    from ortho.block import rectify_block

    ref_eo = root / "work" / "reference_eo.txt"
    ref_eo.parent.mkdir(parents=True, exist_ok=True)
    ref_eo.write_text(format_eo(ExteriorOrientations(list(ref.image_id), ref.centre_m, ref.opk_deg, None)))
    out = {}
    for name, eo in (("reference", ref_eo), ("adjusted", None)):
        done = rectify_block(root, eo_path=eo)
        shifts = overlap_shifts(root / "ortho" / "frames")
        s = np.array([v["shift_px"] for v in shifts.values()])
        out[name] = {"res_m": done.res_m, "pairs": shifts,
                     "shift_rms_px": float(np.sqrt(np.mean(s**2))) if len(s) else None,
                     "shift_max_px": float(s.max()) if len(s) else None}
    return out


def _share_3plus(root: Path) -> float:
    """Share of the tie points (at/tiepoints.csv tracks) measured in 3 or more frames."""
    import csv

    with open(root / "at" / "tiepoints.csv", newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    head = [h.strip().lower() for h in rows[0]]
    ids = [r[head.index("point_id")] for r in rows[1:]]
    _, rays = np.unique(ids, return_counts=True)
    return round(float(np.mean(rays >= 3)), 4) if len(rays) else 0.0


def evaluate(data_dir: Path, out_dir: Path, options: dict, with_ortho: bool = False) -> dict:
    from aerotri.adjust.pipeline import run_adjustment
    from aerotri.core.settings import to_table
    from aerotri.match.pipeline import match_project

    ref = ngi.read_reference(data_dir)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    root = ngi.build_ngi_project(data_dir, out_dir)
    t0 = time.perf_counter()
    mrep = match_project(root, ngi.match_settings())
    t_match = time.perf_counter() - t0
    settings = adjust_settings(options)
    t0 = time.perf_counter()
    res = run_adjustment(root, settings)
    ba, rep = res.adjustment, json.loads(res.report_path.read_text())
    t_adjust = time.perf_counter() - t0
    ks = rep["key_statistics"]
    eo = ba.eo_map
    res = {
        "adjust_options": to_table(options),
        "frames": mrep.frames,
        "tracks": mrep.tracks,
        "tie_observations": mrep.observations,
        "ties_per_pair": {f"{p.left}|{p.right}": p.ties for p in mrep.ties_per_pair},
        "tracks_in_3plus_frames_share": _share_3plus(root),
        # after the adjustment: per pair of frames, the tie points both see and the RMS of their image
        # residuals in the two frames (at/report.json "image_pairs")
        "pairs_after_adjustment": rep["image_pairs"],
        "adjust_success": bool(ks["success"]),
        "adjust_iterations": ks["iterations"],
        "sigma0_um": ks["sigma0_um"],
        "sigma0_px": ks["sigma0_px"],
    }
    res.update(ngi.opk_differences(eo.image_id, eo.opk_deg, eo.centre_m, ref))
    res.update(tie_height_measures(root, data_dir, ref))
    if with_ortho:
        res["ortho_overlap_shifts"] = ortho_measures(root, ref)
    res["seconds"] = {"match": round(t_match, 1), "adjust": round(t_adjust, 1)}
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "ngi_dmc")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "ngi", help="project folder (replaced)")
    ap.add_argument("--adjust-option", action="append", default=[], metavar="KEY=VALUE",
                    help="a field of aerotri.adjust.settings.AdjustSettings (repeatable), e.g. dem=PATH")
    ap.add_argument("--variant", default=None, help="name of this run in the results (default: no_surface_control "
                                                   "without --adjust-option, else the options)")
    ap.add_argument("--results", type=Path, default=None,
                    help="results file (default bench/results/ngi_surface.json, bench/results/ngi_surface_<variant>.json with "
                         "--adjust-option)")
    ap.add_argument("--ortho", action="store_true", help="also rectify and measure the overlap shifts")
    a = ap.parse_args(argv)
    if not (a.data / ngi.REFERENCE_FILE).is_file():
        ap.error(f"{a.data}: not the NGI data folder (no {ngi.REFERENCE_FILE})")
    options = parse_adjust_options(a.adjust_option, Path.cwd())
    variant = a.variant or ("no_surface_control" if not options else
                            "_".join(f"{k}" for k in options))
    results = a.results or (REPO / "bench" / "results" / ("ngi_surface.json" if not options else f"ngi_surface_{variant}.json"))
    res = {"variant": variant, "data": a.data.name} | evaluate(a.data.resolve(), a.out, options, a.ortho)
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(json.dumps(res, indent=1, default=str) + "\n")
    print(f"{variant}: opk RMS diff {res['opk_rms_diff_deg']:.4f} deg (max {res['opk_max_abs_diff_deg']:.4f}), "
          f"tie - DEM median {res['tie_minus_dem_median_m']:.2f} m (RMS {res['tie_minus_dem_rms_m']:.2f}), "
          f"with the reference orientation {res['reference_tie_minus_dem_median_m']:.2f} m -> {results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
