"""``lidarctl evaluate --reference``: pixel confusion matrix, kappa and building accuracy on 20 x 20 cell maps
whose counts are worked out by hand (see ``_maps``)."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pyproj
import pytest
import rasterio
import shapely
from click.testing import CliRunner
from pyogrio.raw import write as write_vector
from rasterio.transform import from_origin

from lidarctl.classify import class_grid as cg
from lidarctl.checks import classes as evaluate
from lidarctl.checks import map_accuracy
from lidarctl.cli.main import main
from aerotri.geom.las import FOOT_M

X0, Y0 = 500000.0, 5400000.0   # south-west corner of the 20 x 20 cell area (CRS units)
N = 20
M_CRS, FT_CRS = "EPSG:32632", "EPSG:2994"


def _maps():
    """Prediction (ASPRS, medium veg 4 for the tree) and reference (tree 5, one nodata cell), rows from north.

    prediction: building rows 2-7 x cols 2-7 (36), tree rows 12-15 x cols 12-15 (16), road rows 18-19 (40),
    the rest ground; reference: the building one column east (rows 2-7 x cols 3-8), the same tree and road,
    cell (0, 0) nodata. On the 399 labelled cells: building 30 hit, 6 missed, 6 false; ground 301 hit.
    """
    pred = np.full((N, N), 2, np.uint8)
    pred[2:8, 2:8] = 6
    pred[12:16, 12:16] = 4
    pred[18:20, :] = 11
    ref = np.full((N, N), 2, np.uint8)
    ref[2:8, 3:9] = 6
    ref[12:16, 12:16] = 5
    ref[18:20, :] = 11
    ref[0, 0] = cg.IGNORE
    return pred, ref


def _write_cloud(path, pred, crs, unit_m=1.0):
    """One point per cell centre with the cell's class (1 CRS unit cells), a ground point under each tree
    cell and a high-noise point over a ground cell (neither must show in the class raster)."""
    rows, cols = np.nonzero(np.ones_like(pred, bool))
    x, y = X0 + cols + 0.5, Y0 + N - rows - 0.5
    cls = pred[rows, cols]
    z = 10.0 + np.where(cls == 6, 20.0, np.where(cls == 4, 8.0, 0.0))
    tree = cls == 4
    x, y = np.r_[x, x[tree], X0 + 10.5], np.r_[y, y[tree], Y0 + 10.5]
    z, cls = np.r_[z, np.full(tree.sum(), 10.0), 100.0], np.r_[cls, np.full(tree.sum(), 2), 18]
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.array([X0, Y0, 0.0])
    header.add_crs(pyproj.CRS(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z / unit_m
    las.classification = cls.astype(np.uint8)
    las.write(str(path))


def _write_raster(path, classes, crs, nodata=255):
    with rasterio.open(path, "w", driver="GTiff", width=N, height=N, count=1, dtype="uint8", crs=crs,
                       transform=from_origin(X0, Y0 + N, 1.0, 1.0), nodata=nodata) as ds:
        ds.write(classes, 1)


def _box(r0, r1, c0, c1):
    """Polygon over rows r0..r1-1, cols c0..c1-1 (cell edges, CRS units)."""
    return shapely.box(X0 + c0, Y0 + N - r1, X0 + c1, Y0 + N - r0)


def _write_polygons(path, polys, classes, crs, field="class"):
    wkb = np.array([shapely.to_wkb(p) for p in polys], dtype=object)
    fields = [np.array(classes, dtype=object)] if field else []
    write_vector(path, wkb, fields, [field] if field else [], geometry_type="Polygon", crs=crs,
                 driver="GeoJSON" if str(path).endswith("json") else "GPKG")


def _run(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_confusion_kappa_by_hand():
    # 2 x 2: po = 0.7, pe = (5*6 + 5*4) / 100 = 0.5 -> kappa 0.4
    truth = np.array([1] * 5 + [2] * 5)
    pred = np.array([1, 1, 1, 1, 2, 1, 1, 2, 2, 2])
    c = evaluate.confusion(pred, truth)
    assert c.overall_accuracy_pct == pytest.approx(70.0)
    assert c.kappa_pct == pytest.approx(40.0)


def test_building_accuracy_by_count_and_area():
    pred, ref = _maps()
    valid = ref != cg.IGNORE
    ref_b = ref == 6
    ref_b[10:14, 2:6] = True   # a second reference building (16 cells) that the prediction misses
    pred_b = pred == 6
    pred_b[0:3, 16:20] = True  # a false detection of 12 cells
    pred_b[9, 9] = True        # a one-cell speck: below min_building_m2 (area 0.25 m2 per cell)
    b = map_accuracy.building_accuracy(pred_b, ref_b, valid, cell_area_m2=0.25, min_overlap=0.5, min_building_m2=1.0)
    assert (b.n_reference, b.n_found, b.n_detected, b.n_correct) == (2, 1, 2, 1)
    assert b.completeness_count_pct == pytest.approx(50.0) and b.correctness_count_pct == pytest.approx(50.0)
    # area: reference 52 cells, 30 found; false 6 + 12 + 1 = 19 of 399 - 52 = 347 non-building cells
    assert b.type_i_error_pct == pytest.approx(100 * 22 / 52)
    assert b.type_ii_error_pct == pytest.approx(100 * 19 / 347)
    assert b.overall_accuracy_pct == pytest.approx(100 * (399 - 41) / 399)
    assert b.completeness_area_pct == pytest.approx(100 * 30 / 52)
    assert b.correctness_area_pct == pytest.approx(100 * 30 / 49)
    assert b.reference_area_m2 == pytest.approx(52 * 0.25)
    strict = map_accuracy.building_accuracy(pred_b, ref_b, valid, cell_area_m2=0.25, min_overlap=0.9,
                                            min_building_m2=1.0)
    assert strict.n_found == 0 and strict.n_correct == 0   # 30 of 36 cells = 83 % overlap


def test_cloud_against_class_raster_cli(tmp_path):
    pred, ref = _maps()
    _write_cloud(tmp_path / "c.las", pred, M_CRS)
    _write_raster(tmp_path / "ref.tif", ref, M_CRS)
    r = _run(["evaluate", tmp_path / "c.las", "--reference", tmp_path / "ref.tif", "--json", tmp_path / "e.json"])
    assert r.exit_code == 0, r.output
    assert "building" in r.output and "kappa" in r.output and "type II" in r.output
    d = json.loads((tmp_path / "e.json").read_text())
    c = d["confusion"]
    assert c["classes"] == [2, 5, 6, 11] and d["n_cells"] == 399
    assert c["matrix"] == [[301, 0, 6, 0], [0, 16, 0, 0], [6, 0, 30, 0], [0, 0, 0, 40]]
    assert c["overall_accuracy_pct"] == pytest.approx(100 * 387 / 399)
    assert c["producers_accuracy_pct"]["6"] == pytest.approx(100 * 30 / 36)
    rows, cols = np.array([307, 16, 36, 40]), np.array([307, 16, 36, 40])
    pe = float(rows @ cols) / 399 ** 2
    assert c["kappa_pct"] == pytest.approx(100 * (387 / 399 - pe) / (1 - pe))
    b = d["buildings"]
    assert b["type_i_error_pct"] == pytest.approx(100 * 6 / 36) and b["type_ii_error_pct"] == pytest.approx(100 * 6 / 363)
    assert (b["n_reference"], b["n_found"], b["n_detected"], b["n_correct"]) == (1, 1, 1, 1)
    assert d["class_names"]["5"] == "tree"


@pytest.mark.parametrize("crs, unit_m", [(M_CRS, 1.0), (FT_CRS, FOOT_M)])
def test_polygons_reference_cloud_and_raster_prediction(tmp_path, crs, unit_m):
    """Footprints plus a tree polygon: outside them is "other", so ground and road predictions are too.
    Building polygons: rows 2-7 x cols 3-9 (42 cells, 30 predicted) and rows 10-13 x cols 2-5 (16, missed)."""
    pred, _ = _maps()
    _write_cloud(tmp_path / "c.las", pred, crs, unit_m)
    _write_raster(tmp_path / "p.tif", np.where(pred == 4, 5, pred).astype(np.uint8), crs)
    _write_polygons(tmp_path / "ref.geojson", [_box(2, 8, 3, 10), _box(10, 14, 2, 6), _box(12, 16, 12, 16)],
                    ["building", "6", "tree"], crs)
    res = 1.0 * unit_m   # one cell per CRS unit
    for pred_path in ("c.las", "p.tif"):
        out = tmp_path / f"{pred_path}.json"
        r = _run(["evaluate", tmp_path / pred_path, "--reference", tmp_path / "ref.geojson", "--res-m", res,
                  "--min-building-m2", 10 * unit_m ** 2, "--json", out])
        assert r.exit_code == 0, r.output
        d = json.loads(out.read_text())
        c = d["confusion"]
        assert c["classes"] == [0, 5, 6] and d["n_cells"] == 400
        # other: 400 - 58 - 16 = 326 reference cells, 6 of them predicted building
        assert c["matrix"] == [[320, 0, 6], [0, 16, 0], [28, 0, 30]]
        b = d["buildings"]
        assert (b["n_reference"], b["n_found"], b["n_detected"], b["n_correct"]) == (2, 1, 1, 1)
        assert b["reference_area_m2"] == pytest.approx(58 * unit_m ** 2)
        assert b["overall_accuracy_pct"] == pytest.approx(100 * (400 - 34) / 400)
    # only inside the blocks' hulls: the three polygons are apart, so the hulls are the polygons
    r = _run(["evaluate", tmp_path / "c.las", "--reference", tmp_path / "ref.geojson", "--res-m", res,
              "--within", "hull", "--json", tmp_path / "h.json"])
    assert r.exit_code == 0, r.output
    c = json.loads((tmp_path / "h.json").read_text())["confusion"]
    assert c["classes"] == [0, 5, 6] and c["matrix"] == [[0, 0, 0], [0, 16, 0], [28, 0, 30]]


def test_bad_reference_inputs_exit_2_and_write_nothing(tmp_path):
    pred, ref = _maps()
    _write_cloud(tmp_path / "c.las", pred, M_CRS)
    _write_raster(tmp_path / "ref_other_crs.tif", ref, "EPSG:32633")
    _write_polygons(tmp_path / "nofield.gpkg", [_box(2, 8, 3, 10)], [], M_CRS, field=None)
    _write_polygons(tmp_path / "badclass.gpkg", [_box(2, 8, 3, 10)], ["house"], M_CRS)
    out = tmp_path / "e.json"
    cases = [
        (["--reference", tmp_path / "ref_other_crs.tif"], "EPSG:32633"),
        (["--reference", tmp_path / "nofield.gpkg"], "no field 'class'"),
        (["--reference", tmp_path / "badclass.gpkg"], "feature 1, field 'class': class 'house'"),
        (["--reference", tmp_path / "c.las"], "--reference must be"),
        (["--reference", tmp_path / "nofield.gpkg", "--truth", tmp_path / "c.las"], "either --truth"),
        ([], "either --truth"),
        (["--reference", tmp_path / "badclass.gpkg", "--min-overlap", "0"], "--min-overlap"),
    ]
    for extra, message in cases:
        r = _run(["evaluate", tmp_path / "c.las", *extra, "--json", out])
        assert r.exit_code == 2, (extra, r.output)
        assert message in r.output, (extra, r.output)
        assert "Traceback" not in r.output and not out.exists()
