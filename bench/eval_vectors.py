"""The line map (DLG) of the simulator's projects checked against the scene's true vectors.

    .venv/bin/python bench/eval_vectors.py [--out results] [--keep DIR] [--presets tiny demo]

Per project (``tiny``: where the defaults of ``lidarctl vectors`` were set by looking at the result,
development; ``demo``: not looked at before, held-out): simulate (``--keep DIR``: there, reused), classify
the strips fused with the true orthophoto (RGB + NIR; roads, class 11, need the fusion), then
``lidarctl vectors`` (with ``--image truth/ortho.tif --dem truth/dem.tif``) and ``lidarctl check-vectors``
against a reference GeoPackage written from the simulator's scene (rebuilt from the preset's seed as
``aerotri sim`` builds it): buildings = the roof (eave) outlines, roads = the union of the road rectangles,
road_centrelines = the road axes, water = the pond outlines. Also the eave and ridge heights of the buildings
against the scene's (the product building overlapping a true one most), and the centre lines' widths against
the true width of the nearest road axis.

The demo's GeoPackage is opened a second time without pyogrio (geopandas and fiona are not installed):
``sqlite3`` on the GeoPackage tables (gpkg_contents, gpkg_geometry_columns, gpkg_spatial_ref_sys and the
feature tables, GeoPackage binary geometry headers parsed by hand), the layers and CRS compared with
pyogrio's, and drawn from the sqlite reading to bench/results/vectors_demo.png.

Writes bench/results/vectors_demo.json, bench/results/vectors_demo.png (the DLG), bench/results/vectors_demo_check.png
(offset vectors of the demo's building corners).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sqlite3
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import shapely

from aerotri.sim import load_preset, simulate
from aerotri.sim.flight import block_layout
from aerotri.sim.scene import build_scene
from lidarctl.classify import fusion as fu
from lidarctl import tiles
from lidarctl.checks import vectors as vc
from lidarctl.classify.pipeline import ClassifySettings
from lidarctl.vectors.layers import MapVectorSettings, draw_layers, vectors_to_file

REPO = Path(__file__).resolve().parents[1]
ROLES = {"tiny": "development", "demo": "held-out"}


def project(name: str, root: Path) -> tuple[Path, list]:
    proj = root / name
    if not (proj / "truth" / "classes.tif").is_file():
        simulate(load_preset(name), proj, force=True)
    fused = root / f"{name}_fused"
    if not fused.is_dir() or not any(fused.glob("*.las")):
        fusion = fu.Fusion(fu.open_image(proj / "truth" / "ortho.tif", str(proj / "truth" / "ortho_nir.tif")))
        tiles.classify_files(sorted((proj / "lidar").glob("*.las")), fused, params=ClassifySettings(), fusion=fusion)
    return proj, sorted(fused.glob("*.las"))


def true_scene(name: str):
    """The scene ``aerotri sim`` builds for the preset (same seeds) and its origin."""
    cfg = load_preset(name)
    ss = np.random.SeedSequence(int(cfg.preset.seed))
    s_scene = ss.spawn(4)[0]
    origin = np.array([cfg.crs.origin_e_m, cfg.crs.origin_n_m, cfg.crs.base_height_m])
    layout = block_layout(cfg)
    seed = int(np.random.default_rng(s_scene).integers(0, 2**31 - 1))
    return build_scene(cfg.scene, layout.width_m, layout.height_m, origin, seed), origin, int(cfg.crs.epsg)


def write_reference(scene, origin, epsg: int, path: Path) -> dict:
    import pyproj
    from pyogrio.raw import write

    sh = lambda g: shapely.affinity.translate(g, origin[0], origin[1])  # noqa: E731
    bl = [sh(b.outline) for b in scene.buildings]
    rects = [shapely.LineString([(r[0], r[1]), (r[2], r[3])]).buffer(r[4] / 2, cap_style="flat") for r in scene.roads]
    road_union = shapely.union_all(rects) if rects else shapely.Polygon()
    roads = [sh(g) for g in getattr(road_union, "geoms", [road_union])]
    axes = [sh(shapely.LineString([(r[0], r[1]), (r[2], r[3])])) for r in scene.roads]
    ponds = [sh(shapely.affinity.rotate(shapely.affinity.scale(shapely.Point(p[0], p[1]).buffer(1.0, 32), p[2], p[3]),
                                        p[4], origin=(p[0], p[1]), use_radians=True)) for p in scene.ponds]
    crs = pyproj.CRS.from_epsg(epsg).to_wkt()
    layers = {"buildings": (bl, "Polygon", {"building_id": np.array([b.building_id for b in scene.buildings]),
                                            "eave_z": np.array([b.eave_z_m + origin[2] for b in scene.buildings]),
                                            "ridge_z": np.array([b.ridge_z_m + origin[2] for b in scene.buildings])}),
              "roads": (roads, "Polygon", {"area_m2": np.array([g.area for g in roads])}),
              "road_centrelines": (axes, "LineString", {"width_m": np.array([r[4] for r in scene.roads])}),
              "water": (ponds, "Polygon", {"area_m2": np.array([g.area for g in ponds])})}
    path.unlink(missing_ok=True)
    for i, (name, (geoms, gtype, fields)) in enumerate(layers.items()):
        write(path, np.array(shapely.to_wkb(np.array(geoms, dtype=object)), dtype=object), field_data=list(fields.values()),
              fields=list(fields), geometry_type=gtype, crs=crs, driver="GPKG", layer=name, append=i > 0)
    return {k: len(v[0]) for k, v in layers.items()}


def height_errors(product: Path, scene, origin) -> dict:
    from pyogrio.raw import read

    meta, _, wkb, fields = read(product, layer="buildings")
    names = list(meta["fields"])
    eave, ridge = fields[names.index("eave_z")], fields[names.index("ridge_z")]
    prod = [shapely.from_wkb(b) for b in wkb]
    true = [shapely.affinity.translate(b.outline, origin[0], origin[1]) for b in scene.buildings]
    tree = shapely.STRtree(true)
    de, dr, kinds = [], [], []
    for k, g in enumerate(prod):
        cand = tree.query(g, predicate="intersects")
        if not len(cand):
            continue
        j = max(cand, key=lambda i: g.intersection(true[i]).area)
        b = scene.buildings[j]
        de.append(eave[k] - (b.eave_z_m + origin[2]))
        dr.append(ridge[k] - (b.ridge_z_m + origin[2]))
        kinds.append(b.roof)
    de, dr, kinds = np.array(de), np.array(dr), np.array(kinds)
    out = {"n_matched": len(de)}
    for roof in ("all", "flat", "gable", "hip"):
        m = np.ones(len(de), bool) if roof == "all" else kinds == roof
        if m.any():
            out[roof] = {"n": int(m.sum()), "eave_rms_m": float(np.sqrt(np.mean(de[m] ** 2))),
                         "eave_mean_m": float(de[m].mean()), "ridge_rms_m": float(np.sqrt(np.mean(dr[m] ** 2))),
                         "ridge_mean_m": float(dr[m].mean())}
    return out


def width_errors(product: Path, scene, origin) -> dict:
    """Centre-line width against the true width of the road whose axis is nearest to the line's midpoint."""
    from pyogrio.raw import read

    meta, _, wkb, fields = read(product, layer="road_centrelines")
    width = fields[list(meta["fields"]).index("width_m")]
    lines = [shapely.from_wkb(b) for b in wkb]
    axes = [shapely.LineString([(r[0] + origin[0], r[1] + origin[1]), (r[2] + origin[0], r[3] + origin[1])])
            for r in scene.roads]
    d = []
    for ln, w in zip(lines, width):
        mid = ln.interpolate(0.5, normalized=True)
        j = int(np.argmin([a.distance(mid) for a in axes]))
        d.append(w - scene.roads[j][4])
    d = np.array(d)
    lengths = np.array([ln.length for ln in lines])
    return {"n_lines": len(d), "width_rms_m": float(np.sqrt(np.mean(d**2))) if len(d) else None,
            "width_mean_m": float(d.mean()) if len(d) else None,
            "width_rms_length_weighted_m": float(np.sqrt(np.average(d**2, weights=lengths))) if len(d) else None}


