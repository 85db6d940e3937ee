"""The adjustment in a feet CRS: the same block in metres and in feet (coordinates / 0.3048, the sigmas and limits in
metres as everywhere) gives the same adjustment, the same report verdict and the same accuracy-report rows. Before,
the control sigmas (metres) went into the adjustment as feet (the control held 3.3 x too tightly: gcp01's height
residual 0.016 ft = 0.005 m against 0.045 m in metres), and the residuals (feet) were judged against the tolerance
tables' metre limits (check plan RMS 0.366 "m" > 0.140 m, in metres 0.117 m)."""

from __future__ import annotations

import json
import logging
import re
import shutil

import numpy as np
import pytest

from aerotri.adjust import report
from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
from aerotri.adjust.report_record import map_unit_m, read_adjustment_report
from aerotri.core.errors import CrsError
from aerotri.core.records import to_record
from aerotri.qa.report import build_qa_report
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

FT = 0.3048
FT_CRS = "+proj=utm +zone=49 +datum=WGS84 +units=ft +vunits=ft +no_defs +type=crs"


def _to_feet(src, dst):
    """A copy of a UTM 49N (EPSG:32649) project in the same projection in international feet."""
    shutil.copytree(src, dst)
    toml = (dst / "project.toml").read_text()
    assert 'crs = "EPSG:32649"' in toml
    (dst / "project.toml").write_text(toml.replace('crs = "EPSG:32649"', f'crs = "{FT_CRS}"'))
    lines = (dst / "gnss.txt").read_text().splitlines()
    out = [lines[0]] + [" ".join([p[0]] + [f"{float(v) / FT:.5f}" for v in p[1:4]] + p[4:])
                        for p in (ln.split() for ln in lines[1:] if ln.strip())]
    (dst / "gnss.txt").write_text("\n".join(out) + "\n")
    lines = (dst / "control" / "points.csv").read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        p = ln.split(",")
        out.append(",".join(p[:2] + [f"{float(v) / FT:.5f}" for v in p[2:5]] + p[5:]))
    (dst / "control" / "points.csv").write_text("\n".join(out) + "\n")


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    base = tmp_path_factory.mktemp("units")
    m = write_block_project(geometric_block(2, 5, seed=11), base / "m")
    write_truth_observations(m, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=6, seed=5)
    _to_feet(m, base / "ft")
    st = AdjustSettings(gnss_correction="shift", image_sigma_px=0.3)
    return {u: run_adjustment(base / u, st, html=False) for u in ("m", "ft")}


def test_map_unit_of_the_report(caplog):
    assert map_unit_m(FT_CRS) == pytest.approx((FT, FT, FT))
    assert map_unit_m("EPSG:32649") == (1.0, 1.0, 1.0)
    # no CRS (the adjustment always writes one): metres, said
    with caplog.at_level(logging.WARNING):
        assert map_unit_m(None, "r.json: crs") == (1.0, 1.0, 1.0)
    assert "r.json: crs: no CRS; its ground coordinates and residuals are read as metres" in caplog.text


@pytest.mark.parametrize("crs, expected", [("EPSG:99999", "unknown CRS 'EPSG:99999'"),
                                            ("EPSG:4326", "EPSG:4326 (WGS 84) is geographic; expected a projected")])
def test_a_report_crs_without_a_known_length_unit_is_refused(tmp_path, crs, expected):
    """A CRS this PROJ cannot read or in degrees: an error naming the file and key (it was read as metres: a feet
    report's figures 3.3 x too large against the metre limits)."""
    with pytest.raises(CrsError, match=re.escape(expected)):
        map_unit_m(crs, "at/report.json: crs")
    path = tmp_path / "report.json"
    path.write_text(json.dumps({"schema_version": 1, "crs": crs, "counts": {}, "check_rms_m": [0.1, 0.1, 0.1]}))
    with pytest.raises(CrsError, match=re.escape(f"{path}: crs: {expected}")):
        read_adjustment_report(path)


def test_control_sigmas_are_metres_in_a_feet_crs(pair):
    """The same weights: the control residuals in metres agree to 1 mm (before: 3-9 x smaller in feet)."""
    res = {}
    for u, r in pair.items():
        rows = to_record(report.build_report(r.adjustment))["control_points"]
        res[u] = np.array([row["residual_m"] for row in rows], float) * (FT if u == "ft" else 1.0)
    assert np.nanmax(np.abs(res["m"])) > 0.01  # residuals to compare
    assert np.allclose(res["ft"], res["m"], atol=1e-3, equal_nan=True), (res["m"], res["ft"])
    assert pair["ft"].adjustment.result.sigma0 == pytest.approx(pair["m"].adjustment.result.sigma0, rel=1e-3)


