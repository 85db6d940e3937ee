"""PAT-B files (``patb/``): orientations, control and image coordinates; export and import.

PAT-B (Ackermann's bundle block adjustment, Inpho/Trimble) exchanges fixed-column Fortran records. Layouts:

- ``block.ori`` (orientations), the layout PCI Geomatics documents for reading PAT-B orientations
  ("Using Pat-B in OrthoEngine"): three records per photo, no terminator::

      I16, F16.5, 3F16.5  photo number, c (mm; columns OrthoEngine does not read, where MATCH-AT and ISAT
                          write the principal distance), X0 Y0 Z0 (projection centre, project CRS)
      5F16.12             a11 a12 a13 a21 a22
      4F16.12             a23 a31 a32 a33

  ``a``: the rotation camera -> object (``P - C = s a p``, photo frame x right, y up, z back; the matrix of
  omega phi kappa, ``a = Rx(omega) Ry(phi) Rz(kappa)``, ``aerotri.geom.rotation``), which is what
  Metashape's PAT-B export writes with "X right, Y up".
- ``block.im`` (image coordinates; no field widths found in a primary source, so the ``.ori``'s 16-column
  fields): per photo a record ``I16`` photo number, then ``I16, 2F16.6`` point number, x, y (mm, photo frame
  x right, y up, origin at the principal point, distortion removed with the adjusted camera:
  ``photo_coordinates_mm``), and ``-99`` (``I16``) closing the photo. Every measurement the adjustment
  kept (tie and control points), and the check points' measurements (control/image_points.csv).
- ``block.con`` (control): ``I16, 3F16.4`` point number, X, Y, Z (project CRS), ``-99`` at the end: the
  full (XYZ) control points the adjustment used. The other kinds go to files of the same layout a PAT-B
  reader would not take for XYZ control: ``block_horizontal.con`` (Z not used), ``block_height.con``
  (X, Y not used), ``block_check.con`` (check points of control/points.csv).

Not PAT-B (aerotri's own, for the round trip): ``numbers.txt`` maps PAT-B's integer numbers to our ids
(``photo <number> <image id>``, ``point <number> <point id> [<kind>]``; ids that are all plain integers
keep their values, others are numbered 1, 2, ... in order); ``block.cam`` holds the adjusted camera
(``key value`` lines of camera.toml's keys, ``-99`` at the end), which PAT-B keeps in its project file.

Import (any of the files; the CRS is the project's, or ``--crs``): ``.ori`` -> imported/eo.txt
(approximations; gnss.txt only with ``--as-gnss``); ``.cam`` -> camera.toml; ``.con`` files ->
control/points.csv (kind from numbers.txt, else from the file name's ``_check``/``_horizontal``/``_height``,
else full; sigmas: ``--sigma-xyz-m``, else the project's ``[control]`` sigmas); ``.im`` ->
control/image_points.csv: the measurements of the control points (of the ``.con`` imported with it, else of
control/points.csv), back in pixels through the camera (the ``.cam`` imported with it, else camera.toml)
and its distortion. Records are read as blank-separated fields (a fixed-column file reads the same);
``*`` starts a comment. Numbers map back to ids through ``numbers.txt`` when it is given.

ISAT (Intergraph ImageStation Automatic Triangulation) orientation files are not read or written: no
documented layout of them was found (the references that list an "ISAT EO file" do not give its fields).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_text
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.exchange.imported import ImportedBlock, ImportSettings, control_sigma_m, positions_as_gnss, to_project_crs
from aerotri.exchange.poses import adjusted_orientations, number, orientations_to_project
from aerotri.geom.camera import Camera
from aerotri.geom.observations import CONTROL_KINDS, ControlPoints, ImageObservations

END = "-99"
FIELD = 16  # columns of every PAT-B field written here
MAX_NUMBER = 10 ** 15  # I16 with a sign column to spare
CON_FILES = {"full": "block.con", "horizontal": "block_horizontal.con", "height": "block_height.con",
             "check": "block_check.con"}


def photo_coordinates_mm(block: AdjustedBlock, xy_px=None) -> tuple[np.ndarray, np.ndarray, float]:
    """(x_mm, y_mm, c_mm): undistorted photo coordinates of every measurement (or of the pixels ``xy_px``, (N, 2)
    as measured) and the principal distance."""
    fx, fy, _, u0, v0 = block.cal[:5]
    xy = block.obs_xy_px if xy_px is None else np.asarray(xy_px, float).reshape(-1, 2)
    xd = (xy[:, 0] - u0) / fx
    yd = (xy[:, 1] - v0) / fy
    xn, yn = block.camera.calibration_camera(block.cal).undistort(xd, yd)
    c_mm = 0.5 * (fx + fy) * block.camera.pixel_um / 1000.0
    return xn * c_mm, -yn * c_mm, c_mm


# -- export ------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class PatbNumbering:
    """PAT-B's integer number of each id (``ids`` in order, each once; ``numbers`` beside them)."""

    ids: tuple[str, ...]
    numbers: tuple[int, ...]
    _number: dict = dataclasses.field(init=False, repr=False, compare=False)  # id -> number, for the lookups

    def __post_init__(self):
        object.__setattr__(self, "_number", dict(zip(self.ids, self.numbers)))

    def number_of(self, id_: str) -> int:
        """The PAT-B number of an id (KeyError for an id that was not numbered)."""
        return self._number[id_]


