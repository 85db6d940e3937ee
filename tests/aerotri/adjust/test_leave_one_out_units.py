"""Leave-one-out figures are metres in a feet project (trial-api F1): the same block adjusted in UTM metres and in
UTM US survey feet gave a leave-one-out plan RMS of 0.4634 m and "1.5204 m" (feet), and the QA report showed the
latter under "m"."""

from __future__ import annotations

import json
import math

import pytest

from aerotri.adjust.leave_one_out import ControlScatter, LeaveOneOut, LeftOutPoint, _record, read_leave_one_out

US_FT = 1200 / 3937
FEET_CRS = "+proj=utm +zone=49 +datum=WGS84 +units=us-ft +no_defs +type=crs"


def _loo(unit, crs):
    nan3 = (math.nan,) * 3
    pts = (LeftOutPoint("a", "full", 2, (100.0, 200.0, 50.0), (103.0, 196.0, 52.0), nan3, 1.0, (unit,) * 3),
           LeftOutPoint("b", "full", 3, (400.0, 200.0, 50.0), (400.0, 200.0, 50.0), nan3, 1.0, (unit,) * 3))
    return LeaveOneOut(pts, ControlScatter(2, 0.1, 0.2, {}), 1.0, crs=crs)


def test_the_differences_of_a_feet_project_are_metres(tmp_path):
    loo = _loo(US_FT, FEET_CRS)
    # 3 ft east, 4 ft south, 2 ft up at one of two points
    assert loo.rms_xy_m == pytest.approx(5 * US_FT / math.sqrt(2))
    assert loo.points[0].d_m == pytest.approx([3 * US_FT, -4 * US_FT, 2 * US_FT])
    path = tmp_path / "leave_one_out.json"
    path.write_text(json.dumps(_record(loo)))
    rec = json.loads(path.read_text())
    assert rec["crs"] == FEET_CRS and rec["points"][0]["given"] == [100.0, 200.0, 50.0]
    assert rec["points"][0]["dx_m"] == pytest.approx(3 * US_FT, abs=1e-4)
    assert read_leave_one_out(path).rms_xy_m == pytest.approx(5 * US_FT / math.sqrt(2), abs=1e-4)


def test_an_older_record_takes_the_unit_of_the_adjustment_beside_it(tmp_path):
    # written before the record stated its CRS: its "_m" figures were the CRS's units
    rec = _record(_loo(1.0, None))
    del rec["crs"]
    (tmp_path / "leave_one_out.json").write_text(json.dumps(rec))
    (tmp_path / "report.json").write_text(json.dumps({"crs": FEET_CRS}))
    assert read_leave_one_out(tmp_path / "leave_one_out.json").rms_xy_m == pytest.approx(
        5 * US_FT / math.sqrt(2), abs=1e-4)


def test_a_height_only_point_is_checked_in_height_alone_and_the_height_rms_is_said():
    """trial s102 txt M2/M3: a height-only point printed plan differences (0.396 m, read against the plan limit) and
    the section of report.txt had no height RMS."""
    nan3 = (math.nan,) * 3
    pts = (LeftOutPoint("a", "full", 2, (100.0, 200.0, 50.0), (103.0, 196.0, 52.0), nan3, 1.0),
           LeftOutPoint("h", "height", 3, (400.0, 200.0, 50.0), (400.3, 199.6, 49.0), nan3, 1.0),
           LeftOutPoint("p", "horizontal", 2, (700.0, 200.0, 0.0), (700.0, 201.0, 9.0), nan3, 1.0))
    loo = LeaveOneOut(pts, ControlScatter(3, 0.1, 0.1 * math.sqrt(3), {}), 1.0, crs="EPSG:32649")
    rows = {ln.split()[0]: ln.split() for ln in loo.table().splitlines()[1:4]}
    assert rows["h"][3:6] == ["-", "-", "-"] and rows["h"][6] == "-1.000"
    assert rows["p"][3:6] == ["0.000", "1.000", "1.000"] and rows["p"][6] == "-"
    # plan over a and p, height over a and h
    assert loo.rms_xy_m == pytest.approx(math.sqrt((25 + 1) / 2))
    lines = loo.table().splitlines()
    assert f"leave-one-out plan RMS {math.sqrt(13):.3f} m over 2 points" in lines[-2]
    assert "plan RMS 0.100 m x sqrt(n / (n - 2))" in lines[-2]
    assert lines[-1] == f"leave-one-out height RMS {math.sqrt((4 + 1) / 2):.3f} m over 2 points"
    rec = _record(loo)["points"]
    assert rec[1]["dx_m"] is None and rec[1]["dxy_m"] is None and rec[1]["dz_m"] == -1.0
    assert rec[2]["dz_m"] is None and rec[2]["dxy_m"] == 1.0
