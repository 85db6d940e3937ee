"""Rasters across datums and projections: DEM/DSM heights and orthophoto images (``aerotri crs warp``).

The destination grid is north-up in the target CRS, snapped to multiples of the cell size, and covers
the source's footprint. It is filled block by block (memory bounded by the block size, whatever the
raster size): each block's pixel centres are mapped back into the source CRS by the inverse of the
coordinate operation (``aerotri.geom.crs.transform``: the toolkit's one policy, so a datum change needs
a parameter set or is refused), interpolated from anchors within 1 mm, and the source is resampled
there (``aerotri.geom.crs.raster_warp``). For height rasters the values change too: Z' = Z transformed at
its place (a datum shift moves ellipsoidal heights by up to several metres; a height anomaly model
turns them into normal heights). Nodata stays nodata (never interpolated into valid cells). The
result is a Cloud-Optimised GeoTIFF with the operation in its metadata.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path

import numpy as np
import rasterio
import rasterio.shutil
from rasterio.windows import Window

from aerotri.core.atomic import atomic_path, refuse_input_as_output, scratch_dir
from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.core.limits import check_disk
from aerotri.core.log import progress
from aerotri.geom.crs.definition import (check_stored_crs, crs_label, geotiff_crs, height_unit_m, horizontal_crs,
                               length_in_units, length_unit_name, linear_unit_m, parse_crs, same_horizontal,
                               unit_long_name, unit_name)
from aerotri.geom.inputs import check_height_values
from aerotri.geom.crs.raster_warp import (RESAMPLING, anchor_grid, cast_to_dtype, height_change, interpolate_anchors,
                                         open_north_up, read_on_grid)
from aerotri.geom.crs.transform import CrsTransformer

log = logging.getLogger(__name__)

KINDS = ("auto", "height", "image")


@dataclasses.dataclass
class WarpResult:
    path: Path
    kind: str
    width: int
    height: int
    res: float
    crs: str
    operation: dict
    valid_fraction: float
    height_change_m: tuple[float, float] | None = None  # smallest and largest change of a height cell (m)


def _open(path):
    return open_north_up(path, "raster", no_crs_hint="; give it one (e.g. gdal_edit.py -a_srs) before warping")


def _footprint(ds, operation: CrsTransformer, per_side: int = 64):
    """Target-CRS bounds of the source raster's outline (densified edges)."""
    b = ds.bounds
    t = np.linspace(0.0, 1.0, per_side)
    x = np.concatenate([b.left + (b.right - b.left) * t, np.full(per_side, b.right),
                        b.right - (b.right - b.left) * t, np.full(per_side, b.left)])
    y = np.concatenate([np.full(per_side, b.top), b.top - (b.top - b.bottom) * t,
                        np.full(per_side, b.bottom), b.bottom + (b.top - b.bottom) * t])
    X, Y, _ = operation.transform(x, y)
    return float(X.min()), float(Y.min()), float(X.max()), float(Y.max())


