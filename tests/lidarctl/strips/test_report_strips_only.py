"""A LiDAR delivery checked by its strips alone (no surveyed points yet): `aerotri report --standard usgs-lbs` judges
the swath overlaps and the density (trial-qa 2026-12-01: AHN3 Delft's strips check and DEM read "nothing to report
yet ... run the adjustment first (aerotri match P, then aerotri adjust P)")."""

from __future__ import annotations

import json
import shutil

import laspy
import numpy as np
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin

from aerotri.cli import main as aerotri
from lidarctl.cli.main import main as lidarctl


def test_a_lidar_folder_with_its_strip_check_alone_is_reported(clean_block, tmp_path):
    p = tmp_path / "P"
    (p / "lidar").mkdir(parents=True)
    (p / "project.toml").write_text('[project]\ncrs = "EPSG:32649"\n')
    r = CliRunner().invoke(aerotri, ["report", str(p), "--standard", "usgs-lbs"])
    # nothing checked yet: refused, pointing at the LiDAR checks too (it named the adjustment only)
    assert r.exit_code == 2 and "a LiDAR delivery alone: lidarctl strips check" in r.output, r.output
    for path in clean_block.paths:
        shutil.copy(path, p / "lidar")
    strips = sorted((p / "lidar").iterdir())
    r = CliRunner().invoke(lidarctl, ["strips", "check", *map(str, strips), str(p / "lidar_out" / "strips")])
    assert r.exit_code == 0, r.output
    # the DEM the density is counted over: every cell of a 2 m grid over the strips valid
    heads = [laspy.open(s).header for s in strips]
    x0, y0 = min(h.mins[0] for h in heads), min(h.mins[1] for h in heads)
    nx, ny = (int(np.ceil((max(h.maxs[i] for h in heads) - v) / 2.0)) for i, v in ((0, x0), (1, y0)))
    with rasterio.open(p / "lidar_out" / "dem.tif", "w", driver="GTiff", width=nx, height=ny, count=1,
                       dtype="float32", crs="EPSG:32649", transform=from_origin(x0, y0 + 2.0 * ny, 2.0, 2.0)) as ds:
        ds.write(np.zeros((1, ny, nx), np.float32))
    first = sum(int(np.count_nonzero(laspy.read(s).return_number == 1)) for s in strips)
    r = CliRunner().invoke(aerotri, ["report", str(p), "--standard", "usgs-lbs"])
    assert r.exit_code == 0, r.output
    comp = json.loads((p / "reports" / "summary.json").read_text())["compliance"]
    rows = {c["product"]: c for c in comp["checks"]}
    rms = json.loads((p / "lidar_out" / "strips" / "strips.json").read_text())["all_pairs"]["rms_m"]
    assert rows["LiDAR swath overlaps"]["measured"] == round(rms, 4) and rows["LiDAR swath overlaps"]["verdict"] == "pass"
    assert rows["LiDAR density"]["measured"] == round(first / (nx * ny * 4.0), 4)
    assert rows["LiDAR DEM"]["verdict"] == "not testable" and "no surveyed check points" in rows["LiDAR DEM"]["why"]


def test_a_pair_the_strip_check_warned_of_is_said_in_the_report(shifted_block, tmp_path):
    """Trial s100 rc2 L4: AHN3's strip check warned that a rigid shift does not model one pair (a boresight or
    scan-angle error), and the accuracy report passed the swath row without a word of it. The row's note says it."""
    from aerotri.qa.report import write_qa_report

    p = tmp_path / "P"
    (p / "lidar").mkdir(parents=True)
    (p / "project.toml").write_text('[project]\ncrs = "EPSG:32632"\n')
    r = CliRunner().invoke(lidarctl, ["strips", "check", *map(str, shifted_block.paths),
                                      str(p / "lidar_out" / "strips")])
    assert r.exit_code == 0 and "a rigid shift does not model" in r.output, r.output
    note = write_qa_report(p).check("strip_rmsdz_m").note
    assert "2 pair(s) a rigid shift does not model (strip_2 - strip_1, strip_3 - strip_2)" in note, note
