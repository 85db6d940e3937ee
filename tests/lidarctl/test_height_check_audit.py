"""What a QA auditor's trial (trial-audit F2, F4, F9, F12) found in the LiDAR height check: metres under a feet CRS
read as feet without a word, P00 and p00 counted as two check points, dz on a bin's edge counted on one side for +0.5
and the other for -0.5, and a DEM-only height_check.json whose top-level overall was null."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin

from aerotri.core.errors import InputError
from lidarctl.checks.heights import check_heights_file, read_height_check, read_points_csv
from lidarctl.cli.main import main

X0, Y0 = 4000000.0, 800000.0


def _flat_dem(path, crs: str, z: float, tags: dict | None = None):
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", driver="GTiff", width=60, height=60, count=1, dtype="float64", crs=crs,
                       transform=from_origin(X0, Y0, 3.0, 3.0), nodata=-9999) as d:
        d.write(np.full((60, 60), z), 1)
        if tags:
            d.update_tags(**tags)
    return path


def _points(path, dz_m, z_surface: float, z_factor: float = 1.0, ids=None):
    """Surveyed points under a flat surface at ``z_surface``: dz = surface - survey = ``dz_m`` (metres), heights
    written in metres times ``z_factor``."""
    ids = ids or [f"P{k:02d}" for k in range(len(dz_m))]
    rows = [f"{i},{X0 + 10 + (k % 7) * 20.5},{Y0 - 10 - (k // 7) * 20.5},{(z_surface - d) * z_factor:.6f},open"
            for k, (i, d) in enumerate(zip(ids, dz_m))]
    path.write_text("id,x,y,z,group\n" + "\n".join(rows) + "\n")
    return path


def _run(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_dem_heights_in_metres_under_a_feet_crs_are_said_and_can_be_stated(tmp_path):
    """F2: EPSG:2994 (international feet), heights in metres, no vertical CRS nor VERTICAL_UNITS: the heights were
    read as feet (RMSE 0.046 m, "meets QL0") without a word; the true 0.150 m fails QL2."""
    from aerotri.qa.report import write_qa_report

    dem = _flat_dem(tmp_path / "lidar_out" / "dem.tif", "EPSG:2994", 100.0)
    pts = _points(tmp_path / "points.csv", [0.15, -0.15] * 17 + [0.15], 100.0)
    (tmp_path / "project.toml").write_text('[project]\nname = "feet"\ncrs = "EPSG:2994"\nheights = "ellipsoidal"\n')
    hc_json = tmp_path / "lidar_out" / "height_check.json"
    r = _run(["check-heights", pts, "--dem", dem, "--json", hc_json])
    assert r.exit_code == 0, r.output
    said = [ln for ln in r.output.splitlines() if ln.startswith("warning:")]
    assert len(said) == 1 and str(dem) in said[0] and "declares no vertical unit" in said[0]
    assert "international feet (0.3048 m)" in said[0] and "--dem-z-unit" in said[0]
    doc = json.loads(hc_json.read_text())
    assert "international feet" in doc["dem"]["z_unit_note"]
    assert doc["dem"]["overall"]["all"]["rmse_m"] == pytest.approx(0.15 * 0.3048, abs=1e-4)  # the assumption
    row = write_qa_report(tmp_path, standard="usgs-lbs", accuracy_class="QL2").check("dem_raster_rmse_m")
    assert "declares no vertical unit" in row.note and "--dem-z-unit" in row.note
    # stated: the true figure, and the note says where the unit came from
    r = _run(["check-heights", pts, "--dem", dem, "--dem-z-unit", "m", "--json", hc_json])
    assert r.exit_code == 0 and "warning:" not in r.output, r.output
    doc = json.loads(hc_json.read_text())
    assert doc["dem"]["overall"]["all"]["rmse_m"] == pytest.approx(0.15, abs=1e-6)
    assert doc["dem"]["z_unit_m"] == 1.0 and "--dem-z-unit m" in doc["dem"]["z_unit_note"]
    rep = write_qa_report(tmp_path, standard="usgs-lbs", accuracy_class="QL2")
    assert rep.check("dem_raster_rmse_m").verdict == "fail"


def test_dem_height_unit_declared_by_the_file_takes_no_note_and_refuses_another(tmp_path):
    dem = _flat_dem(tmp_path / "dem.tif", "EPSG:2994", 100.0, tags={"VERTICAL_UNITS": "metre"})
    pts = _points(tmp_path / "points.csv", [0.15, -0.15], 100.0)
    check = check_heights_file(None, pts, dem_path=dem)
    assert check.document["dem"]["z_unit_note"] is None
    assert check.document["dem"]["overall"]["all"]["rmse_m"] == pytest.approx(0.15, abs=1e-6)
    r = _run(["check-heights", pts, "--dem", dem, "--dem-z-unit", "ft"])
    assert r.exit_code == 2 and "--dem-z-unit ft" in r.output and "declares its heights in metres" in r.output
    # metres under a metric CRS without a tag: said briefly, not as a warning
    metric = _flat_dem(tmp_path / "m.tif", "EPSG:32610", 100.0)
    r = _run(["check-heights", _points(tmp_path / "pm.csv", [0.1], 100.0), "--dem", metric])
    assert r.exit_code == 0 and "declares no vertical unit: heights taken in metres" in r.output
    assert "warning:" not in r.output
    check = check_heights_file(None, tmp_path / "pm.csv", dem_path=metric)
    assert check.document["dem"]["z_unit_note"] and not check.document["dem"]["z_unit_consequential"]
    assert check.record.dem_z_unit_note is None   # the report's row keeps to what changes a figure


def test_a_point_id_again_in_another_case_or_with_leading_zeros_is_refused(tmp_path):
    """F4: P00 and p00 (same coordinates) were read as 30 points and met ASPRS 2023's minimum of 30 with 29."""
    from ortho.check import read_points_csv as read_dom_points

    pts = _points(tmp_path / "p.csv", [0.1, 0.1, 0.1], 100.0, ids=["P00", "007", "p00"])
    with pytest.raises(InputError, match=r"p\.csv: line 4: point 'p00' again \(first on line 2 as 'P00'; ids match "
                                         "without case"):
        read_points_csv(pts)
    pts = _points(tmp_path / "n.csv", [0.1, 0.1], 100.0, ids=["007", "7"])
    with pytest.raises(InputError, match=r"point '7' again \(first on line 2 as '007';"):
        read_points_csv(pts)
    dem = _flat_dem(tmp_path / "dem.tif", "EPSG:32610", 100.0)
    r = _run(["check-heights", tmp_path / "p.csv", "--dem", dem])
    assert r.exit_code == 2 and "point 'p00' again (first on line 2 as 'P00'" in r.output
    dom = tmp_path / "dom.csv"
    dom.write_text("id,x,y,x_dom,y_dom\nGCP01,10,20,10.1,20\nB2,50,20,50,20\ngcp01,30,20,30,20.1\n")
    with pytest.raises(InputError, match=r"dom\.csv:4: point 'gcp01' again \(first on line 2 as 'GCP01';"):
        read_dom_points(dom)


