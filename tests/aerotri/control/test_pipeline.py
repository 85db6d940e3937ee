"""The control transfer on three small rendered frames of one flat-roofed building with known corners:
measurements against the true projections, the multi-ray and LiDAR checks, the summary, the output files and
manual measurements."""

from __future__ import annotations

import csv
import dataclasses
import json
import re

import cv2
import numpy as np
import pytest

from aerotri.control.corners import LidarCorners, ManualMeasurements
from aerotri.control.chips import write_review
from aerotri.control.pipeline import output_texts, review_page, run_control, summary, transfer_control
from aerotri.control.settings import ControlSettings, LayoutSettings
from aerotri.core.errors import InputError
from aerotri.geom.camera import BrownCamera
from aerotri.geom.eo import ExteriorOrientations, write_eo

CAM = BrownCamera(focal_mm=10.0, pixel_um=10.0, width=400, height=300, name="test")
ROOF = (1000.0, 1996.0, 1012.0, 2004.0)  # x0 y0 x1 y1 of the eave outline (m)
EAVE_Z = 10.0
CORNERS = np.array([[ROOF[0], ROOF[1]], [ROOF[2], ROOF[1]], [ROOF[2], ROOF[3]], [ROOF[0], ROOF[3]]])
EO = ExteriorOrientations(["f1", "f2", "f3"], np.array([[1000.0, 2000.5, 100.0], [1006.0, 1999.5, 100.0],
                                                        [1012.0, 2000.0, 100.0]]),
                          np.array([[0.4, -0.3, 0.0], [-0.2, 0.3, 1.0], [0.3, 0.2, -0.5]]))


def render(i: int, samples: int = 4) -> np.ndarray:
    """Frame i (8-bit RGB): the roof (bright) over the ground (dark), ``samples`` x ``samples`` rays per pixel."""
    R, C = EO.rotation(i), EO.centre_m[i]
    acc = np.zeros((CAM.height, CAM.width))
    off = (np.arange(samples) + 0.5) / samples - 0.5
    yy, xx = np.mgrid[0:CAM.height, 0:CAM.width].astype(float)
    for oy in off:
        for ox in off:
            d = CAM.rays((xx + ox).ravel(), (yy + oy).ravel(), R)
            t = (EAVE_Z - C[2]) / d[:, 2]
            p = C[:2] + t[:, None] * d[:, :2]
            roof = (p[:, 0] >= ROOF[0]) & (p[:, 0] <= ROOF[2]) & (p[:, 1] >= ROOF[1]) & (p[:, 1] <= ROOF[3])
            acc += np.where(roof, 200.0, 50.0).reshape(acc.shape)
    grey = np.rint(acc / samples**2).astype(np.uint8)
    return np.dstack([grey, grey, (grey * 0.9).astype(np.uint8)])


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    d = tmp_path_factory.mktemp("control") / "images"
    d.mkdir()
    for i, iid in enumerate(EO.image_id):
        cv2.imwrite(str(d / f"{iid}.tif"), render(i)[:, :, ::-1])
    return d


def corners(z_error_m: float = 0.0, far: bool = False) -> LidarCorners:
    """The four eave corners (the first one ``z_error_m`` too high), and optionally one outside every frame."""
    xy = CORNERS if not far else np.vstack([CORNERS, [[1300.0, 2000.0]]])
    n = len(xy)
    z = np.full(n, EAVE_Z)
    z[0] += z_error_m
    return LidarCorners(np.array([f"C{k + 1}" for k in range(n)], dtype=object), np.column_stack([xy, z]),
                        np.tile([0.05, 0.05, 0.05], (n, 1)), np.tile([90.0, 0.0], (n, 1)), np.full(n, 90.0),
                        np.ones(n), np.ones(n, bool), np.array(["flat"] * n, dtype=object))


def truth_px(k: int, i: int) -> np.ndarray:
    x, y, _ = CAM.project(np.array([[*CORNERS[k], EAVE_Z]]), EO.centre_m[i], EO.rotation(i))
    return np.array([x[0], y[0]])


def test_corners_are_measured_at_their_true_projections(frames):
    res = transfer_control(corners(), CAM, EO, frames, ControlSettings(), crs=None)
    assert len(res.measurements) == 12  # 4 corners x 3 frames
    err = [np.hypot(*(np.array([m.x_px, m.y_px]) - truth_px(k, i))) for (k, i), m in res.measurements.items()]
    assert all(m.ok for m in res.measurements.values()), {key: m.reason for key, m in res.measurements.items()}
    assert np.sqrt(np.mean(np.square(err))) < 0.3 and max(err) < 0.5  # px
    for k in range(4):
        r = res.rays[k]
        assert r.ok and r.kept.all() and r.images == [0, 1, 2]
        # the intersection is the LiDAR corner (heights from a base of 6-12 m at 90 m: a few decimetres)
        assert np.abs(r.lidar_diff_m[:2]).max() < 0.05 and abs(r.lidar_diff_m[2]) < 0.5
    assert set(res.kind) <= {"full", "height", "check"}
    sm = summary(res)
    assert (sm.corners_in_file, sm.corners_measured, sm.corners_accepted) == (4, 4, 4)
    assert (sm.measurements_attempted, sm.measurements_accepted_in_image) == (12, 12)
    assert sm.control_full + sm.control_height + sm.check_points == 4
    assert sm.selected_rays_min in (0, 3) and sm.manual_measurements == 0 and sm.corners_rejected == {}


