"""``lidarctl vectors`` and ``lidarctl check-vectors`` on a small synthetic classified cloud with known
rectangles: two flat roofs, a 10 m road, a pond with few returns, a sloping ground plane."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pyproj
import pytest
import shapely
from click.testing import CliRunner
from pyogrio.raw import read, write
from shapely import affinity
from shapely.geometry import box

from lidarctl.checks import vectors as vc
from lidarctl.cli.main import main
from aerotri.geom.las import FOOT_M

X0, Y0 = 500000.0, 5400000.0
M_CRS, FT_CRS = "EPSG:32632", "EPSG:2994"
SPACING = 0.7
ROOFS = [(affinity.rotate(box(20, 20, 44, 36), 17.0, origin=(32, 28)), 9.0),   # (outline, eave height above ground)
         (box(70, 60, 88, 84), 14.0)]
ROAD = box(0, 48, 120, 58)          # 10 m wide, axis y = 53
POND = box(85, 10, 110, 30)


def ground_z(x, y):
    return 100.0 + 0.02 * x + 0.01 * y


def _truth_m():
    """Points (local metres) and classes: ground 2, building 6 (roof at ground + eave), road 11, water 9 (a
    tenth of the pond's points: water returns are few)."""
    rng = np.random.default_rng(3)
    gx, gy = np.meshgrid(np.arange(0, 120, SPACING), np.arange(0, 100, SPACING))
    x = gx.ravel() + rng.uniform(-0.2, 0.2, gx.size)
    y = gy.ravel() + rng.uniform(-0.2, 0.2, gx.size)
    z = ground_z(x, y) + rng.normal(0, 0.02, x.size)
    cls = np.full(x.size, 2, np.uint8)
    cls[shapely.contains_xy(ROAD, x, y)] = 11
    pond = shapely.contains_xy(POND, x, y)
    cls[pond] = 9
    z[pond] = 99.0
    keep = ~pond | (rng.random(x.size) < 0.1)
    for poly, h in ROOFS:
        inside = shapely.contains_xy(poly, x, y)
        cls[inside] = 6
        z[inside] = ground_z(poly.centroid.x, poly.centroid.y) + h + rng.normal(0, 0.02, inside.sum())
    return x[keep], y[keep], z[keep], cls[keep]


def _write_las(path, crs=M_CRS, unit_m=1.0, points=None):
    """The scene's cloud (``points``: x, y, z, classes in metres from the scene's origin; default ``_truth_m()``)."""
    x, y, z, cls = _truth_m() if points is None else points
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.array([X0 / unit_m, Y0 / unit_m, 0.0])
    if crs:
        header.add_crs(pyproj.CRS(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = (X0 + x) / unit_m, (Y0 + y) / unit_m, z / unit_m
    las.classification = cls
    las.write(path)
    return path


def _reference(path, unit_m=1.0, shift_m=(0.0, 0.0)):
    sh = lambda g: affinity.scale(affinity.translate(g, X0 + shift_m[0], Y0 + shift_m[1]), 1 / unit_m, 1 / unit_m,  # noqa: E731
                                  origin=(0, 0))
    crs = pyproj.CRS(M_CRS if unit_m == 1.0 else FT_CRS).to_wkt()
    layers = {"buildings": ([sh(p) for p, _ in ROOFS], "Polygon"), "roads": ([sh(ROAD)], "Polygon"),
              "road_centrelines": ([sh(shapely.LineString([(0, 53), (120, 53)]))], "LineString"),
              "water": ([sh(POND)], "Polygon")}
    for i, (name, (geoms, gtype)) in enumerate(layers.items()):
        write(path, np.array(shapely.to_wkb(np.array(geoms, dtype=object)), dtype=object), field_data=[np.arange(len(geoms))],
              fields=["id"], geometry_type=gtype, crs=crs, driver="GPKG", layer=name, append=i > 0)
    return path


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("vectors")
    cloud = _write_las(d / "cloud.las")
    out = d / "dlg.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out), "--spot-spacing-m", "40"])
    assert r.exit_code == 0, r.output
    return d, cloud, out


def _layer(path, name):
    meta, _, wkb, fields = read(path, layer=name)
    return meta, [shapely.from_wkb(b) for b in wkb], dict(zip(meta["fields"], fields))


def test_layers_match_the_known_rectangles(made):
    d, _, out = made
    for name in ("buildings", "roads", "road_centrelines", "water", "spot_heights"):
        meta, _, _ = _layer(out, name)
        assert pyproj.CRS(meta["crs"]).to_epsg() == 32632, name
    _, bl, f = _layer(out, "buildings")
    assert len(bl) == 2
    for (poly, h) in ROOFS:
        true = affinity.translate(poly, X0, Y0)
        k = int(np.argmax([g.intersection(true).area for g in bl]))
        assert bl[k].symmetric_difference(true).area / true.area < 0.06
        ground = ground_z(poly.centroid.x, poly.centroid.y)
        assert f["eave_z"][k] == pytest.approx(ground + h, abs=0.1)
        assert f["ridge_z"][k] == pytest.approx(ground + h, abs=0.15)
        assert f["area_m2"][k] == pytest.approx(true.area, rel=0.06)
    _, roads, f = _layer(out, "roads")
    assert len(roads) == 1
    assert f["width_m"][0] == pytest.approx(10.0, abs=0.8)
    _, lines, f = _layer(out, "road_centrelines")
    assert sum(ln.length for ln in lines) > 100
    assert max(float(np.max(np.abs(np.asarray(ln.coords)[:, 1] - (Y0 + 53)))) for ln in lines) < 1.0
    assert np.all(np.abs(f["width_m"] - 10.0) < 0.8)
    _, water, _ = _layer(out, "water")   # from 10 % of the returns: the void around them joins
    assert len(water) == 1
    pond = affinity.translate(POND, X0, Y0)
    assert water[0].intersection(pond).area / water[0].union(pond).area > 0.85
    _, spots, f = _layer(out, "spot_heights")
    assert len(spots) >= 6
    xy = np.array([s.coords[0] for s in spots])
    assert np.abs(f["z"] - ground_z(xy[:, 0] - X0, xy[:, 1] - Y0)).max() < 0.05
    obstacles = shapely.union_all([affinity.translate(g, X0, Y0) for g in [p for p, _ in ROOFS] + [POND]])
    assert shapely.distance(shapely.points(xy), obstacles).min() > 2.0   # off the breaklines


def test_check_vectors_against_reference(made):
    d, _, out = made
    ref = _reference(d / "ref.gpkg")
    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(ref), "--json", str(d / "c.json"),
                                  "--png", str(d / "c.png")])
    assert r.exit_code == 0, r.output
    res = json.loads((d / "c.json").read_text())
    b = res["layers"]["buildings"]
    assert b["n_matched_corners"] == 8
    assert b["rms_xy_corner_m"] < 0.5 and b["within_tolerance"]
    assert res["tolerance_feature_rms_xy_m"] == 0.5   # 1:10000 flat, the table of design/reports.md
    # ... unconfirmed and tighter than 1:2000's: the verdict says both (trial-city: 1:2000 passed what 1:10000 failed)
    assert res["tolerance_confirmed"] is False and "tighter than 1:2000's 1.2 m" in res["tolerance_note"]
    assert "(unconfirmed limit)" in r.output and "tighter than 1:2000's" in r.output
    # the scale nobody gave is said as the default (trial s96 F9); given, it is not
    assert "(1:10000 (the default scale: --scale for your map's), flat)" in r.output
    r2 = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(ref), "--scale", "1:2000"])
    assert r2.exit_code == 0 and "the default scale" not in r2.output, r2.output
    for name in ("buildings", "roads", "water"):
        assert res["layers"][name]["completeness_pct"] > 85 and res["layers"][name]["correctness_pct"] > 90
    assert res["layers"]["road_centrelines"]["completeness_pct"] > 85
    assert (d / "c.png").stat().st_size > 10_000


