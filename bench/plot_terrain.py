"""Pictures of the terrain products: contours and streams over the hillshade (issue 24), from the real commands.

    .venv/bin/python bench/plot_terrain.py [--which demo lidr] [--work out/plot_terrain] [--out results]

Each map is made by the CLIs, in order: ``lidarctl classify`` -> ``lidarctl rasters`` -> ``lidarctl smooth`` (the
DEM) -> ``lidarctl contours --smooth bspline`` -> ``lidarctl drainage``, and drawn in one figure: the smoothed
DEM's hillshade, contours (index contours bolder and labelled), streams coloured and thickened by Strahler
order, a scale bar and a legend.

- demo: the simulator's ``demo`` project (out/demo/project of this checkout or of ../main, read only; else
  ``aerotri sim --preset demo`` into the work folder). Its LiDAR strips as ``aerotri run`` classified them
  (lidar_out/classified, made by ``lidarctl classify``) when present, else classified here. The simulator has no
  valley line (its valley is a ramp: bench/eval_drainage.py carves one for its score), so the reference drawn is
  the streams of the TRUE terrain (truth/dem.tif through the same ``lidarctl drainage``): dashed gold.
- lidr: ../shared/data/lidr_topography/Topography.laz (lidR's example, 288 x 288 m, EPSG:26917 NAD83 / UTM 17N),
  classified here, 2 m cells (8,159 ground points leave most 1 m cells to the gap filling).

Writes bench/results/terrain_demo.png, bench/results/terrain_lidr.png and bench/results/terrain.json (the commands' outputs).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
# ../shared/data beside the checkout (or beside ../main's, from a worktree under ../wt/)
SHARED = Path(os.environ.get("AEROTRI_SHARED_DATA") or next(
    (p for p in (REPO.parent / "shared" / "data", REPO.parent.parent / "shared" / "data") if p.is_dir()),
    REPO.parent / "shared" / "data"))
DEMOS = [REPO / "out" / "demo" / "project", REPO.parent.parent / "main" / "out" / "demo" / "project"]
EXE = Path(sys.executable).with_name("lidarctl")

# per map: raster cell (m), contour interval (m), index every, stream threshold (m2)
SETTINGS = {"demo": {"res": 1.0, "interval": 2.0, "index": 5, "min_area_m2": 20_000.0},
            "lidr": {"res": 2.0, "interval": 2.0, "index": 5, "min_area_m2": 2_000.0}}


FILLED_M = 0.1  # a stream cell raised more than this by the depression fill lies in a filled depression


def _runs(flags: np.ndarray):
    """(first, last, value) of the runs of equal values in a boolean array."""
    if len(flags) == 0:
        return []
    cut = np.flatnonzero(np.diff(flags.astype(np.int8))) + 1
    starts, ends = np.r_[0, cut], np.r_[cut, len(flags)] - 1
    return [(int(a), int(b), bool(flags[a])) for a, b in zip(starts, ends)]


REUSE = False  # --reuse: keep the products already in the work folder (redraw only)


def run(*args) -> str:
    if REUSE:
        return "(reused)"
    r = subprocess.run([str(a) for a in args], check=True, capture_output=True, text=True)
    print(" ".join(str(a) for a in args[1:3]), "...:", r.stdout.strip().splitlines()[-1] if r.stdout.strip() else "")
    return r.stdout.strip()


def products(classified: list, work: Path, s: dict, crs=None) -> dict:
    """rasters -> smooth -> contours -> drainage of classified cloud(s) into ``work``; the commands' last lines."""
    log = {}
    crs_opt = ["--crs", crs] if crs else []
    log["rasters"] = run(EXE, "rasters", *classified, work / "rasters", "--res-m", s["res"], *crs_opt)
    log["smooth"] = run(EXE, "smooth", work / "rasters" / "dem.tif", work / "dem_smooth.tif")
    log["contours"] = run(EXE, "contours", work / "dem_smooth.tif", work / "contours.gpkg", "--interval-m", s["interval"],
                          "--index", s["index"], "--smooth", "bspline")
    log["drainage"] = run(EXE, "drainage", work / "dem_smooth.tif", work / "drainage", "--min-area-m2",
                          s["min_area_m2"])
    return log


def read_lines(path: Path, layer: str, fields: tuple) -> tuple[list, dict]:
    import shapely
    from pyogrio.raw import read

    meta, _, wkb, data = read(path, layer=layer)
    names = list(meta["fields"])
    return shapely.from_wkb(wkb), {f: np.asarray(data[names.index(f)]) for f in fields}


