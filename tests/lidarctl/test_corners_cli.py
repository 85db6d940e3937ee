"""``lidarctl corners`` end to end on a small synthetic classified LAS file."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import laspy
import numpy as np
import pyproj
from click.testing import CliRunner

from lidarctl.cli.main import main
from lidarctl.corners.roof_corners import read_corner_summary

_spec = importlib.util.spec_from_file_location("corners_synth", Path(__file__).with_name("corners_synth.py"))
cs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cs)

COLUMNS = "id,x,y,z,sx_m,sy_m,sz_m,roof,building_id,edge1_deg,edge2_deg,angle_deg,support_pts,score,usable".split(",")
E0, N0 = 452000.0, 3407000.0  # UTM 49N offsets: realistic coordinate magnitudes


def _write_las(path, x, y, z, cls, sid):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([E0, N0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(32649))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x + E0, y + N0, z
    las.classification = cls
    las.point_source_id = sid
    las.write(path)


def test_corners_command_writes_csv_geojson_summary_and_figure(tmp_path):
    buildings = cs.default_buildings()
    x, y, z, cls, sid = cs.make_cloud(buildings, seed=3, heading_deg=-20.0)
    las = tmp_path / "classified.las"
    _write_las(las, x, y, z, cls, sid)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["corners", str(las), str(out), "--roof", "flat"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(out / "corners.csv")))
    assert list(rows[0].keys()) == COLUMNS
    truth_xyz, _, _ = cs.truth_corners(buildings)
    xy = np.array([[float(q["x"]) - E0, float(q["y"]) - N0] for q in rows])
    j, d = cs.match_corners(xy, truth_xyz[:, :2], max_dist_m=1.0)
    assert np.all(j >= 0)
    usable = np.array([q["usable"] == "1" for q in rows])
    assert usable.sum() >= 15
    assert np.sqrt(np.mean(d[usable] ** 2)) < 0.2
    gj = json.loads((out / "corners.geojson").read_text())
    kinds = [f["properties"]["kind"] for f in gj["features"]]
    assert kinds.count("roof_corner") == len(rows)
    assert kinds.count("roof_outline") >= 6
    assert "32649" in gj["crs"]["properties"]["name"]
    summary = read_corner_summary(out / "corners.json")
    st = summary.stats
    assert st.n_corners == len(rows) and st.n_usable == int(usable.sum()) and summary.no_usable is None
    assert summary.crs == "EPSG:32649" and summary.settings["roof"] == {"value": "flat", "source": "command line"}
    # the reader gives back what was written, to the byte
    assert summary.to_json() == (out / "corners.json").read_text()
    assert (out / "corners.png").stat().st_size > 10000
    # the printed summary names the resolved minimum edge (the same as the JSON's) and the units
    assert f"edges >= {st.min_edge_m:.2f} m; x, y, z in metre" in r.output


def test_corners_record_the_share_of_the_building_class_within_a_roof_outline(tmp_path):
    """A clump of building points too small to be a roof (2 m x 2 m on the ground, away from the buildings) has no
    outline: corners.json's ``n_outlined_points`` is the building points of the outlined roofs (the n_points of
    roof_outlines.gpkg's features), every building point but the clump's, and the summary line prints its share."""
    buildings = cs.default_buildings()
    x, y, z, cls, sid = cs.make_cloud(buildings, seed=3, heading_deg=-20.0)
    rng = np.random.default_rng(4)
    n_clump = 40
    far_x, far_y = float(x.max()) - 3.0, float(y.max()) - 3.0
    clump = (far_x + rng.uniform(0, 2, n_clump), far_y + rng.uniform(0, 2, n_clump), np.full(n_clump, 6.0))
    x, y = np.concatenate([x, clump[0]]), np.concatenate([y, clump[1]])
    z = np.concatenate([z, float(np.median(z)) + clump[2]])
    cls = np.concatenate([cls, np.full(n_clump, 6, cls.dtype)])
    sid = np.concatenate([sid, np.full(n_clump, sid[0], sid.dtype)])
    las = tmp_path / "classified.las"
    _write_las(las, x, y, z, cls, sid)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["corners", str(las), str(out), "--roof", "flat"])
    assert r.exit_code == 0, r.output
    st = read_corner_summary(out / "corners.json").stats
    gj = json.loads((out / "corners.geojson").read_text())
    outlined = sum(f["properties"]["n_points"] for f in gj["features"] if f["properties"]["kind"] == "roof_outline")
    assert st.n_building_points == int((cls == 6).sum())
    assert st.n_outlined_points == outlined == st.n_building_points - n_clump
    assert f"({100 * st.outlined_share:.0f} % of the building points on an outlined roof)" in r.output


def test_figure_draws_cells_without_height_apart_from_the_tallest(tmp_path):
    """nDSM cells without a height (water drop-outs) get a colour of their own, not the grey scale's white."""
    import matplotlib.image as mpimg

    from lidarctl.corners.roof_corners import plot_corners

    ndsm = np.tile(np.linspace(0.0, 15.0, 60), (60, 1))
    ndsm[20:40, 20:40] = np.nan
    png = tmp_path / "c.png"
    plot_corners(png, ndsm, (0.0, 60.0, 0.0, 60.0), [], [])
    rgb = mpimg.imread(png)[..., :3]
    blue = np.all(np.abs(rgb - np.array([176, 196, 222]) / 255.0) < 0.02, axis=-1)   # lightsteelblue
    assert blue.sum() > 1000


