"""PATB-style files (``patb/``): image coordinates, control, orientations and camera; export and import.

Every file: free-format whitespace-separated records, ``*`` starts a comment (to the end of the line),
``-99`` ends a block (a photo in ``.im``) or the file (``.con``, ``.ori``).

- ``block.im`` (image coordinates): per photo an ``image_id`` line, then ``point_id x_mm y_mm`` lines and
  ``-99``. Photo frame (x right, y up, origin at the principal point), millimetres, distortion removed with
  the adjusted interior orientation (the adjustment's camera: ``photo_coordinates_mm``).
- ``block.con`` (control): ``point_id X Y Z  * kind`` (project CRS) of the control points the adjustment
  kept; the kind (full, horizontal, height, check) in the comment; ``-99`` at the end.
- ``block.ori`` (orientations), per photo five records::

      image_id  c_mm
      X0 Y0 Z0                 (projection centre, project CRS)
      r11 r12 r13              (rotation matrix R, camera -> object: P - C = s R p, photo frame x right,
      r21 r22 r23               y up, z back; R = Rx(omega) Ry(phi) Rz(kappa) of aerotri.geom.rotation)
      r31 r32 r33

  and ``-99`` at the end (matrix to 1e-10, centre to 0.1 mm).
- ``block.cam`` (camera): ``key value`` lines of the adjusted camera in the units of its names:
  ``name``, ``model`` (brown or pinhole), ``focal_mm``, ``pixel_um``, ``width``, ``height`` (px),
  ``ppx_mm``, ``ppy_mm`` (principal point from the image centre, photo frame), ``k1 k2 k3 p1 p2`` (Brown,
  on normalised coordinates); ``-99`` at the end.

Import (any of the four; the CRS is the project's, or ``--crs``): ``.ori`` -> imported/eo.txt and gnss.txt;
``.cam`` -> camera.toml; ``.con`` -> control/points.csv (sigmas: ``--sigma-xyz``, else the project's
``[control]`` sigmas); ``.im`` -> control/image_points.csv: the measurements of the control points (of the
``.con`` imported with it, else of control/points.csv), back in pixels through the camera (the ``.cam``
imported with it, else camera.toml) and its distortion.

ISAT (Intergraph ImageStation Automatic Triangulation) orientation files are not read or written: no
documented layout of them was found (the references that list an "ISAT EO file" do not give its fields).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_text
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.imported import ImportedBlock, ImportSettings, to_project_crs
from aerotri.exchange.poses import adjusted_orientations, number, orientations_to_project
from aerotri.geom.camera import Camera
from aerotri.geom.eo import GnssPositions
from aerotri.geom.observations import CONTROL_KINDS, ControlPoints, ImageObservations

END = "-99"


def photo_coordinates_mm(block: AdjustedBlock) -> tuple[np.ndarray, np.ndarray, float]:
    """(x_mm, y_mm, c_mm): undistorted photo coordinates of every measurement and the principal distance."""
    fx, fy, _, u0, v0 = block.cal[:5]
    xd = (block.obs_xy_px[:, 0] - u0) / fx
    yd = (block.obs_xy_px[:, 1] - v0) / fy
    xn, yn = block.camera.calibration_camera(block.cal).undistort(xd, yd)
    c_mm = 0.5 * (fx + fy) * block.camera.pixel_um / 1000.0
    return xn * c_mm, -yn * c_mm, c_mm


# -- export ------------------------------------------------------------------------------------------

def files(block: AdjustedBlock, project: Project | None = None) -> dict[str, str]:
    """``patb/block.im``, ``block.con``; with ``project`` also ``block.ori`` and ``block.cam`` (the adjusted
    orientations of at/eo.txt and the self-calibrated camera)."""
    x_mm, y_mm, c_mm = photo_coordinates_mm(block)
    im = [f"* PATB-style image coordinates (mm, photo frame, principal point origin, undistorted), c = {c_mm:.6f} mm"]
    for i, iid in enumerate(block.image_id):
        im.append(f"{iid}")
        for k in np.flatnonzero(block.obs_image == i):
            im.append(f"  {block.point_id[block.obs_point[k]]:>12} {x_mm[k]:12.4f} {y_mm[k]:12.4f}")
        im.append(END)
    con = [f"* control points (project CRS {block.crs}); kind in the comment"]
    for pid, kind, (X, Y, Z) in zip(block.control_id, block.control_kind, block.control_xyz_m):
        con.append(f"{pid:>12} {X:14.4f} {Y:14.4f} {Z:10.4f}  * {kind}")
    con.append(END)
    out = {"patb/block.im": "\n".join(im) + "\n", "patb/block.con": "\n".join(con) + "\n"}
    if project is not None:
        eo, camera = adjusted_orientations(project)
        out["patb/block.ori"] = orientation_text(eo, camera, block.crs)
        out["patb/block.cam"] = camera_text(camera)
    return out


def orientation_text(eo, camera: Camera, crs: str) -> str:
    lines = [f"* PATB-style orientations (project CRS {crs}): image_id c_mm / X0 Y0 Z0 / rotation matrix rows "
             "(camera -> object, photo frame x right, y up, z back)"]
    R = eo.rotations()
    for i, iid in enumerate(eo.image_id):
        lines.append(f"{iid} {camera.focal_mm:.6f}")
        lines.append("  " + " ".join(f"{v:15.4f}" for v in eo.centre_m[i]))
        lines += ["  " + " ".join(f"{v:15.10f}" for v in row) for row in R[i]]
    lines.append(END)
    return "\n".join(lines) + "\n"


def camera_text(camera: Camera) -> str:
    lines = ["* PATB-style camera (aerotri): key value; mm, um, px as the names say; principal point from the image "
             "centre (photo frame, y up); Brown distortion on normalised coordinates"]
    for k, v in camera.to_dict().items():
        lines.append(f"{k} {v if isinstance(v, (str, int)) else repr(float(v))}")
    lines.append(END)
    return "\n".join(lines) + "\n"


# -- import ------------------------------------------------------------------------------------------

def _records(path: Path, what: str):
    """(line number, fields) of the data lines of a PATB-style file, comments dropped."""
    for n, line in enumerate(read_text(path, what).splitlines(), start=1):
        s = line.split("*", 1)[0].strip()
        if s:
            yield n, s.split(), line


def read_ori(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(image ids, centres (N, 3), rotations (N, 3, 3)) of ``block.ori``."""
    recs = list(_records(path, "PATB-style orientations (.ori)"))
    ids, centres, rots, seen, k = [], [], [], {}, 0
    while k < len(recs):
        n, f, _ = recs[k]
        if f == [END]:
            break
        if len(f) not in (1, 2):
            raise InputError(f"{path}:{n}: expected 'image_id [c_mm]' opening a photo, got {' '.join(f)!r}")
        iid = f[0]
        if iid in seen:
            raise InputError(f"{path}:{n}: duplicate image {iid!r} (first on line {seen[iid]})")
        seen[iid] = n
        if k + 4 >= len(recs):
            raise InputError(f"{path}:{n}: photo {iid!r} needs 4 more records (X0 Y0 Z0 and 3 matrix rows)")
        rows = []
        for m in range(1, 5):
            nm, fm, _ = recs[k + m]
            if len(fm) != 3:
                raise InputError(f"{path}:{nm}: expected 3 numbers ({'X0 Y0 Z0' if m == 1 else 'a matrix row'}) "
                                 f"of photo {iid!r}, got {len(fm)}")
            names = ("X0", "Y0", "Z0") if m == 1 else tuple(f"r{m - 1}{j}" for j in (1, 2, 3))
            rows.append([number(v, f"{path}:{nm}", name) for name, v in zip(names, fm)])
        R = np.array(rows[1:])
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise InputError(f"{path}:{recs[k + 2][0]}-{recs[k + 4][0]}: the matrix of photo {iid!r} is not a rotation "
                             f"(R R^T - I up to {np.abs(R @ R.T - np.eye(3)).max():.2g})")
        ids.append(iid)
        centres.append(rows[0])
        rots.append(R)
        k += 5
    else:
        raise InputError(f"{path}: no -99 at the end (truncated file?)")
    if not ids:
        raise InputError(f"{path}: no photos")
    return ids, np.array(centres), np.array(rots)


