"""Do the adjusted orientations' reported sigmas contain the truth? Normalised RMS (error / reported sigma) per
component (X Y Z omega phi kappa) on simulated blocks whose surface control (the LiDAR DEM) carries the LiDAR's
strip errors, as a real one does.

Cases: ``aerotri sim --preset dmc_block --observations-only`` blocks of 12-120 frames (DMC frames at 0.10 m GSD, the
preset's GNSS: 0.05 m noise, a shift and drift per strip; 4 control points; 600 tie points per frame, as the 2x6
full-size block's matching gave) whose DEM is given the LiDAR's strip errors (``lidar_strip_errors``: the
simulator's LiDAR error model, a 3D offset per strip drawn with ``strip_offset_sigma_m`` 0.03 m, strips flown as the
preset's); and the 2x6 full-size DMC block's own observations (a copy of its run folder: tie points from matching,
LiDAR corners as control and check points, the LiDAR DEM, nDSM and roof planes; scored against its truth/).
The cell size of the surface bias was chosen on the tuning case (``TUNE``); the others are scored.

    nice -n 10 .venv/bin/python bench/eo_sigmas.py [--dmc-run RUN --dmc-truth TRUTH] [--work DIR]
        [--out bench/results/eo_sigmas.json]

Each case is adjusted twice: without the surface bias (``surface_bias_sigma_m = 0``: the DEM's points taken as
independent, what the adjustment did before) and with it (0.03 m, the LiDAR's strip sigma: the default for the
project's own LiDAR DEM and roof planes, as in the 2x6 run). Keys: ``cases`` (per case: RMS, block-common part
and the rest, mean reported sigma, normalised RMS), ``summary`` (normalised RMS pooled over the scored frames).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

COMPONENTS = ("X", "Y", "Z", "omega", "phi", "kappa")
# (name, strips, frames per strip, simulator seed); the first tunes, the others score
CASES = (("obs_2x6_s101", 2, 6, 101), ("obs_2x6_s202", 2, 6, 202), ("obs_3x6_s303", 3, 6, 303),
         ("obs_2x8_s404", 2, 8, 404), ("obs_3x4_s505", 3, 4, 505), ("obs_2x6_s606", 2, 6, 606),
         ("obs_3x6_s707", 3, 6, 707), ("obs_2x8_s808", 2, 8, 808), ("obs_3x4_s909", 3, 4, 909),
         ("obs_4x6_s1010", 4, 6, 1010), ("obs_6x20_s2020", 6, 20, 2020))
TUNE = "obs_2x6_s101"
PRESET = "dmc_block"
TIE_POINTS_PER_FRAME = 600  # the 2x6 full-size block's matching gave 630 per frame
# the LiDAR of the dmc_block preset: lines 900 m above ground, 40 deg field of view (655 m swath), 45 % side
# overlap (360 m apart), flown east-west as the photo strips; every strip offset by its own 3D error
LIDAR_STRIP_SPACING_M = 360.0
LIDAR_SWATH_M = 655.0
STRIP_OFFSET_SIGMA_M = 0.03  # [lidar] strip_offset_sigma_m of the presets


def lidar_strip_errors(dem_path: Path, seed: int) -> dict:
    """Give a DEM of the truth terrain the LiDAR's strip errors, in place: strips flown east-west every
    ``LIDAR_STRIP_SPACING_M`` (swath ``LIDAR_SWATH_M``), each offset by its own 3D error drawn with
    ``STRIP_OFFSET_SIGMA_M``; a cell's height the mean of the strips that cover it (the strip's surface at the
    cell: h(x - dx, y - dy) + dz, to first order in the slope). Returns the strips' lines and offsets."""
    import rasterio

    rng = np.random.default_rng(seed)
    with rasterio.open(dem_path) as ds:
        h = ds.read(1).astype(float)
        nodata, t, profile = ds.nodata, ds.transform, ds.profile
    bad = ~np.isfinite(h) | (h == nodata)
    hy, hx = np.gradient(np.where(bad, np.nanmean(np.where(bad, np.nan, h)), h), -t.a, t.a)  # rows run south
    ys = t.f + t.e * (np.arange(h.shape[0]) + 0.5)
    y_lines = ys.min() - rng.uniform(0, LIDAR_STRIP_SPACING_M) + LIDAR_STRIP_SPACING_M * np.arange(
        int((ys.max() - ys.min()) / LIDAR_STRIP_SPACING_M) + 3)
    offsets = rng.normal(0.0, STRIP_OFFSET_SIGMA_M, (len(y_lines), 3))
    total = np.zeros_like(h)
    count = np.zeros(len(ys))
    for yl, (dx, dy, dz) in zip(y_lines, offsets):
        rows = np.abs(ys - yl) <= LIDAR_SWATH_M / 2
        total[rows] += dz - hx[rows] * dx - hy[rows] * dy
        count[rows] += 1
    h = np.where(bad, nodata, h + total / np.maximum(count, 1)[:, None])
    tmp = dem_path.with_suffix(".tmp.tif")
    with rasterio.open(tmp, "w", **profile) as ds:
        ds.write(h.astype(profile["dtype"]), 1)
    os.replace(tmp, dem_path)
    return dict(strip_y_m=np.round(y_lines, 1).tolist(), strip_offsets_m=np.round(offsets, 4).tolist())