def test_two_ids_at_one_place_are_warned_of(tmp_path, caplog):
    pts = tmp_path / "p.csv"
    pts.write_text("id,x,y,z\nA1,100.0,200.0,5\nB7,300.0,200.0,5\nZ9,100.0004,199.9996,5\n")
    with caplog.at_level("WARNING"):
        assert len(read_points_csv(pts)) == 3   # still read: two marks may stand that close
    said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(said) == 1 and "'A1' (line 2) and 'Z9' (line 4) stand at the same x, y" in said[0]


def test_dz_on_a_bin_edge_is_counted_as_printed_nearer_zero(tmp_path):
    """F9: +0.5 was counted in "0.5 .. 1" but -0.5 in "-0.5 .. 0.5", 5.0 in "> 5", |dz| 1.000 in "> 1", and a typed
    0.3 (0.29999999999999716 after the subtraction) printed "+0.300" but counted "< 0.3"."""
    dz = [0.5, -0.5, 1.0, -1.0, 0.3, -0.3, 1.5, 2.0, 5.0, -5.0, 0.25, 0.0]
    dem = _flat_dem(tmp_path / "dem.tif", "EPSG:32610", 100.0)
    doc = check_heights_file(None, _points(tmp_path / "p.csv", dz, 100.0), dem_path=dem).document["dem"]["overall"]
    bins = {b["bin_m"]: b["count"] for b in doc["bins"]}
    assert bins == {"dz < -1": 1, "-1 <= dz < -0.5": 1, "-0.5 <= dz <= 0.5": 6, "0.5 < dz <= 1": 1,
                    "1 < dz <= 1.5": 1, "1.5 < dz <= 2": 1, "2 < dz <= 5": 1, "dz > 5": 0}
    abs_bins = {b["abs_dz_m"]: b["count"] for b in doc["abs_bins"]}
    assert abs_bins == {"|dz| <= 0.3": 4, "0.3 < |dz| <= 0.5": 2, "0.5 < |dz| <= 1": 2, "|dz| > 1": 4}
    assert doc["without_excluded"]["n"] == 8   # |dz| 1.000 is within "without |dz| > 1 m"


def test_a_dem_checked_alone_fills_the_top_level_overall(tmp_path):
    """F12: height_check.json of check-heights --dem without a cloud had overall null and groups {}, the figures
    under dem.overall only; the report reads it as a DEM check still (no cloud row)."""
    dem = _flat_dem(tmp_path / "dem.tif", "EPSG:32610", 100.0)
    check = check_heights_file(None, _points(tmp_path / "p.csv", [0.1, -0.1, 0.2], 100.0), dem_path=dem)
    doc = check.document
    assert doc["overall_surface"] == "dem" and doc["overall"] == doc["dem"]["overall"]
    assert doc["overall"]["all"]["rmse_m"] == pytest.approx(np.sqrt((0.01 + 0.01 + 0.04) / 3))
    assert doc["groups"] == doc["dem"]["groups"] and list(doc["groups"]) == ["open"]
    (tmp_path / "hc.json").write_text(check.to_json())
    rec = read_height_check(tmp_path / "hc.json")
    assert rec.n_checked is None and rec.rmse_m is None and rec.groups == {} and rec.dem_n_checked == 3
    assert "LiDAR height check (dz = Z_lidar" not in _run(["check-heights", tmp_path / "p.csv", "--dem", dem]).output


