"""Drainage against DEMs with known answers: a tilted plane (one direction, accumulation = cells upslope), a
Y of V-valleys (streams on the valley floors, Strahler 1 above the confluence and 2 below), a pit filled to its
spill height or breached through its rim, nodata respected; the command's files (COGs with the CRS, GeoPackage
layers, areas in m2 also for a DEM in feet) and bad input stopped with exit 2 and nothing written."""

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin

from lidarctl.terrain import drainage as dr
from lidarctl.cli.main import main


def _run(z, min_area_m2=None, method="fill", cell=1.0):
    cond = dr.condition(z, method)
    codes = dr.flow_directions(cond.dem, cell, cell)
    down, order, acc = dr.accumulate(codes, np.isfinite(z))
    net = None
    if min_area_m2 is not None:
        net = dr.stream_network(acc, down, order, transform=from_origin(0.0, z.shape[0] * cell, cell, cell),
                                cell_area_m2=cell * cell, min_area_m2=min_area_m2)
    return cond, codes, acc, net


def test_tilted_plane_flows_down_the_slope():
    r, c = np.mgrid[0:100, 0:100].astype(float)
    _, codes, acc, _ = _run(100.0 - 0.1 * c - 0.02 * r)  # down to the east (and a little south)
    assert np.all(codes[:, :-1] == 1)  # E: 0.1 per cell beats SE's 0.12 / sqrt(2)
    assert np.all(codes[:-1, -1] == 4)  # the east edge: its only lower neighbour is south
    assert np.array_equal(acc[:, :-1], c[:, :-1] + 1)  # every cell receives the row west of it
    assert np.array_equal(acc[:, -1], 100 * (r[:, -1] + 1))  # and the edge all rows north of it
    _, codes, acc, _ = _run(100.0 - 0.1 * c - 0.1 * r)  # down to the south-east: the diagonal is steepest
    assert np.all(codes[:-1, :-1] == 2) and np.all(codes[-1, :-1] == 1) and np.all(codes[:-1, -1] == 4)
    assert acc[-1, -1] == acc.size and np.array_equal(np.diag(acc)[:-1], np.arange(1, 100))


def _y_valleys(n=100):
    """A Y of V-valleys (side slopes 0.5, floor falling 0.05 per cell to the south): two branches from 10 cells
    inside the north edge meeting at the centre, one valley from there to the south edge."""
    r, c = np.mgrid[0:n, 0:n].astype(float)
    mid = n / 2

    def dist_seg(x0, y0, x1, y1):
        t = np.clip(((c - x0) * (x1 - x0) + (r - y0) * (y1 - y0)) / ((x1 - x0) ** 2 + (y1 - y0) ** 2), 0, 1)
        return np.hypot(c - x0 - t * (x1 - x0), r - y0 - t * (y1 - y0))

    d = np.minimum.reduce([dist_seg(20, 10, mid, mid), dist_seg(n - 20, 10, mid, mid), dist_seg(mid, mid, mid, n)])
    return 100.0 + 0.5 * d + 0.05 * (n - r), d


def test_y_valleys_streams_and_strahler():
    z, d = _y_valleys()
    _, codes, acc, net = _run(z, min_area_m2=300.0)
    assert acc[-1, 50] == z.size  # everything drains out at the south end of the valley
    assert np.all(d[net.strahler > 0] <= 1.5)  # streams on the valley floors
    assert net.order.max() == 2
    rows = np.nonzero(net.strahler == 2)[0]
    assert rows.min() >= 48 and rows.max() == 99  # order 2 from the confluence down
    assert np.all(np.nonzero(net.strahler == 1)[0] <= 52)
    assert (net.order == 1).sum() == 2 and (net.downstream >= 0).sum() == 2  # two branches into the stem
    stem = np.flatnonzero(net.order == 2)
    assert net.upstream_area_m2[stem].max() == z.size
    assert np.allclose(net.length_m[stem].sum(), 99 - rows.min(), atol=1.5)  # a straight line after simplifying
    # watersheds: the segments' cells add up to the one basin, which is the whole raster
    assert (net.subcatchment >= 0).all() and (net.basin == net.outlet[stem[-1]]).all()


