"""A DEM that covers part of a frame (issue 42): the covered part is rectified, the rest is nodata, a warning
names the frame and the share; a frame the DEM does not cover at all is refused with the DEM's extent."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from ortho.cli import main
from tests.shared_builds import write_synthetic_project


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    """The 6-frame synthetic block rectified on its whole DEM (the reference for the partial runs)."""
    root = tmp_path_factory.mktemp("coverage") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=11)
    r = run("rectify", root)
    assert r.exit_code == 0, r.output
    return root


def _write_dem(src, dst, rows=None, nan_cols=None):
    with rasterio.open(src) as ds:
        a, prof = ds.read(1), ds.profile
    if rows is not None:
        a = a[rows]
    if nan_cols is not None:
        a = a.copy()
        a[:, nan_cols] = np.nan
    prof.update(height=a.shape[0], width=a.shape[1], nodata=np.nan)
    with rasterio.open(dst, "w", **prof) as out:
        out.write(a, 1)
    with rasterio.open(dst) as ds:
        return ds.bounds


def _read(path):
    with rasterio.open(path) as ds:
        return ds.read(), ds.read_masks(1) > 0, ds.transform


def _compare_with_full(full, project, frame):
    """(valid share of the partial ortho, share of its valid pixels equal to the full-DEM ortho's, valid
    pixels of the partial ortho outside the full one's)."""
    a, ok, t = _read(project / f"ortho/frames/{frame}.tif")
    b, okb, tb = _read(full / f"ortho/frames/{frame}.tif")
    # both grids are snapped to whole pixels (their extents differ where the border rays missed the DEM)
    assert t.a == tb.a and t.e == tb.e
    dc, dr = round((t.c - tb.c) / t.a), round((t.f - tb.f) / t.e)
    assert abs((t.c - tb.c) / t.a - dc) < 1e-6 and abs((t.f - tb.f) / t.e - dr) < 1e-6
    on_b = np.zeros_like(ok)  # the full ortho's validity on the partial ortho's grid
    b_on = np.zeros_like(a)
    r0, c0 = max(0, -dr), max(0, -dc)
    r1, c1 = min(ok.shape[0], okb.shape[0] - dr), min(ok.shape[1], okb.shape[1] - dc)
    on_b[r0:r1, c0:c1] = okb[r0 + dr:r1 + dr, c0 + dc:c1 + dc]
    b_on[:, r0:r1, c0:c1] = b[:, r0 + dr:r1 + dr, c0 + dc:c1 + dc]
    both = ok & on_b
    same = np.all(a[:, both] == b_on[:, both], axis=0).mean()
    return ok.sum() / okb.sum(), same, int(np.count_nonzero(ok & ~on_b)), ok, t


def test_a_partly_covered_frame_is_rectified_where_the_dem_is(full, tmp_path):
    project = tmp_path / "p"
    shutil.copytree(full, project, ignore=shutil.ignore_patterns("ortho"))
    dem = tmp_path / "dem_north.tif"
    with rasterio.open(full / "lidar_out/dem.tif") as ds:
        third = ds.height // 3
    extent = _write_dem(full / "lidar_out/dem.tif", dem, rows=slice(0, third))  # the northern third
    r = run("rectify", project, "--dem", dem, "--frames", "s01_003,s02_001")
    assert r.exit_code == 0, r.output
    index = json.loads((project / "ortho/frames/index.json").read_text())
    shares = {e["image_id"]: e["height_covered_share"] for e in index["frames"]}
    for frame in ("s01_003", "s02_001"):
        assert 0.05 < shares[frame] < 0.6
        assert f"frame {frame}: the DEM {dem} covers {100 * shares[frame]:.1f} %" in r.stderr, r.stderr
        ratio, same, outside, ok, t = _compare_with_full(full, project, frame)
        # the covered part is exactly what the whole DEM gives; nothing is made up beyond it
        assert same > 0.999 and outside == 0
        rows = np.nonzero(ok.any(axis=1))[0]
        assert t.f + (rows.max() + 0.5) * t.e > extent.bottom - 1.0  # no valid pixel south of the DEM
        assert abs(ratio - shares[frame]) < 0.1  # the ortho's valid share follows the covered share
    assert "%" in r.stderr and "nodata in its ortho" in r.stderr
    # the shortfall is said to lie beyond the DEM's extent, none on its nodata (it has none)
    for frame in ("s01_003", "s02_001"):
        line = next(t for t in r.stderr.splitlines() if f"frame {frame}: the DEM" in t)
        gone = 100 * (1 - shares[frame])
        assert f"the other {gone:.1f} % ({gone:.1f} % beyond its extent) is nodata" in line, line
        # the frame's grid ends at the DEM's southern edge (the 2-cell pad), not on the plane beyond it
        with rasterio.open(project / f"ortho/frames/{frame}.tif") as ds:
            assert ds.bounds.bottom >= extent.bottom - 3 * ds.res[0] - 1e-6  # (and the snap to whole cells)


def test_the_frames_warnings_come_in_the_blocks_order_from_every_scheduler(full, tmp_path):
    """A frame's warnings are said in the order of the block's frames, whichever frame finishes first, and from a
    cluster's worker processes too (their logging never reached the console): the same lines on 2 threads and on a
    local cluster of 2 workers."""
    dem = tmp_path / "dem_north.tif"
    with rasterio.open(full / "lidar_out/dem.tif") as ds:
        third = ds.height // 3
    _write_dem(full / "lidar_out/dem.tif", dem, rows=slice(0, third))
    said = {}
    for scheduler in ("threads", "local:2"):
        project = tmp_path / scheduler.replace(":", "_")
        shutil.copytree(full, project, ignore=shutil.ignore_patterns("ortho"))
        r = run("rectify", project, "--dem", dem, "--frames", "s02_001,s01_003", "--scheduler", scheduler,
                "--workers", 2)
        assert r.exit_code == 0, r.output
        said[scheduler] = [line.split(": the DEM")[0] for line in r.stderr.splitlines() if ": the DEM " in line]
        # (said, and not kept in the index)
        frames = json.loads((project / "ortho/frames/index.json").read_text())["frames"]
        assert len(frames) == 2 and not any("messages" in e for e in frames)
    # the frames' order (as --frames names them)
    assert said["threads"] == said["local:2"] == ["warning: frame s02_001", "warning: frame s01_003"], said


def test_a_frame_on_a_nodata_band_is_rectified_around_it(full, tmp_path):
    """DEM nodata (NaN) across the middle of the block, as a DEM from a drone block's points has: the frames
    over it are rectified on both sides, nodata on the band."""
    project = tmp_path / "p"
    shutil.copytree(full, project, ignore=shutil.ignore_patterns("ortho"))
    dem = tmp_path / "dem_hole.tif"
    with rasterio.open(full / "lidar_out/dem.tif") as ds:
        w = ds.width
    _write_dem(full / "lidar_out/dem.tif", dem, nan_cols=slice(int(0.45 * w), int(0.55 * w)))
    r = run("rectify", project, "--dem", dem)
    assert r.exit_code == 0, r.output
    index = json.loads((project / "ortho/frames/index.json").read_text())
    partial = [e for e in index["frames"] if e["height_covered_share"] < 1.0]
    assert partial, "no frame over the nodata band"
    for e in partial:
        line = next(t for t in r.stderr.splitlines() if f"frame {e['image_id']}: the DEM" in t)
        # inside the DEM's extent: the shortfall is its nodata, not beyond it
        assert "% on its nodata cells inside it) is nodata" in line and "beyond its extent" not in line, line
        ratio, same, outside, _, _ = _compare_with_full(full, project, e["image_id"])
        assert same > 0.999 and outside == 0 and ratio < 1.0


def test_a_frame_the_dem_does_not_cover_is_refused_with_the_dem_extent(full, tmp_path):
    project = tmp_path / "p"
    shutil.copytree(full, project)
    before = sorted(p.name for p in (project / "ortho/frames").iterdir())
    dem = tmp_path / "dem_north.tif"
    with rasterio.open(full / "lidar_out/dem.tif") as ds:
        third = ds.height // 3
    b = _write_dem(full / "lidar_out/dem.tif", dem, rows=slice(0, third))
    r = run("rectify", project, "--dem", dem, "--frames", "s01_001")
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    line = r.stderr.strip().splitlines()[-1]
    assert "s01_001" in line and str(dem) in line and "--frames" in line, line
    assert f"X {b.left:.1f} .. {b.right:.1f}, Y {b.bottom:.1f} .. {b.top:.1f}" in line, line
    assert sorted(p.name for p in (project / "ortho/frames").iterdir()) == before
