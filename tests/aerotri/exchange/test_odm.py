"""ODM ``gcp_list.txt`` import and export, OpenSfM ``ground_control_points.json`` export: a round trip through an
adjusted block, the Coal Oil Point file read against an independent parse, and bad input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.exchange import ImportSettings, export_project, import_files
from aerotri.exchange.adjusted import read_adjusted_block
from aerotri.geom.observations import read_control_points, read_image_points


def _fresh(tmp_path, source_root=None, crs=None, name="p"):
    root = tmp_path / name
    root.mkdir()
    if source_root is not None:
        shutil.copy(source_root / "project.toml", root / "project.toml")
    else:
        (root / "project.toml").write_text(f'[project]\nname = "{name}"\ncrs = "{crs}"\n')
    return root


def test_round_trip_through_gcp_list(adjusted_tiny, tmp_path):
    """Export the adjusted block's control to ODM, import it into a fresh project: the same points (to the
    file's 0.1 mm) and the same measurements (0.001 px) as the project's own control files."""
    root, ba = adjusted_tiny
    out = tmp_path / "out"
    export_project(root, ["odm"], out)
    text = (out / "odm" / "gcp_list.txt").read_text().splitlines()
    assert text[0] == "EPSG:32649"
    blk = read_adjusted_block(root)
    fresh = _fresh(tmp_path, root)
    r = CliRunner().invoke(aerotri_cli, ["import", str(fresh), "--format", "odm", str(out / "odm" / "gcp_list.txt"),
                                         "--sigma-xyz-m", "0.02", "0.02", "0.04"])
    assert r.exit_code == 0, r.output
    got = read_control_points(fresh / "control" / "points.csv")
    assert sorted(got.id) == sorted(blk.control_id)
    want = dict(zip(blk.control_id, blk.control_xyz_m))
    assert np.abs(np.array([want[p] for p in got.id]) - got.xyz_m).max() < 1e-4
    assert set(got.kind) == {"full"} and np.allclose(got.sigma_m, [0.02, 0.02, 0.04])
    mine = read_image_points(root / "control" / "image_points.csv")
    theirs = read_image_points(fresh / "control" / "image_points.csv")
    ref = {(p, i): xy for p, i, xy in zip(mine.point_id, mine.image_id, mine.xy_px)}
    assert len(theirs) == len(text) - 1 > 0
    assert max(np.abs(ref[(p, i)] - xy).max() for p, i, xy in zip(theirs.point_id, theirs.image_id, theirs.xy_px)) < 1e-3
    # only measurements of control points the adjustment used
    used = set(blk.control_id)
    assert set(theirs.point_id) <= used


def test_ground_control_points_json_is_opensfm_s(adjusted_tiny, tmp_path):
    """WGS84 positions back through pyproj equal the control coordinates; projections denormalised with
    OpenSfM's formula equal the measurements. The export of a block whose control is all 3D writes no JSON:
    gcp_list.txt holds every point, and OpenSfM adds the JSON's points to gcp_list.txt's (reviewer 10)."""
    from pyproj import CRS, Transformer

    from aerotri.core.project import Project
    from aerotri.exchange.odm_export import _ground_control_points_json, control_measurements

    root, _ = adjusted_tiny
    export_project(root, ["odm"], tmp_path)
    assert (tmp_path / "odm" / "gcp_list.txt").is_file()
    assert not (tmp_path / "odm" / "opensfm" / "ground_control_points.json").exists()
    blk = read_adjusted_block(root)
    kept = control_measurements(blk, Project.open(root))[0]
    xyz = dict(zip(blk.control_id, blk.control_xyz_m))
    doc = json.loads(_ground_control_points_json(kept, list(blk.control_id), xyz, Project.open(root), blk, {}))
    want = dict(zip(blk.control_id, blk.control_xyz_m))
    t = Transformer.from_crs(CRS("EPSG:4979"), CRS("EPSG:32649").to_3d(), always_xy=True)
    obs = read_image_points(root / "control" / "image_points.csv")
    ref = {(p, i): xy for p, i, xy in zip(obs.point_id, obs.image_id, obs.xy_px)}
    w, h = blk.camera.width, blk.camera.height
    n = 0
    for pt in doc["points"]:
        pos = pt["position"]
        assert np.abs(np.array(t.transform(pos["longitude"], pos["latitude"], pos["altitude"])) - want[pt["id"]]).max() < 1e-6
        for o in pt["observations"]:
            xn, yn = o["projection"]
            x, y = xn * max(w, h) - 0.5 + w / 2, yn * max(w, h) - 0.5 + h / 2
            assert np.allclose([x, y], ref[(pt["id"], o["shot_id"])], atol=1e-9)
            n += 1
    assert n > 0 and {p["id"] for p in doc["points"]} == set(blk.control_id)


@pytest.mark.realdata
def test_copr_kite_gcp_list_imported(shared_data, tmp_path):
    """Coal Oil Point: the file as published is refused (gcp04 and gcp00 measured at one pixel of IMG_0031, lines 6
    and 25); without the mislabelled gcp04 line: 10 targets, 26 measurements, UTM 11N coordinates unchanged in an
    EPSG:32611 project, plan-only (every height is 0: not measured) unless --heights-measured."""
    path = shared_data / "copr_kite" / "gcp_list.txt"
    root = _fresh(tmp_path, crs="EPSG:32611")
    with pytest.raises(InputError, match=r"gcp_list.txt:25: points 'gcp04' and 'gcp00' are measured 1.1 px apart in "
                                         r"frame 'IMG_0031' \(lines 6 and 25\)"):
        import_files(root, "odm", [path], ImportSettings(sigma_xyz_m=(0.3, 0.3, 5.0)))
    assert not (root / "control").exists()
    lines = path.read_text().splitlines()
    fixed = tmp_path / "gcp_list.txt"
    fixed.write_text("\n".join(ln for ln in lines if not ("IMG_0031.jpg" in ln and ln.rstrip().endswith("gcp04"))) + "\n")
    import_files(root, "odm", [fixed], ImportSettings(sigma_xyz_m=(0.3, 0.3, 5.0)))
    rows = [ln.split("\t") for ln in fixed.read_text().splitlines()[1:] if ln.strip()]
    c = read_control_points(root / "control" / "points.csv")
    o = read_image_points(root / "control" / "image_points.csv")
    assert len(c) == 10 and len(o) == len(rows) == 26
    assert set(c.kind) == {"horizontal"}  # heights nobody measured are no control
    want = {r[6].strip(): [float(v) for v in r[:3]] for r in rows}
    assert np.abs(np.array([want[p][:2] for p in c.id]) - c.xyz_m[:, :2]).max() < 1e-4
    got = {(p, i): xy for p, i, xy in zip(o.point_id, o.image_id, o.xy_px)}
    for r in rows:
        assert np.allclose(got[(r[6].strip(), r[5].rsplit(".", 1)[0])], [float(r[3]), float(r[4])], atol=5e-4)
    # a measurement off its frame (trial-kite: x 9093.79 in a 4272 px frame was imported) is refused naming its line
    framed = _fresh(tmp_path, crs="EPSG:32611", name="framed")
    (framed / "images").symlink_to(shared_data / "copr_kite" / "images")
    off = tmp_path / "gcp_off.txt"
    bad = fixed.read_text().splitlines()
    f = bad[8].split("\t")
    f[3] = "9093.79"
    bad[8] = "\t".join(f)
    off.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError, match=r"gcp_off.txt:9: point '\w+' measured at \(9093.79, [0-9.]+\) px in "
                                         r"'IMG_\d+', off its 4272 x 2848 px frame"):
        import_files(framed, "odm", [off], ImportSettings(sigma_xyz_m=(0.3, 0.3, 5.0)))
    assert not (framed / "control").exists()
    # a line without its image name: the target's name is read as the image, and the line is named (trial-kite)
    f = fixed.read_text().splitlines()[6].split("\t")
    noname = tmp_path / "gcp_noname.txt"
    noname.write_text("\n".join(fixed.read_text().splitlines()[:6] + ["\t".join(f[:5] + f[6:])]) + "\n")
    with pytest.raises(InputError, match=rf"gcp_noname.txt:7: control measurements of image\(s\) {f[6].strip()} that "):
        import_files(framed, "odm", [noname], ImportSettings(sigma_xyz_m=(0.3, 0.3, 5.0)))
    import_files(framed, "odm", [fixed], ImportSettings(sigma_xyz_m=(0.3, 0.3, 5.0)))   # every one on its frame
    # the heights forced: full control with height 0
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(fixed), "--sigma-xyz-m", "0.3", "0.3",
                                         "5", "--force", "--heights-measured"])
    assert r.exit_code == 0, r.output
    c = read_control_points(root / "control" / "points.csv")
    assert set(c.kind) == {"full"} and np.all(c.xyz_m[:, 2] == 0.0)


def test_heights_all_zero_or_equal_are_not_measured(tmp_path):
    """All heights 0, or all one number: plan-only control with a warning naming the file; real heights stay."""
    root = _fresh(tmp_path, crs="EPSG:32611")
    cases = [("0 0 0", "horizontal"), ("12.5 12.5 12.5", "horizontal"), ("12.5 13.1 12.5", "full")]
    for n, (heights, kind) in enumerate(cases):
        z = heights.split()
        f = tmp_path / f"gcp_{n}.txt"
        f.write_text("EPSG:32611\n" + "".join(f"{235260 + 10 * k} {3811200 + 7 * k} {z[k]} {100 + 50 * k} 200 a.jpg p{k}\n"
                                               f"{235260 + 10 * k} {3811200 + 7 * k} {z[k]} {120 + 50 * k} 900 b.jpg p{k}\n"
                                               for k in range(3)))
        r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(f), "--sigma-xyz-m", "0.1", "0.1",
                                             "0.2", "--force"])
        assert r.exit_code == 0, r.output
        c = read_control_points(root / "control" / "points.csv")
        assert set(c.kind) == {kind}, heights
        assert ("taken as not measured" in r.output) == (kind == "horizontal")


def test_crs_lines_and_unnamed_points(tmp_path):
    """'WGS84 UTM 11N' is EPSG:32611; points without gcp_name are grouped by their coordinates; a NaN height
    makes a horizontal control point."""
    f = tmp_path / "gcp_list.txt"
    f.write_text("# made by hand\nWGS84 UTM 11N\n235269.88 3811198.11 12.5 10 20 a.jpg\n"
                 "235269.88 3811198.11 12.5 30 40 b.jpg\n235262.54 3811203.5 NaN 50 60 a.jpg\n")
    root = _fresh(tmp_path, crs="EPSG:32611")
    import_files(root, "odm", [f], ImportSettings(sigma_xyz_m=(0.1, 0.1, 0.2)))
    c = read_control_points(root / "control" / "points.csv")
    assert list(c.id) == ["gcp1", "gcp2"] and list(c.kind) == ["full", "horizontal"]
    assert np.allclose(c.xyz_m[0], [235269.88, 3811198.11, 12.5])
    o = read_image_points(root / "control" / "image_points.csv")
    assert list(o.point_id) == ["gcp1", "gcp1", "gcp2"] and list(o.image_id) == ["a", "b", "a"]


def test_a_gcp_list_without_its_crs_line_takes_the_crs_given(tmp_path):
    """s95: `--crs` ("CRS of FILES when they carry none") refused a gcp_list.txt without its header line as "first
    line ... is not a CRS"."""
    f = tmp_path / "gcp_list.txt"
    f.write_text("235269.88 3811198.11 12.5 10 20 a.jpg p\n235269.88 3811198.11 12.5 30 40 b.jpg p\n")
    root = _fresh(tmp_path, crs="EPSG:32611")
    import_files(root, "odm", [f], ImportSettings(sigma_xyz_m=(0.1, 0.1, 0.2), crs="EPSG:32611"))
    c = read_control_points(root / "control" / "points.csv")
    assert list(c.id) == ["p"] and np.allclose(c.xyz_m[0], [235269.88, 3811198.11, 12.5])
    # a file with its CRS line still refuses a --crs that only repeats it (the option is for files that carry none)
    f.write_text("EPSG:32611\n" + f.read_text())
    from aerotri.core.errors import OptionError

    with pytest.raises(OptionError, match="the file names its CRS"):
        import_files(_fresh(tmp_path, crs="EPSG:32611", name="headed"), "odm", [f],
                     ImportSettings(sigma_xyz_m=(0.1, 0.1, 0.2), crs="EPSG:32611"))


