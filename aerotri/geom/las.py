"""LAS/LAZ files at the format level: every stage that reads a LAS/LAZ file opens it here, so that a
broken file gives the same one-line error (naming the file and the record) in every command.

- ``open_las``: a laspy reader whose header passed ``check_header`` (the LAS signature, a readable
  header, finite non-zero scale factors and finite offsets, and the header's point count against
  the point records the file holds: uncompressed, the size of the point data block; LAZ, the chunk
  table; so that a header that understates the count does not silently drop the rest of the cloud).
- ``iter_chunks``: point-record chunks of an open reader (coordinates in the file's units); a
  decompression or read error names the block of records; ``iter_file_chunks`` opens the file too.
  Records flagged withheld are left out here (``usable``, the one rule: ASPRS says they are not to be
  processed) unless a writer that copies every record asks for them (``withheld=True``).
- CRS of a header: ``header_crs`` (None when absent or unreadable), ``read_header_crs`` (an
  unreadable record is an error), ``geokey_vertical_unit_m`` / ``read_vertical_unit_m`` (the vertical unit
  the GeoTIFF keys state, which laspy's CRS parser ignores) and ``add_crs`` (writes a compound CRS as GeoTIFF keys
  with its vertical CRS and unit, so that ``geokey_vertical_unit_m`` reads it back).

Units and scaling to metres belong to the readers of the stages (e.g. ``lidarctl.io``).
"""

from __future__ import annotations

import functools
import logging
import re
import struct
from pathlib import Path

import laspy
import numpy as np
import pyproj

from aerotri.core.errors import CrsError, InputError

logger = logging.getLogger(__name__)

US_SURVEY_FOOT_M = 1200.0 / 3937.0
FOOT_M = 0.3048
# EPSG unit-of-measure codes (GeoTIFF VerticalUnitsGeoKey / ProjLinearUnitsGeoKey).
EPSG_UNIT_M = {9001: 1.0, 9002: FOOT_M, 9003: US_SURVEY_FOOT_M}
# GeoTIFF keys: vertical CRS (an EPSG code) and vertical units.
VERTICAL_CS_KEY, VERTICAL_UNITS_KEY = 4096, 4099
PROJ_LINEAR_UNITS_KEY = 3076
PROJ_LINEAR_UNIT_SIZE_KEY = 3077  # metres per unit of a user-defined ProjLinearUnitsGeoKey (32767), a double
# metres per unit of a user-defined VerticalUnitsGeoKey (32767), a double: GeoTIFF 1.1 (OGC 19-008r4) annex B,
# "vertical axis unit through VerticalUnitsGeoKey: ... scaling from SI base unit of meter (through
# GeogLinearUnitSizeGeoKey)"; there is no VerticalUnitSizeGeoKey (requirement 16.9 forbids 32767 for that reason)
GEOG_LINEAR_UNIT_SIZE_KEY = 2053
USER_DEFINED_KEY = 32767


def one_line(exc: Exception) -> str:
    """An exception's message on one line (laspy and lazrs messages may span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__


# ------------------------------------------------------------------------------------------- opening
def open_las(path, decompression_selection=None):
    """A laspy reader for a LAS/LAZ file whose header passed ``check_header`` (use it as a context
    manager); ``InputError`` naming the file for a missing, empty or non-LAS file or a broken header.
    ``decompression_selection``: the LAZ fields to decompress (laspy's ``DecompressionSelection``;
    default all; the others read as zeros in the layered point formats 6 to 10)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: is a folder, expected a LAS/LAZ file" if path.is_dir() else f"{path}: file not found")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: empty file (0 bytes), expected a LAS/LAZ point cloud")
    with open(path, "rb") as fh:
        signature = fh.read(4)
    if signature != b"LASF":
        raise InputError(f"{path}: not a LAS/LAZ file (signature {signature!r}, expected b'LASF')")
    try:
        reader = laspy.open(path) if decompression_selection is None else \
            laspy.open(path, decompression_selection=decompression_selection)
    except Exception as exc:  # laspy raises several types (LaspyException, ValueError, EOFError) for broken headers
        raise InputError(f"{path}: unreadable LAS header ({one_line(exc)})") from exc
    try:
        check_header(path, reader.header)
    except BaseException:
        reader.close()
        raise
    return reader