def warp_raster(in_path, out_path, to_crs, *, from_crs=None, params=None, heights=None, allow_ballpark=False,
                res_m=None, res_deg=None, kind: str = "auto", resampling: str = "bilinear",
                block_px: int = 1024) -> WarpResult:
    """Reproject a GeoTIFF into ``to_crs`` through the coordinate-operation policy (see module docstring).

    ``params``: a ``Transformation`` (``aerotri crs fit``), ``heights``: a ``HeightAnomalyModel``;
    ``res_m``: target cell size in metres for a projected target (converted to its unit: 0.3048 is 1 ft
    on a grid in feet), ``res_deg`` in degrees for a geographic one (default: the source cell size converted
    through the linear units); ``kind``: ``height`` (values are heights and change with the datum),
    ``image``, or ``auto`` (one floating-point band: height). Writes a COG atomically."""
    in_path, out_path = Path(in_path), Path(out_path)
    refuse_input_as_output(out_path, [in_path], "OUT")
    if kind not in KINDS:
        raise OptionError(f"--kind {kind!r}: expected one of {', '.join(KINDS)}", param="--kind")
    if resampling not in RESAMPLING:
        raise OptionError(f"--resampling {resampling!r}: expected one of {', '.join(RESAMPLING)}", param="--resampling")
    with _open(in_path) as ds:
        src_crs = parse_crs(from_crs, "--from") if from_crs else ds.crs
        dst_crs = parse_crs(to_crs, "--to")
        res, res_option = _target_cell(dst_crs, res_m, res_deg)
        if kind == "auto":
            kind = "height" if ds.count == 1 and np.dtype(ds.dtypes[0]).kind == "f" else "image"
        if kind == "height":  # before any work: finite, plausible heights in one band, not all nodata
            if ds.count != 1:
                raise InputError(f"{in_path}: --kind height needs one band of heights; the file has {ds.count}")
            check_height_values(ds, in_path, "height raster", height_unit_m(parse_crs(src_crs, "--from")))
        forward = CrsTransformer(src_crs, dst_crs, params=params, heights=heights, allow_ballpark=allow_ballpark)
        inverse = forward.inverse()
        src_res = abs(ds.transform.a)
        if res is None:
            f_src, f_dst = linear_unit_m(horizontal_crs(src_crs)), linear_unit_m(horizontal_crs(dst_crs))
            res = src_res * (f_src / f_dst if np.isfinite(f_src) and np.isfinite(f_dst) else 1.0)
        if params is None and same_horizontal(src_crs, dst_crs) and abs(res - src_res) <= 1e-12 * src_res:
            # only the heights change: keep the source grid cell for cell
            x0, y0, width, height = ds.transform.c, ds.transform.f, ds.width, ds.height
        else:
            left, bottom, right, top = _footprint(ds, forward)
            x0 = math.floor(left / res) * res
            y0 = math.ceil(top / res) * res
            width = int(math.ceil((right - x0) / res))
            height = int(math.ceil((y0 - bottom) / res))
        check_disk(width * height * ds.count * np.dtype(ds.dtypes[0]).itemsize, out_path.parent,
                   f"the target grid of {width} x {height} cells (uncompressed)", res_option,
                   hint=f"choose a coarser {res_option}")
        # the grid's corners and centre: where the stored CRS must put the grid as the requested one does
        gx = x0 + res * np.array([0.0, width, 0.0, width, width / 2.0])
        gy = y0 - res * np.array([0.0, 0.0, height, height, height / 2.0])
        far = _outside_area(dst_crs, gx, gy, in_path)
        out_crs = geotiff_crs(dst_crs, f"--to {to_crs}", gx, gy, 1e-3 * res)
        nodata = ds.nodata
        dtype = ds.dtypes[0]
        record = forward.record()
        profile = dict(driver="GTiff", width=width, height=height, count=ds.count, dtype=dtype, crs=out_crs,
                       transform=rasterio.transform.Affine(res, 0.0, x0, 0.0, -res, y0), tiled=True,
                       blockxsize=512, blockysize=512, compress="deflate", BIGTIFF="IF_SAFER")
        use_mask = nodata is None
        if not use_mask:
            profile["nodata"] = nodata
        blocks = [(r, c) for r in range(0, height, block_px) for c in range(0, width, block_px)]
        n_valid = 0
        z_src_m, z_dst_m = height_unit_m(parse_crs(src_crs, "--from")), height_unit_m(dst_crs)
        change = [np.inf, -np.inf]
        with scratch_dir(out_path.parent, out_path.name) as tmp_dir, rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
            stage = Path(tmp_dir) / "stage.tif"
            with rasterio.open(stage, "w", **profile) as dst, progress(len(blocks), "warp", "blocks") as bar:
                for r0, c0 in blocks:
                    h, w = min(block_px, height - r0), min(block_px, width - c0)
                    bx, by = x0 + c0 * res, y0 - r0 * res
                    data, valid = read_on_grid(ds, bx, by, res, (h, w), inverse, resampling=resampling, exact_taps=True)
                    if kind == "height" and valid.any():
                        z_new = _heights_through(data[0], valid, inverse, bx, by, res)
                        d = z_new[valid].astype(float) * z_dst_m - data[0][valid].astype(float) * z_src_m
                        change = [min(change[0], float(d.min())), max(change[1], float(d.max()))]
                        data[0] = z_new
                    n_valid += int(valid.sum())
                    win = Window(c0, r0, w, h)
                    out = cast_to_dtype(data, dtype)
                    if use_mask:
                        dst.write(out, window=win)
                        dst.write_mask(np.where(valid, 255, 0).astype(np.uint8), window=win)
                    else:
                        out[:, ~valid] = nodata
                        dst.write(out, window=win)
                    bar.update(1)
                dst.update_tags(COORDINATE_OPERATION=record["description"],
                                COORDINATE_OPERATION_JSON=json.dumps(record), SOURCE=str(in_path),
                                **_unit_tags(dst_crs, res, kind))
                if kind == "height":
                    z_unit = length_unit_name(height_unit_m(dst_crs), long=True)
                    dst.units = (z_unit,) * ds.count
                    dst.update_tags(1, HEIGHTS=f"transformed with the coordinate operation, in {z_unit}")
            if n_valid == 0:
                raise CrsError(f"{in_path}: no valid cell lands in the target grid of {crs_label(dst_crs)}")
            with atomic_path(out_path) as tmp:
                rasterio.shutil.copy(stage, tmp, driver="COG", COMPRESS="DEFLATE", BLOCKSIZE=512,
                                     OVERVIEWS="AUTO", BIGTIFF="IF_SAFER")
                with rasterio.Env(GDAL_PAM_ENABLED=False), rasterio.open(tmp) as written:  # as a reader sees it
                    check_stored_crs(dst_crs, written.crs, str(out_path), gx, gy, 1e-3 * res)
    for w in forward.warnings:
        if w != forward.heights_extrapolation_warning():  # the forward maps the bounds only: said by the inverse
            log.warning(w)
    if far:
        log.warning(far)
    w = inverse.heights_extrapolation_warning()  # the heights are evaluated through the inverse
    if w:
        log.warning(f"{in_path}: {w.replace('points', 'grid points sampled', 1)}")
    dz = (change[0], change[1]) if np.isfinite(change[0]) else None
    src_p = parse_crs(src_crs, "--from")
    if dz and params is None and heights is None and max(abs(dz[0]), abs(dz[1])) > 0.01 and len(src_p.axis_info) < 3:
        # the datum's change of ellipsoidal heights put on heights that may be above a geoid (NAP: +43.6 m in Delft)
        log.warning(f"{in_path}: the heights changed by {dz[0]:+.3f} to {dz[1]:+.3f} m: the raster declares no vertical "
                    f"CRS, so they were taken as ellipsoidal heights of {crs_label(src_p)} and moved with the datum; if "
                    "they are heights above a geoid (NAP, NAVD88, EGM2008 ...), give --from and --to with the vertical "
                    "CRS (EPSG:<code>+<vertical code>, e.g. EPSG:28992+5709) to keep them")
    return WarpResult(out_path, kind, width, height, float(res), crs_label(dst_crs), record,
                      n_valid / float(width * height), dz)


