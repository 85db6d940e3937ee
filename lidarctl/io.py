"""lidarctl's reading and writing of LAS/LAZ clouds (laspy): point clouds in metres, classified copies.

Files are opened and read through ``aerotri.geom.las`` (the format-level checks every stage shares),
so that broken files give the same one-line errors in every command.

A cloud is read as a ``PointCloud`` holding only the fields the filters need (x, y, z, intensity,
return_number, number_of_returns, classification; optionally point_source_id); the full point
records are streamed again chunk by chunk when the classified file is written, so no more than
one chunk of full records is in memory at a time.

Units: x, y, z of a ``PointCloud`` are metres. The file's CRS gives its linear units
(``lidarctl.units``: metre, international foot, US survey foot; heights in the vertical unit of a
compound CRS, else in the horizontal unit); coordinates are scaled to metres once, when they are
read, and ``PointCloud.units`` tells the writers how to scale back. Geographic CRSs are refused.

Checks before any point is used (``aerotri.geom.las.open_las``): the LAS signature, a readable
header, finite non-zero scale factors and finite offsets, and the header's point count against the
point records the file holds; here, in addition, every chunk's coordinates (``validate_xyz``: NaN
or absurd values name the record).
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from pathlib import Path

import laspy
import numpy as np
import pyproj

from aerotri.core.atomic import atomic_path, refuse_input_as_output
from aerotri.core.errors import CrsError, InputError
from aerotri.geom import las
from aerotri.geom.crs.definition import horizontal_crs, parse_crs
from aerotri.core.limits import check_allocation
from lidarctl.units import METRE, UNKNOWN, LengthUnits, units_of

log = logging.getLogger(__name__)


CHUNK_POINTS = 2_000_000
# Projected coordinates beyond these bounds (in metres, after unit scaling) are not an airborne
# survey on Earth.
MAX_ABS_XY_M = 1.0e8
MIN_Z_M, MAX_Z_M = -1000.0, 10000.0


@dataclasses.dataclass
class PointCloud:
    """Point attributes as flat arrays (one entry per point, file order); x, y, z in metres.

    ``crs``: the horizontal CRS of the file (None when unknown); ``units``: the file's linear units,
    by which x, y, z were scaled to metres (``units.xy_from_m`` / ``z_from_m`` scale back).
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    intensity: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    classification: np.ndarray
    crs: pyproj.CRS | None = None
    units: LengthUnits = METRE
    point_source_id: np.ndarray | None = None
    # the file's records the points are (a mask over them), None when every record was used: records
    # flagged withheld are left out (``aerotri.geom.las.usable``)
    used: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.x)

    @property
    def xyz(self) -> np.ndarray:
        return np.column_stack([self.x, self.y, self.z])


GROUND, WATER, ROAD_SURFACE = 2, 9, 11


def ground_classes(header: laspy.LasHeader) -> tuple[int, ...]:
    """The classes of a file that stand on the ground: ground and water, and road surface (11) where the file's LAS
    version defines it (1.4 R13 on; before, 11 is reserved: lidR's MixedConifer, LAS 1.2, holds five class-11
    returns 14-23 m up in the canopy, which a DEM took for ground at 22.6 m)."""
    v = header.version
    return (GROUND, WATER, ROAD_SURFACE) if (v.major, v.minor) >= (1, 4) else (GROUND, WATER)


