"""The DOM check of a DOM in feet (trial-qa 2026-12-01): the displacements and the GSD in metres, as their ``_m`` keys
and the accuracy report take them. Autzen's 1 ft orthophoto placed 2 ft east and 1 ft north of itself read "RMS 2.236
m (2.24 GSD)" and failed the ASPRS H100 class (0.682 m on the ground); a DOM in metres is unchanged."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pyproj import CRS

from ortho.check import run_check
from ortho.synthetic import textured_orthophoto, write_geotiff

FT = 0.3048
SHIFT_PX = 3  # the DOM shows the reference's content 3 cells further east


def _pair(tmp_path, crs, res):
    ref = textured_orthophoto(240, 240, 1, seed=5)[:, :, 0]
    dom = np.concatenate([np.repeat(ref[:, :1], SHIFT_PX, axis=1), ref[:, :-SHIFT_PX]], axis=1)
    write_geotiff(tmp_path / "ref.tif", ref, 1000000.0, 800000.0, res, crs)
    write_geotiff(tmp_path / "dom.tif", dom, 1000000.0, 800000.0, res, crs)
    (tmp_path / "proj").mkdir(exist_ok=True)


@pytest.mark.parametrize("epsg, unit_m", [(2994, FT), (32610, 1.0)])  # Oregon Lambert (international feet); UTM
def test_displacements_of_a_dom_in_feet_are_metres(tmp_path, epsg, unit_m):
    _pair(tmp_path, CRS.from_epsg(epsg), 1.0)            # 1 ft (or 1 m) cells
    rep = run_check(tmp_path / "proj", reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "dom.tif",
                    out_stem=tmp_path / "dom_report")
    d = rep.displacement
    assert d.gsd_m == pytest.approx(unit_m) and d.count >= 9
    assert d.rms_xy_m == pytest.approx(SHIFT_PX * unit_m, abs=0.05 * unit_m)
    assert d.rms_xy_gsd == pytest.approx(SHIFT_PX, abs=0.05)
    doc = json.loads((tmp_path / "dom_report.json").read_text())
    assert doc["gsd_m"] == pytest.approx(unit_m)
    assert np.median([p["de_m"] for p in doc["patches"]]) == pytest.approx(SHIFT_PX * unit_m, abs=0.05 * unit_m)


def test_surveyed_points_in_a_dom_in_feet_give_metres(tmp_path):
    _pair(tmp_path, CRS.from_epsg(2994), 1.0)
    # measured 2 ft east and 1 ft north of where they were surveyed: sqrt(5) ft = 0.6816 m
    rows = [f"P{i},{1000050.0 + 10 * i},{799950.0},{1000052.0 + 10 * i},{799951.0}" for i in range(5)]
    (tmp_path / "points.csv").write_text("id,x,y,x_dom,y_dom\n" + "\n".join(rows) + "\n")
    rep = run_check(tmp_path / "proj", points_path=tmp_path / "points.csv", dom_path=tmp_path / "dom.tif",
                    out_stem=tmp_path / "dom_report")
    assert rep.displacement.rms_xy_m == pytest.approx(math.sqrt(5.0) * FT, abs=1e-9)
    assert rep.displacement.rms_xy_gsd == pytest.approx(math.sqrt(5.0), abs=1e-9)


def test_roof_outlines_of_an_ndsm_in_feet_are_measured_in_square_metres(tmp_path):
    """roof_corners_from_ndsm's smallest building (50 m2) was compared with areas in square feet: a 10 x 10 ft shed
    (9.3 m2) counted as a building in an nDSM in feet."""
    from ortho.check import roof_corners_from_ndsm

    z = np.zeros((200, 200), np.float32)
    z[20:30, 20:30] = 10.0            # 10 x 10 ft, 10 ft high: a shed, 9.3 m2
    z[100:140, 100:140] = 20.0        # 40 x 40 ft: 149 m2, a building
    crs = CRS.from_epsg(2994)
    write_geotiff(tmp_path / "ndsm.tif", z, 1000000.0, 800000.0, 1.0, crs)
    xs, ys = roof_corners_from_ndsm(tmp_path / "ndsm.tif", (1000000.0, 799800.0, 1000200.0, 800000.0), crs)
    assert len(xs) == 4 and (xs > 1000090.0).all() and (ys < 799910.0).all()   # the building's corners only


@pytest.mark.parametrize("epsg, kind", [(4326, "geographic"), (4978, "geocentric")])
def test_a_dom_whose_crs_has_no_map_length_unit_is_refused(tmp_path, epsg, kind):
    """Reviewer 8: a DOM in degrees was read as metres ("RMS 0.000 m", exit 0): now refused, naming the file, its CRS
    and what is expected, nothing written."""
    from aerotri.core.errors import CrsError

    ref = textured_orthophoto(40, 40, 1, seed=5)[:, :, 0]
    write_geotiff(tmp_path / "dom.tif", ref, 114.0, 23.01, 1e-5, CRS.from_epsg(epsg))
    (tmp_path / "proj").mkdir()
    (tmp_path / "points.csv").write_text("id,x,y,x_dom,y_dom\nP1,114.0001,23.0099,114.00011,23.00991\n")
    with pytest.raises(CrsError, match=f"dom.tif: the DOM's CRS: EPSG:{epsg} .* is {kind}; expected a projected or "
                                        "local CRS whose axes are in metres or feet"):
        run_check(tmp_path / "proj", points_path=tmp_path / "points.csv", dom_path=tmp_path / "dom.tif",
                  out_stem=tmp_path / "dom_report")
    assert not list(tmp_path.glob("dom_report*"))
