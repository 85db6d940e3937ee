"""Field check of LiDAR heights against surveyed points (the production "height check table").

For each surveyed point (X, Y, Z) the cloud's ground height is interpolated from the ground points
(class 2) within ``radius_m`` horizontally: a least-squares plane, inverse-distance weighted
(1/d^2), evaluated at (X, Y); with fewer than 3 points the IDW mean. dz = Z_lidar - Z_surveyed (m).
Statistics: counts per error bin, mean |dz|, RMSE, mean dz; the same without |dz| > ``exclude_m``;
all of it per group (e.g. open / road / steep / dense vegetation) when a group column is given.

Units: the surveyed points are in the cloud's CRS (x, y in its horizontal unit, z in its vertical
unit). Radius, threshold, bins and every ``_m`` key (dz, mean, RMSE) are metres, also for clouds
in feet; the per-point coordinates (``x``, ``y``, ``z_survey``, ``z_lidar``) are in the CRS's units,
named by ``xy_unit`` and ``z_unit``.
"""

from __future__ import annotations

import csv
import io as stringio
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from aerotri.geom import las

from aerotri.core.errors import InputError, OptionError
from aerotri.core.textio import read_text
from lidarctl import io
from lidarctl.units import METRE, LengthUnits

BIN_EDGES_M = (-np.inf, -1.0, -0.5, 0.5, 1.0, 1.5, 2.0, 5.0, np.inf)


def bin_labels(edges=BIN_EDGES_M) -> list[str]:
    labels = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        if np.isinf(lo):
            labels.append(f"< {hi:g}")
        elif np.isinf(hi):
            labels.append(f"> {lo:g}")
        else:
            labels.append(f"{lo:g} .. {hi:g}")
    return labels


def read_points_csv(path) -> dict:
    """Surveyed points: header with id, x, y, z (case-insensitive; also e/n/h) and optional group."""
    path = Path(path)
    rows = list(csv.reader(stringio.StringIO(read_text(path, "surveyed points table (id,x,y,z[,group])"), newline="")))
    if not rows:
        raise InputError(f"{path}: empty file, expected a header line 'id,x,y,z[,group]'")
    head = [h.strip().lower() for h in rows[0]]
    alias = {"x": ("x", "e", "easting"), "y": ("y", "n", "northing"), "z": ("z", "h", "height", "elevation")}
    col = {}
    for key, names in alias.items():
        found = [k for k, h in enumerate(head) if h in names]
        if not found:
            raise InputError(f"{path}: line 1: no '{key}' column in header {rows[0]}")
        col[key] = found[0]
    col_id = head.index("id") if "id" in head else None
    col_group = head.index("group") if "group" in head else None
    ids, xyz, groups = [], [], []
    for line_no, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) < len(head):
            raise InputError(f"{path}: line {line_no}: {len(row)} fields, expected {len(head)}")
        try:
            vals = [float(row[col[k]]) for k in ("x", "y", "z")]
        except ValueError:
            raise InputError(f"{path}: line {line_no}: x/y/z not numbers: {row}") from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path}: line {line_no}: non-finite coordinate: {row}")
        ids.append(row[col_id].strip() if col_id is not None else str(line_no - 1))
        xyz.append(vals)
        groups.append(row[col_group].strip() if col_group is not None else "")
    if not xyz:
        raise InputError(f"{path}: no surveyed points after the header")
    xyz = np.array(xyz)
    return {"id": ids, "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
            "group": groups if col_group is not None else None}


