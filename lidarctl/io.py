"""LAS/LAZ input and output (laspy): chunked reading, CRS resolution, validation.

Coordinates are metres in a projected CRS. A cloud is read as a ``PointCloud`` holding only the
fields the filters need (x, y, z, intensity, return_number, number_of_returns, classification);
the full point records are streamed again chunk by chunk when the classified file is written,
so no more than one chunk of full records is in memory at a time.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import laspy
import numpy as np
import pyproj

from aerotri.core.atomic import atomic_path
from aerotri.core.errors import InputError
from aerotri.geom.crs import parse_crs

CHUNK_POINTS = 2_000_000
# Projected coordinates beyond these bounds are not an airborne survey on Earth.
MAX_ABS_XY_M = 1.0e8
MIN_Z_M, MAX_Z_M = -1000.0, 10000.0


@dataclasses.dataclass
class PointCloud:
    """Point attributes as flat arrays (one entry per point, file order)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    intensity: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    classification: np.ndarray
    crs: pyproj.CRS | None = None

    def __len__(self) -> int:
        return len(self.x)

    @property
    def xyz(self) -> np.ndarray:
        return np.column_stack([self.x, self.y, self.z])


def _open(path):
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
        return laspy.open(path)
    except Exception as exc:  # laspy raises several types for broken headers
        raise InputError(f"{path}: unreadable LAS header ({exc})") from exc


def resolve_crs(path, header: laspy.LasHeader, crs_arg: str | int | None) -> pyproj.CRS:
    """CRS from the file's VLRs, else from ``crs_arg`` (``EPSG:xxxx`` or a code); never guessed."""
    try:
        file_crs = header.parse_crs()
    except Exception as exc:
        raise InputError(f"{path}: CRS record present but unreadable ({exc}); pass --crs") from exc
    if file_crs is not None:
        if file_crs.is_compound:
            # Keep the horizontal part: rasters and downstream code work in the projected CRS.
            horizontal = [c for c in file_crs.sub_crs_list if c.is_projected or c.is_geographic]
            if horizontal:
                file_crs = horizontal[0]
        return file_crs
    if crs_arg is None or str(crs_arg).strip() == "":
        raise InputError(
            f"{path}: the file has no CRS record; give the CRS with --crs EPSG:<code> (it is never guessed)"
        )
    crs = parse_crs(crs_arg, "--crs")
    if not crs.is_projected:
        raise InputError(f"--crs {crs_arg!r}: expected a projected CRS in metres, got {crs.name}")
    return crs


def _validate_xyz(path, x, y, z, first_index: int) -> None:
    bad = ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(z))
    bad |= (np.abs(x) > MAX_ABS_XY_M) | (np.abs(y) > MAX_ABS_XY_M) | (z < MIN_Z_M) | (z > MAX_Z_M)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"{path}: point record {first_index + i}: absurd or non-finite coordinates "
            f"({x[i]!r}, {y[i]!r}, {z[i]!r}); expected |x|,|y| <= {MAX_ABS_XY_M:g} m and "
            f"{MIN_Z_M:g} <= z <= {MAX_Z_M:g} m"
        )


def iter_chunks(path, chunk_points: int = CHUNK_POINTS):
    """Yield (first_index, laspy.ScaleAwarePointRecord) chunks; errors name the record."""
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
            raise InputError(
                f"{path}: truncated or corrupt point data near record {done} of {n} ({exc})"
            ) from exc
        if done != n:
            raise InputError(f"{path}: truncated file: header says {n} points, read {done}")


def read_header(path) -> laspy.LasHeader:
    with _open(path) as reader:
        return reader.header


def read_cloud(path, crs: str | int | None = None, require_crs: bool = True,
               chunk_points: int = CHUNK_POINTS, keep_records: bool = False):
    """Read the filter attributes of a LAS/LAZ file in chunks, validated.

    ``crs`` is used only when the file has no CRS record; with ``require_crs`` a file without any
    CRS is an InputError. With ``keep_records`` also return the raw point records (list of chunks)
    so that ``write_classified`` need not decompress the input a second time (costs
    point-record-size bytes per point, e.g. 30 for format 6).
    """
    header = read_header(path)
    n = header.point_count
    if n == 0:
        raise InputError(f"{path}: the file holds no points")
    resolved = resolve_crs(path, header, crs) if (require_crs or crs is not None) else _try_crs(header)
    x = np.empty(n)
    y = np.empty(n)
    z = np.empty(n)
    intensity = np.empty(n, np.uint16)
    rn = np.empty(n, np.uint8)
    nr = np.empty(n, np.uint8)
    cls = np.empty(n, np.uint8)
    records = []
    for first, chunk in iter_chunks(path, chunk_points):
        if keep_records:
            records.append(chunk)
        sl = slice(first, first + len(chunk))
        x[sl], y[sl], z[sl] = chunk.x, chunk.y, chunk.z
        _validate_xyz(path, x[sl], y[sl], z[sl], first)
        intensity[sl] = chunk.intensity
        rn[sl] = chunk.return_number
        nr[sl] = chunk.number_of_returns
        cls[sl] = chunk.classification
    rn, nr = sanitize_returns(rn, nr)
    cloud = PointCloud(x, y, z, intensity, rn, nr, cls, resolved)
    return (cloud, records) if keep_records else cloud


def sanitize_returns(return_number: np.ndarray, number_of_returns: np.ndarray):
    """Broken return counts (0) would mislead the multi-return rules: treat them as single returns."""
    rn = np.where(return_number == 0, 1, return_number).astype(np.uint8)
    return rn, np.maximum(number_of_returns, rn).astype(np.uint8)


def validate_xyz(path, x, y, z, first_index: int) -> None:
    """InputError naming the record (``first_index`` + position) for NaN or absurd coordinates."""
    _validate_xyz(path, x, y, z, first_index)


def output_header(header: laspy.LasHeader, crs: pyproj.CRS | None = None) -> laspy.LasHeader:
    """Copy of an input header for a derived file: same version, point format (with extra bytes),
    scales, offsets, VLRs, EVLRs, system identifier, software, date and GUID; a CRS record is added
    when ``crs`` is given and the input has none. Counts and bounds are set by the writer."""
    out = copy.deepcopy(header)
    if crs is not None and _try_crs(header) is None:
        out.add_crs(crs)
    return out


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
