"""COLMAP text model (``colmap/cameras.txt``, ``images.txt``, ``points3D.txt``).

One camera (OPENCV for a Brown camera, PINHOLE for a pinhole) with the adjusted interior orientation; poses world-to-camera in the adjustment's
local ENU frame (origin and CRS in the header comments); pixel coordinates shifted by +0.5 (COLMAP's
origin is the corner of the top-left pixel, ours the centre); image names are the image files' names
in ``images/`` (with their extension), so COLMAP finds the frames.
"""

from __future__ import annotations

import numpy as np

from aerotri.exchange.adjusted import AdjustedBlock


def _quat_wxyz(R):
    """Unit quaternion (w, x, y, z) of a rotation matrix (robust near 180 degrees, as for nadir cameras)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    return w, x, y, z


def files(block: AdjustedBlock, image_names: dict | None = None) -> dict[str, str]:
    """``image_names``: image id -> file name (default: the id)."""
    fx, fy, _, u0, v0 = block.cal[:5]
    cam = block.camera
    # the model of the camera the measurements fit (COLMAP's PARAMS start fx fy cx cy in every model we
    # write; fx and fy as adjusted, the rest as the model gives them)
    model, params = cam.calibration_camera(block.cal).colmap_model()
    origin = block.frame.origin_map
    head = f"# local ENU frame of the adjustment, origin {origin[0]:.3f} {origin[1]:.3f} {origin[2]:.3f} in {block.crs}"
    cams = [head, "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
            f"1 {model} {cam.width} {cam.height} {fx:.6f} {fy:.6f} {u0 + 0.5:.6f} {v0 + 0.5:.6f}"
            + "".join(f" {v:.10g}" for v in params[4:])]
    used = np.unique(block.obs_point)
    pid3 = {int(j): n + 1 for n, j in enumerate(used)}
    imgs = [head, "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    track = {j: [] for j in pid3}
    names = image_names or {}
    for i, iid in enumerate(block.image_id):
        Rwc = block.R_cv[i].T
        t = -Rwc @ block.centre_local[i]
        q = _quat_wxyz(Rwc)
        imgs.append(f"{i + 1} " + " ".join(f"{v:.12f}" for v in q) + " " + " ".join(f"{v:.6f}" for v in t)
                    + f" 1 {names.get(iid, iid)}")
        pts = []
        for n, k in enumerate(np.flatnonzero(block.obs_image == i)):
            j = int(block.obs_point[k])
            pts.append(f"{block.obs_xy_px[k, 0] + 0.5:.3f} {block.obs_xy_px[k, 1] + 0.5:.3f} {pid3[j]}")
            track[j].append(f"{i + 1} {n}")
        imgs.append(" ".join(pts))
    p3 = [head, "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    for j, n in pid3.items():
        X, Y, Z = block.points_local[j]
        p3.append(f"{n} {X:.4f} {Y:.4f} {Z:.4f} 128 128 128 {block.point_rms_px[j]:.4f} " + " ".join(track[j]))
    return {"colmap/cameras.txt": "\n".join(cams) + "\n", "colmap/images.txt": "\n".join(imgs) + "\n",
            "colmap/points3D.txt": "\n".join(p3) + "\n"}
