"""LiDAR roof corners (``lidar_out/corners.csv`` from ``lidarctl corners``) and manual measurements.

Columns: ``id,x,y,z,sx_m,sy_m,sz_m,roof,building_id,edge1_deg,edge2_deg,angle_deg,support_pts,score[,usable]``.
Edge directions are grid bearings (clockwise from grid north, degrees, modulo 180) of the two roof
edges meeting at the corner; ``angle_deg`` is the interior angle of the roof polygon (90 convex,
270 re-entrant). Without a ``usable`` column a corner is usable when ``score >= USABLE_SCORE``.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.textio import read_text

REQUIRED = ["id", "x", "y", "z", "sx_m", "sy_m", "sz_m", "edge1_deg", "edge2_deg", "angle_deg", "score"]
USABLE_SCORE = 0.5  # lidarctl.corners.roof_corners.USABLE_SCORE (same rule when the file has no usable column)


@dataclasses.dataclass
class LidarCorners:
    """Roof corners; arrays aligned with ``id``."""

    id: np.ndarray  # (N,) str
    xyz_m: np.ndarray  # (N, 3) project CRS
    sigma_m: np.ndarray  # (N, 3) sx sy sz
    bearing_deg: np.ndarray  # (N, 2) grid bearings of the two edges, [0, 180)
    angle_deg: np.ndarray  # (N,)
    score: np.ndarray  # (N,)
    usable: np.ndarray  # (N,) bool
    roof: np.ndarray  # (N,) str

    def __len__(self):
        return len(self.id)

    def subset(self, mask) -> "LidarCorners":
        return LidarCorners(*(getattr(self, f.name)[mask] for f in dataclasses.fields(self)))

    def edge_directions_m(self) -> np.ndarray:
        """Unit edge directions (N, 2, 3) in object space (east, north, up = 0)."""
        b = np.radians(self.bearing_deg)
        return np.stack([np.sin(b), np.cos(b), np.zeros_like(b)], axis=-1)


def read_corners(path, crs=None) -> LidarCorners:
    """``corners.csv`` of lidarctl corners; with ``crs`` (the project's, pyproj) the corners' x, y are checked
    against it (another zone's numbers, feet for metres, swapped columns: InputError naming the line)."""
    path = Path(path)
    text = read_text(path, "corners file", hint="run lidarctl corners CLASSIFIED.laz lidar_out")
    reader = csv.DictReader(text.splitlines())
    missing = [c for c in REQUIRED if c not in (reader.fieldnames or [])]
    if missing:
        raise InputError(f"{path}:1: missing columns {missing} (expected {','.join(REQUIRED)},...)")
    ids, num, usable, roof, seen = [], [], [], [], {}
    for row in reader:
        lineno = reader.line_num
        if None in row or None in row.values():
            n = len(reader.fieldnames) + len(row.get(None) or []) - sum(v is None for v in row.values())
            raise InputError(f"{path}:{lineno}: {n} fields, expected {len(reader.fieldnames)} "
                             f"({','.join(reader.fieldnames)})")
        pid = (row["id"] or "").strip()
        if not pid:
            raise InputError(f"{path}:{lineno}: empty id (record {row})")
        if pid in seen:
            raise InputError(f"{path}:{lineno}: duplicate corner id {pid!r} (first on line {seen[pid]})")
        seen[pid] = lineno
        vals = []
        for c in REQUIRED[1:]:
            try:
                v = float(row[c])
            except (TypeError, ValueError):
                raise InputError(f"{path}:{lineno}: {c} = {row[c]!r} of corner {pid!r} is not a number") from None
            if not math.isfinite(v):
                raise InputError(f"{path}:{lineno}: {c} of corner {pid!r} is NaN or infinite")
            vals.append(v)
        if min(vals[3:6]) <= 0:
            raise InputError(f"{path}:{lineno}: standard deviations of corner {pid!r} must be positive")
        ids.append(pid)
        num.append(vals)
        u = row.get("usable")
        usable.append(vals[-1] >= USABLE_SCORE if u is None else u.strip().lower() in ("1", "true", "yes"))
        roof.append((row.get("roof") or "").strip())
    if not ids:
        raise InputError(f"{path}: no corners")
    a = np.array(num, dtype=float)
    if crs is not None:
        from aerotri.geom.crs.definition import check_coordinates

        check_coordinates(crs, a[:, 0], a[:, 1], str(path), [f"line {seen[i]} (corner {i})" for i in ids])
    return LidarCorners(
        np.array(ids, dtype=object), a[:, 0:3], a[:, 3:6], np.mod(a[:, 6:8], 180.0), a[:, 8], a[:, 9],
        np.array(usable, dtype=bool), np.array(roof, dtype=object),
    )


@dataclasses.dataclass(frozen=True)
class ManualMeasurements:
    """Corners measured by hand: per measurement the corner id, the frame id and (x, y) in pixels (file order)."""

    point_id: tuple[str, ...]
    image_id: tuple[str, ...]
    xy_px: np.ndarray  # (M, 2)

    def __len__(self) -> int:
        return len(self.point_id)


def read_manual(path, corner_ids, image_ids, camera=None, corners_path="corners.csv",
                eo_path="eo.txt") -> ManualMeasurements:
    """Manual measurements ``point_id,image_id,x_px,y_px`` (a corner measured twice in a frame: the last one).

    Every record must name a corner and a frame of the block and, with ``camera``, lie inside the frame
    (a measurement is never dropped silently: InputError naming the line)."""
    from aerotri.geom.observations import read_image_points

    obs = read_image_points(path)
    if len(obs) == 0:  # a file given to import measurements that holds none: the wrong file
        raise InputError(f"{path}: no measurements (expected point_id,image_id,x_px,y_px records after the header)")
    known_c, known_i = set(corner_ids), set(image_ids)
    out = {}  # (point_id, image_id) -> (x_px, y_px): the last measurement of a corner in a frame
    for k in range(len(obs)):
        pid, iid = str(obs.point_id[k]), str(obs.image_id[k])
        where = obs.where(k, path)
        if pid not in known_c:
            raise InputError(f"{where}: point {pid!r} is not a corner id in {corners_path}")
        if iid not in known_i:
            raise InputError(f"{where}: image {iid!r} of point {pid!r} is not in the orientations {eo_path}")
        x, y = obs.xy_px[k]
        if camera is not None and not camera.inside(x, y):
            raise InputError(f"{where}: measurement ({x:.1f}, {y:.1f}) px of point {pid!r} is outside the "
                             f"{camera.width} x {camera.height} px frame {iid!r} (x in 0..{camera.width - 1}, "
                             f"y in 0..{camera.height - 1})")
        out[(pid, iid)] = (float(x), float(y))
    return ManualMeasurements(tuple(p for p, _ in out), tuple(i for _, i in out),
                              np.array(list(out.values()), dtype=float).reshape(-1, 2))