def _dem(path, crs=M_CRS):
    import rasterio
    from rasterio.transform import from_origin

    xs, ys = np.arange(0, 120, 2.0) + 1.0, 100.0 - (np.arange(0, 100, 2.0) + 1.0)
    z = ground_z(*np.meshgrid(xs, ys)).astype("float32")
    with rasterio.open(path, "w", driver="GTiff", width=60, height=50, count=1, dtype="float32", crs=crs,
                       transform=from_origin(X0, Y0 + 100, 2.0, 2.0)) as dst:
        dst.write(z, 1)
    return path


def test_contours_from_dem_and_copied(made, tmp_path):
    _, cloud, _ = made
    dem = _dem(tmp_path / "dem.tif")
    out = tmp_path / "a.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out), "--dem", str(dem), "--contour-interval-m", "0.5"])
    assert r.exit_code == 0, r.output
    meta, lines, f = _layer(out, "contours")
    assert pyproj.CRS(meta["crs"]).to_epsg() == 32632
    assert set(np.round(f["elevation"], 3)) == set(np.arange(100.5, 103.01, 0.5))   # 100.02 .. 103.38 m
    xy = np.vstack([np.asarray(ln.coords) for ln in lines])
    lv = np.concatenate([np.full(len(ln.coords), e) for ln, e in zip(lines, f["elevation"])])
    assert np.abs(ground_z(xy[:, 0] - X0, xy[:, 1] - Y0) - lv).max() < 1e-3   # on the plane
    # `closed` as lidarctl contours writes it (trial s94: the field was missing here)
    assert list(f["closed"]) == [ln.is_closed for ln in lines]
    out2 = tmp_path / "b.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out2), "--contours", str(out)])
    assert r.exit_code == 0, r.output
    assert len(_layer(out2, "contours")[1]) == len(lines)
    bad = _dem(tmp_path / "dem_ft.tif", FT_CRS)
    out3 = tmp_path / "c.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out3), "--dem", str(bad)])
    assert r.exit_code == 2 and "dem_ft.tif" in r.output and not out3.exists()


def test_offsets_of_a_known_shift(tmp_path):
    sq = [box(0, 0, 10, 10)]
    moved = [affinity.translate(sq[0], 0.3, 0.0)]
    off = vc.point_offsets(moved, sq, match_m=3.0)
    assert np.allclose(off.to_corner, [[-0.3, 0.0]] * 4)
    # the two corners moved off the outline are 0.3 away; the other two slid along the top and bottom edges
    assert np.allclose(np.sort(np.hypot(*off.to_line.T)), [0.0, 0.0, 0.3, 0.3])
    a = vc.area_overlap(moved, sq)
    assert a.completeness_pct == pytest.approx(97.0) and a.correctness_pct == pytest.approx(97.0)
    ln = vc.buffer_overlap([shapely.LineString([(0, 0.5), (10, 0.5)])], [shapely.LineString([(0, 0), (20, 0)])], 1.0)
    # the buffer's round cap reaches sqrt(1 - 0.5^2) beyond the line's end
    assert ln.completeness_pct == pytest.approx(100 * (10 + 0.75 ** 0.5) / 20, rel=1e-3) and ln.correctness_pct == pytest.approx(100.0)


def test_cloud_in_feet(tmp_path):
    cloud = _write_las(tmp_path / "ft.las", FT_CRS, FOOT_M)
    out = tmp_path / "ft.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out)])
    assert r.exit_code == 0, r.output
    meta, bl, f = _layer(out, "buildings")
    assert pyproj.CRS(meta["crs"]).to_epsg() == 2994
    true = affinity.scale(affinity.translate(ROOFS[1][0], X0, Y0), 1 / FOOT_M, 1 / FOOT_M, origin=(0, 0))
    k = int(np.argmax([g.intersection(true).area for g in bl]))
    assert bl[k].symmetric_difference(true).area / true.area < 0.06       # coordinates in feet
    assert f["area_m2"][k] == pytest.approx(ROOFS[1][0].area, rel=0.06)    # areas in square metres
    ground = ground_z(ROOFS[1][0].centroid.x, ROOFS[1][0].centroid.y)
    assert f["eave_z"][k] * FOOT_M == pytest.approx(ground + ROOFS[1][1], abs=0.1)
    _, _, rf = _layer(out, "roads")
    assert rf["width_m"][0] == pytest.approx(10.0, abs=0.8)
    res = vc.check_vectors(out, _reference(tmp_path / "ref_ft.gpkg", FOOT_M))
    assert res.document["xy_unit_m"] == pytest.approx(FOOT_M)
    assert res.document["layers"]["buildings"]["rms_xy_corner_m"] < 0.5
    assert res.record.buildings.rms_xy_corner_m == res.document["layers"]["buildings"]["rms_xy_corner_m"]


@pytest.mark.parametrize("case", ["missing", "no_crs", "suffix", "same_as_input", "dem_and_contours", "bad_image"])
def test_vectors_bad_input_exit_2_nothing_written(made, tmp_path, case):
    d, cloud, _ = made
    out = tmp_path / "o.gpkg"
    args = {"missing": [str(tmp_path / "nope.las"), str(out)],
            "no_crs": [str(_write_las(tmp_path / "nocrs.las", crs=None)), str(out)],
            "suffix": [str(cloud), str(tmp_path / "o.txt")],
            "same_as_input": [str(cloud), str(cloud)],
            "dem_and_contours": [str(cloud), str(out), "--dem", str(cloud), "--contours", str(cloud)],
            "bad_image": [str(cloud), str(out), "--image", str(d / "ref_missing_is_not_a_raster.txt")]}[case]
    if case == "bad_image":
        (d / "ref_missing_is_not_a_raster.txt").write_text("not a raster")
    before = {p.name for p in tmp_path.iterdir()}
    r = CliRunner().invoke(main, ["vectors", *args])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    named = {"missing": "nope.las", "no_crs": "nocrs.las", "suffix": "o.txt", "same_as_input": "cloud.las",
             "dem_and_contours": "--contours", "bad_image": "ref_missing_is_not_a_raster.txt"}[case]
    assert named in r.output
    assert {p.name for p in tmp_path.iterdir()} == before