def resolve_crs_units(path, header: laspy.LasHeader, crs_arg: str | int | None,
                      require_crs: bool = True, crs_name: str = "--crs") -> tuple[pyproj.CRS | None, LengthUnits]:
    """(horizontal CRS, linear units) of a file: its CRS records, else ``crs_arg`` (``--crs``:
    ``EPSG:xxxx``, a code, WKT or PROJ text); never guessed.

    A file without any CRS is an InputError with ``require_crs``, else (None, UNKNOWN). A CRS record
    present but unreadable (e.g. user-defined linear units without their size) is a CrsError naming it,
    unless ``crs_arg`` is given: then ``crs_arg`` replaces it (a warning says so). A geographic CRS is a
    CrsError (lidarctl needs lengths). The vertical unit comes from a compound CRS, else from the GeoTIFF
    vertical keys (a user-defined one without its size, GeogLinearUnitSizeGeoKey, is unreadable as above),
    else it is the horizontal unit. A readable CRS record whose horizontal CRS is not ``crs_arg``'s is a CrsError
    (``crs_arg`` never reprojects; ``crs_name`` names it in the message: the option, or the project's CRS).
    """
    hint = "pass --crs EPSG:<code> to use that CRS instead"
    try:
        file_crs = las.read_header_crs(path, header, hint=hint)
        # a vertical units key whose size is unknown is refused as the horizontal one (heights in feet were read
        # in the horizontal unit); --crs replaces both (a compound --crs gives the heights' unit)
        vertical = None if file_crs is None or file_crs.is_compound else \
            las.read_vertical_unit_m(path, header, hint=hint + " (a compound CRS for heights in another unit)")
    except CrsError as exc:
        if crs_arg is None or str(crs_arg).strip() == "":
            raise
        log.warning("%s; --crs %s used in its place", exc, crs_arg)
        file_crs = None
    if file_crs is not None:
        crs, source = file_crs, f"{path}: CRS record"
        if crs_arg is not None and str(crs_arg).strip() != "":
            _refuse_other_crs(path, file_crs, parse_crs(crs_arg, crs_name), crs_arg, crs_name)
        # (a geographic record is refused below: lidarctl needs lengths; a record stating no area of use, a user's own
        # WKT as Autzen's, is not checked: PROJ takes 0.2-1 s to find its way back to longitude and latitude)
        if not crs.is_geographic and horizontal_crs(crs).area_of_use is not None:
            check_given_crs(path, header, crs, None)
    elif crs_arg is None or str(crs_arg).strip() == "":
        if not require_crs:
            return None, UNKNOWN
        raise InputError(
            f"{path}: the file has no CRS record; give the CRS with --crs EPSG:<code> (it is never guessed)"
        )
    else:
        crs, source, vertical = parse_crs(crs_arg, "--crs"), f"--crs {crs_arg}", None
        check_given_crs(path, header, crs, crs_arg)
    units = units_of(crs, source, vertical)
    if file_crs is not None and crs_arg is not None and str(crs_arg).strip() != "":
        _note_unused_vertical(path, file_crs, parse_crs(crs_arg, crs_name), crs_arg, crs_name, units)
    # Rasters and downstream code work in the horizontal (projected) CRS; the vertical unit is kept
    # in ``units``.
    return horizontal_crs(crs), units


_VERTICAL_NOTED: set = set()
_AREA_NOTED: set = set()


def check_given_crs(path, header: laspy.LasHeader, crs: pyproj.CRS, crs_arg) -> None:
    """The header's bounds against the area of use of ``--crs`` given for a file without a CRS record, as ``aerotri
    crs assign`` checks them: coordinates the CRS cannot hold are a CrsError, coordinates outside its area of use a
    warning (once per file and ``--crs``; national grids are used past their zone's area). New-user trial s94: a
    UTM 12N cloud classified with ``--crs EPSG:6880`` (Nebraska, US feet; the points at 50 deg N, beyond its area
    of use at 40-43 deg) was read in feet, the trees 3.28x lower, exit 0 and no word. ``crs_arg`` None: ``crs`` is
    the file's own record, warned of (once per file) where it cannot hold the coordinates (a record edited to another
    CRS, trial s99 lidmut H6), not beside its area."""
    from aerotri.geom.crs.definition import check_coordinates, crs_label

    if header.point_count == 0 or (crs_arg is None and (str(path), None) in _AREA_NOTED):
        return
    cx, cy = las.header_corners(header)
    corners = [f"header bounds corner {i + 1}" for i in range(4)]
    try:
        far = check_coordinates(crs, cx, cy, str(path), corners, outside_area="warn")
    except InputError as exc:
        if crs_arg is None:   # (said, not refused: the record's unit may still be right, and the heights with it)
            _AREA_NOTED.add((str(path), None))
            log.warning("%s; is the file's CRS record right? If not, re-tag the file with the CRS its coordinates "
                        "are in (aerotri crs assign IN OUT --crs EPSG:<code>)", exc)
            return
        raise CrsError(f"{exc}; --crs {crs_arg}: the coordinates cannot be {crs_label(crs)}'s (give the CRS they "
                       "are in)") from None
    if crs_arg is None:
        _AREA_NOTED.add((str(path), None))
        return
    if far and (str(path), str(crs_arg)) not in _AREA_NOTED:
        _AREA_NOTED.add((str(path), str(crs_arg)))
        log.warning("%s; --crs %s used all the same: is it the CRS the coordinates are in (zone, datum, units)?",
                    far, crs_arg)