def numbering(ids) -> PatbNumbering:
    """PAT-B numbers of ``ids`` (repeats numbered once): the ids themselves when every one is a plain integer
    (no sign, no leading zero, below 10^15), else 1, 2, ... in order."""
    ids = tuple(str(i) for i in dict.fromkeys(ids))
    if ids and all(i.isdigit() and str(int(i)) == i and int(i) < MAX_NUMBER for i in ids):
        return PatbNumbering(ids, tuple(int(i) for i in ids))
    return PatbNumbering(ids, tuple(range(1, len(ids) + 1)))


def _i16(n: int) -> str:
    return f"{n:{FIELD}d}"


def orientation_text(eo, photo_no: PatbNumbering, c_mm: float | None = None) -> str:
    """``block.ori``: three fixed-column records per photo (I16,F16.5,3F16.5 / 5F16.12 / 4F16.12); the principal
    distance ``c_mm`` in columns 17-32 where MATCH-AT and ISAT write it (OrthoEngine does not read them: blank
    without ``c_mm``)."""
    lines = []
    R = eo.rotations()
    c_field = " " * FIELD if c_mm is None else f"{c_mm:{FIELD}.5f}"
    for i, iid in enumerate(eo.image_id):
        a = R[i].reshape(9)
        lines.append(_i16(photo_no.number_of(iid)) + c_field + "".join(f"{v:{FIELD}.5f}" for v in eo.centre_m[i]))
        lines.append("".join(f"{v:{FIELD}.12f}" for v in a[:5]))
        lines.append("".join(f"{v:{FIELD}.12f}" for v in a[5:]))
    return "\n".join(lines) + "\n"


def control_text(ids, xyz, point_no: PatbNumbering) -> str:
    """A ``.con`` file: ``I16, 3F16.4`` point number X Y Z per point, ``-99`` at the end."""
    rows = [_i16(point_no.number_of(p)) + "".join(f"{v:{FIELD}.4f}" for v in c) for p, c in zip(ids, xyz)]
    return "\n".join(rows + [_i16(-99)]) + "\n"


