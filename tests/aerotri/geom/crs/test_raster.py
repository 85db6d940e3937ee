"""Rasters across datums (``aerotri crs warp``) and the coordinate-operation policy around rasters: DEM
heights change with the datum, nodata is kept, a compound DEM CRS is taken by its parts, and no silent
ballpark anywhere (the local adjustment frame on a non-WGS 84 project datum included)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from pyproj import CRS

from aerotri.cli import main as aerotri_cli
from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7
from aerotri.geom.crs.datum import HeightAnomalyModel, Transformation
from aerotri.geom.crs.ellipsoid import IAG75, geodetic_to_geocentric
from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.crs.transform import BallparkRefused, CrsTransformer

XIAN_GK = "EPSG:2382"  # Xian 1980 / 3-degree GK CM 111E


@pytest.fixture(scope="module")
def dem_and_params(tiny_project, tmp_path_factory):
    d = tmp_path_factory.mktemp("warp")
    dem = d / "dem.tif"
    with rasterio.open(tiny_project / "truth" / "dem.tif") as src:
        profile = src.profile
        a = src.read(1)
    a[100:140, 200:260] = profile["nodata"]  # a hole the warp must keep
    with rasterio.open(dem, "w", **profile) as dst:
        dst.write(a, 1)
    params = d / "xian.json"
    T = Transformation("bursa-wolf7", dict(TRUE_BURSA_WOLF7), "EPSG:32649", XIAN_GK)
    params.write_text(json.dumps(T.to_dict()))
    return dem, params, T


def _bilinear(ds, x, y):
    a = ds.read(1, masked=True).filled(np.nan).astype(float)
    c = (x - ds.transform.c) / ds.transform.a - 0.5
    r = (y - ds.transform.f) / ds.transform.e - 0.5
    c0, r0 = np.floor(c).astype(int), np.floor(r).astype(int)
    fc, fr = c - c0, r - r0
    return (a[r0, c0] * (1 - fc) * (1 - fr) + a[r0, c0 + 1] * fc * (1 - fr) + a[r0 + 1, c0] * (1 - fc) * fr
            + a[r0 + 1, c0 + 1] * fc * fr)


def test_dem_warp_moves_heights_with_the_datum(dem_and_params, tmp_path):
    dem, params, T = dem_and_params
    out = tmp_path / "dem_xian.tif"
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(dem), str(out), "--to", XIAN_GK, "--params", str(params)])
    assert r.exit_code == 0, r.output
    assert "height raster" in r.output
    assert " m in EPSG:2382 (height raster" in r.output, r.output  # the cells' unit (trial: "cells of 1 in EPSG:3740")
    op = CrsTransformer("EPSG:32649", XIAN_GK, params=T)
    rng = np.random.default_rng(5)
    with rasterio.open(dem) as src, rasterio.open(out) as dst:
        assert dst.crs.to_epsg() == 2382 and dst.nodata == src.nodata
        assert dst.profile["tiled"] and dst.overviews(1)  # a COG
        assert "bursa-wolf7" in dst.tags()["COORDINATE_OPERATION"]
        b = src.bounds
        x = rng.uniform(b.left + 20, b.right - 20, 400)
        y = rng.uniform(b.bottom + 20, b.top - 20, 400)
        z = _bilinear(src, x, y)
        keep = np.isfinite(z) & (z != src.nodata)
        X, Y, Z = op.transform(x[keep], y[keep], z[keep])
        got = _bilinear(dst, X, Y)
        dz = got - Z
        ok = np.isfinite(dz) & (np.abs(got) < 1e4)
        assert ok.sum() > 300
        assert np.median(np.abs(Z - z[keep])) > 5.0  # the datum shift changes heights by metres ...
        assert np.sqrt(np.mean(dz[ok] ** 2)) < 0.05  # ... and the warped DEM carries the change
        # the hole stays nodata at its new place
        hx, hy = src.xy(120, 230)
        HX, HY, _ = op.transform([hx], [hy], [300.0])
        row, col = dst.index(HX[0], HY[0])
        assert dst.read(1)[row, col] == dst.nodata


def test_warp_refuses_ballpark_and_its_input_as_output(dem_and_params, tmp_path):
    dem, _, _ = dem_and_params
    out = tmp_path / "x.tif"
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(dem), str(out), "--to", XIAN_GK])
    assert r.exit_code == 2 and "ballpark" in r.output and not out.exists()
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(dem), str(dem), "--to", XIAN_GK])
    assert r.exit_code == 2 and "input" in r.output


def test_height_model_makes_normal_heights(dem_and_params, tmp_path):
    """Within one CRS, a height anomaly model (zeta = 20 m + a slope) turns ellipsoidal into normal heights."""
    dem, _, _ = dem_and_params
    model = HeightAnomalyModel("plane", (452250.0, 3407400.0), coefficients=[20.0, 0.5, -0.25], crs="EPSG:32649")
    mfile = tmp_path / "zeta.json"
    mfile.write_text(json.dumps(model.to_dict()))
    out = tmp_path / "dem_normal.tif"
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(dem), str(out), "--to", "EPSG:32649", "--heights", str(mfile)])
    assert r.exit_code == 0, r.output
    with rasterio.open(dem) as a, rasterio.open(out) as b:
        assert b.transform == a.transform
        za, zb = a.read(1, masked=True), b.read(1, masked=True)
        rows, cols = np.nonzero(~np.ma.getmaskarray(za) & ~np.ma.getmaskarray(zb))
        xs, ys = rasterio.transform.xy(a.transform, rows, cols)
        expect = za[rows, cols] - model.zeta_m(np.array(xs), np.array(ys))
        assert np.abs(zb[rows, cols] - expect).max() < 2e-3


def test_ortho_dem_compound_crs_by_its_parts(tiny_project, tmp_path):
    """A DEM tagged UTM 49N + EGM2008 height: its horizontal part is the project's. With an ellipsoidal
    project and no geoid grid it is refused naming the grid; with the project's heights declared as
    EGM2008 it is used as it is; with a height anomaly model its heights are converted."""
    root = tmp_path / "p"
    shutil.copytree(tiny_project, root)
    dem = tmp_path / "dem_egm.tif"
    with rasterio.open(root / "truth" / "dem.tif") as src:
        profile = dict(src.profile, crs=rasterio.crs.CRS.from_wkt(CRS("EPSG:32649+3855").to_wkt()))
        with rasterio.open(dem, "w", **profile) as dst:
            dst.write(src.read(1), 1)
    args = ["rectify", str(root), "--eo", str(root / "truth" / "eo.txt"), "--dem", str(dem), "--res-m", "1",
            "--frames", "s01_001"]
    from ortho.cli import main as ortho_cli

    r = CliRunner().invoke(ortho_cli, args)
    assert r.exit_code == 2 and "us_nga_egm08_25.tif" in r.output and "projsync" in r.output, r.output
    toml = (root / "project.toml").read_text()
    (root / "project.toml").write_text(toml.replace('heights = "ellipsoidal"', 'heights = "EPSG:3855"'))
    r = CliRunner().invoke(ortho_cli, args)
    assert r.exit_code == 0, r.output
    assert json.loads((root / "ortho" / "frames" / "index.json").read_text())["height_operation"] is None
    (root / "project.toml").write_text(toml)
    model = HeightAnomalyModel("plane", (452250.0, 3407400.0), coefficients=[-12.0, 0.0, 0.0], crs="EPSG:32649")
    (tmp_path / "zeta.json").write_text(json.dumps(model.to_dict()))
    r = CliRunner().invoke(ortho_cli, args + ["--heights", str(tmp_path / "zeta.json")])
    assert r.exit_code == 0, r.output
    rec = json.loads((root / "ortho" / "frames" / "index.json").read_text())["height_operation"]
    assert rec["steps"][-1]["formula"] == "h = H + zeta(x, y)"


def test_local_frame_uses_the_projects_own_datum():
    """A Xian 1980 GK project: the adjustment frame is geocentric on Xian 1980's own ellipsoid (IAG 75),
    no WGS 84 datum shift (which PROJ could only do as a ballpark)."""
    crs = CRS.from_epsg(2382)
    frame = LocalFrame(crs, (500200.0, 3410000.0, 350.0))
    assert all(s["step"] != "proj" or not s["ballpark"] for s in frame._to_ecef.record()["steps"])
    lon, lat = CrsTransformer(crs, crs.geodetic_crs).transform([500200.0], [3410000.0])[:2]
    X, Y, Z = geodetic_to_geocentric(lat, lon, np.array([350.0]), IAG75)
    assert np.allclose(frame.ecef0, np.concatenate([X, Y, Z]), atol=1e-6)
    # round trip and a 1 km east offset stays 1 km (grid scale aside)
    p = np.array([[500200.0, 3410000.0, 350.0], [501200.0, 3410000.0, 350.0]])
    assert np.allclose(frame.to_map(frame.to_local(p)), p, atol=1e-6)
    with pytest.raises(BallparkRefused):
        CrsTransformer(crs, "EPSG:4978")


@pytest.fixture
def small_dem(tmp_path):
    """50 x 50 float32 DEM of 1 m cells in EPSG:32649, heights 100..107.35 m (a tilted plane)."""
    z = (100.0 + 0.1 * np.arange(50)[:, None] + 0.05 * np.arange(50)[None, :]).astype(np.float32)
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=50, height=50, count=1, dtype="float32", crs="EPSG:32649",
                       transform=rasterio.Affine(1.0, 0.0, 500_000.0, 0.0, -1.0, 3_400_000.0),
                       nodata=-9999.0) as ds:
        ds.write(z, 1)
    return dem


TMERC_PROJ = "+proj=tmerc +lon_0=111.2 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs"
LCC_USFT_PROJ = ("+proj=lcc +lat_1=30 +lat_2=32 +lat_0=29 +lon_0=111 +x_0=0 +y_0=0 +datum=WGS84 +units=us-ft "
                 "+no_defs")


@pytest.mark.parametrize("to, z_unit_m, z_unit", [(TMERC_PROJ, 1.0, "metre"),
                                                  (LCC_USFT_PROJ, 1200 / 3937, "US survey foot")])
def test_warp_to_a_proj_string_keeps_the_crs_and_labels_heights_with_their_unit(small_dem, tmp_path, to, z_unit_m,
                                                                                z_unit):
    out = tmp_path / "out.tif"
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(small_dem), str(out), "--to", to])
    assert r.exit_code == 0, r.output
    want = CRS.from_user_input(to)
    op = CrsTransformer("EPSG:32649", want)
    rng = np.random.default_rng(8)
    with rasterio.open(small_dem) as src, rasterio.open(out) as dst:
        assert dst.crs is not None and CRS.from_wkt(dst.crs.to_wkt()).equals(want)
        # heights 100..107 m: in a US-foot grid they are US feet (328..353), and the raster says so
        assert dst.tags()["VERTICAL_UNITS"] == z_unit and dst.units == (z_unit,)
        assert dst.tags()["LINEAR_UNITS"] == z_unit
        assert json.loads(dst.tags()["COORDINATE_OPERATION_JSON"])["z_units"] == {"from": "metre", "to": z_unit}
        x = rng.uniform(500_005.0, 500_045.0, 200)
        y = rng.uniform(3_399_955.0, 3_399_995.0, 200)
        z = _bilinear(src, x, y)
        X, Y, Z = op.transform(x, y, z)
        assert np.allclose(Z, z / z_unit_m, atol=1e-3)  # same datum: only the unit changes
        got = _bilinear(dst, X, Y)
        assert np.max(np.abs(got - Z)) < 0.01


def test_warp_refuses_a_crs_geotiff_cannot_store(small_dem, tmp_path):
    # a 3D projected CRS (vertical axis in US feet): GDAL's GeoTIFF writer silently drops it
    out = tmp_path / "out" / "dem_lcc.tif"
    out.parent.mkdir()
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(small_dem), str(out), "--to",
                                         LCC_USFT_PROJ + " +vunits=us-ft"])
    assert r.exit_code == 2, r.output
    assert "cannot be stored in a GeoTIFF" in r.output and "--to" in r.output
    assert list(out.parent.iterdir()) == []  # no output, no temporary left


@pytest.mark.parametrize("res_m, cell_usft", [(0.3048006096, 1.0), (2.0, 2.0 * 3937 / 1200)])
def test_warp_cell_size_is_in_metres_and_a_foot_grid_gets_it_in_feet(small_dem, tmp_path, res_m, cell_usft):
    """Issue 40: --res-m is metres like every length option; a US-foot target grid gets the cell in US feet
    (0.3048006096 m is exactly 1 US survey foot, not 0.999999999996)."""
    out = tmp_path / "out.tif"
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(small_dem), str(out), "--to", LCC_USFT_PROJ,
                                         "--res-m", str(res_m)])
    assert r.exit_code == 0, r.output
    with rasterio.open(out) as dst:
        assert dst.res[0] == pytest.approx(cell_usft, rel=1e-9) and dst.res[0] == dst.res[1]
        assert dst.tags()["CELL_SIZE"] == f"{cell_usft:.10g} us-ft"


def test_warp_cell_size_options_follow_the_target_crs(small_dem, tmp_path):
    """A geographic target takes --res-deg and refuses --res-m (and the other way round), exit 2, nothing written."""
    out = tmp_path / "out.tif"
    cases = [(["--to", "EPSG:4326"], "--res-deg"), (["--to", "EPSG:4326", "--res-m", "1"], "--res-m"),
             (["--to", TMERC_PROJ, "--res-deg", "0.001"], "--res-deg")]
    for args, named in cases:
        r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(small_dem), str(out), *args])
        assert r.exit_code == 2 and named in r.output and "Traceback" not in r.output and not out.exists(), r.output
    r = CliRunner().invoke(aerotri_cli, ["crs", "warp", str(small_dem), str(out), "--to", "EPSG:4326",
                                         "--res-deg", "0.00002"])
    assert r.exit_code == 0, r.output
    with rasterio.open(out) as dst:
        assert dst.res == pytest.approx((0.00002, 0.00002)) and dst.tags()["CELL_SIZE"] == "2e-05 deg"


def test_warp_keeps_the_heights_along_the_rasters_edges(tmp_path):
    # a DEM valid to its edges (Autzen's 1 m DEM into UTM 10N): target cells whose centre fell in the outer half of
    # an edge cell were blended with a 0 beyond the edge, 110 cells 0-61 m low (62.7 m where 123.9 m was the lowest)
    from rasterio.transform import from_origin

    from aerotri.geom.crs.raster import warp_raster

    src = tmp_path / "flat.tif"
    with rasterio.open(src, "w", driver="GTiff", width=60, height=40, count=1, dtype="float32", crs="EPSG:32649",
                       transform=from_origin(799_003.3, 3_400_007.7, 1.0, 1.0), nodata=-9999.0) as ds:
        ds.write(np.full((40, 60), 125.0, np.float32), 1)
    warp_raster(src, tmp_path / "utm50.tif", "EPSG:32650")
    with rasterio.open(tmp_path / "utm50.tif") as ds:
        z = ds.read(1, masked=True)
    assert z.count() > 0.9 * 60 * 40
    assert z.min() == pytest.approx(125.0, abs=1e-3) and z.max() == pytest.approx(125.0, abs=1e-3)


def test_warp_says_when_heights_without_a_vertical_crs_move_with_the_datum(tmp_path, caplog):
    # AHN3's DEM (NAP heights, the file declares RD New only) into ETRS89 / UTM 31N: every height went up 43.6 m (taken
    # as heights on the Bessel ellipsoid) and nothing said so; with the vertical CRS declared they stay NAP heights
    from rasterio.transform import from_origin

    from aerotri.geom.crs.raster import warp_raster

    src = tmp_path / "nap.tif"
    with rasterio.open(src, "w", driver="GTiff", width=40, height=40, count=1, dtype="float32", crs="EPSG:28992",
                       transform=from_origin(84_800.0, 447_650.0, 1.0, 1.0), nodata=-9999.0) as ds:
        ds.write(np.full((40, 40), 1.5, np.float32), 1)
    with caplog.at_level("WARNING"):
        r = warp_raster(src, tmp_path / "utm.tif", "EPSG:25831")
    assert 42.0 < r.height_change_m[0] <= r.height_change_m[1] < 45.0
    said = [m for m in caplog.messages if "heights changed by +4" in m]
    assert len(said) == 1 and "declares no vertical CRS" in said[0] and "EPSG:28992+5709" in said[0]
    caplog.clear()
    with caplog.at_level("WARNING"):
        r = warp_raster(src, tmp_path / "utm_nap.tif", "EPSG:25831+5709", from_crs="EPSG:28992+5709")
    assert abs(r.height_change_m[0]) < 0.01 and abs(r.height_change_m[1]) < 0.01
    assert not [m for m in caplog.messages if "heights changed" in m]


def test_warp_of_a_flat_raster_changes_its_unit(tmp_path):
    """Review 48: a raster (or a 512-cell block: a hydro-flattened lake) of one height took the height change's slope
    k as 0, so NAVD88 100 m into NAVD88 (ft) came out 169.52 ft instead of 328.08."""
    from rasterio.transform import from_origin

    from aerotri.geom.crs.raster import warp_raster

    src = tmp_path / "flat.tif"
    with rasterio.open(src, "w", driver="GTiff", width=20, height=20, count=1, dtype="float32",
                       crs=rasterio.crs.CRS.from_wkt(CRS("EPSG:26910+5703").to_wkt()),
                       transform=from_origin(500_000.0, 5_000_000.0, 10.0, 10.0), nodata=-9999.0) as ds:
        ds.write(np.full((20, 20), 100.0, np.float32), 1)
    warp_raster(src, tmp_path / "ft.tif", "EPSG:26910+8228")
    with rasterio.open(tmp_path / "ft.tif") as ds:
        z = ds.read(1, masked=True)
    assert z.count() > 300 and np.allclose(z.compressed(), 100.0 / 0.3048006096012192, atol=1e-3)


def test_ortho_takes_a_height_model_on_the_projects_datum_only():
    """ortho's DEM in normal heights -> the project's h with a height model: a model recorded on h of the project's
    datum (WGS 84 for UTM 49N) converts; one recorded on Beijing 1954's h would put them on the wrong ellipsoid:
    refused, naming both datums."""
    from aerotri.core.errors import CrsError
    from ortho.dem import dem_height_operation

    plane = dict(model="plane", origin_m=(452250.0, 3407400.0), coefficients=[-12.0, 0.0, 0.0], crs="EPSG:32649")
    op = dem_height_operation("EPSG:32649+3855", "EPSG:32649", None, HeightAnomalyModel(**plane, h_crs="EPSG:4326"))
    assert op.transform([452250.0], [3407400.0], [100.0])[2][0] == pytest.approx(88.0, abs=1e-6)
    with pytest.raises(CrsError, match="heights of Beijing 1954 .* only on World Geodetic System 1984"):
        dem_height_operation("EPSG:32649+3855", "EPSG:32649", None, HeightAnomalyModel(**plane, h_crs="EPSG:4214"))


def test_a_dem_whose_vertical_datum_was_lost_is_refused_saying_so():
    """Trial 116: the NGI DEM ("Lo25 WGS84 + EGM2008 height") cut with Debian's gdal_translate 3.6 came back with
    VDATUM["unknown"] under the same name: ``ortho rectify`` refused it (exit 2) naming EGM2008 height on both sides.
    The error now says the vertical datum is missing and how to give it back; the file's own CRS passes."""
    from aerotri.core.errors import CrsError
    from ortho.dem import dem_height_operation

    project = CRS("EPSG:32735+3855")
    wkt = project.to_wkt("WKT2_2019")
    lost = CRS(wkt.replace('VDATUM["EGM2008 geoid"]', 'VDATUM["unknown"]').replace(',ID["EPSG",3855]]]', "]]"))
    assert lost.sub_crs_list[1].name == "EGM2008 height" and lost.sub_crs_list[1].datum.name == "unknown"
    with pytest.raises(CrsError) as e:
        dem_height_operation(lost, "EPSG:32735", CRS("EPSG:3855"))
    said = str(e.value)
    assert "its vertical CRS 'EGM2008 height' names no vertical datum (VDATUM unknown" in said
    assert "if they are EGM2008 height (EGM2008 geoid), as the name says, give the file its vertical datum" in said
    assert "--allow-ballpark" in said   # the ways out said before are still there
    assert dem_height_operation(project, "EPSG:32735", CRS("EPSG:3855")) is None


