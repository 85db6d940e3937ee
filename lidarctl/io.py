"""LAS/LAZ input and output (laspy): every LAS/LAZ file lidarctl reads is opened here, so that
broken files give the same one-line errors in every command.

A cloud is read as a ``PointCloud`` holding only the fields the filters need (x, y, z, intensity,
return_number, number_of_returns, classification; optionally point_source_id); the full point
records are streamed again chunk by chunk when the classified file is written, so no more than
one chunk of full records is in memory at a time.

Units: x, y, z of a ``PointCloud`` are metres. The file's CRS gives its linear units
(``lidarctl.units``: metre, international foot, US survey foot; heights in the vertical unit of a
compound CRS, else in the horizontal unit); coordinates are scaled to metres once, when they are
read, and ``PointCloud.units`` tells the writers how to scale back. Geographic CRSs are refused.

Checks before any point is used: the LAS signature, a readable header, finite non-zero scale
factors and finite offsets, and the header's point count against the point records the file
holds (uncompressed: the size of the point data block; LAZ: the chunk table), so that a header
that understates the count does not silently drop the rest of the cloud.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import struct
from pathlib import Path

import laspy
import numpy as np
import pyproj

from aerotri.core.atomic import atomic_path, refuse_input_as_output
from aerotri.core.errors import InputError
from aerotri.geom.crs import horizontal_crs, parse_crs
from lidarctl.grid import check_allocation
from lidarctl.units import EPSG_UNIT_M, METRE, UNKNOWN, LengthUnits, units_of

logger = logging.getLogger(__name__)

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

    def __len__(self) -> int:
        return len(self.x)

    @property
    def xyz(self) -> np.ndarray:
        return np.column_stack([self.x, self.y, self.z])


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _open(path):
    """A laspy reader for a LAS/LAZ file whose header passed ``check_header``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: empty file (0 bytes), expected a LAS/LAZ point cloud")
    with open(path, "rb") as fh:
        signature = fh.read(4)
    if signature != b"LASF":
        raise InputError(f"{path}: not a LAS/LAZ file (signature {signature!r}, expected b'LASF')")
    try:
        reader = laspy.open(path)
    except Exception as exc:  # laspy raises several types for broken headers
        raise InputError(f"{path}: unreadable LAS header ({_one_line(exc)})") from exc
    try:
        check_header(path, reader.header)
    except BaseException:
        reader.close()
        raise
    return reader


def check_header(path, header: laspy.LasHeader) -> None:
    """InputError for scale factors that are zero or not finite, offsets that are not finite, or a
    point count that differs from the point records the file holds (``check_point_count``)."""
    for axis, scale, offset in zip("xyz", np.asarray(header.scales, float).tolist(),
                                   np.asarray(header.offsets, float).tolist()):
        if not np.isfinite(scale) or scale == 0.0:
            raise InputError(f"{path}: LAS header: {axis} scale factor {scale!r}; expected a finite, non-zero "
                             "scale (e.g. 0.01 or 0.001)")
        if not np.isfinite(offset):
            raise InputError(f"{path}: LAS header: {axis} offset {offset!r} is not a finite number")
    check_point_count(path, header)


def _laz_chunk_counts(path, header: laspy.LasHeader):
    """(points per chunk, variable-size chunks?, chunk table offset, file size) of a LAZ file from
    its chunk table; None when the file has no chunk table (the LAZ format allows that)."""
    import lazrs

    vlr = next((v for v in header.vlrs if type(v).__name__ == "LasZipVlr"), None)
    if vlr is None:
        raise InputError(f"{path}: compressed points but no LASzip record in the header (corrupt LAZ file)")
    size = Path(path).stat().st_size
    with open(path, "rb") as fh:
        fh.seek(header.offset_to_point_data)
        raw = fh.read(8)
        if len(raw) < 8:
            raise InputError(f"{path}: truncated LAZ file: it ends ({size} bytes) before its point data "
                             f"(byte {header.offset_to_point_data})")
        (table_at,) = struct.unpack("<q", raw)
        if table_at == -1:
            return None
        if not header.offset_to_point_data + 8 <= table_at <= size - 8:
            raise InputError(f"{path}: truncated or corrupt LAZ file: its chunk table is said to start at byte "
                             f"{table_at}, but the file has {size} bytes")
        fh.seek(header.offset_to_point_data)
        try:
            lazvlr = lazrs.LazVlr(vlr.record_data)
            table = lazrs.read_chunk_table(fh, lazvlr)
        except Exception as exc:
            raise InputError(f"{path}: corrupt LAZ chunk table ({_one_line(exc)})") from exc
    return [int(c) for c, _ in table], bool(lazvlr.uses_variable_size_chunks()), int(lazvlr.chunk_size())