def test_a_line_without_a_name_at_a_named_point_s_coordinates_is_that_point(tmp_path):
    """Kite trial: a line whose gcp_name was lost, at gcp09's coordinates, became an 11th point 'gcp1' without a word.
    It is gcp09 (as OpenSfM groups lines by their coordinates), said on the console naming the line; a nameless line
    at new coordinates is named past the names the file uses (here 'gcp1' is one: 'gcp2')."""
    f = tmp_path / "gcp_list.txt"
    f.write_text("EPSG:32611\n235269.88 3811198.11 12.5 10 20 a.jpg gcp09\n"
                 "235269.88 3811198.11 12.5 30 40 b.jpg\n235262.54 3811203.5 11.0 50 60 a.jpg gcp1\n"
                 "235250.00 3811210.0 11.0 70 80 b.jpg\n")
    root = _fresh(tmp_path, crs="EPSG:32611")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(f), "--sigma-xyz-m", "0.1", "0.1",
                                         "0.2"])
    assert r.exit_code == 0, r.output
    assert "gcp_list.txt:3: no gcp_name: taken as point 'gcp09'" in r.output
    c = read_control_points(root / "control" / "points.csv")
    assert list(c.id) == ["gcp09", "gcp1", "gcp2"]
    o = read_image_points(root / "control" / "image_points.csv")
    assert list(o.point_id) == ["gcp09", "gcp09", "gcp1", "gcp2"]