def test_verdict_and_normalised_errors_do_not_depend_on_the_unit(pair):
    """Limits between the metric check plan RMS and the same number read in feet: no finding in either unit (before:
    the feet block "weak" with its RMS in feet against metres); limits below it: the same findings, in metres."""
    ba = {u: r.adjustment for u, r in pair.items()}
    rep = {u: to_record(report.build_report(b)) for u, b in ba.items()}
    plan_m = rep["m"]["parameters"]["rms_check_m"][3]
    assert rep["ft"]["parameters"]["rms_check_m"][3] * FT == pytest.approx(plan_m, abs=2e-4)
    assert np.allclose(rep["ft"]["check_normalised_rms"], rep["m"]["check_normalised_rms"], atol=0.01)
    import dataclasses

    for factor, found in ((1.5, False), (0.9, True)):
        st = dataclasses.replace(ba["m"].settings, rms_limit_xy_m=plan_m * factor, residual_limit_m=10.0)
        ks = {u: to_record(report.build_report(dataclasses.replace(b, settings=st)))["key_statistics"]
              for u, b in ba.items()}
        q = {u: [(x["quantity"], round(x["value_m"], 3)) for x in k["tolerances_exceeded"]] for u, k in ks.items()}
        assert q["ft"] == q["m"], q
        assert (("check points, plan RMS", round(plan_m, 3)) in q["m"]) is found
        assert ks["ft"]["verdict"] == ks["m"]["verdict"]
    # the Parameters table labels the feet as feet (they stood under "(m)" beside the limits in metres)
    txt = report.format_txt(rep["ft"])
    assert "RMS Check (ft)" in txt and "RMS Limits (m)" in txt and "RMS Check (m)" in report.format_txt(rep["m"])
    # the tables below in the unit of their figures too (they read "m" beside feet)
    assert "OBSERVATIONS (control, ft)" in txt and "Check points (d = adjusted - measured, ft)" in txt
    assert "Control points (residual = adjusted - given, ft;" in txt and "GNSS residual ft; std dev of position m" in txt
    assert " ft  chv = " in txt and " m  chv = " not in txt
    assert "Check points (d = adjusted - measured, m)" in report.format_txt(rep["m"])
    html = report.format_html(rep["ft"])
    assert "dX ft" in html and "dZ ft" in html and "GNSS res X ft" in html and "dX m" not in html
    assert "dX m" in report.format_html(rep["m"])


def test_accuracy_report_judges_metres(pair, tmp_path):
    """The QA rows of the adjustment (control and check RMS, gross errors) have the same values and verdicts; the
    record's figures are metres (``aerotri adjust`` prints them under "(m)")."""
    rec = {u: read_adjustment_report(r.report_path) for u, r in pair.items()}
    assert np.allclose(rec["ft"].check_rms_m, rec["m"].check_rms_m, atol=2e-4)
    assert np.allclose(rec["ft"].control_rms_m, rec["m"].control_rms_m, atol=1e-3)
    rows, comp = {}, {}
    for u, r in pair.items():
        qa = build_qa_report(r.report_path.parent.parent, scale="1:2000", terrain="flat")
        rows[u] = {c.id: c for c in qa.checks if c.section in ("Control points", "Aerotriangulation")
                   and c.id.startswith(("control_rms", "check_rms", "check_gross"))}
        comp[u] = [c for c in qa.compliance["checks"] if c["product"] == "Aerotriangulation"]
    # the compliance section too (trial-qa 2026-12-01: it read at/report.json's d_m, feet in the feet project, as
    # metres: 3.28 x the verdict table's figure)
    assert len(comp["m"]) == len(comp["ft"]) == 2
    for a, b in zip(comp["m"], comp["ft"]):
        assert b["measured"] == pytest.approx(a["measured"], abs=1e-3) and b["verdict"] == a["verdict"], b["quantity"]
    assert comp["m"][0]["measured"] == pytest.approx(rows["m"]["check_rms_xy_m"].value, abs=1e-3)
    assert set(rows["m"]) == set(rows["ft"]) and {"check_rms_xy_m", "control_rms_xy_m"} <= set(rows["m"])
    for k, c in rows["m"].items():
        assert rows["ft"][k].verdict == c.verdict, k
        assert rows["ft"][k].value == pytest.approx(c.value, abs=1e-3), k


def test_a_geocentric_report_crs_is_refused():
    """Reviewer 8: the docstring said geocentric CRSs were refused, but EPSG:4978 (metre axes) was read as a map."""
    with pytest.raises(CrsError, match=re.escape("at/report.json: crs: EPSG:4978 (WGS 84) is geocentric; expected")):
        map_unit_m("EPSG:4978", "at/report.json: crs")


