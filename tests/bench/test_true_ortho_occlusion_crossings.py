"""bench/eval_true_ortho_occlusion.py's per-roof seam measure (``crossings_by_roof``) on a constructed grid: a roof one
frame covers whole is counted as one a seam could have gone round, a roof the frames' edges cut as one no choice of
frames keeps whole, and a roof the DOM's nodata cuts in two is still one roof."""

from __future__ import annotations

import numpy as np

BENCH_SCRIPT = "eval_true_ortho_occlusion.py"

H, W = 20, 30


def test_a_roof_is_avoidable_only_where_one_frame_covers_all_its_cells_in_the_dom(bench_script):
    # frame a covers columns 0-17, frame b columns 12-29 (masks placed at their first row and column)
    masks = [("a", 0, 0, np.ones((H, 18), bool)), ("b", 0, 12, np.ones((H, 18), bool))]
    roof = np.zeros((H, W), bool)
    roof[2:6, 13:17] = True     # inside both frames: either could take it whole
    roof[10:14, 8:22] = True    # from column 8 (a only) to 21 (b only): no frame holds it whole
    dom_valid = np.ones((H, W), bool)
    dom_valid[2:6, 15] = False  # the DOM's nodata cuts the first roof in two: still one roof
    on_roof = np.zeros((H, W), bool)
    on_roof[2:6, 14] = True     # a seam down column 14 across both roofs
    on_roof[10:14, 14] = True
    got = bench_script.crossings_by_roof(on_roof, roof, dom_valid, masks)
    assert got["roofs_crossed"] == 2 and got["roofs_crossed_that_one_frame_covers_whole"] == 1
    assert got["roof_cells_crossed_on_roofs_one_frame_covers_whole"] == 4
    assert got["roof_cells_crossed_on_roofs_no_frame_covers_whole"] == 4
    small, wide = sorted(got["roofs_crossed_detail"], key=lambda r: r["roof_cells"])
    assert small == {"roof_cells": 12, "seam_cells": 4, "frames_covering_it_whole": 2, "rows_cols": [2, 5, 13, 16]}
    assert wide["frames_covering_it_whole"] == 0 and wide["rows_cols"] == [10, 13, 8, 21]


def test_roof_nodata_is_counted_by_depth_inside_the_roof(bench_script):
    """``roof_nodata_by_depth``: a 12 x 12 cell roof at 0.4 m, its outer ring of cells nodata; the cells at up to 1 m
    from the outline (the two outer rings: centres 0.4, 0.8 m) hold every nodata cell, the roof's inside none; a
    roof outside every footprint is not counted."""
    roof = np.zeros((H, W), bool)
    roof[4:16, 4:16] = True
    roof[4:8, 24:28] = True          # outside the footprints
    covered = np.zeros((H, W), bool)
    covered[:, :20] = True
    dom_valid = np.ones((H, W), bool)
    dom_valid[4:16, 4:16] = False
    dom_valid[5:15, 5:15] = True     # the outer ring nodata
    got = bench_script.roof_nodata_by_depth(roof, covered, dom_valid, 0.4)
    ring = 12 * 4 - 4
    assert got["0-1m"]["nodata"] == ring and got["1-2m"]["nodata"] == 0 and got["2-infm"]["nodata"] == 0
    assert sum(b["cells"] for b in got.values()) == 144
    assert got["0-1m"]["nodata_share"] == ring / got["0-1m"]["cells"]


def test_the_truth_takes_a_contract_crs_grid_s_cells_to_the_project_crs(bench_script):
    """``Truth.local_xy``: a grid in the project CRS gives its cell centres less the scene's origin, as before; a
    grid in CGCS2000 3-degree Gauss-Krueger (EPSG:4546, ``ortho rectify --crs gk3:cgcs2000``) gives each cell centre
    taken to UTM 49N by PROJ (known points: a UTM point taken to EPSG:4546 and back lands within a millimetre)."""
    from pyproj import CRS, Transformer

    from ortho.grid import OrthoGrid

    truth = bench_script.Truth.__new__(bench_script.Truth)
    truth.crs, truth.origin = CRS.from_epsg(32649), np.array([500_000.0, 2_500_000.0, 100.0])
    utm = OrthoGrid(truth.crs, 500_100.0, 2_500_900.0, 0.4, 30, 20)
    x, y = truth.local_xy(utm, np.array([0, 19]), np.array([0, 29]))
    assert np.allclose(x, [100.2, 111.8]) and np.allclose(y, [899.8, 892.2])
    e, n = Transformer.from_crs(truth.crs, "EPSG:4546", always_xy=True).transform(500_300.0, 2_500_600.0)
    gk = OrthoGrid(CRS.from_epsg(4546), e - 0.2, n + 0.2, 0.4, 30, 20)  # cell (0, 0) centred on that point
    x, y = truth.local_xy(gk, np.array([0]), np.array([0]))
    assert abs(x[0] - 300.0) < 1e-3 and abs(y[0] - 600.0) < 1e-3
    assert abs(n - 2_500_600.0) > 100  # the grids differ there (UTM's scale 0.9996): the test is not the identity