@pytest.mark.parametrize("method", ["fill", "breach"])
def test_pit_filled_or_breached(method):
    z, _ = _y_valleys()
    pit = np.zeros(z.shape, bool)
    pit[70:75, 45:56] = True
    zp = np.where(pit, z - 4.0, z)
    cond, codes, acc, _ = _run(zp, method=method)
    assert acc[-1, 50] == z.size  # the pit drains: nothing ends inside
    if method == "fill":
        spill = z[75:, 50].max()  # the valley floor just below the pit
        assert np.allclose(cond.dem[pit & (zp < spill)], spill, atol=1e-9)
        assert cond.raised_max == pytest.approx(spill - zp[pit].min(), abs=1e-9) and cond.lowered_max == 0
        assert np.all(cond.dem >= zp)
    else:
        assert np.array_equal(cond.dem[pit], zp[pit]) or np.abs(cond.dem[pit] - zp[pit]).max() < 1e-9
        assert np.all(cond.dem <= zp + 1e-9) and cond.lowered_max > 0
        assert np.abs(cond.dem - zp).max() <= 4.0 + 1e-9


def test_nodata_is_an_outlet_and_stays_nodata():
    r, c = np.mgrid[0:60, 0:60].astype(float)
    z = 100.0 + np.hypot(r - 30, c - 30) * 0.1  # a bowl, the centre missing
    z[28:33, 28:33] = np.nan
    cond, codes, acc, _ = _run(z)
    assert np.all(codes[28:33, 28:33] == 0) and np.isnan(acc[28:33, 28:33]).all()
    assert cond.cells_changed == 0  # draining into the hole, nothing to fill
    # everything leaves through the ring around the hole
    down = dr.accumulate(codes, np.isfinite(z))[0]
    ring = np.zeros(z.shape, bool)
    ring[27:34, 27:34] = True
    ring[28:33, 28:33] = False
    outlets = (down < 0).reshape(z.shape) & np.isfinite(z)
    assert np.all(ring[outlets]) and acc[outlets].sum() == np.isfinite(z).sum()


def _write(path, z, crs, cell):
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs=crs, transform=from_origin(1000.0, 5000.0, cell, cell), nodata=-9999.0) as d:
        d.write(np.where(np.isfinite(z), z, -9999.0).astype("float32"), 1)


def test_command_files_and_feet(tmp_path):
    from pyogrio import list_layers, read_info
    from pyogrio.raw import read

    z, _ = _y_valleys()
    z[:5, :5] = np.nan
    ft = 1200.0 / 3937.0
    seg = {}
    for name, crs, unit in (("m", "EPSG:32633", 1.0), ("ft", "EPSG:2992", 0.3048)):
        # the same terrain in feet: cells of 2 m = 6.56 ft, heights in feet
        _write(tmp_path / f"dem_{name}.tif", z / unit, crs, 2.0 / unit)
        out = tmp_path / f"out_{name}"
        r = CliRunner().invoke(main, ["drainage", str(tmp_path / f"dem_{name}.tif"), str(out), "--min-area-m2", "1200"])
        assert r.exit_code == 0, r.output
        assert sorted(p.name for p in out.iterdir()) == sorted(dr.FILES)
        with rasterio.open(out / "flowdir.tif") as f:
            assert f.crs.to_epsg() == int(crs.split(":")[1]) and f.nodata == 255
            assert f.read(1)[0, 0] == 255 and set(np.unique(f.read(1))) <= {1, 2, 4, 8, 16, 32, 64, 128, 255}
        with rasterio.open(out / "accum_m2.tif") as f:
            assert f.read(1).max() == pytest.approx(np.isfinite(z).sum() * 4.0, rel=1e-6)
        assert {name for name, _ in list_layers(out / "drainage.gpkg")} == {"streams", "watersheds", "basins"}
        assert read_info(out / "drainage.gpkg", layer="streams")["crs"].endswith(crs.split(":")[1])
        meta, _, _, fields = read(out / "drainage.gpkg", layer="streams")
        f = dict(zip(meta["fields"], fields))
        seg[name] = (np.sort(f["strahler_order"]), np.sort(f["length_m"]))
        meta, _, _, fields = read(out / "drainage.gpkg", layer="basins")
        assert dict(zip(meta["fields"], fields))["area_m2"].sum() == pytest.approx(np.isfinite(z).sum() * 4.0)
    assert np.array_equal(seg["m"][0], seg["ft"][0]) and np.allclose(seg["m"][1], seg["ft"][1], rtol=1e-6)
    assert ft  # US survey feet are not used here: EPSG:2992 is in international feet


