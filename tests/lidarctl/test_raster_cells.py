"""The loops of the tiled rasters give the array versions they replaced, bit for bit: per-cell sums chunk by chunk
(np.bincount), maxima, the CHM's bilinear DEM samples, the pull-push fill, the footprint's hole filling; the
hillshade's grey levels and PNG are matplotlib's colours."""

import numpy as np
import pytest
from scipy import ndimage

from lidarctl.rasters.cells import CellStats
from lidarctl.raster_ops import fill_nodata, sample_bilinear


def _points(n, seed, res_m, x0, y0, nrows, ncols):
    rng = np.random.default_rng(seed)
    x = x0 + rng.uniform(0, ncols * res_m, n)
    y = y0 + rng.uniform(0, nrows * res_m, n)
    z = rng.normal(300, 20, n)
    cls = rng.choice(np.array([1, 2, 4, 5, 6, 7, 9, 18], np.uint8), n)
    rn = rng.integers(1, 4, n).astype(np.uint8)
    inten = rng.integers(0, 65535, n).astype(np.uint16)
    return x, y, z, cls, rn, inten


def _reference(chunks, res_m, x0, y0, nrows, ncols, row0, col0):
    """The array version (np.isin, np.bincount, np.fmax) the loops replaced."""
    n = nrows * ncols
    valid_n, ground_n, inten_n = (np.zeros(n, np.int64) for _ in range(3))
    ground_sum, inten_sum, dsm = np.zeros(n), np.zeros(n), np.full(n, np.nan)
    for x, y, z, cls, rn, inten in chunks:
        flat = (np.floor((y - y0) / res_m).astype(np.int64) - row0) * ncols + np.floor((x - x0) / res_m).astype(np.int64) - col0
        valid = ~np.isin(cls, (7, 18))
        valid_n += np.bincount(flat[valid], minlength=n)
        g = np.isin(cls, (2, 9))
        ground_sum += np.bincount(flat[g], z[g], minlength=n)
        ground_n += np.bincount(flat[g], minlength=n)
        first = valid & (rn == 1)
        top = np.full(n, np.nan)
        np.fmax.at(top, flat[first], z[first])
        dsm = np.fmax(dsm, top)
        inten_sum += np.bincount(flat[first], inten[first].astype(float), minlength=n)
        inten_n += np.bincount(flat[first], minlength=n)
    return valid_n, ground_sum, ground_n, dsm, inten_sum, inten_n


def test_cell_stats_equal_bincount_chunk_by_chunk():
    res_m, x0, y0, nrows, ncols, row0, col0 = 0.5, 1000.0, 5000.0, 40, 60, 3, 7
    wx0, wy0 = x0 + col0 * res_m, y0 + row0 * res_m          # the window of a larger grid
    chunks = [_points(n, seed, res_m, wx0, wy0, nrows, ncols) for seed, n in ((1, 9000), (2, 5000), (3, 1))]
    stats = CellStats(res_m, x0, y0, nrows, ncols, row0=row0, col0=col0)
    for c in chunks:
        stats.add(*c)
    ref = _reference(chunks, res_m, x0, y0, nrows, ncols, row0, col0)
    for got, want in zip((stats.valid_n, stats.ground_sum, stats.ground_n, stats.dsm, stats.inten_sum, stats.inten_n), ref):
        np.testing.assert_array_equal(got, want)
    # the CHM: highest vegetation above the bilinear DEM
    dem = np.random.default_rng(4).normal(300, 5, (nrows, ncols))
    for c in chunks:
        stats.add_chm(c[0], c[1], c[2], c[3], dem)
    want = np.full(nrows * ncols, np.nan)
    for x, y, z, cls, _, _ in chunks:
        veg = np.isin(cls, (4, 5))
        hag = z[veg] - sample_bilinear(dem, x[veg], y[veg], cell_m=res_m, x0=x0, y0=y0, row0=row0, col0=col0)
        flat = (np.floor((y[veg] - y0) / res_m).astype(np.int64) - row0) * ncols + np.floor((x[veg] - x0) / res_m).astype(np.int64) - col0
        np.fmax.at(want, flat, hag)
    np.testing.assert_array_equal(stats.chm, want)
    with pytest.raises(RuntimeError, match="outside the raster grid"):
        stats.add(np.array([x0]), np.array([y0]), np.array([1.0]), np.array([2], np.uint8), np.array([1], np.uint8),
                  np.array([0], np.uint16))


