"""Roof corners of several classified strips by tiles (lidarctl.corners.roof_corners.find_roof_corners_tiled) against
the whole cloud (find_roof_corners of the concatenated strips): every roof found once, the same corners
CSV, roof planes and outlines."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from lidarctl.corners import roof_corners as C
from lidarctl.cli.main import main


def _strips(tiny_project):
    files = sorted((tiny_project / "truth" / "lidar").glob("strip_*.la[sz]"))
    assert len(files) > 1
    return files


def test_tiled_corners_equal_whole_cloud(tiny_project, tmp_path):
    files = _strips(tiny_project)
    cat = C.read_strips(files)
    whole = C.find_roof_corners(cat.x, cat.y, cat.z, cat.classification, cat.point_source_id,
                                roof="any")
    # 150 m tiles with a 100 m buffer: the ~515 m x 830 m block in 4 x 6 tiles, roofs cut by tile edges
    # small chunks: the files and the building points kept aside for the spacing are read in pieces
    tiled, crs, units, figure = C.find_roof_corners_tiled(files, tile_m=150.0, buffer_m=100.0, roof="any",
                                                          work_dir=tmp_path, figure_cells=500, chunk_points=30_000)
    assert tiled.stats.tiles >= 12
    assert not list(tmp_path.iterdir())                                    # temporary tiles removed
    assert len(whole.corners) > 20
    assert C.corners_csv_text(tiled.corners) == C.corners_csv_text(whole.corners)
    for k in ("n_points", "n_building_points", "point_spacing_m", "n_roofs", "n_outlines", "n_corners_traced",
              "n_usable", "n_roof_planes", "n_outlined_points"):
        assert getattr(tiled.stats, k) == getattr(whole.stats, k), k
    planes = [C.roof_planes_geojson(C._faces_in_crs_units(r.faces, units), None,
                                    sigma_strip_xy_m=r.stats.sigma_strip_xy_m, sigma_strip_z_m=r.stats.sigma_strip_z_m)
              for r in (whole, tiled)]
    assert planes[0] == planes[1]
    for a, b in zip(whole.outlines, tiled.outlines):
        assert a["building_id"] == b["building_id"] and len(a["rings"]) == len(b["rings"])
        for ra, rb in zip(a["rings"], b["rings"]):
            np.testing.assert_array_equal(ra, rb)
    # strip margins: a tile sees a strip's footprint only within its buffer (clipped, and a gap that reaches
    # past the buffer is not filled as a hole), so its margin is a lower bound of the whole cloud's; equal
    # where the score looks (10 m)
    for a, b in zip(whole.corners, tiled.corners):
        assert (a["strip_margin_m"] >= 10.0) == (b["strip_margin_m"] >= 10.0)
        assert b["strip_margin_m"] <= a["strip_margin_m"]
    assert sum(a["strip_margin_m"] == b["strip_margin_m"] for a, b in zip(whole.corners, tiled.corners)) > 0
    ndsm, extent = figure
    assert ndsm.shape[1] <= 500 and np.nanmax(ndsm) > 5.0                 # roofs stand out in the figure
    # the figure ends where the points end, not with the whole tiles (no empty margins)
    cell = (extent[1] - extent[0]) / ndsm.shape[1]
    assert extent[0] >= cat.x.min() - cell and extent[1] <= cat.x.max() + cell
    assert extent[2] >= cat.y.min() - cell and extent[3] <= cat.y.max() + cell
    assert all(np.isfinite(edge).any() for edge in (ndsm[0], ndsm[-1], ndsm[:, 0], ndsm[:, -1]))


def test_corners_cli_tiles_options(tiny_project, tmp_path):
    files = [str(f) for f in _strips(tiny_project)]
    out = tmp_path / "c"
    r = CliRunner().invoke(main, ["corners", *files, str(out), "--tile-m", "100", "--buffer-m", "150"])
    assert r.exit_code == 2 and "--buffer-m" in r.output and "larger than the tile size" in r.output
    # the tiny block's sparse roofs give no corner usable as control: exit 2, nothing written
    r = CliRunner().invoke(main, ["corners", *files, str(out), "--tile-m", "300", "--buffer-m", "100", "--roof", "any"])
    assert r.exit_code == 2 and "no usable roof corner" in r.output, r.output
    assert not out.exists() or not list(out.iterdir())