def check_point_count(path, header: laspy.LasHeader) -> None:
    """InputError naming both counts when the header's point count differs from the point records
    stored: a count that is too low would silently drop the rest of the cloud, one too high means
    a truncated file.

    Uncompressed LAS: the point data block (from ``offset_to_point_data`` to the EVLRs, the internal
    waveform data or the end of the file) must hold ``point_count`` records of the record length.
    LAZ: the chunk table gives the exact count for variable-size chunks, else the number of chunks
    of ``chunk_size`` points (all but the last full), so the count must lie in
    ((chunks - 1) x chunk_size, chunks x chunk_size]; a LAZ file without a chunk table is not checked
    here (a truncated one still fails while it is read).
    """
    n = int(header.point_count)
    if header.are_points_compressed:
        counts = _laz_chunk_counts(path, header)
        if counts is None:
            return
        per_chunk, variable, chunk_size = counts
        if variable:
            lo = hi = sum(per_chunk)
        else:
            lo, hi = (len(per_chunk) - 1) * chunk_size + 1, len(per_chunk) * chunk_size
        if len(per_chunk) == 0:
            lo = hi = 0
        if n < lo:
            held = f"{lo}" if lo == hi else f"at least {lo}"
            raise InputError(
                f"{path}: the header says {n} points but the file holds {held} point records "
                f"({len(per_chunk)} LAZ chunks); refusing to read only part of the cloud (fix the header's "
                "point count, e.g. by rewriting the file with lasinfo -repair or pdal translate)")
        if n > hi:
            held = f"{hi}" if lo == hi else f"at most {hi}"
            raise InputError(f"{path}: truncated or corrupt LAZ file: the header says {n} points but the "
                             f"file holds {held} point records ({len(per_chunk)} LAZ chunks)")
        return
    rec_len = int(header.point_format.size)
    offset = int(header.offset_to_point_data)
    size = Path(path).stat().st_size
    end = size
    if getattr(header, "number_of_evlrs", 0) and 0 < int(header.start_of_first_evlr or 0) <= size:
        end = int(header.start_of_first_evlr)
    waveform = int(getattr(header, "start_of_waveform_data_packet_record", 0) or 0)
    if offset < waveform <= end:
        end = waveform
    held, extra = divmod(max(end - offset, 0), rec_len)
    if held < n:
        raise InputError(f"{path}: truncated LAS file: the header says {n} points but the file holds {held} "
                         f"point records of {rec_len} bytes ({size} bytes in all)")
    if held > n:
        raise InputError(
            f"{path}: the header says {n} points but the file holds {held} point records of {rec_len} bytes; "
            "refusing to read only part of the cloud (fix the header's point count, e.g. with lasinfo -repair)")
    if extra:
        logger.debug("%s: %d stray bytes after the last point record", path, extra)


def _geokey_vertical_unit_m(header: laspy.LasHeader) -> float | None:
    """Vertical unit from the GeoTIFF keys: VerticalUnitsGeoKey (4099), else the unit of the EPSG
    vertical CRS in VerticalCSTypeGeoKey (4096); laspy's CRS parser reads neither."""
    for vlr in header.vlrs:
        if type(vlr).__name__ != "GeoKeyDirectoryVlr":
            continue
        keys = {k.id: k for k in vlr.geo_keys}
        units_key = keys.get(4099)
        if units_key is not None and units_key.tiff_tag_location == 0 and units_key.value_offset in EPSG_UNIT_M:
            return EPSG_UNIT_M[units_key.value_offset]
        vcs = keys.get(4096)
        if vcs is not None and vcs.tiff_tag_location == 0 and 1024 <= vcs.value_offset <= 32766:
            try:
                return float(pyproj.CRS.from_epsg(vcs.value_offset).axis_info[0].unit_conversion_factor)
            except (pyproj.exceptions.CRSError, IndexError):
                return None
    return None


def resolve_crs_units(path, header: laspy.LasHeader, crs_arg: str | int | None,
                      require_crs: bool = True) -> tuple[pyproj.CRS | None, LengthUnits]:
    """(horizontal CRS, linear units) of a file: its CRS records, else ``crs_arg`` (``--crs``:
    ``EPSG:xxxx``, a code, WKT or PROJ text); never guessed.

    A file without any CRS is an InputError with ``require_crs``, else (None, UNKNOWN). A
    geographic CRS is a CrsError (lidarctl needs lengths). The vertical unit comes from a compound
    CRS, else from the GeoTIFF vertical keys, else it is the horizontal unit.
    """
    try:
        file_crs = header.parse_crs()
    except Exception as exc:
        raise InputError(f"{path}: CRS record present but unreadable ({_one_line(exc)}); pass --crs") from exc
    if file_crs is not None:
        crs, source = file_crs, f"{path}: CRS record"
        vertical = None if file_crs.is_compound else _geokey_vertical_unit_m(header)
    elif crs_arg is None or str(crs_arg).strip() == "":
        if not require_crs:
            return None, UNKNOWN
        raise InputError(
            f"{path}: the file has no CRS record; give the CRS with --crs EPSG:<code> (it is never guessed)"
        )
    else:
        crs, source, vertical = parse_crs(crs_arg, "--crs"), f"--crs {crs_arg}", None
    units = units_of(crs, source, vertical)
    # Rasters and downstream code work in the horizontal (projected) CRS; the vertical unit is kept
    # in ``units``.
    return horizontal_crs(crs), units


