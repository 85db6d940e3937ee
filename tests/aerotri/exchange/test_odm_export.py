"""``aerotri export --format odm``: the OpenSfM reconstruction (orientations, camera, points, reference_lla) against
OpenSfM's documented formulas written out here, its round trip through ``aerotri import --format opensfm``, the
ground control, check points and rejected measurements, a block without control, and the Tuniu reconstruction
made by ODM imported and written again."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from aerotri.cli import main as aerotri_cli
from aerotri.core.project import Project
from aerotri.exchange import ImportSettings, export_project, import_files, opensfm
from aerotri.exchange.adjusted import read_adjusted_block
from aerotri.geom.camera import oriented_camera
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo
from aerotri.geom.observations import read_control_points, read_image_points


def _topocentric(xyz_map, crs, ref):
    """Map coordinates -> OpenSfM's topocentric frame (pyproj to ECEF, then the east/north/up rows at the
    reference: opensfm/geo.py ecef_from_topocentric_transform, transposed)."""
    from pyproj import CRS, Transformer

    ecef = np.column_stack(Transformer.from_crs(CRS(crs).to_3d(), CRS("EPSG:4978"), always_xy=True).transform(*xyz_map.T))
    ecef0 = np.array(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(
        ref["longitude"], ref["latitude"], ref["altitude"]))
    la, lo = np.radians(ref["latitude"]), np.radians(ref["longitude"])
    R = np.array([[-np.sin(lo), np.cos(lo), 0], [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                  [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])
    return (ecef - ecef0) @ R.T


def _opensfm_pixels(cam, shot, X_topo):
    """OpenSfM's brown projection (doc/source/geometry.rst) to pixels (origin: centre of the top-left pixel)."""
    R = Rotation.from_rotvec(shot["rotation"]).as_matrix()
    p = X_topo @ R.T + np.array(shot["translation"])
    xn, yn = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    r2 = xn ** 2 + yn ** 2
    rad = 1 + r2 * (cam["k1"] + r2 * (cam["k2"] + r2 * cam["k3"]))
    xd = xn * rad + 2 * cam["p1"] * xn * yn + cam["p2"] * (r2 + 2 * xn ** 2)
    yd = yn * rad + cam["p1"] * (r2 + 2 * yn ** 2) + 2 * cam["p2"] * xn * yn
    w, h = cam["width"], cam["height"]
    s = max(w, h)
    return np.column_stack([(cam["focal_x"] * xd + cam["c_x"]) * s + (w - 1) / 2,
                            (cam["focal_y"] * yd + cam["c_y"]) * s + (h - 1) / 2])


def _rotation_deg(Ra, Rb):
    """Angle (degrees) of the rotation between two stacks of rotation matrices."""
    return np.degrees(Rotation.from_matrix(np.swapaxes(Ra, -1, -2) @ Rb).magnitude())  # not arccos(trace): exact near 0


@pytest.fixture(scope="module")
def exported(adjusted_tiny, tmp_path_factory):
    root, ba = adjusted_tiny
    out = tmp_path_factory.mktemp("odm_exp")
    export_project(root, ["odm"], out)
    return root, out / "odm", ba


