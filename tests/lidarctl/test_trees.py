"""lidarctl trees (CHM, stands, tree tops) and check-heights --dem / --groups density, on small synthetic clouds
with known truth: cone-shaped trees of known height on flat ground, a forest edge of known canopy cover."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin

from aerotri.geom.las import US_SURVEY_FOOT_M
from lidarctl import synthetic
from lidarctl.cli.main import main
from lidarctl.io import PointCloud
from lidarctl.rasters.trees import TreeSettings, tree_model

X0, Y0, GROUND_Z = 500000.0, 5000000.0, 100.0
# (x, y, height, crown radius) in metres from the scene's corner
CONES = ((25.0, 25.0, 15.0, 4.0), (62.0, 22.0, 10.0, 3.0), (45.0, 68.0, 20.0, 5.0), (18.0, 70.0, 8.0, 2.5),
         (75.0, 75.0, 12.0, 3.5), (75.0, 45.0, 6.0, 2.5))


def cone_cloud(cones=CONES, size_m: float = 100.0, density: float = 8.0, seed: int = 0, gap=None):
    """Flat ground at 100 m with cone-shaped crowns (first returns on the cone, 30 % of them with a last
    return on the ground), classes 2/3/4/5; ``gap`` (x0, x1): a band without any return (water, a shadow)."""
    rng = np.random.default_rng(seed)
    n = int(size_m * size_m * density)
    x, y = rng.uniform(0, size_m, n), rng.uniform(0, size_m, n)
    if gap is not None:
        keep = (x < gap[0]) | (x > gap[1])
        x, y = x[keep], y[keep]
        n = len(x)
    h = np.zeros(n)
    for cx, cy, top, r in cones:
        d = np.hypot(x - cx, y - cy)
        h = np.maximum(h, np.where(d < r, top * (1 - d / r), 0.0))
    veg = h > 0.3
    cls = np.where(veg, np.where(h > 2, 5, np.where(h > 0.5, 4, 3)), 2).astype(np.uint8)
    through = veg & (rng.random(n) < 0.3)
    k = int(through.sum())
    xs = np.concatenate([x, x[through]]) + X0
    ys = np.concatenate([y, y[through]]) + Y0
    zs = np.concatenate([GROUND_Z + h, np.full(k, GROUND_Z)]) + rng.normal(0, 0.02, n + k)
    rn = np.concatenate([np.ones(n, np.uint8), np.full(k, 2, np.uint8)])
    nr = np.concatenate([np.where(through, 2, 1), np.full(k, 2)]).astype(np.uint8)
    cl = np.concatenate([cls, np.full(k, 2, np.uint8)])
    return PointCloud(xs, ys, zs, np.full(n + k, 100, np.uint16), rn, nr, cl)


@pytest.fixture(scope="module")
def cones_las(tmp_path_factory):
    d = tmp_path_factory.mktemp("trees")
    cloud = cone_cloud()
    synthetic.write_las(d / "cones.laz", cloud, crs="EPSG:32632")
    synthetic.write_las(d / "cones_ft.laz", cloud, crs="EPSG:2264")   # NC state plane, US survey feet
    return d, cloud


def _ok(args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r


def _fails(args, out, text):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 2, r.output
    assert text in r.output, r.output
    assert "Traceback" not in r.output
    assert not out.exists() or not any(out.iterdir())
    return r


def test_trees_heights_tops_and_stands_against_the_cones(cones_las):
    import pyogrio.raw
    import shapely

    d, _ = cones_las
    out = d / "out"
    r = _ok(["trees", d / "cones.laz", out, "--min-stand-area-m2", "5"])
    assert "6 stands" in r.output and "6 tree tops" in r.output
    s = json.loads((out / "trees.json").read_text())
    assert s["stands"] == 6 and s["tree_tops"] == 6 and s["xy_unit"] == "m"
    _, _, geoms, (ids, heights, _, _, stand_ids) = pyogrio.raw.read(out / "trees.gpkg", layer="tree_tops")
    tops = shapely.get_coordinates(shapely.from_wkb(geoms))
    for cx, cy, top, r_m in CONES:
        k = np.argmin(np.hypot(tops[:, 0] - X0 - cx, tops[:, 1] - Y0 - cy))
        assert np.hypot(tops[k, 0] - X0 - cx, tops[k, 1] - Y0 - cy) < 0.75        # the apex found
        # a cone's apex is sharp: the highest return lies up to a point spacing below it (slope top / r)
        assert top - 0.5 * top / r_m - 0.15 < heights[k] <= top + 0.1
    assert len(set(stand_ids)) == 6                                                # one top per stand
    with rasterio.open(out / "chm.tif") as ds:
        assert ds.crs.to_epsg() == 32632 and ds.units == ("metre",)
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        chm = ds.read(1, masked=True)
        rows, cols = np.mgrid[0:ds.height, 0:ds.width]
        xs, ys = rasterio.transform.xy(ds.transform, rows.ravel(), cols.ravel())
    xs, ys = np.array(xs).reshape(chm.shape) - X0, np.array(ys).reshape(chm.shape) - Y0
    true = np.zeros(chm.shape)
    for cx, cy, top, r_m in CONES:
        true = np.maximum(true, np.clip(top * (1 - np.hypot(xs - cx, ys - cy) / r_m), 0, None))
    # NODATA where no trees (open ground and below 2 m), heights within 0.5 m where there are
    assert not chm.mask[true > 3.0].any() and chm.mask[true < 1.0].all()
    err = (chm - true)[~chm.mask & (true > 3.0)]
    assert np.sqrt(np.mean(err ** 2)) < 0.5
    _, _, sg, (sid, area, n_tops, mean_h, p50, p90, p95, hmax) = pyogrio.raw.read(out / "trees.gpkg", layer="stands")
    for cx, cy, top, r_m in CONES:
        k = int(np.argmin([shapely.distance(g, shapely.Point(X0 + cx, Y0 + cy)) for g in shapely.from_wkb(sg)]))
        true_area = np.pi * (r_m * (1 - 2.0 / top)) ** 2     # the cone above the 2 m minimum height
        assert area[k] == pytest.approx(true_area, rel=0.25) and n_tops[k] == 1
        assert p50[k] <= p90[k] <= p95[k] <= hmax[k] <= top and hmax[k] > top - 0.5 * top / r_m - 0.15
        # the mean height of a cone above 2 m: 2 + (top - 2) / 3
        assert mean_h[k] == pytest.approx(2 + (top - 2) / 3, abs=0.4)
    assert (out / "trees.png").stat().st_size > 10_000


def test_trees_in_us_feet_equal_the_metric_run(cones_las, monkeypatch):
    import pyogrio.raw

    from lidarctl.rasters import trees as trees_module

    drawn = []  # the previews' axes: new-user trial, Autzen's map drew metres beside a chm.tif in feet
    save = trees_module.save_png

    def keep(fig, path, **kw):
        ax, key = fig.axes
        drawn.append((ax.get_xlabel(), ax.get_xlim()[1], ax.images[0].get_array().max(), key.get_ylabel()))
        save(fig, path, **kw)

    monkeypatch.setattr(trees_module, "save_png", keep)
    d, _ = cones_las
    _ok(["trees", d / "cones.laz", d / "m", "--min-stand-area-m2", "5"])
    _ok(["trees", d / "cones_ft.laz", d / "ft", "--min-stand-area-m2", "5"])
    (xm, wm, zm, km), (xf, wf, zf, kf) = drawn
    assert xm.startswith("m east of easting") and xf.startswith("us-ft east of easting")
    assert wf * US_SURVEY_FOOT_M == pytest.approx(wm, rel=0.01) and zf * US_SURVEY_FOOT_M == pytest.approx(zm, abs=0.02)
    assert km.startswith("tree height above ground (m)") and kf.startswith("tree height above ground (us-ft)")
    sm, sf = (json.loads((d / k / "trees.json").read_text()) for k in ("m", "ft"))
    assert sf["xy_unit"] == "us-ft" and sf["z_unit"] == "us-ft"
    assert sf["forest_area_m2"] == pytest.approx(sm["forest_area_m2"], rel=0.02)
    assert sf["forest_heights"]["max_height_m"] == pytest.approx(sm["forest_heights"]["max_height_m"], abs=0.02)
    with rasterio.open(d / "m" / "chm.tif") as a, rasterio.open(d / "ft" / "chm.tif") as b:
        assert b.units == ("US survey foot",)
        assert b.transform.a == pytest.approx(0.5 / US_SURVEY_FOOT_M)
        assert float(b.read(1, masked=True).max()) * US_SURVEY_FOOT_M == pytest.approx(
            float(a.read(1, masked=True).max()), abs=0.02)
    _, _, _, fm = pyogrio.raw.read(d / "m" / "trees.gpkg", layer="tree_tops")
    _, _, _, ff = pyogrio.raw.read(d / "ft" / "trees.gpkg", layer="tree_tops")
    np.testing.assert_allclose(ff[1], fm[1], atol=0.02)                    # height_m in metres
    np.testing.assert_allclose(ff[2] * US_SURVEY_FOOT_M, fm[2], atol=0.02)  # height in the CRS's unit


def test_tin_edge_limit_keeps_gaps_between_crowns_nodata():
    # two crowns 9 m apart with a 4 m band without returns between them, lined up along y
    cones = ((40.0, 30.0, 12.0, 6.0), (49.0, 30.0, 12.0, 6.0))
    c = cone_cloud(cones, size_m=80.0, density=6.0, gap=(42.5, 46.5))
    args = (c.x, c.y, c.z, c.classification, c.return_number)
    short = tree_model(*args, TreeSettings(max_edge_m=2.0, min_stand_area_m2=10))
    long = tree_model(*args, TreeSettings(max_edge_m=10.0, min_stand_area_m2=10))
    g = short.grid
    col = lambda x: int((X0 + x - g.x0) / g.res_m)   # noqa: E731
    row = int((g.y_top - (Y0 + 30.0)) / g.res_m)
    assert np.isnan(short.chm[row, col(43.5):col(45.5)]).all()      # the gap stays NODATA
    assert np.isfinite(long.chm[row, col(43.5):col(45.5)]).all()    # a long edge bridges it
    assert len(short.stands) == 2 and len(long.stands) == 1


def test_cells_far_finer_than_the_points_are_warned_about(caplog):
    """Trial-forest: `trees --res-m 0.05` on Autzen (about 25 M cells) ran 9 minutes without a word; the rasters'
    warning (more than 100 cells a point) now comes from trees too, and not at a cell of the points' spacing."""
    c = cone_cloud(((40.0, 30.0, 12.0, 6.0),), size_m=40.0, density=0.5)
    args = (c.x, c.y, c.z, c.classification, c.return_number)
    with caplog.at_level("WARNING", logger="lidarctl.rasters.products"):
        tree_model(*args, TreeSettings(res_m=0.1, min_stand_area_m2=10))
    assert any("a point): the grids interpolate between the points" in m for m in caplog.messages), caplog.messages
    caplog.clear()
    with caplog.at_level("WARNING", logger="lidarctl.rasters.products"):
        tree_model(*args, TreeSettings(res_m=1.0, min_stand_area_m2=10))
    assert not caplog.messages