def file_crs(header: laspy.LasHeader) -> pyproj.CRS | None:
    """The CRS record of a file as it is (a compound CRS keeps its vertical part), or None."""
    try:
        return header.parse_crs()
    except Exception:  # unreadable records were reported by resolve_crs_units already
        return None


def resolve_crs(path, header: laspy.LasHeader, crs_arg: str | int | None) -> pyproj.CRS:
    """The horizontal CRS of ``resolve_crs_units``."""
    return resolve_crs_units(path, header, crs_arg)[0]


def same_crs(a: pyproj.CRS | None, b: pyproj.CRS | None) -> bool:
    if a is None or b is None:
        return a is b
    return a.equals(b, ignore_axis_order=True)


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
            f"({x[i]!r}, {y[i]!r}, {z[i]!r}); expected {expected}"
        )


def iter_chunks(path, chunk_points: int = CHUNK_POINTS):
    """Yield (first_index, laspy.ScaleAwarePointRecord) chunks (coordinates in the file's units);
    errors name the file and the record."""
    reader = _open(path)
    with reader:
        n = reader.header.point_count
        done = 0
        try:
            for chunk in reader.chunk_iterator(chunk_points):
                yield done, chunk
                done += len(chunk)
        except InputError:
            raise
        except Exception as exc:
            # The reader decodes a block of records at a time: name the block (records counted from 0).
            last = min(done + chunk_points, n) - 1
            where = f"record {done}" if last <= done else f"records {done}-{last}"
            raise InputError(
                f"{path}: truncated or corrupt point data in {where} of {n} ({_one_line(exc)})"
            ) from exc
        if done != n:
            raise InputError(f"{path}: truncated file: header says {n} points, read {done}")


def read_records(path) -> laspy.ScaleAwarePointRecord:
    """All point records of a (small) LAS/LAZ file at once, checked as ``iter_chunks`` does."""
    header = read_header(path)
    chunks = [chunk for _, chunk in iter_chunks(path, max(int(header.point_count), 1))]
    if not chunks:
        return laspy.ScaleAwarePointRecord.zeros(0, header=header)
    if len(chunks) == 1:
        return chunks[0]
    return laspy.ScaleAwarePointRecord(np.concatenate([c.array for c in chunks]), header.point_format,
                                       header.scales, header.offsets)


def read_header(path) -> laspy.LasHeader:
    with _open(path) as reader:
        return reader.header


def read_cloud(path, crs: str | int | None = None, require_crs: bool = True,
               chunk_points: int = CHUNK_POINTS, keep_records: bool = False,
               point_source_id: bool = False):
    """Read the filter attributes of a LAS/LAZ file in chunks, validated; x, y, z in metres.

    ``crs`` is used only when the file has no CRS record; with ``require_crs`` a file without any
    CRS is an InputError, else its coordinates are taken as they are (``units`` UNKNOWN). With
    ``keep_records`` also return the raw point records (list of chunks, file units) so that
    ``write_classified`` need not decompress the input a second time (costs point-record-size bytes
    per point, e.g. 30 for format 6). ``point_source_id``: also read the strip ids.
    """
    header = read_header(path)
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
    records = []
    for first, chunk in iter_chunks(path, chunk_points):
        if keep_records:
            records.append(chunk)
        sl = slice(first, first + len(chunk))
        cx, cy, cz = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
        _validate_xyz(path, cx, cy, cz, first, units)
        x[sl], y[sl], z[sl] = units.xy_to_m(cx), units.xy_to_m(cy), units.z_to_m(cz)
        intensity[sl] = chunk.intensity
        rn[sl] = chunk.return_number
        nr[sl] = chunk.number_of_returns
        cls[sl] = chunk.classification
        if sid is not None:
            sid[sl] = chunk.point_source_id
    rn, nr = sanitize_returns(rn, nr)
    cloud = PointCloud(x, y, z, intensity, rn, nr, cls, resolved, units, sid)
    return (cloud, records) if keep_records else cloud