def is_copc(header: laspy.LasHeader) -> bool:
    """Whether the header has a COPC record (user id "copc": the COPC info VLR, the hierarchy EVLR)."""
    return any(getattr(v, "user_id", "") == "copc" for v in list(header.vlrs) + list(header.evlrs or []))


def refuse_copc(path, header: laspy.LasHeader, command: str) -> None:
    """InputError for a COPC (cloud-optimized point cloud) file given to ``command``, which rewrites the points in
    chunks of its own: the COPC records' octree hierarchy points at byte offsets of the input's chunks, wrong in the
    output (and laspy writes no COPC: its info record raised NotImplementedError, a traceback, review 31)."""
    if is_copc(header):
        raise InputError(
            f"{path}: a COPC file (cloud-optimized point cloud): {command} writes the points in other LAZ chunks, so "
            "its COPC hierarchy (byte offsets of the input's chunks) would be wrong; write it as a plain LAZ first "
            f"(lidarctl merge {path} PLAIN.laz keeps every point and dimension and drops the COPC records; or "
            "pdal translate), then give that")


def copc_free(vlrs) -> list:
    """``vlrs`` without the COPC records (a file rewritten chunk by chunk is a plain LAS/LAZ file)."""
    return [v for v in vlrs if getattr(v, "user_id", "") != "copc"]


def read_header(path) -> laspy.LasHeader:
    """The checked header of a LAS/LAZ file (``open_las``)."""
    with open_las(path) as reader:
        return reader.header


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
    """(points per chunk, variable-size chunks?, chunk size) of a LAZ file from its chunk table;
    None when the file has no chunk table (the LAZ format allows that)."""
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
            raise InputError(f"{path}: corrupt LAZ chunk table ({one_line(exc)})") from exc
    # a chunk of no bytes holds no point: an empty cloud is written as one (laspy with lazrs)
    return ([int(c) for c, n_bytes in table if n_bytes > 0], bool(lazvlr.uses_variable_size_chunks()),
            int(lazvlr.chunk_size()))


def _check_laz_point_count(path, header: laspy.LasHeader) -> None:
    n = int(header.point_count)
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


def _check_las_point_count(path, header: laspy.LasHeader) -> None:
    n = int(header.point_count)
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
    if header.are_points_compressed:
        _check_laz_point_count(path, header)
    else:
        _check_las_point_count(path, header)


# ------------------------------------------------------------------------------------------- reading
def usable(chunk) -> np.ndarray | None:
    """The one rule for points that are not to be used: a mask of the chunk's records without the LAS withheld
    flag (ASPRS: "should not be included in processing"); None when every record may be used (no record
    flagged, or a point format without the flag), so that the common case costs no copy."""
    if "withheld" not in chunk.point_format.dimension_names:
        return None
    withheld = np.asarray(chunk.withheld, bool)
    return ~withheld if withheld.any() else None


def iter_chunks(reader, path, chunk_points: int, *, withheld: bool = False):
    """Yield (first_index, laspy.ScaleAwarePointRecord) chunks of an open reader (``open_las``),
    coordinates in the file's units; a read or decompression error names the file and the block of
    records, a file that ends early names both counts.

    Records flagged withheld (``usable``) are left out of the chunks unless ``withheld`` (writers that copy
    every record: classified outputs, CRS transforms, merges); a note says once per file how many were left
    out. ``first_index`` is the file's record number of the chunk's first record whatever was left out (a
    reader's ``first_index + i`` names record i exactly when no record before it in the chunk was withheld)."""
    n = reader.header.point_count
    done = left_out = 0
    try:
        for chunk in reader.chunk_iterator(chunk_points):
            size = len(chunk)
            if not withheld and (mask := usable(chunk)) is not None:
                if not left_out:
                    first_flagged = done + int(np.argmin(mask))
                left_out += size - int(mask.sum())
                chunk = chunk[mask]
            yield done, chunk
            done += size
    except InputError:
        raise
    except Exception as exc:  # lazrs/laszip and numpy raise their own types for corrupt data
        # The reader decodes a block of records at a time: name the block (records counted from 0).
        last = min(done + chunk_points, n) - 1
        where = f"record {done}" if last <= done else f"records {done}-{last}"
        raise InputError(f"{path}: truncated or corrupt point data in {where} of {n} ({one_line(exc)})") from exc
    if done != n:
        raise InputError(f"{path}: truncated file: header says {n} points, read {done}")
    if left_out and left_out == n:
        raise all_withheld(path, n)
    if left_out:
        note_withheld(path, left_out, n, first_flagged)


