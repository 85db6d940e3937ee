"""The DEM's gap fill in ``lidarctl rasters``: the TIN of the ground around each gap (default) against the
pyramid (pull-push) fill alone (``--dem-fill-radius-px 0``), on real and simulated data.

Real set ``lidr_topography`` (forested hills, 73,403 points, 8,159 ground): its class-2 points in 5 random
folds (seeded); each fold is removed from the cloud, the 1 m DEM is made from the other ground and water
points, and the held-out points are compared with the DEM (bilinear). The check points are LiDAR ground
returns: their own noise (a few cm) is part of the error. Also a TIN of the remaining ground *points*
(Delaunay, linear), the interpolation a DEM of cells can at best approach.

Simulator: the ``demo`` preset's scene, seed 2, all LiDAR strips with the truth classes, 1 m DEM against the
scene's true terrain at every cell centre inside the survey (20 m in from the edges): all cells, and the cells
without any ground point (under buildings, under crowns), where the fill decides.

No parameter is chosen here: the fill radius is the default (64 cells), fixed before this run.
Writes bench/results/dem_fill.json. Run: .venv/bin/python bench/eval_dem_fill.py
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
LIDR = Path("/work/shared/data/lidr_topography/Topography.laz")
RADII = {"pyramid_fill_only": 0, "tin_fill_default": None}


def _trees_bench():
    spec = importlib.util.spec_from_file_location("eval_trees", REPO / "bench" / "eval_trees.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _stats(dz):
    dz = np.asarray(dz, float)
    dz = dz[np.isfinite(dz)]
    return {"n": int(len(dz)), "rmse_m": float(np.sqrt(np.mean(dz ** 2))), "mean_abs_m": float(np.mean(np.abs(dz))),
            "p95_abs_m": float(np.percentile(np.abs(dz), 95)), "max_abs_m": float(np.max(np.abs(dz)))}


def _sample(grids, x, y):
    from lidarctl.raster_ops import sample_bilinear

    t = grids.transform
    dem = grids.dem[::-1].astype(float)            # south-up rows, as sample_bilinear expects
    y0 = t.f + t.e * dem.shape[0]
    return sample_bilinear(np.where(np.isfinite(dem), dem, np.nan), x, y, cell_m=t.a, x0=t.c, y0=y0)


def _grids(cloud, radius):
    from lidarctl.rasters import products as rasters

    kw = {} if radius is None else {"dem_fill_radius_px": radius}
    return rasters.make_grids(cloud, 1.0, **kw)


def lidr(folds: int = 5):
    from scipy.spatial import Delaunay

    from lidarctl import io
    from lidarctl.classify.ground import tin_heights

    full = io.read_cloud(LIDR)
    gidx = np.flatnonzero(full.classification == 2)
    fold_of = np.random.default_rng(24).integers(0, folds, len(gidx))
    dz = {k: [] for k in (*RADII, "tin_of_points")}
    seconds = {k: 0.0 for k in RADII}
    for f in range(folds):
        check = gidx[fold_of == f]
        keep = np.ones(len(full.x), bool)
        keep[check] = False
        c = io.PointCloud(*(getattr(full, k)[keep] for k in ("x", "y", "z", "intensity", "return_number",
                                                             "number_of_returns", "classification")), crs=full.crs)
        for name, radius in RADII.items():
            t0 = time.perf_counter()
            g = _grids(c, radius)
            seconds[name] += time.perf_counter() - t0
            dz[name].append(_sample(g, full.x[check], full.y[check]) - full.z[check])
        gm = np.isin(c.classification, (2, 9))
        gx, gy, gz = c.x[gm], c.y[gm], c.z[gm]
        tri = Delaunay(np.column_stack([gx - gx.min(), gy - gy.min()])).simplices
        dz["tin_of_points"].append(tin_heights(gx, gy, gz, tri, full.x[check], full.y[check]) - full.z[check])
    out = {k: _stats(np.concatenate(v)) for k, v in dz.items()}
    out["seconds_make_grids"] = seconds
    return out


def sim(seed: int = 2):
    trees = _trees_bench()
    scene, cloud = trees.simulate(seed)
    out = {}
    for name, radius in RADII.items():
        g = _grids(cloud, radius)
        t = g.transform
        dem = g.dem[::-1]
        nr, nc = dem.shape
        cx = t.c + (np.arange(nc) + 0.5) * t.a
        cy = t.f + t.e * nr + (np.arange(nr) + 0.5) * t.a
        X, Y = np.meshgrid(cx, cy)
        inside = ((X > trees.X0 + 20) & (X < trees.X0 + scene.width_m - 20) & (Y > trees.Y0 + 20)
                  & (Y < trees.Y0 + scene.height_m - 20) & np.isfinite(dem))
        truth = scene.terrain_height(X[inside] - trees.X0, Y[inside] - trees.Y0)
        err = dem[inside] - truth
        # cells without a ground point: where the fill decides
        gm = np.isin(cloud.classification, (2, 9))
        j = np.floor((cloud.x[gm] - t.c) / t.a).astype(int)
        i = np.floor((cloud.y[gm] - (t.f + t.e * nr)) / t.a).astype(int)
        has = np.zeros((nr, nc), bool)
        ok = (i >= 0) & (i < nr) & (j >= 0) & (j < nc)
        has[i[ok], j[ok]] = True
        gap = ~has[inside]
        out[name] = {"all_cells": _stats(err), "cells_without_ground": _stats(err[gap]),
                     "gap_fraction_pct": float(100 * gap.mean())}
        print(f"sim {name}: all {out[name]['all_cells']['rmse_m']:.3f} m, gaps {out[name]['cells_without_ground']['rmse_m']:.3f} m",
              flush=True)
    return out


def main():
    t0 = time.perf_counter()
    res = {"what": __doc__.split("\n\n")[0], "fill_radius_px_default": None}
    from lidarctl.raster_ops import DEFAULT_TIN_FILL_RADIUS_PX

    res["fill_radius_px_default"] = DEFAULT_TIN_FILL_RADIUS_PX
    if LIDR.exists():
        res["lidr_topography_5fold_ground_holdout_1m"] = lidr()
        print("lidr:", {k: round(v["rmse_m"], 3) for k, v in res["lidr_topography_5fold_ground_holdout_1m"].items()
                        if isinstance(v, dict) and "rmse_m" in v}, flush=True)
    res["simulator_demo_seed2_1m_truth_classes"] = sim()
    res["seconds"] = time.perf_counter() - t0
    out = REPO / "bench" / "results" / "dem_fill.json"
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(out)


if __name__ == "__main__":
    main()