def read_cam(path: Path) -> Camera:
    d = {}
    for n, f, _ in _records(path, "PATB-style camera (.cam)"):
        if f == [END]:
            break
        if len(f) < 2:
            raise InputError(f"{path}:{n}: expected 'key value', got {' '.join(f)!r}")
        key, value = f[0], " ".join(f[1:])
        if key in d:
            raise InputError(f"{path}:{n}: duplicate key {key!r}")
        if key in ("name", "model"):
            d[key] = value
        else:
            v = number(value, f"{path}:{n}", key)
            d[key] = int(v) if key in ("width", "height") and v == int(v) else v
    return Camera.from_dict(d, source=str(path))


def _control_sigma(project: Project, options: ImportSettings, path: Path) -> np.ndarray:
    if options.sigma_xyz_m:
        return np.asarray(options.sigma_xyz_m, float)
    c = project.control_points
    if c.sigma_xy_m is not None and c.sigma_z_m is not None:
        return np.array([c.sigma_xy_m, c.sigma_xy_m, c.sigma_z_m], float)
    raise InputError(f"{path}: control points without accuracies; give --sigma-xyz SX SY SZ (m) or [control] "
                     f"sigma_xy_m, sigma_z_m in {project.config_path}")


def read_con(path: Path, project: Project, options: ImportSettings) -> ControlPoints:
    ids, kinds, xyz, seen = [], [], [], {}
    for n, f, line in _records(path, "PATB-style control (.con)"):
        if f == [END]:
            break
        if len(f) != 4:
            raise InputError(f"{path}:{n}: expected 'point_id X Y Z', got {len(f)} fields")
        if f[0] in seen:
            raise InputError(f"{path}:{n}: duplicate control point {f[0]!r} (first on line {seen[f[0]]})")
        seen[f[0]] = n
        comment = line.split("*", 1)[1].strip().lower() if "*" in line else ""
        kinds.append(comment if comment in CONTROL_KINDS else "full")
        ids.append(f[0])
        xyz.append([number(v, f"{path}:{n}", k) for k, v in zip("XYZ", f[1:])])
    if not ids:
        raise InputError(f"{path}: no control points")
    xyz = np.array(xyz)
    if options.crs:
        xyz = to_project_crs(xyz, options.crs, project, "--crs")
    sig = np.tile(_control_sigma(project, options, path), (len(ids), 1))
    return ControlPoints(np.array(ids, object), np.array(kinds, object), xyz, sig)