def test_reconstruction_is_opensfm_s(exported):
    """Points: the adjusted object points in OpenSfM's topocentric frame (pyproj's ECEF, 1e-6 m); shots and camera:
    OpenSfM's projection of the exported points reproduces the measurements the adjustment kept with its own
    residuals (RMS within 20 % of the adjustment's)."""
    import csv

    root, odm, ba = exported
    (rec,) = json.loads((odm / "opensfm" / "reconstruction.json").read_text())
    blk = read_adjusted_block(root)
    ref = rec["reference_lla"]
    assert ref == json.loads((odm / "opensfm" / "reference_lla.json").read_text())
    rows = list(csv.DictReader(open(root / "at" / "object_points.csv")))
    want = _topocentric(np.array([[float(r[k]) for k in "xyz"] for r in rows]), blk.crs, ref)
    got = np.array([rec["points"][r["id"]]["coordinates"] for r in rows])
    assert len(rec["points"]) == len(rows) and np.abs(got - want).max() < 1e-6
    (cam_id, cam), = rec["cameras"].items()
    assert json.loads((odm / "cameras.json").read_text()) == {cam_id: cam} and cam["projection_type"] == "brown"
    assert len(rec["shots"]) == len(blk.image_id)
    topo = {r["id"]: p for r, p in zip(rows, want)}
    res = []
    for i, iid in enumerate(blk.image_id):
        k = np.flatnonzero(blk.obs_image == i)
        X = np.array([topo[str(blk.point_id[j])] for j in blk.obs_point[k]])
        res.append(_opensfm_pixels(cam, rec["shots"][iid], X) - blk.obs_xy_px[k])
        assert rec["shots"][iid]["camera"] == cam_id and "gps_position" in rec["shots"][iid]
    rms = float(np.sqrt(np.mean(np.vstack(res) ** 2)))
    rms_adj = float(np.sqrt(np.mean(ba.result.residual_px[ba.result.obs_active] ** 2)))
    assert abs(rms - rms_adj) < 0.2 * rms_adj, (rms, rms_adj)
    # gps_position is OpenSfM's prior of the camera centre: gnss.txt's antenna reduced by the lever arm at the shot's
    # attitude (trial s100 ex F1: the antennas were written, 1.46 m above the centres on the demo)
    from scipy.spatial.transform import Rotation

    from aerotri.core.project import Project
    from aerotri.geom.eo import read_gnss
    from aerotri.geom.rotation import FLIP_YZ

    g = read_gnss(root / "gnss.txt")
    antenna = dict(zip(g.image_id, _topocentric(g.position_m, blk.crs, ref)))
    arm = FLIP_YZ @ np.asarray(Project.open(root).gnss.lever_arm_m, float)
    assert np.linalg.norm(arm) > 1.0  # (tiny's antenna, 1.45 m above the centre)
    for iid in blk.image_id:
        shot = rec["shots"][iid]
        R_cv = Rotation.from_rotvec(shot["rotation"]).as_matrix().T
        np.testing.assert_allclose(np.asarray(shot["gps_position"]) + R_cv @ arm, antenna[iid], atol=1e-6)


def test_round_trip_through_the_opensfm_import(exported, tmp_path, fresh_project):
    """Export -> import: the orientations back to 1e-6 m and 1e-6 degrees (in memory; the files keep 0.1 mm and
    1e-7 degrees), the camera's pixel geometry to 1e-9; no gnss.txt without --as-gnss."""
    root, odm, _ = exported
    p = Project.open(root)
    dst = fresh_project(root, tmp_path / "p")
    block = opensfm.read([odm / "opensfm" / "reconstruction.json"], Project.open(dst), ImportSettings())
    eo = read_eo(p.eo_path)
    assert block.eo.image_id == eo.image_id
    assert np.abs(block.eo.centre_m - eo.centre_m).max() < 1e-6
    assert _rotation_deg(block.eo.rotations(), eo.rotations()).max() < 1e-6
    cam, got = oriented_camera(p)[0], block.camera
    for k in ("focal_px", "cx_px", "cy_px", "k1", "k2", "k3", "p1", "p2"):
        assert getattr(got, k) == pytest.approx(getattr(cam, k), rel=1e-9, abs=1e-12), k
    r = CliRunner().invoke(aerotri_cli, ["import", str(dst), "--format", "opensfm",
                                         str(odm / "opensfm" / "reconstruction.json")])
    assert r.exit_code == 0, r.output
    back = read_eo(dst / "imported" / "eo.txt")
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4 and _rotation_deg(back.rotations(), eo.rotations()).max() < 2e-7
    assert not (dst / "gnss.txt").exists()