# ------------------------------------------------------------------------------- the second reader: sqlite3
def _gpkg_geometry(blob: bytes):
    """A GeoPackage binary geometry: 'GP', version, flags (envelope code in bits 1-3), srs_id, envelope, WKB."""
    if blob is None:
        return None
    assert blob[:2] == b"GP", "not a GeoPackage geometry"
    flags = blob[3]
    env = {0: 0, 1: 32, 2: 48, 3: 48, 4: 64}[(flags >> 1) & 0x07]
    return shapely.from_wkb(blob[8 + env:])


def read_gpkg_sqlite(path: Path) -> dict:
    """{layer: {"geometries", "srs_id", "crs_wkt", "fields"}} read with sqlite3 only."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        out = {}
        rows = con.execute("SELECT c.table_name, g.column_name, g.srs_id, s.definition FROM gpkg_contents c "
                           "JOIN gpkg_geometry_columns g ON g.table_name = c.table_name "
                           "JOIN gpkg_spatial_ref_sys s ON s.srs_id = g.srs_id WHERE c.data_type = 'features'").fetchall()
        for table, geom_col, srs_id, wkt in rows:
            cols = [r[1] for r in con.execute(f'PRAGMA table_info("{table}")')]
            data = con.execute(f'SELECT * FROM "{table}"').fetchall()
            gi = cols.index(geom_col)
            out[table] = {"geometries": [_gpkg_geometry(r[gi]) for r in data], "srs_id": srs_id, "crs_wkt": wkt,
                          "fields": [c for c in cols if c not in (geom_col, "fid")],
                          "srs_id_in_blobs": sorted({struct.unpack("<i" if r[gi][3] & 1 else ">i", r[gi][4:8])[0]
                                                     for r in data if r[gi] is not None})}
        return out
    finally:
        con.close()


def compare_readers(path: Path) -> dict:
    import pyogrio
    import pyproj
    from pyogrio.raw import read

    sq = read_gpkg_sqlite(path)
    out = {}
    for name, _ in pyogrio.list_layers(path):
        meta, _, wkb, _ = read(path, layer=name)
        a = [shapely.from_wkb(b) for b in wkb]
        b = sq[name]["geometries"]
        same = len(a) == len(b) and all(shapely.equals_exact(x, y, 1e-9) for x, y in zip(a, b))
        out[str(name)] = {"features_pyogrio": len(a), "features_sqlite": len(b), "geometries_equal": bool(same),
                          "crs_equal": pyproj.CRS(meta["crs"]) == pyproj.CRS(sq[name]["crs_wkt"]),
                          "fields_pyogrio": [str(f) for f in meta["fields"]], "fields_sqlite": sq[name]["fields"],
                          "srs_id": sq[name]["srs_id"]}
    return out


def draw_from_sqlite(path: Path, image: Path, png: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pyproj
    import rasterio
    from rasterio.enums import Resampling

    sq = read_gpkg_sqlite(path)
    fig, ax = plt.subplots(figsize=(12, 12))
    with rasterio.open(image) as src:
        f = max(1, int(np.ceil(max(src.width, src.height) / 2000)))
        rgb = src.read(indexes=[1, 2, 3], out_shape=(3, src.height // f, src.width // f), resampling=Resampling.average)
        b = src.bounds
    ax.imshow(np.moveaxis(rgb, 0, -1), extent=(b.left, b.right, b.bottom, b.top), alpha=0.55)
    draw_layers(ax, {name: v["geometries"] for name, v in sq.items()})
    crs = pyproj.CRS(next(iter(sq.values()))["crs_wkt"])
    x0 = b.left + 0.05 * (b.right - b.left)
    y0 = b.bottom + 0.04 * (b.top - b.bottom)
    ax.plot([x0, x0 + 100], [y0, y0], color="k", lw=4)
    ax.text(x0 + 50, y0 + 0.01 * (b.top - b.bottom), "100 m", ha="center")
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_xlabel(f"easting ({crs.name})")
    ax.set_ylabel("northing")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--keep", type=Path, default=None, help="Keep (and reuse) the simulated projects here.")
    ap.add_argument("--presets", nargs="+", default=["tiny", "demo"])
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="eval_vectors_"))
    root = args.keep or tmp
    result = {"command": "lidarctl classify STRIPS OUT --image truth/ortho.tif --nir truth/ortho_nir.tif; "
                         "lidarctl vectors OUT/*.las DLG.gpkg --image truth/ortho.tif --dem truth/dem.tif; "
                         "lidarctl check-vectors DLG.gpkg --reference REF.gpkg",
              "params": dataclasses.asdict(MapVectorSettings()),
              "projects": {}}
    try:
        for name in args.presets:
            proj, strips = project(name, root)
            dlg, ref = tmp / f"{name}_dlg.gpkg", tmp / f"{name}_reference.gpkg"
            t0 = time.perf_counter()
            summary = vectors_to_file(strips, dlg, params=MapVectorSettings(), dem=proj / "truth" / "dem.tif",
                                      image=proj / "truth" / "ortho.tif")
            seconds = time.perf_counter() - t0
            scene, origin, epsg = true_scene(name)
            n_ref = write_reference(scene, origin, epsg, ref)
            png = args.out / f"vectors_{name}_check.png" if name == "demo" else None
            check = vc.check_files(dlg, ref, vc.VectorCheckSettings(), png_path=png)
            print(f"--- {name} ({ROLES.get(name)}): vectors {seconds:.0f} s\n{vc.format_report(check)}")
            entry = {"role": ROLES.get(name), "vectors_seconds": seconds,
                     "vectors": {**{k: v for k, v in dataclasses.asdict(summary.counts).items()
                                    if k != "contours" or v is not None}, "units": summary.units.as_dict()},
                     "reference_features": n_ref, "check": check.document, "heights": height_errors(dlg, scene, origin),
                     "road_widths": width_errors(dlg, scene, origin)}
            print("heights:", json.dumps(entry["heights"]["all"]))
            print("road widths:", json.dumps(entry["road_widths"]))
            if name == "demo":
                entry["second_reader"] = compare_readers(dlg)
                draw_from_sqlite(dlg, proj / "truth" / "ortho.tif", args.out / "vectors_demo.png",
                                 f"demo DLG read with sqlite3 (layers: {', '.join(entry['second_reader'])})")
                shutil.copy(dlg, tmp / "keep_demo_dlg.gpkg")
                if args.keep:
                    shutil.copy(dlg, args.keep / "demo_dlg.gpkg")
                    shutil.copy(ref, args.keep / "demo_reference.gpkg")
            result["projects"][name] = entry
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out = args.out / ("vectors_demo.json" if "demo" in args.presets else "vectors_tiny.json")
    out.write_text(json.dumps(result, indent=2, default=float))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