def all_withheld(path, n: int) -> InputError:
    """The error for a file whose every record carries the withheld flag: nothing in it may be used."""
    return InputError(f"{path}: every one of its {n:,} points carries the withheld flag (not to be used)")


def note_withheld(path, left_out: int, n: int, first_flagged: int) -> None:
    """The note (once per process and file) that ``left_out`` of the file's ``n`` records were left out as
    withheld; for readers that apply ``usable`` themselves (they read every record for a copy)."""
    if str(path) not in _WITHHELD_NOTED:
        _WITHHELD_NOTED.add(str(path))
        logger.info(f"{path}: {left_out:,} of {n:,} points carry the withheld flag (first record {first_flagged}) "
                    "and were left out (LAS: not to be used)")


# files already noted (once per process and file: the stages read a file several times)
_WITHHELD_NOTED: set[str] = set()


def iter_file_chunks(path, chunk_points: int, decompression_selection=None, *, withheld: bool = False):
    """``iter_chunks`` of a file, opened (and checked) by ``open_las`` and closed at the end. A
    ``decompression_selection`` always takes the flags layer too (LAZ point formats 6-10), so that withheld
    records are known."""
    if decompression_selection is not None and not withheld:
        decompression_selection = decompression_selection | laspy.DecompressionSelection.FLAGS
    with open_las(path, decompression_selection) as reader:
        yield from iter_chunks(reader, path, chunk_points, withheld=withheld)


# ----------------------------------------------------------------------------------------------- CRS
def header_crs(header: laspy.LasHeader) -> pyproj.CRS | None:
    """The CRS record of a header as it is (a compound CRS keeps its vertical part); None when the
    header has none or it cannot be read (``read_header_crs`` reports that)."""
    try:
        return _parse_crs(header)
    except Exception:  # laspy/pyproj raise several types for malformed CRS records
        return None


def read_header_crs(path, header: laspy.LasHeader, hint: str = "") -> pyproj.CRS | None:
    """The CRS record of a header, or None when it has none; ``CrsError`` naming the file for a record
    that is present but unreadable (``hint``: what to do instead, appended after a semicolon)."""
    try:
        return _parse_crs(header)
    except RecordsDisagree as exc:
        raise CrsError(f"{path}: CRS records disagree ({exc}); {hint + ', or ' if hint else ''}re-tag the file with "
                       "the CRS its coordinates are in (aerotri crs assign IN OUT --crs EPSG:<code>)") from None
    except Exception as exc:  # laspy/pyproj raise several types for malformed CRS records
        raise CrsError(f"{path}: CRS record present but unreadable ({one_line(exc)})"
                       + (f"; {hint}" if hint else "")) from exc


class RecordsDisagree(ValueError):
    """A header's WKT record and GeoTIFF keys state different linear units (``_parse_crs``)."""


def _parse_crs(header: laspy.LasHeader) -> pyproj.CRS | None:
    """laspy's CRS of the header (its WKT record first), with the GeoTIFF keys' ProjLinearUnitsGeoKey
    (3076) applied when the CRS came from the keys: laspy takes ProjectedCSTypeGeoKey's EPSG code alone,
    so a file keyed "EPSG:32104 (metres), linear units US survey foot" (GDAL, PDAL and QGIS read feet:
    the GeoTIFF rule that the units key overrides the code's) was processed as metres."""
    wkt = _wkt_crs(header)
    if wkt is None:
        return _keys_crs(header)
    # a WKT record edited alone (trial s99 lidmut H6: Nebraska's WKT replaced by EPSG:32104, metres, its keys still
    # in US survey feet) read 2,445,180 ft as metres, exit 0: two records in two units are not guessed
    keyed = _keys_linear_unit(header) if wkt.is_projected else None
    if keyed is not None:
        unit = wkt.axis_info[0]
        if abs(unit.unit_conversion_factor - keyed[0]) > 1e-6 * keyed[0]:
            raise RecordsDisagree(f"its WKT record ({wkt.name}) states {unit.unit_name}, its GeoTIFF keys "
                                  f"{keyed[1]}: the coordinates' unit is not known")
    return wkt


