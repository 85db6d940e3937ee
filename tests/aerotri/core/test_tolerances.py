"""Tolerance tables chosen by GSD and platform (aerotri/core/tolerances.py, aerotri/geom/block_scale.py):
a drone block gets ASPRS 2023 classes, a coarse manned block a Chinese map-scale table, [qa] overrides,
the reports name the table and why, every shipped limit carries its source."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from aerotri.adjust.flight_acceptance import LIMIT_KEYS, Terrain, flight_acceptance
from aerotri.core.errors import ConfigError
from aerotri.core.project import Project
from aerotri.core.tolerances import (SCALE_TABLES, TOLERANCE_DIR, asprs_classes_for_gsd, load_table, qa_settings,
                                     read_qa_config)
from aerotri.geom.block_scale import project_block_scale
from aerotri.geom.camera import BrownCamera
from aerotri.qa.report import write_qa_report

GROUND_M = 180.0
# DJI FC300S as Brighton Beach's EXIF gives it: 4000 x 2250 px, f 3.61 mm, 1/2.3" sensor 6.17 mm wide
DRONE = BrownCamera(focal_mm=3.61, pixel_um=6.17e3 / 4000, width=4000, height=2250, name="FC300S")
DMC = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=1728, height=960, name="DMC-like")


def _project(root: Path, camera, height_m: float, qa: str = "", frames: int = 8) -> Path:
    """Two strips of ``frames`` frames ``height_m`` above flat ground at GROUND_M ([flight] mean height)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32615"\n\n'
                                       f"[flight]\nmean_terrain_height_m = {GROUND_M}\n\n{qa}")
    (root / "camera.toml").write_text(camera.to_toml())
    base = 0.3 * height_m
    rows = [f"f{s}_{i:02d} {500000 + i * base:.3f} {5000000 + s * 2 * base:.3f} {GROUND_M + height_m:.3f}"
            for s in range(2) for i in range(frames)]
    (root / "gnss.txt").write_text("\n".join(rows) + "\n")
    return root


def _choose(root: Path):
    return qa_settings(root, project_block_scale(Project.open(root))).table


def test_drone_block_gets_asprs_classes_by_gsd_and_no_manned_flight_spec(tmp_path):
    root = _project(tmp_path / "drone", DRONE, 40.0)
    block = project_block_scale(Project.open(root))
    assert block.platform == "uas" and block.height_above_ground_m == pytest.approx(40.0)
    assert block.gsd_m == pytest.approx(40.0 * DRONE.pixel_um * 1e-6 / (DRONE.focal_mm * 1e-3))  # 1.71 cm
    t = _choose(root)
    assert t.key == "ASPRS2023 H7.1cm V10cm UAS" and t.path.name == "asprs2023.toml"
    assert "UAS" in t.reason and "GSD 1.7 cm" in t.reason and "2.5 cm" in t.reason  # the [[gsd_classes]] row
    # limits are the class multiples of the table file: AT plan 1/2 H, product H, NVA V
    assert t.limits["rms_xy_m"] == pytest.approx(0.0355) and t.limits["feature_rms_xy_m"] == pytest.approx(0.071)
    assert t.limits["dem_rmse_m"] == pytest.approx(0.10) and t.limits["check_points_min"] == 30
    assert t.limits["flight_limits_apply"] is False and "none applies" in t.limits["flight_spec"]
    assert not any(k in t.limits for k in LIMIT_KEYS)  # no manned flight limit reaches the drone
    assert t.provenance["check_points_min"].confirmed and "rms_xy_m" in t.unconfirmed


def test_manned_blocks_by_gsd(tmp_path):
    # DMC 12 um / 120 mm at 1500 m: GSD 15 cm, manned -> the Chinese 1:2000 table (GSD <= 20 cm)
    t = _choose(_project(tmp_path / "coarse", DMC, 1500.0))
    assert t.key == "1:2000" and t.platform is None and "manned block" in t.reason and "GSD 15 cm" in t.reason
    assert t.limits["flight_tilt_max_deg"] == 2.0 and t.limits["rms_xy_m"] == 0.14
    # at 4000 m (GSD 40 cm) -> 1:5000
    assert _choose(_project(tmp_path / "high", DMC, 4000.0)).key == "1:5000"
    # a manned block under 5 cm GSD (DMC at 300 m: 3 cm) -> ASPRS classes, but the manned flight limits stay
    t = _choose(_project(tmp_path / "fine", DMC, 300.0))
    assert t.key == "ASPRS2023 H14.1cm V20cm" and t.limits["flight_tilt_max_deg"] == 2.0
    assert "GSD under 5 cm" in t.reason
    # a GSD of a metre and more in whole centimetres (the NGI frames' report said "GSD 5.8e+02 cm")
    t = _choose(_project(tmp_path / "very_high", DMC, 12000.0))
    assert "GSD 120 cm at 12000 m above ground" in t.reason and "e+" not in t.reason