def _note_unused_vertical(path, file_crs: pyproj.CRS, given: pyproj.CRS, crs_arg, crs_name: str,
                          units: LengthUnits) -> None:
    """A warning (once per file and ``--crs``) when a compound ``--crs`` names a vertical CRS the file's readable
    record does not: the record is used, its heights' unit with it (s27: Autzen with `--crs EPSG:2994+5703`, NAVD88
    height in metres, still read its heights in feet, silently)."""
    from aerotri.geom.crs.definition import crs_label, vertical_crs

    v = vertical_crs(given)
    fv = vertical_crs(file_crs)
    if v is None or (fv is not None and fv.equals(v)) or (str(path), str(crs_arg)) in _VERTICAL_NOTED:
        return
    _VERTICAL_NOTED.add((str(path), str(crs_arg)))
    record = crs_label(file_crs) + ("" if fv is not None else ", a 2D CRS")
    vname = f"{v.name}, {v.axis_info[0].unit_name}" if v.axis_info else v.name
    log.warning("%s: the vertical part of %s, %s (%s), is not used: the file's CRS record (%s) is, heights read in %s; "
                "if they are in fact %s, re-tag the file (aerotri crs assign %s OUT --crs %s)", path, crs_name,
                crs_label(v), vname, record, units.z_name, vname, path,
                crs_label(given) if len(str(crs_arg)) > 40 else str(crs_arg).strip())


def _refuse_other_crs(path, file_crs: pyproj.CRS, given: pyproj.CRS, crs_arg, crs_name: str = "--crs") -> None:
    """CrsError when ``--crs`` (``crs_name``) names another horizontal CRS than the file's readable record: ``--crs``
    is the CRS of files without one and never reprojects (trial-lidar: `rasters autzen.laz --crs EPSG:3740` wrote
    its rasters in the file's EPSG:2994 feet, exit 0, as if asked for UTM metres). The message names the three ways
    out (s27-fixes): the record is wrong (``aerotri crs assign`` re-tags the file without moving a point), ``--crs``
    is wrong (leave it out), or the points must move (``aerotri crs transform``); a WKT or PROJJSON ``--crs`` is
    named by its label, not echoed."""
    from aerotri.geom.crs.definition import crs_label, other_realisation, same_horizontal, without_bound

    if same_horizontal(file_crs, given):
        return
    given_h = horizontal_crs(given)
    label, file_label = crs_label(given_h), crs_label(horizontal_crs(file_crs))
    text = str(crs_arg).strip()
    short = len(text) <= 40 and not any(ch in text for ch in "[{\n")
    # what to type: the option's own text when short, else the EPSG code PROJ finds for it, else its label quoted
    code = without_bound(given_h).to_epsg(min_confidence=70) if not short else None
    typed = text if short else (f"EPSG:{code}" if code else f"'<the same CRS text as {label}>'")
    opt = crs_name if crs_name == "--crs" else f"{crs_name} ="
    named = f"{opt} {text}" + (f" ({label})" if label != text else "") if short else f"{opt} {label}"
    realisation = other_realisation(file_crs, given)
    differs = (f"differs: the same projection on another datum realisation (the record's {realisation[0]}, "
               f"{crs_name}'s {realisation[1]}), coordinates centimetres to metres apart" if realisation else "differs")
    never = "--crs gives the CRS of files without one and" if crs_name == "--crs" else "the chain"
    fix_option = ("if --crs is wrong, leave it out to use the file's CRS" if crs_name == "--crs"
                  else f"if {crs_name} is itself wrong, correct it in project.toml")
    raise CrsError(
        f"{path}: its CRS record says {file_label}, but {named} {differs}; {never} never reprojects LiDAR. "
        f"If the record is wrong (the coordinates are in fact in {label}), re-tag the file without moving a point: "
        f"aerotri crs assign {path} OUT --crs {typed}; {fix_option}; if the points must move into {label}: "
        f"aerotri crs transform {path} OUT --to {typed}")