def test_check_vectors_bad_input(made, tmp_path):
    d, _, out = made
    ref = _reference(tmp_path / "ref.gpkg")
    js = tmp_path / "c.json"
    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(ref), "--layer", "bridges",
                                  "--json", str(js)])
    assert r.exit_code == 2 and "bridges" in r.output and not js.exists()
    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(tmp_path / "none.gpkg")])
    assert r.exit_code == 2 and "none.gpkg" in r.output


@pytest.mark.parametrize("command, old", [("vectors", "--spot-spacing"), ("vectors", "--cell"), ("vectors", "--min-area"),
                                          ("vectors", "--simplify"), ("vectors", "--contour-interval"),
                                          ("check-vectors", "--match"), ("check-vectors", "--buffer")])
def test_the_old_option_names_without_units_are_gone(made, tmp_path, command, old):
    """Issue 40: no compatibility layer before 1.0. The names renamed with their units (--cell -> --cell-m, ...)
    are refused by click, naming the option, and nothing is written."""
    d, cloud, out = made
    target = tmp_path / "old.gpkg"
    args = [str(cloud), str(target)] if command == "vectors" else [str(out), "--reference", str(out)]
    r = CliRunner().invoke(main, [command, *args, old, "1"])
    assert r.exit_code == 2 and f"No such option '{old}'" in r.output and not target.exists()


def test_a_shed_below_the_outliner_is_on_the_map():
    """Issue 44: a 3 x 2.5 m garden shed (7.5 m2, below the regularised outliner's 25 m2) classified building is in
    the buildings layer (the outline of its cells), next to the two regularised roofs; no sliver is added."""
    from lidarctl.corners.roof_corners import ClassifiedStrips
    from lidarctl.units import METRE
    from lidarctl.vectors.layers import building_outlines

    x, y, z, cls = _truth_m()
    shed = box(10, 70, 13, 72.5)
    inside = shapely.contains_xy(shed, x, y)
    cls[inside] = 6
    z[inside] = ground_z(11.5, 71.25) + 2.4
    pts = ClassifiedStrips(x=x, y=y, z=z, classification=cls, point_source_id=np.ones(len(x), np.int64), crs=None,
                           units=METRE)
    polys, rows, _ = building_outlines(pts)
    assert len(polys) == 3
    k = [i for i, p in enumerate(polys) if p.contains(shed.centroid)]
    assert len(k) == 1 and rows[k[0]]["roof"] == "cells"
    assert rows[k[0]]["area_m2"] == pytest.approx(shed.area, rel=0.5)
    assert rows[k[0]]["height_m"] == pytest.approx(2.4, abs=0.2)


def test_line_overlap_window_by_window_equals_the_whole_layer_at_once():
    """The line overlap computed in windows (memory follows the window) equals the union-and-buffer of the whole
    layers, with lines crossing many windows, lines drawn twice and a product missing part of the reference."""
    rng = np.random.default_rng(5)
    ref = [shapely.LineString(np.cumsum(rng.normal(0, 3, (40, 2)), axis=0) + rng.uniform(0, 300, 2)) for _ in range(60)]
    prod = [shapely.LineString(np.asarray(g.coords) + rng.normal(0, 0.8, (40, 2))) for g in ref[:45]]
    prod += [ref[0], ref[0]]  # drawn twice: counted once
    whole_r, whole_p = shapely.union_all(ref), shapely.union_all(prod)
    # the buffer of a layer: the union of its lines' buffers
    want_c = 100 * whole_r.intersection(shapely.union_all(shapely.buffer(prod, 1.5))).length / whole_r.length
    want_k = 100 * whole_p.intersection(shapely.union_all(shapely.buffer(ref, 1.5))).length / whole_p.length
    for window in (None, 17.0, 1000.0):
        got = vc.buffer_overlap(prod, ref, 1.5, window=window)
        assert got.reference_size == pytest.approx(whole_r.length, rel=1e-9)
        assert got.product_size == pytest.approx(whole_p.length, rel=1e-9)
        assert got.completeness_pct == pytest.approx(want_c, rel=1e-9)
        assert got.correctness_pct == pytest.approx(want_k, rel=1e-9)
    assert 50 < want_c < 95 and want_k > 90  # the case is not trivial
    assert vc.buffer_overlap([], ref, 1.5).completeness_pct == 0.0
    assert vc.buffer_overlap(prod, [], 1.5).completeness_pct is None


def test_a_roof_that_returned_no_pulse_is_on_the_map_and_a_shadow_is_not():
    """Issue 44: a 6 x 4 m flat roof whose middle returned no pulse (glass, a black or wet surface: AHN3 Delft has
    two BGT buildings seen by their rims alone) and whose south rim is missing too (the void reaches the ground
    beyond the wall) is one building polygon over its centre; a strip without returns beside the tall roof (a
    scan shadow: ground on three sides) stays off the map. Without the join the roof's centre is not covered."""
    from lidarctl.corners.roof_corners import ClassifiedStrips
    from lidarctl.units import METRE
    from lidarctl.vectors import layers

    x, y, z, cls = _truth_m()
    roof, void = box(40, 70, 46, 74), box(40.8, 69.0, 45.2, 73.2)
    shadow = box(67.0, 62, 69.8, 82)
    inside = shapely.contains_xy(roof, x, y)
    cls[inside] = 6
    z[inside] = ground_z(43, 72) + 3.0
    keep = ~shapely.contains_xy(void, x, y) & ~shapely.contains_xy(shadow, x, y)
    pts = ClassifiedStrips(x=x[keep], y=y[keep], z=z[keep], classification=cls[keep],
                           point_source_id=np.ones(int(keep.sum()), np.int64), crs=None, units=METRE)

    def covering(polys, px, py):
        return [p for p in polys if p.contains(shapely.Point(px, py))]

    polys, rows, _ = layers.building_outlines(pts)
    hit = covering(polys, *roof.centroid.coords[0])
    assert len(hit) == 1 and hit[0].area == pytest.approx(roof.area, rel=0.35)
    assert not covering(polys, 68.4, 72.0) and not covering(polys, 68.4, 65.0)
    assert len(polys) == 3
    polys, _, _ = layers.building_outlines(pts, roof_dropouts=False)
    assert not covering(polys, *roof.centroid.coords[0])


