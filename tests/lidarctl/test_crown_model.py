"""Tree crowns fitted to their returns (``lidarctl.rasters.crown_model``), on constructed crowns."""

import numpy as np
import pytest

from lidarctl.rasters.crown_model import crown_sub_cells, fit_crowns


def _scene(seed, spacing=0.75, trees=((10.0, 10.0, 3.0, 12.0), (30.3, 12.2, 2.2, 8.0)), gap_share=0.15, size=42.0):
    """First returns on a jittered grid over spheroid crowns (x, y, radius, top) and flat ground at 0; a
    ``gap_share`` of the pulses into a crown reach the ground (its first return there); one interior return per
    crown pulse at half the crown's depth, and one stray low-vegetation return on open ground."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, size, spacing)
    x, y = np.meshgrid(g, g)
    x = (x + rng.uniform(-0.3, 0.3, x.shape) * spacing).ravel()
    y = (y + rng.uniform(-0.3, 0.3, y.shape) * spacing).ravel()
    z = np.zeros_like(x)
    cls = np.full(len(x), 2, np.uint8)
    extra = []
    for cx, cy, a, top in trees:
        q = 1 - ((x - cx) ** 2 + (y - cy) ** 2) / a ** 2
        hit = (q > 0) & (rng.uniform(size=len(x)) >= gap_share)
        c = a  # vertical semi-axis
        z[hit] = top - c + c * np.sqrt(q[hit])
        cls[hit] = 5
        extra.append((x[hit], y[hit], top - c - 0.5 * c * np.sqrt(q[hit])))
    rn = np.ones(len(x), np.uint8)
    ix = np.concatenate([e[0] for e in extra])
    iy = np.concatenate([e[1] for e in extra])
    iz = np.concatenate([e[2] for e in extra])
    x, y, z = np.concatenate([x, ix, [25.0]]), np.concatenate([y, iy, [30.0]]), np.concatenate([z, iz, [0.4]])
    cls = np.concatenate([cls, np.full(len(ix), 5, np.uint8), [3]])
    rn = np.concatenate([rn, np.full(len(ix), 2, np.uint8), [1]])
    return x, y, z, cls, rn


def test_round_crowns_are_fitted_within_0_4_of_the_spacing():
    for seed in (1, 2, 3):
        crowns = fit_crowns(*_scene(seed))
        assert len(crowns) == 2  # the stray return is no tree
        order = np.argsort(crowns.x_m)
        assert np.all(crowns.circle_fit)
        np.testing.assert_allclose(crowns.x_m[order], [10.0, 30.3], atol=0.3)
        np.testing.assert_allclose(crowns.y_m[order], [10.0, 12.2], atol=0.3)
        np.testing.assert_allclose(crowns.radius_m[order], [3.0, 2.2], atol=0.3)
        np.testing.assert_allclose(crowns.top_m[order], [12.0, 8.0], atol=0.05)
        # the lowest return inside the crown: half way down, above the true base (top - 2 x radius)
        assert np.all(crowns.base_m[order] > np.array([12.0 - 6.0, 8.0 - 4.4]))
        assert np.all(crowns.base_m[order] < np.array([12.0 - 3.0, 8.0 - 2.2]))


def test_sub_cells_follow_the_fitted_disk():
    crowns = fit_crowns(*_scene(4))
    rows, cols, margin_cm, base, top = crown_sub_cells(crowns, x0_m=0.0, y_top_m=42.0, res_m=0.5, shape=(84, 84),
                                                       sub=5)
    inside = margin_cm >= 0
    area = inside.sum() * 0.1 * 0.1
    fitted = np.pi * (crowns.radius_m ** 2).sum()   # the disks apart: their sub-cells' area is theirs
    assert abs(area - fitted) < 0.02 * fitted
    covered = inside.any(axis=(1, 2))
    assert np.all(np.isfinite(base[covered])) and np.all(np.isnan(base[~covered]))
    # a cell whose centre lies 2 m from the first crown's centre is inside at all its sub-cells
    k = np.flatnonzero((rows == int((42.0 - 10.0) / 0.5)) & (cols == int((10.0 + 2.0) / 0.5)))
    assert inside[k].all()


def _nearest_dsm(x, y, z, cls, rn, res=0.5, n=84):
    """The first return nearest each cell centre (the nearest-return DSM of ``lidarctl.rasters.nearest``)."""
    from scipy.spatial import cKDTree

    first = rn == 1
    c = (np.arange(n) + 0.5) * res
    X, Y = np.meshgrid(c, n * res - c)
    _, j = cKDTree(np.column_stack([x[first], y[first]])).query(np.column_stack([X.ravel(), Y.ravel()]))
    return z[first][j].reshape(n, n).astype(np.float32), cls[first][j].reshape(n, n)


def test_the_surface_closes_the_crowns_gaps_and_drops_the_crown_beyond_the_disks():
    from lidarctl.rasters.crown_model import crown_surface

    import dataclasses

    pts = _scene(5)
    crowns = fit_crowns(*pts)
    # disks half a metre narrower than the fit: the returns' crown spills beyond them
    crowns = dataclasses.replace(crowns, radius_m=crowns.radius_m - 0.5)
    dsm, near_cls = _nearest_dsm(*pts)
    out = crown_surface(crowns, *pts, dsm, x0_m=0.0, y_top_m=42.0, res_m=0.5)
    c = (np.arange(84) + 0.5) * 0.5
    X, Y = np.meshgrid(c, 42.0 - c)
    inner = np.hypot(X - 10.0, Y - 10.0) < 2.0   # well within the first crown (3 m; its disk about 2.5 m)
    assert (dsm[inner] < 1.0).any() and (out[inner] > 9.0).all()  # its gaps (ground returns) stand at the crown
    beyond = ~(np.hypot(X[:, :, None] - crowns.x_m, Y[:, :, None] - crowns.y_m) < crowns.radius_m + 0.36).any(-1)
    spill = beyond & (near_cls == 5)
    assert spill.any() and (out[spill] == 0.0).all()  # the nearest-return crown beyond the disks: the ground
    assert (out[beyond & ~spill] == dsm[beyond & ~spill]).all()  # the rest beyond them as it was


@pytest.mark.parametrize(("epsg", "unit_m"), [(32611, 1.0), (2263, 0.30480060960121924)])
def test_write_crown_model_round_trip(tmp_path, epsg, unit_m):
    """The files in the CRS's units (metres; US survey feet: the fit in metres all the same)."""
    import laspy
    import rasterio
    from pyproj import CRS
    from rasterio.transform import from_origin

    from lidarctl.rasters.crown_model import write_crown_model
    from ortho.crown_cells import read_crowns

    x, y, z, cls, rn = _scene(6)
    x0, y0 = 500000.0, 4000000.0
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = [0.001] * 3, [x0, y0, 0.0]
    header.add_crs(CRS.from_epsg(epsg))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x / unit_m + x0, y / unit_m + y0, z / unit_m
    las.classification, las.return_number, las.number_of_returns = cls, rn, np.where(rn == 1, 1, 2)
    las.write(tmp_path / "strip.las")
    dsm, _ = _nearest_dsm(x, y, z, cls, rn)
    tf = from_origin(x0, y0 + 42.0 / unit_m, 0.5 / unit_m, 0.5 / unit_m)
    with rasterio.open(tmp_path / "dsm_nearest.tif", "w", driver="GTiff", width=84, height=84, count=1,
                       dtype="float32", crs=f"EPSG:{epsg}", transform=tf) as ds:
        ds.write(dsm / unit_m, 1)
    gpkg, tif = write_crown_model([tmp_path / "strip.las"], tmp_path / "dsm_nearest.tif", tmp_path)
    crowns = read_crowns(gpkg, CRS.from_epsg(epsg))
    order = np.argsort(crowns.x_m)
    np.testing.assert_allclose((crowns.x_m[order] - x0) * unit_m, [10.0, 30.3], atol=0.3)
    np.testing.assert_allclose(crowns.radius_m[order] * unit_m, [3.0, 2.2], atol=0.3)
    np.testing.assert_allclose(crowns.top_m[order] * unit_m, [12.0, 8.0], atol=0.05)
    with rasterio.open(tif) as ds:
        assert ds.shape == (84, 84) and ds.transform == tf
        assert abs(float(ds.read(1).max()) * unit_m - 12.0) < 0.05