def _validate_xyz(path, x, y, z, first_index: int, units: LengthUnits = METRE) -> None:
    """Bounds in the file's units (the metre bounds scaled), so that the check costs no scaling."""
    max_xy, z_lo, z_hi = MAX_ABS_XY_M / units.xy_m, MIN_Z_M / units.z_m, MAX_Z_M / units.z_m
    bad = ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(z))
    bad |= (np.abs(x) > max_xy) | (np.abs(y) > max_xy) | (z < z_lo) | (z > z_hi)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        if units.is_metric:
            expected = f"|x|,|y| <= {MAX_ABS_XY_M:g} m and {MIN_Z_M:g} <= z <= {MAX_Z_M:g} m"
        else:
            expected = (f"|x|,|y| <= {max_xy:g} {units.xy_name} and {z_lo:g} <= z <= {z_hi:g} {units.z_name} "
                        f"({MAX_ABS_XY_M:g} m; {MIN_Z_M:g} .. {MAX_Z_M:g} m)")
        raise InputError(
            f"{path}: point record {first_index + i}: absurd or non-finite coordinates "
            f"({float(x[i])!r}, {float(y[i])!r}, {float(z[i])!r}); expected {expected}"
        )


def read_records(path) -> laspy.ScaleAwarePointRecord:
    """All point records of a (small) LAS/LAZ file at once (those flagged withheld too: for copies), checked as
    ``las.iter_chunks`` does."""
    with las.open_las(path) as reader:
        header = reader.header
        chunks = [chunk for _, chunk in las.iter_chunks(reader, path, max(int(header.point_count), 1), withheld=True)]
    if not chunks:
        return laspy.ScaleAwarePointRecord.zeros(0, header=header)
    if len(chunks) == 1:
        return chunks[0]
    return laspy.ScaleAwarePointRecord(np.concatenate([c.array for c in chunks]), header.point_format,
                                       header.scales, header.offsets)


def read_cloud(path, crs: str | int | None = None, require_crs: bool = True,
               chunk_points: int = CHUNK_POINTS, keep_records: bool = False,
               point_source_id: bool = False):
    """Read the filter attributes of a LAS/LAZ file in chunks, validated; x, y, z in metres.

    ``crs`` is used only when the file has no CRS record; with ``require_crs`` a file without any
    CRS is an InputError, else its coordinates are taken as they are (``units`` UNKNOWN). With
    ``keep_records`` also return the raw point records (list of chunks, file units) so that
    ``write_classified`` need not decompress the input a second time (costs point-record-size bytes
    per point, e.g. 30 for format 6; every record, withheld ones too). ``point_source_id``: also read the strip
    ids. Records flagged withheld are not in the cloud (``PointCloud.used`` says which records are).
    """
    header = las.read_header(path)
    n = header.point_count
    if n == 0:
        raise InputError(f"{path}: the file holds no points")
    if require_crs or crs is not None:
        resolved, units = resolve_crs_units(path, header, crs)
    else:
        try:
            resolved, units = resolve_crs_units(path, header, None, require_crs=False)
        except InputError:
            # A CRS lidarctl cannot use (unreadable, geographic) where none is required: compare as is.
            resolved, units = None, UNKNOWN
    per_point = 8 * 3 + 2 + 3 + (2 if point_source_id else 0) + (header.point_format.size if keep_records else 0)
    check_allocation(n * per_point, f"{path}: reading its {n:,} points at once",
                     hint="'lidarctl classify' works in tiles; for the other commands split the cloud first")
    x = np.empty(n)
    y = np.empty(n)
    z = np.empty(n)
    intensity = np.empty(n, np.uint16)
    rn = np.empty(n, np.uint8)
    nr = np.empty(n, np.uint8)
    cls = np.empty(n, np.uint8)
    sid = np.empty(n, np.uint16) if point_source_id else None
    records, used, at = [], [], 0
    for first, chunk in las.iter_file_chunks(path, chunk_points, withheld=keep_records):
        if keep_records:
            records.append(chunk)
            mask = las.usable(chunk)
            used.append(np.ones(len(chunk), bool) if mask is None else mask)
            if mask is not None:
                chunk = chunk[mask]
        sl = slice(at, at + len(chunk))
        at += len(chunk)
        cx, cy, cz = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
        _validate_xyz(path, cx, cy, cz, first, units)
        x[sl], y[sl], z[sl] = units.xy_to_m(cx), units.xy_to_m(cy), units.z_to_m(cz)
        intensity[sl] = chunk.intensity
        rn[sl] = chunk.return_number
        nr[sl] = chunk.number_of_returns
        cls[sl] = chunk.classification
        if sid is not None:
            sid[sl] = chunk.point_source_id
    if at == 0:
        raise las.all_withheld(path, n)
    used_mask = _used_mask(used, keep_records, at, n, path)
    if at < n:
        x, y, z, intensity, rn, nr, cls = (a[:at] for a in (x, y, z, intensity, rn, nr, cls))
        sid = None if sid is None else sid[:at]
    rn, nr = sanitize_returns(rn, nr)
    cloud = PointCloud(x, y, z, intensity, rn, nr, cls, resolved, units, sid, used_mask)
    return (cloud, records) if keep_records else cloud