def _outside_area(dst_crs, gx, gy, in_path) -> str | None:
    """The warning for a target grid outside ``dst_crs``'s area of use (a zone not the data's: said, not refused, as
    point lists and LAS files are; a DEM into a Gauss-Kruger zone 12 deg away was written without a word, trial s96
    F9), or None."""
    from aerotri.core.errors import InputError
    from aerotri.geom.crs.definition import check_coordinates

    try:
        far = check_coordinates(dst_crs, gx, gy, str(in_path), ["the target grid's corner 1", "corner 2", "corner 3",
                                                                 "corner 4", "centre"], outside_area="warn",
                                swapped_hint=False)
    except InputError as exc:
        far = str(exc)
    return None if far is None else (f"{far}; written all the same: is --to {crs_label(dst_crs)} the grid meant (the "
                                     "zone, 3- or 6-degree, the central meridian)?")


def _target_cell(dst_crs, res_m, res_deg) -> tuple[float | None, str]:
    """(the target cell size in the target CRS's unit, or None for the source's; the option that sets it):
    ``res_m`` (metres) for a projected target, converted to its unit; ``res_deg`` for a geographic one."""
    projected = horizontal_crs(dst_crs).is_projected
    given, option, other = (res_m, "--res-m", "--res-deg") if projected else (res_deg, "--res-deg", "--res-m")
    if (res_deg if projected else res_m) is not None:
        kind = "projected (a grid in its linear unit)" if projected else "geographic"
        raise OptionError(f"--to {crs_label(dst_crs)} is {kind}: give {option}, not {other}", param=other)
    if given is None:
        if not projected:
            raise OptionError(f"--to {crs_label(dst_crs)} is geographic: give the cell size with --res-deg",
                              param="--res-deg")
        return None, option
    if not (given > 0 and math.isfinite(given)):
        raise OptionError(f"{option} {given}: must be a positive cell size", param=option)
    return (length_in_units(given, linear_unit_m(dst_crs)) if projected else float(given)), option


def _unit_tags(crs, res: float, kind: str) -> dict:
    """The units a reader needs, from the CRS (as ``lidarctl rasters`` writes them): LINEAR_UNITS and the
    cell size, and for height rasters VERTICAL_UNITS, the unit the height values are in (a 2D foot grid:
    feet, converted from the source's unit by the operation; a compound CRS: its vertical unit)."""
    tags = {"LINEAR_UNITS": unit_long_name(crs), "CELL_SIZE": f"{res:.10g} {unit_name(crs)}"}
    if horizontal_crs(crs).is_projected:
        tags["CELL_SIZE_M"] = f"{res * linear_unit_m(crs):.10g}"
    if kind == "height":
        tags["VERTICAL_UNITS"] = length_unit_name(height_unit_m(crs), long=True)
    return tags


def _heights_through(z: np.ndarray, valid: np.ndarray, inverse: CrsTransformer, x_left, y_top, res) -> np.ndarray:
    """Target heights from source heights ``z`` sampled at the block's pixels: with the inverse operation's
    height change z_src = z_dst + dz0 + k z_dst (on anchors of the target block), z_dst = (z_src - dz0) / (1 + k)."""
    rows, cols = z.shape
    v = z[valid]
    zlo, zhi = float(v.min()), float(v.max())

    def change(x, y):
        dz0, k = height_change(inverse, x, y, zlo, zhi)
        return dz0.reshape(np.shape(x)), k.reshape(np.shape(x))

    D0, K, s = anchor_grid(change, x_left, y_top, res, cols, rows, spacing_px=64, tolerance=1e-4)
    dz0 = interpolate_anchors(D0, s, rows, cols)
    k = interpolate_anchors(K, s, rows, cols)
    return np.where(valid, (z - dz0) / (1.0 + k), z).astype(np.float32)