def test_bad_input_exit_2_nothing_written(tmp_path):
    (tmp_path / "bad.tif").write_text("no raster")
    r = CliRunner().invoke(main, ["drainage", str(tmp_path / "bad.tif"), str(tmp_path / "o1")])
    assert r.exit_code == 2 and "bad.tif" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "o1").exists()
    z, _ = _y_valleys(30)
    _write(tmp_path / "dem.tif", z, "EPSG:32633", 1.0)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("keep")
    r = CliRunner().invoke(main, ["drainage", str(tmp_path / "dem.tif"), str(tmp_path / "busy")])
    assert r.exit_code == 2 and "OUTDIR" in r.output and [p.name for p in (tmp_path / "busy").iterdir()] == ["notes.txt"]
    r = CliRunner().invoke(main, ["drainage", str(tmp_path / "dem.tif"), str(tmp_path / "o2"), "--min-area-m2", "-5"])
    assert r.exit_code == 2 and "--min-area-m2" in r.output and not (tmp_path / "o2").exists()
    r = CliRunner().invoke(main, ["drainage", str(tmp_path / "dem.tif"), str(tmp_path)])
    assert r.exit_code == 2 and "OUTDIR" in r.output and (tmp_path / "dem.tif").exists()


def test_default_threshold_from_the_dem_finds_a_known_channel(tmp_path):
    """At its defaults the command finds the Y of valleys (the old fixed 1 ha found none on this 1 ha DEM)
    and only there; the threshold is 2 x the longer side in cells x the cell area, printed with its rule;
    the same terrain in feet gives the same threshold in m2."""
    from pyogrio.raw import read

    z, d = _y_valleys()  # 100 x 100 cells of 1 m: 1 ha
    for name, crs, unit in (("m", "EPSG:32633", 1.0), ("ft", "EPSG:2992", 0.3048)):
        _write(tmp_path / f"y_{name}.tif", z / unit, crs, 1.0 / unit)
        r = CliRunner().invoke(main, ["drainage", str(tmp_path / f"y_{name}.tif"), str(tmp_path / f"o_{name}")])
        assert r.exit_code == 0, r.output
        assert "stream threshold 200.0 m2 (from the DEM: 2 x the longer side of its valid data (100 cells)" in r.output
        with rasterio.open(tmp_path / f"o_{name}" / "strahler.tif") as f:
            s = f.read(1)
        on = (s > 0) & (s < 255)
        assert on.sum() > 80 and np.all(d[on] <= 1.5)  # streams on the valley floors only
        assert on[-1, 50] and on[10:40].any(axis=1).sum() >= 25  # the trunk at the outlet; both branches' reaches
        meta, _, _, fields = read(tmp_path / f"o_{name}" / "drainage.gpkg", layer="streams")
        # branches meeting make the trunk of a higher order (here the heads' two sides meet first: order 3)
        assert dict(zip(meta["fields"], fields))["strahler_order"].max() >= 2
        assert "0 streams" not in r.output