def _write_strip(path, x, y, z, cls, rn, x0, y0, epsg=32611):
    import laspy
    from pyproj import CRS

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = [0.001] * 3, [x0, y0, 0.0]
    header.add_crs(CRS.from_epsg(epsg))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x + x0, y + y0, z
    las.classification, las.return_number, las.number_of_returns = cls, rn, np.where(rn == 1, 1, 2)
    las.write(path)


def test_tiled_crowns_equal_the_untiled_ones_with_trees_across_the_tile_edges(tmp_path):
    """A 126 m block of 150 crowns (radius 1.5-3.5 m on a jittered 10 m lattice) cut into 5 x 5 tiles of 25 m:
    the crowns across the tiles' edges are fitted from all their returns once, the files equal those of one tile
    (the whole block in memory) and ``fit_crowns`` of all the returns."""
    import rasterio
    from pyogrio import raw
    from rasterio.transform import from_origin

    from lidarctl.rasters.crown_model import SEGMENT_RES_M, write_crown_model_run

    rng = np.random.default_rng(11)
    size = 126.0
    lattice = np.arange(5.0, size - 4.0, 10.0)
    trees = [(cx + rng.uniform(-2, 2), cy + rng.uniform(-2, 2), rng.uniform(1.5, 3.5), rng.uniform(6.0, 18.0))
             for cx in lattice for cy in lattice][:150]
    x, y, z, cls, rn = _scene(12, trees=tuple(trees), size=size)
    x0, y0 = 500000.0, 4000000.0
    _write_strip(tmp_path / "strip.las", x, y, z, cls, rn, x0, y0)
    n = int(size / 0.5)
    dsm, _ = _nearest_dsm(x, y, z, cls, rn, n=n)
    tf = from_origin(x0, y0 + size, 0.5, 0.5)
    with rasterio.open(tmp_path / "dsm_nearest.tif", "w", driver="GTiff", width=n, height=n, count=1,
                       dtype="float32", crs="EPSG:32611", transform=tf) as ds:
        ds.write(dsm, 1)
    runs, out = {}, {}
    for name, tile_m in (("tiled", 25.0), ("whole", None)):
        runs[name] = write_crown_model_run([tmp_path / "strip.las"], tmp_path / "dsm_nearest.tif",
                                           tmp_path / name, tile_m=tile_m)
        meta, _, geoms, fields = raw.read(runs[name].crowns_path)
        with rasterio.open(runs[name].surface_path) as ds:
            out[name] = dict(zip(meta["fields"], fields)), list(geoms), ds.read(1)
    assert runs["tiled"].tiles >= 25 and runs["whole"].tiles <= 4  # (the whole: its tile and the halo's neighbours)
    assert runs["tiled"].cells_beyond_halo == 0 and runs["tiled"].max_tile_returns < 0.7 * len(x)
    (ft, gt, st), (fw, gw, sw) = out["tiled"], out["whole"]
    assert len(ft["x_m"]) == len(fw["x_m"]) >= 140
    for k in fw:
        np.testing.assert_array_equal(ft[k], fw[k], err_msg=k)
    assert gt == gw and np.array_equal(st, sw)
    # the crowns across a tile edge (the tiles of 50 cells of the segmentation grid from the vegetation's corner)
    veg_first = (rn == 1) & np.isin(cls, (3, 4, 5))
    gx0, gy_top = x[veg_first].min() + x0 - SEGMENT_RES_M, y[veg_first].max() + y0 + SEGMENT_RES_M
    cx, cy, r = fw["x_m"], fw["y_m"], fw["radius_m"]
    across = ((np.floor((cx - r - gx0) / 25.0) != np.floor((cx + r - gx0) / 25.0))
              | (np.floor((gy_top - cy - r) / 25.0) != np.floor((gy_top - cy + r) / 25.0)))
    assert across.sum() >= 30
    import laspy

    las = laspy.read(tmp_path / "strip.las")  # the in-memory fit of every return, as stored (mm)
    crowns = fit_crowns(np.asarray(las.x), np.asarray(las.y), np.asarray(las.z), np.asarray(las.classification),
                        np.asarray(las.return_number))
    np.testing.assert_array_equal(np.sort(crowns.x_m), np.sort(fw["x_m"]))
    np.testing.assert_array_equal(np.sort(crowns.radius_m), np.sort(fw["radius_m"]))