PROJECTED_CS_KEY = 3072  # ProjectedCSTypeGeoKey: an EPSG projected CRS


def _keys_linear_unit(header: laspy.LasHeader) -> tuple[float, str] | None:
    """(metres per unit, what states it) of the GeoTIFF keys' projected CRS: ProjLinearUnitsGeoKey (3076), else the
    unit of the EPSG CRS in ProjectedCSTypeGeoKey (3072); None when the keys state neither or cannot be read (stale
    keys beside a readable WKT record are otherwise not read: ``geokey_vertical_unit_m``). No CRS is built from
    the keys: a user's own WKT record costs PROJ 0.05-0.1 s a CRS, and the stages read a header many times."""
    keys = _geo_keys(header) or {}
    if _in_directory(keys.get(PROJ_LINEAR_UNITS_KEY)):
        try:
            unit = _units_key(header, keys)
        except ValueError:  # (a user-defined unit without its size: the keys' unit is not known)
            return None
        if unit is None:
            return None
        unit_m, code = unit
        user = keys[PROJ_LINEAR_UNITS_KEY].value_offset == USER_DEFINED_KEY  # (its size said, not the code it matches)
        return unit_m, (f"ProjLinearUnitsGeoKey {unit_m:g} m" if user else
                        f"ProjLinearUnitsGeoKey {code} ({_UNIT_NAME[code]})")
    key = keys.get(PROJECTED_CS_KEY)
    if key is None or key.tiff_tag_location != 0 or not 1024 <= key.value_offset < USER_DEFINED_KEY:
        return None
    unit = _epsg_projected_unit(int(key.value_offset))
    return None if unit is None else (unit[0], f"EPSG:{key.value_offset} ({unit[1]})")


_UNIT_NAME = {9001: "metre", 9002: "foot", 9003: "US survey foot"}


@functools.lru_cache(maxsize=64)
def _epsg_projected_unit(code: int) -> tuple[float, str] | None:
    """(metres per unit, unit name) of an EPSG projected CRS, None for a code PROJ does not know as one."""
    try:
        crs = pyproj.CRS.from_epsg(code)
    except pyproj.exceptions.CRSError:
        return None
    if not crs.is_projected:
        return None
    a = crs.axis_info[0]
    return float(a.unit_conversion_factor), a.unit_name


def _keys_crs(header: laspy.LasHeader) -> pyproj.CRS | None:
    """The CRS of the header's GeoTIFF keys, with ProjLinearUnitsGeoKey applied (``_parse_crs``)."""
    crs = header.parse_crs(prefer_wkt=False)
    if crs is None or not crs.is_projected:
        return crs
    unit = _units_key(header, _geo_keys(header) or {})
    if unit is None:
        return crs
    unit_m, code = unit
    if all(abs(a.unit_conversion_factor - unit_m) < 1e-12 for a in crs.axis_info):
        return crs
    return with_linear_unit(crs, code if code is not None else unit_m)


def _in_directory(key) -> bool:
    """Whether a GeoTIFF key holds its value in the key directory itself (tag location 0: a SHORT, e.g. a code)."""
    return key is not None and key.tiff_tag_location == 0


