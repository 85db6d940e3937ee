"""lidarctl strips check on the AHN3 Delft crop (4 strips by point_source_id; real data)."""

from __future__ import annotations

import pytest

from lidarctl.strips.check import analyse
from lidarctl.strips.overlap import SurfaceSettings, read_strip_planes


@pytest.mark.realdata
def test_ahn3_strip_differences_close_around_the_triangle(shared_data):
    path = shared_data / "ahn3_delft" / "ahn3_cropped_1.laz"
    params = SurfaceSettings()
    res = analyse(read_strip_planes([path], params, crs="EPSG:28992"), params, [path])
    s = res.summary
    # about 12 single returns per cell at the strips' own density (5-7 points per m^2 each); the file's header
    # density (~15 per m^2, the overlaps counted twice) made it 1.0 m before trial-strips
    assert s.cell_m == 1.5
    pairs = {(p.a, p.b): p.diff for p in s.pairs}
    # psid57140 holds 50 points at the crop's edge: no smooth cell in common with anyone
    assert set(pairs) == {("psid44266", "psid57138"), ("psid44266", "psid57139"), ("psid57138", "psid57139")}
    for p in pairs.values():
        assert p.n_cells > 300 and p.nmad_m < 0.015 and abs(p.mean_m) < 0.05
    # differences of three strips must add up: (c - a) = (b - a) + (c - b), up to the cells they are measured on
    ab = pairs[("psid44266", "psid57138")].median_m
    bc = pairs[("psid57138", "psid57139")].median_m
    ac = pairs[("psid44266", "psid57139")].median_m
    assert ac == pytest.approx(ab + bc, abs=0.01)
