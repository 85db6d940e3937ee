"""Rasters of several classified files by tiles (lidarctl.rasters.products.write_rasters_tiled) against the
whole grids of the concatenated cloud (make_grids): same cells, same values, same metadata; the
CLI takes several files; bad input leaves no output."""

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from lidarctl import io, synthetic
from lidarctl.rasters import products as rasters
from lidarctl.cli.main import main

FIELDS = ("x", "y", "z", "intensity", "return_number", "number_of_returns")


@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    """A 300 m x 300 m classified scene (truth classes) in two overlapping strips, and a scene cut to a
    diagonal band (an irregular footprint: nodata corners, extrapolated edge cells)."""
    d = tmp_path_factory.mktemp("rasters_tiled")
    cloud, truth = synthetic.synthetic_scene(width_m=300.0, density_per_m2=3.0, seed=5, n_buildings=10, n_trees=80)
    u = cloud.x - cloud.x.min()
    v = cloud.y - cloud.y.min()
    parts = {"west": u < 180.0, "east": u >= 140.0,                       # 40 m overlap: points in both
             "band": np.abs(u - v) < 90.0}
    for name, m in parts.items():
        sub = io.PointCloud(*[getattr(cloud, f)[m] for f in FIELDS], truth[m])
        synthetic.write_las(d / f"{name}.las", sub, crs="EPSG:32632")
    return d


def _whole(paths, res_m, out, **kw):
    clouds = [io.read_cloud(p) for p in paths]
    cat = io.PointCloud(*[np.concatenate([getattr(c, f) for c in clouds]) for f in FIELDS + ("classification",)],
                        crs=clouds[0].crs, units=clouds[0].units)
    return rasters.write_rasters(cat, out, res_m, **kw)


def _read(path):
    with rasterio.open(path) as ds:
        return ds.read(), ds.transform, ds.crs, ds.tags(), ds.units, ds.descriptions