def test_a_lake_running_out_of_the_data_is_water_by_its_level(tmp_path):
    """lidR Topography's western lake reaches the tile's edge: its gap without returns touched the grid's border, so
    it was taken for the outside of the footprint and left out (three slivers of 15-66 m2, one with water_z NaN).
    Now the water rule decides (``layers.lakes_at_edge``): a lake returning only along its shore, cut by the west
    edge, is one water polygon at its level; a notch in the footprint beside it, rimmed by ground below the water's
    level (water cannot stand there), is not water; no feature without a height."""
    rng = np.random.default_rng(7)
    lake, notch, low = box(0, 10, 25, 30), box(20, 0, 37, 10), box(25, 0, 45, 14)
    gx, gy = np.meshgrid(np.arange(0, 80, SPACING), np.arange(0, 60, SPACING))
    x = gx.ravel() + rng.uniform(-0.2, 0.2, gx.size)
    y = gy.ravel() + rng.uniform(-0.2, 0.2, gx.size)
    z = ground_z(x, y) + rng.normal(0, 0.02, x.size)
    low_ground = shapely.contains_xy(low, x, y)
    z[low_ground] = 97.5 + rng.normal(0, 0.02, low_ground.sum())     # below the lake's level
    cls = np.full(x.size, 2, np.uint8)
    in_lake = shapely.contains_xy(lake, x, y)
    shore = in_lake & ~shapely.contains_xy(lake.buffer(-1.5), x, y) & (x > 1.5)  # returns only along its shores
    cls[in_lake], z[in_lake] = 9, 99.0 + rng.normal(0, 0.01, in_lake.sum())
    keep = (~in_lake | shore) & ~shapely.contains_xy(notch, x, y)
    _write_las(tmp_path / "edge.las", points=(x[keep], y[keep], z[keep], cls[keep]))
    r = CliRunner().invoke(main, ["vectors", str(tmp_path / "edge.las"), str(tmp_path / "v.gpkg")])
    assert r.exit_code == 0, r.output
    _, water, fields = _layer(tmp_path / "v.gpkg", "water")
    truth = affinity.translate(lake, X0, Y0)
    assert len(water) == 1, [w.area for w in water]
    assert water[0].intersection(truth).area / water[0].union(truth).area > 0.9
    assert water[0].intersection(affinity.translate(notch, X0, Y0)).area < 5.0
    np.testing.assert_allclose(fields["water_z"], 99.0, atol=0.02)


def test_a_river_falling_along_its_course_out_of_the_data_is_water(tmp_path):
    """A river crossing the tile (1.6 m of fall over its 80 m) returning only along its shores: its gap without
    returns reaches both edges of the data, so ``lakes_at_edge`` decides. One level for the whole rim (the median
    of its water returns) put the downstream banks below the upstream water (Autzen's river: 7 ragged pieces of
    6,857 m2 in all, one polygon of 20,823 m2 since); the level beside each bank cell is its own stretch of the
    river's, and the river is one water polygon."""
    rng = np.random.default_rng(11)
    river = box(0, 20, 80, 36)
    gx, gy = np.meshgrid(np.arange(0, 80, SPACING), np.arange(0, 60, SPACING))
    x = gx.ravel() + rng.uniform(-0.2, 0.2, gx.size)
    y = gy.ravel() + rng.uniform(-0.2, 0.2, gx.size)
    level = 99.0 - 0.02 * x
    from_water = np.maximum(np.maximum(20 - y, y - 36), 0.0)
    z = level + 0.3 + 0.05 * from_water + rng.normal(0, 0.02, x.size)  # banks rising out of the water
    cls = np.full(x.size, 2, np.uint8)
    in_river = shapely.contains_xy(river, x, y)
    shore = in_river & ~shapely.contains_xy(river.buffer(-1.5), x, y) & (x > 1.5) & (x < 78.5)
    cls[in_river], z[in_river] = 9, level[in_river] + rng.normal(0, 0.01, in_river.sum())
    keep = ~in_river | shore
    _write_las(tmp_path / "river.las", points=(x[keep], y[keep], z[keep], cls[keep]))
    r = CliRunner().invoke(main, ["vectors", str(tmp_path / "river.las"), str(tmp_path / "v.gpkg")])
    assert r.exit_code == 0, r.output
    _, water, fields = _layer(tmp_path / "v.gpkg", "water")
    truth = affinity.translate(river, X0, Y0)
    assert len(water) == 1, [w.area for w in water]
    assert water[0].intersection(truth).area / water[0].union(truth).area > 0.9
    assert 98.0 < fields["water_z"][0] < 98.6  # the median of a river falling 99.0 -> 97.4 m


def test_a_water_piece_joined_through_a_cell_corner_is_one_valid_polygon():
    """Eight-neighbour pieces touching through a corner were an invalid ring that fell apart into parts below the
    layer's minimum area (Autzen's river: ten polygons of 1-17 m2 with --min-area-m2 50)."""
    from lidarctl.vectors.layers import class_mask, mask_polygons, without_pinches

    # two 8 x 8 m ponds touching at one corner, and a 3-cell spur joined to the second through another corner
    xy = [(x + 0.5, y + 0.5) for x in range(8) for y in range(8)]
    xy += [(x + 0.5, y + 0.5) for x in range(8, 16) for y in range(8, 16)]
    xy += [(16.5, 16.5), (17.5, 16.5), (18.5, 16.5)]
    mask = class_mask(np.array(xy), 0.0, 20.0, 1.0, (20, 20), min_area_m2=50.0, close_cells=0)
    assert mask.sum() == 131
    polys = mask_polygons(without_pinches(mask), 0.0, 20.0, 1.0, 0.01)
    assert len(polys) == 1 and polys[0].is_valid
    assert 131 <= polys[0].area <= 133  # a cell added at each of the two corners
    assert all(p.area >= 50.0 for p in mask_polygons(without_pinches(mask), 0.0, 20.0, 1.0, 0.5))
    parts = mask_polygons(mask, 0.0, 20.0, 1.0, 0.01)  # what the layer was made of before
    assert len(parts) == 3 and min(p.area for p in parts) < 50.0


def _ortho(path, left, top, size_px, pixel_m=2.0, crs=M_CRS):
    import rasterio
    from rasterio.transform import from_origin

    rgb = np.stack([np.full((size_px, size_px), v, np.uint8) for v in (120, 140, 100)])
    with rasterio.open(path, "w", driver="GTiff", width=size_px, height=size_px, count=3, dtype="uint8", crs=crs,
                       transform=from_origin(left, top, pixel_m, pixel_m)) as dst:
        dst.write(rgb)
    return path


def test_the_preview_is_framed_by_the_data_not_the_orthophoto(made, tmp_path, monkeypatch):
    # trial (Autzen): the preview took the orthophoto's extent, 3,248 x 4,385 ft around 1,177 x 563 ft of LiDAR: the
    # features sat in a corner of an empty map. Now the data (points and features) with a 5 % margin, the orthophoto
    # clipped to it
    import matplotlib.image

    import lidarctl.vectors.layers as L

    figs = []
    real = L.save_png
    monkeypatch.setattr(L, "save_png", lambda fig, path, **k: figs.append(fig) or real(fig, path, **k))
    _, cloud, _ = made
    ortho = _ortho(tmp_path / "ortho.tif", X0 - 400.0, Y0 + 700.0, 500)       # 1,000 m square around the 120 x 100 m
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(tmp_path / "v.gpkg"), "--image", str(ortho)])
    assert r.exit_code == 0, r.output
    # the points' extent and the features' (the road and water masks reach half a cell beyond the points)
    x, y, _, _ = _truth_m()
    geoms = [g for name in ("buildings", "roads", "road_centrelines", "water", "spot_heights")
             for g in _layer(tmp_path / "v.gpkg", name)[1]]
    fb = shapely.total_bounds(np.asarray(geoms, dtype=object))
    data = (min(X0 + x.min(), fb[0]), min(Y0 + y.min(), fb[1]), max(X0 + x.max(), fb[2]), max(Y0 + y.max(), fb[3]))
    assert data[2] - data[0] < 121.0 and data[3] - data[1] < 101.0
    m = 0.05 * max(data[2] - data[0], data[3] - data[1])
    (ax,) = figs[-1].axes
    np.testing.assert_allclose(ax.get_xlim(), (data[0] - m, data[2] + m), atol=0.01)
    np.testing.assert_allclose(ax.get_ylim(), (data[1] - m, data[3] + m), atol=0.01)
    (im,) = [a for a in ax.get_children() if isinstance(a, matplotlib.image.AxesImage)]
    left, right, bottom, top = im.get_extent()                               # clipped to the frame (whole pixels)
    assert data[0] - m - 2.0 <= left <= data[0] - m and data[2] + m <= right <= data[2] + m + 2.0
    assert data[1] - m - 2.0 <= bottom <= data[1] - m and data[3] + m <= top <= data[3] + m + 2.0
    assert im.get_array().shape[:2] == (round((top - bottom) / 2.0), round((right - left) / 2.0))
    assert (tmp_path / "v.png").stat().st_size > 10_000
    # an orthophoto beside the data: said, not drawn
    far = _ortho(tmp_path / "far.tif", X0 + 5000.0, Y0 + 5000.0, 50)
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(tmp_path / "w.gpkg"), "--image", str(far)])
    assert r.exit_code == 0, r.output
    (ax,) = figs[-1].axes
    assert ax.get_title() == "DLG layers (the orthophoto does not cover the data)"
    assert not [a for a in ax.get_children() if isinstance(a, matplotlib.image.AxesImage)]
    np.testing.assert_allclose(ax.get_xlim(), (data[0] - m, data[2] + m), atol=0.01)


