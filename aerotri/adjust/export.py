"""Exports of an adjusted block: a PATB-style image/control file pair and a COLMAP text model.

PATB-style (``at/patb/block.im``, ``at/patb/block.con``): image coordinates in millimetres in the
photo frame (x right, y up, origin at the principal point; distortion removed), one photo per block
``image_id`` line followed by ``point_id x_mm y_mm`` lines and a ``-99`` terminator; control lines
``point_id X Y Z`` (project CRS) with ``-99`` at the end.
COLMAP text model (``at/colmap/cameras.txt, images.txt, points3D.txt``): OPENCV camera, poses
world-to-camera in the local ENU frame of the adjustment (origin in the header comments), pixel
coordinates shifted by +0.5 (COLMAP's origin is the corner of the top-left pixel).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aerotri.adjust.check_points import pixel_rays
from aerotri.core.atomic import write_text_atomic


def patb_files(ba) -> dict[str, str]:
    b, r = ba.block, ba.result
    cal = r.state.cal
    act = r.obs_active
    # undistorted photo coordinates (mm): normalised coordinates times the focal length
    d_cam = pixel_rays(b.obs_xy_px, np.broadcast_to(np.eye(3), (len(b.obs_xy_px), 3, 3)), cal)
    f_mm = 0.5 * (cal[0] + cal[1]) * ba.camera_apriori.pixel_um / 1000.0
    x_mm = d_cam[:, 0] / d_cam[:, 2] * f_mm
    y_mm = -d_cam[:, 1] / d_cam[:, 2] * f_mm
    im = [f"* PATB-style image coordinates (mm, photo frame, principal point origin, undistorted), c = {f_mm:.6f} mm"]
    for i, iid in enumerate(b.image_id):
        im.append(f"{iid}")
        for k in np.flatnonzero(act & (b.obs_image == i)):
            im.append(f"  {b.point_id[b.obs_point[k]]:>12} {x_mm[k]:12.4f} {y_mm[k]:12.4f}")
        im.append("-99")
    con = [f"* control points (project CRS {ba.crs}); kind in the comment"]
    for c, pid in enumerate(ba.control.id):
        if r.control_active[c]:
            X, Y, Z = ba.control.xyz_m[c]
            con.append(f"{pid:>12} {X:14.4f} {Y:14.4f} {Z:10.4f}  * {ba.control.kind[c]}")
    con.append("-99")
    return {"patb/block.im": "\n".join(im) + "\n", "patb/block.con": "\n".join(con) + "\n"}


def _quat_wxyz(R):
    """Unit quaternion (w, x, y, z) of a rotation matrix (robust near 180 degrees, as for nadir cameras)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    return w, x, y, z


def colmap_files(ba) -> dict[str, str]:
    b, r = ba.block, ba.result
    st = r.state
    cam = ba.camera_apriori
    fx, fy, _, u0, v0, k1, k2, p1, p2 = st.cal
    origin = ba.frame.origin_map
    head = f"# local ENU frame of the adjustment, origin {origin[0]:.3f} {origin[1]:.3f} {origin[2]:.3f} in {ba.crs}"
    cams = [head, "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
            f"1 OPENCV {cam.width} {cam.height} {fx:.6f} {fy:.6f} {u0 + 0.5:.6f} {v0 + 0.5:.6f} {k1:.10g} {k2:.10g} {p1:.10g} {p2:.10g}"]
    act = r.obs_active
    used = np.unique(b.obs_point[act])
    pid3 = {int(j): n + 1 for n, j in enumerate(used)}
    imgs = [head, "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    track = {j: [] for j in pid3}
    for i, iid in enumerate(b.image_id):
        Rwc = st.R_cv[i].T
        t = -Rwc @ st.centre[i]
        q = _quat_wxyz(Rwc)
        imgs.append(f"{i + 1} " + " ".join(f"{v:.12f}" for v in q) + " " + " ".join(f"{v:.6f}" for v in t) + f" 1 {iid}")
        ks = np.flatnonzero(act & (b.obs_image == i))
        pts = []
        for n, k in enumerate(ks):
            j = int(b.obs_point[k])
            pts.append(f"{b.obs_xy_px[k, 0] + 0.5:.3f} {b.obs_xy_px[k, 1] + 0.5:.3f} {pid3[j]}")
            track[j].append(f"{i + 1} {n}")
        imgs.append(" ".join(pts))
    p3 = [head, "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    rms = np.sqrt(np.bincount(b.obs_point[act], (r.residual_px[act] ** 2).sum(1), minlength=b.n_points)
                  / np.maximum(np.bincount(b.obs_point[act], minlength=b.n_points), 1))
    for j, n in pid3.items():
        X, Y, Z = st.points[j]
        p3.append(f"{n} {X:.4f} {Y:.4f} {Z:.4f} 128 128 128 {rms[j]:.4f} " + " ".join(track[j]))
    return {"colmap/cameras.txt": "\n".join(cams) + "\n", "colmap/images.txt": "\n".join(imgs) + "\n",
            "colmap/points3D.txt": "\n".join(p3) + "\n"}


def write_files(at_dir, files: dict[str, str]) -> None:
    for rel, text in files.items():
        write_text_atomic(Path(at_dir) / rel, text)
