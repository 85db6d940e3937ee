"""Trial audit F5: under ASPRS 2023 (asked for, or chosen by the tolerance table) the verdict table judged the DEM's
measured height RMSE, 0.0998 m "pass" against V10's 0.1 m, while the compliance section judged the figure ASPRS 2023
asks for, the RMSE combined with the survey's own accuracy: sqrt(0.0998^2 + 0.01^2) = 0.1003 m "fail". The table
judges that figure now where its limit is ASPRS 2023's, and says so; a map-scale table keeps the measured one."""

from __future__ import annotations

import math

import pytest

from aerotri.qa.report import write_qa_report
from tests.aerotri.qa.test_compliance import _dem_checked_alone


def test_the_table_judges_asprs_2023s_figure_with_the_surveys_accuracy(tmp_path):
    _dem_checked_alone(tmp_path, open_dz_m=0.0998, forest_dz_m=0.0998)
    with open(tmp_path / "project.toml", "a") as f:
        f.write("[qa]\nsurvey_sigma_z_m = 0.01\n")
    rep = write_qa_report(tmp_path, standard="asprs2023", accuracy_class="H7.1 V10")
    row = rep.check("dem_raster_rmse_m")
    nva = [c for c in rep.compliance["checks"] if c["quantity"].startswith("NVA")][0]
    assert nva["measured"] == pytest.approx(0.0998) and nva["verdict"] == "fail"
    assert row.limit == 0.1 and row.value == pytest.approx(math.hypot(0.0998, 0.01), abs=1e-4)
    assert row.value == nva["figure"] and row.verdict == "fail", row
    assert "with the check points' own accuracy, ASPRS 2023" in row.quantity
    assert row.note.startswith("ASPRS 2023: measured 0.0998 m combined with the check points' own 0.0100 m "
                               "([qa] survey_sigma_xy_m / survey_sigma_z_m)"), row.note
    # a map-scale table's limit is no ASPRS 2023 limit: the measured RMSE, as before
    rep = write_qa_report(tmp_path, scale="1:5000")
    row = rep.check("dem_raster_rmse_m")
    assert row.value == pytest.approx(0.0998) and "ASPRS" not in row.note + row.quantity


def test_the_line_map_row_judges_asprs_2023s_figure_too(tmp_path):
    """The line map's building corners under an ASPRS 2023 class: the compliance section's figure (the survey's
    sqrt(2) x 0.1 m combined with the 0.3 m measured) in the table too."""
    from lidarctl.checks.vectors import check_files
    from tests.aerotri.qa.test_report import _dlg, _project

    (tmp_path / "p").mkdir()
    p = _project(tmp_path / "p", [0.1, 0.1, 0.5], 0.18)
    with open(p / "project.toml", "a") as f:
        f.write("[qa]\nsurvey_sigma_xy_m = 0.1\n")
    (p / "lidar_out").mkdir()
    check_files(_dlg(tmp_path / "dlg.gpkg", 0.0), _dlg(tmp_path / "ref.gpkg", 0.3),
                json_path=p / "lidar_out" / "vectors_check.json")
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H30 V30")
    row = rep.check("line_map_rms_xy_m")
    dlg = [c for c in rep.compliance["checks"] if c["product"] == "Line map (DLG)"][0]
    assert row.value == pytest.approx(math.hypot(0.3, math.sqrt(2) * 0.1), abs=1e-3) and row.value == dlg["figure"]
    assert row.verdict == "fail" and row.limit == 0.3 and "ASPRS 2023: measured 0.3" in row.note
