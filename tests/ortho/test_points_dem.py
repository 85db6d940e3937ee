"""``ortho dem``: the robust grid of adjusted tie points (outliers out, holes filled, extended to the footprints)."""

from __future__ import annotations

import numpy as np
import pytest

from aerotri.core.errors import InputError, OptionError
from ortho.points_dem import points_dem


def _surface(x, y):
    return 100.0 + 0.05 * x - 0.02 * y + 2.0 * np.sin(x / 40.0)


def test_points_dem_recovers_the_surface_without_its_outliers():
    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 200, (20000, 2))
    xy = xy[np.hypot(xy[:, 0] - 100, xy[:, 1] - 100) > 20]  # a hole: no tie points on a pond
    z = _surface(xy[:, 0], xy[:, 1]) + rng.normal(0, 0.05, len(xy))
    bad = rng.choice(len(xy), 200, replace=False)
    z[bad] += rng.choice([-1, 1], 200) * rng.uniform(5, 30, 200)  # wrong matches
    dem = points_dem(np.column_stack([xy, z]), 2.0, bounds=(-20, -20, 220, 220))
    assert dem.n_outliers >= 190 and dem.cells_interpolated > 0 and dem.cells_extrapolated > 0
    h, w = dem.heights_m.shape
    xc = dem.x_left_m + (np.arange(w) + 0.5) * dem.res_m
    yc = dem.y_top_m - (np.arange(h) + 0.5) * dem.res_m
    X, Y = np.meshgrid(xc, yc)
    inside = (X > 2) & (X < 198) & (Y > 2) & (Y < 198)
    err = dem.heights_m - _surface(X, Y)
    assert np.all(np.isfinite(dem.heights_m))
    assert np.sqrt(np.mean(err[inside] ** 2)) < 0.1  # m: cells of 2 m on a 5 % slope, 5 cm noise
    assert np.abs(err[inside]).max() < 0.5  # no outlier survives
    pond = np.hypot(X - 100, Y - 100) < 15
    assert np.abs(err[pond]).max() < 0.5  # interpolated across the hole


def test_points_dem_refuses_what_it_cannot_grid():
    with pytest.raises(InputError, match="too few"):
        points_dem(np.zeros((2, 3)), 1.0)
    with pytest.raises(OptionError, match="positive"):
        points_dem(np.random.default_rng(1).uniform(0, 10, (50, 3)), 0.0)


def test_the_dem_covers_every_frame_where_the_ground_falls_away(tiny_project, tmp_path):
    """`ortho dem` extends the tie points' DEM to the frames' footprints so that `ortho rectify --dem at/dem.tif`
    finds ground under every pixel. Footprints taken on the median height's plane fall short where the ground at
    the edges lies lower (Brighton Beach: 'the DEM does not cover frame DJI_0023', 1.2 m short); here the tie points
    cover the middle of the block and the ground falls 150 m towards its edges."""
    import shutil

    from click.testing import CliRunner

    from aerotri.geom.eo import read_eo
    from ortho.cli import main as ortho_main

    p = shutil.copytree(tiny_project, tmp_path / "p", ignore=shutil.ignore_patterns("lidar", "work", "at"))
    (p / "at").mkdir()
    shutil.copy(p / "truth" / "eo.txt", p / "at" / "eo.txt")
    eo = read_eo(p / "at" / "eo.txt")
    c = eo.centre_m[:, :2].mean(axis=0)
    half = 0.3 * np.ptp(eo.centre_m[:, :2], axis=0)
    gx, gy = np.meshgrid(np.linspace(-1, 1, 30), np.linspace(-1, 1, 30))
    x, y = c[0] + gx.ravel() * half[0], c[1] + gy.ravel() * half[1]
    z = 310.0 - 150.0 * np.hypot(gx.ravel(), gy.ravel()) / np.sqrt(2.0)
    rows = ["id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px"]
    rows += [f"T{k:07d},tie,{x[k]:.3f},{y[k]:.3f},{z[k]:.3f},0.1,0.1,0.1,3,0.1" for k in range(len(x))]
    (p / "at" / "object_points.csv").write_text("\n".join(rows) + "\n")
    r = CliRunner().invoke(ortho_main, ["dem", str(p)])
    assert r.exit_code == 0, r.output
    # without LiDAR and without --dem: the tie points' DEM is named (new-user trial 88), nothing written
    shutil.rmtree(p / "lidar_out", ignore_errors=True)
    r = CliRunner().invoke(ortho_main, ["rectify", str(p)])
    assert r.exit_code == 2 and f"pass --dem {p / 'at' / 'dem.tif'}" in r.output, r.output
    assert "lidar_out/dem.tif: DEM not found" in r.output and not (p / "ortho").exists()
    r = CliRunner().invoke(ortho_main, ["rectify", str(p), "--dem", str(p / "at" / "dem.tif")])
    assert r.exit_code == 0, r.output
    assert len(list((p / "ortho" / "frames").glob("*.tif"))) == len(eo.image_id)