def test_one_point_spelled_two_ways_is_one_control_point(tmp_path):
    """Trial-messy F16: 'gcp01' on one line and 'GCP01' on another were two control points of one ray each at the same
    coordinates (the report counted 5 control points for 4 targets). Ids match as the report matches them (case, a
    number's leading zeros): one point, spelled as first written; at other coordinates refused naming both."""
    f = tmp_path / "gcp_list.txt"
    f.write_text("EPSG:32611\n235269.88 3811198.11 12.5 10 20 a.jpg gcp01\n"
                 "235269.88 3811198.11 12.5 30 40 b.jpg GCP01\n235262.54 3811203.5 11.0 50 60 a.jpg 007\n"
                 "235262.54 3811203.5 11.0 70 80 b.jpg 7\n")
    root = _fresh(tmp_path, crs="EPSG:32611")
    import_files(root, "odm", [f], ImportSettings(sigma_xyz_m=(0.1, 0.1, 0.2)))
    c = read_control_points(root / "control" / "points.csv")
    assert list(c.id) == ["gcp01", "007"]
    o = read_image_points(root / "control" / "image_points.csv")
    assert list(o.point_id) == ["gcp01", "gcp01", "007", "007"] and list(o.image_id) == ["a", "b", "a", "b"]
    f.write_text("EPSG:32611\n235269.88 3811198.11 12.5 10 20 a.jpg gcp01\n"
                 "235279.88 3811198.11 12.5 30 40 b.jpg GCP01\n")
    root2 = _fresh(tmp_path, crs="EPSG:32611", name="p2")
    with pytest.raises(InputError, match=r":3: point 'gcp01' \(written 'GCP01'.*has the coordinates"):
        import_files(root2, "odm", [f], ImportSettings(sigma_xyz_m=(0.1, 0.1, 0.2)))