def test_an_orthophoto_in_another_crs_is_refused_naming_image_and_both_crss(made, tmp_path):
    # sf-fixes (review of small-fixes): an orthophoto in another CRS (the Autzen one warped to UTM) was drawn in its
    # own coordinates, the title said "the orthophoto does not cover the data" and the exit code was 0
    _, cloud, _ = made
    # the same ground in UTM 33N: far from the data's UTM 32N coordinates, never drawn
    ortho = _ortho(tmp_path / "ortho33.tif", X0 - 400.0, Y0 + 700.0, 50, crs="EPSG:32633")
    out = tmp_path / "v.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out), "--image", str(ortho)])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "--image" in r.output and "ortho33.tif" in r.output, r.output
    assert "32633" in r.output and "32632" in r.output, r.output
    assert not out.exists() and not out.with_suffix(".png").exists()


def test_a_cloud_without_road_returns_says_where_roads_come_from(made, tmp_path):
    # trial-quick: `lidarctl vectors` of the demo's classified strips with --image printed "roads 0,
    # road_centrelines 0" and nothing else: the chain classifies without an orthophoto, so no class 11
    d, cloud, out = made
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(tmp_path / "a.gpkg"), "--spot-spacing-m", "40"])
    assert r.exit_code == 0 and "no road returns" not in r.output  # the scene's road is class 11
    x, y, z, cls = _truth_m()
    cls = np.where(cls == 11, 2, cls).astype(np.uint8)          # the road as plain ground
    bare = _write_las(tmp_path / "no_roads.las", points=(x, y, z, cls))
    r = CliRunner().invoke(main, ["vectors", str(bare), str(tmp_path / "b.gpkg"), "--spot-spacing-m", "40"])
    assert r.exit_code == 0, r.output
    assert "roads 0, road_centrelines 0" in r.output
    assert "the clouds hold no road returns (class 11)" in r.output and "classify ... --image DOM.tif" in r.output


@pytest.mark.parametrize("bands", [3, 1])
def test_the_previews_orthophoto_nodata_is_the_page_not_dark_grey(tmp_path, monkeypatch, bands):
    # small-fixes 6 (trial-quick: the demo's vectors.png drew the mosaic's nodata margin dark grey, 0 at alpha 0.6,
    # like data): the orthophoto's nodata is transparent, the page's white; its pixels as before (alpha 0.6)
    import pyproj
    import rasterio
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from rasterio.transform import from_origin

    import lidarctl.vectors.layers as L
    from lidarctl.units import LengthUnits

    figs = []
    monkeypatch.setattr(L, "save_png", lambda fig, path, **k: figs.append(fig))
    img = np.zeros((bands, 100, 100), np.uint8)                             # the west half nodata (0)
    img[:, :, 50:] = np.array([120, 140, 100][:bands], np.uint8)[:, None, None] if bands == 3 else \
        np.linspace(50, 250, 50).astype(np.uint8)[None, None, :]
    with rasterio.open(tmp_path / "dom.tif", "w", driver="GTiff", width=100, height=100, count=bands, dtype="uint8",
                       crs="EPSG:32632", nodata=0, transform=from_origin(1000.0, 2000.0, 1.0, 1.0)) as dst:
        dst.write(img)
    mv = L.MapVectors([], pyproj.CRS("EPSG:32632"), LengthUnits(), L.VectorCounts(0, None, 0, 0, 0, 0),
                      extent=(1010.0, 1910.0, 1090.0, 1990.0))
    L.preview_png(mv, tmp_path / "v.png", image=tmp_path / "dom.tif")
    canvas = FigureCanvasAgg(figs[-1])
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    (ax,) = figs[-1].axes

    def pixel(x, y):
        col, row = ax.transData.transform((x, y))
        return rgba[int(round(rgba.shape[0] - row)), int(round(col)), :3].astype(int)

    for y in (1915.0, 1950.0, 1985.0):
        assert pixel(1020.0, y).tolist() == [255, 255, 255], y             # was 102 grey
        if bands == 3:                                                      # 0.6 of the pixel over the white page
            expected = 255 - 0.6 * (255 - np.array([120, 140, 100]))
            assert np.abs(pixel(1080.0, y) - expected).max() <= 2, (y, pixel(1080.0, y))
        else:
            assert pixel(1080.0, y).max() < 250, y


def test_contours_from_a_dem_in_another_height_unit_are_in_the_clouds(made, tmp_path):
    """trial-lidar: a DEM whose heights are in another unit than the cloud's (Autzen in feet, a DEM in NAVD88 metres)
    gave a contours layer at 124 beside spot heights at 425, the command saying "(ft)"; every height of the
    GeoPackage is in the cloud's unit (the module's contract): here a metre cloud and a DEM in US survey feet."""
    import rasterio

    _, cloud, _ = made
    dem = _dem(tmp_path / "dem.tif")
    with rasterio.open(dem) as src:
        profile, z = src.profile, src.read(1)
    profile["crs"] = rasterio.crs.CRS.from_user_input(f"{M_CRS}+6360")  # NAVD88 height (ftUS): a unit, not a datum
    with rasterio.open(tmp_path / "dem_ftus.tif", "w", **profile) as dst:
        dst.write(z / 0.3048006096, 1)
    out = tmp_path / "a.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out), "--dem", str(tmp_path / "dem_ftus.tif"),
                                  "--contour-interval-m", "0.6096012192"])  # every 2 US survey feet
    assert r.exit_code == 0, r.output
    _, lines, f = _layer(out, "contours")
    assert np.allclose(f["elevation"], f["elevation_m"]) and len(lines) > 3
    assert np.allclose(f["elevation"] / 0.3048006096 / 2, np.round(f["elevation"] / 0.3048006096 / 2), atol=1e-6)
    xy = np.vstack([np.asarray(ln.coords) for ln in lines])
    lv = np.concatenate([np.full(len(ln.coords), e) for ln, e in zip(lines, f["elevation"])])
    assert np.abs(ground_z(xy[:, 0] - X0, xy[:, 1] - Y0) - lv).max() < 1e-3   # on the plane, in metres