def test_trees_bad_input_exit_2_and_nothing_written(cones_las, tmp_path):
    d, cloud = cones_las
    no_ground = PointCloud(cloud.x, cloud.y, cloud.z, cloud.intensity, cloud.return_number,
                           cloud.number_of_returns, np.where(cloud.classification == 2, 1, cloud.classification))
    synthetic.write_las(tmp_path / "noground.laz", no_ground, crs="EPSG:32632")
    out = tmp_path / "o"
    _fails(["trees", tmp_path / "noground.laz", out], out, "noground.laz")
    _fails(["trees", d / "cones.laz", out, "--max-edge-m", "0.2"], out, "--max-edge-m")
    _fails(["trees", d / "cones.laz", out, "--classes", "3,x"], out, "--classes")
    _fails(["trees", d / "cones.laz", out, "--classes", "2"], out, "--classes")
    _fails(["trees", d / "cones.laz", out, "--res-m", "-1"], out, "--res-m")
    (tmp_path / "trunc.laz").write_bytes((d / "cones.laz").read_bytes()[:5000])
    _fails(["trees", tmp_path / "trunc.laz", out], out, "trunc.laz")
    assert not list(tmp_path.glob(".*part-*"))


# ------------------------------------------------------------------------------------------------
# check-heights --dem and --groups density