def test_lidarctl_crowns_refuses_a_missing_nearest_return_dsm(tmp_path):
    from click.testing import CliRunner

    from lidarctl.cli.main import main

    (tmp_path / "strip.las").write_bytes(b"")
    r = CliRunner().invoke(main, ["crowns", str(tmp_path / "strip.las"), str(tmp_path / "out")])
    assert r.exit_code == 2 and "dsm_nearest.tif: nearest-return DSM not found" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "out").exists()


def test_the_tile_files_are_refused_before_they_fill_the_disk(tmp_path, monkeypatch):
    """The tile files (each return once, and again in each halo it lies in) are checked against the free disk before
    any is written: a ResourceError naming --tile-m, no output and no tile folder left."""
    import collections
    import shutil

    import rasterio
    from rasterio.transform import from_origin

    from aerotri.core.errors import ResourceError
    from lidarctl.rasters.crown_model import write_crown_model_run

    x, y, z, cls, rn = _scene(6)
    x0, y0 = 500000.0, 4000000.0
    _write_strip(tmp_path / "strip.las", x, y, z, cls, rn, x0, y0)
    dsm, _ = _nearest_dsm(x, y, z, cls, rn)
    with rasterio.open(tmp_path / "dsm_nearest.tif", "w", driver="GTiff", width=84, height=84, count=1,
                       dtype="float32", crs="EPSG:32611", transform=from_origin(x0, y0 + 42.0, 0.5, 0.5)) as ds:
        ds.write(dsm, 1)
    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9 - 1000, 1000))
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(ResourceError, match="tile files") as e:
        write_crown_model_run([tmp_path / "strip.las"], tmp_path / "dsm_nearest.tif", out, tile_m=25.0)
    assert e.value.param == "--tile-m"
    assert list(out.iterdir()) == []


