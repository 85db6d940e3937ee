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
