"""OpenDroneMap's ``gcp_list.txt`` (import and export) and OpenSfM's ``ground_control_points.json`` (export).

``gcp_list.txt`` (ODM's documentation; read by OpenSfM's ``io.read_gcp_list``): the first line that is
not empty or a ``#`` comment names the CRS: a PROJ string (``+proj=utm ...``), ``EPSG:nnnn``,
``WGS84 UTM <zone>[N|S]`` or ``WGS84`` (then x = longitude, y = latitude in degrees, z = ellipsoidal
height). Then one line per image measurement, separated by blanks or tabs::

    geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extras...]

Pixel coordinates: OpenSfM, which consumes the file for ODM, normalises them with
``(x + 0.5 - width / 2) / max(width, height)``: pixel centres at integers, the origin at the centre of the
top-left pixel, as ours; they are taken and written unchanged. A point without ``gcp_name`` is named by
its coordinates (OpenSfM groups measurements by (x, y, z)): the named point at the same coordinates, else
``gcp1``, ``gcp2``, ... in order of first appearance (past the names the file uses). ``geo_z`` NaN (OpenSfM: no
altitude) makes the point a horizontal control point. The file carries no accuracies: ``--sigma-xyz-m`` gives them
(required).

Control as measured: a file whose heights are all 0 (or all the same number) has heights nobody measured (ODM
writes 0 where a survey gave none: the Coal Oil Point targets); its points are imported as horizontal control,
with a warning, unless ``ImportSettings.heights_measured`` (``--heights-measured``) says the heights are real.
Two different points measured within 2 px of each other in one frame are refused, naming both and their lines
(``aerotri.geom.observations.check_distinct_points``): one of them is mislabelled.

Heights: a header with a vertical CRS (``EPSG:32611+5703``: orthometric heights) is converted to the project's
heights through PROJ's geoid grid (refused, naming the grid, when it is not installed); a 2D header (``EPSG:32611``)
says nothing of them and its z is taken in the project's heights (said in imports.json), unless ``--crs`` gives the
header's CRS with a vertical one (``--crs EPSG:32611+5703``: the user declares the heights orthometric): then
converted as that header.

Export (``aerotri export --format odm``): ``aerotri.exchange.odm_export`` (this layout, in the project CRS:
its EPSG code, else its PROJ string).
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError, OptionError
from aerotri.core.project import Project
from aerotri.core.textio import read_text
from aerotri.core.point_ids import point_id_key
from aerotri.exchange.import_checks import unmeasured_heights
from aerotri.exchange.imported import ImportedBlock, ImportSettings, control_sigma_m, to_project_crs
from aerotri.geom.observations import ControlPoints, ImageObservations, check_distinct_points

_log = logging.getLogger(__name__)

_UTM = re.compile(r"^WGS84\s+UTM\s+(\d{1,2})\s*([NS]?)$", re.IGNORECASE)


def crs_of_header(line: str, source: str) -> str:
    """The CRS text (for ``parse_crs``) of a gcp_list.txt header line."""
    text = line.strip()
    m = _UTM.match(text)
    if m:
        zone, hemi = int(m.group(1)), (m.group(2) or "N").upper()
        if not 1 <= zone <= 60:
            raise InputError(f"{source}: UTM zone {zone} in {text!r} is not 1..60")
        return f"EPSG:{(32600 if hemi == 'N' else 32700) + zone}"
    if text.upper() == "WGS84":
        return "EPSG:4979"
    if text.startswith("+proj") or text.upper().startswith("EPSG:"):
        return text
    raise InputError(f"{source}: first line {text!r} is not a CRS; expected a PROJ string (+proj=...), EPSG:nnnn, "
                     f"'WGS84 UTM <zone>[N|S]' or 'WGS84'")


def _is_point_line(text: str) -> bool:
    """A gcp_list.txt point line (three coordinates, two pixel coordinates, an image name), not a header."""
    parts = text.split()
    try:
        [float(v) for v in parts[:5]]
    except ValueError:
        return False
    return len(parts) >= 6


def read_gcp_list(path, crs_given: str | None = None
                  ) -> tuple[str, list[tuple[str, np.ndarray]], list[tuple[str, str, float, float, int]], bool]:
    """(CRS text, [(point id, xyz)], [(point id, image id, x_px, y_px, line)], whether the file has its CRS line) of
    a gcp_list.txt; ``crs_given`` (--crs): the CRS of a file without its header line (s95: refused as "not a CRS"
    with --crs given)."""
    path = Path(path)
    lines = read_text(path, "ODM gcp_list.txt").splitlines()
    body = [(n, ln.strip()) for n, ln in enumerate(lines, start=1) if ln.strip() and not ln.strip().startswith("#")]
    if not body:
        raise InputError(f"{path}: empty; expected a CRS line and 'geo_x geo_y geo_z im_x im_y image_name [gcp_name]' lines")
    headed = not _is_point_line(body[0][1])
    if not headed:
        if crs_given is None:
            raise InputError(f"{path}:{body[0][0]}: a point line where the CRS line belongs (a PROJ string, "
                             "EPSG:nnnn, 'WGS84 UTM <zone>[N|S]' or 'WGS84'): add it, or give the CRS with --crs")
        body = [(0, crs_given)] + body
    crs = crs_of_header(body[0][1], f"{path}:{body[0][0]}")
    points: dict[str, np.ndarray] = {}
    first_line: dict[str, int] = {}
    by_xyz: dict[tuple, str] = {}
    spelled: dict[str, str] = {}  # point_id_key -> the id as first written
    obs = []
    # the named points by their coordinates: a line without a name at one's coordinates is that point, as OpenSfM
    # groups lines by coordinates (kite trial: such a line became an 11th point "gcp1" on gcp09's coordinates)
    named = {}
    for _, s in body[1:]:
        parts = s.split()
        if len(parts) > 6:
            try:
                x, y, z = (float(v) for v in parts[:3])
            except ValueError:
                continue  # refused below, with its line
            named.setdefault((x, y, z if math.isfinite(z) else None), parts[6])
    taken = {point_id_key(n) for n in named.values()}
    for lineno, s in body[1:]:
        parts = s.split()
        if len(parts) < 6:
            raise InputError(f"{path}:{lineno}: {len(parts)} fields; expected geo_x geo_y geo_z im_x im_y image_name "
                             f"[gcp_name]: {s!r}")
        try:
            x, y, z, px, py = (float(v) for v in parts[:5])
        except ValueError:
            raise InputError(f"{path}:{lineno}: non-numeric coordinate in {s!r} (expected geo_x geo_y geo_z im_x im_y)") from None
        if not all(math.isfinite(v) for v in (x, y, px, py)) or math.isinf(z):
            raise InputError(f"{path}:{lineno}: NaN or infinite coordinate in {s!r} (only geo_z may be NaN: no height)")
        xyz = np.array([x, y, z])
        key = (x, y, z if math.isfinite(z) else None)
        if len(parts) > 6:
            pid = parts[6]
        elif key in named:
            pid = named[key]
            _log.warning(f"{path}:{lineno}: no gcp_name: taken as point {pid!r}, whose coordinates it has (as OpenSfM "
                         "groups the lines)")
        else:
            if key not in by_xyz:  # gcp1, gcp2, ... in order of first appearance, past the names the file uses
                k = len(by_xyz) + 1
                while point_id_key(f"gcp{k}") in taken:
                    k += 1
                by_xyz[key] = f"gcp{k}"
                taken.add(point_id_key(by_xyz[key]))
            pid = by_xyz[key]
        # one point however its name is spelled ("gcp01" and "GCP01 ": ids match as the report matches them,
        # point_id_key); two spellings were two control points of one ray each (trial-messy F16)
        written = pid
        pid = spelled.setdefault(point_id_key(pid), pid)
        as_written = "" if written == pid else f" (written {written!r}: the same id without case or leading zeros)"
        if pid in points and not np.array_equal(points[pid], xyz, equal_nan=True):
            raise InputError(f"{path}:{lineno}: point {pid!r}{as_written} has the coordinates {x} {y} {z} here but "
                             f"{' '.join(repr(float(v)) for v in points[pid])} on line {first_line[pid]}")
        points.setdefault(pid, xyz)
        first_line.setdefault(pid, lineno)
        obs.append((pid, Path(parts[5]).stem, px, py, lineno))
    if not obs:
        raise InputError(f"{path}: no measurement lines after the CRS line")
    seen = {}
    for pid, iid, _, _, lineno in obs:
        if (pid, iid) in seen:
            raise InputError(f"{path}:{lineno}: point {pid!r} measured twice in image {iid!r} (first on line "
                             f"{seen[(pid, iid)]})")
        seen[(pid, iid)] = lineno
    check_distinct_points(ImageObservations(np.array([o[0] for o in obs], dtype=object), np.array([o[1] for o in obs], dtype=object),
                                            np.array([[o[2], o[3]] for o in obs], float), np.array([o[4] for o in obs], int)), path)
    return crs, list(points.items()), obs, headed


def _declared_heights(path, file_crs: str, declared: str) -> str:
    """The CRS of a gcp_list.txt whose 2D header (``file_crs``) the user gave heights with ``--crs`` (``declared``:
    that CRS with a vertical one, EPSG:32611+5703: the heights orthometric, converted to the project's through PROJ's
    geoid grid); OptionError for any other ``--crs`` (the file names its CRS)."""
    from aerotri.geom.crs.definition import crs_label, parse_crs, same_horizontal, vertical_crs

    src, given = parse_crs(file_crs, f"{path}: line 1"), parse_crs(declared, "--crs")
    # the header "WGS84" reads as EPSG:4979 (its heights ellipsoidal); orthometric ones are EPSG:4326 with a vertical
    # CRS (review 37: refused, and the hint named EPSG:4979+3855, which PROJ rejects)
    plain = parse_crs("EPSG:4326", "WGS84") if src.to_epsg() == 4979 else src
    if (vertical_crs(src) is None or plain is not src) and vertical_crs(given) is not None and \
            same_horizontal(plain, given):
        return declared
    label = crs_label(plain)
    example = f" ({label}+5703 for NAVD88 heights, {label}+3855 for EGM2008)" if label.startswith("EPSG:") else ""
    raise OptionError(f"{path}: the file names its CRS ({file_crs}); --crs is for files that carry none, or gives "
                      f"the heights of a 2D header: its CRS with a vertical one{example}, not {declared}",
                      param="--crs")


def _is_2d(crs_text: str) -> bool:
    from aerotri.geom.crs.definition import parse_crs, vertical_crs

    c = parse_crs(crs_text, "gcp_list.txt")
    return vertical_crs(c) is None and len(c.axis_info) == 2


def read(files, project: Project, options: ImportSettings) -> ImportedBlock:
    """The ``odm`` importer: control points and their image measurements of a gcp_list.txt."""
    if len(files) != 1:
        raise InputError(f"odm expects one gcp_list.txt, got {len(files)} files")
    path = Path(files[0])
    sigma_m = control_sigma_m(project, options, path)  # gcp_list.txt carries no accuracies
    crs, points, obs, headed = read_gcp_list(path, options.crs)
    if options.crs is not None and headed:
        crs = _declared_heights(path, crs, options.crs)
    ids = np.array([p for p, _ in points], dtype=object)
    xyz = np.array([v for _, v in points])
    no_z = ~np.isfinite(xyz[:, 2])
    block = ImportedBlock(source=[str(path)])
    why = unmeasured_heights(xyz[:, 2])
    if why and not options.heights_measured:
        # heights nobody measured are no control: the points give their plan position only
        no_z[:] = True
        xyz[:, 2] = np.nan
        block.notes.append(f"{path}: {why}: taken as not measured; the {len(ids)} points are horizontal control "
                           "(plan only). If the heights were surveyed, import again with --heights-measured")
    if options.crs is None and not no_z.all() and _is_2d(crs):
        block.notes.append(f"{path}: the header {crs} gives no height system: the heights are taken as the "
                           "project's; if they are orthometric (above a geoid), import with --crs giving the header's "
                           "CRS with the vertical one (e.g. --crs EPSG:32611+5703) to convert them")
    xyz_fill = xyz.copy()
    xyz_fill[no_z, 2] = 0.0
    # checked in the file's CRS first, naming the line: a geographic header with latitude first failed in the
    # transformation as "point 1 could not be transformed rigorously", no file, no line (trial-messy F4)
    from aerotri.geom.crs.definition import check_coordinates, parse_crs

    first_line = {}
    for pid, _, _, _, lineno in obs:
        first_line.setdefault(pid, lineno)
    check_coordinates(parse_crs(crs, str(path)), xyz_fill[:, 0], xyz_fill[:, 1], str(path),
                      records=[f"line {first_line[pid]} (point {pid})" for pid in ids])
    xyz_map = to_project_crs(xyz_fill, crs, project, f"{path} (CRS {crs})")
    xyz_map[no_z, 2] = 0.0
    kinds = np.where(no_z, "horizontal", "full").astype(object)
    block.control = ControlPoints(ids, kinds, xyz_map, np.tile(sigma_m, (len(ids), 1)))
    block.image_points = ImageObservations(np.array([o[0] for o in obs], dtype=object),
                                           np.array([o[1] for o in obs], dtype=object),
                                           np.array([[o[2], o[3]] for o in obs], float),
                                           np.array([o[4] for o in obs], int))   # lines: for the checks' messages
    block.notes.append(f"control: {len(ids)} points ({int(no_z.sum())} without height: horizontal), "
                       f"{len(obs)} measurements; pixel coordinates taken as OpenSfM reads them (centre of the "
                       f"top-left pixel at 0, 0)")
    return block