def test_crown_heights_in_the_clouds_height_unit_beside_metre_lengths(tmp_path):
    """UTM in metres with NAVD88 heights in US survey feet (a common US delivery): the crowns' tops and the surface in
    feet, as the DSM beside them; the same crowns as the all-metre block, scaled."""
    import laspy
    import rasterio
    from pyproj import CRS
    from rasterio.transform import from_origin

    from lidarctl.rasters.crown_model import write_crown_model
    from ortho.crown_cells import read_crowns

    ft = 0.30480060960121924
    x, y, z, cls, rn = _scene(6)
    x0, y0 = 500000.0, 4000000.0
    dsm, _ = _nearest_dsm(x, y, z, cls, rn)
    out = {}
    for name, crs_text, zunit in (("m", "EPSG:32611+5703", 1.0), ("ft", "EPSG:32611+6360", ft)):
        d = tmp_path / name
        d.mkdir()
        crs = CRS.from_user_input(crs_text)
        header = laspy.LasHeader(point_format=6, version="1.4")
        header.scales, header.offsets = [0.001] * 3, [x0, y0, 0.0]
        header.add_crs(crs)
        las = laspy.LasData(header)
        las.x, las.y, las.z = x + x0, y + y0, z / zunit
        las.classification, las.return_number, las.number_of_returns = cls, rn, np.where(rn == 1, 1, 2)
        las.write(d / "strip.las")
        with rasterio.open(d / "dsm_nearest.tif", "w", driver="GTiff", width=84, height=84, count=1, dtype="float32",
                           crs=rasterio.crs.CRS.from_wkt(crs.to_wkt()), transform=from_origin(x0, y0 + 42.0, 0.5, 0.5)
                           ) as ds:
            ds.write(dsm / zunit, 1)
        gpkg, tif = write_crown_model([d / "strip.las"], d / "dsm_nearest.tif", d)
        with rasterio.open(tif) as ds:
            out[name] = read_crowns(gpkg, crs), ds.read(1, masked=True).filled(np.nan)
    (cm, sm), (cf, sf) = out["m"], out["ft"]
    np.testing.assert_allclose(np.sort(cf.top_m) * ft, np.sort(cm.top_m), atol=0.01)
    np.testing.assert_allclose(np.sort(cf.base_m) * ft, np.sort(cm.base_m), atol=0.01)
    np.testing.assert_allclose(np.sort(cf.radius_m), np.sort(cm.radius_m), atol=0.01)
    np.testing.assert_allclose(sf * ft, sm, atol=0.01)


@pytest.mark.parametrize(("crs_text", "xy_unit", "z_unit", "noted"), [
    ("EPSG:32611", 1.0, 1.0, False), ("EPSG:2263", 0.30480060960121924, 0.30480060960121924, True),
    ("EPSG:32611+6360", 1.0, 0.30480060960121924, True)])
