"""``lidarctl trees`` against the simulator's trees, and DEM accuracy by vegetation density (seed 004 Tab. 1)
on the simulator and on the real forested set ``lidr_topography`` (issue 24).

Simulator: the ``demo`` preset's scene (``aerotri.sim.scene``: single trees, groves, the forest on the valley
side, bushes; crowns are spheroids, ``tree_c`` centres and ``tree_ac`` semi-axes) scanned by its LiDAR
(``aerotri.sim.lidar.scan_strip``, all strips, about 5 M points), scene seeds 1 (tuning) and 2 (scoring).
True trees: every crown whose top (centre height + vertical semi-axis) is at least 2 m above the terrain
(the bushes are lower), with its crown radius (horizontal semi-axis) and top height above the terrain at
its centre. A detected top matches a true tree within that tree's crown radius (one to one, nearest
first). Detection rate = matched / true trees; commission = unmatched / detected tops; height RMSE over
the matches (detected - true). The tree-top window (``top_radius_m``, ``top_radius_per_m``, ``smooth_px``)
is chosen on seed 1 by the F-score of detection and 1 - commission, and scored on seed 2 with the truth
classes and with our classifier's classes (``lidarctl classify`` defaults); the defaults are scored too.

DEM accuracy by vegetation density, simulator (seed 2): 2000 check points on the ground (a third uniform
over the scene, two thirds under random crowns, none within 3 m of a building or water return), truth =
the simulator's terrain there; checked with ``check_heights_file`` (the ``lidarctl check-heights`` library
call) against the 1 m DEM ``lidarctl rasters`` makes from our classifier's ground, grouped by the canopy
cover of the first returns more than 2 m above that DEM within 10 m (open < 20 %, sparse 20-60 %, dense
> 60 %). Also the DEM from the truth classes (the interpolation's share of the error without
classification errors). The demo scene's crowns stand apart (no point reaches 60 % cover within 10 m),
so the table is also made on a forested variant of seed 2 (25 times the valley-side trees, three times
the groves: a closed forest), where tree detection is scored too.

Real set ``lidr_topography`` (73,403 points, 8,159 ground; classes 1/2/9): its class-2 points are the check
points in 5 folds (random, seeded): each fold's ground points are removed from the cloud and the DEM is
made from the other ground and water points, (a) as ``lidarctl rasters`` does (1 m cells, mean per cell,
gaps filled by pull-push) and (b) as a TIN (Delaunay of those points, linear); the held-out points are
checked against both DEMs and against the local ground plane of the remaining points (check-heights'
own interpolation, 5 m radius), grouped by the canopy cover from all first returns of the full cloud
(class 1 holds the vegetation in this set). The check points are LiDAR ground returns, not surveyed
points: their own noise (a few cm) is part of the error.

Writes bench/results/trees.json and bench/results/trees_sim.png. Run: .venv/bin/python bench/eval_trees.py
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.sim import load_preset, raycast  # noqa: E402
from aerotri.sim.flight import block_layout, lidar_lines  # noqa: E402
from aerotri.sim.lidar import scan_strip  # noqa: E402
from aerotri.sim.scene import build_scene  # noqa: E402
from lidarctl.checks import heights as hc  # noqa: E402
from lidarctl import synthetic  # noqa: E402
from lidarctl.io import PointCloud  # noqa: E402
from lidarctl.rasters.trees import TreeSettings, tree_model, tree_tops  # noqa: E402

X0, Y0 = 500000.0, 4000000.0   # map origin of the scene's (0, 0), UTM 33N
EPSG = "EPSG:32633"
TUNE_SEED, SCORE_SEED = 1, 2
GRID = [dict(top_radius_m=a, top_radius_per_m=b, smooth_px=s)
        for a in (0.6, 1.0, 1.5, 2.0) for b in (0.05, 0.1, 0.15) for s in (0.5, 1.0)]
LIDR = Path("/work/shared/data/lidr_topography/Topography.laz")
RESULTS = REPO / "bench" / "results"


def simulate(seed: int, forested: bool = False):
    """(scene, cloud in map metres with truth classes) of the demo preset's scene ``seed``, all LiDAR strips;
    ``forested``: 25 times the trees on the valley side and three times the groves (a closed forest)."""
    cfg = load_preset("demo")
    if forested:
        cfg = load_preset("demo", [f"scene.slope_trees={cfg.scene.slope_trees * 25}",
                                    f"scene.tree_clusters={cfg.scene.tree_clusters * 3}"])
    layout = block_layout(cfg)
    scene = build_scene(cfg.scene, layout.width_m, layout.height_m, np.zeros(3), seed)
    accel = raycast.build_accel(scene)
    rng = np.random.default_rng(seed + 500)
    parts = [scan_strip(scene, accel, line, L=cfg.lidar, rng=rng,
                        width_m=layout.width_m) for line in lidar_lines(cfg, layout)]
    cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in ("xyz", "intensity", "return_number",
                                                                 "number_of_returns", "classification")}
    xyz = cat["xyz"]
    cloud = PointCloud(xyz[:, 0] + X0, xyz[:, 1] + Y0, xyz[:, 2], cat["intensity"], cat["return_number"],
                       cat["number_of_returns"], cat["classification"])
    return scene, cloud


def true_trees(scene, min_height_m: float = 2.0):
    """(x, y in map metres, top height above the terrain, crown radius) of the crowns at least 2 m high."""
    c, ac = scene.tree_c, scene.tree_ac
    h = c[:, 2] + ac[:, 1] - scene.terrain_height(c[:, 0], c[:, 1])
    k = h >= min_height_m
    return c[k, 0] + X0, c[k, 1] + Y0, h[k], ac[k, 0]


def match(tops, truth):
    """One-to-one matching of detected tops to true trees within the tree's crown radius, nearest first."""
    from scipy.spatial import cKDTree

    tx, ty, th, tr = truth
    tree = cKDTree(np.column_stack([tx, ty]))
    pairs = []
    for k, nb in enumerate(tree.query_ball_point(np.column_stack([tops.x, tops.y]), float(tr.max()))):
        for j in nb:
            d = np.hypot(tops.x[k] - tx[j], tops.y[k] - ty[j])
            if d <= tr[j]:
                pairs.append((d, k, j))
    pairs.sort()
    used_t, used_d, m = set(), set(), []
    for d, k, j in pairs:
        if k not in used_d and j not in used_t:
            used_d.add(k)
            used_t.add(j)
            m.append((k, j))
    m = np.array(m, dtype=np.int64).reshape(-1, 2)
    dh = tops.height_m[m[:, 0]] - th[m[:, 1]]
    det = len(m) / len(tx)
    comm = 1 - len(m) / max(len(tops.x), 1)
    f = 2 * det * (1 - comm) / max(det + 1 - comm, 1e-9)
    big = th >= 8.0
    return {"true_trees": int(len(tx)), "detected_tops": int(len(tops.x)), "matched": int(len(m)),
            "detection_rate": det, "commission": comm, "f_score": f,
            "detection_rate_trees_over_8m": float(np.isin(np.flatnonzero(big), m[:, 1]).mean()),
            "height_rmse_m": float(np.sqrt(np.mean(dh ** 2))) if len(dh) else None,
            "height_bias_m": float(np.mean(dh)) if len(dh) else None,
            "matched_pairs": m}


