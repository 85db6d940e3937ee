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
