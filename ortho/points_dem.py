"""A DEM from the adjusted tie points (``ortho dem PROJECT``), for blocks with no DEM from elsewhere (no LiDAR).

The adjusted object points (``at/object_points.csv``, tie points seen in at least ``min_rays`` frames) are
binned into a north-up grid in the project CRS:

1. outliers out: a point whose height is more than 3 robust sigmas (at least ``min_tolerance_m``) from the
   median of its 3 x 3 cell neighbourhood is dropped (wrong matches, moving objects, points on thin poles);
2. each cell takes the median height of its points;
3. empty cells inside the points' hull are interpolated linearly between the filled cells (Delaunay), and cells
   outside it, up to the frames' footprints, take the height of the nearest filled cell: the frames' edges reach
   beyond the tie points, and a flat continuation is the best guess there (the console, ``<out>.json`` and the
   GeoTIFF's tags give their share, the farthest one's distance and how far the grid reaches beyond the points to
   the north, east, south and west; a warning when they are more than half of the DEM).

The result is a surface of the visible tops (roofs, trees: a DSM where the tie points are on them), as dense as
the tie points; its heights are those of the adjustment (relative ones when the control had no heights). Written
as a Cloud-Optimized GeoTIFF (float32, nodata -9999) in the project CRS.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path

import numpy as np

from aerotri.core.atomic import atomic_path, refuse_input_as_output, write_text_atomic
from aerotri.core.errors import InputError, OptionError

_log = logging.getLogger(__name__)
# Fewer tie points a frame than this and the DEM shows the plane through them, not the ground's relief
# (Tuniu with --min-rays 3: 3 points for a block of frames).
MIN_POINTS_PER_FRAME = 10
from aerotri.core.project import Project
from aerotri.geom.crs.definition import project_crs
from ortho.tie_points import read_tie_points, read_tie_points_with_rays

NODATA = -9999.0
POINTS_DEM_VERSION = 1  # the chain's dem stage stamp: bump when at/dem.tif changes at the same tie points and EO


@dataclasses.dataclass(frozen=True)
class PointsDem:
    """A height grid: ``heights_m`` (rows, cols) north up, NaN nodata, cell ``res_m``, top-left corner."""

    heights_m: np.ndarray
    x_left_m: float
    y_top_m: float
    res_m: float
    n_points: int  # points used
    n_outliers: int  # points dropped as outliers
    cells_measured: int  # cells with points
    cells_interpolated: int  # empty cells inside the points' hull
    cells_extrapolated: int  # cells outside it, within the footprints
    # where the extended cells are: the farthest one's distance from a cell of the data (measured or interpolated),
    # and how far the grid reaches beyond the data's extent to the north, east, south and west (m)
    extrapolated_max_distance_m: float = 0.0
    extended_beyond_nesw_m: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


def _cell_index(x, y, x0, y0, res, shape):
    col = np.floor((x - x0) / res).astype(int)
    row = np.floor((y0 - y) / res).astype(int)
    return row, col


def _neighbourhood_median(z_cell: np.ndarray) -> np.ndarray:
    """Median of the finite cells of each 3 x 3 neighbourhood (NaN where none)."""
    h, w = z_cell.shape
    pad = np.pad(z_cell, 1, constant_values=np.nan)
    stack = np.stack([pad[r:r + h, c:c + w] for r in range(3) for c in range(3)])
    with np.errstate(all="ignore"):
        out = np.full((h, w), np.nan)
        has = np.isfinite(stack).any(axis=0)
        out[has] = np.nanmedian(stack[:, has], axis=0)
    return out


def _cell_medians(row, col, z, shape) -> np.ndarray:
    """Median of ``z`` per cell (NaN for empty cells)."""
    flat = row * shape[1] + col
    order = np.lexsort((z, flat))
    f, zs = flat[order], z[order]
    starts = np.r_[0, np.flatnonzero(np.diff(f)) + 1]
    ends = np.r_[starts[1:], len(f)]
    out = np.full(shape[0] * shape[1], np.nan)
    lo, hi = zs[starts + (ends - starts - 1) // 2], zs[starts + (ends - starts) // 2]
    out[f[starts]] = 0.5 * (lo + hi)
    return out.reshape(shape)


def points_dem(xyz_m: np.ndarray, res_m: float, bounds=None, min_tolerance_m: float = 0.1) -> PointsDem:
    """The robust grid of ``xyz_m`` (N, 3) at ``res_m`` (see the module docstring) over ``bounds`` (x0, y0, x1, y1;
    default: the points' extent), filled inside the points' hull and extended by the nearest filled cell outside."""
    from scipy.interpolate import LinearNDInterpolator
    from scipy.ndimage import distance_transform_edt
    from scipy.spatial import QhullError

    p = np.asarray(xyz_m, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 3:
        raise InputError(f"{len(p)} adjusted tie points: too few for a DEM (need at least 3)")
    if not (math.isfinite(res_m) and res_m > 0):
        raise OptionError(f"DEM cell size {res_m!r}: expected a positive number of metres", param="--res-m")
    x0, y0, x1, y1 = bounds if bounds is not None else (p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max())
    x0, y0 = min(x0, p[:, 0].min()), min(y0, p[:, 1].min())
    x1, y1 = max(x1, p[:, 0].max()), max(y1, p[:, 1].max())
    x0, y1 = math.floor(x0 / res_m) * res_m, math.ceil(y1 / res_m) * res_m  # cells on multiples of res_m
    shape = (int(math.ceil((y1 - y0) / res_m)) + 1, int(math.ceil((x1 - x0) / res_m)) + 1)
    if shape[0] * shape[1] > 200_000_000:
        raise OptionError(f"DEM of {shape[1]} x {shape[0]} cells at {res_m} m: too large; give a larger cell size",
                          param="--res-m")
    row, col = _cell_index(p[:, 0], p[:, 1], x0, y1, res_m, shape)
    z = p[:, 2]
    # 1. outliers against the neighbourhood's median
    first = _cell_medians(row, col, z, shape)
    ref = _neighbourhood_median(first)[row, col]
    dev = z - ref
    mad = 1.4826 * np.median(np.abs(dev[np.isfinite(dev)])) if np.isfinite(dev).any() else 0.0
    keep = np.abs(dev) <= max(3.0 * mad, min_tolerance_m)
    # 2. cell medians of the kept points
    grid = _cell_medians(row[keep], col[keep], z[keep], shape)
    measured = np.isfinite(grid)
    # 3. inside the hull: linear between the measured cells; outside: the nearest measured cell
    rr, cc = np.nonzero(measured)
    empty = ~measured
    n_interp = 0
    if empty.any() and len(rr) >= 3:
        try:
            lin = LinearNDInterpolator(np.column_stack([rr, cc]), grid[measured])
            er, ec = np.nonzero(empty)
            v = lin(np.column_stack([er, ec]))
            ok = np.isfinite(v)
            grid[er[ok], ec[ok]] = v[ok]
            n_interp = int(ok.sum())
        except QhullError:  # the points on one line: no hull, only the nearest cell
            pass
    still = ~np.isfinite(grid)
    far_m, beyond = 0.0, (0.0, 0.0, 0.0, 0.0)
    if still.any():
        dist, (ir, ic) = distance_transform_edt(still, return_indices=True)
        grid[still] = grid[ir[still], ic[still]]
        far_m = float(dist[still].max() * res_m)
        dr, dc = np.nonzero(~still)  # the data's extent in cells
        beyond = tuple(float(v * res_m) for v in (dr.min(), shape[1] - 1 - dc.max(), shape[0] - 1 - dr.max(), dc.min()))
    return PointsDem(grid.astype(np.float32), float(x0), float(y1), float(res_m), int(keep.sum()), int((~keep).sum()),
                     int(measured.sum()), n_interp, int(still.sum()), far_m, beyond)


def default_resolution(xyz_m: np.ndarray, points_per_cell: float = 4.0) -> float:
    """A cell size holding about ``points_per_cell`` points where the points are (nice number, metres)."""
    from scipy.spatial import ConvexHull

    from ortho.grid import nice_resolution

    try:
        area = ConvexHull(xyz_m[:, :2]).volume  # in 2D, the area
    except Exception:  # noqa: BLE001 - qhull on degenerate input: the bounding box
        area = float(np.ptp(xyz_m[:, 0]) * np.ptp(xyz_m[:, 1]))
    return nice_resolution(max(math.sqrt(points_per_cell * max(area, 1e-6) / len(xyz_m)), 1e-3))


def _footprint_bounds(root: Path, z_lo_m: float, z_hi_m: float, margin_m: float = 0.0):
    """Bounds (x0, y0, x1, y1) of the adjusted frames' footprints between the planes at ``z_lo_m`` and ``z_hi_m``,
    widened by ``margin_m``."""
    from ortho.block import _plane_footprint_bounds, load_block

    block = load_block(root)
    b = np.array([_plane_footprint_bounds(block.camera, block.eo.centre_m[i], block.eo.rotation(i), z_lo_m, z_hi_m, iid,
                                          crs=block.project_crs) for i, iid in enumerate(block.eo.image_id)])
    return (float(b[:, 0].min()) - margin_m, float(b[:, 1].min()) - margin_m, float(b[:, 2].max()) + margin_m,
            float(b[:, 3].max()) + margin_m)


def _n_frames(project) -> int:
    from aerotri.geom.eo import read_eo

    return len(read_eo(project.eo_path).image_id)


def chain_min_rays(root) -> int:
    """The chain's ``min_rays`` (``aerotri run`` has no option for it): 3, or 2 where the tie points seen in three
    frames or more are too few to follow the ground (``MIN_POINTS_PER_FRAME`` a frame) and those seen in two are not
    (docs/your-own-block.md's advice for a few obliques; trial s98: Tuniu's 4 frames, 14 points in three frames, a
    plane under the orthophotos, and no way to give ``--min-rays 2`` to ``aerotri run``)."""
    project = Project.open(root)
    _, rays = read_tie_points_with_rays(project.object_points_path)
    enough = MIN_POINTS_PER_FRAME * _n_frames(project)
    return 2 if np.sum(rays >= 3) < enough <= np.sum(rays >= 2) else 3


def _warn_if_sparse(project, n_points: int, min_rays: int) -> None:
    n_frames = _n_frames(project)
    if n_points < MIN_POINTS_PER_FRAME * n_frames:
        _log.warning(f"{project.object_points_path}: {n_points} tie points seen in {min_rays} or more frames for "
                     f"{n_frames} frames ({n_points / n_frames:.1f} a frame, fewer than {MIN_POINTS_PER_FRAME}): the "
                     f"DEM follows the plane through them, not the ground's relief; a lower --min-rays or a DEM from "
                     f"LiDAR would show more")


# the DEM's tag holding the share (%) of its cells extended beyond the tie points (the QA report's terrain class reads
# it: the slope of a flat continuation is no terrain's, ``aerotri.qa.terrain_class``)
EXTRAPOLATED_PERCENT_TAG = "CELLS_EXTRAPOLATED_PERCENT"


@dataclasses.dataclass(frozen=True)
class PointsDemResult:
    """``ortho dem``'s numbers (``<out>.json``, keys in field order): the COG, its grid (project CRS, cells of
    ``res_m``), the tie points used and dropped, the cells measured / interpolated / extended, the heights' range."""

    file: str
    crs: str
    res_m: float
    width: int
    height: int
    points: int
    outliers: int
    min_rays: int
    cells_measured: int
    cells_interpolated: int
    cells_extrapolated: int
    extrapolated_percent: float  # of all cells: filled beyond the data, a flat continuation of the nearest cell
    extrapolated_max_distance_m: float  # the farthest extended cell from the data
    extended_beyond_nesw_m: tuple[float, float, float, float]  # the grid beyond the data's extent: N, E, S, W
    height_range_m: tuple[float, float]
    source: str
    note: str = ("median height of the adjusted tie points per cell (3-sigma neighbourhood outliers out), linear "
                 "inside their hull, nearest cell outside it up to the frames' footprints")

    def to_json(self) -> str:
        """The ``<out>.json`` text."""
        return json.dumps(dataclasses.asdict(self), indent=1) + "\n"

    def extension_words(self) -> str:
        """What share of the DEM is extended beyond the tie points and where, in words."""
        sides = ", ".join(f"{name} {m:.0f} m" for name, m in zip(("north", "east", "south", "west"),
                                                                  self.extended_beyond_nesw_m) if m > 0)
        # the three counts together (new-user trial: "cells_measured=7" in the run's table beside "7474 of 7482
        # extended" read as two counts that disagree; the 8th cell is interpolated)
        return (f"{self.extrapolated_percent:.0f} % of the cells ({self.cells_extrapolated} of "
                f"{self.width * self.height}) extended beyond the tie points (the nearest cell's height, not measured), "
                f"up to {self.extrapolated_max_distance_m:.0f} m from them; {self.cells_measured} measured (holding "
                f"tie points), {self.cells_interpolated} interpolated between them"
                + (f"; the grid reaches {sides} beyond their extent" if sides else ""))