def test_object_point_sigmas_are_metres_in_a_feet_crs(pair):
    """object_points.csv's sx_m, sy_m, sz_m are metres in both projects, as eo.txt's (trial-api F5: feet under "_m",
    0.2888 beside the metre project's 0.0880); x, y, z stay in the CRS's units."""
    import csv

    rows = {u: {r["id"]: r for r in csv.DictReader((p.report_path.parent / "object_points.csv").open())}
            for u, p in pair.items()}
    common = sorted(set(rows["m"]) & set(rows["ft"]))
    assert len(common) > 50
    for key in ("sx_m", "sy_m", "sz_m"):
        m = np.array([float(rows["m"][i][key]) for i in common])
        ft = np.array([float(rows["ft"][i][key]) for i in common])
        assert m.max() > 0.005 and np.allclose(ft, m, rtol=0.01, atol=2e-4), key
    x_m = np.array([float(rows["m"][i]["x"]) for i in common])
    x_ft = np.array([float(rows["ft"][i]["x"]) for i in common])
    assert np.allclose(x_ft * FT, x_m, atol=1e-3)


def test_the_check_points_scale_pattern_is_the_same_in_feet(pair):
    """The displacement a scale about the check points' centre makes is metres in both projects: it is held against
    the plan RMS in metres (it was the CRS's feet, 3.28 x larger)."""
    m, ft = (report.check_scale_pattern(pair[u].adjustment) for u in ("m", "ft"))
    assert m is not None and ft is not None
    assert ft[0] == pytest.approx(m[0], abs=1.0) and ft[1] == pytest.approx(m[1], abs=0.01)
    assert ft[2] == pytest.approx(m[2], rel=0.01, abs=1e-4)


def test_the_flight_acceptance_judges_metres_in_a_feet_crs(pair):
    """trial s102 txt2 H1: a feet block's height step of 13.15 ft was printed as "13.15 m" and judged against 30 m
    (its metre copy: 4.01 m)."""
    from aerotri.adjust.flight_acceptance import Terrain

    ground = {"m": Terrain(100.0), "ft": Terrain(100.0 / FT)}  # the same ground, in each project's unit
    fa = {u: to_record(report.build_report(pair[u].adjustment, ground=ground[u]))["flight_acceptance"]
          for u in ("m", "ft")}
    assert fa["m"] and fa["ft"]
    for key in ("height_step_m", "height_above_ground_m"):
        a = [f[key] for f in fa["m"]["frames"]]
        b = [f[key] for f in fa["ft"]["frames"]]
        assert any(v for v in a) and np.allclose(np.array(b, float), np.array(a, float), atol=0.02, equal_nan=True), key
    for key in ("height_range_m", "length_m", "mean_height_above_ground_m"):
        a, b = ([s[key] for s in fa[u]["strips"]] for u in ("m", "ft"))
        assert np.allclose(b, a, atol=0.02), key
    # the rows the verdict reads: the same values, the same verdicts
    rows = {u: {c["key"]: (c["value"], c["verdict"]) for c in fa[u]["checks"]} for u in ("m", "ft")}
    for key, (v, verdict) in rows["m"].items():
        assert rows["ft"][key][1] == verdict and (v is None or abs(rows["ft"][key][0] - v) <= 0.02), key


def test_the_coordinate_system_line_names_the_feet(pair):
    """trial s102 txt2 M6: report.txt's Coordinate System line of a feet CRS named no unit (its false easting reads
    as 500000 ft)."""
    txt = {u: pair[u].report_path.with_suffix(".txt").read_text() for u in ("m", "ft")}
    line = {u: next(ln for ln in txt[u].splitlines() if ln.startswith("  Coordinate System : ")) for u in txt}
    assert "coordinates in" not in line["m"] and "; coordinates in foot; heights ellipsoidal" in line["ft"], line


def test_the_gnss_misfit_before_the_corrections_is_also_in_feet(pair):
    """trial s103 L10: report.txt's RMS of adjusted antenna - GNSS before the corrections was in metres alone, under
    the Parameters rows in the CRS's feet; now also in its feet (the same block: the metre copy's figures / 0.3048)."""
    txt = {u: pair[u].report_path.with_suffix(".txt").read_text() for u in ("m", "ft")}
    pattern = r"RMS of adjusted antenna - GNSS before them, .*?: ([-\d. ]+) m(?:, ([-\d. ]+) ft)?\)"
    found = {u: re.search(pattern, txt[u]) for u in txt}
    assert found["m"] and found["ft"], txt["ft"]
    metres = np.array(found["m"].group(1).split(), float)
    assert found["m"].group(2) is None and metres.size == 3 and metres.max() > 0
    assert np.allclose(np.array(found["ft"].group(1).split(), float), metres, atol=0.002)
    assert np.allclose(np.array(found["ft"].group(2).split(), float), metres / FT, atol=0.01)