def test_cloud_without_buildings_gives_clear_message_and_no_files(tmp_path):
    rng = np.random.default_rng(1)
    n = 3000
    las = tmp_path / "ground.las"
    _write_las(las, rng.uniform(0, 60, n), rng.uniform(0, 60, n), rng.normal(0, 0.05, n), np.full(n, 2), np.ones(n))
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["corners", str(las), str(out)])
    assert r.exit_code == 2
    assert "no building points" in r.output and "ground.las" in r.output
    assert not out.exists() or not any(out.iterdir())
    # lead (new-user trial, Autzen): a classified cloud without buildings was told "classify the cloud first"
    assert "classify the cloud first" not in r.output and "Traceback" not in r.output
    assert ("no building points (ASPRS class 6) among 3000 points of a classified cloud (class 2: 3000): it holds "
            "no building to take roof corners from") in r.output


def test_an_unclassified_cloud_is_told_to_be_classified_first(tmp_path):
    rng = np.random.default_rng(2)
    n = 3000
    las = tmp_path / "raw.las"
    cls = np.where(np.arange(n) % 3 == 0, 0, 1)   # never classified (0) and unclassified (1)
    _write_las(las, rng.uniform(0, 60, n), rng.uniform(0, 60, n), rng.normal(0, 0.05, n), cls, np.ones(n))
    r = CliRunner().invoke(main, ["corners", str(las), str(tmp_path / "out")])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert ("no building points (ASPRS class 6) among 3000 points, all of them unclassified (class 0 or 1): classify "
            "the cloud first (lidarctl classify)") in r.output


def test_no_usable_corner_gives_clear_message_and_no_files(tmp_path):
    # only a 6 x 6 m shed: its edges are shorter than --min-edge-m 8
    shed = [(cs._rect(30, 30, 6, 6, 10.0), "flat", 4.0, 0.0, 0.0)]
    x, y, z, cls, sid = cs.make_cloud(shed, extent=(0.0, 60.0, 0.0, 60.0), seed=2)
    las = tmp_path / "shed.las"
    _write_las(las, x, y, z, cls, sid)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["corners", str(las), str(out), "--min-edge-m", "8"])
    assert r.exit_code == 2
    assert "no usable roof corner" in r.output
    assert not out.exists() or not any(out.iterdir())


def test_unreadable_file_is_an_input_error(tmp_path):
    bad = tmp_path / "bad.laz"
    bad.write_bytes(b"not a las file")
    r = CliRunner().invoke(main, ["corners", str(bad), str(tmp_path / "out")])
    assert r.exit_code == 2
    assert "bad.laz" in r.output