def test_a_constant_offset_is_said_and_the_columns_stay_apart(tmp_path):
    """Trial s94: a normalised cloud's heights against elevations, RMSE 2149.993 m on every point and no word of
    why; the table's large dz ran into the next column ("2149.9932149.993", "dz (m)dz (us-ft)")."""
    dem = _flat_dem(tmp_path / "dem.tif", "EPSG:32610", 0.1)
    pts = _points(tmp_path / "p.csv", [-2149.99, -2150.0, -2149.98, -2150.01], 0.1)
    r = _run(["check-heights", pts, "--dem", dem])
    assert r.exit_code == 0, r.output
    assert "nearly constant -2149.995 m on the 4 points checked" in r.output and "geoid" in r.output
    assert "2149.995 2149.995" in " ".join(r.output.split())  # mean |dz| and RMSE apart
    row = next(line for line in r.output.splitlines() if line.startswith("P00"))
    assert row.split()[-2:] == ["0.100", "-2149.990"]
    doc = check_heights_file(None, pts, dem_path=dem).document
    assert doc["constant_offset"]["median_dz_m"] == pytest.approx(-2149.995)
    # an error that varies from point to point is not an offset, nor a small common one
    for dz in ([-12.0, 3.0, -20.0, 8.0], [0.3, 0.31, 0.29, 0.3]):
        doc = check_heights_file(None, _points(tmp_path / "q.csv", dz, 0.1), dem_path=dem).document
        assert "constant_offset" not in doc


def test_points_mostly_off_the_dem_are_said_before_a_height_offset(tmp_path):
    """Trial s96 F7: check points in a Gauss-Kruger zone on a UTM DEM, 24 of 30 off it; the 6 that fell on it read
    as "two height systems" (RMSE 97.7 m). Points mostly off the DEM now suggest another CRS, zone or grid first;
    a few off it (edge points) say nothing of it."""
    dem = _flat_dem(tmp_path / "dem.tif", "EPSG:32610", 100.0)
    pts = _points(tmp_path / "p.csv", [0.05] * 10, 100.0)
    lines = pts.read_text().splitlines()
    far = [",".join([f.split(",")[0], str(float(f.split(",")[1]) + 5000.0), *f.split(",")[2:]]) for f in lines[4:]]
    pts.write_text("\n".join(lines[:4] + far) + "\n")   # 7 of the 10 points 5 km east, off the DEM
    r = _run(["check-heights", pts, "--dem", dem])
    assert r.exit_code == 0, r.output
    assert "7 of 10 points lie off the DEM" in r.output and "another CRS, zone or grid" in r.output
    r = _run(["check-heights", _points(tmp_path / "q.csv", [0.05] * 10, 100.0), "--dem", dem])
    assert "lie off the DEM" not in r.output


@pytest.mark.parametrize("scale, unit, z", [(1 / 0.3048, "feet", 310.0), (100.0, "centimetres", 45.0)])
def test_a_dem_in_another_height_unit_is_named_so_not_a_datum(tmp_path, scale, unit, z):
    """trial s99 lidmut M2: a DEM of feet on a metric grid (no tag) read "a nearly constant +707 m: two height systems
    (the geoid)"; an integer DEM in centimetres gave RMSE 1,821 m with no word. The unit that fits is named."""
    dem = _flat_dem(tmp_path / "dem.tif", "EPSG:32633", z * scale)
    pts = _points(tmp_path / "p.csv", [0.02, -0.01, 0.03, 0.0, -0.02], z)
    r = _run(["check-heights", pts, "--dem", dem])
    assert r.exit_code == 0, r.output
    assert f"if the DEM's heights were {unit}" in r.output and "its height unit is wrong, not the datum" in r.output
    assert "two height systems" not in r.output
    # a datum's offset stays one
    dem2 = _flat_dem(tmp_path / "dem2.tif", "EPSG:32633", z + 31.5)
    r = _run(["check-heights", pts, "--dem", dem2])
    assert "two height systems" in r.output and "height unit is wrong" not in r.output


def test_a_semicolon_table_is_named_so(tmp_path):
    """trial s99 lidmut L4: "no 'x' column in header ['id;x;y;z']" did not name the separator."""
    (tmp_path / "p.csv").write_text("id;x;y;z\nP1;4000010,5;799990,0;310,2\n")
    with pytest.raises(InputError, match="separated by semicolons; expected commas"):
        read_points_csv(tmp_path / "p.csv")