def test_qa_settings_override_the_choice_and_are_checked(tmp_path):
    # [qa] map_scale on a drone block: the Chinese table, still no manned flight limits
    t = _choose(_project(tmp_path / "a", DRONE, 40.0, '[qa]\nmap_scale = "1:5000"\nterrain = "hilly"\n'))
    assert t.key == "1:5000 UAS" and t.limits["rms_z_m"] == 2.0 and "map scale 1:5000 from" in t.reason
    assert t.limits["flight_limits_apply"] is False
    # [qa] standard with its classes; [qa] platform
    t = _choose(_project(tmp_path / "b", DMC, 1500.0,
                         '[qa]\nstandard = "asprs2023"\nhorizontal_class_cm = 10\nvertical_class_cm = 15\n'
                         'platform = "uas"\n'))
    assert t.key == "ASPRS2023 H10cm V15cm UAS" and t.limits["rms_xy_m"] == pytest.approx(0.05)
    assert "platform uas from" in t.reason
    for bad, key in (('standard = "nssda"', "standard"), ("horizontal_class_cm = -5", "horizontal_class_cm"),
                     ('platform = "balloon"', "platform")):
        root = _project(tmp_path / key, DRONE, 40.0, f"[qa]\n{bad}\n")
        with pytest.raises(ConfigError, match=key):
            read_qa_config(root)


def test_unknown_gsd_keeps_the_default_and_says_why(tmp_path):
    root = tmp_path / "nocam"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32615"\n')
    t = qa_settings(root, project_block_scale(Project.open(root))).table
    assert t.key == "1:5000" and "GSD unknown (no camera.toml)" in t.reason
    # camera and positions but no terrain height: named as such
    root = _project(tmp_path / "noterrain", DRONE, 40.0)
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32615"\n')
    assert "no terrain height" in _choose(root).reason


def test_every_shipped_limit_names_its_source():
    """Each number of each shipped table has a source; the ASPRS GSD rows and the selection rules too."""
    for scale in SCALE_TABLES:
        for terrain in ("flat", "hilly", "mountainous"):
            t = load_table(scale, terrain)
            missing = [k for k in t.limits if k not in t.provenance and k not in ("flight_spec",)]
            assert not missing, (scale, missing)
            assert all(p.source for p in t.provenance.values())
    t = load_table("ASPRS2023 H5cm V10cm")
    assert not [k for k in t.limits if k not in t.provenance and k != "flight_spec"]
    a = tomllib.loads((TOLERANCE_DIR / "asprs2023.toml").read_text())
    assert a["gsd_classes_provenance"]["confirmed"] is False and a["table"]["edition"].startswith("Edition 2")
    sel = tomllib.loads((TOLERANCE_DIR / "selection.toml").read_text())
    assert all("source" in sel[k] for k in ("platform", "asprs")) and "source" in sel["cn_scale_provenance"]
    # the GSD rows: classes grow with the GSD (finest row for 1 cm, coarsest beyond)
    assert asprs_classes_for_gsd(0.01)[:2] == (3.5, 5.0) and asprs_classes_for_gsd(5.0)[:2] == (282.8, 400.0)


def test_uas_flight_values_reported_not_judged():
    """A UAS table's limits leave the flight checks without verdicts; the manned limits flag the same flight."""
    ids = [f"f{i}" for i in range(6)]
    c = np.column_stack([np.arange(6) * 12.0, np.zeros(6), np.full(6, 40.0)])
    opk = np.zeros((6, 3))
    opk[:, 2] = -90.0
    opk[2, :2] = (4.0, 0.0)  # 4 deg tilt: beyond the manned 2 deg
    uas = flight_acceptance(ids, c, opk, DRONE, Terrain(0.0), np.ones(6, int),
                            limits=load_table("ASPRS2023 H7.1cm V10cm UAS").limits)
    assert all(ch["verdict"] == "not judged" for ch in uas.checks if ch["n"]) and "none applies" in uas.spec
    assert not uas.failed
    assert max(f["tilt_deg"] for f in uas.frames) == pytest.approx(4.0)  # measured all the same
    manned = flight_acceptance(ids, c, opk, DRONE, Terrain(0.0), np.ones(6, int), limits=load_table("1:5000").limits)
    assert {ch["key"]: ch for ch in manned.checks}["flight_tilt_max_deg"]["verdict"] == "fail"
    assert "manned" in manned.spec