def test_a_corner_off_in_height_and_one_outside_every_frame_are_rejected(frames):
    res = transfer_control(corners(z_error_m=1.5, far=True), CAM, EO, frames, ControlSettings(), crs=None)
    assert res.rays[0].reason == "lidar_mismatch" and abs(res.rays[0].lidar_diff_m[2] + 1.5) < 0.1
    assert res.rays[4].reason == "too_few_rays" and not any(k == 4 for k, _ in res.measurements)
    assert res.kind[0] == res.kind[4] == "rejected"
    sm = summary(res)
    assert sm.corners_rejected == {"lidar_mismatch": 1, "too_few_rays": 1} and sm.corners_accepted == 3


def test_manual_measurements_replace_the_automatic_ones(frames):
    t = truth_px(1, 2) + [0.4, -0.2]
    res = transfer_control(corners(), CAM, EO, frames, ControlSettings(),
                           manual=ManualMeasurements(("C2",), ("f3",), np.array([t], float)), crs=None)
    m = res.measurements[(1, 2)]
    assert m.ok and m.reason == "manual" and (m.x_px, m.y_px) == tuple(t)
    assert summary(res).manual_measurements == 1


def test_output_files(frames):
    res = transfer_control(corners(z_error_m=1.5), CAM, EO, frames, ControlSettings(), crs=None)
    texts = output_texts(res)
    pts = list(csv.DictReader(texts.points_csv.splitlines()))
    assert [p["id"] for p in pts] == ["C2", "C3", "C4"]  # the rejected corner is no control
    assert {p["kind"] for p in pts} <= {"full", "height", "check"}
    obs = list(csv.DictReader(texts.image_points_csv.splitlines()))
    assert len(obs) == 9
    for o in obs:
        k, i = int(o["point_id"][1:]) - 1, EO.row(o["image_id"])
        assert np.hypot(*(np.array([float(o["x_px"]), float(o["y_px"])]) - truth_px(k, i))) < 0.5
    rep = json.loads(texts.transfer_json)
    assert rep["summary"] == json.loads(json.dumps(dataclasses.asdict(summary(res))))
    assert [c["id"] for c in rep["corners"]] == ["C1", "C2", "C3", "C4"]
    assert rep["corners"][0]["reason"] == "lidar_mismatch"
    assert all(f["status"] == "accepted" for c in rep["corners"][1:] for f in c["frames"].values())
    for t in rep["layout_targets"]:
        assert t["corner"] in (None, "C2", "C3", "C4")
    # without check points only the control remains
    no_checks = list(csv.DictReader(output_texts(res, checks=False).points_csv.splitlines()))
    assert [p for p in pts if p["kind"] != "check"] == no_checks


def test_run_control_writes_every_output(frames, tmp_path):
    root = tmp_path / "p"
    (root / "lidar_out").mkdir(parents=True)
    (root / "images").symlink_to(frames)
    c = corners()
    (root / "lidar_out" / "corners.csv").write_text(
        "id,x,y,z,sx_m,sy_m,sz_m,edge1_deg,edge2_deg,angle_deg,score,usable\n"
        + "".join(f"{c.id[k]},{x:.3f},{y:.3f},{z:.3f},0.05,0.05,0.05,90,0,90,1.0,1\n"
                  for k, (x, y, z) in enumerate(c.xyz_m)))
    write_eo(root / "eo.txt", EO)
    (root / "camera.toml").write_text(CAM.to_toml())
    sm = run_control(root, eo_path=root / "eo.txt", camera_path=root / "camera.toml")
    assert sm.corners_accepted == 4
    for name in ("points.csv", "image_points.csv", "transfer.json", "review/review.html"):
        assert (root / "control" / name).is_file(), name
    assert len(list((root / "control" / "review" / "chips").glob("*.png"))) == 12
    # a frame of another size than the camera's is refused by name, and nothing is written
    (root / "images").unlink()
    (root / "images").mkdir()
    for iid in EO.image_id:
        cv2.imwrite(str(root / "images" / f"{iid}.tif"), np.zeros((150, 200, 3), np.uint8))
    before = (root / "control" / "points.csv").read_text()
    with pytest.raises(InputError, match="f1.tif: image is 200 x 150 px but the camera says 400 x 300 px"):
        run_control(root, eo_path=root / "eo.txt", camera_path=root / "camera.toml")
    assert (root / "control" / "points.csv").read_text() == before


