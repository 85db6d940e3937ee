"""Tiled classification (lidarctl.tiles): tiling geometry, tiled == untiled, fields preserved,
byte-identical output for every scheduler, bad input and interrupts leave no output."""

import datetime

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.core.executor import Executor
from aerotri.geom import las as las_format
from lidarctl.classify import pipeline as cl
from lidarctl import io, synthetic, tiles
from lidarctl.cli.main import main
from aerotri.core.errors import InputError


def _scene(width_m, density, seed, n_buildings=8, n_trees=60):
    return synthetic.synthetic_scene(width_m=width_m, density_per_m2=density, seed=seed,
                                     n_buildings=n_buildings, n_trees=n_trees)


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    """300 m x 300 m, 4 points/m^2 (~370 k points), LAS 1.4 with a CRS, an extra VLR, an EVLR and
    an extra-bytes dimension."""
    d = tmp_path_factory.mktemp("tiles")
    cloud, truth = _scene(300.0, 4.0, 3, n_buildings=10, n_trees=80)
    synthetic.write_las(d / "plain.las", cloud, crs="EPSG:32632")
    las = laspy.read(d / "plain.las")
    las.header.system_identifier = "tile test scanner"
    las.header.generating_software = "test generator"
    las.header.creation_date = datetime.date(2019, 3, 4)
    las.header.vlrs.append(laspy.VLR("acme", 7, "project note", b"strip 12, flight 3"))
    las.header.evlrs = type(las.header.vlrs)([laspy.VLR("acme", 8, "waveform note", b"e" * 64)])
    las.gps_time = np.arange(len(las.points)) * 1e-5 + 1000.0      # fields the classifier ignores
    las.add_extra_dim(laspy.ExtraBytesParams(name="echo_width", type=np.float32))
    las.echo_width = np.arange(len(las.points), dtype=np.float32)
    las.write(d / "in.laz")
    return d, cloud, truth


def _record_bytes_without_classification(las):
    """Raw point records with the class bits zeroed (formats 0-5 share the byte with 3 flag bits)."""
    arr = las.points.array.copy()
    if "classification" in arr.dtype.names:
        arr["classification"] = 0
    else:
        arr["raw_classification"] &= 0b11100000
    return arr.tobytes()


def test_tile_grid_cores_partition_and_buffers_match_brute_force():
    rng = np.random.default_rng(1)
    grid = tiles.TileGrid(1000.0, 2000.0, 100.0, 30.0, nrows=3, ncols=4)
    x = rng.uniform(990.0, 1410.0, 20000)                # some points off the grid: edge tiles
    y = rng.uniform(1990.0, 2310.0, 20000)
    ids, pos = grid.assign(x, y)
    row, col = grid.core_rc(x, y)
    for tid in range(grid.n_tiles):
        r, c = divmod(tid, grid.ncols)
        x0, y0, x1, y1 = grid.core_box(r, c)
        # Core = own tile; buffer = inside the core box grown by buffer_m (the grid's outer edges
        # are open: off-grid points belong to the edge tiles).
        lo_x = -np.inf if c == 0 else x0 - grid.buffer_m
        hi_x = np.inf if c == grid.ncols - 1 else x1 + grid.buffer_m
        lo_y = -np.inf if r == 0 else y0 - grid.buffer_m
        hi_y = np.inf if r == grid.nrows - 1 else y1 + grid.buffer_m
        expect = np.flatnonzero((x >= lo_x) & (x < hi_x) & (y >= lo_y) & (y < hi_y))
        np.testing.assert_array_equal(pos[ids == tid], expect)          # file order within a tile
        assert np.all(np.isin(np.flatnonzero((row == r) & (col == c)), expect))
    assert np.bincount(row * grid.ncols + col, minlength=grid.n_tiles).sum() == len(x)


