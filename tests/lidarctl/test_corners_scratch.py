"""The corner stage's scratch (``lidarctl.corners.roof_corners._bin_corner_points``): every point written once as its LAS file
stores it, the tiles with their buffers rebuilt from it equal to the whole cloud's corners (two strips in a foot CRS,
noise points, several files), the scratch removed on success and on errors, and a full disk during the binning a
one-line error with exit code 2 and no output."""

from __future__ import annotations

import errno
import importlib.util
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from aerotri.core.errors import InputError
from lidarctl.corners import roof_corners as C
from lidarctl.cli.main import main

_spec = importlib.util.spec_from_file_location("corners_synth", Path(__file__).with_name("corners_synth.py"))
cs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cs)

FT = 1200.0 / 3937.0  # metres per US survey foot
E0_FT, N0_FT = 2_000_000.0, 600_000.0  # NAD83 / North Carolina (ftUS): realistic coordinate magnitudes


@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    """Two overlapping strips (scan lines 90 deg apart, point_source_id 11 and 12) of the synthetic town in feet,
    with noise points (class 7) among them; the second file on other offsets."""
    d = tmp_path_factory.mktemp("corner_scratch")
    paths = []
    for k, (seed, heading) in enumerate(((0, 17.0), (1, 107.0))):
        x, y, z, cls, _ = cs.make_cloud(seed=seed, heading_deg=heading)
        cls = cls.copy()
        cls[::997] = 7
        header = laspy.LasHeader(point_format=6, version="1.4")
        header.scales = np.array([0.001, 0.001, 0.001])
        header.offsets = np.array([E0_FT + 1000.0 * k, N0_FT, 0.0])
        header.add_crs(pyproj.CRS.from_epsg(2264))
        las = laspy.LasData(header)
        las.x, las.y, las.z = x / FT + E0_FT, y / FT + N0_FT, z / FT
        las.classification = cls
        las.point_source_id = np.full(len(x), 11 + k)
        las.write(d / f"strip_{k}.las")
        paths.append(d / f"strip_{k}.las")
    return paths


def test_tiles_from_the_scratch_equal_the_whole_cloud(strips, tmp_path):
    cat = C.read_strips(strips)
    assert cat.units.xy_m == pytest.approx(FT)
    whole = C.find_roof_corners(cat.x, cat.y, cat.z, cat.classification, cat.point_source_id,
                                roof="any")
    # 50 m tiles with a 45 m buffer over the 150 m x 140 m town: roofs cut by tile edges, files read in pieces
    tiled, _, units, _ = C.find_roof_corners_tiled(strips, tile_m=50.0, buffer_m=45.0, roof="any", work_dir=tmp_path,
                                                   chunk_points=7_000)
    assert tiled.stats.tiles >= 9 and not list(tmp_path.iterdir())
    assert len(whole.corners) > 20
    assert C.corners_csv_text(tiled.corners) == C.corners_csv_text(whole.corners)
    for k in ("n_points", "n_building_points", "point_spacing_m", "n_roofs", "n_outlines", "n_corners_traced",
              "n_usable", "n_roof_planes"):
        assert getattr(tiled.stats, k) == getattr(whole.stats, k), k


def test_each_point_is_written_once_as_its_file_stores_it(strips, tmp_path):
    tc = C._bin_corner_points(strips, None, tmp_path, 50.0, 45.0, 7_000)
    files = [f for f in tmp_path.iterdir() if f.name.startswith("tile_")]
    assert sum(f.stat().st_size for f in files) == tc.n_points * tc.record.itemsize == tc.n_points * 19
    cat = C.read_strips(strips)
    keep = ~np.isin(cat.classification, C.NOISE)
    got = np.concatenate([C._tile_points(tc, t) for t in np.flatnonzero(tc.used)])
    core = got[got["core"] == 1]
    assert len(core) == tc.n_points == keep.sum()
    core = core[np.argsort(core["index"])]
    np.testing.assert_array_equal(core["index"], np.arange(tc.n_points))
    for name, field in (("x", "x"), ("y", "y"), ("z", "z"), ("cls", "classification")):
        np.testing.assert_array_equal(core[name], getattr(cat, field)[keep])       # bit for bit, in metres
    n0 = laspy.open(strips[0]).header.point_count
    n_kept = [keep[:n0].sum(), keep[n0:].sum()]
    np.testing.assert_array_equal(core["file"], np.repeat([0, 1], n_kept))
    np.testing.assert_array_equal(core["sid"], np.repeat([11, 12], n_kept))   # the files' own strip ids


def test_scratch_removed_when_a_tile_fails(strips, tmp_path, monkeypatch):
    calls = []

    def fail(*a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise InputError("a bad tile")
        return real(*a, **k)

    real = C._tile_clusters
    monkeypatch.setattr(C, "_tile_clusters", fail)
    with pytest.raises(InputError, match="a bad tile"):
        C.find_roof_corners_tiled(strips, tile_m=50.0, buffer_m=45.0, work_dir=tmp_path)
    assert len(calls) == 3 and not list(tmp_path.iterdir())


def test_full_disk_while_binning_is_one_line_and_leaves_nothing(strips, tmp_path, monkeypatch):
    """The disk fills up after a few scratch files: exit code 2, one line naming the cause, no traceback, no
    output, no scratch."""
    import builtins

    opened = []

    def open_fails(path, mode="r", *a, **k):
        if "a" in mode and Path(path).name.startswith("tile_"):
            opened.append(path)
            if len(opened) > 5:
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return builtins.open(path, mode, *a, **k)

    monkeypatch.setattr(C, "open", open_fails, raising=False)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["corners", *map(str, strips), str(out), "--tile-m", "50", "--buffer-m", "45"])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.stderr
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and "no space left on device" in errors[0], r.stderr
    assert len(opened) == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no output folder, no scratch beside it


def test_too_little_free_disk_is_refused_before_binning(strips, tmp_path, monkeypatch):
    import shutil

    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=1_000_000))
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["corners", *map(str, strips), str(out)])
    assert r.exit_code == 2 and "Traceback" not in r.stderr
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and "scratch (19 + 8 bytes a point) would need up to" in errors[0], r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []
