"""Files: common-point lists, height points, parameter files, and transforming point lists and LAS/LAZ.

Common points (``crs fit``), CSV or whitespace text with a header line::

    id,x_from,y_from,z_from,x_to,y_to,z_to
    P01,423456.789,3812345.678,512.345,37423400.123,3812300.456,498.765

x = easting (or longitude), y = northing (or latitude) in the units of each CRS; z (ellipsoidal
heights, metres) is needed by the spatial models only. Columns may carry a unit suffix
(``x_from_m``, ``y_to_deg``, ``_ft``); the suffixes must agree with each other and with the CRS.

Height points (``crs fit-heights``): header ``id,x,y,h,H`` (h ellipsoidal, H normal height, metres;
``h_ellipsoidal``/``H_normal`` also accepted).

Point lists (``crs transform``): CSV with a header naming ``x``, ``y`` and optionally ``z`` columns
(case-insensitive; other columns are copied), or header-less whitespace text ``id x y z ...``
(like gnss.txt). Lines starting with ``#`` are kept as they are. Columns omega, phi, kappa (degrees; named by the
header, or by the comment line above header-less records, as eo.txt writes it) are attitudes: they turn with the grid.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import io
import math
import re
from pathlib import Path

import numpy as np

from aerotri.geom import las
from aerotri.geom.crs.ellipsoid import Ellipsoid, geocentric_to_geodetic, geodetic_to_geocentric
from aerotri.geom.crs.definition import (check_coordinates, crs_label, height_unit_m, horizontal_crs, length_unit_name,
                                         linear_unit_m, parse_crs, same_crs, unit_name, vertical_crs)
from aerotri.geom.crs.fit import fit_plane, fit_spatial
from aerotri.geom.crs.datum import SPATIAL, load_height_model, load_transformation
from aerotri.geom.crs.transform import CrsTransformer, to_own_geodetic
from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.core.log import track_chunks
from aerotri.core.atomic import atomic_path, write_text_atomic
from aerotri.core.textio import read_text

LAS_SUFFIXES = (".las", ".laz")
_UNIT_SUFFIX = re.compile(r"^(?P<base>.+?)_(?P<unit>m|deg|ft|usft|us-ft)$", re.IGNORECASE)


# ----------------------------------------------------------------------------------------------
# Reading tables
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Table:
    path: Path
    header: list | None
    rows: list  # list of field lists
    line_numbers: list
    delimiter: str | None  # ',' or None for whitespace
    lines: list  # raw lines (for copying comments)


def _read_table(path, require_header: bool) -> _Table:
    path = Path(path)
    text = read_text(path, "point table")
    lines = text.splitlines()
    data = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not data:
        raise InputError(f"{path}: no records")
    delimiter = "," if "," in data[0][1] else None

    def split(ln):
        if delimiter == ",":
            return [f.strip() for f in next(csv.reader([ln]))]
        return ln.split()

    first = split(data[0][1])
    has_header = not _is_number(first[1]) if len(first) > 1 else True
    if require_header and not has_header:
        raise InputError(f"{path}: line {data[0][0]}: a header line naming the columns is required")
    if len(first) == 1 and (";" in first[0] or "，" in first[0]):
        # (trial s96 F12: "header ['id;x;y;z'] must name x and y columns", without saying why)
        sep = "semicolons" if ";" in first[0] else "full-width commas (，)"
        raise InputError(f"{path}: line {data[0][0]}: the fields are separated by {sep}, not commas or blanks (a "
                         "spreadsheet's CSV with decimal commas?): save it comma-separated with decimal points")
    header = first if has_header else None
    body = data[1:] if has_header else data
    if not body:
        raise InputError(f"{path}: a header line and no records (expected one point per line after it)")
    return _Table(path, header, [split(ln) for _, ln in body], [n for n, _ in body], delimiter, lines)


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _columns(table: _Table, wanted: dict, optional=(), skip=()) -> dict:
    """Map logical names to column indices; ``wanted`` maps a name to accepted header spellings (matched without
    case), the columns ``skip`` (indices) left out. Returns {name: (index, unit or None)}."""
    found = {}
    for j, col in enumerate(table.header):
        if j in skip:
            continue
        m = _UNIT_SUFFIX.match(col)
        base, unit = (m["base"], m["unit"].lower().replace("usft", "us-ft")) if m else (col, None)
        for name, spellings in wanted.items():
            if base in spellings or base.lower() in spellings:
                if name in found:
                    raise InputError(f"{table.path}: line 1: column {name} appears twice")
                found[name] = (j, unit)
    missing = [n for n in wanted if n not in found and n not in optional]
    if missing:
        raise InputError(
            f"{table.path}: header {table.header} lacks column(s) {', '.join(missing)} "
            f"(expected {', '.join(wanted)})"
        )
    return found


def _float_columns(table: _Table, cols: dict, names) -> dict:
    out = {n: np.empty(len(table.rows)) for n in names}
    for r, (fields, line) in enumerate(zip(table.rows, table.line_numbers)):
        for n in names:
            j = cols[n][0]
            if j >= len(fields):
                raise InputError(f"{table.path}: line {line}: missing value for {n}")
            try:
                v = float(fields[j])
            except ValueError:
                raise InputError(f"{table.path}: line {line}: {n} = {fields[j]!r} is not a number") from None
            if not math.isfinite(v):
                raise InputError(f"{table.path}: line {line}: {n} = {fields[j]!r} is not finite")
            out[n][r] = v
    return out


def _ids(table: _Table, j: int) -> list:
    ids, seen = [], {}
    for fields, line in zip(table.rows, table.line_numbers):
        pid = fields[j]
        if pid in seen:
            raise InputError(f"{table.path}: line {line}: duplicate point id {pid!r} (first on line {seen[pid]})")
        seen[pid] = line
        ids.append(pid)
    return ids


def _check_units(table: _Table, cols: dict, side: str, crs) -> None:
    units = {n: cols[n][1] for n in cols if n.endswith(side) and cols[n][1] is not None}
    horiz = {n: u for n, u in units.items() if not n.startswith("z")}
    if len(set(horiz.values())) > 1:
        raise InputError(
            f"{table.path}: line 1: mixed units in the header for the {side.strip('_')} system: "
            + ", ".join(f"{n}[{u}]" for n, u in horiz.items())
        )
    expected = unit_name(crs)
    for n, u in horiz.items():
        if u != expected:
            raise InputError(
                f"{table.path}: line 1: column {n} is in {u} but {crs_label(crs)} ({crs.name}) uses {expected} (mixed units)"
            )
    for n, u in units.items():
        if n.startswith("z") and u not in ("m",):
            raise InputError(f"{table.path}: line 1: column {n}: heights must be in metres, not {u}")


@dataclasses.dataclass
class CommonPoints:
    ids: list
    src: np.ndarray  # (n, 2) or (n, 3)
    dst: np.ndarray
    has_z: bool


# a point table's id column: "id", or as Chinese survey lists name it (点号 point number, 点名 point name; trial s96
# F12: crs fit refused 点号 that crs transform took)
ID_COLUMNS = ("id", "点号", "点名")


def read_common_points(path, from_crs, to_crs, need_z: bool = False) -> CommonPoints:
    table = _read_table(path, require_header=True)
    normal = [j for j, c in enumerate(table.header) if _is_normal_height_column(c)]
    if normal and need_z:
        raise InputError(f"{table.path}: line 1: column {table.header[normal[0]]} holds normal heights (H); the "
                         f"common points' heights are ellipsoidal heights h of each side's datum (z_from, z_to or "
                         f"h_from, h_to): {NORMAL_HEIGHTS_ADVICE}")
    wanted = {n: (n,) + ((n.replace("z_", "h_"),) if n.startswith("z_") else ())
              for n in ("id", "x_from", "y_from", "z_from", "x_to", "y_to", "z_to")}
    wanted["id"] = ID_COLUMNS
    # a plane model reads no heights: normal ones are left as any other column (review 44: helmert2d was refused)
    cols = _columns(table, wanted, optional=("z_from", "z_to"), skip=normal)
    has_z = "z_from" in cols and "z_to" in cols
    if need_z and not has_z:
        raise InputError(f"{table.path}: the spatial models need ellipsoidal heights in columns z_from and z_to")
    src_crs, dst_crs = parse_crs(from_crs, "--from"), parse_crs(to_crs, "--to")
    _check_units(table, cols, "_from", src_crs)
    _check_units(table, cols, "_to", dst_crs)
    names = ["x_from", "y_from", "x_to", "y_to"] + (["z_from", "z_to"] if has_z else [])
    v = _float_columns(table, cols, names)
    ids = _ids(table, cols["id"][0])
    rec = [f"line {ln} (id {pid})" for ln, pid in zip(table.line_numbers, ids)]
    check_coordinates(src_crs, v["x_from"], v["y_from"], f"{table.path} [from {crs_label(src_crs)}]", rec)
    check_coordinates(dst_crs, v["x_to"], v["y_to"], f"{table.path} [to {crs_label(dst_crs)}]", rec)
    src = [v["x_from"], v["y_from"]] + ([v["z_from"]] if has_z else [])
    dst = [v["x_to"], v["y_to"]] + ([v["z_to"]] if has_z else [])
    return CommonPoints(ids, np.column_stack(src), np.column_stack(dst), has_z)


def _is_normal_height_column(col: str) -> bool:
    """A common-point column of normal heights: H_from, H_to (any unit suffix; the rest of the name without case, as
    columns are matched: H_FROM too, review 44). The capital H is the convention's mark; h_from, h_to are
    ellipsoidal."""
    m = _UNIT_SUFFIX.match(col)
    base = m["base"] if m else col
    return base[:1] == "H" and base.lower() in ("h_from", "h_to")


# what to do with common points whose heights are normal heights (leftovers2: a bursa-wolf7 fit on z_to = 1985
# heights took up the height anomaly in its translation, rotations and scale, with centimetre residuals, and
# `crs transform --heights` then subtracted the anomaly a second time)
NORMAL_HEIGHTS_ADVICE = ("a spatial set (bursa-wolf7, translation3) fitted on normal heights takes up the height "
                         "anomaly (tens of metres, tilted) in its translation, rotations and scale, and --heights "
                         "would subtract it a second time. Give ellipsoidal heights on both sides with 2D "
                         "--from/--to, or fit the plane with --model helmert2d and the heights with crs fit-heights")


def _geocentric_of_heights(crs_obj, x, y, z, opt: str):
    """``geocentric_of`` for ``crs fit``: a CRS whose vertical part PROJ cannot take to ellipsoidal heights (the 1985
    heights of China, EPSG:5737: no geoid) is refused saying what its z are."""
    try:
        return geocentric_of(crs_obj, x, y, z)
    except CrsError:
        v = vertical_crs(crs_obj)
        if v is None:
            raise
        side = "z_to" if opt == "--to" else "z_from"
        raise InputError(f"{opt} {crs_label(crs_obj)}: {side} are heights of {v.name} (above a geoid, not "
                         f"ellipsoidal), and PROJ has no geoid model of them to make ellipsoidal heights: "
                         f"{NORMAL_HEIGHTS_ADVICE}") from None


def geocentric_of(crs_obj, x, y, z):
    """Geocentric XYZ (metres) and geodetic lat/lon of coordinates in ``crs_obj`` on its own datum
    (a conversion, never a datum shift)."""
    if crs_obj.is_geocentric:
        XYZ = np.column_stack([x, y, z])
        lat, lon, _ = geocentric_to_geodetic(x, y, z, Ellipsoid.from_crs(crs_obj))
        return XYZ, np.column_stack([lat, lon])
    lon, lat, h = to_own_geodetic(crs_obj, np.asarray(x, float), np.asarray(y, float), np.asarray(z, float))
    XYZ = np.column_stack(geodetic_to_geocentric(lat, lon, h, Ellipsoid.from_crs(crs_obj)))
    return XYZ, np.column_stack([lat, lon])


def fit_common_points(path, model: str, from_crs, to_crs):
    """Read a common-point file and fit ``model`` (library entry point of ``crs fit``)."""
    src_crs, dst_crs = parse_crs(from_crs, "--from"), parse_crs(to_crs, "--to")
    cp = read_common_points(path, src_crs, dst_crs, need_z=SPATIAL[model])
    src_label, dst_label = crs_label(src_crs), crs_label(dst_crs)
    if not SPATIAL[model]:
        for c, opt in ((src_crs, "--from"), (dst_crs, "--to")):
            h = horizontal_crs(c)
            # a site's engineering grid (ENGCRS: a plane in metres, no projection) is the classic 4-parameter case
            if not (h.is_projected or h.is_engineering) or abs(linear_unit_m(h) - 1.0) > 1e-12:
                what = ("a grid in another unit than the metre" if h.is_projected or h.is_engineering else
                        "geographic or geocentric coordinates: use bursa-wolf7 or translation3 for those")
                raise InputError(f"{opt} {crs_label(c)} ({c.name}): {model} works on metre grids (a projected or "
                                 f"engineering CRS in metres), this is {what}")
        try:
            res = fit_plane(model, cp.ids, cp.src[:, :2], cp.dst[:, :2], from_crs=src_label, to_crs=dst_label)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
        return _with_crs_wkt(res, src_crs, dst_crs)
    XYZ_s, _ = _geocentric_of_heights(src_crs, cp.src[:, 0], cp.src[:, 1], cp.src[:, 2], "--from")
    XYZ_d, ll_d = _geocentric_of_heights(dst_crs, cp.dst[:, 0], cp.dst[:, 1], cp.dst[:, 2], "--to")
    plane = cp.src[:, :2] if horizontal_crs(src_crs).is_projected and linear_unit_m(src_crs) == 1.0 else None
    try:
        res = fit_spatial(model, cp.ids, XYZ_s, XYZ_d, dst_lat_lon_deg=ll_d, from_crs=src_label, to_crs=dst_label,
                          src_plane_m=plane)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    return dataclasses.replace(_with_crs_wkt(res, src_crs, dst_crs), heights=_fit_heights_words(src_crs, dst_crs))


def _with_crs_wkt(res, src_crs, dst_crs):
    """The fit with its CRSs as WKT in the parameter set (what ``crs transform --params`` parses: review 44, the
    labels of a PROJ string, a +datum=EPSG:nnnn grid or a .prj file's CRS were "unknown CRS" there)."""
    t = dataclasses.replace(res.transformation, from_crs_wkt=src_crs.to_wkt(), to_crs_wkt=dst_crs.to_wkt())
    return dataclasses.replace(res, transformation=t)


def _fit_heights_words(src_crs, dst_crs) -> str:
    """What the z columns of a spatial fit were taken as (said by ``crs fit`` and kept in the parameter file)."""
    def side(c, col):
        v = vertical_crs(c)
        datum = horizontal_crs(c).geodetic_crs.datum.name
        if v is None:
            return f"{col} ellipsoidal heights h on {datum}"
        return f"{col} heights of {v.name}, taken to ellipsoidal heights on {datum} through PROJ's geoid model"
    return (f"{side(src_crs, 'z_from')}; {side(dst_crs, 'z_to')} (normal heights in a column of a 2D CRS would be "
            "taken up by the set: give them with a compound --from/--to)")


def read_height_points(path, crs=None):
    """(ids, x, y, h, H) from a header table id,x,y,h,H."""
    table = _read_table(path, require_header=True)
    wanted = {
        "id": ID_COLUMNS,
        "x": ("x", "X", "easting"),
        "y": ("y", "Y", "northing"),
        "h": ("h", "h_ellipsoidal", "h_ell"),
        "H": ("H", "H_normal", "H_norm"),
    }
    cols = {}
    for j, col in enumerate(table.header):
        base = _UNIT_SUFFIX.match(col)["base"] if _UNIT_SUFFIX.match(col) else col
        for name, spell in wanted.items():
            if base in spell or (name in ("id", "x", "y") and base.lower() in spell):
                cols[name] = (j, None)
    missing = [n for n in wanted if n not in cols]
    if missing:
        raise InputError(f"{table.path}: header {table.header} lacks column(s) {', '.join(missing)} "
                         "(expected id, x, y, h (ellipsoidal), H (normal height))")
    v = _float_columns(table, cols, ["x", "y", "h", "H"])
    ids = _ids(table, cols["id"][0])
    if crs is not None:
        c = parse_crs(crs, "--epsg")
        if not c.is_projected:
            raise InputError(f"--epsg {crs_label(c)}: height anomaly models need a projected (metre) CRS")
        if abs(linear_unit_m(c) - 1.0) > 1e-12:
            # the model file keeps its origin in metres and its slopes per km (origin_m, "m/km"): a foot grid's x, y
            # would put feet under those names (the heights it gives would be right, its file wrong)
            raise InputError(f"--epsg {crs_label(c)} ({c.name}): x, y in {unit_name(c)}; height anomaly models "
                             "need a metre grid (the model file holds its origin in metres, slopes in m/km): give "
                             "the points' x, y in one (e.g. the UTM zone; h and H stay in metres) with its EPSG code. "
                             "'crs transform --heights' evaluates the model in its grid whatever CRS it writes")
        rec = [f"line {ln} (id {pid})" for ln, pid in zip(table.line_numbers, ids)]
        check_coordinates(c, v["x"], v["y"], str(table.path), rec)
    return ids, v["x"], v["y"], v["h"], v["H"]


# ----------------------------------------------------------------------------------------------
# Point lists
# ----------------------------------------------------------------------------------------------


def _decimals(crs) -> int:
    return 9 if unit_name(crs) == "deg" else 4


_ANGLE = re.compile(r"^(?P<name>omega|phi|kappa)(?:_(?P<unit>[a-z]+))?$", re.IGNORECASE)


def _attitude_columns(table: _Table) -> dict | None:
    """{"omega": j, "phi": j, "kappa": j}: the columns of an orientation list (eo.txt and the like), named by the
    header or, header-less, by the comment line just above the records ("# image_id X_m Y_m Z_m omega_deg phi_deg
    kappa_deg", as eo.txt writes it); None when there are none. Angles in degrees only (``_deg`` or no suffix)."""
    names = table.header
    if names is None:
        first = table.line_numbers[0] - 1  # the raw lines above the first record, nearest first
        for ln in reversed(table.lines[:first]):
            if ln.lstrip().startswith("#"):
                names = ln.lstrip().lstrip("#").split()
                break
            if ln.strip():
                break
        # a comment names the columns only when it has a name for each field (not prose that says "phi")
        if names is not None and len(names) != len(table.rows[0]):
            return None
    if not names:
        return None
    found = {}
    for j, col in enumerate(names):
        m = _ANGLE.match(col.strip())
        if m:
            if m["unit"] and m["unit"].lower() != "deg":
                raise InputError(f"{table.path}: column {col}: attitudes are read in degrees (omega_deg, phi_deg, "
                                 "kappa_deg); convert the column")
            found[m["name"].lower()] = j
    if not found:
        return None
    if len(found) < 3:
        raise InputError(f"{table.path}: columns {', '.join(found)} found without all of omega, phi, kappa: an "
                         "orientation list needs the three")
    return found


def _attitudes_through(transformer: CrsTransformer, path, x, y, omega_deg, phi_deg, kappa_deg):
    """(omega, phi, kappa) in degrees of orientations (eo.txt: the rotation camera -> grid east, grid north, up at
    the projection centre, ``aerotri.geom.rotation``) in the output grid: the grid axes turn by the operation's
    rotation at each centre (the meridian convergence of another zone or central meridian, a plane set's
    rotation), taken from its Jacobian by 1 m steps (the rotation of its polar decomposition: exact for conformal
    grids). The vertical is kept (a datum's rotation of arc-seconds tilts it by as much). trial-datum: eo.txt of UTM
    49N into UTM 50N kept its kappa, 3.08 deg off at 110.5E."""
    from aerotri.geom.rotation import opk_from_matrix, rotation_matrix_opk

    for c, opt in ((transformer.src, "--from"), (transformer.dst, "--to")):
        if not horizontal_crs(c).is_projected:
            raise InputError(f"{path}: an orientation list (omega, phi, kappa) needs projected grids: {opt} "
                             f"{crs_label(c)} is not one (the angles refer to grid axes)")
    probe = CrsTransformer(transformer.src, transformer.dst, transformer.params, None, transformer.allow_ballpark)
    step = 1.0 / linear_unit_m(transformer.src)
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    ex = probe.transform(np.concatenate([x + step, x - step]), np.concatenate([y, y]))
    ny = probe.transform(np.concatenate([x, x]), np.concatenate([y + step, y - step]))
    n = len(x)
    j00, j10 = ex[0][:n] - ex[0][n:], ex[1][:n] - ex[1][n:]  # d(X, Y)/dx
    j01, j11 = ny[0][:n] - ny[0][n:], ny[1][:n] - ny[1][n:]  # d(X, Y)/dy
    theta = np.arctan2(j10 - j01, j00 + j11)  # counter-clockwise in (easting, northing)
    c, s_ = np.cos(theta), np.sin(theta)
    Rz = np.zeros((n, 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s_, s_, c, 1.0
    return opk_from_matrix(Rz @ rotation_matrix_opk(omega_deg, phi_deg, kappa_deg))


_GEOGRAPHIC_NAMES = ("lon", "lat")
_GRID_NAMES = ("x", "y", "easting", "northing", "e", "n")


def _renamed_header(header: list, ix: int, iy: int, dst) -> list:
    """``header`` with the x / y columns renamed when the output's kind differs from what their names say: lon,lat
    for a geographic output of grid columns, x,y for a grid output of lon,lat; other names kept."""
    out = list(header)
    geographic = horizontal_crs(dst).is_geographic
    names = (out[ix].lower(), out[iy].lower())
    if geographic and any(n in _GRID_NAMES for n in names):
        out[ix], out[iy] = "lon", "lat"
    elif not geographic and any(n in _GEOGRAPHIC_NAMES for n in names):
        out[ix], out[iy] = "x", "y"
    return out


def transform_point_list(in_path, out_path, transformer: CrsTransformer) -> int:
    """Transform a CSV/TXT point list (see module docstring); returns the number of points."""
    table = _read_table(in_path, require_header=False)
    if table.header is None:
        ix, iy, iz = 1, 2, 3
        if any(len(f) < 3 for f in table.rows):
            ln = table.line_numbers[next(i for i, f in enumerate(table.rows) if len(f) < 3)]
            raise InputError(f"{table.path}: line {ln}: expected 'id x y [z ...]'")
        if any(len(f) < 4 for f in table.rows):
            iz = None
    else:
        lower = [c.lower() for c in table.header]
        pick = {}
        for name, spell in {"x": ("x", "easting", "e", "lon"), "y": ("y", "northing", "n", "lat"),
                            "z": ("z", "h", "height", "elevation")}.items():
            pick[name] = next((lower.index(s) for s in spell if s in lower), None)
        if pick["x"] is None or pick["y"] is None:
            raise InputError(f"{table.path}: header {table.header} must name x and y columns")
        ix, iy, iz = pick["x"], pick["y"], pick["z"]
    cols = {"x": (ix, None), "y": (iy, None)}
    if iz is not None:
        cols["z"] = (iz, None)
    angles = _attitude_columns(table)
    cols.update({k: (j, None) for k, j in (angles or {}).items()})
    v = _float_columns(table, cols, list(cols))
    recs = [f"line {ln}" for ln in table.line_numbers]
    check_coordinates(transformer.src, v["x"], v["y"], str(table.path), recs)
    if angles:
        opk = _attitudes_through(transformer, table.path, v["x"], v["y"], v["omega"], v["phi"], v["kappa"])
    X, Y, Z = transformer.transform(v["x"], v["y"], v.get("z"))
    # as for LAS/LAZ (below): a point list written outside the target's area of use is said (trial-datum: eo.txt of
    # UTM 49N into UTM 50N, easting -122,381 m; points at 110.5E into the 3-degree CM 114E grid: without a word)
    try:
        far = check_coordinates(transformer.dst, X, Y, f"{table.path} transformed", recs, outside_area="warn")
    except InputError as exc:
        far = str(exc)
    if far:
        transformer.notes.append(f"{far}; written all the same: is --to {crs_label(transformer.dst)} the grid meant "
                                 "(zone, 3- or 6-degree, central meridian)?")
    dec = _decimals(transformer.dst)
    out_rows = []
    for r, fields in enumerate(table.rows):
        f = list(fields)
        f[ix] = f"{X[r]:.{dec}f}"
        f[iy] = f"{Y[r]:.{dec}f}"
        if iz is not None:
            f[iz] = f"{Z[r]:.4f}"
        if angles:
            for k, name in enumerate(("omega", "phi", "kappa")):
                f[angles[name]] = f"{opk[k][r]:.7f}"
        out_rows.append(f)
    # Rebuild the text with comments where they were.
    body_by_line = dict(zip(table.line_numbers, out_rows))
    if table.header is not None:
        # the coordinate columns named for what they hold now (trial-cn: GK eastings written under lon,lat)
        header_line = next(i for i, ln in enumerate(table.lines, start=1)
                           if ln.strip() and not ln.lstrip().startswith("#"))
        body_by_line[header_line] = _renamed_header(table.header, ix, iy, transformer.dst)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n") if table.delimiter == "," else None
    for i, ln in enumerate(table.lines, start=1):
        if i in body_by_line:
            if writer:
                writer.writerow(body_by_line[i])
            else:
                buf.write(" ".join(body_by_line[i]) + "\n")
        else:
            buf.write(ln + "\n")
    write_text_atomic(out_path, buf.getvalue())
    return len(out_rows)


# ----------------------------------------------------------------------------------------------
# LAS / LAZ
# ----------------------------------------------------------------------------------------------


def las_crs(path):
    """The CRS recorded in a LAS/LAZ header (WKT or GeoTIFF keys), or None (also when unreadable)."""
    with las.open_las(path) as reader:
        return las.header_crs(reader.header)


def _nice_scale(scale: float) -> float:
    """The largest power of ten not above ``scale`` (0.003048 -> 0.001)."""
    return 10.0 ** math.floor(math.log10(scale) + 1e-9)


def transform_las(in_path, out_path, transformer: CrsTransformer, chunk_size: int = 1_000_000) -> int:
    """Transform a LAS/LAZ file chunk by chunk; every point dimension other than x, y, z is copied
    bit for bit (classes, returns, GPS time, intensity, RGB, extra bytes). The header gets new
    scales/offsets for the target units and the target CRS record (WKT for point formats >= 6,
    GeoTIFF keys otherwise). Returns the number of points."""
    import laspy
    in_path, out_path = Path(in_path), Path(out_path)
    if chunk_size < 1:
        raise OptionError(f"{chunk_size}: expected at least 1 point per chunk", param="--chunk-points")
    with las.open_las(in_path) as reader:
        hdr = reader.header
        las.refuse_copc(in_path, hdr, "crs transform")
        if not (np.asarray(hdr.scales) > 0).all():
            # (new scales are derived from them below)
            raise InputError(f"{in_path}: header scale factors {list(hdr.scales)} must be positive numbers")
        file_crs = las.header_crs(hdr)
        src = transformer.src
        # a compound --from over the file's 2D CRS adds the heights' system to it
        src_as_file = horizontal_crs(src) if src.is_compound and file_crs is not None and not file_crs.is_compound \
            else src
        if file_crs is not None and not same_crs(file_crs, src_as_file):
            units = [c.axis_info[0].unit_name if c.axis_info else "" for c in (file_crs, src)]
            raise InputError(
                f"{in_path}: the file's CRS ({file_crs.name}) is not --from {crs_label(src)}"
                + (f" (the file's coordinates are in {units[0]}, --from's in {units[1]}; leave --from out to use "
                   "the file's CRS)" if units[0] != units[1] else "")
            )
        # the heights' unit: a compound CRS record's vertical axis, else the GeoTIFF vertical units key read as
        # lidarctl's readers read it (4099; a user-defined one sized by 2053; one whose size cannot be known is
        # refused naming the file), else the unit the transformer reads z in for --from (a 2D grid's unit)
        keys_z_m = None
        if file_crs is None or not file_crs.is_compound:
            try:
                keys_z_m = las.read_vertical_unit_m(
                    in_path, hdr, hint="give --from a compound CRS (EPSG:<horizontal>+<vertical>) stating it")
            except CrsError:
                if not src.is_compound:  # a compound --from states the heights' unit in the key's place
                    raise
        if keys_z_m is not None and src.is_compound and abs(keys_z_m - height_unit_m(src)) > 1e-9 * keys_z_m:
            raise InputError(
                f"{in_path}: the file's VerticalUnitsGeoKey (4099) gives heights in "
                f"{length_unit_name(keys_z_m, long=True)}, --from {crs_label(src)} in "
                f"{length_unit_name(height_unit_m(src), long=True)}")
        z_in_m = keys_z_m if keys_z_m is not None else height_unit_m(src)
        z_factor = z_in_m / height_unit_m(src)  # the file's heights -> the unit the transformer reads z in
        out_hdr = laspy.LasHeader(version=hdr.version, point_format=hdr.point_format)
        for vlr in hdr.vlrs:
            # laspy writes the extra-bytes and LASzip records itself from the point format
            if type(vlr).__name__ == "ExtraBytesVlr" or getattr(vlr, "user_id", "") == "laszip encoded":
                continue
            out_hdr.vlrs.append(vlr)
        out_hdr.global_encoding = copy.copy(hdr.global_encoding)
        out_hdr.global_encoding.wkt = False  # add_crs sets it again when it writes a WKT record
        out_hdr.system_identifier = hdr.system_identifier
        out_hdr.generating_software = "aerotri crs transform"
        out_hdr.file_source_id = hdr.file_source_id
        out_hdr.creation_date = hdr.creation_date
        # Scales for the target units; offsets from the transformed bounding box corners.
        dst = transformer.dst
        # (the horizontal axes' unit: z_unit_m is 1 for any compound CRS, which made a compound --from in feet give
        # XY scales 3.3x coarser)
        f_in, f_out = (111_320.0 if horizontal_crs(c).is_geographic else linear_unit_m(c)
                       for c in (transformer.src, dst))
        sx = _nice_scale(hdr.scales[0] * f_in / f_out)
        sz = _nice_scale(hdr.scales[2] * z_in_m / height_unit_m(dst))
        cx, cy = las.header_corners(hdr)
        cz = np.full(4, 0.5 * (hdr.mins[2] + hdr.maxs[2]) * z_factor)
        if hdr.point_count == 0:
            raise InputError(f"{in_path}: the file holds no points (nothing to transform)")
        # outside the area of use: said, not refused (national grids past their zone's area, review 31)
        far = check_coordinates(transformer.src, cx, cy, str(in_path),
                                [f"header bounds corner {i + 1}" for i in range(4)], outside_area="warn")
        if far:
            transformer.notes.append(f"{far}; transformed all the same (a CRS used past its area of use)")
        X, Y, Z = transformer.transform(cx, cy, cz)
        transformer.n_points -= 4  # corners are not points of the file
        transformer.n_outside_fit_extent = 0
        transformer.n_beyond_heights_hull, transformer.beyond_heights_hull_m = 0, 0.0
        try:
            # s27: RD New coordinates tagged UTM 31N (plausible there, at 4 deg N) came out at x = -660,124 in RD New,
            # exit 0, without a word. A warning, not a refusal: a transform into a neighbouring zone far off is legal
            check_coordinates(dst, X, Y, str(in_path), [f"header bounds corner {i + 1} transformed" for i in range(4)])
        except InputError as exc:
            transformer.notes.append(
                f"{exc}; is the file's CRS ({crs_label(src)}) right? A file whose CRS record is wrong is re-tagged, no "
                f"point moved, with aerotri crs assign {in_path} OUT --crs <its CRS>")
        unit = 1.0 if dst.is_geographic else 1000.0
        out_hdr.offsets = np.array([math.floor(X.min() / unit) * unit, math.floor(Y.min() / unit) * unit,
                                    math.floor(Z.min() / 100.0) * 100.0 if np.isfinite(Z).all() else 0.0])
        out_hdr.scales = np.array([sx, sx, sz])
        # laspy's add_crs drops the copied CRS records (the input's vertical keys with them); a compound --to on
        # GeoTIFF keys gets its vertical CRS and unit keys (las.add_crs), a 2D one none: heights in its grid unit
        las.add_crs(out_hdr, dst)
        from aerotri.core.limits import check_task_count

        check_task_count(math.ceil(hdr.point_count / chunk_size), f"{in_path}: {hdr.point_count:,} points in chunks of "
                         f"{chunk_size:,}", "--chunk-points", "use a larger --chunk-points")
        n = 0
        with atomic_path(out_path) as tmp:
            with laspy.open(tmp, mode="w", header=out_hdr, do_compress=out_path.suffix.lower() == ".laz") as writer:
                for _, chunk in track_chunks(las.iter_chunks(reader, in_path, chunk_size, withheld=True), hdr.point_count,
                                             f"transform {in_path.name}"):
                    z = np.asarray(chunk.z) * z_factor if z_factor != 1.0 else np.asarray(chunk.z)
                    X, Y, Z = transformer.transform(np.asarray(chunk.x), np.asarray(chunk.y), z)
                    out = laspy.ScaleAwarePointRecord.zeros(len(chunk), header=out_hdr)
                    out.array[:] = chunk.array  # every dimension bit for bit, then new X, Y, Z
                    _set_scaled(out, "X", X, out_hdr.offsets[0], out_hdr.scales[0], in_path)
                    _set_scaled(out, "Y", Y, out_hdr.offsets[1], out_hdr.scales[1], in_path)
                    _set_scaled(out, "Z", Z, out_hdr.offsets[2], out_hdr.scales[2], in_path)
                    writer.write_points(out)
                    n += len(chunk)
    return n


_CRS_RECORDS = ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr", "GeoAsciiParamsVlr", "GeoDoubleParamsVlr")


@dataclasses.dataclass(frozen=True)
class AssignResult:
    """``assign_las``: points copied, the CRS record replaced (``old``: its label, None when the file had none)."""

    n_points: int
    old: str | None
    new: str
    warnings: tuple[str, ...] = ()  # the header bounds outside the CRS's area of use (not refused)


def assign_las(in_path, out_path, crs, chunk_size: int = 1_000_000) -> AssignResult:
    """``aerotri crs assign``: a copy of a LAS/LAZ file tagged with ``crs``, no point moved (PDAL's override_srs,
    ``gdal_edit -a_srs``): for a file whose CRS record is wrong or missing. The point records, the header's scales,
    offsets and bounds and every VLR and EVLR but the CRS records (WKT, GeoTIFF keys) are copied as they are; the
    CRS record is ``crs``'s (WKT for point formats >= 6, else GeoTIFF keys, which hold EPSG CRSs only). Refused
    (InputError) when the header bounds cannot be coordinates of ``crs`` (``check_coordinates``, ``outside_area=
    "warn"``: degrees out of range, a Gauss-Krueger zone not theirs, beyond the projection's domain); bounds outside
    its area of use (widened by 1 deg) are a warning (``warnings``): a national grid used past its zone's area is
    common, another zone, degrees or feet are said. A COPC file is refused (``las.refuse_copc``). Atomic."""
    import laspy
    from laspy.vlrs.vlrlist import VLRList

    from aerotri.core.atomic import refuse_input_as_output

    in_path, out_path = Path(in_path), Path(out_path)
    for p, name in ((in_path, "IN"), (out_path, "OUT")):
        if p.suffix.lower() not in LAS_SUFFIXES:
            raise InputError(f"{p}: {name} of 'crs assign' must be a .las or .laz file")
    refuse_input_as_output(out_path, [in_path], "OUT")
    if chunk_size < 1:
        raise OptionError(f"{chunk_size}: expected at least 1 point per chunk", param="--chunk-points")
    new = parse_crs(crs, "--crs")
    label = crs_label(new)
    with las.open_las(in_path) as reader:
        hdr = reader.header
        las.refuse_copc(in_path, hdr, "crs assign")
        if hdr.point_count == 0:
            raise InputError(f"{in_path}: the file holds no points (no coordinates to check against {label})")
        old = las.header_crs(hdr)
        cx, cy = las.header_corners(hdr)
        try:
            # outside the area of use: a warning (Oslo in UTM 33, Berlin in UTM 32: grids used past their zone's area,
            # review 31); only coordinates the CRS cannot hold are refused
            far = check_coordinates(new, cx, cy, str(in_path), [f"header bounds corner {i + 1}" for i in range(4)],
                                    outside_area="warn")
        except InputError as exc:
            raise InputError(f"{exc}; not re-tagged: the coordinates cannot be {label}'s (give the CRS they are in)") \
                from None
        out_hdr = copy.deepcopy(hdr)
        out_hdr.vlrs = VLRList([v for v in hdr.vlrs if type(v).__name__ not in _CRS_RECORDS])
        evlrs = [v for v in (hdr.evlrs or []) if type(v).__name__ not in _CRS_RECORDS]
        out_hdr.evlrs = VLRList(evlrs) if hdr.evlrs is not None else None
        out_hdr.global_encoding.wkt = False  # add_crs sets it again when it writes a WKT record
        try:
            las.add_crs(out_hdr, new)
        except RuntimeError as exc:  # laspy: GeoTIFF keys hold EPSG projected CRSs only
            raise InputError(f"{in_path}: LAS {hdr.version} point format {hdr.point_format.id} carries its CRS as "
                             f"GeoTIFF keys, which cannot hold {label} ({las.one_line(exc)}); give an EPSG code") \
                from None
        n = 0
        with atomic_path(out_path) as tmp:
            with laspy.open(tmp, mode="w", header=out_hdr, do_compress=out_path.suffix.lower() == ".laz") as writer:
                for _, chunk in track_chunks(las.iter_chunks(reader, in_path, chunk_size, withheld=True),
                                             hdr.point_count, f"assign {in_path.name}"):
                    writer.write_points(chunk)  # the records as they are
                    n += len(chunk)
                if evlrs:
                    writer.write_evlrs(VLRList(evlrs))
    warnings = () if not far else (f"{far}; re-tagged all the same (a CRS used past its area of use); check that "
                                    f"{label} is the CRS the coordinates are in",)
    return AssignResult(n, None if old is None else crs_label(old), label, warnings)


def _set_scaled(record, dim: str, values, offset, scale, path):
    q = np.round((values - offset) / scale)
    if q.min(initial=0) < -(2**31) or q.max(initial=0) > 2**31 - 1:
        raise InputError(f"{path}: transformed {dim.lower()} does not fit the LAS integer range at scale {scale}")
    record[dim] = q.astype(np.int32)


def transform_file(in_path, out_path, transformer: CrsTransformer, chunk_size: int = 1_000_000) -> int:
    """Dispatch on the suffix: LAS/LAZ chunked, anything else a point list."""
    if Path(in_path).suffix.lower() in LAS_SUFFIXES:
        if Path(out_path).suffix.lower() not in LAS_SUFFIXES:
            raise InputError(f"{out_path}: a LAS/LAZ input needs a .las or .laz output")
        return transform_las(in_path, out_path, transformer, chunk_size)
    return transform_point_list(in_path, out_path, transformer)


def transform_points_file(in_path, out_path, *, from_crs=None, to_crs=None, params=None, heights=None,
                          allow_ballpark: bool = False, chunk_size: int = 1_000_000,
                          normal_to_ellipsoidal: bool = False) -> tuple[int, CrsTransformer]:
    """``aerotri crs transform``: a CSV/TXT point list or a LAS/LAZ file from ``from_crs`` (a LAS file's own CRS
    record when None) to ``to_crs``, with an optional fitted transformation (``params`` JSON) and height anomaly
    model (``heights`` JSON): ellipsoidal heights h in, normal heights H = h - zeta out, or with
    ``normal_to_ellipsoidal`` normal heights in, h = H + zeta out (on the datum the model records, ``h_crs``,
    carried on to the output's). Returns (points written, the transformer: its description and warnings)."""
    from aerotri.core.atomic import refuse_input_as_output
    from aerotri.geom.crs.definition import parse_crs

    if normal_to_ellipsoidal and not heights:
        raise OptionError("needs the height anomaly model of the normal heights: give --heights (a model file from "
                          "'aerotri crs fit-heights')", param="--normal-to-ellipsoidal")
    refuse_input_as_output(out_path, [in_path, params, heights], "OUT")
    if not Path(in_path).exists():
        raise InputError(f"{in_path}: file not found")
    if from_crs is None:
        if Path(in_path).suffix.lower() not in LAS_SUFFIXES:
            raise InputError("--from is required for point lists")
        src = las_crs(in_path)
        if src is None:
            with las.open_las(in_path) as reader:  # a record present but unreadable: why, not "no CRS record"
                las.read_header_crs(in_path, reader.header, hint="give --from")
            raise InputError(f"{in_path}: no CRS record in the file; give --from")
    else:
        src = parse_crs(from_crs, "--from")
    model = load_height_model(heights) if heights else None
    if normal_to_ellipsoidal and not model.crs:
        # a model without its grid is evaluated where the normal heights are: here the input (the inverse of a
        # transformation that wrote them into this CRS, as CrsTransformer.inverse takes it)
        model = dataclasses.replace(model, crs=src.to_wkt())
    t = CrsTransformer(src, to_crs, params=load_transformation(params) if params else None, heights=model,
                       allow_ballpark=allow_ballpark, heights_inverse=normal_to_ellipsoidal)
    return transform_file(in_path, out_path, t, chunk_size), t