def files(block: AdjustedBlock, project: Project | None = None) -> list[ExportFile]:
    """``patb/block.im``, the ``.con`` files and ``numbers.txt``; with ``project`` also ``block.ori``,
    ``block.cam`` (the adjusted orientations of at/eo.txt and the self-calibrated camera) and
    ``block_check.con`` (the check points of control/points.csv)."""
    x_mm, y_mm, _ = photo_coordinates_mm(block)
    eo = camera = None
    if project is not None:
        eo, camera = adjusted_orientations(project)
    check = None
    if project is not None and project.control_points_path.is_file():
        from aerotri.geom.observations import read_control_points

        cp = read_control_points(project.control_points_path)
        check = cp.subset(cp.kind == "check")
    photo_no = numbering(list(block.image_id) + ([] if eo is None else list(eo.image_id)))
    point_ids = [str(p) for p in block.point_id] + [str(p) for p in block.control_id]
    point_ids += [] if check is None else [str(p) for p in check.id]
    point_no = numbering(point_ids)
    checked = _check_measurements(block, project, check)
    im = []
    by_image = np.argsort(block.obs_image, kind="stable")  # each image's observations in file order, at once
    bounds = np.searchsorted(block.obs_image[by_image], np.arange(len(block.image_id) + 1))
    for i, iid in enumerate(block.image_id):
        im.append(_i16(photo_no.number_of(iid)))
        for k in by_image[bounds[i]:bounds[i + 1]].tolist():
            im.append(_i16(point_no.number_of(str(block.point_id[block.obs_point[k]]))) + f"{x_mm[k]:{FIELD}.6f}"
                      + f"{y_mm[k]:{FIELD}.6f}")
        for pid, x, y in checked.get(str(iid), ()):
            im.append(_i16(point_no.number_of(pid)) + f"{x:{FIELD}.6f}" + f"{y:{FIELD}.6f}")
        im.append(_i16(-99))
    out = [ExportFile("patb/block.im", "\n".join(im) + "\n")]
    kinds = {}
    for kind in ("full", "horizontal", "height"):
        m = block.control_kind == kind
        if m.any() or kind == "full":
            out.append(ExportFile(f"patb/{CON_FILES[kind]}",
                                  control_text(block.control_id[m].astype(str), block.control_xyz_m[m], point_no)))
        kinds.update({str(p): kind for p in block.control_id[m]})
    if check is not None and len(check):
        out.append(ExportFile(f"patb/{CON_FILES['check']}", control_text(check.id.astype(str), check.xyz_m, point_no)))
        kinds.update({str(p): "check" for p in check.id})
    if eo is not None:
        out.append(ExportFile("patb/block.ori", orientation_text(eo, photo_no, camera.focal_mm)))
        out.append(ExportFile("patb/block.cam", camera_text(camera)))
    nums = ["# aerotri: PAT-B numbers of the files beside this one -> ids (photo|point number id [kind])"]
    nums += [f"photo {n} {i}" for i, n in zip(photo_no.ids, photo_no.numbers)]
    nums += [f"point {n} {p}" + (f" {kinds[p]}" if p in kinds else "") for p, n in zip(point_no.ids, point_no.numbers)]
    out.append(ExportFile("patb/numbers.txt", "\n".join(nums) + "\n"))
    return out


def _check_measurements(block: AdjustedBlock, project: Project | None, check) -> dict:
    """image id -> [(point id, x_mm, y_mm)] of the check points' measurements (control/image_points.csv, the points of
    ``block_check.con``), as the adjustment's: undistorted photo coordinates. block_check.con held 390 points and
    block.im none of their measurements, so MATCH-AT / ISAT could not run them (trial s96 M2)."""
    if project is None or check is None or not len(check) or not project.control_image_points_path.is_file():
        return {}
    from aerotri.geom.observations import read_image_points

    obs = read_image_points(project.control_image_points_path)
    ids, images = {str(p) for p in check.id}, {str(i) for i in block.image_id}
    keep = np.array([str(p) in ids and str(i) in images for p, i in zip(obs.point_id, obs.image_id)], bool)
    if not keep.any():
        return {}
    x_mm, y_mm, _ = photo_coordinates_mm(block, obs.xy_px[keep])
    out: dict = {}
    for p, i, x, y in zip(obs.point_id[keep], obs.image_id[keep], x_mm, y_mm):
        out.setdefault(str(i), []).append((str(p), float(x), float(y)))
    return out


