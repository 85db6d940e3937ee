"""``aerotri control`` on the simulated tiny project (truth orientations, corners from the simulator truth)."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
from click.testing import CliRunner

from aerotri.geom.camera import BrownCamera
from aerotri.cli import main
from aerotri.geom.eo import read_eo
from aerotri.sim.evaluate import truth_roof_corners, write_truth_corners_csv


def project_copy(tiny_project, tmp_path):
    root = tmp_path / "p"
    root.mkdir()
    for name in ("images", "truth"):
        shutil.copytree(tiny_project / name, root / name)
    for name in ("camera.toml", "project.toml", "gnss.txt"):
        shutil.copy(tiny_project / name, root / name)
    write_truth_corners_csv(root, root / "lidar_out" / "corners.csv")
    return root


def run(root, *extra):
    args = ["control", str(root), "--eo", str(root / "truth" / "eo.txt"), "--camera", str(root / "truth" / "camera.toml"),
            "--min-frames", "2", *extra]
    return CliRunner().invoke(main, args, catch_exceptions=False)


def truth_errors(root):
    cam = BrownCamera.read(root / "truth" / "camera.toml")
    eo = read_eo(root / "truth" / "eo.txt")
    t = truth_roof_corners(root)
    pos = {p: k for k, p in enumerate(t.id)}
    errs = []
    for r in csv.DictReader(open(root / "control" / "image_points.csv")):
        i = eo.row(r["image_id"])
        x, y, _ = cam.project(t.xyz_m[pos[r["point_id"]]], eo.centre_m[i], eo.rotation(i))
        errs.append([float(r["x_px"]) - x[0], float(r["y_px"]) - y[0]])
    return np.array(errs)


def test_control_transfer_on_tiny(tiny_project, tmp_path):
    root = project_copy(tiny_project, tmp_path)
    res = run(root)
    assert res.exit_code == 0, res.output
    pts = list(csv.DictReader(open(root / "control" / "points.csv")))
    kinds = [p["kind"] for p in pts]
    assert kinds.count("full") >= 3 and kinds.count("check") >= 5
    e = truth_errors(root)
    assert len(e) >= 20
    assert np.sqrt(np.mean(np.sum(e**2, axis=1))) < 0.5  # image measurements vs true projections (px)
    rep = json.loads((root / "control" / "transfer.json").read_text())
    s = rep["summary"]
    assert s["corners_accepted"] == len(pts)
    assert s["measurements_attempted"] == s["measurements_accepted_in_image"] + sum(s["measurements_rejected_in_image"].values())
    html = (root / "control" / "review" / "review.html").read_text()
    assert pts[0]["id"] in html
    assert len(list((root / "control" / "review" / "chips").glob("*.png"))) == s["measurements_attempted"]

    # manual import: a corner that was not accepted, measured by hand at its true position in two frames
    accepted = {p["id"] for p in pts}
    cam = BrownCamera.read(root / "truth" / "camera.toml")
    eo = read_eo(root / "truth" / "eo.txt")
    t = truth_roof_corners(root)
    pick = None
    for k, pid in enumerate(t.id):
        if pid in accepted:
            continue
        seen = []
        for i in range(len(eo)):
            x, y, _ = cam.project(t.xyz_m[k], eo.centre_m[i], eo.rotation(i))
            if cam.inside(x, y, 20)[0]:
                seen.append((eo.image_id[i], x[0], y[0]))
        if len(seen) >= 2:
            pick = (pid, seen[:2])
            break
    assert pick is not None
    manual = tmp_path / "manual.csv"
    manual.write_text("point_id,image_id,x_px,y_px\n" + "".join(f"{pick[0]},{i},{x:.3f},{y:.3f}\n" for i, x, y in pick[1]))
    res = run(root, "--import-manual", str(manual), "--no-chips")
    assert res.exit_code == 0, res.output
    obs = [r for r in csv.DictReader(open(root / "control" / "image_points.csv")) if r["point_id"] == pick[0]]
    assert {r["image_id"] for r in obs} >= {i for i, _, _ in pick[1]}
    for r in obs:
        ref = [s for s in pick[1] if s[0] == r["image_id"]]
        if ref:
            assert abs(float(r["x_px"]) - ref[0][1]) < 1e-2 and abs(float(r["y_px"]) - ref[0][2]) < 1e-2


def test_bad_corner_file_exit_2_and_no_output(tiny_project, tmp_path):
    root = project_copy(tiny_project, tmp_path)
    path = root / "lidar_out" / "corners.csv"
    lines = path.read_text().splitlines()
    lines[3] = lines[3].replace(lines[3].split(",")[1], "abc", 1)
    path.write_text("\n".join(lines) + "\n")
    res = CliRunner().invoke(main, ["control", str(root), "--eo", str(root / "truth" / "eo.txt")])
    assert res.exit_code == 2
    assert "corners.csv:4" in res.output and "not a number" in res.output
    assert not (root / "control").exists()


def test_manual_point_unknown_is_an_input_error(tiny_project, tmp_path):
    root = project_copy(tiny_project, tmp_path)
    manual = tmp_path / "manual.csv"
    manual.write_text("point_id,image_id,x_px,y_px\nNOPE,s01_001,10,10\n")
    res = run(root, "--import-manual", str(manual))
    assert res.exit_code == 2 and "NOPE" in res.output
    assert not (root / "control").exists()


def test_foreign_orientations_take_the_nominal_camera_not_the_adjusted_one(tiny_project, tmp_path):
    """``aerotri control --eo OTHER``: at/camera.toml was estimated with at/eo.txt and belongs to no other
    orientations. Before, the control stage took it for any --eo (a self-calibration 30 % off in focal length
    put every prediction off its corner: nothing measured, exit 2); now OTHER takes the nominal camera.toml,
    and at/eo.txt itself (however it is given) still takes at/camera.toml."""
    import dataclasses

    from aerotri.core.project import Project
    from aerotri.geom.camera import orientations_camera

    root = project_copy(tiny_project, tmp_path)
    nominal = BrownCamera.read(root / "camera.toml")
    adjusted = dataclasses.replace(nominal, focal_mm=0.7 * nominal.focal_mm)
    (root / "at").mkdir()
    (root / "at" / "camera.toml").write_text(adjusted.to_toml())
    res = CliRunner().invoke(main, ["control", str(root), "--eo", str(root / "truth" / "eo.txt"), "--min-frames", "2"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    e = truth_errors(root)
    assert len(e) >= 20 and np.sqrt(np.mean(np.sum(e**2, axis=1))) < 0.5
    shutil.copy(root / "truth" / "eo.txt", root / "at" / "eo.txt")
    project = Project.open(root)
    for eo_path in (None, root / "at" / "eo.txt", root / "at" / ".." / "at" / "eo.txt"):
        cam, source = orientations_camera(project, eo_path)
        assert cam == adjusted and source == f"{root / 'at' / 'camera.toml'} (self-calibrated)"
    cam, source = orientations_camera(project, root / "truth" / "eo.txt")
    assert cam == nominal and source == str(root / "camera.toml")
    cam, source = orientations_camera(project, root / "at" / "eo.txt", root / "truth" / "camera.toml")
    assert cam == BrownCamera.read(root / "truth" / "camera.toml") and source == str(root / "truth" / "camera.toml")