def _units_key(header: laspy.LasHeader, keys: dict) -> tuple[float, int | None] | None:
    """ProjLinearUnitsGeoKey (3076) as (metres per unit, its EPSG unit code; None for a user-defined size matching no
    known unit); None when the key is absent or holds a code that is no linear unit known here. A user-defined unit
    (32767) takes its size from ProjLinearUnitSizeGeoKey (3077, GeoTIFF 1.0 6.3.1.3), a known unit's code when it is
    one's size (so that the CRS and the outputs name it as GDAL does); ValueError without that size."""
    key = keys.get(PROJ_LINEAR_UNITS_KEY)
    if not _in_directory(key):
        return None
    code = key.value_offset
    if code == USER_DEFINED_KEY:
        size = _geo_double(header, keys.get(PROJ_LINEAR_UNIT_SIZE_KEY))
        if size is None or not size > 0:
            raise ValueError("ProjLinearUnitsGeoKey (3076) is user-defined (32767) but ProjLinearUnitSizeGeoKey "
                             "(3077), the unit's size in metres, is missing or not a positive number")
        return size, next((c for c, m in EPSG_UNIT_M.items() if abs(size - m) <= 1e-9 * m), None)
    return (EPSG_UNIT_M[code], code) if code in EPSG_UNIT_M else None


def _geo_double(header: laspy.LasHeader, key) -> float | None:
    """The value of a GeoTIFF key held in the GeoDoubleParams record (tag 34736), None when it is not there."""
    if key is None or key.tiff_tag_location != 34736:
        return None
    for vlr in header.vlrs:
        if type(vlr).__name__ == "GeoDoubleParamsVlr":
            doubles = list(vlr.doubles)  # laspy's ctypes.c_double values
            return float(getattr(doubles[key.value_offset], "value", doubles[key.value_offset])) \
                if key.value_offset < len(doubles) else None
    return None


def _wkt_crs(header: laspy.LasHeader) -> pyproj.CRS | None:
    """The CRS of the header's WKT record (None when there is none or laspy cannot read it)."""
    from laspy.vlrs.known import WktCoordinateSystemVlr

    for vlr in list(header.vlrs) + list(header.evlrs or []):
        if isinstance(vlr, WktCoordinateSystemVlr):
            try:
                crs = vlr.parse_crs()
            except Exception:  # an unreadable WKT record: laspy falls back to the keys, as we do
                crs = None
            if crs is not None:
                return crs
    return None


# the unit at the end of a CRS name: EPSG's "(ftUS)", "(ft)", "(m)" and the names with_linear_unit gives
_NAME_UNIT = re.compile(r"\s*\((?:ftUS|ftIna|ftCla|ftSe|ft|m|metre|meter|foot|feet|US survey foot|"
                        r"user-defined unit of [^()]*)\)\s*$")


def with_linear_unit(crs: pyproj.CRS, unit_code: int | float) -> pyproj.CRS:
    """Projected ``crs`` with its axes in EPSG unit ``unit_code`` (9001 metre, 9002 foot, 9003 US survey
    foot; a float: a unit of that many metres, a user-defined GeoTIFF unit); the projection's parameters keep their
    own units (false easting 500000 m stays 500000 m), as GDAL's SetLinearUnitsAndUpdateParameters does for such
    GeoTIFF keys. The name says the new unit ("NAD83 / Nebraska (US survey foot)"): it is no longer the EPSG
    code's CRS, whose name it would otherwise keep (so that "the file's CRS (NAD83 / Nebraska) is not --from
    EPSG:32104" read as a contradiction)."""
    if isinstance(unit_code, float):
        unit = {"type": "LinearUnit", "name": f"user-defined unit of {unit_code:.10g} m",
                "conversion_factor": unit_code}
    else:
        unit = {9001: "metre", 9002: {"type": "LinearUnit", "name": "foot", "conversion_factor": FOOT_M,
                                      "id": {"authority": "EPSG", "code": 9002}},
                9003: {"type": "LinearUnit", "name": "US survey foot", "conversion_factor": US_SURVEY_FOOT_M,
                       "id": {"authority": "EPSG", "code": 9003}}}[unit_code]
    d = crs.to_json_dict()
    for axis in d["coordinate_system"]["axis"]:
        axis["unit"] = unit
    d.pop("id", None)  # no longer the EPSG code's CRS
    # a unit the EPSG name already gives ("NAD83 / North Carolina (ftUS)") is replaced, not followed by the new one
    name = _NAME_UNIT.sub("", str(d.get("name", "unknown")))
    d["name"] = f"{name} ({unit if isinstance(unit, str) else unit['name']})"
    return pyproj.CRS.from_json_dict(d)