def test_copied_contours_take_the_clouds_height_unit(tmp_path):
    """s27: `vectors --contours` copied the contours' elevation as it was: heights in metres beside spot heights in
    feet. Now converted as --dem is: from their elevation_m, else the file's CRS's height unit; refused without
    either beside a cloud in feet."""
    from pyogrio.raw import write

    cloud = _write_las(tmp_path / "ft.las", FT_CRS, FOOT_M)
    x0, y0 = X0 / FOOT_M, Y0 / FOOT_M
    lines = [shapely.LineString([(x0 + 10, y0 + 10 + i), (x0 + 300, y0 + 10 + i)]) for i in range(3)]
    wkb = np.array([shapely.to_wkb(g) for g in lines], dtype=object)
    level_m = np.array([100.0, 101.0, 102.0])
    cases = {"compound.gpkg": (f"{FT_CRS}+5703", {"elevation": level_m}),             # NAVD88 height in metres
             "elev_m.gpkg": (FT_CRS, {"elevation": level_m, "elevation_m": level_m}),  # lidarctl contours' fields
             "no_unit.gpkg": (None, {"elevation": level_m})}
    for name, (crs, fields) in cases.items():
        write(tmp_path / name, wkb, layer="contours", driver="GPKG", geometry_type="LineString", crs=crs,
              fields=list(fields), field_data=list(fields.values()))
    for name in ("compound.gpkg", "elev_m.gpkg"):
        out = tmp_path / f"v_{name}"
        r = CliRunner().invoke(main, ["vectors", str(cloud), str(out), "--contours", str(tmp_path / name)])
        assert r.exit_code == 0, (name, r.output)
        _, got, f = _layer(out, "contours")
        assert len(got) == 3
        np.testing.assert_allclose(f["elevation"], level_m / FOOT_M, rtol=1e-12)   # 328.08 ft, like z of spot heights
        np.testing.assert_allclose(f["elevation_m"], level_m, rtol=1e-12)
    out = tmp_path / "v_no_unit.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out), "--contours", str(tmp_path / "no_unit.gpkg")])
    assert r.exit_code == 2 and "no_unit.gpkg" in r.output and "no unit" in r.output and not out.exists(), r.output
    # contours in the cloud's unit already are copied as written (trial s96 F13: 420.0 ft came back
    # 420.00000000000006 through metres)
    ft = np.array([420.0, 422.0, 424.0])
    write(tmp_path / "ft.gpkg", wkb, layer="contours", driver="GPKG", geometry_type="LineString", crs=FT_CRS,
          fields=["elevation", "elevation_m"], field_data=[ft, ft * FOOT_M])
    out = tmp_path / "v_ft.gpkg"
    r = CliRunner().invoke(main, ["vectors", str(cloud), str(out), "--contours", str(tmp_path / "ft.gpkg")])
    assert r.exit_code == 0, r.output
    assert list(_layer(out, "contours")[2]["elevation"]) == [420.0, 422.0, 424.0]


@pytest.mark.parametrize("command", ["check-vectors", "check-plan"])
def test_an_unknown_map_scale_names_the_tables_the_command_can_take(made, tmp_path, command):
    """Trial: check-vectors --scale 1:1000 advised "give your own with --tolerances FILE", an option neither it nor
    check-plan has (click: "No such option"). The advice names the built-in tables --scale takes; aerotri report,
    which has --tolerances, keeps its advice."""
    from aerotri.core.errors import ConfigError
    from aerotri.core.tolerances import load_table

    d, cloud, out = made
    pts = tmp_path / "p.csv"
    pts.write_text("id,x,y\n1,500020,5400020\n")
    args = ([str(out), "--reference", str(out)] if command == "check-vectors" else [str(cloud), str(pts)])
    r = CliRunner().invoke(main, [command, *args, "--scale", "1:25000"])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert "--scale '1:25000': no built-in limit for map features (have 1:500, 1:1000, 1:2000, 1:5000, 1:10000" in \
        r.output
    assert "--tolerances" not in r.output
    with pytest.raises(ConfigError, match="give your own with --tolerances FILE"):
        load_table("1:1000")
    assert str(load_table("1:2000", source="--scale", own_table=None).path).endswith("cn_1to2000.toml")


def test_feature_limits_grow_with_the_scale_number():
    """1:500 and 1:1000 (municipal base maps) by GB/T 7931's mm on the map, as 1:2000 (trial-city: refused); the
    confirmed limits grow with the denominator; 1:5000 / 1:10000's design-table metres are marked unconfirmed."""
    from aerotri.core.tolerances import feature_limit

    for terrain, mm in (("flat", 0.6), ("mountainous", 0.8)):
        lims = [feature_limit(s, terrain) for s in ("1:500", "1:1000", "1:2000")]
        assert [f.limit_m for f in lims] == pytest.approx([mm * 0.5, mm * 1.0, mm * 2.0])
        assert all(f.confirmed and not f.note for f in lims)
        for s in ("1:5000", "1:10000"):
            f = feature_limit(s, terrain)
            assert not f.confirmed and f.limit_m < lims[-1].limit_m and "unconfirmed" in f.note


def _buildings_only(path, polys, crs=M_CRS):
    """A GeoPackage with one layer, buildings: ``polys`` (scene metres) at the scene's origin."""
    geoms = np.array([affinity.translate(p, X0, Y0) for p in polys], dtype=object)
    write(path, np.array(shapely.to_wkb(geoms), dtype=object), field_data=[np.arange(len(geoms))], fields=["id"],
          geometry_type="Polygon", crs=pyproj.CRS(crs).to_wkt(), driver="GPKG", layer="buildings")
    return path