def test_a_dem_from_a_handful_of_tie_points_is_warned_of(tiny_project, tmp_path, caplog):
    """Tuniu with --min-rays 3 kept 3 tie points for its whole block: the DEM was made without a word. A DEM from
    fewer than 10 tie points a frame is a plane through them; the command says so (and still makes it)."""
    import shutil

    from aerotri.geom.eo import read_eo
    from ortho.points_dem import write_points_dem

    p = shutil.copytree(tiny_project, tmp_path / "p", ignore=shutil.ignore_patterns("lidar", "work", "at"))
    (p / "at").mkdir()
    shutil.copy(p / "truth" / "eo.txt", p / "at" / "eo.txt")
    n_frames = len(read_eo(p / "at" / "eo.txt").image_id)
    c = read_eo(p / "at" / "eo.txt").centre_m[:, :2].mean(axis=0)
    rows = ["id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px"]
    rows += [f"T{k:07d},tie,{c[0] + 30 * k:.3f},{c[1] + 17 * (k % 3):.3f},{310 + k % 2:.3f},0.1,0.1,0.1,3,0.1"
             for k in range(5)]
    rows += ["T9999999,tie,0,0,0,0.1,0.1,0.1,2,0.1"]  # seen in 2 frames: not counted with min_rays 3
    (p / "at" / "object_points.csv").write_text("\n".join(rows) + "\n")
    with caplog.at_level("WARNING"):
        s = write_points_dem(p, min_rays=3)
    assert s.points <= 5 and (p / "at" / "dem.tif").is_file()
    msgs = [m for m in caplog.messages if "tie points seen in 3 or more frames" in m]
    assert len(msgs) == 1 and f"for {n_frames} frames" in msgs[0] and "fewer than 10" in msgs[0], caplog.messages


def test_a_dem_from_enough_tie_points_is_not_warned_of(tiny_project, tmp_path, caplog):
    import shutil

    from aerotri.geom.eo import read_eo
    from ortho.points_dem import write_points_dem

    p = shutil.copytree(tiny_project, tmp_path / "p", ignore=shutil.ignore_patterns("lidar", "work", "at"))
    (p / "at").mkdir()
    shutil.copy(p / "truth" / "eo.txt", p / "at" / "eo.txt")
    eo = read_eo(p / "at" / "eo.txt")
    c, half = eo.centre_m[:, :2].mean(axis=0), 0.4 * np.ptp(eo.centre_m[:, :2], axis=0)
    gx, gy = np.meshgrid(np.linspace(-1, 1, 40), np.linspace(-1, 1, 40))
    rows = ["id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px"]
    rows += [f"T{k:07d},tie,{c[0] + a * half[0]:.3f},{c[1] + b * half[1]:.3f},310.0,0.1,0.1,0.1,3,0.1"
             for k, (a, b) in enumerate(zip(gx.ravel(), gy.ravel()))]
    (p / "at" / "object_points.csv").write_text("\n".join(rows) + "\n")
    assert 1600 >= 10 * len(eo.image_id)
    with caplog.at_level("WARNING"):
        write_points_dem(p, min_rays=3)
    assert not [m for m in caplog.messages if "tie points seen in" in m], caplog.messages