def camera_text(camera: Camera) -> str:
    lines = ["* aerotri camera (not PAT-B): key value; mm, um, px as the names say; principal point from the image "
             "centre (photo frame, y up); Brown distortion on normalised coordinates"]
    for k, v in camera.to_dict().items():
        lines.append(f"{k} {v if isinstance(v, (str, int)) else repr(float(v))}")
    lines.append(END)
    return "\n".join(lines) + "\n"


# -- import ------------------------------------------------------------------------------------------

def _records(path: Path, what: str):
    """(line number, fields, line) of the data lines of a PAT-B file, ``*`` comments dropped."""
    for n, line in enumerate(read_text(path, what).splitlines(), start=1):
        s = line.split("*", 1)[0].strip()
        if s:
            yield n, s.split(), line


def read_numbers(path: Path) -> tuple[dict, dict, dict]:
    """(photo number -> image id, point number -> point id, point id -> kind) of ``numbers.txt``."""
    photos, points, kinds = {}, {}, {}
    for n, f, _ in _records(path, "PAT-B number map (numbers.txt)"):
        if f[0].startswith("#"):
            continue
        where = f"{path}:{n}"
        if f[0] not in ("photo", "point") or len(f) not in (3, 4) or (f[0] == "photo" and len(f) != 3):
            raise InputError(f"{where}: expected 'photo NUMBER ID' or 'point NUMBER ID [KIND]', got {' '.join(f)!r}")
        table = photos if f[0] == "photo" else points
        if f[1] in table:
            raise InputError(f"{where}: {f[0]} number {f[1]} twice")
        table[f[1]] = f[2]
        if len(f) == 4:
            if f[3] not in CONTROL_KINDS:
                raise InputError(f"{where}: kind {f[3]!r} is not one of {', '.join(CONTROL_KINDS)}")
            kinds[f[2]] = f[3]
    return photos, points, kinds


def read_ori(path: Path) -> tuple[list[str], np.ndarray, np.ndarray, dict[str, tuple[int, float]]]:
    """(photo numbers, centres (N, 3), rotations (N, 3, 3), photo number -> (line, principal distance c in mm) of
    the photos that give one) of a PAT-B ``.ori``: per photo ``number [c] X0 Y0 Z0`` / ``a11 a12 a13 a21 a22`` /
    ``a23 a31 a32 a33``; an optional ``-99`` ends the file."""
    recs = list(_records(path, "PAT-B orientations (.ori)"))
    ids, centres, rots, seen, k, c_mm = [], [], [], {}, 0, {}
    while k < len(recs):
        n, f, _ = recs[k]
        if f == [END]:
            break
        if len(f) not in (4, 5):
            raise InputError(f"{path}:{n}: expected 'photo_number [c] X0 Y0 Z0' opening a photo, got {len(f)} fields")
        _require_fixed_columns(path, n, recs[k][2], f)
        iid = f[0]
        if iid in seen:
            raise InputError(f"{path}:{n}: duplicate photo {iid!r} (first on line {seen[iid]})")
        seen[iid] = n
        if k + 2 >= len(recs):
            raise InputError(f"{path}:{n}: photo {iid!r} needs 2 more records (a11 a12 a13 a21 a22 / a23 a31 a32 a33)")
        centre = [number(v, f"{path}:{n}", name) for name, v in zip(("X0", "Y0", "Z0"), f[-3:])]
        if len(f) == 5:
            c_mm[iid] = (n, number(f[1], f"{path}:{n}", "c"))
        a = []
        for m, names in ((1, ("a11", "a12", "a13", "a21", "a22")), (2, ("a23", "a31", "a32", "a33"))):
            nm, fm, _ = recs[k + m]
            if len(fm) != len(names):
                raise InputError(f"{path}:{nm}: expected {len(names)} numbers ({' '.join(names)}) of photo {iid!r}, "
                                 f"got {len(fm)}")
            a += [number(v, f"{path}:{nm}", name) for name, v in zip(names, fm)]
        R = np.array(a).reshape(3, 3)
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise InputError(f"{path}:{recs[k + 1][0]}-{recs[k + 2][0]}: the matrix of photo {iid!r} is not a rotation "
                             f"(R R^T - I up to {np.abs(R @ R.T - np.eye(3)).max():.2g})")
        ids.append(iid)
        centres.append(centre)
        rots.append(R)
        k += 3
    if not ids:
        raise InputError(f"{path}: no photos")
    return ids, np.array(centres), np.array(rots), c_mm