def _geo_keys(header: laspy.LasHeader) -> dict | None:
    for vlr in header.vlrs:
        if type(vlr).__name__ == "GeoKeyDirectoryVlr":
            return {k.id: k for k in vlr.geo_keys}
    return None


def epsg_linear_unit_m(code: int) -> float | None:
    """Metres per unit of an EPSG linear unit-of-measure code (9001 metre, 9002 foot, 9003 US survey foot, 1025
    millimetre ...; PROJ's database); None for a code that is not one."""
    if code in EPSG_UNIT_M:
        return EPSG_UNIT_M[code]
    for unit in pyproj.get_units_map(auth_name="EPSG", category="linear").values():
        if unit.code == str(code):
            return float(unit.conv_factor)
    return None


def geokey_vertical_unit_m(header: laspy.LasHeader) -> float | None:
    """Metres per vertical unit from the GeoTIFF keys: VerticalUnitsGeoKey (4099) - an EPSG linear unit, or
    user-defined (32767) with its size in metres in GeogLinearUnitSizeGeoKey (2053, GeoTIFF 1.1 annex B) -, else
    the unit of the EPSG vertical CRS in VerticalCSTypeGeoKey (4096); None when they say nothing (laspy's CRS
    parser reads neither). A units key holding a code that is no EPSG linear unit (a vertical datum's, 5703, from
    some writers) gives way to the vertical CRS's unit. ValueError for a units key whose size cannot be known
    (user-defined without its size, a code that is no EPSG linear unit and no vertical CRS): falling back to the
    horizontal unit read heights in feet as metres. (GDAL reads a user-defined vertical unit as metres: it has no
    size key of its own.) A readable WKT record (LAS 1.4) is the CRS, as in ``_parse_crs``: keys left beside it
    (stale, from an older copy) are not read, and the heights' unit is the WKT's (None here)."""
    keys = _geo_keys(header)
    if keys is None or _wkt_crs(header) is not None:
        return None
    vcs_unit_m = _vertical_cs_unit_m(keys.get(VERTICAL_CS_KEY))
    units_key = keys.get(VERTICAL_UNITS_KEY)
    if units_key is not None and units_key.tiff_tag_location == 0 and units_key.value_offset != 0:
        code = int(units_key.value_offset)
        if code == USER_DEFINED_KEY:
            size = _geo_double(header, keys.get(GEOG_LINEAR_UNIT_SIZE_KEY))
            if size is None or not (np.isfinite(size) and size > 0):
                raise ValueError(
                    "VerticalUnitsGeoKey (4099) is user-defined (32767) but GeogLinearUnitSizeGeoKey (2053), the "
                    "unit's size in metres (GeoTIFF 1.1 annex B), is missing or not a positive number: the heights' "
                    "unit is unknown")
            return float(size)
        unit_m = epsg_linear_unit_m(code) if code < USER_DEFINED_KEY else None
        if unit_m is None:
            # some writers put the vertical datum's code (5703) here: the vertical CRS's unit, when it has one
            if vcs_unit_m is not None:
                return vcs_unit_m
            raise ValueError(f"VerticalUnitsGeoKey (4099) is {code}, not an EPSG linear unit code, and "
                             "VerticalCSTypeGeoKey (4096) names no EPSG vertical CRS: the heights' unit is unknown")
        return unit_m
    return vcs_unit_m


