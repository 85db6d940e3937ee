"""corners.png: map coordinates on the axes as they are (UTM northings of 3.4 million m), not as an offset."""

from __future__ import annotations

import numpy as np

import lidarctl.corners.roof_corners as rc


def test_corners_png_axes_read_plain_map_coordinates(tmp_path, monkeypatch):
    """The 2 x 2 DMC block's corners.png labelled its northings 3.4070 ... 3.4095 under a '1e6' (trial 8)."""
    figs = []
    monkeypatch.setattr(rc, "save_png", lambda fig, path, dpi=None: (figs.append(fig), fig.canvas.draw()))
    ndsm = np.zeros((50, 24))
    ndsm[10:20, 5:10] = 8.0
    corners = [dict(x=452100.0, y=3408000.0, usable=True), dict(x=452150.0, y=3408400.0, usable=False)]
    rc.plot_corners(tmp_path / "corners.png", ndsm, (452000.0, 453200.0, 3407000.0, 3409500.0), [], corners)
    ax = figs[0].axes[0]
    for axis in (ax.xaxis, ax.yaxis):
        assert axis.get_major_formatter().get_offset() == ""
        labels = [t.get_text().replace("\u2212", "-") for t in axis.get_ticklabels() if t.get_text()]
        assert labels and all(float(t) > 4e5 for t in labels)


def test_the_tiled_figure_s_grid_is_checked_at_its_own_cost(monkeypatch):
    """The demo's figure grid (3,240 x 2,430 cells of 0.617 m) beside the 414 MiB the process held in a 1 GiB batch
    job: refused as 721 MiB (the whole-cloud nDSM's 96 bytes a cell) although the figure added 96 MB (12 bytes a
    cell, measured); now counted at 24 bytes a cell, it fits. A grid that does not fit (16 M cells beside 414 MiB
    at 600 MiB) is still refused, naming --figure."""
    from types import SimpleNamespace

    import pytest

    from aerotri.core import limits
    from aerotri.core.errors import ResourceError
    from lidarctl.corners import roof_corners as C

    monkeypatch.setattr(limits, "_own_memory_limit", lambda: 2**30)
    monkeypatch.setattr(limits, "resident_bytes", lambda: 414 * 2**20)
    grid = SimpleNamespace(ncols=2, nrows=2, tile_m=1000.0, x0_m=0.0, y0_m=0.0)
    rec = {"core": np.zeros(1, np.uint8)}
    fig = C._figure_tile(None, rec, SimpleNamespace(grid=grid), 0, 0.617, C.FIGURE_CELLS)
    assert fig["ndsm"].shape == (3242, 3242)   # 2 km a side in cells of 0.617 m: 10.5 M cells, 252 MB counted
    grid = SimpleNamespace(ncols=8, nrows=8, tile_m=1000.0, x0_m=0.0, y0_m=0.0)  # 4000 x 4000 cells of 2 m
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: 600 * 2**20)
    with pytest.raises(ResourceError) as e:
        C._figure_tile(None, rec, SimpleNamespace(grid=grid), 0, 2.0, C.FIGURE_CELLS)
    assert e.value.param == "--figure" and "--no-figure" in str(e.value)