def test_an_empty_layout_target_measures_fallback_corners_and_says_why_when_it_stays_empty(frames):
    # one usable corner (C1); a search radius of 2 baselines (12 m) reaches two corners from each target
    c = corners(z_error_m=1.5, far=True)
    c.usable[:] = False
    c.usable[0] = True
    res = transfer_control(c, CAM, EO, frames, ControlSettings(layout=LayoutSettings(search_radius_baselines=2.0)), crs=None)
    sm = summary(res)
    # C1 fails the LiDAR check, so every target was empty: C2-C4 (not usable) were measured and fill three
    assert res.rays[0].reason == "lidar_mismatch"
    assert sm.corners_measured_fallback == 3 and sorted(res.rays) == [0, 1, 2, 3]
    filled = [t for t in res.targets if t.corner is not None]
    assert sorted(t.corner for t in filled) == [1, 2, 3] and all(t.tier == "lower_score" for t in filled)
    assert sm.layout_targets_by_tier == {"lower_score": 3} and sm.layout_targets_unfilled == 1
    empty = [t for t in res.targets if t.corner is None][0]
    assert empty.empty_reason == ("2 LiDAR corners within 12.0 m: 1 rejected by consistency (lidar mismatch); "
                                  "1 control for another target")
    pts = list(csv.DictReader(output_texts(res).points_csv.splitlines()))
    assert sorted(p["id"] for p in pts) == ["C2", "C3", "C4"]
    rep = json.loads(output_texts(res).transfer_json)
    assert [c["fallback"] for c in rep["corners"]] == [False, True, True, True]
    assert sum(t["empty_reason"] is not None for t in rep["layout_targets"]) == 1

    off = transfer_control(c, CAM, EO, frames, ControlSettings(layout=LayoutSettings(search_radius_baselines=2.0,
                                                                                     fallback=False)), crs=None)
    assert sorted(off.rays) == [0] and all(t.corner is None for t in off.targets)
    assert off.targets[0].empty_reason == ("2 LiDAR corners within 12.0 m: 1 rejected by consistency (lidar "
                                           "mismatch); 1 not measured (not marked usable; fallback off)")
    # out of reach: the nearest corner is named
    near = transfer_control(c, CAM, EO, frames, ControlSettings(layout=LayoutSettings(search_radius_baselines=0.2)), crs=None)
    assert re.fullmatch(r"no LiDAR roof corner within 1\.2 m of the target \(nearest \d+\.\d m away\)",
                        near.targets[0].empty_reason)


def test_review_page_lists_the_rejections_as_a_table_not_a_python_dict(frames, tmp_path):
    res = transfer_control(corners(z_error_m=1.5, far=True), CAM, EO, frames, ControlSettings(), crs=None)
    page = review_page(res, frames)
    assert [(r.what, r.reason, r.count) for r in page.rejections] == [
        ("corner", "lidar_mismatch", 1), ("corner", "too_few_rays", 1), ("corner", "too_few_rays: in_no_frame", 1)]
    assert page.rejections[0].meaning == "the rays meet away from the LiDAR corner"
    write_review(tmp_path, "p", page.summary, page.corners, page.chips, page.rejections)
    html = (tmp_path / "review.html").read_text()
    assert "{" not in page.summary and "&#39;" not in html and "{&" not in html
    assert "<td>corner</td><td>too_few_rays: in_no_frame</td><td style=\"text-align:right\">1</td><td>of those: in no " \
           "frame</td>" in html
    assert "2 corners and 0 image measurements rejected (table below)" in page.summary
    assert summary(res).command_line().endswith("rejected corners: lidar_mismatch 1, too_few_rays 1")


def test_too_few_rays_by_cause(frames):
    res = transfer_control(corners(far=True), CAM, EO, frames, ControlSettings(), crs=None)
    assert summary(res).too_few_rays_by_cause == {"in_no_frame": 1}


def test_fallback_corners_are_measured_near_targets_the_rule_did_not_fill():
    # a target filled from a later tier (here: a usable corner in two frames, height only) must still try the
    # lower-scored corners near it, which come first
    from aerotri.control.layout import LayoutTarget
    from aerotri.control.pipeline import _near_unfilled_targets

    c = corners(far=True)
    todo = np.array([False, True, True, True, True])
    t = [LayoutTarget("full", 1000.0, 1996.0, corner=0, tier="usable", search_radius_m=20.0),
         LayoutTarget("full", 1300.0, 2000.0, corner=4, tier="height_only", search_radius_m=5.0)]
    assert _near_unfilled_targets(c, t, todo).tolist() == [4]
    t[1] = LayoutTarget("full", 1012.0, 2004.0, search_radius_m=5.0)  # empty: C3 is within reach, C1 not todo
    assert _near_unfilled_targets(c, t, todo).tolist() == [2]