def _scale_bar(ax, extent, unit="m"):
    """A black-and-white bar of a round length (~1/5 of the map width) in the lower left."""
    w = extent[1] - extent[0]
    raw = w / 5
    length = min((b * 10**e for e in range(0, 5) for b in (1, 2, 5)), key=lambda v: abs(v - raw))
    x0, y0 = extent[0] + 0.04 * w, extent[2] + 0.05 * (extent[3] - extent[2])
    h = 0.012 * (extent[3] - extent[2])
    for k in range(4):
        ax.add_patch(__import__("matplotlib.patches").patches.Rectangle(
            (x0 + k * length / 4, y0), length / 4, h, facecolor="k" if k % 2 == 0 else "w", edgecolor="k", lw=0.8,
            zorder=6))
    ax.text(x0, y0 + 1.8 * h, "0", ha="center", va="bottom", fontsize=8, zorder=6,
            bbox=dict(fc="w", ec="none", alpha=0.7, pad=0.5))
    ax.text(x0 + length, y0 + 1.8 * h, f"{length:g} {unit}", ha="center", va="bottom", fontsize=8, zorder=6,
            bbox=dict(fc="w", ec="none", alpha=0.7, pad=0.5))


def draw(work: Path, out_png: Path, title: str, truth_streams: Path | None = None) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import rasterio
    import shapely
    from matplotlib.lines import Line2D

    from lidarctl.rasters.products import hillshade

    with rasterio.open(work / "dem_smooth.tif") as src:
        dem = src.read(1, masked=True).astype(float).filled(np.nan)
        t = src.transform
    ny, nx = dem.shape
    extent = (t.c, t.c + nx * t.a, t.f + ny * t.e, t.f)
    hs = hillshade(dem, abs(t.a))
    cont, cf = read_lines(work / "contours.gpkg", "contours", ("elevation", "index"))
    streams, sf = read_lines(work / "drainage" / "drainage.gpkg", "streams", ("strahler_order",))
    aspect = ny / nx
    fig, ax = plt.subplots(figsize=(12.5, min(13.0, 8.5 * aspect + 1.2)))
    ax.imshow(hs, cmap="gray", extent=extent, vmin=-0.1, vmax=1.05, interpolation="bilinear")
    # height tint without terrain's blue low end (which reads as water)
    tint = matplotlib.colors.LinearSegmentedColormap.from_list("land", plt.get_cmap("terrain")(np.linspace(0.25, 0.95, 64)))
    ax.imshow(dem, cmap=tint, extent=extent, alpha=0.25, interpolation="bilinear")
    label_min = 0.15 * (extent[1] - extent[0])
    for g, z, idx in zip(cont, cf["elevation"], cf["index"]):
        xy = np.asarray(g.coords)
        ax.plot(xy[:, 0], xy[:, 1], color="#7a3b10", lw=1.1 if idx else 0.45, alpha=0.95 if idx else 0.8, zorder=3)
        if idx and g.length > label_min:
            p = g.interpolate(0.5, normalized=True)
            q = g.interpolate(min(1.0, 0.5 + 2.0 / g.length), normalized=True)
            ang = np.degrees(np.arctan2(q.y - p.y, q.x - p.x))
            ang = ang - 180 if ang > 90 else ang + 180 if ang < -90 else ang
            ax.text(p.x, p.y, f"{z:g}", fontsize=7, color="#7a3b10", rotation=ang, ha="center", va="center",
                    rotation_mode="anchor", zorder=4, bbox=dict(fc="w", ec="none", alpha=0.6, pad=0.2))
    orders = sf["strahler_order"].astype(int)
    top = max(int(orders.max(initial=1)), 1)
    cmap = plt.get_cmap("cool", top)
    with rasterio.open(work / "drainage" / "conditioned.tif") as src:
        filled = src.read(1, masked=True).astype(float).filled(np.nan) - dem  # depth the depression fill added
    n_filled_m = 0.0
    for g, o in sorted(zip(streams, orders), key=lambda v: v[1]):
        # D8 paths across a filled depression are straight lines to its spill point, not channels: dotted
        if shapely.get_num_coordinates(g) < 2 or g.length == 0:  # a one-cell segment (a confluence at the outlet)
            continue
        g = shapely.segmentize(g, abs(t.a))
        xy = np.asarray(g.coords)
        col, row = ~t * (xy[:, 0], xy[:, 1])
        r = np.clip(row.astype(int), 0, ny - 1)
        c = np.clip(col.astype(int), 0, nx - 1)
        in_pit = np.nan_to_num(filled[r, c]) > FILLED_M
        seg_pit = in_pit[:-1] & in_pit[1:]
        for k0, k1, pit in _runs(seg_pit):
            part = xy[k0:k1 + 2]
            ax.plot(part[:, 0], part[:, 1], color=cmap(o - 1), lw=(0.6 + 0.8 * o) * (0.6 if pit else 1.0),
                    ls=(0, (1, 1.5)) if pit else "-", solid_capstyle="round", zorder=5)
            if pit:
                n_filled_m += float(np.hypot(*np.diff(part, axis=0).T).sum())
    handles = [Line2D([], [], color="#7a3b10", lw=0.45, label="contour"),
               Line2D([], [], color="#7a3b10", lw=1.1, label="index contour")]
    handles += [Line2D([], [], color=cmap(o - 1), lw=0.6 + 0.8 * o, label=f"stream, Strahler order {o}")
                for o in range(1, top + 1)]
    handles.append(Line2D([], [], color="0.3", lw=0.9, ls=(0, (1, 1.5)),
                          label=f"flow path across a filled depression (> {FILLED_M:g} m)"))
    n_true = 0
    if truth_streams is not None:
        tl, _ = read_lines(truth_streams, "streams", ("strahler_order",))
        for g in tl:
            xy = np.asarray(g.coords)
            ax.plot(xy[:, 0], xy[:, 1], color="gold", lw=1.0, ls=(0, (4, 3)), zorder=6)
        n_true = int(len(tl))
        handles.append(Line2D([], [], color="gold", lw=1.0, ls=(0, (4, 3)),
                              label="streams of the TRUE terrain (same command)"))
    _scale_bar(ax, extent)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.85)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    ax.set_xlabel("easting (m)")
    ax.set_ylabel("northing (m)")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=85, bbox_inches="tight")
    plt.close(fig)
    lengths = shapely.length(streams)
    return {"contours": int(len(cont)), "index_contours": int(cf["index"].sum()), "stream_segments": int(len(streams)),
            "stream_length_m_by_order": {str(o): float(lengths[orders == o].sum()) for o in range(1, top + 1)},
            "stream_length_m_across_filled_depressions": n_filled_m, "true_terrain_stream_segments": n_true,
            "png": str(out_png)}