def test_warp_keeps_every_cell_whose_bilinear_taps_are_valid(tmp_path):
    """trial-lidar: the validity rule (the nearest source pixel's 3 x 3 all valid) took a ring of valid cells off every
    nodata edge: Autzen's DEM (feet) in UTM 10N metres 48,502 cells where GDAL's bilinear warp gives 49,900 (ours now
    49,203, all equal to GDAL's), and a warp that changes only the heights' unit on the source grid 1,633 of 48,502.
    Now a target cell is valid when every source pixel the bilinear interpolation weighs is."""
    from rasterio.transform import from_origin

    from aerotri.geom.crs.raster import warp_raster

    z = (120.0 + 0.1 * np.arange(60)[:, None] + 0.05 * np.arange(80)[None, :]).astype(np.float32)
    z[20:30, 30:45] = -9999.0  # a hole (a river without returns)
    src = tmp_path / "dem.tif"
    with rasterio.open(src, "w", driver="GTiff", width=80, height=60, count=1, dtype="float32", crs="EPSG:3740+5703",
                       transform=from_origin(494_116.0, 4_877_601.0, 1.0, 1.0), nodata=-9999.0) as ds:
        ds.write(z, 1)
    valid = z != -9999.0
    # the heights' unit alone (NAVD88 metres -> US survey feet) on the source grid: every valid cell stays
    warp_raster(src, tmp_path / "ftus.tif", "EPSG:3740+6360", res_m=1.0)
    with rasterio.open(tmp_path / "ftus.tif") as ds:
        got = ds.read(1, masked=True)
    assert np.array_equal(~np.ma.getmaskarray(got), valid)
    assert np.allclose(got.filled(0)[valid] * 0.3048006096, z[valid], atol=1e-4)
    # into a foot grid: the cells whose four bilinear taps are all valid (weight above 1e-3), at their bilinear value
    warp_raster(src, tmp_path / "lcc.tif", "EPSG:2994+6360", res_m=1.0)
    op = CrsTransformer("EPSG:2994", "EPSG:3740")
    with rasterio.open(tmp_path / "lcc.tif") as ds:
        got = ds.read(1, masked=True)
        rows, cols = np.indices(got.shape)
        x, y = ds.xy(rows.ravel(), cols.ravel())
    X, Y, _ = op.transform(np.asarray(x), np.asarray(y), np.zeros(rows.size))
    c, r = X - 494_116.0 - 0.5, 4_877_601.0 - Y - 0.5
    c0, r0 = np.floor(c).astype(int), np.floor(r).astype(int)
    fc, fr = c - c0, r - r0
    on = (c0 >= 0) & (r0 >= 0) & (c0 + 1 < 80) & (r0 + 1 < 60)
    taps = [(np.clip(r0 + dr, 0, 59), np.clip(c0 + dc, 0, 79), w) for dr, dc, w in
            ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)), (1, 1, fr * fc))]
    need = on & np.logical_and.reduce([valid[rr, cc] | (w <= 1e-3) for rr, cc, w in taps])
    ok = ~np.ma.getmaskarray(got).ravel()
    assert need.sum() > 3000 and ok[need].all()
    assert not ok[on & ~need].any()  # nodata never bleeds in
    zz = sum(w * np.where(valid, z, 0.0)[rr, cc] for rr, cc, w in taps) / sum(w * valid[rr, cc] for rr, cc, w in taps)
    assert np.allclose(got.filled(0).ravel()[need] * 0.3048006096, zz[need], atol=2e-3)