def _used_mask(used, keep_records: bool, n_used: int, n: int, path) -> np.ndarray | None:
    """``PointCloud.used`` from ``read_cloud``'s per-chunk masks (``keep_records``) or a second look at the
    flags (only when records were left out)."""
    if n_used == n:
        return None
    if keep_records:
        mask = np.concatenate(used)
        las.note_withheld(path, n - n_used, n, int(np.argmin(mask)))
        return mask
    mask = np.ones(n, bool)
    for first, chunk in las.iter_file_chunks(path, CHUNK_POINTS, laspy.DecompressionSelection.XY_RETURNS_CHANNEL
                                             | laspy.DecompressionSelection.FLAGS, withheld=True):
        m = las.usable(chunk)
        if m is not None:
            mask[first:first + len(chunk)] = m
    return mask


def require_same_crs(path, crs, units: LengthUnits, first) -> None:
    """InputError naming ``path`` when its CRS or units differ from ``first``, the (path, CRS, units)
    of the first strip of a set that must share one CRS."""
    from aerotri.geom.crs.definition import crs_label, same_crs

    first_path, first_crs, first_units = first
    if units != first_units or not same_crs(crs, first_crs):
        raise InputError(f"{path}: CRS {crs_label(crs)} ({units.describe()}) differs from the CRS of {first_path}, "
                         f"{crs_label(first_crs)} ({first_units.describe()}); give strips in one CRS "
                         "(aerotri crs transform)")


def checked_headers(paths, crs=None, crs_name: str = "--crs"):
    """(path, header, CRS, units) of each file of a set of strips, read from the headers only and checked:
    no empty file, one CRS and units for all (``require_same_crs``); ``crs`` for files without a CRS record (a file
    tagged with another is refused, naming ``crs_name``)."""
    first = None
    for path in paths:
        header = las.read_header(path)
        if header.point_count == 0:
            raise InputError(f"{path}: the file holds no points")
        crs_i, units = resolve_crs_units(path, header, crs, crs_name=crs_name)
        if first is None:
            first = (path, crs_i, units)
        else:
            require_same_crs(path, crs_i, units, first)
        yield path, header, crs_i, units


def sanitize_returns(return_number: np.ndarray, number_of_returns: np.ndarray):
    """Broken return counts (0) would mislead the multi-return rules: treat them as single returns."""
    rn = np.where(return_number == 0, 1, return_number).astype(np.uint8)
    return rn, np.maximum(number_of_returns, rn).astype(np.uint8)


def validate_xyz(path, x, y, z, first_index: int, units: LengthUnits = METRE) -> None:
    """InputError naming the record (``first_index`` + position) for NaN or absurd coordinates
    (x, y, z in the file's ``units``)."""
    _validate_xyz(path, x, y, z, first_index, units)


def record_crs(crs_arg, resolved: pyproj.CRS | None) -> pyproj.CRS | None:
    """The CRS record a derived file of an input without one gets (``output_header``): ``--crs`` as given (a
    compound CRS keeps its vertical unit), else the CRS ``resolve_crs_units`` read."""
    return parse_crs(crs_arg, "--crs") if crs_arg is not None and str(crs_arg).strip() else resolved


def output_header(header: laspy.LasHeader, crs: pyproj.CRS | None = None) -> laspy.LasHeader:
    """Copy of an input header for a derived file: same version, point format (with extra bytes),
    scales, offsets, VLRs, EVLRs, system identifier, software, date and GUID; a CRS record is added
    when ``crs`` is given and the input has none. Counts and bounds are set by the writer."""
    out = copy.deepcopy(header)
    if crs is not None and las.header_crs(header) is None:
        las.add_crs(out, crs)
    return out


def write_evlrs(writer, header: laspy.LasHeader) -> None:
    """The streaming writer drops EVLRs (LAS 1.4) unless they are written explicitly."""
    evlrs = getattr(header, "evlrs", None)
    if evlrs is not None and len(evlrs) > 0:
        writer.write_evlrs(evlrs)


def _numbered(records):
    first = 0
    for rec in records:
        yield first, rec
        first += len(rec)