@pytest.mark.parametrize("text, error, message", [
    ("", InputError, "empty"),
    ("UTM somewhere\n1 2 3 4 5 a.jpg p\n", InputError, ":1: first line 'UTM somewhere' is not a CRS"),
    ("EPSG:99999\n1 2 3 4 5 a.jpg p\n", CrsError, "unknown CRS"),
    ("EPSG:32611\n235269 3811198 0 4 a.jpg\n", InputError, ":2: 5 fields"),
    ("EPSG:32611\n235269 3811198 0 4 x a.jpg p\n", InputError, ":2: non-numeric"),
    ("EPSG:32611\nnan 3811198 0 4 5 a.jpg p\n", InputError, ":2: NaN or infinite"),
    ("EPSG:32611\n235269 3811198 0 4 5 a.jpg p\n235270 3811198 0 4 5 b.jpg p\n", InputError, ":3: point 'p' has the coordinates"),
    # the first line's coordinates as written (trial-kite: '%g' gave "235258 3.81122e+06 0")
    ("EPSG:32611\n235257.74 3811222.65 0 4 5 a.jpg p\n235262.74 3811222.65 0 4 5 b.jpg p\n", InputError,
     "but 235257.74 3811222.65 0.0 on line 2"),
    ("EPSG:32611\n235269 3811198 0 4 5 a.jpg p\n235269 3811198 0 6 7 a.jpg p\n", InputError, ":3: point 'p' measured twice"),
    ("EPSG:32611\n235269 3811198 0 4 5 a.jpg p\n235279 3811198 0 5.5 5.5 a.jpg q\n", InputError,
     r":3: points 'p' and 'q' are measured 1.6 px apart in frame 'a' \(lines 2 and 3\)"),
    ("EPSG:32611\n", InputError, "no measurement lines"),
    # no CRS line and no --crs (s95)
    ("235269 3811198 0 4 5 a.jpg p\n", InputError, ":1: a point line where the CRS line belongs .* give the CRS "
     "with --crs"),
    # latitude first under a geographic header (trial-messy F4: "point 1 could not be transformed", no file, no line)
    ("EPSG:4326\n34.4138 -119.8489 10 4 5 a.jpg p\n34.4138 -119.8489 10 6 7 b.jpg p\n", InputError,
     r"gcp_list.txt: line 2 \(point p\): \(34.414, -119.849\) is not a longitude/latitude.*latitude first\?"),
])
def test_bad_gcp_lists_are_refused(tmp_path, text, error, message):
    f = tmp_path / "gcp_list.txt"
    f.write_text(text)
    root = _fresh(tmp_path, crs="EPSG:32611")
    with pytest.raises(error, match=message):
        import_files(root, "odm", [f], ImportSettings(sigma_xyz_m=(0.1, 0.1, 0.2)))
    assert not (root / "control").exists()