def sanitize_returns(return_number: np.ndarray, number_of_returns: np.ndarray):
    """Broken return counts (0) would mislead the multi-return rules: treat them as single returns."""
    rn = np.where(return_number == 0, 1, return_number).astype(np.uint8)
    return rn, np.maximum(number_of_returns, rn).astype(np.uint8)


def validate_xyz(path, x, y, z, first_index: int, units: LengthUnits = METRE) -> None:
    """InputError naming the record (``first_index`` + position) for NaN or absurd coordinates
    (x, y, z in the file's ``units``)."""
    _validate_xyz(path, x, y, z, first_index, units)


def output_header(header: laspy.LasHeader, crs: pyproj.CRS | None = None) -> laspy.LasHeader:
    """Copy of an input header for a derived file: same version, point format (with extra bytes),
    scales, offsets, VLRs, EVLRs, system identifier, software, date and GUID; a CRS record is added
    when ``crs`` is given and the input has none. Counts and bounds are set by the writer."""
    out = copy.deepcopy(header)
    if crs is not None and _try_crs(header) is None:
        add_crs(out, crs)
    return out


def add_crs(header: laspy.LasHeader, crs: pyproj.CRS) -> None:
    """Add a CRS record to a header (laspy: WKT for LAS 1.4 / point formats >= 6, else GeoTIFF keys).

    GeoTIFF keys in laspy take only EPSG projected CRSs, not compound ones: a compound CRS
    (projected + vertical) then gets the projected CRS's keys plus VerticalCSTypeGeoKey and
    VerticalUnitsGeoKey, so that its vertical unit is read back (``resolve_crs_units``)."""
    try:
        header.add_crs(crs)
        return
    except RuntimeError:
        if not crs.is_compound:
            raise
    from laspy.vlrs.known import GeoKeyEntryStruct

    horizontal = horizontal_crs(crs)
    header.add_crs(horizontal)
    vertical = next((c for c in crs.sub_crs_list if c.is_vertical), None)
    vlr = next((v for v in header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr"), None)
    if vertical is None or vlr is None:
        return
    unit_m = float(vertical.axis_info[0].unit_conversion_factor)
    unit_code = next((code for code, f in EPSG_UNIT_M.items() if abs(f - unit_m) < 1e-12), None)
    keys = [(4096, vertical.to_epsg() or 32767), (4099, unit_code or 32767)]
    vlr.geo_keys = [k for k in vlr.geo_keys if k.id != 0 and k.id not in (4096, 4099)]
    for key_id, value in keys:
        k = GeoKeyEntryStruct()
        k.id, k.tiff_tag_location, k.count, k.value_offset = key_id, 0, 1, value
        vlr.geo_keys.append(k)
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)


def write_evlrs(writer, header: laspy.LasHeader) -> None:
    """The streaming writer drops EVLRs (LAS 1.4) unless they are written explicitly."""
    evlrs = getattr(header, "evlrs", None)
    if evlrs is not None and len(evlrs) > 0:
        writer.write_evlrs(evlrs)


def _try_crs(header):
    try:
        return header.parse_crs()
    except Exception:
        return None


def _numbered(records):
    first = 0
    for rec in records:
        yield first, rec
        first += len(rec)


def write_classified(in_path, out_path, classification: np.ndarray, crs: pyproj.CRS | None = None,
                     chunk_points: int = CHUNK_POINTS, records=None, progress=None) -> None:
    """Copy ``in_path`` to ``out_path`` chunk by chunk with new classes (atomic; LAS or LAZ by suffix).

    Everything but the classification is copied: the header (see ``output_header``; a CRS record is
    added when ``crs`` is given and the input has none), VLRs, EVLRs and all point record fields.
    ``classification`` may be a memory map (only a chunk of it is touched at a time); ``records``:
    the chunks kept by ``read_cloud(keep_records=True)``, or any iterable of point-record chunks in
    file order (consumed lazily), else the input is streamed again;
    ``progress(n_points)`` is called after each chunk.
    """
    refuse_input_as_output(out_path, [in_path], "OUT_PATH")
    header = read_header(in_path)
    if len(classification) != header.point_count:
        raise ValueError("classification length differs from the point count")
    out_header = output_header(header, crs)
    out_path = Path(out_path)
    with atomic_path(out_path) as tmp:
        with laspy.open(tmp, mode="w", header=out_header,
                        do_compress=out_path.suffix.lower() == ".laz") as writer:
            chunks = _numbered(records) if records is not None else iter_chunks(in_path, chunk_points)
            for first, chunk in chunks:
                chunk.classification = np.asarray(classification[first:first + len(chunk)], np.uint8)
                writer.write_points(chunk)
                if progress is not None:
                    progress(len(chunk))
            write_evlrs(writer, out_header)