@pytest.mark.parametrize("names,tile_px,buffer_px", [(("west", "east"), 64, 32), (("band",), 48, 16)])
def test_tiled_rasters_equal_whole_grids(strips, tmp_path, names, tile_px, buffer_px):
    paths = [strips / f"{n}.las" for n in names]
    # the DEM's TIN gap fill reaches at most 2 r + 2 cells: equal when the buffer covers that
    fill = {"dem_fill_radius_px": (buffer_px - 2) // 2}
    _whole(paths, 1.0, tmp_path / "whole", **fill)
    # small chunks: a tile's points arrive from several chunks of several files
    from numpy._core.multiarray import _get_madvise_hugepage

    advice = _get_madvise_hugepage()
    rasters.write_rasters(paths, tmp_path / "tiled", 1.0, tile_px=tile_px, buffer_px=buffer_px, chunk_points=30_000,
                          **fill)
    assert _get_madvise_hugepage() == advice          # numpy's setting off during the stage only
    with rasterio.open(tmp_path / "whole" / "dem.tif") as ds:
        assert ds.width > 3 * tile_px and ds.height > 3 * tile_px          # several tiles each way
    for f in rasters.FILES:
        a, b = _read(tmp_path / "whole" / f), _read(tmp_path / "tiled" / f)
        np.testing.assert_array_equal(a[0], b[0], err_msg=f)
        if f.endswith(".tif"):
            assert a[1:] == b[1:], f
    # one PNG writer for both: the same bytes
    assert (tmp_path / "whole" / "hillshade.png").read_bytes() == (tmp_path / "tiled" / "hillshade.png").read_bytes()
    assert sorted(p.name for p in (tmp_path / "tiled").iterdir()) == sorted(rasters.FILES)   # no temporaries


def test_rasters_cli_several_files_and_errors(strips, tmp_path):
    out = tmp_path / "r"
    r = CliRunner().invoke(main, ["rasters", str(strips / "west.las"), str(strips / "east.las"), str(out),
                                  "--res-m", "2", "--tile-px", "40", "--buffer-px", "20"])
    assert r.exit_code == 0, r.output
    with rasterio.open(out / "dem.tif") as ds:
        assert ds.crs.to_epsg() == 32632 and ds.width == 150 and ds.is_tiled
        assert ds.tags(ns="IMAGE_STRUCTURE") == {"LAYOUT": "COG", "COMPRESSION": "ZSTD", "INTERLEAVE": "BAND",
                                                 "PREDICTOR": "3"}   # lossless, the float predictor
        dem = ds.read(1, masked=True)
    assert dem.count() > 0.95 * dem.size                                   # the strips cover the square
    before = {f: (out / f).read_bytes() for f in rasters.FILES}
    r = CliRunner().invoke(main, ["rasters", str(strips / "west.las"), str(out), "--res-m", "2", "--tile-px", "10",
                                  "--buffer-px", "20"])
    assert r.exit_code == 2 and "--buffer-px" in r.output
    # a file in another CRS: refused before anything is written, the old set stays
    cloud = io.read_cloud(strips / "east.las")
    synthetic.write_las(tmp_path / "other.las", cloud, crs="EPSG:32633")
    r = CliRunner().invoke(main, ["rasters", str(strips / "west.las"), str(tmp_path / "other.las"), str(out),
                                  "--res-m", "2"])
    assert r.exit_code == 2 and "other.las" in r.output and "differs" in r.output
    cloud.classification[:] = 1
    synthetic.write_las(tmp_path / "unclassified.las", cloud, crs="EPSG:32632")
    r = CliRunner().invoke(main, ["rasters", str(tmp_path / "unclassified.las"), str(out), "--res-m", "2"])
    assert r.exit_code == 2 and "no ground points" in r.output
    assert {f: (out / f).read_bytes() for f in rasters.FILES} == before
    assert sorted(p.name for p in out.iterdir()) == sorted(rasters.FILES)


def test_dsm_nearest_is_the_nearest_first_return_across_tiles(strips, tmp_path):
    """dsm_nearest.tif by tiles of 32 cells (buffer 8, the 5 m search radius at 1 m: 6 cells) equals the nearest
    first return of all the strips' points at every cell centre that has one within 5 m (no seams), and dsm.tif
    elsewhere; noise (a return 50 m above the highest put among them) is not taken, and it is not dsm.tif (roof edges move)."""
    from lidarctl.rasters.nearest import nearest_return_surface

    cloud = io.read_cloud(strips / "west.las")
    k = int(np.flatnonzero((cloud.return_number == 1) & (cloud.classification == 2))[len(cloud.x) // 3])
    noise_z = float(cloud.z.max()) + 50.0
    cloud.z[k], cloud.classification[k] = noise_z, 7          # a high noise return, first of its pulse
    synthetic.write_las(tmp_path / "noisy.las", cloud, crs="EPSG:32632")
    out = tmp_path / "r"
    rasters.write_rasters([tmp_path / "noisy.las"], out, 1.0, tile_px=32, buffer_px=8, chunk_points=30_000)
    with rasterio.open(out / "dsm_nearest.tif") as ds:
        got, tf, nd = ds.read(1), ds.transform, ds.nodata
        assert ds.descriptions[0].startswith("DSM: first return nearest") and ds.units == ("metre",)
    with rasterio.open(out / "dsm.tif") as ds:
        dsm = ds.read(1)
    assert got.shape[0] > 4 * 32 and got.shape[1] > 4 * 32
    keep = (cloud.return_number == 1) & ~np.isin(cloud.classification, (7, 18))
    near = nearest_return_surface(cloud.x[keep], cloud.y[keep], cloud.z[keep], x0_m=tf.c, y_top_m=tf.f, res_m=1.0,
                                  nrows=got.shape[0], ncols=got.shape[1], max_dist_m=5.0)
    want = np.where((dsm == nd) | np.isnan(near), dsm, near).astype(np.float32)
    np.testing.assert_array_equal(got, want)
    assert (got != dsm).mean() > 0.05 and np.nanmax(np.where(got == nd, np.nan, got)) < noise_z - 40
    assert ((got == nd) == (dsm == nd)).all()


def test_working_rasters_in_memory_or_on_disk_give_the_same_bytes(strips, tmp_path, monkeypatch):
    """The working rasters held in memory (small grids) or written to working GeoTIFFs (large ones): every file the
    same bytes, and no working file left either way."""
    paths = [strips / "west.las", strips / "east.las"]
    out, opened = {}, rasters._tiled_gtiff
    for share in (1.0, 0.0):           # in memory, on disk
        monkeypatch.setattr(rasters, "WORKING_IN_MEMORY_SHARE", share)
        seen = []
        monkeypatch.setattr(rasters, "_tiled_gtiff", lambda *a, **k: seen.append(k["in_memory"]) or opened(*a, **k))
        rasters.write_rasters(paths, tmp_path / str(share), 1.0, tile_px=64, buffer_px=16)
        assert set(seen) == {share > 0} and len(seen) == len(rasters.RASTERS) + 1
        assert sorted(p.name for p in (tmp_path / str(share)).iterdir()) == sorted(rasters.FILES)
        out[share] = {f: (tmp_path / str(share) / f).read_bytes() for f in rasters.FILES}
    assert out[1.0] == out[0.0]


def test_a_cloud_without_vegetation_classes_is_told_its_chm_is_empty(strips, tmp_path):
    """trial-lidar: AHN3 as delivered (vegetation in class 1) gave a chm.tif of nodata alone with exit 0 and no word
    (`lidarctl trees` refuses the same cloud): the command now says so, naming the classes the cloud holds."""
    cloud = io.read_cloud(strips / "east.las")
    assert np.isin(cloud.classification, (4, 5)).any()
    r = CliRunner().invoke(main, ["rasters", str(strips / "east.las"), str(tmp_path / "veg"), "--res-m", "4"])
    assert r.exit_code == 0 and "no vegetation points" not in r.output, r.output
    cloud.classification[np.isin(cloud.classification, (3, 4, 5))] = 1
    synthetic.write_las(tmp_path / "delivered.las", cloud, crs="EPSG:32632")
    r = CliRunner().invoke(main, ["rasters", str(tmp_path / "delivered.las"), str(tmp_path / "r"), "--res-m", "4"])
    assert r.exit_code == 0, r.output
    held = ", ".join(map(str, np.unique(cloud.classification)))
    assert f"delivered.las: no vegetation points (classes 4, 5; the cloud holds classes {held})" in r.output
    with rasterio.open(tmp_path / "r" / "chm.tif") as ds:
        assert ds.read(1, masked=True).count() == 0
    # s27: classified, low vegetation only (classes 2, 3): not told to classify the cloud
    cloud.classification[cloud.classification == 1] = 3
    synthetic.write_las(tmp_path / "low.las", cloud, crs="EPSG:32632")
    r = CliRunner().invoke(main, ["rasters", str(tmp_path / "low.las"), str(tmp_path / "r3"), "--res-m", "4"])
    assert r.exit_code == 0, r.output
    assert "low.las: no medium or high vegetation points (classes 4, 5; the cloud holds classes 2, 3" in r.output
    assert "class 3, low vegetation, is not a canopy" in r.output and "lidarctl classify" not in r.output
    # a cloud written without intensities (trial s99 lidmut L6: intensity.tif all 0, no word) is said; one with is not
    assert "intensity is 0" not in r.output
    cloud.intensity[:] = 0
    synthetic.write_las(tmp_path / "no_intensity.las", cloud, crs="EPSG:32632")
    r = CliRunner().invoke(main, ["rasters", str(tmp_path / "no_intensity.las"), str(tmp_path / "r4"), "--res-m", "4"])
    assert r.exit_code == 0 and "no_intensity.las: every point's intensity is 0 (the file was written without " \
                                "intensities)" in r.output, r.output


def test_the_grid_holds_the_lowest_points_where_the_origin_rounds_above_them(tmp_path):
    """AHN3 Delft (ymin 447412.8) at --res-m 0.2 or 0.1: floor(ymin / res) * res rounds to 447412.80000000005, above
    the lowest points, which the cell kernels put in row -1: "RuntimeError: a point lies outside the raster grid",
    exit 1 (new-user trial). The origin is a cell lower now; every point's cell is inside the grid."""
    rng = np.random.default_rng(3)
    for xmin, ymin, res in [(84808.3, 447412.8, 0.2), (84808.3, 447412.8, 0.1), *[
            (float(np.round(rng.uniform(1e4, 9e5), 3)), float(np.round(rng.uniform(1e5, 6e6), 3)),
             float(rng.choice([0.1, 0.2, 0.25, 0.3, 0.5, 1.0]))) for _ in range(2000)]]:
        xmax, ymax = xmin + 191.7, ymin + 228.5
        _, x0, y0, nrows, ncols = rasters.grid_for_bounds(xmin, ymin, xmax, ymax, res)
        for v, v0, n in ((xmin, x0, ncols), (xmax, x0, ncols), (ymin, y0, nrows), (ymax, y0, nrows)):
            assert 0 <= np.floor((v - v0) / res) < n, (xmin, ymin, res)
    # the whole command on a cloud whose header starts there
    cloud, truth = synthetic.synthetic_scene(width_m=60.0, density_per_m2=2.0, seed=2, n_buildings=1, n_trees=4)
    shifted = io.PointCloud(cloud.x - cloud.x.min() + 84808.3, cloud.y - cloud.y.min() + 447412.8,
                            *[getattr(cloud, f) for f in FIELDS[2:]], truth)
    synthetic.write_las(tmp_path / "c.las", shifted, crs="EPSG:28992")
    import laspy

    assert laspy.read(tmp_path / "c.las").header.mins[1] == 447412.8
    r = CliRunner().invoke(main, ["rasters", str(tmp_path / "c.las"), str(tmp_path / "out"), "--res-m", "0.2"])
    assert r.exit_code == 0, r.output
    with rasterio.open(tmp_path / "out" / "dem.tif") as ds:
        assert ds.bounds.bottom <= 447412.8 and ds.read(1, masked=True).count() > 0.9 * ds.width * ds.height


def test_a_stopped_run_gives_up_the_tiles_it_is_computing(strips, tmp_path, monkeypatch):
    """Ctrl-C / SIGTERM in `lidarctl rasters` at 0.01 m cells on Autzen: the process lived on more than 150 s, the
    pool's exit waiting for the tiles computing (minutes each in the nearest-return search), then closing working
    GeoTIFFs by writing their unwritten blocks. Now the tiles computing see the stop and give up (nothing of them is
    kept), the working files are sparse: the interrupt ends the run at once."""
    import threading
    import time

    seen = {}
    started = threading.Event()

    def tile_grids(*args, stop=None, **kwargs):
        if not started.is_set():            # the first tile: a long one, until it is told to stop
            started.set()
            t0 = time.monotonic()
            while not stop[0] and time.monotonic() - t0 < 60:
                time.sleep(0.01)
            seen["stopped_after_s"] = time.monotonic() - t0 if stop[0] else None
            raise rasters._Stopped
        started.wait(10)
        time.sleep(0.2)
        raise KeyboardInterrupt              # what the calling thread gets from a tile: the run stops

    monkeypatch.setattr(rasters, "_tile_threads", lambda cells: 2)
    monkeypatch.setattr(rasters, "_tile_grids", tile_grids)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        rasters.write_rasters_tiled([strips / "west.las", strips / "east.las"], tmp_path / "out", 0.5, tile_px=128,
                                    buffer_px=16)
    assert seen["stopped_after_s"] is not None and time.monotonic() - t0 < 30
    assert not (tmp_path / "out").exists()


def test_the_nearest_return_search_stops_when_told():
    from lidarctl.rasters import nearest

    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 40, (3200, 2))            # 2 points per m2
    grid = dict(x0_m=0.0, y_top_m=40.0, res_m=0.01, nrows=4000, ncols=4000, max_dist_m=5.0)
    near = nearest.NearestReturns(**grid)
    cls, first = np.zeros(len(xy), np.uint8), np.ones(len(xy), np.uint8)
    near.count(xy[:, 0], xy[:, 1], cls, first)
    near.add(xy[:, 0], xy[:, 1], rng.uniform(0, 9, len(xy)), cls, first)
    out = near.surface(np.ones(1, np.bool_))     # stopped before its first row: returns at once, unfinished
    assert out.shape == (4000, 4000)
    small = dict(grid, res_m=0.5, nrows=80, ncols=80)
    z = rng.uniform(0, 9, len(xy))
    want = nearest.nearest_return_surface(xy[:, 0], xy[:, 1], z, **small)
    near = nearest.NearestReturns(**small)
    near.count(xy[:, 0], xy[:, 1], cls, first)
    near.add(xy[:, 0], xy[:, 1], z, cls, first)
    assert np.array_equal(near.surface(np.zeros(1, np.bool_)), want, equal_nan=True)


def test_cells_far_finer_than_the_points_are_said(caplog):
    import logging

    with caplog.at_level(logging.WARNING, logger="lidarctl.rasters.products"):
        rasters.warn_cells_finer_than_points(1_000_000, 617_000_000, 0.01, "autzen.laz")
        assert "cells of 0.01 m on points about 0.25 m apart" in caplog.text and "617 a point" in caplog.text
        caplog.clear()
        rasters.warn_cells_finer_than_points(1_000_000, 4_000_000, 0.5, "autzen.laz")
        assert caplog.text == ""


def test_under_a_memory_limit_the_tiles_that_fit_give_the_same_bytes_and_the_others_are_refused(strips, tmp_path,
                                                                                                  monkeypatch):
    """A batch job's memory limit (cgroup): the check counts the tiles in flight, GDAL's block cache (an eighth of
    the limit) and the stage's own part beside what the process holds; before, the demo's strips were killed by the
    kernel at 600 MiB whatever --tile-px. A run that fits writes the same bytes as one without the limit; one that
    does not is refused before anything is written, naming --tile-px."""
    from aerotri.core import limits
    from aerotri.core.errors import ResourceError

    paths = [strips / "west.las", strips / "east.las"]
    rasters.write_rasters(paths, tmp_path / "free", 1.0, tile_px=64, buffer_px=16)
    limit = 400 * 2**20
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: limit)
    monkeypatch.setattr(limits, "resident_bytes", lambda: 64 * 2**20)   # the test worker's own is not the point
    monkeypatch.setattr(rasters, "resident_bytes", lambda: 64 * 2**20)
    assert limits.cache_bytes(rasters.RASTERS_CACHE_BYTES) == limit // 8
    kept = []
    freed = rasters._freed_memory_kept
    monkeypatch.setattr(rasters, "_freed_memory_kept", lambda keep=True: kept.append(keep) or freed(keep))
    rasters.write_rasters(paths, tmp_path / "limited", 1.0, tile_px=64, buffer_px=16)
    assert kept == [False]                    # memory short: freed memory given back, not kept for speed
    for f in rasters.FILES:
        assert (tmp_path / "limited" / f).read_bytes() == (tmp_path / "free" / f).read_bytes(), f
    # 1 tile of 1,536 x 1,536 cells (1024 + 2 x 256) x 168 bytes + 50 MiB of cache + 64 MiB of the stage's + 64 MiB
    # held > 90 % of 400 MiB
    with pytest.raises(ResourceError) as e:
        rasters.write_rasters(paths, tmp_path / "refused", 0.1, tile_px=1024, buffer_px=256)
    msg = str(e.value)
    assert "1 tile of 1,536 x 1,536 cells" in msg and "block cache of 50.0 MiB" in msg
    assert "64.0 MiB the process holds" in msg
    assert "400.0 MiB this process's cgroup allows" in msg and e.value.param == "--tile-px"
    assert not (tmp_path / "refused").exists() and not list(tmp_path.glob("refused*"))


def test_under_a_memory_limit_the_default_tiles_shrink_until_they_fit(strips, tmp_path, monkeypatch, caplog):
    """Without --tile-px (as the chain's rasters stage runs) the default tile is halved while its tiles would not fit
    in the memory the process may use: at 400 MiB the 300 m scene at 0.25 m (one 1,200 x 1,200-cell tile by default)
    is refused when --tile-px 2048 is asked for, and written in smaller tiles when nothing is asked, the same bytes
    as a run without the limit at that tile size. Before, the demo's chain at 2 GiB stopped in its rasters stage
    ("use a smaller --tile-px", an option the chain does not have)."""
    import logging
    import re

    from aerotri.core import limits
    from aerotri.core.errors import ResourceError

    paths = [strips / "west.las", strips / "east.las"]
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: 400 * 2**20)
    monkeypatch.setattr(limits, "resident_bytes", lambda: 64 * 2**20)
    monkeypatch.setattr(rasters, "resident_bytes", lambda: 64 * 2**20)
    with pytest.raises(ResourceError):
        rasters.write_rasters(paths, tmp_path / "refused", 0.25, tile_px=rasters.DEFAULT_TILE_PX)
    with caplog.at_level(logging.INFO, logger="lidarctl.rasters.products"):
        rasters.write_rasters(paths, tmp_path / "limited", 0.25)
    chosen = re.search(r"rasters: tiles of (\d+) cells \(default 2048\) to fit in the 400.0 MiB", caplog.text)
    assert chosen and int(chosen[1]) in (256, 512, 1024)
    monkeypatch.undo()
    rasters.write_rasters(paths, tmp_path / "free", 0.25, tile_px=int(chosen[1]))
    for f in rasters.FILES:
        assert (tmp_path / "limited" / f).read_bytes() == (tmp_path / "free" / f).read_bytes(), f