def ground_height_at(gx, gy, gz, qx, qy, radius_m: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Interpolated ground height at (qx, qy) and the number of ground points used (NaN if none)."""
    tree = cKDTree(np.column_stack([gx, gy]))
    z_out = np.full(len(qx), np.nan)
    n_used = np.zeros(len(qx), int)
    for k, nb in enumerate(tree.query_ball_point(np.column_stack([qx, qy]), radius_m)):
        if not nb:
            continue
        nb = np.asarray(nb)
        dx, dy = gx[nb] - qx[k], gy[nb] - qy[k]
        w = 1.0 / np.maximum(dx * dx + dy * dy, 0.01)
        n_used[k] = len(nb)
        if len(nb) >= 3:
            a = np.column_stack([np.ones(len(nb)), dx, dy]) * np.sqrt(w)[:, None]
            coef, _, rank, _ = np.linalg.lstsq(a, gz[nb] * np.sqrt(w), rcond=None)
            if rank == 3:
                z_out[k] = coef[0]
                continue
        z_out[k] = np.sum(w * gz[nb]) / np.sum(w)
    return z_out, n_used


def stats(dz: np.ndarray, exclude_m: float) -> dict:
    dz = dz[np.isfinite(dz)]
    counts, _ = np.histogram(dz, bins=np.array(BIN_EDGES_M))
    kept = dz[np.abs(dz) <= exclude_m]
    n = len(dz)

    def block(d):
        return {"n": int(len(d)),
                "mean_dz_m": float(np.mean(d)) if len(d) else None,
                "mean_abs_dz_m": float(np.mean(np.abs(d))) if len(d) else None,
                "rmse_m": float(np.sqrt(np.mean(d * d))) if len(d) else None}

    return {
        "bins": [{"bin_m": lab, "count": int(c), "percent": 100.0 * c / n if n else 0.0}
                 for lab, c in zip(bin_labels(), counts)],
        "all": block(dz),
        "excluded_beyond_m": exclude_m,
        "without_excluded": block(kept),
    }


def check_heights(gx, gy, gz, points: dict, radius_m: float = 5.0, exclude_m: float = 1.0,
                  units: LengthUnits = METRE) -> dict:
    """dz statistics of surveyed ``points`` against ground points (gx, gy, gz); all in metres.

    ``units``: the CRS's units, in which the per-point coordinates are reported (the points as read,
    ``read_points_csv``, scaled by ``units`` to metres give ``points``)."""
    z_lidar, n_used = ground_height_at(gx, gy, gz, points["x"], points["y"], radius_m)
    dz = z_lidar - points["z"]
    xs, ys = units.xy_from_m(np.asarray(points["x"])), units.xy_from_m(np.asarray(points["y"]))
    zs, zl_crs = units.z_from_m(np.asarray(points["z"])), units.z_from_m(z_lidar)
    per_point = [{"id": i, "x": float(x), "y": float(y), "z_survey": float(z),
                  "z_lidar": None if not np.isfinite(zl) else float(zl),
                  "dz_m": None if not np.isfinite(d) else float(d), "n_ground": int(nu),
                  "group": (points["group"][k] if points["group"] else None)}
                 for k, (i, x, y, z, zl, d, nu) in enumerate(zip(points["id"], xs, ys, zs, zl_crs, dz, n_used))]
    result = {"radius_m": radius_m, **units.as_dict(), "n_points": len(dz),
              "n_without_ground": int(np.sum(~np.isfinite(dz))),
              "overall": stats(dz, exclude_m), "points": per_point, "groups": {}}
    if points["group"]:
        groups = np.array(points["group"])
        for g in sorted(set(points["group"])):
            result["groups"][g] = stats(dz[groups == g], exclude_m)
    return result


def _near_points(px_m, py_m, radius_m: float):
    """A function (x, y) -> mask of the points within ``radius_m`` of any of (px_m, py_m)."""
    tree = cKDTree(np.column_stack([px_m, py_m]))
    lo = np.array([np.min(px_m), np.min(py_m)]) - radius_m
    hi = np.array([np.max(px_m), np.max(py_m)]) + radius_m

    def near(x, y):
        mask = (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
        k = np.flatnonzero(mask)
        if len(k):
            d, _ = tree.query(np.column_stack([x[k], y[k]]), distance_upper_bound=radius_m)
            mask[k] = d <= radius_m
        return mask

    return near


def check_heights_file(cloud_paths, points_csv, radius_m: float = 5.0, exclude_m: float = 1.0, crs=None) -> dict:
    """``check_heights`` of the ground (class 2) of a classified LAS/LAZ file, or of several strips
    (one CRS and unit, else an InputError naming the strip; only their ground points are kept),
    against a CSV of surveyed points in the cloud's CRS and units (``crs`` only for files without CRS)."""
    if not (np.isfinite(radius_m) and radius_m > 0):
        raise OptionError(f"--radius {radius_m}: must be a positive distance in metres", param="--radius")
    if not (np.isfinite(exclude_m) and exclude_m > 0):
        raise OptionError(f"--exclude {exclude_m}: must be a positive height difference in metres", param="--exclude")
    paths = [cloud_paths] if isinstance(cloud_paths, (str, Path)) else list(cloud_paths)
    points = read_points_csv(points_csv)
    # Only ground points within radius_m of a surveyed point enter the interpolation: the strips
    # are read by chunks and only those are kept (memory set by the chunk, not by the block).
    ground, first, n_ground = [], None, 0
    for path in paths:
        header = las.read_header(path)
        if header.point_count == 0:
            raise InputError(f"{path}: the file holds no points")
        crs_i, units = io.resolve_crs_units(path, header, crs)
        if first is None:
            first = (path, crs_i, units)
            near = _near_points(units.xy_to_m(points["x"]), units.xy_to_m(points["y"]), radius_m)
        else:
            io.require_same_crs(path, crs_i, units, first)
        for first_record, chunk in las.iter_file_chunks(path, io.CHUNK_POINTS):
            cx, cy, cz = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            io.validate_xyz(path, cx, cy, cz, first_record, units)
            g = np.asarray(chunk.classification) == 2
            n_ground += int(g.sum())
            gx, gy = units.xy_to_m(cx[g]), units.xy_to_m(cy[g])
            keep = near(gx, gy)
            ground.append((gx[keep], gy[keep], units.z_to_m(cz[g][keep])))
    gx, gy, gz = (np.concatenate([gr[k] for gr in ground]) for k in range(3))
    if not n_ground:
        raise InputError(f"{', '.join(map(str, paths))}: no ground points (class 2); run 'lidarctl classify' first")
    crs_found, u = first[1], first[2]
    points_m = dict(points, x=u.xy_to_m(points["x"]), y=u.xy_to_m(points["y"]), z=u.z_to_m(points["z"]))
    result = check_heights(gx, gy, gz, points_m, radius_m, exclude_m, units=u)
    result["crs"] = crs_found.to_string() if crs_found is not None else None
    return result