def forest_edge_cloud(seed: int = 1):
    """60 x 60 m on a 5 % slope: canopy 15 m high with cover 0.9 (x < 20 m), 0.4 (20-40 m), 0 (x > 40 m)."""
    rng = np.random.default_rng(seed)
    n = 60 * 60 * 10
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 60, n)
    ground = GROUND_Z + 0.05 * x
    cover = np.where(x < 20, 0.9, np.where(x < 40, 0.4, 0.0))
    canopy = rng.random(n) < cover
    z = ground + np.where(canopy, 15.0 + rng.normal(0, 1, n), rng.normal(0, 0.02, n))
    cls = np.where(canopy, 5, 2).astype(np.uint8)
    under = canopy & (rng.random(n) < 0.5)
    k = int(under.sum())
    xs, ys = np.concatenate([x, x[under]]), np.concatenate([y, y[under]])
    zs = np.concatenate([z, ground[under] + rng.normal(0, 0.02, k)])
    rn = np.concatenate([np.ones(n, np.uint8), np.full(k, 2, np.uint8)])
    nr = np.concatenate([np.where(under, 2, 1), np.full(k, 2)]).astype(np.uint8)
    return PointCloud(xs + X0, ys + Y0, zs, np.full(n + k, 100, np.uint16), rn, nr,
                      np.concatenate([cls, np.full(k, 2, np.uint8)]))