def true_canopy(scene, grid):
    """Height of the crowns above the terrain at the CHM's cell centres (north-up; 0 outside every crown) and the
    cells within 0.8 crown radii of a crown's centre (away from the crowns' vertical sides)."""
    rows, cols = np.mgrid[0:grid.nrows, 0:grid.ncols]
    x, y = grid.centres(rows, cols)
    lx, ly = x - X0, y - Y0
    ground = scene.terrain_height(lx, ly)
    out = np.zeros(lx.shape)
    inner = np.zeros(lx.shape, bool)
    for (cx, cy, cz), (a, c) in zip(scene.tree_c, scene.tree_ac):
        r0, r1 = int((grid.y_top - (cy + Y0 + a)) / grid.res_m), int((grid.y_top - (cy + Y0 - a)) / grid.res_m) + 1
        c0, c1 = int((cx + X0 - a - grid.x0) / grid.res_m), int((cx + X0 + a - grid.x0) / grid.res_m) + 1
        r0, c0, r1, c1 = max(r0, 0), max(c0, 0), min(r1, grid.nrows), min(c1, grid.ncols)
        if r0 >= r1 or c0 >= c1:
            continue
        q = 1 - ((lx[r0:r1, c0:c1] - cx) ** 2 + (ly[r0:r1, c0:c1] - cy) ** 2) / (a * a)
        top = np.where(q > 0, cz + c * np.sqrt(np.clip(q, 0, None)) - ground[r0:r1, c0:c1], 0.0)
        np.maximum(out[r0:r1, c0:c1], top, out=out[r0:r1, c0:c1])
        inner[r0:r1, c0:c1] |= q > 1 - 0.8 ** 2
    return out, inner