def test_qa_report_names_the_table_and_marks_unconfirmed_limits(tmp_path):
    root = _project(tmp_path / "drone", DRONE, 40.0)
    (root / "at").mkdir()
    (root / "at" / "report.json").write_text(json.dumps(dict(
        project="t", check_rms_m=[0.02, 0.02, 0.05], check_points=[{"d_m": [0.02, 0.02, 0.05]}] * 12,
        key_statistics=dict(sigma0_px=0.5, success=True, message="Solution Successful."))))
    rep = write_qa_report(root)
    assert rep.table["key"] == "ASPRS2023 H7.1cm V10cm UAS" and "UAS" in rep.table["reason"]
    plan = rep.check("check_rms_xy_m")  # 0.028 m against 1/2 x 7.1 cm: pass
    assert plan.limit == pytest.approx(0.0355) and plan.verdict == "pass" and plan.limit_confirmed is False
    assert rep.check("check_rms_z_m").verdict == "pass"  # 0.05 m <= 7.1 cm
    n = rep.check("check_points_count")
    assert n.value == 12 and "at least 30" in n.note and "indicative" in n.note
    html = (root / "reports" / "index.html").read_text()
    assert "ASPRS Positional Accuracy Standards, Edition 2 (2023)" in html and "chosen because" in html
    assert "class='unconf'" in html and "Tolerance table" in html
    summary = json.loads((root / "reports" / "summary.json").read_text())
    assert summary["table"]["file"] == "asprs2023.toml" and summary["block"]["platform"] == "uas"
    # the command line overrides: --scale
    rep = write_qa_report(root, scale="1:2000")
    assert rep.table["key"] == "1:2000 UAS" and "--scale" in rep.table["reason"]


_spec = importlib.util.spec_from_file_location("realdata_ngi", Path(__file__).parents[2] / "realdata_ngi.py")
ngi = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("realdata_ngi", ngi)
_spec.loader.exec_module(ngi)


@pytest.mark.realdata
def test_brighton_beach_drone_block_is_judged_by_asprs(shared_data, tmp_path):
    """The real drone block (EXIF import, ground from the ODM cloud of the same frames as the adjustment's
    tie points would give it): about 40 m above ground, GSD about 1.7 cm (its README) -> ASPRS 2023, UAS."""
    import laspy

    from aerotri.exchange import import_files

    data = shared_data / "brighton_beach"
    root = tmp_path / "brighton"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "brighton"\ncrs = "EPSG:32615"\n')
    import_files(root, "exif", [data / "images"])
    with laspy.open(data / "model.laz") as f:
        z = next(f.chunk_iterator(200_000)).z
    block = project_block_scale(Project.open(root), np.asarray(z), "the ODM cloud")
    assert 35.0 < block.height_above_ground_m < 45.0  # README: about 40 m
    assert 0.012 < block.gsd_m < 0.022 and block.platform == "uas"  # README: about 1.7 cm
    t = qa_settings(root, block).table
    assert t.key.startswith("ASPRS2023 ") and t.key.endswith(" UAS") and "flight_tilt_max_deg" not in t.limits


@pytest.mark.realdata
def test_ngi_dmc_block_is_manned_and_gets_a_map_scale_table(shared_data, tmp_path):
    """The real DMC block (flying about 5250 m over 150-780 m terrain, frames downsampled to 144 um pixels):
    a manned block of GSD about 5.6 m, judged by the coarsest Chinese table with a note that says so."""
    d = shared_data / "ngi_dmc"
    if not (d / ngi.REFERENCE_FILE).is_file():
        pytest.skip(f"NGI DMC frames not found at {d}")
    root = ngi.build_ngi_project(d, tmp_path / "ngi")
    block = project_block_scale(Project.open(root))
    assert block.platform == "manned" and 4000.0 < block.height_above_ground_m < 5200.0
    assert block.gsd_m == pytest.approx(block.height_above_ground_m * 144e-6 / 0.12)
    t = qa_settings(root, block).table
    assert t.key == "1:10000" and "coarser than every shipped table" in t.reason
    assert t.limits["flight_tilt_max_deg"] == 2.0 and math.isclose(t.limits["rms_xy_m"], 0.35)


