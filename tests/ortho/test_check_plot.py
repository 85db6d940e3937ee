"""The DOM check's plot (``ortho/dom_report.png``): its histogram counts every patch the statistics take (the title's
n), its map draws at most ``MAX_LISTED`` of them and says so."""

from __future__ import annotations

import json

import matplotlib.axes
import numpy as np
from pyproj import CRS

import ortho.check
from ortho.check import run_check
from ortho.synthetic import textured_orthophoto, write_geotiff


def test_histogram_counts_every_patch_not_only_those_drawn(tmp_path, monkeypatch):
    """The 2 x 2 DMC block's dom_report.png said n=83284 over a histogram of the 20,000 patches listed (trial 8)."""
    crs = CRS.from_epsg(32649)
    img = textured_orthophoto(400, 400, 1, seed=5)[:, :, 0]
    write_geotiff(tmp_path / "ref.tif", img, 500000.0, 3000000.0, 0.2, crs)
    write_geotiff(tmp_path / "dom.tif", np.roll(img, 2, axis=0), 500000.0, 3000000.0, 0.2, crs)
    monkeypatch.setattr(ortho.check, "MAX_LISTED", 10)
    seen = {}
    hist, quiver, set_title = matplotlib.axes.Axes.hist, matplotlib.axes.Axes.quiver, matplotlib.axes.Axes.set_title

    def spy_hist(self, x, *a, **k):
        seen["hist"] = len(x)
        return hist(self, x, *a, **k)

    def spy_quiver(self, *a, **k):
        seen["quiver"] = len(a[0])
        return quiver(self, *a, **k)

    def spy_title(self, label, *a, **k):
        seen.setdefault("titles", []).append(label)
        return set_title(self, label, *a, **k)

    monkeypatch.setattr(matplotlib.axes.Axes, "hist", spy_hist)
    monkeypatch.setattr(matplotlib.axes.Axes, "quiver", spy_quiver)
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title", spy_title)
    (tmp_path / "proj").mkdir()
    rep = run_check(tmp_path / "proj", reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "dom.tif",
                    out_stem=tmp_path / "dom_report", seams=False)
    doc = json.loads((tmp_path / "dom_report.json").read_text())
    n = rep.displacement.count
    assert n == doc["patches_total"] > 20 and doc["patches_listed"] == 10
    assert seen["hist"] == n and seen["quiver"] == 10
    assert any(f"n={n}" in t for t in seen["titles"])
    assert any(f"10 of {n:,} patches drawn" in t for t in seen["titles"])
    assert (tmp_path / "dom_report.png").stat().st_size > 0