def _heights_words(project: Project) -> str:
    """The DEM's HEIGHTS tag: the project's heights, or relative ones when the adjustment measured none (its report's
    heights_measured; trial-kite: a plan-only block's dem.tif ran -0.05 .. 1.17 with nothing saying so)."""
    from aerotri.core.textio import read_json

    path = project.adjustment_report_path
    rep = read_json(path, "adjustment report") if path.is_file() else {}
    if rep.get("heights_measured", True) is False:
        return (f"relative: no height was measured (plan-only control, no GNSS or DEM; {path} DATUM); 0 at the control "
                "points' median ground")
    return f"the project's: {project.info.heights} ({project.config_path} [project] heights)"


def write_points_dem(root, out=None, res_m: float | None = None, min_rays: int = 3) -> PointsDemResult:
    """``ortho dem``: the DEM of the project's adjusted tie points as a COG (default ``at/dem.tif``) over the frames'
    footprints, and its numbers (``<out>.json``); returns them."""
    import rasterio
    from rasterio.shutil import copy as rio_copy
    from rasterio.transform import from_origin

    project = Project.open(root)
    crs = project_crs(project)
    pts = read_tie_points(project.object_points_path, min_rays)
    if len(pts) < 3:
        raise InputError(f"{project.object_points_path}: {len(pts)} tie points seen in {min_rays} or more frames: too "
                         "few for a DEM")
    _warn_if_sparse(project, len(pts), min_rays)
    res = float(res_m) if res_m is not None else default_resolution(pts)
    z = float(np.median(pts[:, 2]))
    dem = points_dem(pts, res, _footprint_bounds(project.root, z, z))
    # Again over the footprints between the lowest and highest heights of that DEM: a frame's edge ray meets a
    # lower ground farther out than on the median plane (Brighton: 1.2 m beyond it, where ortho rectify found no DEM)
    lo, hi = float(np.nanmin(dem.heights_m)), float(np.nanmax(dem.heights_m))
    dem = points_dem(pts, res, _footprint_bounds(project.root, lo, hi, margin_m=2.0 * res))
    out = Path(out) if out is not None else project.at_dir / "dem.tif"
    refuse_input_as_output(out, [project.object_points_path, project.eo_path, project.camera_path], option="--out")
    refuse_input_as_output(out.with_suffix(".json"), [project.object_points_path, project.eo_path], option="--out")
    transform = from_origin(dem.x_left_m, dem.y_top_m, dem.res_m, dem.res_m)
    data = np.where(np.isfinite(dem.heights_m), dem.heights_m, NODATA).astype(np.float32)
    profile = dict(driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype="float32", crs=crs,
                   transform=transform, nodata=NODATA)
    stats = PointsDemResult(
        file=str(out), crs=project.crs, res_m=dem.res_m, width=int(data.shape[1]), height=int(data.shape[0]),
        points=dem.n_points, outliers=dem.n_outliers, min_rays=min_rays, cells_measured=dem.cells_measured,
        cells_interpolated=dem.cells_interpolated, cells_extrapolated=dem.cells_extrapolated,
        extrapolated_percent=round(100.0 * dem.cells_extrapolated / data.size, 1),
        extrapolated_max_distance_m=round(dem.extrapolated_max_distance_m, 2),
        extended_beyond_nesw_m=tuple(round(v, 2) for v in dem.extended_beyond_nesw_m),
        height_range_m=(float(np.nanmin(dem.heights_m)), float(np.nanmax(dem.heights_m))),
        source=str(project.object_points_path))
    with rasterio.MemoryFile() as mem:
        with mem.open(**profile) as ds:
            ds.write(data, 1)
            ds.set_band_description(1, "height of the adjusted tie points (median per cell)")
            ds.update_tags(SOURCE="aerotri adjusted tie points (ortho dem)", CELLS_MEASURED=str(dem.cells_measured),
                           CELLS_INTERPOLATED=str(dem.cells_interpolated),
                           CELLS_EXTRAPOLATED=str(dem.cells_extrapolated),
                           **{EXTRAPOLATED_PERCENT_TAG: f"{stats.extrapolated_percent:.1f}"},
                           EXTRAPOLATED_MAX_DISTANCE_M=f"{stats.extrapolated_max_distance_m:.2f}",
                           EXTENDED_BEYOND_NESW_M=" ".join(f"{v:.2f}" for v in stats.extended_beyond_nesw_m),
                           EXTRAPOLATION=stats.extension_words(), HEIGHTS=_heights_words(project))
        with mem.open() as src, atomic_path(out) as tmp:
            rio_copy(src, tmp, driver="COG", compress="DEFLATE", predictor=3, overview_resampling="average")
    write_text_atomic(out.with_suffix(".json"), stats.to_json())
    if 2 * stats.cells_extrapolated > data.size:  # most of the DEM is no measurement
        _log.warning(f"{out}: most of this DEM ({stats.extrapolated_percent:.0f} % of the cells, up to "
                     f"{stats.extrapolated_max_distance_m:.0f} m from the tie points) is a flat continuation beyond "
                     "them: orthophotos there stand on no measured height (a DEM from LiDAR"
                     + (", or --min-rays 2, " if min_rays > 2 else " ") + "reaches farther)")
    return stats