def test_tiles_that_cut_the_gap_fill_s_pyramid_differently_are_said(strips, tmp_path):
    """Trial s94: AHN3 Delft with --tile-px 160 --buffer-px 130 (blocks of 2 cells) had DSM cells beside the canal
    up to 14.6 m off the untiled run's, no word. The alignment is the largest power of 2 dividing both, at most
    256; below 256 a warning names both options; the defaults and multiples of 256 are silent."""
    assert rasters.pyramid_alignment_px(160, 130) == 2 and rasters.pyramid_alignment_px(2048, 256) == 256
    assert rasters.pyramid_alignment_px(512, 0) == 256 and rasters.pyramid_alignment_px(64, 32) == 32
    runner = CliRunner()
    r = runner.invoke(main, ["rasters", str(strips / "west.las"), str(tmp_path / "a"), "--res-m", "2",
                             "--tile-px", "160", "--buffer-px", "130"])
    assert r.exit_code == 0, r.output
    assert "--tile-px 160 and --buffer-px 130 are common multiples of 2 cells only" in r.output
    r = runner.invoke(main, ["rasters", str(strips / "west.las"), str(tmp_path / "b"), "--res-m", "2",
                             "--tile-px", "512", "--buffer-px", "256"])
    assert r.exit_code == 0 and "common multiples" not in r.output, r.output