def test_control_check_points_and_rejected_measurements(adjusted_with_rejections, tmp_path):
    """gcp_list.txt holds the control the adjustment used and the measurements it kept; the check points go to
    gcp_list_check.txt; the removed measurement (gcp03, 40 px) and those of the rejected point (gcp01, shifted 3 m)
    go to gcp_list_rejected.txt with the reason, and the console names each. Every control and check measurement
    is in exactly one of the three files."""
    root, _ = adjusted_with_rejections
    report = json.loads((root / "at" / "report.json").read_text())
    removed = {(x["point_id"], x["image_id"]) for x in report["removed_observations"] if not x["point_id"].startswith("t")}
    rejected_points = {x["id"] for x in report["rejected_control"]}
    assert "gcp03" in {p for p, _ in removed} and "gcp01" in rejected_points
    r = CliRunner().invoke(aerotri_cli, ["export", str(root), "--format", "odm", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output

    def rows(name):
        lines = (tmp_path / "odm" / name).read_text().splitlines()
        assert lines[0] == "EPSG:32649"
        return [ln.split("\t") for ln in lines[1:]]

    kept, check, rejected = rows("gcp_list.txt"), rows("gcp_list_check.txt"), rows("gcp_list_rejected.txt")
    keys = lambda rs: {(x[6], x[5]) for x in rs}  # noqa: E731  (point, image)
    assert not rejected_points & {x[6] for x in kept} and not keys(kept) & removed
    assert removed <= keys(rejected) and {x[6] for x in rejected} == rejected_points | {p for p, _ in removed}
    why = {(x[6], x[5]): x[7] for x in rejected}
    assert all("data snooping" in why[k] for k in removed)
    assert all("rejected by the adjustment" in w for k, w in why.items() if k[0] in rejected_points and k not in removed)
    for p, i in why:
        assert f"measurement of {p} in {i} left out of gcp_list.txt" in r.output
    cp = read_control_points(root / "control" / "points.csv")
    assert {x[6] for x in check} == set(cp.id[cp.kind == "check"])
    obs = read_image_points(root / "control" / "image_points.csv")
    all_obs = {(p, i) for p, i in zip(obs.point_id, obs.image_id) if p in set(cp.id)}
    assert len(kept) + len(check) + len(rejected) == len(all_obs)
    assert keys(kept) | keys(check) | keys(rejected) == all_obs


def test_block_without_control(adjusted_without_control, tmp_path):
    """No control/ at all: the reconstruction (with the shots' GNSS) and the camera, no gcp_list.txt, and the
    console says why."""
    root, _ = adjusted_without_control
    r = CliRunner().invoke(aerotri_cli, ["export", str(root), "--format", "odm", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert "no odm/gcp_list.txt" in r.output
    assert not (tmp_path / "odm" / "gcp_list.txt").exists()
    (rec,) = json.loads((tmp_path / "odm" / "opensfm" / "reconstruction.json").read_text())
    assert len(rec["shots"]) == 10 and all("gps_position" in s and s["gps_dop"] > 0 for s in rec["shots"].values())
    assert len(rec["points"]) > 100
    # a format with nothing to write for the block says so (trial-odm: "exported micmac", no file)
    r = CliRunner().invoke(aerotri_cli, ["export", str(root), "--format", "micmac", "--out", str(tmp_path / "mm")])
    assert r.exit_code == 0 and "micmac: nothing to write for this block" in r.output, r.output
    assert not (tmp_path / "mm" / "micmac").exists()


@pytest.mark.realdata
def test_tuniu_imported_and_written_again(shared_data, tmp_path):
    """ODM's reconstruction of the Tuniu frames (its georeferenced one: UTM 51N minus the whole metres reference_lla
    marks; trial-odm) imported (camera.toml, imported/eo.txt; with --as-gnss the shots' gps_position with gps_dop)
    and written again from the project files as OpenSfM's topocentric reconstruction at the same reference_lla: the
    same camera, the same GNSS (2e-4 m; gps_position is topocentric in both), and the ODM surface model's points in
    the frames' field of view projected by OpenSfM through both within 0.1 px (the original in the grid, ours on the
    earth's tangent plane: the map's scale, 1.00015 here); from the import in memory the same shots as through
    eo.txt to 1e-6 m and 1e-6 degrees."""
    import pyproj
    import rasterio

    from aerotri.geom.eo import read_gnss

    data = shared_data / "tuniu_drone"
    src = data / "opensfm" / "reconstruction.json"
    (orig,) = json.loads(src.read_text())
    root = tmp_path / "p"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "tuniu"\ncrs = "EPSG:32651"\n')
    shutil.copytree(data / "images", root / "images")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "opensfm", str(src), "--as-gnss"])
    assert r.exit_code == 0 and "ODM's georeferenced solution (EPSG:32651 minus the offset 292632, 2731169" in \
        " ".join(r.output.split()), r.output
    project = Project.open(root)
    eo, cam, gnss = read_eo(root / "imported" / "eo.txt"), read_camera(root / "camera.toml"), read_gnss(root / "gnss.txt")
    assert np.allclose(gnss.sigma_m, [[s["gps_dop"]] * 3 for _, s in sorted(orig["shots"].items())], atol=5e-5)  # 0.1 mm
    again = opensfm.reconstruction(eo, cam, project, orig["reference_lla"], gnss=gnss)
    (cid, c0), = orig["cameras"].items()
    (cid1, c1), = again["cameras"].items()
    assert cid1 == cid and c1.keys() == c0.keys()
    for k in c0:
        assert c1[k] == (c0[k] if isinstance(c0[k], str) else pytest.approx(c0[k], rel=1e-12, abs=1e-15)), k
    assert again["shots"].keys() == orig["shots"].keys()
    xc, yc = cam.pixel_to_normalized(np.array([-0.5, cam.width - 0.5] * 2), np.repeat([-0.5, cam.height - 0.5], 2))
    r_max = np.hypot(xc, yc).max()
    ref = orig["reference_lla"]
    e0, n0 = pyproj.Transformer.from_crs(4326, 32651, always_xy=True).transform(ref["longitude"], ref["latitude"])
    with rasterio.open(data / "odm_dem" / "dsm.tif") as ds:
        z = ds.read(1, masked=True)
        rows, cols = np.mgrid[0:ds.height:9, 0:ds.width:9]
        ok = ~np.ma.getmaskarray(z)[rows, cols]
        xs, ys = rasterio.transform.xy(ds.transform, rows[ok], cols[ok])
        utm = np.column_stack([xs, ys, z[rows, cols][ok].filled(np.nan)])
    in_grid = utm - [round(e0), round(n0), 0.0]
    on_plane = _topocentric(utm, "EPSG:32651", ref)
    for sid, s0 in orig["shots"].items():
        s1 = again["shots"][sid]
        assert np.abs(np.array(s1["gps_position"]) - s0["gps_position"]).max() < 2e-4
        u0, u1 = _opensfm_pixels(c0, s0, in_grid), _opensfm_pixels(c1, s1, on_plane)
        R0 = Rotation.from_rotvec(s0["rotation"]).as_matrix()
        d = (in_grid + R0.T @ np.array(s0["translation"])) @ R0.T
        # the field of view: rays within the undistorted image corners (beyond, the Brown polynomial folds back)
        seen = (d[:, 2] > 0) & (np.hypot(d[:, 0], d[:, 1]) < r_max * d[:, 2])
        assert seen.sum() > 500 and np.abs(u1 - u0)[seen].max() < 0.1
    # in memory (before eo.txt rounds): 1e-6 m and 1e-6 degrees
    block = opensfm.read([src], project, ImportSettings())
    mem = opensfm.reconstruction(block.eo, block.camera, project, orig["reference_lla"])
    for sid, s0 in again["shots"].items():
        s1 = mem["shots"][sid]
        R0, R1 = (Rotation.from_rotvec(s["rotation"]).as_matrix()[None] for s in (s0, s1))
        assert _rotation_deg(R0, R1)[0] < 1e-6
        assert np.abs(-R1[0].T @ np.array(s1["translation"]) + R0[0].T @ np.array(s0["translation"])).max() < 2e-4


def test_plan_only_control_is_never_given_a_height_of_0(adjusted_tiny, tmp_path):
    """Plan-only control (the kite's targets: control/points.csv holds z = 0, kind horizontal) is written as each
    format allows, never as a height of 0: ODM's gcp_list.txt leaves it out and the console names the points, no
    NaN text file is written (OpenSfM's text reader groups lines by (x, y, z): with z NaN each measurement would be
    a point of its own, unused), OpenSfM's JSON gives it without altitude and each plan-only point, as OpenSfM's
    JSON reader groups it (one point per entry, its observations inside), with every measurement the adjustment
    kept of it; Metashape x y without z, MicMac sZ = -1; the full control keeps its heights."""
    import xml.etree.ElementTree as ET

    src, _ = adjusted_tiny
    root = tmp_path / "p"
    shutil.copytree(src, root)
    path = root / "control" / "points.csv"
    head, *rows = path.read_text().splitlines()
    plan = []
    for k, row in enumerate(rows):
        f = row.split(",")
        if f[1] == "full" and len(plan) < 2:
            f[1], f[4] = "horizontal", "0"
            plan.append(f[0])
            rows[k] = ",".join(f)
    path.write_text("\n".join([head] + rows) + "\n")
    cp = read_control_points(path)
    full = set(cp.id[cp.kind == "full"])
    report = json.loads((root / "at" / "report.json").read_text())  # as the adjustment writes plan-only control
    for c in report["control_points"]:
        if c["id"] in plan:
            c["kind"], c["given_m"][2], c["residual_m"][2] = "horizontal", 0.0, None
    (root / "at" / "report.json").write_text(json.dumps(report))
    adjusted_z = {c["id"]: c["adjusted_m"][2] for c in report["control_points"]}
    r = CliRunner().invoke(aerotri_cli, ["export", str(root), "--format", "odm", "--format", "metashape",
                                         "--format", "micmac", "--format", "gpkg", "--out", str(tmp_path / "x")])
    assert r.exit_code == 0, r.output
    assert f"2 plan-only control points ({', '.join(plan)}) have no height" in r.output
    odm = tmp_path / "x" / "odm"
    listed = [ln.split("\t") for ln in (odm / "gcp_list.txt").read_text().splitlines()[1:]]
    assert {x[6] for x in listed} == full
    assert not (odm / "gcp_list_plan_only.txt").exists()
    assert "NaN" not in "".join(f.read_text() for f in odm.glob("*.txt") if f.name != "gcp_list_rejected.txt")
    assert "ground_control_points.json (without altitude" in r.output
    assert "ODM: --gcp odm/gcp_list.txt" in r.output and "OpenSfM alone: gcp_list.txt and the JSON" in r.output
    gcps = json.loads((odm / "opensfm" / "ground_control_points.json").read_text())["points"]
    # only the points gcp_list.txt lacks: OpenSfM's load_ground_control_points returns gcp_list.txt's points plus
    # the JSON's, and ODM copies --gcp to opensfm/gcp_list.txt beside it (reviewer 10: every 3D point twice)
    assert {g["id"] for g in gcps} == set(plan) and len(gcps) == len(plan)
    assert not any("altitude" in g["position"] for g in gcps)
    read_by_opensfm = [x[6] for x in listed] + [g["id"] for g in gcps]
    assert set(read_by_opensfm) == full | set(plan) and not ({x[6] for x in listed} & {g["id"] for g in gcps})
    measured = read_image_points(Project.open(root).control_image_points_path)
    removed = {(x["point_id"], x["image_id"]) for x in report["removed_observations"]}
    for g in gcps:
        if g["id"] in plan:  # OpenSfM's JSON reader: has_altitude = "altitude" in position, observations inside
            images = [i for p, i in zip(measured.point_id.astype(str), measured.image_id.astype(str))
                      if p == g["id"] and (p, i) not in removed]
            shots = [o["shot_id"] for o in g["observations"]]
            assert len(shots) == len(images) >= 2 and len(set(shots)) == len(shots), (g["id"], shots, images)
    markers = ET.parse(tmp_path / "x" / "metashape" / "cameras.xml").getroot().findall(".//markers/marker")
    refs = {m.get("label"): m.find("reference") for m in markers if m.find("reference") is not None}
    assert all("z" not in refs[p].attrib for p in plan) and all("z" in refs[p].attrib for p in full)
    micmac = ET.parse(tmp_path / "x" / "micmac" / "gcp.xml").getroot()
    sz = {o.findtext("NamePt"): o.findtext("Incertitude").split()[2] for o in micmac.iter("OneAppuisDAF")}
    assert all(sz[p] == "-1" for p in plan) and all(sz[p] != "-1" for p in full)
    from pyogrio.raw import read as read_layer

    _, _, geom, fields = read_layer(tmp_path / "x" / "layers" / "block.gpkg", layer="control_points",
                                    return_fids=False)
    import shapely

    z = {pid: shapely.from_wkb(g).z for pid, g in zip(fields[0], geom)}  # point_id is the first field
    assert all(z[p] == pytest.approx(adjusted_z[p], abs=1e-3) and abs(z[p]) > 1.0 for p in plan)


def test_check_points_held_back_by_the_adjustment_go_to_the_check_list(tmp_path):
    """Trial-kite: control points held back with `adjust --check ID,...` (control/points.csv still says control)
    went to gcp_list_rejected.txt as "point not in the adjustment", beside docs/exchange.md's gcp_list_check.txt."""
    from aerotri.adjust.pipeline import run_adjustment
    from aerotri.adjust.settings import AdjustSettings
    from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

    root = write_block_project(geometric_block(2, 5, seed=7), tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=6, points_per_image=80, n_check=0, seed=2)
    cp = read_control_points(root / "control" / "points.csv")
    held = tuple(sorted(str(p) for p in cp.id)[:2])
    run_adjustment(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3, check=held))
    r = CliRunner().invoke(aerotri_cli, ["export", str(root), "--format", "odm", "--out", str(tmp_path / "x")])
    assert r.exit_code == 0, r.output
    odm = tmp_path / "x" / "odm"
    check = {ln.split("\t")[6] for ln in (odm / "gcp_list_check.txt").read_text().splitlines()[1:]}
    kept = {ln.split("\t")[6] for ln in (odm / "gcp_list.txt").read_text().splitlines()[1:]}
    assert check == set(held) and not kept & set(held)
    assert not (odm / "gcp_list_rejected.txt").exists()


def test_metashape_and_micmac_leave_the_rejected_measurements_out(adjusted_with_rejections, tmp_path):
    """Trial s96 M1: Metashape's cameras.xml pinned and MicMac's measures.xml kept the measurements the adjustment
    rejected (demo w 4.29 and 6.83), so a re-adjustment there took the blunders back; PAT-B left them out, ODM lists
    them apart. Left out now, each named in a warning; the kept and the check measurements are all there."""
    import xml.etree.ElementTree as ET

    root, _ = adjusted_with_rejections
    report = json.loads((root / "at" / "report.json").read_text())
    removed = {(x["point_id"], x["image_id"]) for x in report["removed_observations"] if not x["point_id"].startswith("t")}
    rejected_points = {x["id"] for x in report["rejected_control"]}
    r = CliRunner().invoke(aerotri_cli, ["export", str(root), "--format", "metashape", "--format", "micmac",
                                         "--format", "odm", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    odm = lambda name: {(x.split("\t")[6], x.split("\t")[5])  # noqa: E731
                        for x in (tmp_path / "odm" / name).read_text().splitlines()[1:]}
    kept, check, rejected = odm("gcp_list.txt"), odm("gcp_list_check.txt"), odm("gcp_list_rejected.txt")
    assert removed <= rejected and rejected_points <= {p for p, _ in rejected}
    micmac = set()
    for im in ET.parse(tmp_path / "micmac" / "measures.xml").getroot():
        micmac |= {(one.findtext("NamePt"), Path(im.findtext("NameIm")).stem) for one in im.iter("OneMesureAF1I")}
    assert micmac == kept | check
    doc = ET.parse(tmp_path / "metashape" / "cameras.xml").getroot()
    chunk = doc.find("chunk")
    label = {c.get("id"): c.get("label") for c in chunk.iter("camera")}
    marker = {m.get("id"): m.get("label") for m in chunk.find("markers").iter("marker")}
    metashape = {(marker[m.get("marker_id")], label[loc.get("camera_id")])
                 for m in chunk.find("frames").iter("marker") for loc in m.iter("location")}
    assert metashape == kept | check
    for fmt in ("metashape", "micmac"):
        for p, i in rejected:
            assert f"{fmt} export: measurement of {p} in {i} left out" in r.output