@pytest.fixture(scope="module")
def forest_edge(tmp_path_factory):
    d = tmp_path_factory.mktemp("edge")
    synthetic.write_las(d / "edge.laz", forest_edge_cloud(), crs="EPSG:32632")
    # a DEM of the true terrain, 1 m cells, raised by 0.4 m where x > 40 m (the open part) and 0.7 m where
    # x < 20 m (the dense part): the DEM check must report exactly these errors per group
    xc = np.arange(60) + 0.5
    dem = np.tile(GROUND_Z + 0.05 * xc + np.where(xc > 40, 0.4, np.where(xc < 20, 0.7, 0.0)), (60, 1))
    with rasterio.open(d / "dem.tif", "w", driver="GTiff", width=60, height=60, count=1, dtype="float32",
                       crs="EPSG:32632", transform=from_origin(X0, Y0 + 60, 1.0, 1.0), nodata=-9999.0) as ds:
        ds.write(dem.astype(np.float32), 1)
    rng = np.random.default_rng(5)
    px = np.concatenate([rng.uniform(6, 14, 8), rng.uniform(26, 34, 8), rng.uniform(46, 54, 8)])
    py = rng.uniform(8, 52, 24)
    pz = GROUND_Z + 0.05 * px
    (d / "pts.csv").write_text("id,x,y,z\n" + "".join(f"P{k},{X0 + a:.3f},{Y0 + b:.3f},{c:.4f}\n"
                                                      for k, (a, b, c) in enumerate(zip(px, py, pz))))
    return d


