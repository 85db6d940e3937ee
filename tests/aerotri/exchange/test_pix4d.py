"""Pix4D image geolocation and orientation file: its rows put the control points where they were measured when
read with Pix4D's own convention (coded here independently of aerotri.geom.rotation), and carry the adjustment's
sigmas."""

from __future__ import annotations

import numpy as np

from aerotri.core.project import Project
from aerotri.exchange import export_project
from aerotri.exchange.poses import adjusted_orientations
from aerotri.geom.eo import read_eo
from aerotri.geom.observations import read_control_points, read_image_points


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_rows_project_the_control_where_it_was_measured(adjusted_tiny, tmp_path):
    root, _ = adjusted_tiny
    out = tmp_path / "exp"
    export_project(root, ["pix4d"], out)
    lines = (out / "pix4d" / "image_geolocation.csv").read_text().splitlines()
    assert lines[0].startswith("# imagename,X,Y,Z,omega,phi,kappa,accuracy_horz_m,accuracy_vert_m")
    rows = {r[0]: np.array(r[1:], float) for r in (ln.split(",") for ln in lines[1:])}
    assert all(len(v) == 8 for v in rows.values())
    project = Project.open(root)
    assert (out / "pix4d" / "image_geolocation.prj").read_text().startswith("PROJCRS")
    eo = read_eo(project.eo_path)
    assert len(rows) == len(eo.image_id)
    # the accuracies are the adjustment's centre sigmas
    s = eo.sigma[0, :3]
    key = next(k for k in rows if k.startswith(eo.image_id[0]))
    assert abs(rows[key][6] - np.sqrt((s[0] ** 2 + s[1] ** 2) / 2)) < 1e-4 and abs(rows[key][7] - s[2]) < 1e-4

    _, camera = adjusted_orientations(project)
    fx, fy, _, u0, v0 = camera.calibration_vector()[:5]
    ctl = read_control_points(project.control_points_path)
    xyz = dict(zip(ctl.id, ctl.xyz_m))
    obs = read_image_points(project.control_image_points_path)
    err = []
    for pid, iid, xy in zip(obs.point_id, obs.image_id, obs.xy_px):
        name = next((k for k in rows if k == iid or k.rsplit(".", 1)[0] == iid), None)
        if pid not in xyz or name is None:
            continue
        X, Y, Z, om, ph, ka = rows[name][:6]
        R = _rx(np.radians(om)) @ _ry(np.radians(ph)) @ _rz(np.radians(ka))  # camera (x right, y up, z back) -> map
        c = R.T @ (xyz[pid] - [X, Y, Z])
        assert c[2] < 0  # in front of the camera: it looks along -z
        col, row = u0 + fx * c[0] / -c[2], v0 - fy * c[1] / -c[2]  # y up on the image, rows down
        err.append(np.hypot(col - xy[0], row - xy[1]))
    # the lens distortion (not applied here) and the measurement noise are a few pixels on this small block
    assert len(err) >= 10 and np.median(err) < 3.0, np.median(err)