def test_the_extended_share_and_where_are_said(tiny_project, tmp_path, caplog):
    """Brighton's DEM was 85 % extension beyond the tie points and said so in counts only. Tie points over a known
    square inside the frames: the grid's reach beyond them to N, E, S, W is the footprints' bounds minus the
    square (to a cell), the farthest extended cell lies at least that far out, and the share, the distance and the
    sides are in the console line, at/dem.json and the GeoTIFF's tags; a DEM mostly extended is warned of."""
    import json
    import shutil

    import rasterio
    from click.testing import CliRunner

    from aerotri.geom.eo import read_eo
    from ortho.cli import main as ortho_main
    from ortho.points_dem import _footprint_bounds

    p = shutil.copytree(tiny_project, tmp_path / "p", ignore=shutil.ignore_patterns("lidar", "work", "at"))
    (p / "at").mkdir()
    shutil.copy(p / "truth" / "eo.txt", p / "at" / "eo.txt")
    eo = read_eo(p / "at" / "eo.txt")
    c = eo.centre_m[:, :2].mean(axis=0)
    gx, gy = np.meshgrid(np.linspace(-60, 60, 41), np.linspace(-60, 60, 41))  # a 120 m square, 3 m apart
    rows = ["id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px"]
    rows += [f"T{k:07d},tie,{c[0] + a:.3f},{c[1] + b:.3f},310.0,0.1,0.1,0.1,3,0.1"
             for k, (a, b) in enumerate(zip(gx.ravel(), gy.ravel()))]
    (p / "at" / "object_points.csv").write_text("\n".join(rows) + "\n")
    r = CliRunner().invoke(ortho_main, ["dem", str(p), "--res-m", "6"])
    assert r.exit_code == 0, r.output
    rec = json.loads((p / "at" / "dem.json").read_text())
    x0, y0, x1, y1 = _footprint_bounds(p, 310.0, 310.0, margin_m=12.0)
    want = (y1 - (c[1] + 60), x1 - (c[0] + 60), (c[1] - 60) - y0, (c[0] - 60) - x0)
    assert min(want) > 50  # the frames reach well beyond the square
    assert np.allclose(rec["extended_beyond_nesw_m"], want, atol=6.0 + 1e-6)
    assert rec["extrapolated_max_distance_m"] >= max(want) - 6.0
    share = 100.0 * rec["cells_extrapolated"] / (rec["width"] * rec["height"])
    assert rec["extrapolated_percent"] == pytest.approx(share, abs=0.05) and share > 50
    assert f"{share:.0f} % of the cells ({rec['cells_extrapolated']} of" in r.output
    assert "extended beyond the tie points" in r.output and "most of this DEM (" in r.output and "is a flat continuation" in r.output
    # the three counts add up to the grid, and the words give all three (a trial user read 7 measured beside 7474 of
    # 7482 extended as counts that disagree)
    assert rec["cells_measured"] + rec["cells_interpolated"] + rec["cells_extrapolated"] == rec["width"] * rec["height"]
    assert (f"{rec['cells_measured']} measured (holding tie points), {rec['cells_interpolated']} interpolated "
            "between them") in r.output
    with rasterio.open(p / "at" / "dem.tif") as ds:
        tags = ds.tags()
    assert float(tags["CELLS_EXTRAPOLATED_PERCENT"]) == pytest.approx(share, abs=0.05)
    assert "north" in tags["EXTRAPOLATION"] and len(tags["EXTENDED_BEYOND_NESW_M"].split()) == 4
    # the advice names --min-rays 2 only to a user who has not given it (Tuniu trial: advised while given)
    assert "or --min-rays 2," in r.output
    r = CliRunner().invoke(ortho_main, ["dem", str(p), "--res-m", "6", "--min-rays", "2"])
    assert r.exit_code == 0 and "is a flat continuation" in r.output, r.output
    assert "--min-rays" not in r.output and "(a DEM from LiDAR reaches farther)" in r.output


def test_the_chain_takes_two_ray_tie_points_where_three_ray_ones_are_too_few(tiny_project, tmp_path):
    """Trial s98 (Tuniu through ``aerotri run``): 14 tie points in three frames made the orthophotos' DEM a plane, and
    ``aerotri run`` has no ``--min-rays``: the chain takes those seen in two frames when the three-ray ones are under
    10 a frame and the two-ray ones are not; a block with enough three-ray points keeps 3."""
    import shutil

    from aerotri.geom.eo import read_eo
    from ortho.points_dem import chain_min_rays

    p = shutil.copytree(tiny_project, tmp_path / "p", ignore=shutil.ignore_patterns("lidar", "work", "at"))
    (p / "at").mkdir()
    shutil.copy(p / "truth" / "eo.txt", p / "at" / "eo.txt")
    eo = read_eo(p / "at" / "eo.txt")
    c = eo.centre_m[:, :2].mean(axis=0)
    n = 10 * len(eo.image_id)

    def write(three: int, two: int) -> int:
        rows = ["id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px"]
        rows += [f"T{k:07d},tie,{c[0] + k % 40:.3f},{c[1] + k // 40:.3f},310.0,0.1,0.1,0.1,{3 if k < three else 2},0.1"
                 for k in range(three + two)]
        (p / "at" / "object_points.csv").write_text("\n".join(rows) + "\n")
        return chain_min_rays(p)

    assert write(14, n) == 2  # Tuniu's case
    assert write(n, n) == 3  # enough seen in three
    assert write(14, 5) == 3  # two-ray points would not help either