def test_a_block_without_gnss_is_scaled_by_the_adjustment_s_own_centres(tmp_path):
    """A block without gnss.txt (the kite) has no frame positions before its first eo.txt: the adjustment's report
    chose the default 1:5000 table while reports/ (after at/eo.txt) chose by the block's GSD. With the adjusted
    centres passed in, both choose the drone table."""
    root = _project(tmp_path / "kite", DRONE, 40.0)
    centres = np.array([[float(v) for v in line.split()[1:]] for line in (root / "gnss.txt").read_text().splitlines()])
    (root / "gnss.txt").unlink()
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32615"\n')  # no mean terrain height
    ground = np.full(50, GROUND_M)
    assert project_block_scale(Project.open(root), ground).gsd_m is None  # no positions: the default table
    block = project_block_scale(Project.open(root), ground, positions=(centres, "the adjusted projection centres"))
    assert block.platform == "uas" and block.height_above_ground_m == pytest.approx(40.0)
    assert "the adjusted projection centres" in block.how
    assert qa_settings(root, block).table.key == "ASPRS2023 H7.1cm V10cm UAS"


def test_the_ground_of_the_gsd_is_the_adjusted_tie_points_not_the_planned_terrain_height(tmp_path):
    """Tuniu: the EXIF import writes the take-off point's height as [flight] mean_terrain_height_m; the report
    stated "GSD 11 cm at 100 m" from it while the tie points lay 9 m higher (10.0 cm at 91 m). The adjusted tie
    points (at/object_points.csv, or the heights the adjustment passes) come first, the planned height last."""
    root = _project(tmp_path / "drone", DRONE, 40.0)  # [flight] mean_terrain_height_m = GROUND_M (the take-off)
    assert project_block_scale(Project.open(root)).height_above_ground_m == pytest.approx(40.0)  # no tie points yet
    rng = np.random.default_rng(1)
    z = GROUND_M + 9.0 + rng.normal(0.0, 0.5, 301)
    z[:20] += 30.0  # a tree row: the median holds
    (root / "at").mkdir()
    (root / "at" / "object_points.csv").write_text(
        "id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px\n"
        + "".join(f"T{i},tie,500010.0,5000010.0,{v:.4f},0.01,0.01,0.02,3,0.2\n" for i, v in enumerate(z)))
    block = project_block_scale(Project.open(root))
    assert block.height_above_ground_m == pytest.approx(40.0 - 9.0, abs=0.2)
    assert block.gsd_m == pytest.approx(DRONE.gsd_m(block.height_above_ground_m))
    assert "the adjusted points of at/object_points.csv" in block.how and "mean_terrain_height_m" not in block.how
    # the adjustment's own tie points when it passes them (its report is written before object_points.csv)
    block = project_block_scale(Project.open(root), np.r_[np.full(50, GROUND_M + 12.0), np.nan])
    assert block.height_above_ground_m == pytest.approx(28.0) and "the adjusted tie points (192.0 m)" in block.how
    assert "GSD 1.2 cm at 28 m above ground" in qa_settings(root, block).table.reason


def test_the_planned_terrain_height_is_in_metres_whatever_the_crs_unit(tmp_path):
    """[flight] mean_terrain_height_m is metres by its name; in a CRS in US survey feet it was taken as feet (the
    flying height above ground came out 1,125 m for 1,000 m)."""
    ft = 1200.0 / 3937.0
    root = tmp_path / "feet"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:2229"\n\n'
                                       f"[flight]\nmean_terrain_height_m = {GROUND_M}\n")
    (root / "camera.toml").write_text(DMC.to_toml())
    rows = [f"f{s}_{i:02d} {6000000 + i * 984.0:.3f} {2000000 + s * 1968.0:.3f} {(GROUND_M + 1000.0) / ft:.3f}"
            for s in range(2) for i in range(8)]
    (root / "gnss.txt").write_text("\n".join(rows) + "\n")
    block = project_block_scale(Project.open(root))
    assert block.height_above_ground_m == pytest.approx(1000.0, rel=1e-6)
    assert block.gsd_m == pytest.approx(1000.0 * 12e-6 / 0.12, rel=1e-6)
