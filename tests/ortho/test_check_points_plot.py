"""The DOM check at surveyed points draws a plan (trial audit F10): ``ortho check --points``' dom_report.png put the
points along x at their list index (0-9) with a squashed y axis of +-0.05, showing neither where they are nor readable
vectors. Now each point sits at its map position with its displacement vector (exaggerated by one factor, a scale
arrow in metres), the adjustment's control points drawn apart."""

from __future__ import annotations

import json

import matplotlib.axes
import numpy as np
import pytest
from pyproj import CRS

from ortho.check import run_check
from ortho.synthetic import textured_orthophoto, write_geotiff


def test_surveyed_points_are_drawn_at_their_map_positions(tmp_path, monkeypatch):
    ref = textured_orthophoto(240, 240, 1, seed=5)[:, :, 0]
    write_geotiff(tmp_path / "dom.tif", ref, 500000.0, 3000000.0, 1.0, CRS.from_epsg(32649))
    proj = tmp_path / "proj"
    (proj / "at").mkdir(parents=True)
    # P0 was the adjustment's control: drawn apart (it is no independent check of the DOM)
    (proj / "at" / "report.json").write_text(json.dumps(dict(control_points=[dict(id="p0", kind="full", used=True)])))
    xy = [(500020.0, 2999780.0), (500200.0, 2999800.0), (500100.0, 2999900.0), (500050.0, 2999950.0)]
    d_m = [(0.0, 0.0), (0.6, 0.0), (0.0, -0.3), (0.4, 0.3)]
    (tmp_path / "points.csv").write_text("id,x,y,x_dom,y_dom\n" + "".join(
        f"P{i},{x},{y},{x + de},{y + dn}\n" for i, ((x, y), (de, dn)) in enumerate(zip(xy, d_m))))
    seen = {"quiver": [], "key": []}
    quiver, quiverkey = matplotlib.axes.Axes.quiver, matplotlib.axes.Axes.quiverkey

    def spy_quiver(self, *a, **k):
        seen["quiver"].append((np.asarray(a[0], float), np.asarray(a[1], float), np.asarray(a[2], float),
                               np.asarray(a[3], float), k))
        return quiver(self, *a, **k)

    def spy_key(self, q, x, y, u, label, **k):
        seen["key"].append((u, label))
        return quiverkey(self, q, x, y, u, label, **k)

    monkeypatch.setattr(matplotlib.axes.Axes, "quiver", spy_quiver)
    monkeypatch.setattr(matplotlib.axes.Axes, "quiverkey", spy_key)
    run_check(proj, points_path=tmp_path / "points.csv", dom_path=tmp_path / "dom.tif",
              out_stem=tmp_path / "dom_report", seams=False)
    assert (tmp_path / "dom_report.png").stat().st_size > 0
    (xi, yi, ui, vi, _), (xc, yc, uc, vc, kc) = seen["quiver"]  # the check points, then the control
    assert list(zip(xi, yi)) == xy[1:] and list(zip(xc, yc)) == xy[:1]
    assert kc.get("color") == "tab:red"
    scale = ui[0] / 0.6  # one exaggeration for every vector, east right, north up
    assert scale > 1 and ui == pytest.approx(np.array([0.6, 0.0, 0.4]) * scale)
    assert vi == pytest.approx(np.array([0.0, -0.3, 0.3]) * scale)
    # the largest vector a tenth of the points' extent (180 m), the scale arrow a round length in metres
    assert 0.6 * scale == pytest.approx(18.0)
    (u, label), = seen["key"]
    assert label == "0.5 m" and u == pytest.approx(0.5 * scale)