def test_accuracy_is_required_and_the_command_says_so(tmp_path):
    f = tmp_path / "gcp_list.txt"
    f.write_text("EPSG:32611\n235269 3811198 0 4 5 a.jpg p\n")
    root = _fresh(tmp_path, crs="EPSG:32611")
    with pytest.raises(OptionError, match="--sigma-xyz-m"):
        import_files(root, "odm", [f])
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(f)])
    assert r.exit_code == 2 and "--sigma-xyz-m" in r.output and "Traceback" not in r.output
    assert "[control] sigma_xy_m, sigma_z_m" in r.output


def test_the_projects_control_sigmas_stand_in_for_the_missing_accuracies(tmp_path):
    """Trial-messy F10: with [control] sigma_xy_m / sigma_z_m in project.toml ("imports without accuracies") the ODM
    import still demanded --sigma-xyz-m; PAT-B took them. Now both; --sigma-xyz-m still decides when given."""
    f = tmp_path / "gcp_list.txt"
    f.write_text("EPSG:32611\n235269 3811198 12 4 5 a.jpg p\n235269 3811198 12 6 7 b.jpg p\n")
    root = _fresh(tmp_path, crs="EPSG:32611")
    (root / "project.toml").write_text((root / "project.toml").read_text()
                                       + "\n[control]\nsigma_xy_m = 0.03\nsigma_z_m = 0.05\n")
    import_files(root, "odm", [f])
    assert read_control_points(root / "control" / "points.csv").sigma_m.tolist() == [[0.03, 0.03, 0.05]]
    root2 = _fresh(tmp_path, crs="EPSG:32611", name="p2")
    (root2 / "project.toml").write_text((root / "project.toml").read_text())
    import_files(root2, "odm", [f], ImportSettings(sigma_xyz_m=(0.1, 0.1, 0.2)))
    assert read_control_points(root2 / "control" / "points.csv").sigma_m.tolist() == [[0.1, 0.1, 0.2]]