def test_check_heights_dem_by_vegetation_density(forest_edge):
    d = forest_edge
    r = _ok(["check-heights", d / "edge.laz", d / "pts.csv", "--dem", d / "dem.tif", "--groups", "density",
             "--json", d / "hc.json"])
    hc = json.loads((d / "hc.json").read_text())
    groups = [p["group"] for p in hc["points"]]
    assert groups == ["dense"] * 8 + ["sparse"] * 8 + ["open"] * 8
    cover = np.array([p["canopy_cover"] for p in hc["points"]])
    np.testing.assert_allclose(cover, np.repeat([0.9, 0.4, 0.0], 8), atol=0.1)
    dem = hc["dem"]
    assert list(dem["groups"]) == ["open", "sparse", "dense"]
    assert dem["groups"]["open"]["all"]["rmse_m"] == pytest.approx(0.4, abs=0.01)
    assert dem["groups"]["sparse"]["all"]["mean_abs_dz_m"] == pytest.approx(0.0, abs=0.01)
    assert dem["groups"]["dense"]["all"]["mean_dz_m"] == pytest.approx(0.7, abs=0.01)
    # seed 004 Tab. 1 bins: the open points in 0.3-0.5, the dense ones in 0.5-1
    assert [b["count"] for b in dem["groups"]["open"]["abs_bins"]] == [0, 8, 0, 0]
    assert [b["count"] for b in dem["groups"]["dense"]["abs_bins"]] == [0, 0, 8, 0]
    assert hc["groups"]["open"]["all"]["rmse_m"] < 0.05            # the ground points: no offset
    assert "DEM by group" in r.output and "0.3 < |dz| <= 0.5" in r.output
    # the same groups from the cloud's ground planes (no DEM) and with other thresholds
    _ok(["check-heights", d / "edge.laz", d / "pts.csv", "--groups", "density", "--dense-above", "0.95",
         "--json", d / "hc2.json"])
    hc2 = json.loads((d / "hc2.json").read_text())
    assert [p["group"] for p in hc2["points"]] == ["sparse"] * 16 + ["open"] * 8 and "dem" not in hc2


def test_check_heights_dem_alone_with_group_column(forest_edge, tmp_path, monkeypatch):
    d = forest_edge
    lines = (d / "pts.csv").read_text().splitlines()
    pts = tmp_path / "g.csv"
    pts.write_text("\n".join([lines[0] + ",group"] + [f"{ln},{'wood' if k < 8 else 'field'}"
                                                       for k, ln in enumerate(lines[1:])]) + "\n")
    monkeypatch.chdir(d)  # the DEM given relative to the working folder, as a user types it
    _ok(["check-heights", pts, "--dem", "dem.tif", "--json", tmp_path / "hc.json"])
    hc = json.loads((tmp_path / "hc.json").read_text())
    assert hc["dem"]["path"] == str((d / "dem.tif").resolve())  # found again from any other folder
    assert hc["overall"] == hc["dem"]["overall"] and hc["overall_surface"] == "dem" and hc["grouping"] == "column"
    assert hc["dem"]["groups"]["wood"]["all"]["mean_dz_m"] == pytest.approx(0.7, abs=0.01)
    assert hc["dem"]["groups"]["field"]["all"]["n"] == 16


@pytest.mark.parametrize("column", ["landcover", "Land_Cover", "cover"])
def test_check_heights_reads_the_land_cover_under_its_usual_names(forest_edge, tmp_path, column):
    """trial-us 1b: only a column named "group" was read; a "landcover" column was dropped without a word, and the
    report judged the forest points as open ground, saying check-heights ran without --groups."""
    d = forest_edge
    lines = (d / "pts.csv").read_text().splitlines()
    pts = tmp_path / "g.csv"
    pts.write_text("\n".join([lines[0] + f",{column}"] + [f"{ln},{'VVA' if k < 8 else 'NVA'}"
                                                          for k, ln in enumerate(lines[1:])]) + "\n")
    _ok(["check-heights", pts, "--dem", d / "dem.tif", "--json", tmp_path / "hc.json"])
    hc = json.loads((tmp_path / "hc.json").read_text())
    assert hc["grouping"] == "column"
    assert hc["dem"]["groups"]["VVA"]["all"]["mean_dz_m"] == pytest.approx(0.7, abs=0.01)
    assert hc["dem"]["groups"]["NVA"]["all"]["n"] == 16