def chm_scores(model, scene):
    true, inner = true_canopy(scene, model.grid)
    chm = model.chm
    found = np.isfinite(chm)
    tree = true >= model.settings.min_height_m
    err = chm[found & tree] - true[found & tree]
    e_in = np.where(found, chm, 0.0)[inner & tree] - true[inner & tree]
    return {"canopy_cells_found_pct": 100.0 * float((found & tree).sum() / max(tree.sum(), 1)),
            "chm_cells_outside_true_canopy_pct": 100.0 * float((found & ~tree).sum() / max(found.sum(), 1)),
            "chm_rmse_in_canopy_m": float(np.sqrt(np.mean(err ** 2))), "chm_bias_in_canopy_m": float(np.mean(err)),
            "chm_median_abs_error_in_canopy_m": float(np.median(np.abs(err))),
            "chm_rmse_inner_crowns_m": float(np.sqrt(np.mean(e_in ** 2))),
            "chm_bias_inner_crowns_m": float(np.mean(e_in))}, true


def clean(d):
    return {k: v for k, v in d.items() if k != "matched_pairs"}


def sim_trees():
    out = {}
    t0 = time.perf_counter()
    scene, cloud = simulate(TUNE_SEED)
    truth = true_trees(scene)
    base = tree_model(cloud.x, cloud.y, cloud.z, cloud.classification, cloud.return_number, TreeSettings())
    out["tune_seed"] = TUNE_SEED
    tuning = []
    for g in GRID:
        s = dataclasses.replace(base.settings, **g)
        tops = tree_tops(base.chm, base.grid, s, base.stand_label)
        tuning.append({**g, **clean(match(tops, truth))})
    best = max(tuning, key=lambda r: r["f_score"])
    chosen = {k: best[k] for k in GRID[0]}
    out["tuning_seed_1"] = tuning
    out["chosen_on_seed_1"] = chosen
    print(f"seed {TUNE_SEED}: {len(cloud.x):,} points, {len(truth[0])} trees; chosen {chosen}: F {best['f_score']:.3f} "
          f"({time.perf_counter() - t0:.0f} s)", flush=True)
    del cloud, base

    scene, cloud = simulate(SCORE_SEED)
    truth = true_trees(scene)
    scored = {}
    for name, classes in (("truth_classes", cloud.classification), ("lidarctl_classify", None)):
        if classes is None:
            from lidarctl.classify.pipeline import classify_points

            t1 = time.perf_counter()
            classes = classify_points(cloud.x, cloud.y, cloud.z, cloud.return_number, cloud.number_of_returns,
                                      cloud.intensity)
            scored["classify_seconds"] = time.perf_counter() - t1
            ours = classes
        variants = (("chosen", dict(chosen)), ("chosen_without_pit_free", dict(chosen, pit_free=False)),
                    ("defaults", {})) if name == "truth_classes" else (("chosen", dict(chosen)),)
        for label, params in variants:
            s = dataclasses.replace(TreeSettings(), **params)
            t1 = time.perf_counter()
            m = tree_model(cloud.x, cloud.y, cloud.z, classes, cloud.return_number, s)
            sec = time.perf_counter() - t1
            r = match(m.tops, truth)
            cs, true_chm = chm_scores(m, scene)
            scored[f"{name}_{label}"] = {**clean(r), **cs, "stands": len(m.stands),
                                         "forest_area_ha": float((m.stand_label > 0).sum() * m.grid.res_m ** 2 / 1e4),
                                         "seconds": sec, "points": int(len(cloud.x))}
            print(f"seed {SCORE_SEED} {name} {label}: detection {r['detection_rate']:.3f}, commission "
                  f"{r['commission']:.3f}, height RMSE {r['height_rmse_m']:.2f} m, CHM RMSE {cs['chm_rmse_in_canopy_m']:.2f} m "
                  f"(inner crowns {cs['chm_rmse_inner_crowns_m']:.2f} m) ({sec:.0f} s)", flush=True)
            if name == "truth_classes" and label == "chosen":
                picture_model, picture_match, picture_true = m, r, true_chm
    out["score_seed"] = SCORE_SEED
    out["scored_seed_2"] = scored
    return out, (scene, cloud, ours, truth, picture_model, picture_match, picture_true)