def observations_case(work: Path, name: str, strips: int, frames: int, seed: int) -> Path:
    """``aerotri sim --preset dmc_block --observations-only`` of ``strips`` x ``frames`` (the preset's GNSS with a
    shift and drift per strip, 4 control points, pp and radial self-calibration), its DEM given the LiDAR's strip
    errors (``lidar_strip_errors``)."""
    from aerotri.sim.command import simulate_command

    root = work / name
    if (root / "truth" / "lidar_dem.json").is_file():
        return root
    simulate_command(PRESET, root, seed=seed, force=True, observations_only=True,
                     overrides=(f"flight.strips={strips}", f"flight.frames_per_strip={frames}"),
                     tie_points_per_frame=TIE_POINTS_PER_FRAME)
    info = lidar_strip_errors(root / "dem.tif", seed + 1)
    (root / "truth" / "lidar_dem.json").write_text(json.dumps(info) + "\n")
    return root


def read_eo_file(path) -> tuple[list, np.ndarray]:
    rows = [ln.split() for ln in Path(path).read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    return [r[0] for r in rows], np.array([[float(v) for v in r[1:]] for r in rows])


def score(eo, truth_eo: Path) -> dict:
    """Errors of the adjusted orientations against the truth: RMS, the block-common part (mean) and the rest, and
    the normalised RMS (error / reported sigma) per component; angles in degrees."""
    ids, t = read_eo_file(truth_eo)
    ti = {k: i for i, k in enumerate(ids)}
    sel = np.array([ti[i] for i in eo.image_id])
    d = np.column_stack([eo.centre_m - t[sel, :3], (eo.opk_deg - t[sel, 3:6] + 180.0) % 360.0 - 180.0])
    s = eo.sigma
    mean = d.mean(axis=0)

    def per(v, nd):
        return dict(zip(COMPONENTS, (round(float(x), nd) for x in v)))

    return dict(frames=len(ids), rms=per(np.sqrt(np.mean(d**2, axis=0)), 5), common=per(mean, 5),
                rms_without_common=per(np.sqrt(np.mean((d - mean) ** 2, axis=0)), 5),
                mean_sigma=per(np.sqrt(np.mean(s**2, axis=0)), 5),
                normalised_rms=per(np.sqrt(np.mean((d / s) ** 2, axis=0)), 2))


def pooled(results: dict, label: str, names) -> dict | None:
    """The normalised RMS per component over the cases ``names``, each block weighted alike (a block's frames share
    its common errors: 120 frames are not 10 x the evidence of 12), and its range over the blocks."""
    rows = [results[n][label] for n in names if label in results.get(n, {})]
    if not rows:
        return None
    frames = np.array([r["frames"] for r in rows], float)
    ms = np.array([[r["normalised_rms"][c] for c in COMPONENTS] for r in rows]) ** 2
    return dict(cases=len(rows), frames=int(frames.sum()), normalised_rms=dict(zip(COMPONENTS, (
        round(float(v), 2) for v in np.sqrt(ms.mean(axis=0))))),
        per_case_range=dict(zip(COMPONENTS, ([round(float(lo), 2), round(float(hi), 2)] for lo, hi in
                                             zip(np.sqrt(ms).min(axis=0), np.sqrt(ms).max(axis=0))))))


def run_case(root: Path, truth_eo: Path, settings) -> dict:
    from aerotri.adjust.pipeline import adjust_project

    t0, c0 = time.perf_counter(), time.process_time()
    ba = adjust_project(root, settings)
    out = score(ba.eo_map, truth_eo)
    out["wall_s"], out["cpu_s"] = round(time.perf_counter() - t0, 1), round(time.process_time() - c0, 1)
    rep = ba.result.surface
    out["surface_points"] = None if rep is None else rep.used
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/i41-sigmas/eo_sigmas"))
    ap.add_argument("--dmc-run", type=Path, default=None, help="a copy of the 2x6 DMC run folder (project)")
    ap.add_argument("--dmc-truth", type=Path, default=None, help="its block's truth/ folder")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "eo_sigmas.json")
    ap.add_argument("--cases", nargs="*", default=None)
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    from aerotri.adjust.pipeline import project_settings
    from aerotri.core.project import Project

    results = {}
    cases = [c for c in CASES if a.cases is None or c[0] in a.cases]
    for name, strips, frames, seed in cases:
        root = observations_case(a.work, name, strips, frames, seed)
        base = dataclasses.replace(project_settings(Project.open(root)).settings, dem=root / "dem.tif")
        r = {}
        for label, st in (("independent_dem", dataclasses.replace(base, surface_bias_sigma_m=0.0)),
                          ("with_surface_bias", dataclasses.replace(base, surface_bias_sigma_m=STRIP_OFFSET_SIGMA_M))):
            r[label] = run_case(root, root / "truth" / "eo.txt", st)
            print(name, label, r[label]["normalised_rms"], r[label]["wall_s"], "s", flush=True)
        results[name] = dict(role="tuning" if name == TUNE else "scored", strips=strips, frames_per_strip=frames,
                             seed=seed, **r)
    if a.dmc_run is not None and (a.cases is None or "dmc_2x6" in a.cases):
        r = {}
        for label, st in (("independent_dem", 0.0), ("with_surface_bias", None)):
            resolved = project_settings(Project.open(a.dmc_run))
            s = resolved.settings if st is None else dataclasses.replace(resolved.settings, surface_bias_sigma_m=0.0)
            r[label] = run_case(a.dmc_run, a.dmc_truth / "eo.txt", s)
            print("dmc_2x6", label, r[label]["normalised_rms"], r[label]["wall_s"], "s", flush=True)
        results["dmc_2x6"] = dict(role="scored", source=str(a.dmc_run), **r)
    scored = [n for n in results if n != TUNE and n != "dmc_2x6"]
    summary = {label: dict(simulated_scored=pooled(results, label, scored), tuning=pooled(results, label, [TUNE]),
                           dmc_2x6=pooled(results, label, ["dmc_2x6"]))
               for label in ("independent_dem", "with_surface_bias")}
    for label, v in summary.items():
        print(label, "pooled over the scored simulated cases:", v["simulated_scored"], flush=True)
    load = os.getloadavg()
    record = dict(command=" ".join(["bench/eo_sigmas.py", *(argv if argv is not None else sys.argv[1:])]),
                  tuning_case=TUNE, preset=PRESET, tie_points_per_frame=TIE_POINTS_PER_FRAME,
                  lidar_model=dict(strip_spacing_m=LIDAR_STRIP_SPACING_M, swath_m=LIDAR_SWATH_M,
                                   strip_offset_sigma_m=STRIP_OFFSET_SIGMA_M),
                  load_average=[round(v, 2) for v in load], summary=summary, cases=results)
    if a.out:
        old = json.loads(a.out.read_text()) if a.out.is_file() else {}
        if a.cases is not None and old.get("cases"):  # a partial run: the other cases as they were
            old["cases"].update(results)
            record["cases"] = results = old["cases"]
            scored = [n for n in results if n != TUNE and n != "dmc_2x6"]
            record["summary"] = {label: dict(simulated_scored=pooled(results, label, scored),
                                             tuning=pooled(results, label, [TUNE]),
                                             dmc_2x6=pooled(results, label, ["dmc_2x6"]))
                                 for label in ("independent_dem", "with_surface_bias")}
        a.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = a.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(record, indent=1) + "\n")
        os.replace(tmp, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