def test_check_heights_dem_bad_input(forest_edge, tmp_path):
    d = forest_edge
    out = tmp_path / "x"
    out.mkdir()
    _fails(["check-heights", d / "pts.csv", "--json", out / "a.json"], out, "--dem")
    _fails(["check-heights", d / "pts.csv", "--dem", d / "dem.tif", "--groups", "density", "--json", out / "a.json"],
           out, "--groups")
    _fails(["check-heights", d / "edge.laz", d / "pts.csv", "--groups", "density", "--open-below", "0.7",
            "--json", out / "a.json"], out, "--dense-above")
    with rasterio.open(d / "dem.tif") as src:
        profile, data = src.profile, src.read()
    profile.update(crs="EPSG:32633")
    with rasterio.open(tmp_path / "other.tif", "w", **profile) as dst:
        dst.write(data)
    _fails(["check-heights", d / "edge.laz", d / "pts.csv", "--dem", tmp_path / "other.tif", "--json",
            out / "a.json"], out, "other.tif")
    (tmp_path / "bad.tif").write_text("not a raster")
    _fails(["check-heights", d / "pts.csv", "--dem", tmp_path / "bad.tif", "--json", out / "a.json"], out, "bad.tif")


def test_the_trees_map_names_its_corner_in_the_crs_unit():
    """Autzen (international feet): the corner is the easting of the user's files, not its value in metres, and the
    distances from it are in feet too (new-user trial: "metres east of easting 636000.7 ft")."""
    from lidarctl.rasters.trees import corner_axis_labels
    from lidarctl.units import LengthUnits

    x, y = corner_axis_labels(193853.0, 1502.4, LengthUnits(xy_m=0.3048, z_m=0.3048))
    assert x == "ft east of easting 636000.7 ft" and y == "ft north of northing 4929.1 ft"
    assert corner_axis_labels(100.0, 200.0, LengthUnits())[0] == "m east of easting 100.0 m"


def test_stands_touching_at_a_corner_are_valid_polygons_of_their_cells():
    """8-connected canopy cells that meet at a corner only: GDAL traces them as a ring touching itself, an invalid
    polygon (lidR Topography: 5 of 5 stands invalid, AHN3 Delft 15 of 17); now valid, with the cells' area."""
    import shapely

    from lidarctl.rasters.trees import _stand_polygons

    label = np.zeros((8, 8), np.int32)
    label[1:3, 1:3] = 1          # a block and one cell diagonal to it: one 8-connected stand
    label[3, 3] = 1
    label[4:7, 4:7] = 2          # a ring of cells around a gap whose corner touches the outer edge
    label[5, 5] = 0
    label[4, 4] = 0
    label[3, 4] = 2
    polys = _stand_polygons(label, from_origin(500000.0, 5000008.0, 1.0, 1.0))
    assert sorted(polys) == [1, 2]
    for k, g in polys.items():
        assert shapely.is_valid(g), shapely.is_valid_reason(g)
        assert g.geom_type in ("Polygon", "MultiPolygon")
        assert g.area == pytest.approx(float((label == k).sum()))