def forested(tmp: Path):
    """Tree detection and the DEM table on a closed forest (``simulate(forested=True)``, seed 2)."""
    from lidarctl.classify.pipeline import classify_points

    scene, cloud = simulate(SCORE_SEED, forested=True)
    truth = true_trees(scene)
    m = tree_model(cloud.x, cloud.y, cloud.z, cloud.classification, cloud.return_number, TreeSettings())
    r = match(m.tops, truth)
    cs, _ = chm_scores(m, scene)
    print(f"forested seed {SCORE_SEED} truth classes: {len(truth[0])} trees, detection {r['detection_rate']:.3f}, "
          f"commission {r['commission']:.3f}, height RMSE {r['height_rmse_m']:.2f} m", flush=True)
    ours = classify_points(cloud.x, cloud.y, cloud.z, cloud.return_number, cloud.number_of_returns, cloud.intensity)
    return {"truth_classes_defaults": {**clean(r), **cs, "stands": len(m.stands)}}, sim_dem(scene, cloud, ours, tmp,
                                                                                            "forested")


def write_dem(path, dem_north_up, x0, y_top, res, crs):
    from rasterio.transform import from_origin

    from lidarctl.rasters.products import write_cog

    write_cog(path, dem_north_up.astype(np.float32), from_origin(x0, y_top, res, res), crs, unit="metre")


def table(result, key="dem"):
    """Seed-004-style rows: per group n, |dz| bin shares, MAE, RMSE."""
    block = result[key] if key else result
    rows = {}
    for g, s in [*block["groups"].items(), ("all", block["overall"])]:
        rows[g] = {"n": s["all"]["n"], "mean_abs_dz_m": s["all"]["mean_abs_dz_m"], "rmse_m": s["all"]["rmse_m"],
                   "mean_dz_m": s["all"]["mean_dz_m"],
                   "abs_bins_pct": {b["abs_dz_m"]: round(b["percent"], 1) for b in s["abs_bins"]}}
    return rows