def demo(work: Path, out: Path) -> dict:
    project = next((d for d in DEMOS if d.is_dir()), None)
    if project is None:
        project = work / "sim_demo"
        subprocess.run([str(Path(sys.executable).with_name("aerotri")), "sim", "--preset", "demo", "--force",
                        str(project)], check=True)
    s = SETTINGS["demo"]
    classified = sorted((project / "lidar_out" / "classified").glob("strip_*.la[sz]"))
    log = {}
    if not classified:
        log["classify"] = run(EXE, "classify", *sorted((project / "lidar").glob("strip_*.la[sz]")), work / "classified")
        classified = sorted((work / "classified").glob("strip_*.la[sz]"))
    log.update(products(classified, work, s))
    log["drainage_truth"] = run(EXE, "drainage", project / "truth" / "dem.tif", work / "drainage_truth",
                                "--min-area-m2", s["min_area_m2"])
    info = draw(work, out / "terrain_demo.png",
                f"simulator demo: smoothed LiDAR DEM ({s['res']:g} m), contours every {s['interval']:g} m (B-spline), "
                f"streams >= {s['min_area_m2'] / 1e4:g} ha", work / "drainage_truth" / "drainage.gpkg")
    return {"project": str(project), "classified": [str(p) for p in classified], **s, "commands": log, **info}


def lidr(work: Path, out: Path) -> dict:
    laz = SHARED / "lidr_topography" / "Topography.laz"
    s = SETTINGS["lidr"]
    log = {"classify": run(EXE, "classify", laz, work / "classified.laz")}
    log.update(products([work / "classified.laz"], work, s))
    info = draw(work, out / "terrain_lidr.png",
                f"lidr_topography: smoothed DEM ({s['res']:g} m), contours every {s['interval']:g} m (B-spline), "
                f"streams >= {s['min_area_m2']:g} m2")
    return {"source": str(laz), **s, "commands": log, **info}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--which", nargs="+", default=["demo", "lidr"], choices=["demo", "lidr"])
    ap.add_argument("--work", type=Path, default=REPO / "out" / "plot_terrain")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--reuse", action="store_true", help="Redraw from the products already in --work.")
    args = ap.parse_args()
    global REUSE
    REUSE = args.reuse
    path = args.out / "terrain.json"
    res = json.loads(path.read_text()) if path.exists() else {}
    for name in args.which:
        if REUSE and name in res:
            res[name].update({k: v for k, v in {"demo": demo, "lidr": lidr}[name](args.work / name, args.out).items()
                              if k != "commands"})
            continue
        res[name] = {"demo": demo, "lidr": lidr}[name](args.work / name, args.out)
    path.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
