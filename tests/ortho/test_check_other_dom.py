"""review 12c: `ortho check P --dom OTHER` without --out wrote OTHER's check over P's own ortho/dom_report.json (the
accuracy report went from pass to fail "DOM check of another DOM"), and without P's ortho/mosaic.tif such a check
read as the project's. Another DOM's check now goes beside that DOM, never over the project's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner
from pyproj import CRS

from ortho.check import DomCheck, read_dom_check, run_check
from ortho.cli import main
from ortho.synthetic import textured_orthophoto, write_geotiff


def _project(tmp_path):
    crs = CRS.from_epsg(32649)
    ref = textured_orthophoto(160, 160, 1, seed=5)[:, :, 0]
    other = np.concatenate([np.repeat(ref[:, :1], 2, axis=1), ref[:, :-2]], axis=1)  # 2 m east
    p = tmp_path / "P"
    (p / "ortho").mkdir(parents=True)
    (p / "project.toml").write_text('[project]\ncrs = "EPSG:32649"\n')
    write_geotiff(tmp_path / "ref.tif", ref, 452000.0, 3408000.0, 1.0, crs)
    write_geotiff(p / "ortho" / "mosaic.tif", ref, 452000.0, 3408000.0, 1.0, crs)
    write_geotiff(tmp_path / "other.tif", other, 452000.0, 3408000.0, 1.0, crs)
    return p


def test_another_doms_check_goes_beside_it_not_over_the_projects(tmp_path):
    p = _project(tmp_path)
    own = run_check(p, reference_path=tmp_path / "ref.tif")
    assert own.json_path == str(p / "ortho" / "dom_report.json") and own.displacement.rms_xy_m < 0.05
    before = (p / "ortho" / "dom_report.json").read_bytes()
    r = CliRunner().invoke(main, ["check", str(p), "--dom", str(tmp_path / "other.tif"), "--reference",
                                  str(tmp_path / "ref.tif")])
    assert r.exit_code == 0, r.output
    assert (p / "ortho" / "dom_report.json").read_bytes() == before
    other = read_dom_check(tmp_path / "other_dom_report.json")
    assert other.of_project_mosaic is False and abs(other.displacement.mean_e_m - 2.0) < 0.05
    assert str(tmp_path / "other_dom_report.json") in r.output
    # nor with --out naming the project's own check: exit 2 naming the option, the project's check untouched
    r = CliRunner().invoke(main, ["check", str(p), "--dom", str(tmp_path / "other.tif"), "--reference",
                                  str(tmp_path / "ref.tif"), "--out", str(p / "ortho" / "dom_report")])
    assert r.exit_code == 2 and "--out" in r.output and "the project's DOM check" in r.output
    assert (p / "ortho" / "dom_report.json").read_bytes() == before


def test_a_check_of_another_dom_is_never_the_projects_even_without_a_mosaic(tmp_path):
    from aerotri.qa.compliance import dom_checks

    mosaic = tmp_path / "ortho" / "mosaic.tif"  # not there
    assert DomCheck(displacement=None, of_project_mosaic=False).stale_for(mosaic)
    assert not DomCheck(displacement=None, of_project_mosaic=True).stale_for(mosaic)
    cs = dom_checks({"displacement": {"rms_xy_m": 0.1, "count": 99}, "dom": "/x/other.tif",
                     "dom_is_project_mosaic": False}, None, stale=True)
    assert cs.rmse_h_m is None and "another DOM (/x/other.tif" in cs.note and "earlier mosaic" not in cs.note


def test_a_dom_on_a_read_only_disk_is_refused_before_the_work_pointing_to_out(tmp_path, monkeypatch):
    """Reviewer 14: `ortho check P --dom X` beside a read-only X matched every patch, then failed writing
    X_dom_report.json. Now exit 2 before the work, naming --out (os.access stands in for a read-only mount: root
    writes a chmod 555 folder)."""
    import os

    import pytest

    import ortho.check as check
    from aerotri.core.errors import OptionError

    p = _project(tmp_path)
    real_access = os.access
    monkeypatch.setattr(check.os, "access", lambda path, mode: Path(path) != tmp_path and real_access(path, mode))
    monkeypatch.setattr(check, "open_north_up", lambda *a, **k: pytest.fail("the work began"))
    with pytest.raises(OptionError, match=r"other_dom_report.json: cannot write into .* \(beside the DOM, by "
                                          r"default\): give --out") as e:
        run_check(p, reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "other.tif")
    assert e.value.param == "--out"
