"""Water bodies that run out of the data in ``lidarctl vectors`` (``lidarctl.vectors.layers.lakes_at_edge``): lidR
Topography (its western lake is cut by the tile's west edge), the AHN3 Delft crop (canals leave the tile) and Autzen
(the Willamette falls about 1.25 m across the crop and leaves it at the north), each
classified by this checkout (``classify_file``, default settings; AHN3 with ``--crs EPSG:7415``), then the water layer
of ``extract_vectors`` with the rule and with it switched off in-process (``lakes_at_edge`` returning no cell: the
previous behaviour, gaps touching the grid's border never joined) and with one level for the whole rim
(``LOCAL_LEVEL_CELLS`` beyond any rim: the rule before the level beside each bank cell).

Reported per set and variant: the water polygons (area m2, water_z, bounds), how many have a NaN height, and the
delivered water points (class 9 of the input, the sets' own labels) inside the layer; areas in m2 from the CRS's
unit; Autzen's against the hand-digitised river outline (bench/reference, clipped to the data's convex hull):
intersection over union.
A classified file already in the work folder is reused (delete it after changing classify).
Writes bench/results/water_edge.json.
Run: .venv/bin/python bench/eval_water_edge.py [--work /tmp/water_edge]
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import laspy
import numpy as np
import pyproj
import shapely
from pyogrio.raw import read

DATA = Path("/work/shared/data")
SETS = {"topography": (DATA / "lidr_topography" / "Topography.laz", None),
        "ahn3_delft": (DATA / "ahn3_delft" / "ahn3_cropped_1.laz", "EPSG:7415"),
        "autzen": (DATA / "autzen" / "autzen_trim.laz", None)}
# the river outline digitised by hand from Autzen's orthophoto (feet, the cloud's CRS)
AUTZEN_OUTLINE = Path(__file__).resolve().parent / "reference" / "autzen_river_outline_ft.geojson"


def water_layer(path: Path):
    meta, _, wkb, fields = read(path, layer="water")
    f = dict(zip(meta["fields"], fields))
    return [shapely.from_wkb(b) for b in wkb], np.asarray(f["water_z"], float)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/water_edge"))
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    from lidarctl.tiles import classify_file
    from lidarctl.vectors import layers

    args.work.mkdir(parents=True, exist_ok=True)
    doc = {"what": __doc__.split("\n\n")[0].replace("\n", " ")}
    rule = layers.lakes_at_edge
    local_cells = layers.LOCAL_LEVEL_CELLS
    for name, (src, crs) in SETS.items():
        if not src.exists():
            doc[name] = f"skipped: {src} absent"
            continue
        classified = args.work / f"{name}.laz"
        if not classified.exists():
            classify_file(src, classified, crs=crs)
        delivered = laspy.read(src)
        wx, wy = (np.asarray(v)[np.asarray(delivered.classification) == 9] for v in (delivered.x, delivered.y))
        doc[name] = {"delivered_water_points": int(len(wx))}
        # the square of the CRS's linear unit in metres (the layer is written in the cloud's CRS: Autzen in feet)
        unit_m = pyproj.CRS(crs or delivered.header.parse_crs()).axis_info[0].unit_conversion_factor
        hull = shapely.MultiPoint(np.column_stack([delivered.x, delivered.y])).convex_hull
        outline = None
        if name == "autzen":
            outline = shapely.Polygon(json.loads(AUTZEN_OUTLINE.read_text())["features"][0]["geometry"]
                                      ["coordinates"][0]).intersection(hull)
        for variant in ("rule", "one_level_for_the_rim", "gaps_at_the_border_never_join"):
            if variant == "gaps_at_the_border_never_join":
                layers.lakes_at_edge = lambda void, *a, **k: np.zeros(void.shape, bool)
            elif variant == "one_level_for_the_rim":  # every wet rim cell in the level beside each bank cell
                layers.LOCAL_LEVEL_CELLS = 10**9
            try:
                out = args.work / f"{name}_{variant}.gpkg"
                layers.write_vectors(layers.extract_vectors([classified], out, crs=crs), out)
            finally:
                layers.lakes_at_edge, layers.LOCAL_LEVEL_CELLS = rule, local_cells
            polys, z = water_layer(out)
            union = shapely.union_all(polys) if polys else shapely.Polygon()
            doc[name][variant] = {
                "polygons": [{"area_m2": round(p.area * unit_m**2, 1),
                              "water_z": None if np.isnan(h) else round(float(h), 3),
                              "bounds": [round(b, 1) for b in p.bounds]} for p, h in zip(polys, z)],
                "area_m2": round(union.area * unit_m**2, 1), "nan_heights": int(np.isnan(z).sum()),
                "delivered_water_points_inside": int(shapely.contains_xy(union, wx, wy).sum()) if len(wx) else 0}
            if outline is not None:
                doc[name][variant]["outline_in_data_m2"] = round(outline.area * unit_m**2, 1)
                doc[name][variant]["iou_with_outline"] = round(
                    union.intersection(outline).area / union.union(outline).area, 3)
    out = Path(__file__).resolve().parent / "results" / "water_edge.json"
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