def test_a_reference_of_part_of_the_area_is_said_and_within_hull_checks_inside_it(made, tmp_path):
    """Trial (Delft, BGT of part of the map's area): correctness 35.48 %, corner-to-outline RMS 37.2 m (max 125 m)
    "-> within tolerance", without a word that 57 % of the map's buildings lie where the BGT maps nothing.
    A reference of the first of the scene's two roofs only: the second building is counted false (correctness
    = 384 / (384 + 432) m2 ~ 47 %) and its corners are metres from any reference outline; the warning says so. With
    --within hull (as lidarctl evaluate) only the first roof's block is checked: correctness > 90 %, the
    corner-to-outline RMS small. The verdict is the corner-to-corner RMS's, printed after it."""
    _, _, out = made
    ref = _buildings_only(tmp_path / "part.gpkg", [ROOFS[0][0]])
    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(ref),
                                  "--json", str(tmp_path / "a.json")])
    assert r.exit_code == 0, r.output
    a = json.loads((tmp_path / "a.json").read_text())["layers"]["buildings"]
    assert a["correctness_pct"] == pytest.approx(100 * 384 / (384 + 432), abs=4)
    assert a["n_product_outside_reference_area"] == 1 and a["pct_product_outside_reference_area"] == 50.0
    assert a["rms_xy_to_line_m"] > 10
    assert ("warning: 1 of 2 buildings of " in r.output and "(50 %) lie outside the area" in r.output
            and "--within hull" in r.output)
    line = next(ln for ln in r.output.splitlines() if "plan RMS corner-to-corner" in ln)
    assert line.endswith("-> within tolerance 0.5 m (unconfirmed limit)") and "corner-to-outline" not in line
    assert "corner-to-outline (every corner to the nearest reference outline; not judged)" in r.output

    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(ref), "--within", "hull",
                                  "--json", str(tmp_path / "h.json")])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "h.json").read_text())
    h = doc["layers"]["buildings"]
    assert doc["within"] == "hull" and h["n_product"] == 1 and h["n_reference"] == 1
    assert h["correctness_pct"] > 90 and h["completeness_pct"] == pytest.approx(a["completeness_pct"])
    assert h["n_corners"] == 4 and h["n_matched_corners"] == 4 and h["rms_xy_to_line_m"] < 0.5
    assert "warning" not in r.output and "1 of 2 produced buildings lie outside --within hull: left out" in r.output

    # a polygon file: the whole reference, checked only around the second roof
    full = _buildings_only(tmp_path / "full.gpkg", [p for p, _ in ROOFS])
    area = _buildings_only(tmp_path / "area.gpkg", [ROOFS[1][0].buffer(5)])
    res = vc.check_vectors(out, full, vc.VectorCheckSettings(within=str(area))).document["layers"]["buildings"]
    assert res["n_product"] == 1 and res["n_reference"] == 1 and res["n_matched_corners"] == 4
    assert res["correctness_pct"] > 90 and res["completeness_pct"] > 90


@pytest.mark.parametrize("case", ["missing", "other_crs", "hull_of_lines", "as_json"])
def test_check_vectors_within_bad_input(made, tmp_path, case):
    _, _, out = made
    ref = _buildings_only(tmp_path / "ref.gpkg", [p for p, _ in ROOFS])
    other = _buildings_only(tmp_path / "ft.gpkg", [box(0, 0, 1, 1)], crs=FT_CRS)
    lines = tmp_path / "lines.gpkg"
    write(lines, np.array(shapely.to_wkb(np.array([shapely.LineString([(X0, Y0), (X0 + 50, Y0)])], dtype=object)),
                          dtype=object), field_data=[np.arange(1)], fields=["id"], geometry_type="LineString",
          crs=pyproj.CRS(M_CRS).to_wkt(), driver="GPKG", layer="road_centrelines")
    js = tmp_path / "c.json"
    args, named = {"missing": ([str(ref), "--within", str(tmp_path / "nope.gpkg")], "nope.gpkg: no such file"),
                   "other_crs": ([str(ref), "--within", str(other)], "ft.gpkg is in"),
                   "hull_of_lines": ([str(lines), "--within", "hull"], "lines.gpkg has no polygons"),
                   "as_json": ([str(ref), "--within", str(js)], "c.json")}[case]
    if case == "as_json":
        js.write_bytes(other.read_bytes())
    before = js.exists()
    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", *args, "--json", str(js)])
    assert r.exit_code == 2 and "Traceback" not in r.output and named in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1
    assert js.exists() == before


def test_a_map_moved_or_turned_against_its_reference_is_not_passed_on_chance_pairs(made, tmp_path):
    """Trials (AHN3 Delft's map against BGT): corners paired within 3 m as the map lay kept chance neighbours only,
    whose offsets the pairing distance bounds: moved 16.8 m it read 1.64 m, turned 5 deg 1.48 m, moved 2 m 1.46 m,
    each "within" an ASPRS H150cm or H250cm tolerance. Corners are paired under the map's rigid motion against the
    reference now (the building areas' cross-correlation, then iterated closest corners from turns of 0 to +-10
    deg) and measured as the map lies."""
    _, _, out = made
    rng = np.random.default_rng(5)
    squares = [box(x, y, x + 8, y + 6) for x, y in rng.uniform(0, 200, (40, 2))]
    est = vc.map_offset([affinity.translate(g, 7.3, -4.1) for g in squares], squares, 0.5)
    assert est.dx == pytest.approx(-7.3, abs=0.5) and est.dy == pytest.approx(4.1, abs=0.5)
    assert est.covered_at_offset_pct > 90 > est.covered_as_lies_pct

    scale = "ASPRS2023 H250cm V250cm"
    centre = (X0 + 60.0, Y0 + 50.0)
    for name, move in (("asis", None), ("moved", (12.0, 5.0)), ("turned", 6.0)):
        ref = _reference(tmp_path / f"ref_{name}.gpkg", shift_m=move if isinstance(move, tuple) else (0.0, 0.0))
        if isinstance(move, float):   # the reference turned 6 deg about the scene's centre: the map is turned -6
            meta, _, wkb, fields = read(ref, layer="buildings")
            turned = [affinity.rotate(shapely.from_wkb(b), move, origin=centre) for b in wkb]
            ref = _buildings_only(tmp_path / "ref_turned_b.gpkg", [affinity.translate(g, -X0, -Y0) for g in turned])
        js = tmp_path / f"c_{name}.json"
        r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(ref), "--layer", "buildings",
                                      "--scale", scale, "--json", str(js)])
        assert r.exit_code == 0, r.output
        b = json.loads(js.read_text())["layers"]["buildings"]
        assert b["n_matched_corners"] == 8
        if name == "asis":
            assert b["rms_xy_corner_m"] < 0.5 and b["within_tolerance"] is True and "the map lies" not in r.output
            assert abs(b["map_offset_dx_m"]) < 0.1 and abs(b["map_rotation_deg"]) < 0.1
        elif name == "moved":
            assert b["map_offset_dx_m"] == pytest.approx(-12.0, abs=0.1)
            assert b["map_offset_dy_m"] == pytest.approx(-5.0, abs=0.1)
            assert b["rms_xy_corner_m"] == pytest.approx(13.0, abs=0.3) and b["within_tolerance"] is False
            assert "the map lies moved against the reference by dx -12.0" in r.output
        else:
            assert b["map_rotation_deg"] == pytest.approx(-6.0, abs=0.1)
            assert b["rms_xy_corner_m"] > 3.0 and b["within_tolerance"] is False
            assert "turned -6.0" in r.output


def test_the_water_layer_states_the_spread_of_its_returns(made):
    """``water_z_range_m``: the 5th to 95th percentile range of a body's water returns (metres), what lidarctl
    hydro-flatten tells a lake (centimetres) from falling water by; the scene's pond returns all lie at 99 m."""
    _, _, out = made
    _, polys, f = _layer(out, "water")
    assert len(polys) == 1 and f["water_z"][0] == pytest.approx(99.0, abs=0.01)
    assert 0.0 <= f["water_z_range_m"][0] < 0.01