def header_corners(header: laspy.LasHeader) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the four corners of the header's bounds (file units): min/min, max/min, min/max, max/max, which the
    CRS checks name "header bounds corner 1..4"."""
    x = np.array([header.mins[0], header.maxs[0], header.mins[0], header.maxs[0]], float)
    y = np.array([header.mins[1], header.mins[1], header.maxs[1], header.maxs[1]], float)
    return x, y


def vertical_keys_beside_wkt(header: laspy.LasHeader) -> bool:
    """True when a readable WKT record is the CRS and GeoTIFF keys beside it still hold a VerticalUnitsGeoKey
    (4099) or VerticalCSTypeGeoKey (4096), which ``geokey_vertical_unit_m`` does not read (LAS 1.4: the WKT wins)."""
    keys = _geo_keys(header)
    return keys is not None and _wkt_crs(header) is not None and \
        any(keys.get(k) is not None for k in (VERTICAL_UNITS_KEY, VERTICAL_CS_KEY))


def _vertical_cs_unit_m(vcs) -> float | None:
    """Metres per unit of the EPSG vertical CRS in a VerticalCSTypeGeoKey (None: no key, or not an EPSG CRS)."""
    if vcs is not None and vcs.tiff_tag_location == 0 and 1024 <= vcs.value_offset <= 32766:
        try:
            return float(pyproj.CRS.from_epsg(vcs.value_offset).axis_info[0].unit_conversion_factor)
        except (pyproj.exceptions.CRSError, IndexError):
            return None
    return None


def read_vertical_unit_m(path, header: laspy.LasHeader, hint: str = "") -> float | None:
    """``geokey_vertical_unit_m``, a units key whose size cannot be known a ``CrsError`` naming the file (``hint``:
    what to do instead, appended after a semicolon)."""
    try:
        return geokey_vertical_unit_m(header)
    except ValueError as exc:
        raise CrsError(f"{path}: CRS record present but unreadable ({one_line(exc)})"
                       + (f"; {hint}" if hint else "")) from exc


def add_crs(header: laspy.LasHeader, crs: pyproj.CRS) -> None:
    """Add a CRS record to a header (laspy: WKT for LAS 1.4 / point formats >= 6, else GeoTIFF keys).

    GeoTIFF keys in laspy take only EPSG projected CRSs, not compound ones: a compound CRS
    (projected + vertical) then gets the projected CRS's keys plus VerticalCSTypeGeoKey and
    VerticalUnitsGeoKey, so that its vertical unit is read back (``geokey_vertical_unit_m``)."""
    try:
        header.add_crs(crs)
        return
    except RuntimeError:
        if not crs.is_compound:
            raise
    from laspy.vlrs.known import GeoKeyEntryStruct

    header.add_crs(crs.sub_crs_list[0])  # its horizontal part (aerotri.geom.crs imports this module, not back)
    vertical = next((c for c in crs.sub_crs_list if c.is_vertical), None)
    vlr = next((v for v in header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr"), None)
    if vertical is None or vlr is None:
        return
    axis = vertical.axis_info[0]
    unit_m = float(axis.unit_conversion_factor)
    unit_code = next((code for code, f in EPSG_UNIT_M.items() if abs(f - unit_m) < 1e-12), None)
    if unit_code is None and axis.unit_auth_code == "EPSG" and str(axis.unit_code).isdigit():
        unit_code = int(axis.unit_code)
    # (key, location, value): a unit without an EPSG code is user-defined, its size in GeogLinearUnitSizeGeoKey
    keys = [(VERTICAL_CS_KEY, 0, vertical.to_epsg() or USER_DEFINED_KEY),
            (VERTICAL_UNITS_KEY, 0, unit_code or USER_DEFINED_KEY)]
    if unit_code is None:
        import ctypes

        from laspy.vlrs.known import GeoDoubleParamsVlr

        doubles = next((v for v in header.vlrs if type(v).__name__ == "GeoDoubleParamsVlr"), None)
        if doubles is None:
            doubles = GeoDoubleParamsVlr()
            header.vlrs.append(doubles)
        doubles.doubles.append(ctypes.c_double(unit_m))
        keys.append((GEOG_LINEAR_UNIT_SIZE_KEY, 34736, len(doubles.doubles) - 1))
    ids = (VERTICAL_CS_KEY, VERTICAL_UNITS_KEY, GEOG_LINEAR_UNIT_SIZE_KEY)
    vlr.geo_keys = [k for k in vlr.geo_keys if k.id != 0 and k.id not in ids]
    for key_id, location, value in keys:
        k = GeoKeyEntryStruct()
        k.id, k.tiff_tag_location, k.count, k.value_offset = key_id, location, 1, value
        vlr.geo_keys.append(k)
    vlr.geo_keys.sort(key=lambda k: k.id)  # GeoTIFF: keys in ascending order
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)
