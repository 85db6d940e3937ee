"""dom_report.json read back as a typed record (ortho.check.read_dom_check): the displacements as
``displacement_statistics`` gave them (written as ``run_check`` writes them), the seam figures, and one InputError
naming the file otherwise."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aerotri.core.errors import InputError
from aerotri.core.records import to_record
from ortho.check import displacement_statistics, read_dom_check


def test_the_record_gives_back_what_was_written(tmp_path):
    rng = np.random.default_rng(4)
    stats = displacement_statistics(rng.normal(0, 0.1, 200), rng.normal(0, 0.1, 200), 0.2)
    path = tmp_path / "dom_report.json"
    doc = to_record(stats, drop_none=True)
    path.write_text(json.dumps({"displacement": doc, "seams": {"rms_px": 0.49, "patches": 17, "per_seam": []}}))
    r = read_dom_check(path)
    assert r.displacement.count == 200 and r.displacement.rms_xy_m == stats.rms_xy_m
    assert r.displacement == stats  # every figure and bin as computed
    assert r.seams_rms_px == 0.49 and r.seam_patches == 17
    # keys, order, values and types (the bins a list) as the file holds them
    assert to_record(r.displacement, drop_none=True) == json.loads(path.read_text())["displacement"]
    assert json.dumps(to_record(r.displacement, drop_none=True)) == json.dumps(doc)
    assert list(doc)[:3] == ["count", "gsd_m", "rms_e_m"] and isinstance(doc["distribution_gsd"], list)
    path.write_text(json.dumps({"displacement": to_record(displacement_statistics([], [], 0.2), drop_none=True)}))
    r = read_dom_check(path)
    assert to_record(r.displacement, drop_none=True) == {"count": 0} and r.seams_rms_px is None


@pytest.mark.parametrize("text, words", [("[]", "a JSON array, expected an object"), ("{}", "KeyError 'displacement'"),
                                         ('{"displacement": {"count": 1, "rms": 2}}', "TypeError")])
def test_what_is_not_a_dom_check_names_the_file(tmp_path, text, words):
    path = tmp_path / "dom_report.json"
    path.write_text(text)
    with pytest.raises(InputError, match=rf"dom_report.json: not a DOM check \(dom_report.json\)") as e:
        read_dom_check(path)
    assert words in str(e.value) and str(e.value).startswith(str(path))