def test_a_dem_without_a_vertical_crs_given_with_a_height_model_is_in_normal_heights(caplog):
    """trial-site: `ortho rectify --dem DEM --heights zeta.json` dropped the model for a DEM that declares no vertical
    CRS (what `aerotri crs warp --heights` writes): the normal heights were taken as ellipsoidal, the DOM 5-14 m off
    under exit 0. The model given for the DEM now converts it; a DSM beside it (no model stated for it) is left."""
    from ortho.dem import dem_height_operation

    model = HeightAnomalyModel("plane", (452250.0, 3407400.0), coefficients=[-12.0, 0.0, 0.0], crs="EPSG:32649",
                               h_crs="EPSG:4326")
    op = dem_height_operation("EPSG:32649", "EPSG:32649", None, model, model_states_heights=True)
    assert op.transform([452250.0], [3407400.0], [100.0])[2][0] == pytest.approx(88.0, abs=1e-6)
    assert "taken as normal heights" in caplog.text
    assert dem_height_operation("EPSG:32649", "EPSG:32649", None, model) is None  # the DSM's call
    # a project in normal heights: the DEM is in them, the model unused, said
    assert dem_height_operation("EPSG:32649", "EPSG:32649", CRS("EPSG:3855"), model, model_states_heights=True) is None
    assert "the height model given is not used" in caplog.text