def read_im(path: Path) -> tuple[list, list, np.ndarray, list]:
    """(point ids, image ids, photo coordinates (K, 2) mm, line numbers) of ``block.im``."""
    pids, iids, xy, lines, photo, seen = [], [], [], [], None, {}
    for n, f, _ in _records(path, "PATB-style image coordinates (.im)"):
        if f == [END]:
            photo = None
            continue
        if photo is None:
            if len(f) != 1:
                raise InputError(f"{path}:{n}: expected an image id opening a photo, got {' '.join(f)!r}")
            photo = f[0]
            continue
        if len(f) != 3:
            raise InputError(f"{path}:{n}: expected 'point_id x_mm y_mm' in photo {photo!r}, got {len(f)} fields")
        if (f[0], photo) in seen:
            raise InputError(f"{path}:{n}: duplicate point {f[0]!r} in photo {photo!r} (first on line {seen[f[0], photo]})")
        seen[f[0], photo] = n
        pids.append(f[0])
        iids.append(photo)
        xy.append([number(f[1], f"{path}:{n}", "x_mm"), number(f[2], f"{path}:{n}", "y_mm")])
        lines.append(n)
    if photo is not None:
        raise InputError(f"{path}: photo {photo!r} has no -99 at its end (truncated file?)")
    return pids, iids, np.array(xy).reshape(-1, 2), lines


def pixels_of_photo_mm(camera: Camera, xy_mm: np.ndarray) -> np.ndarray:
    """Undistorted photo coordinates (mm, principal point origin, y up) -> measured pixels (distortion on)."""
    c = camera.focal_mm
    x_px, y_px = camera.normalized_to_pixel(xy_mm[:, 0] / c, -xy_mm[:, 1] / c)
    return np.column_stack([x_px, y_px])


def read(files: list[Path], project: Project, options: ImportSettings) -> ImportedBlock:
    """``.ori``, ``.cam``, ``.con`` and ``.im`` files (see the module docstring)."""
    by = {}
    for f in files:
        s = f.suffix.lower()
        if s not in (".ori", ".cam", ".con", ".im"):
            raise InputError(f"{f}: not a PATB-style file (expected .ori, .cam, .con or .im)")
        if s in by:
            raise InputError(f"{f}: a second {s} file (import one of each)")
        by[s] = f
    block = ImportedBlock(source=[str(f) for f in files])
    crs = options.crs or project.crs
    if ".cam" in by:
        block.camera = read_cam(by[".cam"])
    if ".ori" in by:
        ids, centre, R = read_ori(by[".ori"])
        block.eo = orientations_to_project(ids, centre, R, crs, project, "--crs" if options.crs else str(project.config_path))
        sigma = np.tile(options.sigma_xyz_m, (len(ids), 1)) if options.sigma_xyz_m else None
        block.gnss = GnssPositions(list(ids), block.eo.centre_m.copy(), sigma)
    if ".con" in by:
        block.control = read_con(by[".con"], project, options)
    if ".im" in by:
        path = by[".im"]
        pids, iids, xy_mm, lines = read_im(path)
        if block.control is not None:
            control_ids = set(block.control.id)
        elif project.control_points_path.is_file():
            from aerotri.geom.observations import read_control_points

            control_ids = set(read_control_points(project.control_points_path).id)
        else:
            raise InputError(f"{path}: the image coordinates of which points? import the .con with it or have "
                             f"{project.control_points_path}")
        if block.camera is not None:
            camera = block.camera
        elif project.camera_path.is_file():
            camera = Camera.read(project.camera_path)
        else:
            raise InputError(f"{path}: photo coordinates need the camera: import the .cam with it or have "
                             f"{project.camera_path}")
        keep = np.array([p in control_ids for p in pids], bool)
        if not keep.any():
            raise InputError(f"{path}: no measurements of the control points ({len(control_ids)} points)")
        block.image_points = ImageObservations(np.array(pids, object)[keep], np.array(iids, object)[keep],
                                               pixels_of_photo_mm(camera, xy_mm[keep]), np.array(lines)[keep])
        block.notes.append(f"{path}: {int(keep.sum())} measurements of control points imported, "
                           f"{int((~keep).sum())} of tie points left out")
    return block
