"""Readers and validation of the adjustment inputs (tie points, control points and their image points).

``at/tiepoints.csv``: ``point_id,image_id,x_px,y_px``; ``control/points.csv``:
``id,kind,x,y,z,sx_m,sy_m,sz_m`` with kind ``full`` (XYZ control), ``horizontal``, ``height`` or
``check``; ``control/image_points.csv``: ``point_id,image_id,x_px,y_px``. Pixel coordinates follow
aerotri.geom.camera (origin at the centre of the top-left pixel, x right, y down).
Every problem raises InputError naming the file, line and record.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError, id_listing
from aerotri.core.textio import read_text

TIE_HEADER = ["point_id", "image_id", "x_px", "y_px"]
CONTROL_HEADER = ["id", "kind", "x", "y", "z", "sx_m", "sy_m", "sz_m"]
CONTROL_KINDS = ("full", "horizontal", "height", "check")
KIND_COMPONENTS = {"horizontal": (True, True, False), "height": (False, False, True)}  # x y z surveyed; others all
COINCIDENT_PX = 2.0  # two different control points measured closer than this in one frame: one is mislabelled


@dataclasses.dataclass
class ImageObservations:
    """Image measurements, one row per (point, image); arrays aligned."""

    point_id: np.ndarray  # (N,) str
    image_id: np.ndarray  # (N,) str
    xy_px: np.ndarray  # (N, 2)
    line: np.ndarray | None = None  # (N,) line numbers in the file read (for messages)

    def __len__(self):
        return len(self.point_id)

    def subset(self, mask) -> "ImageObservations":
        return ImageObservations(self.point_id[mask], self.image_id[mask], self.xy_px[mask],
                                 None if self.line is None else self.line[mask])

    def where(self, k: int, path) -> str:
        """``path:line`` of observation ``k`` (``path`` alone when the lines are unknown)."""
        return f"{path}:{int(self.line[k])}" if self.line is not None else str(path)


@dataclasses.dataclass
class ControlPoints:
    """Ground control and check points in the project CRS."""

    id: np.ndarray  # (M,) str
    kind: np.ndarray  # (M,) str, one of CONTROL_KINDS
    xyz_m: np.ndarray  # (M, 3)
    sigma_m: np.ndarray  # (M, 3)
    measured: np.ndarray | None = None  # (M, 3) bool: the coordinates surveyed (None: those of the kind)

    def __len__(self):
        return len(self.id)

    def measured_xyz(self) -> np.ndarray:
        """(M, 3) bool: which of x, y, z each point was surveyed in (a horizontal point made a check point
        keeps its unmeasured height out of the check)."""
        if self.measured is not None:
            return self.measured
        return np.array([KIND_COMPONENTS.get(k, (True, True, True)) for k in self.kind], bool).reshape(-1, 3)

    def subset(self, mask) -> "ControlPoints":
        return ControlPoints(self.id[mask], self.kind[mask], self.xyz_m[mask], self.sigma_m[mask],
                             None if self.measured is None else self.measured[mask])

    def with_kinds(self, kinds: dict[str, str]) -> "ControlPoints":
        """A copy with the kind of some points changed (e.g. ``{"gcp03": "check"}``); the coordinates each
        point was surveyed in stay (``measured_xyz``)."""
        unknown = sorted(set(kinds) - set(self.id.tolist()))
        if unknown:
            raise InputError(f"control points {unknown} are not in the control point file")
        kind = self.kind.copy()
        for i, pid in enumerate(self.id):
            if pid in kinds:
                kind[i] = kinds[pid]
        return ControlPoints(self.id.copy(), kind, self.xyz_m.copy(), self.sigma_m.copy(), self.measured_xyz().copy())


def _rows(path: Path, header: list[str], hint: str = ""):
    text = read_text(path, f"CSV table ({','.join(header)})", hint)
    lines = text.splitlines()
    reader = csv.reader(lines)
    try:
        head = next(reader)
    except StopIteration:
        raise InputError(f"{path}: empty file (expected header {','.join(header)})") from None
    if [h.strip() for h in head] != header:
        raise InputError(f"{path}:1: header {','.join(head)!r} is not {','.join(header)!r}")
    for lineno, row in enumerate(reader, start=2):
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(row) != len(header):
            raise InputError(f"{path}:{lineno}: expected {len(header)} fields ({','.join(header)}), got {row}")
        yield lineno, [c.strip() for c in row]


def _number(path, lineno, row, field, text) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"{path}:{lineno}: {field} = {text!r} is not a number (record {row})") from None
    if not math.isfinite(v):
        raise InputError(f"{path}:{lineno}: {field} is NaN or infinite (record {row})")
    return v


def _plain_image_points(text: str) -> ImageObservations | None:
    """The observations of a ``point_id,image_id,x_px,y_px`` text that is plain (the header, then four fields a
    line: no quotes, blanks, empty lines, empty ids, NaN or duplicate pairs), read by whole-text splits and
    one float conversion per column (5 M lines in seconds, not minutes); None for any other text, which
    ``read_image_points`` then reads line by line and refuses with the line of the first problem."""
    header = ",".join(TIE_HEADER) + "\n"
    if not text.startswith(header) or '"' in text or " " in text or "\t" in text or "\r" in text:
        return None
    body = text[len(header):]
    if body and not body.endswith("\n"):
        body += "\n"
    # every line three commas and its newline, in that order (a line of 3 fields and one of 5 would
    # otherwise split into the right number of fields)
    raw = np.frombuffer(body.encode(), dtype=np.uint8)
    sep = raw[(raw == 44) | (raw == 10)]
    if len(sep) % 4 or not (sep.reshape(-1, 4) == (44, 44, 44, 10)).all():
        return None
    n = len(sep) // 4
    fields = body[:-1].replace("\n", ",").split(",") if n else []
    pids, iids = fields[0::4], fields[1::4]
    if "" in pids or "" in iids or _has_duplicate_pair(pids, iids):
        return None
    try:
        xy = np.column_stack([np.array(fields[2::4], dtype=float), np.array(fields[3::4], dtype=float)]).reshape(-1, 2)
    except ValueError:
        return None
    if not np.isfinite(xy).all():
        return None
    return ImageObservations(np.array(pids, dtype=object), np.array(iids, dtype=object), xy, np.arange(2, n + 2))


def _has_duplicate_pair(pids: list, iids: list) -> bool:
    """Whether a (point, image) pair occurs twice: by the strings' hashes (sorted), exactly only when two hashes
    agree."""
    key = np.fromiter(map(hash, pids), np.int64, len(pids)) * np.int64(1_000_003) ^ np.fromiter(
        map(hash, iids), np.int64, len(iids))
    key.sort()
    if not (key[1:] == key[:-1]).any():
        return False
    return len(set(zip(pids, iids))) != len(pids)


def read_image_points(path, hint: str = "") -> ImageObservations:
    """Read a ``point_id,image_id,x_px,y_px`` file; rejects NaN and duplicate (point, image) pairs.
    ``hint``: added to the message when the file does not exist (the stage that writes it)."""
    path = Path(path)
    plain = _plain_image_points(read_text(path, f"CSV table ({','.join(TIE_HEADER)})", hint))
    if plain is not None:
        return plain
    pids, iids, xy, seen = [], [], [], {}
    for lineno, row in _rows(path, TIE_HEADER, hint):
        pid, iid = row[0], row[1]
        if not pid or not iid:
            raise InputError(f"{path}:{lineno}: empty point_id or image_id (record {row})")
        key = (pid, iid)
        if key in seen:
            raise InputError(
                f"{path}:{lineno}: duplicate measurement of point {pid!r} in image {iid!r} (first on line {seen[key]})"
            )
        seen[key] = lineno
        xy.append((_number(path, lineno, row, "x_px", row[2]), _number(path, lineno, row, "y_px", row[3])))
        pids.append(pid)
        iids.append(iid)
    return ImageObservations(np.array(pids, dtype=object), np.array(iids, dtype=object),
                             np.array(xy, dtype=float).reshape(-1, 2), np.array(list(seen.values()), dtype=int))


def check_distinct_points(obs: ImageObservations, path, min_px: float = COINCIDENT_PX) -> None:
    """Refuse (``InputError``) two different points measured within ``min_px`` of each other in one frame: a target
    has one place, so at least one of the two is measured on the wrong target (or under the wrong name). The
    message names both points, the frame and the lines of ``path`` (``obs.line``)."""
    if len(obs) < 2:
        return
    from scipy.spatial import cKDTree

    images = obs.image_id.astype(str)
    for image in np.unique(images):
        k = np.flatnonzero(images == image)
        if len(k) < 2:
            continue
        for a, b in sorted(cKDTree(obs.xy_px[k]).query_pairs(min_px)):
            ka, kb = sorted((k[a], k[b]), key=lambda q: (obs.line[q] if obs.line is not None else q))
            if obs.point_id[ka] == obs.point_id[kb]:
                continue
            d = float(np.hypot(*(obs.xy_px[ka] - obs.xy_px[kb])))
            where = f" (lines {int(obs.line[ka])} and {int(obs.line[kb])})" if obs.line is not None else ""
            raise InputError(
                f"{obs.where(kb, path)}: points {str(obs.point_id[ka])!r} and {str(obs.point_id[kb])!r} are measured "
                f"{d:.1f} px apart in frame {str(image)!r}{where}; two targets cannot be at one place: one of the "
                f"measurements is on the wrong target or under the wrong name. Correct or remove it")


def read_control_image_points(path, hint: str = "") -> ImageObservations:
    """``read_image_points`` of control measurements (``control/image_points.csv``), with ``check_distinct_points``."""
    obs = read_image_points(path, hint)
    check_distinct_points(obs, path)
    return obs


def read_control_points(path, crs=None, hint: str = "") -> ControlPoints:
    """Read ``control/points.csv``; rejects unknown kinds, NaN, non-positive sigmas, duplicate ids, and
    with ``crs`` (pyproj CRS) coordinates that cannot be in it (swapped x/y, degrees, another zone)."""
    path = Path(path)
    ids, kinds, xyz, sig, seen = [], [], [], [], {}
    for lineno, row in _rows(path, CONTROL_HEADER, hint):
        pid, kind = row[0], row[1].lower()
        if not pid:
            raise InputError(f"{path}:{lineno}: empty id (record {row})")
        if pid in seen:
            raise InputError(f"{path}:{lineno}: duplicate control point id {pid!r} (first on line {seen[pid]})")
        seen[pid] = lineno
        if kind not in CONTROL_KINDS:
            raise InputError(f"{path}:{lineno}: kind {row[1]!r} of point {pid!r} is not one of {', '.join(CONTROL_KINDS)}")
        vals = [_number(path, lineno, row, f, t) for f, t in zip(CONTROL_HEADER[2:], row[2:])]
        if min(vals[3:]) <= 0:
            raise InputError(f"{path}:{lineno}: standard deviations of point {pid!r} must be positive (record {row})")
        ids.append(pid)
        kinds.append(kind)
        xyz.append(vals[:3])
        sig.append(vals[3:])
    if not ids:
        raise InputError(f"{path}: no control points")
    if crs is not None:
        from aerotri.geom.crs.definition import check_coordinates

        a = np.array(xyz, dtype=float)
        check_coordinates(crs, a[:, 0], a[:, 1], str(path), [f"line {seen[p]} (point {p})" for p in ids])
    return ControlPoints(
        np.array(ids, dtype=object), np.array(kinds, dtype=object), np.array(xyz, dtype=float), np.array(sig, dtype=float)
    )


def format_image_points(obs: ImageObservations) -> str:
    """``point_id,image_id,x_px,y_px`` CSV text (the reader's format; pixel centre origin, x right, y down)."""
    rows = [",".join(TIE_HEADER)]
    rows += [f"{p},{i},{x:.3f},{y:.3f}" for p, i, (x, y) in zip(obs.point_id, obs.image_id, obs.xy_px)]
    return "\n".join(rows) + "\n"


def format_control_points(cp: ControlPoints) -> str:
    """``control/points.csv`` text (the reader's format: id,kind,x,y,z,sx_m,sy_m,sz_m; project CRS)."""
    rows = [",".join(CONTROL_HEADER)]
    for pid, kind, xyz, sig in zip(cp.id, cp.kind, cp.xyz_m, cp.sigma_m):
        rows.append(f"{pid},{kind}," + ",".join(f"{v:.4f}" for v in xyz) + "," + ",".join(f"{v:.4f}" for v in sig))
    return "\n".join(rows) + "\n"


def validate_references(
    ties: ImageObservations,
    control: ControlPoints | None,
    control_obs: ImageObservations | None,
    image_ids: list[str],
    *, tie_path="at/tiepoints.csv",
    control_path="control/points.csv",
    control_obs_path="control/image_points.csv",
    camera=None,
    block_path="gnss.txt",
    camera_path="camera.toml",
) -> None:
    """Cross-file checks: unknown images, measurements outside the frame, control ids without image
    measurement, ids in both files. ``block_path``: the file that defines the block's images
    (gnss.txt or an EO file), ``camera_path``: the camera's file (both for the messages)."""
    known = set(image_ids)
    for obs, path in ((ties, tie_path), (control_obs, control_obs_path)):
        if obs is None or len(obs) == 0:
            continue
        # a set lookup per measurement (np.isin of object arrays compares every measurement with every image)
        unknown = ~np.fromiter(map(known.__contains__, obs.image_id.tolist()), dtype=bool, count=len(obs))
        if unknown.any():
            k = int(np.argmax(unknown))
            bad = [i for i in np.unique(obs.image_id) if i not in known]
            raise InputError(f"{obs.where(k, path)}: image id(s) {id_listing(bad)} are not in the block ({block_path} has "
                             f"{len(known)} image(s))")
        if camera is not None:
            outside = ~camera.inside(obs.xy_px[:, 0], obs.xy_px[:, 1])
            if outside.any():
                k = int(np.argmax(outside))
                raise InputError(
                    f"{obs.where(k, path)}: measurement of point {obs.point_id[k]!r} in image {obs.image_id[k]!r} at "
                    f"({obs.xy_px[k, 0]:.1f}, {obs.xy_px[k, 1]:.1f}) px is outside the {camera.width} x {camera.height} "
                    f"px frame of {camera_path}"
                )
    if control is None:
        return
    measured = set() if control_obs is None else set(np.unique(control_obs.point_id).tolist())
    missing = [p for p in control.id if p not in measured]
    if missing:
        raise InputError(f"{control_path}: {len(missing)} control point(s) have no image measurement in {control_obs_path}: "
                         f"{id_listing(missing)}")
    if control_obs is not None:
        orphan = sorted(set(measured) - set(control.id.tolist()))
        if orphan:
            raise InputError(f"{control_obs_path}: point ids {id_listing(orphan)} are not in {control_path}")
    clash = sorted(set(control.id.tolist()) & set(ties.point_id.tolist()))  # a set: no sort of every measurement
    if clash:
        raise InputError(f"{tie_path}: point ids {id_listing(clash)} are also control point ids in {control_path}")