def write_classified(in_path, out_path, classification: np.ndarray, *, crs: pyproj.CRS | None = None,
                     chunk_points: int = CHUNK_POINTS, records=None, progress=None) -> None:
    """Copy ``in_path`` to ``out_path`` chunk by chunk with new classes (atomic; LAS or LAZ by suffix).

    Everything but the classification is copied: the header (see ``output_header``; a CRS record is
    added when ``crs`` is given and the input has none), VLRs, EVLRs and all point record fields.
    ``classification`` may be a memory map (only a chunk of it is touched at a time); ``records``:
    the chunks kept by ``read_cloud(keep_records=True)``, or any iterable of point-record chunks in
    file order (consumed lazily), else the input is streamed again;
    ``progress(n_points)`` is called after each chunk. ``classification`` holds a class for every record: a
    record flagged withheld keeps its delivered class whatever is given for it (it was not classified).
    """
    refuse_input_as_output(out_path, [in_path], "OUT_PATH")
    header = las.read_header(in_path)
    if len(classification) != header.point_count:
        raise ValueError("classification length differs from the point count")
    out_header = output_header(header, crs)
    out_path = Path(out_path)
    with atomic_path(out_path) as tmp:
        with laspy.open(tmp, mode="w", header=out_header,
                        do_compress=out_path.suffix.lower() == ".laz") as writer:
            chunks = _numbered(records) if records is not None else \
                las.iter_file_chunks(in_path, chunk_points, withheld=True)
            for first, chunk in chunks:
                new = np.asarray(classification[first:first + len(chunk)], np.uint8)
                if (mask := las.usable(chunk)) is not None:
                    new = np.where(mask, new, np.asarray(chunk.classification, np.uint8))
                chunk.classification = new
                writer.write_points(chunk)
                if progress is not None:
                    progress(len(chunk))
            write_evlrs(writer, out_header)


SAME_POINTS_SAMPLE = 20_000  # the first points compared when two files' headers agree


def check_distinct_clouds(paths, what: str = "LAS/LAZ file") -> None:
    """``aerotri.geom.inputs.check_distinct_files``, and ``InputError`` when two of the files hold the same points under
    other bytes (a strip re-exported as LAZ, with another point source id or scale): the same point count and extent
    (within 1 cm) and their first ``SAME_POINTS_SAMPLE`` points equal to the millimetre. Trial s99 lidmut H5: such a
    copy was merged (84,890 points twice) and checked against its original as a pair at RMS 0.000 m, the block's NMAD
    0.006 against 0.019 m, exit 0."""
    from aerotri.geom.inputs import check_distinct_files

    check_distinct_files(paths, what)
    by_count: dict = {}  # point count -> (path, mins, maxs): only files of one count can hold the same points
    for p in paths:
        try:
            h = las.read_header(p)
        except (InputError, OSError):
            continue  # the reader names it
        by_count.setdefault(int(h.point_count), []).append((Path(p), np.asarray(h.mins, float),
                                                            np.asarray(h.maxs, float)))
    for n, heads in by_count.items():
        if n == 0 or len(heads) < 2:
            continue
        first = {}
        for i, (p, lo, hi) in enumerate(heads):
            for q, lo2, hi2 in heads[:i]:
                if np.abs(lo - lo2).max() > 0.01 or np.abs(hi - hi2).max() > 0.01:
                    continue
                try:
                    for f in (p, q):
                        if f not in first:
                            first[f] = _first_points_mm(f)
                except Exception:  # noqa: BLE001 - a file its reader will name (corrupt points): not compared here
                    continue
                if np.array_equal(first[p], first[q]):
                    raise InputError(f"{p}: holds the same points as {q} ({n:,} points, the same extent, the first "
                                     f"{min(n, SAME_POINTS_SAMPLE):,} equal to the millimetre): one strip under two "
                                     f"names or formats? give each {what} once")


def _first_points_mm(path) -> np.ndarray:
    """The first ``SAME_POINTS_SAMPLE`` points' x, y, z (the file's units) rounded to thousandths, and GPS times to
    microseconds where the format has them: (k, 3 or 4) int64."""
    with las.open_las(path) as reader:
        pts = reader.read_points(SAME_POINTS_SAMPLE)
    cols = [np.round(np.asarray(pts.x, float) * 1000.0), np.round(np.asarray(pts.y, float) * 1000.0),
            np.round(np.asarray(pts.z, float) * 1000.0)]
    if "gps_time" in pts.point_format.dimension_names:
        cols.append(np.round(np.asarray(pts.gps_time, float) * 1e6))
    return np.stack(cols, axis=1).astype(np.int64)