def test_crowns_file_fields_hold_metres(tmp_path, crs_text, xy_unit, z_unit, noted):
    """The _m fields of crowns.gpkg in metres whatever the CRS's units (a cloud in feet held feet there: Autzen's
    radius_m 24.17 for a 7.4 m crown); the polygons in the CRS's units; a CRS not all in metres notes it in the
    layer's description (the metre file's bytes as before: the mark alone)."""
    import laspy
    import pyogrio
    import rasterio
    import shapely
    from pyproj import CRS
    from rasterio.transform import from_origin

    from aerotri.core.vector_files import MARK
    from aerotri.geom.crown_disks import CROWNS_IN_METRES_NOTE
    from lidarctl.rasters.crown_model import write_crown_model

    x, y, z, cls, rn = _scene(6)
    x0, y0 = 500000.0, 4000000.0
    crs = CRS.from_user_input(crs_text)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = [0.001] * 3, [x0, y0, 0.0]
    header.add_crs(crs)
    las = laspy.LasData(header)
    las.x, las.y, las.z = x / xy_unit + x0, y / xy_unit + y0, z / z_unit
    las.classification, las.return_number, las.number_of_returns = cls, rn, np.where(rn == 1, 1, 2)
    las.write(tmp_path / "strip.las")
    dsm, _ = _nearest_dsm(x, y, z, cls, rn)
    with rasterio.open(tmp_path / "dsm_nearest.tif", "w", driver="GTiff", width=84, height=84, count=1,
                       dtype="float32", crs=rasterio.crs.CRS.from_wkt(crs.to_wkt()),
                       transform=from_origin(x0, y0 + 42.0 / xy_unit, 0.5 / xy_unit, 0.5 / xy_unit)) as ds:
        ds.write(dsm / z_unit, 1)
    gpkg, _ = write_crown_model([tmp_path / "strip.las"], tmp_path / "dsm_nearest.tif", tmp_path)
    meta, _, geoms, fields = pyogrio.raw.read(str(gpkg))
    f = dict(zip(meta["fields"], fields))
    order = np.argsort(f["x_m"])
    np.testing.assert_allclose(f["x_m"][order] - x0 * xy_unit, [10.0, 30.3], atol=0.3)
    np.testing.assert_allclose(f["radius_m"][order], [3.0, 2.2], atol=0.3)
    np.testing.assert_allclose(f["top_m"][order], [12.0, 8.0], atol=0.05)
    assert (f["base_m"] < f["top_m"]).all() and (f["base_m"] > 0.5).all()
    bounds = shapely.bounds(shapely.from_wkb(geoms))  # the polygons in the CRS's units: the disks' boxes
    np.testing.assert_allclose((bounds[:, 2] - bounds[:, 0]) / 2 * xy_unit, f["radius_m"], rtol=1e-9)
    np.testing.assert_allclose((bounds[:, 2] + bounds[:, 0]) / 2 * xy_unit, f["x_m"], rtol=1e-9)
    description = pyogrio.read_info(str(gpkg))["layer_metadata"]["DESCRIPTION"]
    assert description == (f"{MARK}; {CROWNS_IN_METRES_NOTE}" if noted else MARK)


def test_strips_in_another_crs_than_the_dsm_are_refused(tmp_path):
    """Strips in UTM 12N beside a DSM in UTM 11N: an InputError naming the strip, nothing written."""
    import rasterio
    from rasterio.transform import from_origin

    from aerotri.core.errors import InputError
    from lidarctl.rasters.crown_model import write_crown_model

    x, y, z, cls, rn = _scene(6)
    _write_strip(tmp_path / "strip.las", x, y, z, cls, rn, 500000.0, 4000000.0, epsg=32612)
    dsm, _ = _nearest_dsm(x, y, z, cls, rn)
    with rasterio.open(tmp_path / "dsm_nearest.tif", "w", driver="GTiff", width=84, height=84, count=1,
                       dtype="float32", crs="EPSG:32611", transform=from_origin(500000.0, 4000042.0, 0.5, 0.5)) as ds:
        ds.write(dsm, 1)
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(InputError, match="strip.las"):
        write_crown_model([tmp_path / "strip.las"], tmp_path / "dsm_nearest.tif", out)
    assert list(out.iterdir()) == []