def _fill_nodata_arrays(a):
    """The array version of the pull-push fill."""
    valid = np.isfinite(a)
    if valid.all() or not valid.any():
        return a.copy()
    levels = [(np.where(valid, a, 0.0), valid.astype(float))]
    while True:
        v, w = levels[-1]
        if (w > 0).all() or min(v.shape) == 1:
            break
        h, wd = (v.shape[0] + 1) // 2 * 2, (v.shape[1] + 1) // 2 * 2
        vp, wp = np.zeros((h, wd)), np.zeros((h, wd))
        vp[:v.shape[0], :v.shape[1]] = v * w
        wp[:v.shape[0], :v.shape[1]] = w
        ws = wp.reshape(h // 2, 2, wd // 2, 2).sum(axis=(1, 3))
        vs = vp.reshape(h // 2, 2, wd // 2, 2).sum(axis=(1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            levels.append((np.where(ws > 0, vs / np.maximum(ws, 1e-12), 0.0), (ws > 0).astype(float)))
    filled, w = levels[-1]
    if not (w > 0).all():
        filled = np.where(w > 0, filled, np.sum(filled * w) / w.sum())
    for v, w in reversed(levels[:-1]):
        filled = np.where(w > 0, v, np.repeat(np.repeat(filled, 2, axis=0), 2, axis=1)[:v.shape[0], :v.shape[1]])
    return filled


@pytest.mark.parametrize("shape, share", [((97, 131), 0.5), ((64, 64), 0.95), ((1, 40), 0.5), ((33, 1), 0.3),
                                          ((50, 70), 0.0)])
def test_pull_push_equals_the_array_version(shape, share):
    rng = np.random.default_rng(sum(shape))
    a = rng.normal(300, 30, shape)
    a[rng.random(shape) < share] = np.nan
    np.testing.assert_array_equal(fill_nodata(a), _fill_nodata_arrays(a))


def test_footprint_holes_as_binary_fill_holes():
    from lidarctl.rasters.products import _fill_holes

    rng = np.random.default_rng(7)
    for _ in range(10):
        m = ndimage.binary_dilation(rng.random((120, 90)) < 0.02, iterations=int(rng.integers(1, 5)))
        np.testing.assert_array_equal(_fill_holes(m), ndimage.binary_fill_holes(m))
        f = ndimage.binary_dilation(m, np.ones((3, 3), bool), iterations=3)
        np.testing.assert_array_equal(f, ndimage.maximum_filter(m, size=7, mode="constant", cval=False))


def hillshade_rgba(hs: np.ndarray) -> np.ndarray:
    """(rows, cols, 4) uint8 RGBA of a hillshade 0..1 as ``matplotlib.pyplot.imsave`` with the grey colour
    map writes it (NaN black): the reference of the rasters' PNG."""
    from matplotlib import cm, colors

    mappable = cm.ScalarMappable(norm=colors.Normalize(0.0, 1.0), cmap="gray")
    return mappable.to_rgba(np.where(np.isfinite(hs), hs, 0.0), bytes=True)


def hillshade_grey(hs: np.ndarray) -> np.ndarray:
    """The grey level of ``hillshade_rgba`` by the rasters' table: int(value x 256), 1.0 -> 255."""
    from lidarctl.rasters.products import _GREY_LUT

    x = np.where(np.isfinite(hs), hs, 0.0) * 256.0
    return _GREY_LUT[np.minimum(x.astype(np.int64), 255)]


def test_hillshade_grey_and_png_are_matplotlibs(tmp_path):
    import matplotlib
    import matplotlib.image as mpimg

    from lidarctl.rasters.products import _write_png_grey_as_rgba

    rng = np.random.default_rng(8)
    hs = rng.random((301, 203))
    hs[rng.random(hs.shape) < 0.1] = np.nan
    hs[0, :3] = (0.0, 1.0, np.nextafter(1.0, 0.0))
    rgba = hillshade_rgba(hs)
    grey = hillshade_grey(hs)
    np.testing.assert_array_equal(rgba[..., :3], np.repeat(grey[..., None], 3, axis=2))
    assert (rgba[..., 3] == 255).all()
    _write_png_grey_as_rgba(tmp_path / "h.png", lambda r0, r1: grey[r0:r1], *grey.shape, rows_per_read=64)
    back = mpimg.imread(tmp_path / "h.png")
    np.testing.assert_array_equal(np.round(back * 255).astype(np.uint8), rgba)
    # what the rasters wrote before through matplotlib (plt.imsave): the same pixels
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(tmp_path / "m.png", np.where(np.isfinite(hs), hs, 0.0), cmap="gray", vmin=0, vmax=1)
    np.testing.assert_array_equal(mpimg.imread(tmp_path / "m.png"), back)


def test_hillshade_grey_of_dem_is_the_grey_of_the_hillshade(tmp_path):
    """The one-pass grey levels equal hillshade_grey(hillshade(...)) pixel for pixel (float32 and float64 DEMs,
    nodata, steep and flat cells), and the PNG made by strips of rows from a GeoTIFF equals the whole array's."""
    import matplotlib.image as mpimg
    import rasterio
    from rasterio.transform import from_origin

    from lidarctl.rasters.products import NODATA, _hillshade_png, hillshade, hillshade_grey_of_dem

    rng = np.random.default_rng(11)
    dem = np.cumsum(rng.normal(0.0, 0.3, (517, 389)), axis=1) + 40.0 * (rng.random((517, 389)) < 0.01)
    dem[100:140, 50:90] = 12.0                                   # flat: shade = sin(altitude)
    dem[rng.random(dem.shape) < 0.05] = np.nan
    for d in (dem.astype(np.float32), dem):
        np.testing.assert_array_equal(hillshade_grey_of_dem(d, 0.5), hillshade_grey(hillshade(d, 0.5)))
    d32 = dem.astype(np.float32)
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=d32.shape[1], height=d32.shape[0], count=1,
                       dtype="float32", nodata=NODATA, transform=from_origin(0, 0, 0.5, 0.5)) as ds:
        ds.write(np.where(np.isfinite(d32), d32, NODATA).astype(np.float32), 1)
    with rasterio.open(tmp_path / "dem.tif") as src:
        _hillshade_png(src, tmp_path / "h.png", 0.5)
    back = np.round(mpimg.imread(tmp_path / "h.png") * 255).astype(np.uint8)
    np.testing.assert_array_equal(back[..., 0], hillshade_grey(hillshade(d32, 0.5)))


def test_slopes_come_from_valid_cells_only():
    """Central differences between valid neighbours, one-sided beside a nodata cell (as at the grid's edge), 0
    with no valid neighbour along the axis."""
    from lidarctl.rasters.products import gradient_of_valid

    nan = np.nan
    z = np.array([[nan, 1.0, 3.0, nan, 5.0, 6.0, 8.0, nan, 9.0]])
    g = gradient_of_valid(z, 0.5, 1)
    np.testing.assert_array_equal(g, [[nan, 4.0, 4.0, nan, 2.0, 3.0, 4.0, nan, 0.0]])
    np.testing.assert_array_equal(gradient_of_valid(z.T, 0.5, 0), g.T)
    full = np.arange(12.0).reshape(3, 4) ** 2
    np.testing.assert_array_equal(gradient_of_valid(full, 2.0, 1), np.gradient(full, 2.0, axis=1))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_hillshade_of_a_plane_with_nodata_has_no_rim(dtype):
    """A tilted plane with a nodata border, a hole and a notch shades every valid cell alike: slopes against a
    fill value (the DEM's mean) made a bright or dark rim along every nodata edge."""
    from lidarctl.rasters.products import hillshade, hillshade_grey_of_dem

    y, x = np.mgrid[0:60, 0:80] * 0.5
    dem = (120.0 + 0.3 * x - 0.2 * y).astype(dtype)
    dem[:, :7] = np.nan
    dem[:4, :] = np.nan
    dem[20:30, 30:45] = np.nan
    dem[50:, 60:] = np.nan
    hs = hillshade(dem, 0.5)
    valid = np.isfinite(dem)
    assert np.array_equal(np.isfinite(hs), valid)
    assert np.ptp(hs[valid]) < (1e-4 if dtype is np.float32 else 1e-9)
    grey = hillshade_grey_of_dem(dem, 0.5)
    assert np.ptp(grey[valid].astype(int)) <= 1 and (grey[~valid] == 0).all()


def test_the_dsm_holds_a_crowns_later_returns_over_a_cell_whose_first_returns_reached_the_ground(tmp_path):
    """Trial-gis F1: a tilted pulse's first return hits a crown in one cell and its later returns fall in the next, whose
    own first returns passed through a gap to the ground. dsm.tif took first returns only: DSM = DEM there while the CHM
    (every vegetation return) stood 19 m high (the demo: CHM above nDSM in 33,730 of 80,159 cells, by up to 19.15 m).
    The DSM is raised to the highest return of any number in the cell: nDSM >= CHM."""
    import laspy
    import pyproj
    import rasterio
    from click.testing import CliRunner

    from lidarctl.cli.main import main

    g = np.arange(0.25, 20.0, 0.5)
    gx, gy = (a.ravel() + 500000.0 for a in np.meshgrid(g, g))
    gy = gy - 500000.0 + 3400000.0
    # a crown's second returns (vegetation, 19 m up) in the cells of x, y in [8, 10) x [8, 10): first returns all ground
    vx, vy = (a.ravel() for a in np.meshgrid(np.arange(8.1, 10.0, 0.4), np.arange(8.1, 10.0, 0.4)))
    vx, vy = vx + 500000.0, vy + 3400000.0
    las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    las.header.scales, las.header.offsets = np.array([0.01, 0.01, 0.01]), np.array([500000.0, 3400000.0, 0.0])
    las.header.add_crs(pyproj.CRS("EPSG:32649"))
    las.x, las.y = np.concatenate([gx, vx]), np.concatenate([gy, vy])
    las.z = np.concatenate([np.full(gx.size, 100.0), np.full(vx.size, 119.0)])
    las.classification = np.concatenate([np.full(gx.size, 2), np.full(vx.size, 5)]).astype(np.uint8)
    las.return_number = np.concatenate([np.ones(gx.size), np.full(vx.size, 2)]).astype(np.uint8)
    las.number_of_returns = np.concatenate([np.ones(gx.size), np.full(vx.size, 2)]).astype(np.uint8)
    las.write(tmp_path / "c.las")
    r = CliRunner().invoke(main, ["rasters", str(tmp_path / "c.las"), str(tmp_path / "r"), "--res-m", "1"])
    assert r.exit_code == 0, r.output
    grids = {}
    for name in ("dsm", "ndsm", "chm"):
        with rasterio.open(tmp_path / "r" / f"{name}.tif") as ds:
            grids[name] = ds.read(1, masked=True).filled(np.nan)
            row, col = ds.index(500009.0, 3400009.0)
            grids[name + "_crown"] = grids[name][row, col]
    assert grids["dsm_crown"] == pytest.approx(119.0, abs=0.01)
    assert grids["ndsm_crown"] == pytest.approx(19.0, abs=0.01) and grids["chm_crown"] == pytest.approx(19.0, abs=0.01)
    both = np.isfinite(grids["chm"]) & np.isfinite(grids["ndsm"])
    assert both.any() and np.all(grids["chm"][both] <= grids["ndsm"][both] + 1e-3)