def test_core_near_codes_give_the_memberships_of_assign():
    """One record a point (its core tile and near code, what the corner stage's scratch holds) gives the same
    tile memberships as ``assign``, also for points exactly on a core edge or a buffer line."""
    rng = np.random.default_rng(2)
    for tile_m, buffer_m in ((100.0, 30.0), (100.0, 100.0), (150.0, 1.0)):
        grid = tiles.TileGrid(1000.0, 2000.0, tile_m, buffer_m, nrows=3, ncols=4)
        x = rng.uniform(990.0, 1010.0 + 4 * tile_m, 20000)
        y = rng.uniform(1990.0, 2010.0 + 3 * tile_m, 20000)
        on = rng.random(len(x)) < 0.2   # on the lines themselves
        x[on] = 1000.0 + tile_m * rng.integers(0, 5, on.sum()) + rng.choice([0.0, buffer_m, -buffer_m], on.sum())
        ids, pos = grid.assign(x, y)
        tile, code = grid.core_near(x, y)
        np.testing.assert_array_equal(tile, np.ravel_multi_index(grid.core_rc(x, y), (grid.nrows, grid.ncols)))
        mine = [((t // grid.ncols + dr) * grid.ncols + t % grid.ncols + dc, k)
                for k, (t, c) in enumerate(zip(tile.tolist(), code.tolist()))
                for dr in (-1, 0, 1) for dc in (-1, 0, 1) if tiles.near_code_in_buffer_of(c, dr, dc)]
        np.testing.assert_array_equal(np.array(sorted(mine)), np.column_stack([ids, pos]))


def test_plan_defaults_and_option_errors(big):
    d, _, _ = big
    header = las_format.read_header(d / "in.laz")
    grid = tiles.plan_tiles(header)
    assert grid.n_tiles == 1 and grid.buffer_m == tiles.default_buffer_m() == 60.0
    # 4 points/m^2: 250 k points in 250 m (core 130 m + 2 x 60 m) -> 2 tiles of 150 m per axis.
    small = tiles.plan_tiles(header, tile_points=250_000)
    assert (small.nrows, small.ncols) == (2, 2) and small.tile_m == 150.0
    # Cores are at least twice the buffer (120 m): whole tiles of 150 m.
    tiny = tiles.plan_tiles(header, tile_points=50_000)
    assert (tiny.nrows, tiny.ncols) == (2, 2) and tiny.tile_m == 150.0
    fine = tiles.plan_tiles(header, buffer_m=10.0, tile_points=50_000)    # 112 - 20 m -> 3 x 100 m
    assert (fine.nrows, fine.ncols) == (3, 3) and fine.tile_m == 100.0
    assert tiles.default_buffer_m("ptd") == 30.0 and tiles.default_buffer_m("ptd", ground_params={"seed_cell_m": 60}) == 90
    with pytest.raises(InputError, match="--buffer-m"):
        tiles.plan_tiles(header, tile_size_m=50.0, buffer_m=60.0)
    with pytest.raises(InputError, match="--tile-size-m"):
        tiles.plan_tiles(header, tile_size_m=-5.0)


@pytest.fixture(scope="module")
def classified(big):
    """The big scene classified in one piece (direct path) and in 4 tiles of 150 m (+ 60 m buffer)."""
    d = big[0]
    s1 = tiles.classify_file(d / "in.laz", d / "direct.laz")
    with Executor("synchronous") as ex:
        s2 = tiles.classify_file(d / "in.laz", d / "tiled.laz", tile_size_m=150.0, executor=ex)
    return d / "direct.laz", d / "tiled.laz", s1, s2


def test_tiled_equals_untiled_and_keeps_every_other_field(big, classified):
    d, cloud, truth = big
    direct, tiled, s1, s2 = classified
    assert s1.run.n_tiles == 1 and s2.run.n_tiles == 4 and s2.grid.buffer_m == 60.0
    assert not list(d.glob(".*"))                                  # work files removed
    src, a, b = laspy.read(d / "in.laz"), laspy.read(direct), laspy.read(tiled)
    # Tiles classify on the whole cloud's frame (its grid cells, spacing and noise; tile-phase), so they give the
    # whole cloud's classes (before, 0.06 % differed, vegetation 1 <-> 5 at tree edges, where a grid cell of
    # classify_points moved with the tile's corner).
    differ = np.asarray(a.classification) != np.asarray(b.classification)
    assert not differ.any(), differ.sum()
    assert s1.run.class_counts == {int(c): int(k) for c, k in zip(*np.unique(a.classification, return_counts=True))}
    assert np.mean(np.asarray(b.classification)[truth == 2] == 2) > 0.98
    for out in (a, b):
        assert _record_bytes_without_classification(out) == _record_bytes_without_classification(src)
        h, hs = out.header, src.header
        assert (h.version, h.point_format.id, h.system_identifier, h.generating_software, h.creation_date) == \
            (hs.version, hs.point_format.id, hs.system_identifier, hs.generating_software, hs.creation_date)
        np.testing.assert_array_equal(h.scales, hs.scales)
        np.testing.assert_array_equal(h.offsets, hs.offsets)
        assert [(v.user_id, v.record_id) for v in h.vlrs] == [(v.user_id, v.record_id) for v in hs.vlrs]
        assert [(v.user_id, v.record_id, v.record_data) for v in h.evlrs] == [("acme", 8, b"e" * 64)]
        assert h.parse_crs().to_epsg() == 32632
        assert list(out.point_format.extra_dimension_names) == ["echo_width"]


def test_one_tile_split_equals_direct_path(big, tmp_path):
    d = big[0]
    cloud = io.read_cloud(d / "plain.las")
    header = las_format.read_header(d / "plain.las")
    grid = tiles.plan_tiles(header, tile_size_m=1000.0)
    assert grid.n_tiles == 1
    params = cl.ClassifySettings()
    (task,) = tiles.split_into_tiles(d / "plain.las", grid, tmp_path, params, chunk_points=50_000)
    info = tiles.classify_tile(task)
    assert info.n_points == info.n_core == len(cloud)
    np.testing.assert_array_equal(np.load(task.core_index_path), np.arange(len(cloud)))
    direct = cl.classify_points(cloud.x, cloud.y, cloud.z, cloud.return_number, cloud.number_of_returns,
                                cloud.intensity, params=params)
    np.testing.assert_array_equal(np.load(task.classes_path), direct)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiles_small")
    cloud, _ = _scene(140.0, 2.5, 5, n_buildings=4, n_trees=30)  # 2 x 2 tiles of 70 m
    synthetic.write_las(d / "in.laz", cloud, crs="EPSG:32632")
    synthetic.write_las(d / "v12.las", cloud, version="1.2")
    return d


def test_same_bytes_for_synchronous_threads_and_local_cluster(small):
    d = small
    outs = []
    for sched in ("synchronous", None, "local:2"):
        out = d / f"out_{sched or 'threads'}.laz".replace(":", "")
        args = ["classify", str(d / "in.laz"), str(out), "--tile-size-m", "70", "--buffer-m", "28"]
        if sched:
            args += ["--scheduler", sched]
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
        assert "4 tiles of 70 m + 28 m buffer" in r.output
        outs.append(out.read_bytes())
    assert outs[0] == outs[1] == outs[2]


def test_las12_input_with_crs_option_tiled(small, tmp_path):
    out = tmp_path / "o.las"
    r = CliRunner().invoke(main, ["classify", str(small / "v12.las"), str(out), "--crs", "EPSG:32632",
                                  "--tile-size-m", "70", "--buffer-m", "28", "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    src, res = laspy.read(small / "v12.las"), laspy.read(out)
    assert res.header.version == src.header.version and res.header.point_format.id == 1
    assert res.header.parse_crs().to_epsg() == 32632
    assert _record_bytes_without_classification(res) == _record_bytes_without_classification(src)
    assert np.isin(res.classification, list(cl.CLASS_NAMES)).all()


def _fails(args, out, text):
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    assert text in r.output
    assert not out.exists()
    assert not list(out.parent.glob(f".{out.stem}*"))              # no temporary output or tiles


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast:RuntimeWarning")
def test_bad_input_in_tiled_mode_gives_exit_2_and_no_output(small, tmp_path):
    d = small
    out = tmp_path / "o.laz"
    cloud = io.read_cloud(d / "in.laz")
    cloud.z[len(cloud) - 5] = 1.0e6                                 # late record: found in pass 1
    synthetic.write_las(tmp_path / "absurd.las", cloud, crs="EPSG:32632")
    tiled = ["--tile-size-m", "70", "--buffer-m", "28"]
    _fails(["classify", str(tmp_path / "absurd.las"), str(out), *tiled], out, f"record {len(cloud) - 5}")
    cloud.z[len(cloud) - 5] = 100.0
    cloud.x[7] = np.nan                              # the writer's x offset (floor of the minimum) is NaN
    synthetic.write_las(tmp_path / "nan.las", cloud, crs="EPSG:32632")
    _fails(["classify", str(tmp_path / "nan.las"), str(out)], out, "x offset nan")
    data = (d / "in.laz").read_bytes()
    (tmp_path / "trunc.laz").write_bytes(data[: len(data) * 2 // 3])
    _fails(["classify", str(tmp_path / "trunc.laz"), str(out), *tiled], out, "trunc.laz")
    _fails(["classify", str(d / "v12.las"), str(out), *tiled], out, "no CRS record")
    _fails(["classify", str(d / "in.laz"), str(out), "--tile-size-m", "30"], out, "--buffer-m")


def test_interrupt_during_tasks_leaves_no_output(small, tmp_path, monkeypatch):
    out = tmp_path / "o.laz"
    calls = []

    def interrupted(task):
        calls.append(task)
        raise KeyboardInterrupt

    monkeypatch.setattr(tiles, "classify_tile", interrupted)
    with Executor("synchronous") as ex, pytest.raises(KeyboardInterrupt):
        tiles.classify_file(small / "in.laz", out, tile_size_m=70.0, buffer_m=28.0, executor=ex)
    assert calls and not out.exists()
    assert not list(tmp_path.iterdir())


def test_streamed_rasters_equal_in_memory_grids(classified, tmp_path):
    from lidarctl.rasters import products as rasters

    classified = classified[0]
    cloud = io.read_cloud(classified)
    ref = rasters.make_grids(cloud, 2.0)
    got, n = rasters.make_grids_streamed(classified, 2.0, chunk_points=40_000)     # 10 chunks
    assert n == len(cloud) and got.transform == ref.transform
    for name in ("dem", "dsm", "ndsm", "chm", "intensity"):
        a, b = getattr(ref, name), getattr(got, name)
        np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
        # Means summed chunk by chunk: equal up to the summation order (float32 rounding).
        np.testing.assert_allclose(b[np.isfinite(b)], a[np.isfinite(a)], rtol=1e-6, atol=1e-4)
    r = CliRunner().invoke(main, ["rasters", str(classified), str(tmp_path / "r"), "--res-m", "2"])
    assert r.exit_code == 0, r.output
    import rasterio
    with rasterio.open(tmp_path / "r" / "dem.tif") as ds:
        dem = ds.read(1, masked=True)
        assert ds.crs.to_epsg() == 32632
    np.testing.assert_allclose(dem.filled(np.nan), got.dem, rtol=1e-6, atol=1e-4)
    raw = laspy.read(classified)
    raw.classification = np.ones(len(raw.points), np.uint8)
    raw.write(tmp_path / "unclassified.laz")
    r = CliRunner().invoke(main, ["rasters", str(tmp_path / "unclassified.laz"), str(tmp_path / "r2"), "--res-m", "2"])
    assert r.exit_code == 2 and "no ground points" in r.output
    assert not (tmp_path / "r2" / "dem.tif").exists()


# -- several strips, no merged file ---------------------------------------------------------------
@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    """The 200 m scene as three strips along x (own offsets each; LAZ, LAS, LAZ) and merged into one file."""
    from lidarctl.merge import merge_las

    d = tmp_path_factory.mktemp("strips")
    cloud, truth = _scene(200.0, 2.5, 5, n_buildings=4, n_trees=30)
    band = np.minimum(cloud.x // 70.0 - np.floor(cloud.x.min() / 70.0), 2).astype(int)
    paths = []
    for k, suffix in enumerate((".laz", ".las", ".laz")):
        sel = band == k
        part = io.PointCloud(*(getattr(cloud, f)[sel] for f in ("x", "y", "z", "intensity", "return_number",
                                                                  "number_of_returns", "classification")))
        paths.append(d / "lidar" / f"strip_{k}{suffix}")
        paths[-1].parent.mkdir(exist_ok=True)
        synthetic.write_las(paths[-1], part, crs="EPSG:32632")
        (d / "truth").mkdir(exist_ok=True)
        synthetic.write_las(d / "truth" / f"strip_{k}.las", part, classification=truth[sel], crs="EPSG:32632")
    merge_las(paths, d / "merged.las")
    merge_las(sorted((d / "truth").glob("*.las")), d / "truth_merged.las")
    return d, paths


def test_strips_classified_together_equal_the_merged_file(strips, tmp_path):
    d, paths = strips
    merged = tiles.classify_file(d / "merged.las", tmp_path / "merged_out.las", tile_size_m=100.0, buffer_m=40.0)
    st = tiles.classify_files(paths, tmp_path / "classified", tile_size_m=100.0, buffer_m=40.0)
    assert st.n_files == 3 and st.n_points == merged.n_points and st.run.n_tiles == merged.run.n_tiles == 4
    outs = sorted((tmp_path / "classified").iterdir())
    # and the record of what it wrote (a rerun replaces these, refuses a user's LAS/LAZ)
    assert [p.name for p in outs] == ["classify.json", "strip_0.laz", "strip_1.las", "strip_2.laz"]
    assert tiles.classified_record_names(tmp_path / "classified") == {"strip_0.laz", "strip_1.las", "strip_2.laz"}
    outs = outs[1:]
    classes = []
    for src, out in zip(paths, outs):
        a, b = laspy.read(src), laspy.read(out)
        # the strip unchanged but for its classes (header scales/offsets, CRS, every other field)
        np.testing.assert_array_equal(a.header.offsets, b.header.offsets)
        assert b.header.parse_crs().to_epsg() == 32632 and len(b.points) == len(a.points)
        assert _record_bytes_without_classification(a) == _record_bytes_without_classification(b)
        classes.append(np.asarray(b.classification))
    # a tile takes its points from every strip: the same classes as the merged file, point for point
    np.testing.assert_array_equal(np.concatenate(classes), np.asarray(laspy.read(tmp_path / "merged_out.las").classification))
    assert st.run.class_counts == merged.run.class_counts
    # one tile (the direct path) over the strips: the same as the merged file in one piece
    whole = tiles.classify_files(paths, tmp_path / "whole", suffix=".las")
    direct = tiles.classify_file(d / "merged.las", tmp_path / "direct.las")
    assert whole.run.n_tiles == direct.run.n_tiles == 1
    np.testing.assert_array_equal(
        np.concatenate([laspy.read(tmp_path / "whole" / f"strip_{k}.las").classification for k in range(3)]),
        laspy.read(tmp_path / "direct.las").classification)


def test_strips_that_differ_are_refused_naming_the_strip_and_leave_no_output(strips, tmp_path):
    from aerotri.core.errors import CrsError, OptionError

    d, paths = strips
    other = tmp_path / "zone33.las"
    las = laspy.read(paths[1])
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales, header.offsets = las.header.scales, las.header.offsets
    import pyproj
    header.add_crs(pyproj.CRS.from_epsg(32633))
    out = laspy.LasData(header)
    out.points = las.points
    out.write(other)
    with pytest.raises(CrsError, match="zone33.las.*EPSG:32633"):
        tiles.classify_files([paths[0], other], tmp_path / "out", tile_size_m=100.0, buffer_m=40.0)
    synthetic.write_las(tmp_path / "v12.las", io.read_cloud(paths[1]), crs="EPSG:32632", version="1.2")
    with pytest.raises(InputError, match="v12.las: point format 1"):
        tiles.classify_files([paths[0], tmp_path / "v12.las"], tmp_path / "out")
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".*")) and not list(d.glob(".*"))
    # an input inside the output folder (replaced as a whole) and two strips with one output name
    with pytest.raises(OptionError, match="strip_0.laz: the input lies in the output folder"):
        tiles.classify_files(paths, d / "lidar")
    copy = tmp_path / "copy" / "strip_0.las"
    copy.parent.mkdir()
    copy.write_bytes(paths[1].read_bytes())
    with pytest.raises(OptionError, match="copy/strip_0.las: its classified strip would be named strip_0.las.*strip_0.laz"):
        tiles.classify_files([paths[0], copy], tmp_path / "out", suffix=".las")
    # the command: several strips into a folder, exit code 2 and one line on a bad set
    r = CliRunner().invoke(main, ["classify", str(paths[0]), str(other), str(tmp_path / "out")])
    assert r.exit_code == 2 and "zone33.las" in r.stderr and "Traceback" not in r.output
    r = CliRunner().invoke(main, ["classify", *map(str, paths), str(tmp_path / "out"), "--format", "las",
                                  "--tile-size-m", "100", "--buffer-m", "40"])
    assert r.exit_code == 0, r.output
    assert "of 3 strips" in r.output and sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "classify.json", "strip_0.las", "strip_1.las", "strip_2.las"]
    # the folder is replaced as a whole: a previous run's strips may go, a user's file may not (it went, exit 0)
    (tmp_path / "out" / "notes.txt").write_text("mine")
    with pytest.raises(OptionError, match="holds notes.txt, which lidarctl classify did not write"):
        tiles.classify_files(paths, tmp_path / "out")
    assert (tmp_path / "out" / "notes.txt").read_text() == "mine" and len(list((tmp_path / "out").iterdir())) == 5


def test_strips_evaluated_and_height_checked_as_the_merged_file(strips, tmp_path):
    from lidarctl.checks import classes as evaluate
    from lidarctl.checks import heights as heights_check

    d, paths = strips
    tiles.classify_files(paths, tmp_path / "classified", suffix=".las", tile_size_m=100.0, buffer_m=40.0)
    tiles.classify_file(d / "merged.las", tmp_path / "merged.las", tile_size_m=100.0, buffer_m=40.0)
    classified = sorted((tmp_path / "classified").glob("*.las"))
    truth = sorted((d / "truth").glob("*.las"))
    # each strip against its truth strip: the numbers of the merged file against the merged truth
    by_strip = evaluate.evaluate_strips(classified, truth)
    assert by_strip == evaluate.evaluate_files(tmp_path / "merged.las", d / "truth_merged.las")
    assert sum(map(sum, by_strip.confusion.matrix)) == sum(laspy.read(p).header.point_count for p in paths)
    with pytest.raises(InputError, match=r"classified/strip_0.las: \d+ points, but .*truth/strip_1.las"):
        evaluate.evaluate_strips(classified, truth[1:] + truth[:1])
    # the height check of the strips' ground: that of the merged file
    rng = np.random.default_rng(0)
    cloud = io.read_cloud(d / "merged.las")
    k = rng.choice(len(cloud), 20, replace=False)
    csv = tmp_path / "points.csv"
    csv.write_text("id,x,y,z\n" + "".join(f"p{i},{cloud.x[j]:.3f},{cloud.y[j]:.3f},{cloud.z[j] + 0.1:.3f}\n"
                                          for i, j in enumerate(k)))
    merged = heights_check.check_heights_file(tmp_path / "merged.las", csv)
    assert heights_check.check_heights_file(classified, csv) == merged and merged.document["overall"]["all"]["n"] > 10
    assert merged.record.n_checked == merged.document["overall"]["all"]["n"]


def test_merging_a_finer_strip_after_a_coarser_one_warns_with_the_rounding(strips, tmp_path, caplog):
    """`lidarctl merge` keeps the first strip's scales: a 1 mm strip after a 1 cm one came out rounded to 1 cm
    (trial-lidar, Autzen halves: up to 0.004 ft) without a word; now a warning names the strip and both scales."""
    import logging

    from lidarctl.merge import merge_las

    d, paths = strips
    fine = laspy.read(paths[1])
    header = laspy.LasHeader(version=fine.header.version, point_format=fine.header.point_format)
    header.scales, header.offsets = np.full(3, 0.0001), fine.header.offsets
    header.vlrs = list(fine.header.vlrs)
    out = laspy.LasData(header)
    out.points = laspy.ScaleAwarePointRecord.zeros(len(fine.points), header=header)
    for name in fine.point_format.dimension_names:
        if name not in ("X", "Y", "Z"):
            out[name] = fine[name]
    out.x, out.y, out.z = fine.x + 0.0003, fine.y, fine.z + 0.0003  # values a 1 mm grid cannot hold
    out.write(tmp_path / "fine.las")
    with caplog.at_level(logging.WARNING, logger="lidarctl.merge"):
        merge_las([paths[0], tmp_path / "fine.las"], tmp_path / "m1.las")
    assert "fine.las: its coordinate scales [0.0001, 0.0001, 0.0001] are finer" in caplog.text
    merged = laspy.read(tmp_path / "m1.las")
    dz = np.asarray(merged.z)[-len(fine.points):] - np.asarray(out.z)
    assert 0.0002 < np.max(np.abs(dz)) <= 0.0005 + 1e-9  # the rounding the warning speaks of
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="lidarctl.merge"):
        merge_las([tmp_path / "fine.las", paths[0]], tmp_path / "m2.las")  # finest first: nothing lost, no word
    assert "finer" not in caplog.text


def test_merging_a_strip_with_offsets_off_the_first_grid_warns_naming_both(strips, tmp_path, caplog):
    """`lidarctl merge` keeps the first strip's offsets: a strip written with PDAL-style offsets (500000.123456)
    is not on the first strip's grid and every point moved by up to half a step (3.5-4.9 mm in review 12b)
    without a word; now a warning names both files and the axes; strips on one grid merge without a word."""
    import logging

    from lidarctl.merge import merge_las

    d, paths = strips
    src = laspy.read(paths[1])
    header = laspy.LasHeader(version=src.header.version, point_format=src.header.point_format)
    header.scales, header.offsets = src.header.scales, src.header.offsets + np.array([0.123456, 0.0, 0.0004])
    header.vlrs = list(src.header.vlrs)
    shifted = laspy.LasData(header)
    shifted.points = laspy.ScaleAwarePointRecord.zeros(len(src.points), header=header)
    for name in src.point_format.dimension_names:
        if name not in ("X", "Y", "Z"):
            shifted[name] = src[name]
    shifted.x, shifted.y, shifted.z = src.x, src.y, src.z
    shifted.write(tmp_path / "shifted.las")
    shifted = laspy.read(tmp_path / "shifted.las")
    with caplog.at_level(logging.WARNING, logger="lidarctl.merge"):
        merge_las([paths[0], tmp_path / "shifted.las"], tmp_path / "m1.las")
    assert "shifted.las: its coordinate offsets" in caplog.text and str(paths[0]) in caplog.text
    assert "its x/z coordinates are rounded" in caplog.text
    merged = laspy.read(tmp_path / "m1.las")
    step = float(merged.header.scales[0])
    dx = np.asarray(merged.x)[-len(src.points):] - np.asarray(shifted.x)
    assert 0.1 * step < np.max(np.abs(dx)) <= 0.5 * step + 1e-9  # the rounding the warning speaks of
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="lidarctl.merge"):
        merge_las(paths, tmp_path / "m2.las")  # the simulator's strips share one grid: no word
    assert "offsets" not in caplog.text