def _require_fixed_columns(path: Path, n: int, line: str, fields: list) -> None:
    """A photo's first record whose fields sit in the I16, F16 columns (each ending at a multiple of 16) is read by
    them: a 4-field record is ``number X0 Y0 Z0`` only when columns 17-32 are blank. MATCH-AT / ISAT write c there;
    with Z0 lost such a record read as X0 = c, Y0 = X0, Z0 = Y0 (-3,727,433 m), exit 0 (trial s96 H1)."""
    ends = [m.end() for m in re.finditer(r"\S+", line.split("*", 1)[0])]
    if len(fields) != 4 or not ends or any(e % 16 for e in ends):
        return
    columns = [e // 16 for e in ends]  # 1: the number, 2: c, 3-5: X0 Y0 Z0
    if columns != [1, 3, 4, 5]:
        empty = [name for col, name in zip(range(1, 6), ("photo number", "c", "X0", "Y0", "Z0")) if col not in columns]
        cols = ", ".join(f"{16 * c - 15}-{16 * c}" for c in range(1, 6) if c not in columns)
        raise InputError(f"{path}:{n}: the photo's record has its fields in the I16, F16 columns with "
                         f"{', '.join(empty)} (columns {cols}) empty: expected 'photo_number [c] X0 Y0 Z0' (c in "
                         "columns 17-32 or blank, X0 Y0 Z0 in 33-80)")


def principal_distance_notes(path: Path, c_mm: dict, camera: Camera | None, camera_source: str) -> list[str]:
    """Notes on the ``.ori``'s principal distances that differ from the camera the orientations will be used with
    (by over 1 um: calibration certificates state c to 1 um; the ``.ori`` writes 0.01 um): the orientations were
    computed with the ``.ori``'s c, and with another focal length the ground they give is scaled by f / c about
    the projection centres (a 0.5 mm longer focal length at 120 mm puts the ground 0.42 % of the flying height
    lower). Before trial-exchange the c field was read and dropped, unsaid."""
    if not c_mm or camera is None:
        return []
    f = float(camera.focal_mm)
    off = {iid: (n, c) for iid, (n, c) in c_mm.items() if abs(abs(c) - f) > 1e-3}
    if not off:
        return []
    iid, (n, c) = next(iter(off.items()))
    return [f"{path}:{n}: photo {iid!r} gives the principal distance c = {c:g} mm, the camera ({camera_source}) "
            f"f = {f:g} mm ({len(off)} of {len(c_mm)} photos differ by over 0.001 mm): the orientations were "
            f"computed with c; used with f, the ground they give is scaled by f / c ({abs(f / c):.6f}) about the "
            "projection centres: import the camera of the AT (its .cam, or camera.toml with focal_mm = c)"]


def read_cam(path: Path) -> Camera:
    d = {}
    for n, f, _ in _records(path, "aerotri camera (.cam)"):
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


def read_con(path: Path) -> tuple[list, np.ndarray, list]:
    """(point numbers, (M, 3) X Y Z, kinds a ``* kind`` comment gives (aerotri's earlier files) or None) of a
    ``.con`` file (``-99`` at the end)."""
    ids, xyz, kinds, seen = [], [], [], {}
    for n, f, line in _records(path, "PAT-B control (.con)"):
        if f == [END]:
            break
        if len(f) != 4:
            raise InputError(f"{path}:{n}: expected 'point_number X Y Z', got {len(f)} fields")
        if f[0] in seen:
            raise InputError(f"{path}:{n}: duplicate control point {f[0]!r} (first on line {seen[f[0]]})")
        seen[f[0]] = n
        ids.append(f[0])
        xyz.append([number(v, f"{path}:{n}", k) for k, v in zip("XYZ", f[1:])])
        comment = line.split("*", 1)[1].strip().lower() if "*" in line else ""
        kinds.append(comment if comment in CONTROL_KINDS else None)
    else:
        raise InputError(f"{path}: no -99 at the end (truncated file?)")
    return ids, np.array(xyz).reshape(-1, 3), kinds


def _kind_of_file(path: Path) -> str:
    stem = path.stem.lower()
    return next((k for k in ("check", "horizontal", "height") if stem.endswith(f"_{k}")), "full")


def read_im(path: Path) -> tuple[list, list, np.ndarray, list]:
    """(point numbers, photo numbers, photo coordinates (K, 2) mm, line numbers) of a ``.im`` file."""
    pids, iids, xy, lines, photo, seen = [], [], [], [], None, {}
    for n, f, _ in _records(path, "PAT-B image coordinates (.im)"):
        if f == [END]:
            photo = None
            continue
        if photo is None:
            if len(f) not in (1, 2):
                raise InputError(f"{path}:{n}: expected a photo number opening a photo, got {' '.join(f)!r}")
            photo = f[0]
            continue
        if len(f) != 3:
            raise InputError(f"{path}:{n}: expected 'point_number x_mm y_mm' in photo {photo!r}, got {len(f)} fields")
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


# a .ori's matrices are taken as transposed when, over the points the .im measures in two or more of its photos, the
# rays as read miss each other by over TRANSPOSED_MIN_PX (median y-parallax, in the camera's pixels) and the rays
# of the transposed matrices by TRANSPOSED_FACTOR times less: an AT's y-parallaxes are a fraction of a pixel, a
# matrix written the other way round turns the photo by twice kappa (omega and phi's signs flipped near kappa 0)
TRANSPOSED_MIN_PX = 5.0
TRANSPOSED_FACTOR = 5.0


def _y_parallax_px(centre: np.ndarray, R: np.ndarray, photo: np.ndarray, point: np.ndarray, xy_mm: np.ndarray,
                   c_mm: float, pixel_um: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(photo a, photo b, y-parallax px) of every pair of measurements of one point in two photos: the distance by
    which the two rays (``P - C = s R (x, y, -c)``) miss each other, as an angle from the first photo, in the
    camera's pixels at c."""
    rays = np.einsum("nij,nj->ni", R[photo], np.c_[xy_mm, np.full(len(xy_mm), -c_mm)])
    # consecutive measurements of a point (in the file's order): each photo of the point in a pair (a block's millions
    # of measurements: sorted, not looped)
    code = np.unique(np.asarray(point).astype(str), return_inverse=True)[1].ravel()
    order = np.argsort(code, kind="stable")
    same = code[order[1:]] == code[order[:-1]]
    a, b = order[:-1][same], order[1:][same]
    if not len(a):
        return np.empty(0, int), np.empty(0, int), np.empty(0)
    ra, rb = rays[a], rays[b]
    base = centre[photo[b]] - centre[photo[a]]
    n = np.cross(ra, rb)
    nn = np.linalg.norm(n, axis=1)
    miss = np.abs(np.einsum("ij,ij->i", base, n)) / np.maximum(nn, 1e-300)
    # distance along the first ray to its point nearest the second
    t = np.einsum("ij,ij->i", np.cross(base, rb), n) / np.maximum(nn ** 2, 1e-300)
    range_m = np.abs(t) * np.linalg.norm(ra, axis=1)
    return photo[a], photo[b], miss / np.maximum(range_m, 1e-9) * c_mm * 1000.0 / pixel_um


def transposed_rotation_notes(path: Path, im_path: Path, nums: list[str], centre: np.ndarray, R: np.ndarray,
                              im_photo: list[str], im_point: list[str], xy_mm: np.ndarray, camera: Camera,
                              photo_id) -> list[str]:
    """The refusal when the ``.ori``'s matrices fit the ``.im``'s measurements transposed and not as read (the file
    written object -> camera). Only the orientations and the measurements (tie points too) of the two files, in the
    file's own coordinates; a ``.ori`` without ``.im`` cannot be told (docs/exchange.md)."""
    index = {v: k for k, v in enumerate(nums)}
    keep = np.array([p in index for p in im_photo], bool)
    if keep.sum() < 2:
        return []
    photo = np.array([index[p] for p, k in zip(im_photo, keep) if k], int)
    point = np.array(im_point, object)[keep]
    c_mm, pixel_um = float(camera.focal_mm), float(camera.pixel_um)
    a, b, read_px = _y_parallax_px(centre, R, photo, point, xy_mm[keep], c_mm, pixel_um)
    if len(read_px) == 0:
        return []
    _, _, flip_px = _y_parallax_px(centre, R.transpose(0, 2, 1), photo, point, xy_mm[keep], c_mm, pixel_um)
    med_read, med_flip = float(np.median(read_px)), float(np.median(flip_px))
    if not (med_read > TRANSPOSED_MIN_PX and med_read > TRANSPOSED_FACTOR * med_flip):
        return []
    # per photo, the pairs it is in (grouped once: a test per photo over all pairs was photos x pairs)
    ph = np.r_[a, b]
    order = np.argsort(ph, kind="stable")
    read2, flip2 = np.r_[read_px, read_px][order], np.r_[flip_px, flip_px][order]
    photos, starts = np.unique(ph[order], return_index=True)
    bad = [nums[k] for k, r, f in zip(photos.tolist(), np.split(read2, starts[1:]), np.split(flip2, starts[1:]))
           if np.median(r) > TRANSPOSED_MIN_PX and np.median(r) > TRANSPOSED_FACTOR * np.median(f)]
    names = ", ".join(photo_id(v) for v in bad[:6]) + (" ..." if len(bad) > 6 else "")
    return [f"{path}: the rotation matrices look transposed (object -> camera; the PAT-B .ori holds camera -> "
            f"object): the rays of the points {im_path.name} measures in two photos miss each other by {med_read:.1f} "
            f"px (median y-parallax over {len(read_px)} pairs) as read, {med_flip:.2f} px transposed; "
            f"{len(bad)} of {len(nums)} photos ({names}): read as written, their omega, phi and kappa come in with "
            "their signs flipped. Transpose the three matrix records of each photo (a12 <-> a21, a13 <-> a31, a23 <-> a32) and import again"]


def read(files: list[Path], project: Project, options: ImportSettings) -> ImportedBlock:
    """``.ori``, ``.cam``, ``.con``, ``.im`` files and ``numbers.txt`` (see the module docstring)."""
    by, cons = {}, []
    for f in files:
        s = f.suffix.lower()
        if f.name == "numbers.txt":
            s = "numbers"
        elif s not in (".ori", ".cam", ".con", ".im"):
            raise InputError(f"{f}: not a PAT-B file (expected .ori, .cam, .con, .im or numbers.txt)")
        if s == ".con":
            cons.append(f)
            continue
        if s in by:
            raise InputError(f"{f}: a second {s} file (import one of each; several .con files are fine)")
        by[s] = f
    block = ImportedBlock(source=[str(f) for f in files])
    photos, points, kinds = read_numbers(by["numbers"]) if "numbers" in by else ({}, {}, {})
    photo_id = lambda v: photos.get(v, v)  # noqa: E731
    point_id = lambda v: points.get(v, v)  # noqa: E731
    crs = options.crs or project.crs
    if ".cam" in by:
        block.camera = read_cam(by[".cam"])
        block.origin["camera"] = by[".cam"].name
    if ".ori" in by:
        nums, centre, R, c_mm = read_ori(by[".ori"])
        if block.camera is not None:
            block.notes += principal_distance_notes(by[".ori"], c_mm, block.camera, by[".cam"].name)
        elif project.camera_path.is_file():
            block.notes += principal_distance_notes(by[".ori"], c_mm, Camera.read(project.camera_path),
                                                    str(project.camera_path))
        ori = (nums, centre, R)  # (the .con loop below reuses the names)
        ids = [photo_id(v) for v in nums]
        # the source named in the notes: the files carry no CRS (s95: the heights note named project.toml)
        source = "--crs" if options.crs else f"{by['.ori']} (PAT-B states no CRS: the project's, {project.config_path})"
        block.eo = orientations_to_project(ids, centre, R, crs, project, source)
        block.origin["eo"] = by[".ori"].name
        block.crs_assumed = options.crs is None
        if options.as_gnss:
            block.gnss, block.gnss_holds = positions_as_gnss(ids, block.eo.centre_m, options=options, project=project,
                                                             what="projection centres of the PAT-B orientations")
            block.origin["gnss"] = by[".ori"].name
    # a .con of no point (aerotri's export of a block without control writes one): nothing to import from it
    con_files = [(f, con) for f, con in ((f, read_con(f)) for f in cons) if len(con[0])]
    cons = [f for f, _ in con_files]
    if cons:
        pid, kind, xyz = [], [], []
        for f, (nums, a, said) in con_files:
            for v, k in zip(nums, said):
                p = point_id(v)
                if p in pid:
                    raise InputError(f"{f}: control point {p!r} is in another .con file too")
                pid.append(p)
                kind.append(kinds.get(p) or k or _kind_of_file(f))
            xyz.append(a)
        xyz = np.vstack(xyz)
        if options.crs:
            xyz = to_project_crs(xyz, options.crs, project, "--crs")
        block.crs_assumed = options.crs is None
        sig = np.tile(control_sigma_m(project, options, cons[0]), (len(pid), 1))
        block.control = ControlPoints(np.array(pid, object), np.array(kind, object), xyz, sig)
        block.origin["control"] = ", ".join(f.name for f in cons)
    if ".im" in by:
        path = by[".im"]
        pnums, inums, xy_mm, lines = read_im(path)
        if ".ori" in by and (block.camera is not None or project.camera_path.is_file()):
            transposed = transposed_rotation_notes(
                by[".ori"], path, *ori, inums, pnums, xy_mm,
                block.camera if block.camera is not None else Camera.read(project.camera_path), photo_id)
            if transposed:  # refused: imported, every photo came in up to 2.5 deg off, exit 0 (trial s96 M6)
                raise InputError(transposed[0])
        pids, iids = [point_id(v) for v in pnums], [photo_id(v) for v in inums]
        if block.control is not None:
            control_ids = set(block.control.id)
        elif project.control_points_path.is_file():
            from aerotri.geom.observations import read_control_points

            control_ids = set(read_control_points(project.control_points_path).id)
        elif ".ori" in by:
            # a block without control (the DEM its control): the .im's tie points served the check of the .ori's
            # matrices, the only reading of them (trial-ngi: refused, so a transposed .ori came in without a word)
            block.notes.append(f"{path}: no control points to import measurements of; its {len(pnums)} measurements "
                               f"checked the rotation matrices of {by['.ori'].name}")
            return block
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
        block.origin["image_points"] = path.name
        block.notes.append(f"{path}: {int(keep.sum())} measurements of control points imported, "
                           f"{int((~keep).sum())} of tie points left out")
    return block