def _format_block(title: str, s: dict) -> list[str]:
    lines = [title, f"  {'error bin (m)':<16}{'count':>8}{'percent':>10}"]
    for b in s["bins"]:
        lines.append(f"  {b['bin_m']:<16}{b['count']:>8}{b['percent']:>9.1f}%")

    def fmt(v):
        return "-" if v is None else f"{v:.3f}"

    a, w = s["all"], s["without_excluded"]
    lines.append(f"  n = {a['n']}  mean |dz| = {fmt(a['mean_abs_dz_m'])} m  RMSE = {fmt(a['rmse_m'])} m"
                 f"  mean dz = {fmt(a['mean_dz_m'])} m")
    lines.append(f"  without |dz| > {s['excluded_beyond_m']:g} m: n = {w['n']}  mean |dz| = "
                 f"{fmt(w['mean_abs_dz_m'])} m  RMSE = {fmt(w['rmse_m'])} m")
    return lines


def format_report(result: dict) -> str:
    """The height check table; statistics in metres, heights in the CRS's vertical unit (named), dz
    in metres and, for a cloud in feet, also in feet."""
    zu = result.get("z_unit", "m")
    z_unit_m = result.get("z_unit_m", 1.0)
    lines = ["LiDAR height check (dz = Z_lidar - Z_surveyed, in metres)",
             f"search radius {result['radius_m']:g} m, {result['n_points']} points, "
             f"{result['n_without_ground']} without ground points in range", ""]
    if zu != "m":
        lines[-1:-1] = [f"heights in {zu} (the cloud's vertical unit); dz and statistics in m"]
    lines += _format_block("All points", result["overall"])
    for g, s in result["groups"].items():
        lines += [""] + _format_block(f"Group: {g}", s)
    head = f"{'id':<12}{'group':<18}{f'z survey ({zu})':>16}{f'z lidar ({zu})':>16}{'dz (m)':>9}"
    if zu != "m":
        head += f"{f'dz ({zu})':>10}"
    lines += ["", head]
    for p in result["points"]:
        zl = "-" if p["z_lidar"] is None else f"{p['z_lidar']:.3f}"
        dz = "-" if p["dz_m"] is None else f"{p['dz_m']:+.3f}"
        line = f"{p['id']:<12}{(p['group'] or ''):<18}{p['z_survey']:>16.3f}{zl:>16}{dz:>9}"
        if zu != "m":
            line += f"{'-' if p['dz_m'] is None else format(p['dz_m'] / z_unit_m, '+.3f'):>10}"
        lines.append(line)
    return "\n".join(lines)