def test_points_off_the_data_under_density_groups_are_named_in_the_nva_and_vva_rows(forest_edge, tmp_path):
    # sf-fixes (review of small-fixes): under --groups density a surveyed point off the data has no first return
    # near it, so its group is "unknown" (land cover unknown): it went into neither the NVA's nor the VVA's list of
    # points not counted (Autzen: NVA row 35 points, n_outside 0 with 4 points 5,000 ft off the data). Now it is in
    # both, marked "land cover unknown"; the verdict table's non-vegetated row names no vegetated point
    from aerotri.qa.report import compliance_lines, write_qa_report

    d = forest_edge
    (tmp_path / "project.toml").write_text('[project]\nname = "edge"\ncrs = "EPSG:32632"\n')
    (tmp_path / "lidar_out").mkdir()
    pts = tmp_path / "pts.csv"
    # 24 points on the DEM (8 dense, 8 sparse, 8 open) and 2 far off the data (no first return within 10 m)
    pts.write_text((d / "pts.csv").read_text() + f"X0,{X0 - 500:.3f},{Y0 + 30:.3f},100.0\n"
                   f"X1,{X0 + 30:.3f},{Y0 + 900:.3f},100.0\n")
    r = _ok(["check-heights", d / "edge.laz", pts, "--dem", d / "dem.tif", "--groups", "density",
             "--json", tmp_path / "lidar_out" / "height_check.json"])
    hc = json.loads((tmp_path / "lidar_out" / "height_check.json").read_text())
    assert [p["group"] for p in hc["points"][-2:]] == ["unknown", "unknown"]
    assert [p["dz_dem_m"] for p in hc["points"][-2:]] == [None, None]
    # fixes2 4: the group tables listed "unknown 0" (and 0.0 % in every bin) beside the 2 unknown points: they have
    # no dz; the tables say so, and height_check.json counts the group's points
    unknown = hc["dem"]["groups"]["unknown"]
    assert unknown["all"]["n"] == 0 and unknown["n_points"] == 2 and hc["dem"]["groups"]["open"]["n_points"] == 8
    rows = [ln for ln in r.output.splitlines() if ln.startswith("  unknown ")]
    assert len(rows) == 2  # the ground points' table and the DEM's
    assert all("%" not in x and x.split()[1] == "0" and x.endswith("(2 of 2 points without a dz (no statistics "
                                                                   "from them))") for x in rows), rows
    assert "Group: unknown (DEM; 2 of 2 points without a dz" in r.output
    rep = write_qa_report(tmp_path, standard="usgs-lbs", accuracy_class="QL2")
    nva, vva = [c for c in rep.compliance["checks"] if c["product"] == "LiDAR DEM"]
    assert nva["n_points"] == 8 and vva["n_points"] == 16               # open; sparse and dense
    for row in (nva, vva):
        assert row["n_outside"] == 2 and list(row["outside_ids"]) == ["X0", "X1"], row
        assert list(row["outside_unknown_ids"]) == ["X0", "X1"]
        assert ("2 check points with no valid cell of the DEM dem.tif under them, not counted (land cover unknown: "
                "X0, X1)") in row["checkpoints_note"], row["checkpoints_note"]
    lines = compliance_lines(rep.compliance)
    assert sum("not counted (land cover unknown: X0, X1)" in ln for ln in lines) == 2, lines
    # the verdict table judges the open points only under the LBS NVA limit: the off-data points named there too
    row = [c for c in rep.checks if c.id == "dem_raster_rmse_m"][0]
    assert "at 8 non-vegetated surveyed points" in row.quantity
    assert row.note == ("2 surveyed points with no valid cell of the DEM dem.tif under them, not counted (land cover "
                        "unknown: X0, X1); 8 check points, 30 required by USGS Lidar Base Specification: indicative "
                        "only")   # (trial-qa)


def test_trees_and_rasters_do_not_replace_each_others_chm(cones_las, tmp_path):
    """Trial s96 F2: `lidarctl trees` into the folder of `lidarctl rasters` replaced its chm.tif (1 m highest
    vegetation) by its own (0.5 m pit-free TIN) without a word; the other way round too. Refused, nothing changed."""
    import hashlib

    d, _ = cones_las
    out = tmp_path / "r"
    _ok(["rasters", d / "cones.laz", out, "--res-m", "1"])
    before = hashlib.sha256((out / "chm.tif").read_bytes()).hexdigest()
    r = CliRunner().invoke(main, ["trees", str(d / "cones.laz"), str(out)])
    assert r.exit_code == 2 and "holds the chm.tif of lidarctl rasters (beside dem.tif, dsm.tif, ndsm.tif)" in r.output
    assert hashlib.sha256((out / "chm.tif").read_bytes()).hexdigest() == before and not (out / "trees.json").exists()
    t = tmp_path / "t"
    _ok(["trees", d / "cones.laz", t])
    r = CliRunner().invoke(main, ["rasters", str(d / "cones.laz"), str(t), "--res-m", "1"])
    assert r.exit_code == 2 and "holds the chm.tif of lidarctl trees" in r.output and not (t / "dem.tif").exists()