def sim_dem(scene, cloud, ours, tmp: Path, tag: str = "demo"):
    from lidarctl.rasters import products as rasters

    rng = np.random.default_rng(77)
    w, h = scene.width_m, scene.height_m
    # two thirds of the candidates under the crowns (the scene is mostly open): the groups still come from
    # the cover the check derives from the cloud, not from this choice
    k = rng.integers(0, len(scene.tree_c), 4000)
    rr, aa = scene.tree_ac[k, 0] * np.sqrt(rng.random(4000)), rng.uniform(0, 2 * np.pi, 4000)
    px = np.concatenate([rng.uniform(20, w - 20, 2000), scene.tree_c[k, 0] + rr * np.cos(aa)]) + X0
    py = np.concatenate([rng.uniform(20, h - 20, 2000), scene.tree_c[k, 1] + rr * np.sin(aa)]) + Y0
    inside = (px > X0 + 20) & (px < X0 + w - 20) & (py > Y0 + 20) & (py < Y0 + h - 20)
    px, py = px[inside], py[inside]
    sel = rng.permutation(len(px))
    px, py = px[sel], py[sel]
    from scipy.spatial import cKDTree

    block = np.isin(cloud.classification, (6, 9))
    d, _ = cKDTree(np.column_stack([cloud.x[block], cloud.y[block]])).query(np.column_stack([px, py]))
    keep = np.flatnonzero(d > 3.0)[:2000]
    px, py = px[keep], py[keep]
    pz = scene.terrain_height(px - X0, py - Y0)
    csv = tmp / f"sim_points_{tag}.csv"
    csv.write_text("id,x,y,z\n" + "".join(f"S{k},{a:.3f},{b:.3f},{c:.3f}\n" for k, (a, b, c) in enumerate(zip(px, py, pz))))
    out = {"check_points": int(len(px))}
    for name, classes in (("lidarctl_classify", ours), ("truth_classes", cloud.classification)):
        c = dataclasses.replace(cloud, classification=classes)
        grids = rasters.make_grids(c, 1.0)
        t = grids.transform
        dem = tmp / f"sim_dem_{tag}_{name}.tif"
        write_dem(dem, grids.dem, t.c, t.f, 1.0, EPSG)
        las = tmp / f"sim_{tag}_{name}.laz"
        synthetic.write_las(las, c, crs=EPSG)
        r = hc.check_heights_file([las], csv, radius_m=5.0, exclude_m=1.0, dem_path=dem, grouping="density").document
        out[name] = {"dem_1m": table(r), "ground_points_plane_5m": table(r, None)}
        print(f"sim {tag} DEM ({name}):", {g: (v["n"], round(v["rmse_m"], 3)) for g, v in out[name]["dem_1m"].items()},
              flush=True)
    return out