def test_a_reference_beyond_the_data_is_left_out_by_the_coverage_layer(made, tmp_path):
    """Trial-city: BGT footprints past the crop's edge counted as missed (completeness 77 % where the map has 97 %).
    The line map's coverage layer says where it was made from returns; check-vectors judges the reference inside it
    and says how much it left out."""
    _, _, out = made
    _, cover, f = _layer(out, "coverage")
    x, y, _, _ = _truth_m()
    union = shapely.union_all(np.asarray(cover, dtype=object))
    assert shapely.contains_xy(union, X0 + x, Y0 + y).mean() > 0.999
    assert 0.95 < union.area / ((x.max() - x.min()) * (y.max() - y.min())) < 1.05
    far = box(300, 300, 320, 330)                          # 600 m2 mapped where the cloud has no returns
    near = [p for p, _ in ROOFS]
    ref = _buildings_only(tmp_path / "ref.gpkg", near + [far])
    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(ref), "--json", str(tmp_path / "c.json")])
    assert r.exit_code == 0, r.output
    b = json.loads((tmp_path / "c.json").read_text())["layers"]["buildings"]
    inside = sum(p.area for p in near)
    assert b["reference_area_outside_coverage_m2"] == pytest.approx(600.0, rel=1e-6)
    assert b["pct_reference_outside_coverage"] == pytest.approx(100 * 600 / (600 + inside), rel=1e-6)
    assert b["completeness_pct"] > 95 and b["reference_area_m2"] == pytest.approx(inside, rel=0.01)
    assert "600 m2 of the reference's buildings" in r.output and "not counted as missed" in r.output


def test_contours_traced_from_the_dem_stop_at_the_water():
    """trial-relief F8: contours of a DEM that is not hydro-flattened ran through the ponds (the water returns' waves
    and the TIN across the voids: 3,099 m of contour more than 1 m inside the trial's ponds at 0.5 m, 181 m after,
    in ponds the water layer does not map). A line crossing a lake is cut at its shore into the pieces outside, each
    with the line's fields; a line off the water is kept as it is."""
    import shapely

    from lidarctl.vectors.layers import Layer, _outside_water

    lake = shapely.box(10, 10, 20, 20)
    across = shapely.LineString([(0, 15), (30, 15)])
    inside = shapely.LineString([(12, 12), (18, 12)])
    off = shapely.LineString([(0, 0), (5, 5)])
    layer = Layer("contours", "LineString", [across, inside, off],
                  {"elevation": np.array([1.0, 2.0, 3.0]), "index": np.array([True, False, False])})
    out = _outside_water(layer, [lake])
    assert [g.geom_type for g in out.geometries] == ["LineString"] * 3
    assert sorted(round(g.length, 6) for g in out.geometries) == sorted([10.0, 10.0, round(off.length, 6)])
    assert out.fields["elevation"].tolist() == [1.0, 1.0, 3.0] and out.fields["index"].tolist() == [True, True, False]
    assert not any(g.intersects(shapely.box(10.001, 10.001, 19.999, 19.999)) for g in out.geometries)
    assert _outside_water(layer, []) is layer


def test_a_reference_that_lies_elsewhere_is_refused_one_without_a_crs_said(made, tmp_path, caplog):
    """Trial s94: BGT footprints moved into another CRS and written without one scored 0 % / 0 % with corner offsets
    of 4,747 km, exit 0 (lidarctl evaluate refuses the same file); a reference without a CRS was taken in the
    product's without a word."""
    import logging

    _, _, out = made
    ref = _reference(tmp_path / "ref.gpkg")
    for name, shift in (("nocrs", (0.0, 0.0)), ("far", (3.0e6, 0.0))):
        path = tmp_path / f"{name}.gpkg"
        for i, layer in enumerate(("buildings", "roads")):
            meta, _, geoms, fields = read(ref, layer=layer)
            moved = [affinity.translate(g, *shift) for g in shapely.from_wkb(geoms)]
            write(path, np.array(shapely.to_wkb(np.array(moved, dtype=object)), dtype=object), field_data=fields,
                  fields=meta["fields"], geometry_type=meta["geometry_type"], driver="GPKG", layer=layer,
                  append=i > 0)
    with caplog.at_level(logging.WARNING):
        res = vc.check_vectors(out, tmp_path / "nocrs.gpkg", vc.VectorCheckSettings(layers=("buildings",)))
    assert res.document["layers"]["buildings"]["completeness_pct"] > 80
    assert any("nocrs.gpkg: has no CRS; taken in" in r.getMessage() for r in caplog.records)
    r = CliRunner().invoke(main, ["check-vectors", str(out), "--reference", str(tmp_path / "far.gpkg"),
                                  "--json", str(tmp_path / "c.json")])
    assert r.exit_code == 2 and "lie apart" in r.output and "far.gpkg has no CRS of its own" in r.output
    assert not (tmp_path / "c.json").exists()


def test_an_unclassified_cloud_is_refused(tmp_path):
    """Trial s94: `lidarctl vectors` of an unclassified cloud wrote a GeoPackage of empty layers, exit 0."""
    cloud = _write_las(tmp_path / "c.las")
    pts = laspy.read(cloud)
    pts.classification = np.zeros(len(pts.x), np.uint8)
    pts.write(tmp_path / "u.las")
    r = CliRunner().invoke(main, ["vectors", str(tmp_path / "u.las"), str(tmp_path / "u.gpkg")])
    assert r.exit_code == 2 and "no ground (2) or building (6) points" in r.output and "classify" in r.output
    assert not (tmp_path / "u.gpkg").exists()


def test_swapped_product_and_reference_are_said(made, tmp_path, caplog):
    import logging

    _, _, out = made
    ref = _reference(tmp_path / "ref.gpkg")
    with caplog.at_level(logging.WARNING):
        vc.check_vectors(ref, out, vc.VectorCheckSettings(layers=("buildings",)))
    assert any("ref.gpkg has no coverage layer but" in r.getMessage() and "swapped?" in r.getMessage()
               for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        vc.check_vectors(out, ref, vc.VectorCheckSettings(layers=("buildings",)))
    assert not any("swapped?" in r.getMessage() for r in caplog.records)


def test_neighbouring_outlines_do_not_overlap():
    """Trial s94: two pairs of AHN3 Delft's regularised outlines overlapped by 1.0 and 3.1 m2 (a GIS's "must not
    overlap" rule failed); the overlap stays with the larger outline."""
    from lidarctl.vectors.layers import _without_overlaps

    big, small, apart = box(0, 0, 20, 10), box(19.5, 0, 30, 10), box(40, 0, 45, 5)
    out = _without_overlaps([(small, 2, "pitched", 0.5), (big, 1, "flat", 0.5), (apart, 3, "cells", 0.5)])
    assert [c[1:] for c in out] == [(2, "pitched", 0.5), (1, "flat", 0.5), (3, "cells", 0.5)]
    assert out[1][0].equals(big) and out[2][0].equals(apart)
    assert out[0][0].area == pytest.approx(small.area - 5.0) and out[0][0].intersection(big).area == 0.0
    # a small outline inside a larger one goes
    assert [c[1] for c in _without_overlaps([(box(1, 1, 2, 2), 9, "cells", 0.5), (big, 1, "flat", 0.5)])] == [1]
