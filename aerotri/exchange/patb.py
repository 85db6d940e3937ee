"""PATB-style image and control files (``patb/block.im``, ``patb/block.con``).

Image coordinates in millimetres in the photo frame (x right, y up, origin at the principal point,
distortion removed with the adjusted interior orientation), one photo per block: an ``image_id`` line,
``point_id x_mm y_mm`` lines and a ``-99`` terminator. Control: ``point_id X Y Z`` (project CRS) of the
control points the adjustment kept, ``-99`` at the end.
"""

from __future__ import annotations

import numpy as np

from aerotri.exchange.adjusted import AdjustedBlock


def photo_coordinates_mm(block: AdjustedBlock) -> tuple[np.ndarray, np.ndarray, float]:
    """(x_mm, y_mm, c_mm): undistorted photo coordinates of every measurement and the principal distance."""
    fx, fy, _, u0, v0 = block.cal[:5]
    xd = (block.obs_xy_px[:, 0] - u0) / fx
    yd = (block.obs_xy_px[:, 1] - v0) / fy
    xn, yn = block.camera.calibration_camera(block.cal).undistort(xd, yd)
    c_mm = 0.5 * (fx + fy) * block.camera.pixel_um / 1000.0
    return xn * c_mm, -yn * c_mm, c_mm


def files(block: AdjustedBlock) -> dict[str, str]:
    x_mm, y_mm, c_mm = photo_coordinates_mm(block)
    im = [f"* PATB-style image coordinates (mm, photo frame, principal point origin, undistorted), c = {c_mm:.6f} mm"]
    for i, iid in enumerate(block.image_id):
        im.append(f"{iid}")
        for k in np.flatnonzero(block.obs_image == i):
            im.append(f"  {block.point_id[block.obs_point[k]]:>12} {x_mm[k]:12.4f} {y_mm[k]:12.4f}")
        im.append("-99")
    con = [f"* control points (project CRS {block.crs}); kind in the comment"]
    for pid, kind, (X, Y, Z) in zip(block.control_id, block.control_kind, block.control_xyz_m):
        con.append(f"{pid:>12} {X:14.4f} {Y:14.4f} {Z:10.4f}  * {kind}")
    con.append("-99")
    return {"patb/block.im": "\n".join(im) + "\n", "patb/block.con": "\n".join(con) + "\n"}