def lidr_dem(tmp: Path, folds: int = 5):
    """The real forested set: class-2 points held out in folds (module docstring)."""
    from scipy.spatial import Delaunay

    from lidarctl import io
    from lidarctl.rasters import products as rasters
    from lidarctl.classify.ground import tin_heights

    full = io.read_cloud(LIDR)
    crs = full.crs
    gidx = np.flatnonzero(full.classification == 2)
    rng = np.random.default_rng(24)
    fold_of = rng.integers(0, folds, len(gidx))
    rows_dem, rows_tin, rows_plane, labels_all, cover_all = [], [], [], [], []
    # the density groups come from the full cloud (every first return) and one DEM of all its ground points
    grids = rasters.make_grids(full, 1.0)
    t = grids.transform
    write_dem(tmp / "lidr_dem_all.tif", grids.dem, t.c, t.f, 1.0, crs)
    synthetic.write_las(tmp / "lidr_full.laz", full, crs=crs)
    for f in range(folds):
        check = gidx[fold_of == f]
        keep = np.ones(len(full.x), bool)
        keep[check] = False
        c = PointCloud(*(getattr(full, k)[keep] for k in ("x", "y", "z", "intensity", "return_number",
                                                          "number_of_returns", "classification")), crs=crs)
        csv = tmp / f"lidr_check_{f}.csv"
        csv.write_text("id,x,y,z\n" + "".join(f"G{k},{full.x[k]:.3f},{full.y[k]:.3f},{full.z[k]:.3f}\n" for k in check))
        g = rasters.make_grids(c, 1.0)
        t = g.transform
        write_dem(tmp / f"lidr_dem_{f}.tif", g.dem, t.c, t.f, 1.0, crs)
        # the TIN DEM: Delaunay of the remaining ground and water points, sampled at the cell centres
        gm = np.isin(c.classification, (2, 9))
        gx, gy, gz = c.x[gm], c.y[gm], c.z[gm]
        tri = Delaunay(np.column_stack([gx - gx.min(), gy - gy.min()])).simplices
        nr, nc = g.dem.shape
        cc, rr = np.meshgrid(np.arange(nc), np.arange(nr))
        qx, qy = t.c + (cc.ravel() + 0.5) * t.a, t.f + (rr.ravel() + 0.5) * t.e
        tin = tin_heights(gx, gy, gz, tri, qx, qy).reshape(nr, nc)
        write_dem(tmp / f"lidr_tin_{f}.tif", np.where(np.isfinite(g.dem), tin, np.nan), t.c, t.f, 1.0, crs)
        # cloud without the check points: the ground-point check; the density from the full cloud + full DEM
        las = tmp / f"lidr_fold_{f}.laz"
        synthetic.write_las(las, c, crs=crs)
        dens = hc.check_heights_file([tmp / "lidr_full.laz"], csv, dem_path=tmp / "lidr_dem_all.tif",
                                     grouping="density").document
        labels = [p["group"] for p in dens["points"]]
        cover = [p["canopy_cover"] for p in dens["points"]]
        r_dem = hc.check_heights_file([las], csv, dem_path=tmp / f"lidr_dem_{f}.tif", grouping="none").document
        r_tin = hc.check_heights_file([las], csv, dem_path=tmp / f"lidr_tin_{f}.tif", grouping="none").document
        rows_dem += [p["dz_dem_m"] for p in r_dem["points"]]
        rows_tin += [p["dz_dem_m"] for p in r_tin["points"]]
        rows_plane += [p["dz_m"] for p in r_dem["points"]]
        labels_all += labels
        cover_all += cover
    out = {"points": int(len(full.x)), "ground_points_held_out": int(len(gidx)), "folds": folds,
           "group_counts": {g: labels_all.count(g) for g in hc.group_order(labels_all)}}
    for name, dz in (("dem_cells_1m", rows_dem), ("dem_tin", rows_tin), ("ground_points_plane_5m", rows_plane)):
        dz = np.array([np.nan if v is None else v for v in dz])
        res = {"groups": hc._group_stats_document(dz, labels_all, 1.0), "overall": hc._stats_document(dz, 1.0)}
        out[name] = table(res, None)
        print(f"lidr {name}:", {g: (v["n"], round(v["rmse_m"], 3)) for g, v in out[name].items()}, flush=True)
    return out, np.array([np.nan if v is None else v for v in cover_all])