def test_zero_streams_say_why_and_what_to_change(tmp_path):
    """A plane has no channel: 0 streams at the default, with the largest upstream area, where, and a
    threshold that traces flow lines; a given threshold above every catchment says the same."""
    import json

    r_, c_ = np.mgrid[0:80, 0:120].astype(float)
    _write(tmp_path / "plane.tif", 50.0 - 0.05 * c_ + 0.0 * r_, "EPSG:32633", 1.0)  # down to the east edge
    r = CliRunner().invoke(main, ["drainage", str(tmp_path / "plane.tif"), str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert "0 stream segments" in r.output and "0 streams: no cell collects the 240 m2 threshold" in r.output
    assert "largest upstream area" in r.output and "--min-area-m2 below" in r.output
    summary = json.loads((tmp_path / "o" / "drainage.json").read_text())
    assert summary["min_area_m2"] == 240.0 and summary["no_streams"].startswith("0 streams")
    top = float(summary["no_streams"].split("largest upstream area is ")[1].split(" m2")[0].replace(",", ""))
    assert top == 120.0  # on a plane no cell collects more than its flow path across the DEM (a row)
    z, _ = _y_valleys()
    _write(tmp_path / "y.tif", z, "EPSG:32633", 1.0)
    r = CliRunner().invoke(main, ["drainage", str(tmp_path / "y.tif"), str(tmp_path / "o2"), "--min-area-m2", "20000"])
    assert r.exit_code == 0 and "0 streams" in r.output and "largest upstream area is 10,000 m2" in r.output
    assert "(given (--min-area-m2))" in r.output


def _drawn_hillshade(monkeypatch):
    """The arrays the map draws with imshow (the hillshade), recorded."""
    from matplotlib.axes import Axes

    drawn, imshow = [], Axes.imshow
    monkeypatch.setattr(Axes, "imshow", lambda ax, a, *args, **kw: (drawn.append(np.asarray(a)), imshow(ax, a, *args, **kw))[1])
    return drawn


def test_map_shades_every_valid_cell_up_to_a_hole(tmp_path, monkeypatch):
    """A tilted plane with a nodata hole: the drainage map's hillshade covers every valid cell (the map no longer
    trims a cell along nodata) in one grey (no rim: slopes from valid cells only)."""
    r, c = np.mgrid[0:60, 0:60].astype(float)
    z = 100.0 - 0.1 * c - 0.02 * r
    z[25:35, 20:40] = np.nan
    _write(tmp_path / "dem.tif", z, "EPSG:32633", 2.0)
    drawn = _drawn_hillshade(monkeypatch)
    r = CliRunner().invoke(main, ["drainage", str(tmp_path / "dem.tif"), str(tmp_path / "o"), "--min-area-m2", "400"])
    assert r.exit_code == 0, r.output
    (hs,) = drawn
    assert np.array_equal(np.isfinite(hs), np.isfinite(z))
    assert np.ptp(hs[np.isfinite(hs)]) < 1e-4  # float32 heights; a grey level is 1/256


def test_map_axes_name_the_crs_unit(tmp_path, monkeypatch):
    # Autzen's DEM in feet: the drainage and contour maps said "easting" / "northing" with coordinates in feet
    from lidarctl.terrain import contours as ct

    labels = []

    def keep(fig, path, **kw):
        labels.append((fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()))

    monkeypatch.setattr(dr, "save_png", keep)
    monkeypatch.setattr(ct, "save_png", keep)
    z, _ = _y_valleys()
    for name, crs, unit in (("m", "EPSG:32633", 1.0), ("ft", "EPSG:2992", 0.3048)):
        _write(tmp_path / f"dem_{name}.tif", z / unit, crs, 2.0 / unit)
        r = CliRunner().invoke(main, ["drainage", str(tmp_path / f"dem_{name}.tif"), str(tmp_path / f"o_{name}"),
                                      "--min-area-m2", "1200"])
        assert r.exit_code == 0, r.output
        r = CliRunner().invoke(main, ["contours", str(tmp_path / f"dem_{name}.tif"), str(tmp_path / f"c_{name}.gpkg"),
                                      "--interval-m", "1"])
        assert r.exit_code == 0, r.output
    assert labels == [("easting (m)", "northing (m)")] * 2 + [("easting (ft)", "northing (ft)")] * 2


def test_heights_above_the_ground_are_refused(tmp_path):
    """Trial s94: `lidarctl drainage chm.tif` traced streams over the crowns (exit 0); rasters' chm.tif and ndsm.tif
    say by their band description that they hold heights above the ground: refused, nothing written."""
    z, _ = _y_valleys()
    for name, desc in (("chm", "CHM: highest vegetation above the DEM (metre)"), ("ndsm", "nDSM: DSM - DEM (metre)")):
        path = tmp_path / f"{name}.tif"
        _write(path, z, "EPSG:32633", 2.0)
        with rasterio.open(path, "r+") as d:
            d.set_band_description(1, desc)
        r = CliRunner().invoke(main, ["drainage", str(path), str(tmp_path / f"out_{name}")])
        assert r.exit_code == 2 and "heights above the ground" in r.output and str(path) in r.output
        assert not (tmp_path / f"out_{name}").exists()
    path = tmp_path / "dem.tif"  # a DEM whose description says so is not
    _write(path, z, "EPSG:32633", 2.0)
    with rasterio.open(path, "r+") as d:
        d.set_band_description(1, "DEM: mean height of ground and water points (metre)")
    assert CliRunner().invoke(main, ["drainage", str(path), str(tmp_path / "out_dem")]).exit_code == 0


def test_streams_end_at_the_shores_of_the_water_given(tmp_path):
    """Trial s96 F10: on a hydro-flattened DEM the streams crossed every lake as straight lines of the fill's epsilon
    gradient. With --water the streams end at the water polygons' shores and their courses through the water go to a
    layer of their own (the network's topology kept): no stream part inside the water, the lengths add up."""
    import shapely
    from pyogrio.raw import read, write

    z, _ = _y_valleys()
    z[55:75, 35:65] = np.nanmin(z[55:75, 35:65])   # a flat lake across the southern valley
    _write(tmp_path / "dem.tif", z, "EPSG:32633", 2.0)
    x0, y0, cell = 1000.0, 5000.0, 2.0
    lake = shapely.box(x0 + 35 * cell, y0 - 75 * cell, x0 + 65 * cell, y0 - 55 * cell)
    write(tmp_path / "map.gpkg", np.array([shapely.to_wkb(lake)], dtype=object), layer="water", driver="GPKG",
          geometry_type="Polygon", crs="EPSG:32633", fields=["water_z"], field_data=[np.array([float(z[60, 50])])])
    plain, cut = tmp_path / "plain", tmp_path / "cut"
    for out, extra in ((plain, []), (cut, ["--water", str(tmp_path / "map.gpkg")])):
        r = CliRunner().invoke(main, ["drainage", str(tmp_path / "dem.tif"), str(out), "--min-area-m2", "1200", *extra])
        assert r.exit_code == 0, r.output
    assert "cut at the water's shores" in r.output and "layer through_water" in r.output

    def lines(path, layer):
        _, _, wkb, fields = read(path / "drainage.gpkg", layer=layer)
        return [shapely.from_wkb(b) for b in wkb], fields

    before, _ = lines(plain, "streams")
    streams, _ = lines(cut, "streams")
    wet, _ = lines(cut, "through_water")
    assert sum(g.intersection(lake).length for g in before) > 20 * cell       # the plain network crosses the lake
    assert sum(g.intersection(lake.buffer(-1e-6)).length for g in streams) == pytest.approx(0.0, abs=1e-6)
    assert wet and all(lake.buffer(1e-6).contains(g) for g in wet)
    total = sum(g.length for g in before)
    assert sum(g.length for g in streams) + sum(g.length for g in wet) == pytest.approx(total, rel=1e-9)