def picture(pic, sim_tab, lidr_tab, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    scene, cloud, _, truth, model, r, _ = pic
    g = model.grid
    tx, ty, th, tr = truth
    # a W x W m window around the tree with the most trees within W/2 (a grove or the valley-side forest)
    from scipy.spatial import cKDTree

    W = 120.0
    n_near = np.array([len(v) for v in cKDTree(np.column_stack([tx, ty])).query_ball_point(
        np.column_stack([tx, ty]), W / 2)])
    k = int(np.argmax(n_near))
    wx0 = g.x0 + round((tx[k] - W / 2 - g.x0) / g.res_m) * g.res_m
    wy0 = g.y_top - round((g.y_top - (ty[k] - W / 2)) / g.res_m) * g.res_m
    c0, r1 = int(round((wx0 - g.x0) / g.res_m)), int(round((g.y_top - wy0) / g.res_m))
    c1, r0 = c0 + int(W / g.res_m), r1 - int(W / g.res_m)
    fig, axes = plt.subplots(1, 2, figsize=(15, 7), gridspec_kw={"width_ratios": [1.15, 1]})
    ax = axes[0]
    im = ax.imshow(model.chm[r0:r1, c0:c1], cmap="viridis", vmin=0, vmax=22, extent=(0, W, 0, W),
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.8, label="CHM: tree height above ground (m)")
    matched_true = set(r["matched_pairs"][:, 1].tolist())
    matched_top = set(r["matched_pairs"][:, 0].tolist())
    inwin = (tx >= wx0) & (tx < wx0 + W) & (ty >= wy0) & (ty < wy0 + W)
    for j in np.flatnonzero(inwin):
        ax.add_patch(Circle((tx[j] - wx0, ty[j] - wy0), tr[j], fill=False, lw=0.8,
                            color="w" if j in matched_true else "r"))
    t = model.tops
    w = (t.x >= wx0) & (t.x < wx0 + W) & (t.y >= wy0) & (t.y < wy0 + W)
    ok = np.array([k in matched_top for k in range(len(t.x))])
    ax.plot(t.x[w & ok] - wx0, t.y[w & ok] - wy0, "w+", ms=5, label="detected top, matched")
    ax.plot(t.x[w & ~ok] - wx0, t.y[w & ~ok] - wy0, "rx", ms=5, label="detected top, commission")
    ax.plot([], [], "o", mfc="none", mec="w", label="true crown (white: found, red: missed)")
    ax.set_xlim(0, W)
    ax.set_ylim(0, W)
    ax.legend(loc="lower left", fontsize=7, facecolor="0.85")
    ax.set_xlabel("m")
    ax.set_ylabel("m")
    ax.set_title(f"simulator seed {SCORE_SEED} (truth classes): detection {r['detection_rate']:.0%}, commission "
                 f"{r['commission']:.0%}, height RMSE {r['height_rmse_m']:.2f} m", fontsize=9)
    ax = axes[1]
    groups = ["open", "sparse", "dense"]
    series = [("sim demo, DEM of lidarctl classify", sim_tab["demo_seed_2"]["lidarctl_classify"]["dem_1m"]),
              ("sim forested, DEM of lidarctl classify", sim_tab["forested_seed_2"]["lidarctl_classify"]["dem_1m"]),
              ("sim forested, DEM of truth classes", sim_tab["forested_seed_2"]["truth_classes"]["dem_1m"]),
              ("lidr_topography, DEM 1 m cells", lidr_tab["dem_cells_1m"]),
              ("lidr_topography, DEM TIN", lidr_tab["dem_tin"])]
    wbar = 0.16
    for k, (name, tab) in enumerate(series):
        vals = [tab[g]["rmse_m"] if g in tab else np.nan for g in groups]
        ns = [tab[g]["n"] if g in tab else 0 for g in groups]
        bars = ax.bar(np.arange(3) + (k - 2) * wbar, vals, wbar, label=name)
        for b, n in zip(bars, ns):
            ax.annotate(f"{n}", (b.get_x() + b.get_width() / 2, b.get_height()), ha="center", va="bottom", fontsize=6)
    ax.set_xticks(np.arange(3), ["open (< 20 %)", "sparse (20-60 %)", "dense (> 60 %)"])
    ax.set_ylabel("DEM RMSE at check points (m); numbers: points")
    ax.set_xlabel("canopy cover of first returns > 2 m within 10 m")
    ax.legend(fontsize=7)
    ax.set_title("DEM accuracy by vegetation density (seed 004 Tab. 1 style)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    t0 = time.perf_counter()
    RESULTS.mkdir(exist_ok=True)
    trees, pic = sim_trees()
    with tempfile.TemporaryDirectory(prefix="eval_trees_") as tmp:
        tmp = Path(tmp)
        scene, cloud, ours = pic[0], pic[1], pic[2]
        sim_tab = {"demo_seed_2": sim_dem(scene, cloud, ours, tmp, "demo")}
        del scene, cloud, ours
        trees["forested_seed_2"], sim_tab["forested_seed_2"] = forested(tmp)
        lidr_tab, _ = lidr_dem(tmp)
    picture(pic, sim_tab, lidr_tab, RESULTS / "trees_sim.png")
    out = {"trees_sim": trees, "dem_by_density_sim": sim_tab, "dem_by_density_lidr_topography": lidr_tab,
           "density_groups": dataclasses.asdict(hc.DensityGroups()), "seconds": time.perf_counter() - t0}
    (RESULTS / "trees.json").write_text(json.dumps(out, indent=1, default=float) + "\n")
    print(f"bench/results/trees.json, bench/results/trees_sim.png ({out['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
