"""Orthorectification of one frame by back-projection (ground -> image) onto a height raster.

For every pixel of the output grid (processed in tiles): the ground position in the project CRS
(interpolated from an anchor grid of the output->project CRS transform, exact for an identical CRS; affine per
tile where that holds, ``GridToProject.affine``, so a contract CRS's tiles take the vectorised kernels too),
the height bilinearly from the DEM (or DSM for a true ortho), the collinearity equations with the
camera's lens model (``aerotri.geom.lens_kernels``, inlined into the kernels here) to image coordinates,
the point reaching the camera through the ENU frame at the projection centre as the orientations mean it
(``FrameGeometry.earth``: scale factor, (R + h) / R, convergence and the earth's curvature; a projected CRS is
not Cartesian), then ``cv2.remap`` (bilinear default, cubic or Lanczos) with fixed-point maps written directly by the
kernel. Pixels outside the frame, behind the camera or over DEM nodata are invalid (mask 0, value 0).

The collinearity is evaluated exactly at every output pixel in a compiled, vectorised kernel (about
300 MP/s per core on AVX-512): cheaper than interpolating image coordinates from a coarse anchor
grid, and unlike that interpolation it stays exact where the DEM is rough (relief displacement
reaches several pixels per metre of height at the edge of a large-format frame), so the only mapping
error is cv2.remap's own 1/32 px quantisation (<= 0.022 px), not merely < 0.1 px.

Speed: tiles (1024 px) run on threads (the numba kernels and cv2.remap release the GIL; each kernel
is serial, so there is one level of parallelism and no competing thread pools), map buffers are
reused per thread and output tiles come from a pool (fresh arrays cost a page fault per 4 KiB), and
with a ``sink`` the caller writes tile k while the threads compute the next ones. 8-bit frames with
rows of 32 KiB or more (3-band frames wider than 10,922 px, e.g. the DMC) are resampled from a copy
of the window each tile reads, which keeps cv2.remap on its vectorised path (``SourceWindow``).

True ortho: with ``occlusion_dsm`` every ground point is tested for visibility by marching along its
ray towards the projection centre over the DSM; occluded pixels are invalid (mask 0), so the mosaic
fills them from other frames.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import math
import queue
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, NamedTuple

import cv2
import numpy as np

from aerotri.core.limits import usable_cores
from aerotri.core.errors import InputError
from aerotri.geom.rotation import FLIP_YZ
from aerotri.geom.local_frame import CameraOnEarth, FramesOnEarth
from ortho.grid import GridAffine, GridToProject, OrthoGrid

# the compiled kernels (numba) live in ortho.rectify_kernels, imported by the functions that run them; the
# camera (whose lens model is compiled too) and height rasters are arguments here, not imports
if TYPE_CHECKING:
    from aerotri.geom.camera import Camera
    from ortho.dem import HeightRaster
    from ortho.footprints import FootprintOccluder, OutlineHeights

# The version of a frame's orthorectification (this module's kernels, the true ortho's visibility): a frame's
# resume key (``ortho.block._resume_key``) and the chain's rectify stamp hold it, so frames kept (and stages stamped)
# before a change of a frame's samples are rectified again. Bump it when a frame ortho changes at the same inputs and
# settings. 1: resume-keys (the rectification as of main 195def90). 2: contract-crs-speed (a contract CRS's tiles
# affine in the project's: its true ortho's z-buffer fills the gaps of walls as the project CRS's does, 0.09 % more
# hidden ground masked on a DMC frame; the project CRS's orthos are unchanged). 3 (one bump for the session of
# 2026-12-01, in every CRS): trial-ortho and s28-fixes (a frame's own nodata, its collar, nodata in its ortho: frames
# declaring a nodata value, an internal mask or alpha), jpeg-decode (JPEG-compressed TIFF frames decoded by GDAL in
# every path) and slope-occlusion (the march takes continuous surface as its bilinear one, ``WALL_SLOPE_DEG``: true
# orthos mask less on slopes; s30-fixes: over the ground alone, ``ground_cells``, objects keep their columns).
RECTIFY_VERSION = 3
# the last version that changed the orthos of a grid in the project's CRS (``operation`` None): versions after it
# changed a contract CRS's alone, and a project rectified in its own CRS keeps its frames (no re-rectification)
PROJECT_CRS_RECTIFY_VERSION = 3


def rectify_version(contract_crs: bool) -> int:
    """The version of the rectification whose frame orthos are the same bytes: ``RECTIFY_VERSION`` for an output
    grid in another CRS than the project's, ``PROJECT_CRS_RECTIFY_VERSION`` in the project's own."""
    return RECTIFY_VERSION if contract_crs else PROJECT_CRS_RECTIFY_VERSION

INTERPOLATION = {"nearest": cv2.INTER_NEAREST, "bilinear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "lanczos": cv2.INTER_LANCZOS4}


class RayLimits(NamedTuple):
    """Which rays of a frame the kernels image (``ortho.rectify_kernels._within_limits``, beside "in front of the
    camera"): ``fold_r2``, the square of the normalised radius where the lens model folds (``Camera.fold_radius``;
    inf: it does not), and ``tan2_vertical``, the square of the tangent of the largest angle from the vertical
    (inf: no limit). Beyond the fold the model turns back and ground far outside the field of view lands inside
    the frame (wedges of smeared corner pixels round an oblique drone block's mosaic, and in a true ortho's
    z-buffer surfaces in front of ground they do not hide), so that limit always applies."""

    fold_r2: float
    tan2_vertical: float


# -- the kernels' argument groups (``ortho.rectify_kernels`` reads their fields by name) -------------------------
class HeightGrid(NamedTuple):
    """A DEM or DSM as the kernels take it: heights (float32 (rows, cols), NaN nodata), its top-left corner and cell
    size in the project CRS."""

    heights_m: np.ndarray
    x_left_m: float
    y_top_m: float
    res_m: float


class AnchorGrid(NamedTuple):
    """A tile's project coordinates (float64 (rows, cols) each) at every ``spacing_px``-th output pixel
    (``GridToProject.anchors``), interpolated bilinearly between them."""

    x_m: np.ndarray
    y_m: np.ndarray
    spacing_px: float


class AffineTile(NamedTuple):
    """A tile of an output grid whose ground X, Y (project CRS) are affine in (row, col): the heights at its cell
    centres (float32 (rows, cols)), the first (top-left) cell centre and the ground steps of a column and of a row
    (m; the project grid's own tile: (res, 0) and (0, -res); a contract CRS's: ``ortho.grid.GridAffine``)."""

    heights_m: np.ndarray
    x0_m: float
    y0_m: float
    col_dx_m: float
    col_dy_m: float
    row_dx_m: float
    row_dy_m: float


class FrameArgs(NamedTuple):
    """A frame as the kernels take it: projection centre (3,), the object -> computer-vision camera matrix M
    (``CameraOnEarth.M``; (R @ FLIP_YZ).T in a Cartesian CRS), the camera's kernel parameters
    (``Camera.kernel_params()``), the frame's size, its ``RayLimits`` and the earth's 1 / radius (``earth_dz``; 0: the
    flat collinearity)."""

    centre_m: np.ndarray
    M: np.ndarray
    cam: tuple
    width_px: int
    height_px: int
    limits: RayLimits
    inv_radius: float = 0.0


class RemapMaps(NamedTuple):
    """What the fixed-point kernels write: cv2.remap's maps (int16 (rows, cols, 2), uint16 (rows, cols)), the
    validity mask (uint8 255/0) and the integer bounds of the imaged positions (int32 [4])."""

    map_int: np.ndarray
    map_frac: np.ndarray
    mask: np.ndarray
    bounds: np.ndarray


class ZBufferArgs(NamedTuple):
    """A z-buffer as the kernels take it (``ZBuffer``): depth per cell (float32), cell size (px), tolerance (m)."""

    depth_m: np.ndarray
    cell_px: int
    tolerance_m: float


class MarchArgs(NamedTuple):
    """The march's bounds (``MarchBound``) and settings: the highest DSM height, the highest heights by blocks of
    ``block`` and of ``coarse`` cells, the tolerance (m), ``OWN_COLUMN_M``, the rise between neighbouring DSM
    cells beyond which they are a wall (m, ``WALL_SLOPE_DEG``) and which cells are the ground (uint8 per DSM cell,
    ``ground_cells``; (1, 1): none is), the only ones continuous surface joins."""

    max_m: float
    block_max_m: np.ndarray
    block: int
    coarse_max_m: np.ndarray
    coarse: int
    tolerance_m: float
    own_column_m: float
    wall_rise_m: float
    ground: np.ndarray


class FootprintWalls(NamedTuple):
    """Building footprints as the march takes them (``ortho.footprints.FootprintOccluder``): the underside and top
    of each DSM cell's slab (float32, -inf: none, a solid column), the index of its sub-cell mask (int32, -1: none;
    <= -3: beside an overhang), the sub-cell masks (uint8 (K, sub, sub): bit 1 wall, 2 slab, 4 the whole cell's
    slab), ``sub`` and the sub-cells' margins within the roof outline (int16 (K, sub, sub), cm); (1, 1) arrays: no
    footprints nor crowns."""

    base_m: np.ndarray
    slab_top_m: np.ndarray
    sub_index: np.ndarray
    sub_masks: np.ndarray
    sub: int
    sub_margin_cm: np.ndarray


_NO_WALLS = FootprintWalls(np.full((1, 1), -np.inf, np.float32), np.full((1, 1), -np.inf, np.float32),
                           np.full((1, 1), -1, np.int32),
                           np.zeros((1, 1, 1), np.uint8), 1, np.zeros((1, 1, 1), np.int16))
_NO_GROUND = np.zeros((1, 1), np.uint8)  # ``MarchArgs.ground``: no cell is the ground


class TilePoints(NamedTuple):
    """The points of a tile the march tests: their heights (float32 (rows, cols)), which to test (bool), and the
    z-buffer's hint (``near_share``, float32 like the tile, or (1, 1) for none)."""

    heights_m: np.ndarray
    candidates: np.ndarray
    near_share: np.ndarray


def _height_grid(raster: HeightRaster) -> HeightGrid:
    return HeightGrid(raster.heights_m, raster.x_left_m, raster.y_top_m, raster.res_m)


def _affine_tile(heights_m: np.ndarray, grid: OrthoGrid, affine: GridAffine | None = None) -> AffineTile:
    """``grid``'s tile as the affine kernels take it: in the project CRS, or (``affine``) a contract CRS's."""
    if affine is None:
        return AffineTile(heights_m, grid.x_left_m + 0.5 * grid.res_m, grid.y_top_m - 0.5 * grid.res_m, grid.res_m,
                          0.0, 0.0, -grid.res_m)
    return AffineTile(heights_m, affine.x0_m, affine.y0_m, affine.col_dx_m, affine.col_dy_m, affine.row_dx_m,
                      affine.row_dy_m)


@dataclasses.dataclass
class FrameGeometry:
    """The per-frame inputs of the back-projection; cells whose ray to the projection centre is more than
    ``max_view_angle_deg`` from the vertical (90: no limit) are not imaged.

    ``earth`` (``aerotri.geom.local_frame.CameraOnEarth``): project-CRS points reach the camera through the ENU frame
    at the centre, as the adjustment computed the orientations and the simulator renders them (a projected CRS is
    not Cartesian: at the presets' origin the flat collinearity puts the ground 400 ppm too near the nadir, 2.8 px
    700 m from it at 0.1 m GSD). None: map coordinates taken as a Cartesian frame (exact for an engineering CRS)."""

    camera: Camera
    centre_m: np.ndarray
    R: np.ndarray
    max_view_angle_deg: float = 90.0
    earth: CameraOnEarth | None = None

    def kernel_args(self):
        cam = self.camera
        M = np.ascontiguousarray((np.asarray(self.R, float) @ FLIP_YZ).T) if self.earth is None else self.earth.M
        return np.asarray(self.centre_m, dtype=np.float64), M, cam.kernel_params()

    def fold_r2(self) -> float:
        """The square of the lens fold's normalised radius (inf: the model does not fold)."""
        fold = self.camera.fold_radius()
        return math.inf if fold is None else fold * fold

    def ray_limits(self) -> RayLimits:
        """The kernels' limits of this frame's rays: the lens fold and ``max_view_angle_deg``."""
        tan2 = math.tan(math.radians(self.max_view_angle_deg)) ** 2 if self.max_view_angle_deg < 90.0 else math.inf
        return RayLimits(self.fold_r2(), tan2)

    def kernel_frame(self) -> FrameArgs:
        """The frame as the kernels take it."""
        centre, M, params = self.kernel_args()
        return FrameArgs(centre, M, params, self.camera.width, self.camera.height, self.ray_limits(),
                         0.0 if self.earth is None else self.earth.inv_radius)


def heights_on_grid(dem: HeightRaster, grid: OrthoGrid, out: np.ndarray | None = None,
                    affine: GridAffine | None = None) -> np.ndarray:
    """Bilinear DEM heights at the pixel centres of a grid in the DEM's CRS (float32, NaN = nodata); ``affine``: of
    a grid in another CRS, its cell centres' project coordinates (``GridToProject.affine``).

    cv2.warpAffine does the resampling (vectorised; positions quantised to 1/32 DEM cell, i.e. 3 cm
    for a 1 m DEM, far below what moves a ground point in the image). NaN propagates from nodata
    cells; within half a DEM cell of the raster edge heights are NaN. ``out``: optional (H, W)
    float32 array to fill (reused between tiles, saving the page faults of a fresh array).
    """
    if affine is None:
        scale = grid.res_m / dem.res_m
        u0 = (grid.x_left_m + 0.5 * grid.res_m - dem.x_left_m) / dem.res_m - 0.5
        v0 = (dem.y_top_m - (grid.y_top_m - 0.5 * grid.res_m)) / dem.res_m - 0.5
        A = np.array([[scale, 0.0, u0], [0.0, scale, v0]])
    else:  # DEM column, row of the cell centres: affine in (col, row)
        a = affine
        A = np.array([[a.col_dx_m, a.row_dx_m, a.x0_m - dem.x_left_m],
                      [-a.col_dy_m, -a.row_dy_m, dem.y_top_m - a.y0_m]])
        A /= dem.res_m
        A[:, 2] -= 0.5
    return cv2.warpAffine(dem.heights_m, A, (grid.width, grid.height), dst=out,
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=float("nan"))


def heights_by_side(sides: OutlineHeights, grid: OrthoGrid, out: np.ndarray | None = None) -> np.ndarray:
    """Bilinear heights at the pixel centres of ``grid`` (in the DSM's CRS) each from its own side of the roof
    outlines (``ortho.footprints.OutlineHeights``): within an outline among the roof's cells, beyond every outline
    among the ground's; float32 (H, W) as ``heights_on_grid``."""
    import shapely
    from rasterio.features import rasterize
    from rasterio.transform import from_origin

    z = heights_on_grid(sides.ground, grid, out=out)
    x1, y0 = grid.x_left_m + grid.width * grid.res_m, grid.y_top_m - grid.height * grid.res_m
    near = sides.tree.query(shapely.box(grid.x_left_m, y0, x1, grid.y_top_m), predicate="intersects")
    if len(near) == 0:
        return z
    # rasterised and warped over the outlines' box within the tile only (on the full-size DMC frames a tenth of the
    # tiles' pixels lie within an outline)
    bounds = shapely.bounds(sides.outlines[near]).reshape(-1, 4)
    x0_m, y0_m = bounds[:, :2].min(axis=0)
    x1_m, y1_m = bounds[:, 2:].max(axis=0)
    c0 = max(int(math.floor((x0_m - grid.x_left_m) / grid.res_m)), 0)
    c1 = min(int(math.ceil((x1_m - grid.x_left_m) / grid.res_m)), grid.width)
    r0 = max(int(math.floor((grid.y_top_m - y1_m) / grid.res_m)), 0)
    r1 = min(int(math.ceil((grid.y_top_m - y0_m) / grid.res_m)), grid.height)
    if c1 <= c0 or r1 <= r0:
        return z
    box = grid.window(c0, r0, c1 - c0, r1 - r0)
    within = rasterize(((sides.shapes[k], 1) for k in near), out_shape=(box.height, box.width),
                       transform=from_origin(box.x_left_m, box.y_top_m, box.res_m, box.res_m), dtype="uint8")
    np.copyto(z[r0:r1, c0:c1], heights_on_grid(sides.roof, box), where=within.view(np.bool_))
    return z


def image_coordinates(geometry: FrameGeometry, dem: HeightRaster, grid: OrthoGrid, to_project: GridToProject | None = None,
                      margin_px: float = 0.0):
    """Image coordinates (map_x, map_y float32) and heights (float32) for every pixel of ``grid``.

    Pixels not imaged (outside the frame, behind the camera, beyond ``geometry.ray_limits()``, DEM nodata) have
    map = -1e5.
    Returns (map_x, map_y, heights, anchors).
    """
    to_project = to_project or GridToProject(grid.crs, grid.crs)
    AX, AY, s = to_project.anchors(grid)
    shape = (grid.height, grid.width)
    map_x = np.empty(shape, np.float32)
    map_y = np.empty(shape, np.float32)
    z = np.empty(shape, np.float32)
    from ortho.rectify_kernels import _backproject_kernel

    _backproject_kernel(AnchorGrid(AX, AY, float(s)), _height_grid(dem), geometry.kernel_frame(), float(margin_px),
                        (map_x, map_y, z))
    return map_x, map_y, z, (AX, AY, s)


class MapBuffers:
    """Reusable per-thread arrays for the fixed-point maps and heights of tiles up to ``tile_px`` square.

    Fresh arrays for every tile cost a page fault per 4 KiB (about a third of the map computation on a
    large frame); views of these flat buffers are C-contiguous for any tile shape.
    """

    def __init__(self, tile_px: int):
        n = tile_px * tile_px
        self.capacity = n
        self._int = np.empty(2 * n, np.int16)
        self._frac = np.empty(n, np.uint16)
        self._z = np.empty(n, np.float32)

    def views(self, rows: int, cols: int):
        n = rows * cols
        if n > self.capacity:
            raise ValueError(f"tile {cols} x {rows} px exceeds the buffers ({self.capacity} px)")
        return (self._int[:2 * n].reshape(rows, cols, 2), self._frac[:n].reshape(rows, cols),
                self._z[:n].reshape(rows, cols))


def fixed_point_maps(geometry: FrameGeometry, dem: HeightRaster, grid: OrthoGrid, to_project: GridToProject | None = None,
                     *, margin_px: float = 0.0, buffers: MapBuffers | None = None, mask_out: np.ndarray | None = None,
                     bounds_out: np.ndarray | None = None, sides: OutlineHeights | None = None):
    """cv2.remap fixed-point maps (int16 (H, W, 2), uint16 (H, W)), validity mask (uint8 255/0), heights, anchors.

    ``sides``: the heights each from its own side of the roof outlines (``heights_by_side``) instead of the bilinear
    ``dem`` across them, where ``grid`` is in the project CRS (``to_project`` the identity; else ``dem``'s as before).

    With ``buffers`` the maps and heights are views of those (valid until the next call with them);
    the mask is ``mask_out`` if given, else a new array. ``bounds_out`` (int32 [4]) receives the
    integer image positions the imaged pixels read from: x_min, x_max, y_min, y_max (x_max < 0: none).
    """
    to_project = to_project or GridToProject(grid.crs, grid.crs)
    # another CRS's tile: affine in the project's where that holds within the anchors' tolerance (checked), so
    # neither PROJ's anchors nor their interpolation per pixel
    affine = None if to_project.identity else to_project.affine(grid)
    AX, AY, s = to_project.anchors(grid) if affine is None else affine.anchors(grid.width, grid.height)
    shape = (grid.height, grid.width)
    if buffers is not None:
        map_int, map_frac, z = buffers.views(*shape)
    else:
        map_int, map_frac, z = np.empty(shape + (2,), np.int16), np.empty(shape, np.uint16), np.empty(shape, np.float32)
    mask = np.empty(shape, np.uint8) if mask_out is None else mask_out
    bounds = np.empty(4, np.int32) if bounds_out is None else bounds_out
    bounds[:] = (32767, -32768, 32767, -32768)
    from ortho.rectify_kernels import _fixed_point_kernel, _fixed_point_kernel_affine, _fixed_point_kernel_affine_map

    frame, maps = geometry.kernel_frame(), RemapMaps(map_int, map_frac, mask, bounds)
    if to_project.identity:
        z = heights_on_grid(dem, grid, out=z) if sides is None else heights_by_side(sides, grid, out=z)
        _fixed_point_kernel_affine(_affine_tile(z, grid), frame, float(margin_px), maps)
        return map_int, map_frac, mask, z, (AX, AY, s)
    if affine is not None:
        _fixed_point_kernel_affine_map(affine, _height_grid(dem), frame, float(margin_px), maps, z)
        return map_int, map_frac, mask, z, (AX, AY, s)
    _fixed_point_kernel(AnchorGrid(AX, AY, float(s)), _height_grid(dem), frame, float(margin_px), maps, z)
    return map_int, map_frac, mask, z, (AX, AY, s)


# the march's bounds: the highest DSM height by blocks of 16 and of 128 cells (a ray above a block's highest height
# crosses it in one jump): the fine blocks keep the bound tight between buildings, the coarse ones let a ray
# that has risen above the roofs around it leave in a few jumps
MARCH_BLOCK_CELLS = (16, 128)
# the march tests a point from the top of its own DSM column where its bilinear height lies more than this above it
# (a ground point within half a cell of a wall, part way up the wall's bilinear ramp: from there the ray passes
# over the roof that hides the ground)
OWN_COLUMN_M = 1.0
# the march takes two neighbouring DSM cells for a wall (each its flat-topped column) where the height between their
# centres rises more steeply than this, else for continuous surface (the bilinear one the ground points stand on, no
# column's top above it: ``ortho.rectify_kernels._surface_blocks``). A column's top lies up to half the cell's rise
# above that surface, and masked visible ground on slopes facing away from the camera (stripes along the DSM's rows)
# once the rise passed twice the march's tolerance. 60 deg: steeper than natural slopes outside cliffs, while a
# building wall in a DSM rises its whole height within one cell (on 0.5 m cells a rise of 0.87 m is a wall already,
# a third of a storey); chosen so, not fitted to any block.
WALL_SLOPE_DEG = 60.0
# ... and only where all four cells of the square are the ground (``ground_cells``): within this of the rectify's DEM
# at the cell's centre, plus half the DEM's rise across the cell in each direction (a DSM cell of bare sloping ground
# holds a height from anywhere within the cell: its highest, mean or a point). An object on the ground (a car, hedge,
# shed, bungalow) keeps its flat-topped columns whatever its rise per cell: 60 deg alone took a 1.6 m car on 1 m
# cells or a 2 m hedge on 2 m cells for a ramp and left the ground behind it valid (review 30). 0.5 m: the nDSM
# height up to which the seamlines and ``ortho check`` take a cell for ground (``max_ndsm_m``), the DSM's and the
# DEM's noise; not fitted.
GROUND_NDSM_M = 0.5
CELL_FACTOR = 1.25


@dataclasses.dataclass(frozen=True)
class MarchBound:
    """The highest height of a DSM (m) and its highest heights by blocks of ``block`` and of ``coarse`` cells
    (``_block_max``), which let the march of ``occlusion_mask`` jump over the blocks a ray passes above."""

    max_m: float
    block_max_m: np.ndarray
    block: int
    coarse_max_m: np.ndarray
    coarse: int


def march_bound(dsm: HeightRaster, blocks: tuple[int, int] = MARCH_BLOCK_CELLS,
                occluder: FootprintOccluder | None = None, tolerance_m: float = 0.3) -> MarchBound:
    """The bounds of the march over ``dsm`` (once per frame; ``occlusion_mask`` makes them if not given); with
    ``occluder`` over the tops of its slabs too (a cell beside an overhang carries the overhang's slab), raised by
    the march's ``tolerance_m``: the march skips a block the ray passes more than the tolerance above, and an
    overhang's slab stops a ray below its top without the tolerance."""
    from ortho.rectify_kernels import _block_max, _coarser_max

    fine, coarse = (int(b) for b in blocks)
    slab_top = None if occluder is None else occluder.slab_top_m
    fine_max, seen = _block_max(dsm.heights_m, fine, slab_top, np.float32(tolerance_m))
    coarse_max = _coarser_max(fine_max, coarse // fine) if coarse % fine == 0 else \
        _block_max(dsm.heights_m, coarse, slab_top, np.float32(tolerance_m))[0]
    return MarchBound(float(fine_max.max()) if seen else math.nan, fine_max, fine, coarse_max, coarse)


# the DSM stands off the DEM (``ground_flags``): the 1 m band (+-``GROUND_NDSM_M``) of nDSM heights within its lowest
# ``STAND_OFF_LOW_SHARE`` that holds the most cells (the ground between the objects) lies off 0 by more than
# ``GROUND_NDSM_M``, holds at least ``STAND_OFF_MIN_SHARE`` of the cells, ``STAND_OFF_GAIN`` times those the ground flag
# found and ``STAND_OFF_GAIN`` times those of the band 1 m above it (a level, not a canopy's spread of heights). A
# vertical datum offset (a photogrammetric DSM in ellipsoidal heights over a LiDAR DEM in orthometric ones) moves
# every cell: the ground flag finds almost none and the march falls back to the columns. Looked at on gridded real
# LiDAR (highest return against the ground returns' DEM, 1 m: /work/tmp/leftovers/standoff_stats.py), the DSM as is
# and moved by -2, +1, +2, +3 m: lidr_mixedconifer (a conifer stand: the band holds 0.17, 1 m above it 0.01),
# lidr_topography (forested hills: 0.31, 0.09); checked on ahn3_delft (a town, 1 and 0.5 m: 0.24-0.31, 0.04-0.05) and
# the demo (0.93, 0.00): as is none stands off (level within 0.11 m of 0), moved all do but lidr_topography at -2 m
# (its slopes' slack keeps 11 % ground: the gain 2.8). Not fitted: 3 and 5 % by reasoning, not by these numbers.
# A crop, a meadow or flat roofs over most of a frame form such a level too (review 37: a 0.9 m crop over 92 % of the
# cells, maize at 2.5 m over 86 %, flat roofs at 8 m over 90 %: "stands off" on correct DSMs), but with the bare
# tracks, roads and yards below it (10-14 % of the cells more than ``GROUND_NDSM_M`` below the level), where a datum
# offset moves every cell and leaves none below (the four real sets above moved: 0.0-1.1 %): at most
# ``STAND_OFF_BELOW_SHARE`` below. And a datum offset is the block's: the warning wants it in most frames.
STAND_OFF_LOW_SHARE = 0.25   # the ground between buildings and crowns: on most scenes more than that
STAND_OFF_MIN_SHARE = 0.05
STAND_OFF_GAIN = 3.0
STAND_OFF_BELOW_SHARE = 0.03
# cells looked at (evenly spaced) of a window: the bands' counts, not the flags. Their shares are estimates, to about
# 0.1 % at this size (the shares decided on are 3-5 % and a gain of 3); sorting a demo frame's 1.1 M cells cost 16-27 ms
STAND_OFF_SAMPLES = 250_000


@dataclasses.dataclass(frozen=True)
class GroundFlags:
    """``ground_cells`` of a DSM window and how its heights sit on the DEM: ``share`` the ground cells' share of the
    cells with a height in both; ``level_m`` the middle of the 1 m band of nDSM heights (DSM - DEM, m) within their
    lowest quarter holding the most cells (about 0: the bare ground between the objects), ``level_share`` and
    ``above_share`` the cells' share in it and in the band 1 m above it, ``below_share`` that of the cells more than
    ``GROUND_NDSM_M`` below it; ``stands_off``: the DSM stands off the DEM by about ``level_m`` (a vertical datum
    offset, most likely: ``STAND_OFF_GAIN``, ``STAND_OFF_BELOW_SHARE``)."""

    cells: np.ndarray  # uint8 (rows, cols) of the DSM, 1: the ground
    share: float
    level_m: float
    level_share: float
    above_share: float
    below_share: float = 0.0

    @property
    def stands_off(self) -> bool:
        return (abs(self.level_m) > GROUND_NDSM_M and self.level_share >= STAND_OFF_MIN_SHARE
                and self.level_share >= STAND_OFF_GAIN * max(self.share, self.above_share)
                and self.below_share <= STAND_OFF_BELOW_SHARE)


def _ground_level(ndsm_m: np.ndarray) -> tuple[float, float, float, float]:
    """``GroundFlags``'s ``level_m``, ``level_share``, ``above_share``, ``below_share`` of finite nDSM heights
    ``ndsm_m`` (1-D, a sample of the window's cells)."""
    v = np.sort(ndsm_m)
    lo, hi = float(v[0]), float(v[int(STAND_OFF_LOW_SHARE * (v.size - 1))])
    centres = np.arange(lo, hi + 0.05, 0.1)
    counts = (np.searchsorted(v, centres + GROUND_NDSM_M, "right") - np.searchsorted(v, centres - GROUND_NDSM_M))
    best = int(np.argmax(counts))
    # the band's cells' median: the level itself (the bands that hold the whole of a level sharper than 1 m tie)
    c = float(np.median(v[np.searchsorted(v, centres[best] - GROUND_NDSM_M):
                          np.searchsorted(v, centres[best] + GROUND_NDSM_M, "right")]))
    above = int(np.searchsorted(v, c + 3 * GROUND_NDSM_M, "right") - np.searchsorted(v, c + GROUND_NDSM_M, "right"))
    below = int(np.searchsorted(v, c - GROUND_NDSM_M))
    return c, int(counts[best]) / v.size, above / v.size, below / v.size


def ground_flags(dsm: HeightRaster, dem: HeightRaster) -> GroundFlags:
    """Which cells of ``dsm`` are the ground (uint8 per cell, 1: the ground): within ``GROUND_NDSM_M`` plus half
    the DEM's rise across the cell (along rows plus along columns) of ``dem`` (the same CRS and heights) at the
    cell's centre; NaN in either: not the ground. Once per DSM window (the march's continuous surface,
    ``occlusion_mask``); ``dem`` the DSM itself (or its copy): every cell with a height is the ground. With the
    shares that tell a DSM standing off the DEM (``GroundFlags``)."""
    h, w = dsm.heights_m.shape
    ground_m = heights_on_grid(dem, OrthoGrid(dsm.crs, dsm.x_left_m, dsm.y_top_m, dsm.res_m, w, h))
    # (the resampling leaves NaN within half a DEM cell of its edge, where the DEM's own bilinear heights hold: the
    # last row and column of a DSM window on the DEM's grid, ``--dsm dem.tif``)
    missing = np.isnan(ground_m)
    if missing.any():
        r, c = np.nonzero(missing)
        ground_m[r, c] = dem.sample(dsm.x_left_m + (c + 0.5) * dsm.res_m, dsm.y_top_m - (r + 0.5) * dsm.res_m)
    slack_m = np.full((h, w), GROUND_NDSM_M, np.float32)
    # the DEM's rise per DSM cell (central differences; one-sided at the edges)
    for axis in (0, 1):
        if ground_m.shape[axis] > 1:
            slack_m += 0.5 * np.abs(np.gradient(ground_m, axis=axis))
    ndsm_m = dsm.heights_m - ground_m
    with np.errstate(invalid="ignore"):
        cells = (np.abs(ndsm_m) <= slack_m).astype(np.uint8)
    n_seen = int(np.count_nonzero(np.isfinite(ndsm_m)))
    if not n_seen:
        return GroundFlags(cells, 0.0, 0.0, 0.0, 0.0, 0.0)
    sample = ndsm_m.ravel()[::max(1, ndsm_m.size // STAND_OFF_SAMPLES)]  # (evenly spaced)
    sample = sample[np.isfinite(sample)]
    if not sample.size:
        sample = ndsm_m[np.isfinite(ndsm_m)]
    return GroundFlags(cells, int(np.count_nonzero(cells)) / n_seen, *_ground_level(sample))


def ground_cells(dsm: HeightRaster, dem: HeightRaster) -> np.ndarray:
    """``ground_flags(dsm, dem).cells``: which cells of ``dsm`` are the ground (uint8 per cell, 1: the ground)."""
    return ground_flags(dsm, dem).cells


def occlusion_mask(geometry: FrameGeometry, dsm: HeightRaster, grid: OrthoGrid, heights_m: np.ndarray, anchors, *,
                   tolerance_m: float = 0.3, candidates: np.ndarray | None = None,
                   bound: MarchBound | None = None, near_share: np.ndarray | None = None,
                   occluder: FootprintOccluder | None = None, ground: np.ndarray | None = None) -> np.ndarray:
    """True where the ground point (grid pixel at ``heights_m``) is hidden from the camera by the DSM (a march
    along its ray; only where ``candidates``, e.g. the points the z-buffer puts behind a nearer surface).
    ``near_share`` (``zbuffer_occlusion_from_maps``): where the march looks first; the result is the same.
    ``occluder`` (``ortho.footprints.footprint_occluder`` of the same ``dsm``): building footprints, under whose
    roof overhangs a ray may pass; None: every DSM cell a solid column. ``ground`` (``ground_cells`` of ``dsm``):
    the cells continuous surface may join (``WALL_SLOPE_DEG``); None: none, every cell its flat-topped column (as
    where no DEM tells the ground from the objects on it)."""
    AX, AY, s = anchors
    occ = np.zeros((grid.height, grid.width), dtype=np.bool_)
    bound = bound or march_bound(dsm, occluder=occluder, tolerance_m=tolerance_m)
    from ortho.rectify_kernels import _occlusion_kernel

    points = TilePoints(np.ascontiguousarray(heights_m, np.float32),
                        np.ones(occ.shape, np.bool_) if candidates is None else candidates,
                        np.zeros((1, 1), np.float32) if near_share is None else near_share)
    march = MarchArgs(bound.max_m, bound.block_max_m, bound.block, bound.coarse_max_m, bound.coarse,
                      float(tolerance_m), float(OWN_COLUMN_M), float(dsm.res_m * math.tan(math.radians(WALL_SLOPE_DEG))),
                      _NO_GROUND if ground is None else np.ascontiguousarray(ground, np.uint8))
    if ground is not None and ground.shape != dsm.heights_m.shape:
        raise ValueError(f"ground flags of {ground.shape} cells for a DSM of {dsm.heights_m.shape}")
    walls = _NO_WALLS if occluder is None else FootprintWalls(occluder.base_m, occluder.slab_top_m,
                                                              occluder.sub_index, occluder.sub_masks, int(occluder.sub),
                                                              occluder.sub_margin_cm)
    if occluder is not None and occluder.base_m.shape != dsm.heights_m.shape:
        raise ValueError(f"footprint occluder of {occluder.base_m.shape} cells for a DSM of {dsm.heights_m.shape}")
    _occlusion_kernel(AnchorGrid(AX, AY, float(s)), points, _height_grid(dsm), march, walls,
                      np.asarray(geometry.centre_m, np.float64), occ)
    return occ


@dataclasses.dataclass(frozen=True)
class ZBuffer:
    """The nearest surface of a frame by cells of ``cell_px`` image pixels: depth along the optical axis (m,
    float32 (rows, cols), +inf where nothing was seen), and the depth by which a point must lie behind it
    to be occluded (``tolerance_m``: the depth a visible surface spans within one cell, and a margin)."""

    depth_m: np.ndarray
    cell_px: int
    tolerance_m: float


def frame_zbuffer(geometry: FrameGeometry, dsm: HeightRaster, grid: OrthoGrid, to_project: GridToProject | None = None,
                  tile_px: int = 1024, margin_m: float = 0.5) -> ZBuffer:
    """Z-buffer of the surface ``dsm`` over ``grid`` seen from the frame (every grid pixel at its DSM height
    projected into the image; tile by tile, memory set by the tiles and the buffer).

    Cells: the image pixels an output pixel spans at the frame's mean distance, times 1.5, rounded up (so
    that every cell holds a surface sample where the surface is seen); tolerance: ``margin_m`` plus the
    ground size of a cell (a roof of 45 degrees spans that much depth within a cell)."""
    from ortho.rectify_kernels import _zbuffer_kernel, _zbuffer_scatter_affine

    to_project = to_project or GridToProject(grid.crs, grid.crs)
    # every surface point seen, whatever the view angle (it may hide ground within it), but none beyond the fold:
    # the z-buffer kernels read the frame's fold alone
    frame = geometry.kernel_frame()
    centre, params = frame.centre_m, frame.cam
    cam = geometry.camera
    finite = dsm.heights_m[np.isfinite(dsm.heights_m)]
    distance_m = max(1.0, float(centre[2]) - (float(np.median(finite)) if finite.size else 0.0))
    gsd_m = distance_m / float(params[0])  # ground size of an image pixel at that distance (f in pixels)
    # the surface sampled at the output pixels, or (project CRS) every ``step``-th of them while that still samples
    # the DSM at most half a DSM cell apart: the z-buffer's cells grow with the step, its cost falls with its square
    # (a contract CRS's grid at every pixel, as before its tiles were affine: the same occluders, the cost about the
    # same on a full-size DMC frame)
    step = max(1, int(0.5 * dsm.res_m / grid.res_m)) if to_project.identity else 1
    cell_px = max(1, int(math.ceil(CELL_FACTOR * step * grid.res_m / gsd_m)))
    depth = np.full((-(-cam.height // cell_px), -(-cam.width // cell_px)), np.inf, np.float32)
    buffers = MapBuffers(tile_px)
    mask = np.empty(tile_px * tile_px, np.uint8)
    none = np.zeros((1, 1), np.bool_)
    over = MapBuffers(tile_px + 1)
    if step > 1:  # the same extent, pixels ``step`` times the size (centres every ``step`` output pixels)
        grid = OrthoGrid(grid.crs, grid.x_left_m, grid.y_top_m, grid.res_m * step, -(-grid.width // step),
                         -(-grid.height // step))
    for r0 in range(0, grid.height, tile_px):
        for c0 in range(0, grid.width, tile_px):
            tile = grid.window(c0, r0, min(tile_px, grid.width - c0), min(tile_px, grid.height - r0))
            # the tile and the row above and column left of it: the gaps across its edges are filled too
            r1, c1 = max(r0 - 1, 0), max(c0 - 1, 0)
            wider = grid.window(c1, r1, c0 + tile.width - c1, r0 + tile.height - r1)
            affine = None if to_project.identity else to_project.affine(wider)
            if to_project.identity or affine is not None:
                # the heights alone (no maps needed here), ground X, Y affine in (row, col)
                z = heights_on_grid(dsm, wider, out=over.views(wider.height, wider.width)[2], affine=affine)
                _zbuffer_scatter_affine(_affine_tile(z, wider, affine), frame, ZBufferArgs(depth, cell_px, 0.0))
                continue
            else:
                m = mask[:tile.height * tile.width].reshape(tile.height, tile.width)
                _, _, _, z, (AX, AY, s) = fixed_point_maps(geometry, dsm, tile, to_project, buffers=buffers, mask_out=m)
            _zbuffer_kernel(AnchorGrid(AX, AY, float(s)), z, frame, ZBufferArgs(depth, cell_px, 0.0), none, True)
    # each cell gets the nearest surface of its 3 x 3 cells: a point just inside the edge of a hidden area lands
    # beside the image of the roof edge hiding it, often in a cell that the roof's samples (the last of them up to
    # an output pixel inside the edge) miss, among the visible ground beyond the edge at about its own depth: it was
    # no candidate, and left visible (half the hidden ground the masks left valid on the tall block, exact DSM)
    depth = cv2.erode(depth, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    return ZBuffer(depth, cell_px, margin_m + cell_px * gsd_m)


def zbuffer_occlusion(geometry: FrameGeometry, zbuffer: ZBuffer, heights_m: np.ndarray, anchors,
                      out: np.ndarray | None = None) -> np.ndarray:
    """True where the point of a tile pixel (at ``heights_m``) lies behind the frame's nearest surface."""
    from ortho.rectify_kernels import _zbuffer_kernel

    AX, AY, s = anchors
    occ = np.zeros(heights_m.shape, np.bool_) if out is None else out
    if out is not None:
        occ[...] = False
    _zbuffer_kernel(AnchorGrid(AX, AY, float(s)), heights_m, geometry.kernel_frame(),
                    ZBufferArgs(zbuffer.depth_m, zbuffer.cell_px, float(zbuffer.tolerance_m)), occ, False)
    return occ


def zbuffer_occlusion_from_maps(geometry: FrameGeometry, zbuffer: ZBuffer, tile: OrthoGrid, map_int: np.ndarray,
                                mask: np.ndarray, heights_m: np.ndarray, *, out: np.ndarray,
                                near_share: np.ndarray | None = None, affine: GridAffine | None = None) -> np.ndarray:
    """``zbuffer_occlusion`` of a tile in the project CRS (``affine``: a contract CRS's tile, ``GridToProject.affine``)
    from its cv2.remap maps (``fixed_point_maps`` at the same ``heights_m``): the image positions are not computed
    again; only imaged pixels (``mask``) are tested.
    ``near_share`` (float32 like the tile): set where ``out`` is, to the nearer surface's depth / the point's
    (for ``occlusion_mask``)."""
    from ortho.rectify_kernels import _zbuffer_test_maps

    out[...] = False
    near = np.empty(heights_m.shape, np.float32) if near_share is None else near_share
    _zbuffer_test_maps((map_int, mask), _affine_tile(heights_m, tile, affine), geometry.kernel_frame(),
                       ZBufferArgs(zbuffer.depth_m, zbuffer.cell_px, float(zbuffer.tolerance_m)), out, near)
    return out


def _interpolation_flag(interpolation: str) -> int:
    try:
        return INTERPOLATION[interpolation]
    except KeyError:
        raise InputError(f"unknown interpolation {interpolation!r}; expected one of {sorted(INTERPOLATION)}") from None


# cv2.remap's vectorised bilinear path for 8-bit images addresses source rows with 16-bit offsets:
# images whose rows take 32 KiB or more (3-band frames wider than 10,922 px, e.g. the DMC's 13,824)
# go through its scalar path at about half the speed (one thread: 75 vs 130-160 MP/CPU-s on the DMC
# frame; bench/ortho.py remap_ceiling vs remap_ceiling_windows). Such frames are resampled from a
# compact copy of the window each tile reads; the result is the same to the bit.
_REMAP_VECTOR_MAX_STEP = 1 << 15


class SourceWindow:
    """Reusable per-thread copy of the part of a frame one tile reads, rows short enough for cv2.remap's
    vectorised path (``_REMAP_VECTOR_MAX_STEP``)."""

    def __init__(self):
        self._flat = np.empty(0, np.uint8)

    def source(self, image: np.ndarray, map_int: np.ndarray, bounds: np.ndarray, pad_px: int = 2) -> np.ndarray:
        """The window of ``image`` holding the integer positions ``bounds`` (x_min, x_max, y_min, y_max)
        plus the bilinear neighbour and ``pad_px``, clipped to the image (so its edges are the image's
        where the tile reaches them, and cv2's border rule acts there as on the whole frame); shifts
        ``map_int`` (int16 x, y) to it in place, saturating, so not-imaged positions stay far outside.
        Returns ``image`` itself, maps unchanged, when the window's rows would not be short enough."""
        h, w = image.shape[:2]
        x0, x1 = max(0, int(bounds[0]) - pad_px), min(w, int(bounds[1]) + 2 + pad_px)
        y0, y1 = max(0, int(bounds[2]) - pad_px), min(h, int(bounds[3]) + 2 + pad_px)
        px_bytes = image.itemsize * (image.shape[2] if image.ndim == 3 else 1)
        if (x1 - x0) * px_bytes >= _REMAP_VECTOR_MAX_STEP or x1 <= x0 or y1 <= y0:
            return image
        n = (y1 - y0) * (x1 - x0) * px_bytes
        if self._flat.size < n:
            self._flat = np.empty(n, np.uint8)
        window = self._flat[:n].view(image.dtype).reshape((y1 - y0, x1 - x0) + image.shape[2:])
        np.copyto(window, image[y0:y1, x0:x1])
        cv2.subtract(map_int, (x0, y0, 0, 0), dst=map_int)
        return window


def _remap_bands(image, map1, map2, flag, border):
    """cv2.remap band by band (it takes at most 4 channels) -> (rows, cols, bands)."""
    return np.stack([cv2.remap(image[:, :, b], map1, map2, flag, borderMode=border, borderValue=0)
                     for b in range(image.shape[2])], axis=-1)


def default_threads() -> int:
    """Tile threads per frame: the cores this process may run on (numba kernels and cv2.remap release the GIL)."""
    return usable_cores()


def ordered_thread_map(fn, items, threads: int, ahead: int | None = None):
    """Yield ``fn(item)`` in the order of ``items``, computed by ``threads`` threads at most ``ahead`` items
    in advance (bounded memory: results wait for the consumer, e.g. a GeoTIFF writer).

    A consumer that may stop early (an error while it writes) closes the generator (``contextlib.closing``)
    so that the threads end there, in its thread, before what they use is closed; left to the garbage
    collector the generator would end them at an arbitrary point of any thread."""
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        yield from map(fn, items)
        return
    ahead = ahead or 2 * threads
    with ThreadPoolExecutor(threads, thread_name_prefix="ortho-tile") as pool:
        pending = collections.deque()
        it = iter(items)
        try:
            for item in it:
                pending.append(pool.submit(fn, item))
                if len(pending) >= ahead:
                    break
            while pending:
                result = pending.popleft().result()
                nxt = next(it, None) if len(pending) < ahead else None
                if nxt is not None:
                    pending.append(pool.submit(fn, nxt))
                yield result
        finally:
            for f in pending:
                f.cancel()


# source pixels beyond an output pixel's integer source position that its interpolation kernel reads (OpenCV:
# bilinear x..x+1, cubic x-1..x+2, Lanczos x-3..x+4; nearest rounds, x or x+1): a frame's invalid pixels are grown by
# this much (``frame_validity``), so that no output pixel mixes one in
_KERNEL_REACH_PX = {"nearest": 1, "bilinear": 1, "cubic": 2, "lanczos": 4}
_JPEG_BLOCK_PX = 16  # and, in a JPEG-compressed frame with a nodata value, its largest block (a 4:2:0 MCU)
# JPEG leaves specks of a black collar off its nodata value, which cut the collar's 0 into pieces: the value's pixels
# are joined over this much before the pieces touching the edge are taken (the rest of the block after). Chosen on
# the synthetic frames of tests/ortho/test_frame_nodata.py (0 px: 6 pixels of collar, > 60 DN darker, in an ortho);
# scored on the NGI frames: a collar declared nodata=0, 0 ortho pixels > 30 DN darker than the plain frames'; the
# frames darkened by 60 DN (shadows at 0, no collar), mosaic nodata 0.27 % against 0.11 % plain (4 px: 0.47 %)
_JPEG_JOIN_PX = 2


def declares_nodata(path) -> bool:
    """Whether the frame declares pixels invalid (a nodata value, an internal mask or an alpha band; GDAL's mask
    flags), whether or not any pixel is."""
    import rasterio
    from rasterio.enums import MaskFlags

    with rasterio.open(path) as ds:
        return not all(flags == [MaskFlags.all_valid] for flags in ds.mask_flag_enums)


COLLAR_CORNER_PX = 16  # the square of a frame's corner that ``black_corners`` reads


def black_corners(image) -> int:
    """How many of the frame's four corners (squares of ``COLLAR_CORNER_PX``) hold 0 in every band and pixel: a
    collar the frame does not declare (no nodata value or mask; ``declares_nodata``) is rectified as picture, black in
    the DOM. Ground is never that black over a corner's 256 pixels in every band. ``image``: the frame as decoded for
    its rectification (rows, cols[, bands]), or a ``FrameFile`` (its corners read by windows): taken in the frame's
    task, not by decoding every frame again before the first starts (285 ms a Brighton JPEG; 14 min for 3,000)."""
    rows, cols = image.shape[:2]
    k = min(COLLAR_CORNER_PX, rows, cols)
    n = 0
    for c0, r0 in ((0, 0), (cols - k, 0), (0, rows - k), (cols - k, rows - k)):
        corner = image.read(c0, c0 + k, r0, r0 + k) if isinstance(image, FrameFile) else image[r0:r0 + k, c0:c0 + k]
        n += int(not corner.any())
    return n


# rows of a frame read at a time for its validity (``frame_validity``; whole blocks of a tiled frame): memory set by
# the strip, not the frame's bands
_VALIDITY_STRIP_ROWS = 256


def _invalid_pixels(path, image: np.ndarray | None, band_order: list[int] | None, by_value: bool) -> np.ndarray:
    """uint8 (rows, cols) of the frame, 1 where GDAL's dataset mask says invalid (a nodata value in every band; an
    internal mask's or alpha's 0), else 0. A nodata value is compared in ``image`` when the frame is decoded in memory
    (no second decode), else, as masks and alpha always, read by strips of whole blocks, a GeoTIFF opened for each
    strip: its blocks leave GDAL's cache with it (read through one dataset, a DMC frame's 850 MB of RGBN samples
    filled the cache, +946 MiB)."""
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(path) as ds:
        rows, cols, nodatavals = ds.height, ds.width, ds.nodatavals
        block_rows = ds.block_shapes[0][0] if ds.is_tiled else 1
        reopen = ds.driver == "GTiff"
    invalid = np.empty((rows, cols), np.uint8)
    if isinstance(image, np.ndarray) and by_value and band_order is not None:
        for y in range(0, rows, _VALIDITY_STRIP_ROWS):
            out = invalid[y:y + _VALIDITY_STRIP_ROWS].view(bool)
            out[...] = True
            part = image[y:y + _VALIDITY_STRIP_ROWS]
            for c, band in enumerate(band_order):
                nodata = nodatavals[band - 1]
                if nodata is None:  # a band without the value: every pixel valid in it, so in the frame (GDAL's)
                    out[...] = False
                    break
                a = part if part.ndim == 2 else part[:, :, c]
                out &= np.isnan(a) if np.isnan(nodata) else a == nodata
        return invalid
    step = max(block_rows, _VALIDITY_STRIP_ROWS // block_rows * block_rows)
    ds = None if reopen else rasterio.open(path)
    try:
        for y in range(0, rows, step):
            h = min(step, rows - y)
            with (rasterio.open(path) if reopen else contextlib.nullcontext(ds)) as strip:
                np.equal(strip.dataset_mask(window=Window(0, y, cols, h)), 0, out=invalid[y:y + h].view(bool))
    finally:
        if ds is not None:
            ds.close()
    return invalid


def _edge_connected(invalid: np.ndarray) -> np.ndarray:
    """``invalid`` (uint8 0/1, changed in place) with the regions of 1 that touch the frame's edge (8-connected)
    set to 2: a collar."""
    rows, cols = invalid.shape
    edges = ((0, slice(None)), (rows - 1, slice(None)), (slice(None), 0), (slice(None), cols - 1))
    for r, c in edges:
        for i in np.flatnonzero(invalid[r, c] == 1):
            y, x = (r, int(i)) if isinstance(r, int) else (int(i), c)
            if invalid[y, x] == 1:  # (not yet filled from another seed of the same region)
                cv2.floodFill(invalid, None, (x, y), 2, 0, 0, 8)
    return invalid


def frame_validity(path, interpolation: str = "bilinear", image: np.ndarray | None = None,
                   band_order: list[int] | None = None) -> np.ndarray | None:
    """The frame's own validity as GDAL gives it (its nodata value, an internal mask or an alpha band: the black
    collar of a scanned or rotated frame), uint8 (rows, cols), 255 where every source pixel the ``interpolation``
    kernel reads around a position is valid (the invalid pixels grown by ``_KERNEL_REACH_PX``); None when the frame
    declares no invalid pixel (no nodata value, mask or alpha; or one that no pixel holds). ``rectify_frame``
    makes the cells whose samples would read an invalid pixel nodata, as it does cells outside the frame.

    An internal mask or alpha band is taken as it is. A nodata value marks only the regions holding it in every band
    that touch the frame's edge (8-connected): a collar; the value inside the picture is picture (a shadow clipped
    at 0, a roof saturated at 65535: one 0 pixel had made a 35 x 35 px hole in a JPEG frame's ortho). In a
    JPEG-compressed frame the value's pixels are joined over ``_JPEG_JOIN_PX`` before, and the collar grown by
    ``_JPEG_BLOCK_PX`` after: the value inside the picture is not. ``image`` (rows, cols[, bands]) with its
    ``band_order`` (1-based band of each channel): the frame as decoded for the rectification, whose nodata value is
    read from it rather than decoded again. Memory: one uint8 plane of the frame (101 MiB for a DMC frame), worked in
    place, and a strip of its blocks."""
    import rasterio
    from rasterio.enums import MaskFlags

    with rasterio.open(path) as ds:
        flags = ds.mask_flag_enums
        if all(f == [MaskFlags.all_valid] for f in flags):
            return None
        by_value = not any(MaskFlags.per_dataset in f or MaskFlags.alpha in f for f in flags)
        lossy = ds.driver == "JPEG" or str(getattr(ds.compression, "value", ds.compression) or "").upper() == "JPEG"
    invalid = _invalid_pixels(path, image, band_order, by_value)
    if by_value:
        if lossy:
            # JPEG mixes a collar into every pixel of the blocks its edge crosses (16 x 16 px with 2 x 2 chroma
            # subsampling): those are no longer the nodata value, so valid by it (a mask is stored apart, losslessly);
            # the collar is grown by the block once taken, the value's pieces joined before (``_JPEG_JOIN_PX``)
            k = 2 * _JPEG_JOIN_PX + 1
            cv2.dilate(invalid, np.ones((k, k), np.uint8), dst=invalid)
        # the value inside the picture (not touching the edge) is picture: an area rule would take a large shadow
        # or a saturated roof for nodata, and a collar (scanned or rotated frame) always reaches the frame's edge
        _edge_connected(invalid)
        cut = 1  # 2: the collar
    else:
        cut = 0  # 1: every pixel the mask or alpha declares invalid
    if invalid.max() <= cut:  # (no temporary of the frame)
        return None
    r = _KERNEL_REACH_PX.get(interpolation, 4) + (_JPEG_BLOCK_PX - _JPEG_JOIN_PX if lossy and by_value else 0)
    valid = cv2.threshold(invalid, cut, 255, cv2.THRESH_BINARY_INV, dst=invalid)[1]  # (in place)
    return cv2.erode(valid, np.ones((2 * r + 1, 2 * r + 1), np.uint8), dst=valid)


# frames decoded larger than this are read by windows, tile by tile (a 13,824 x 7,680 px DMC frame of 16-bit
# samples holds 637 MB in RGB, 850 MB in RGBN; two frames at a time on two workers)
WINDOWED_FRAME_BYTES = 256 * 2 ** 20
# source pixels read beyond the positions a tile samples: the interpolation kernel's reach, and one more
_KERNEL_PAD_PX = {"nearest": 1, "bilinear": 2, "cubic": 3, "lanczos": 5}


class FrameFile:
    """A frame read by windows from its file (GDAL, every thread its own handle), for ``rectify_frame``:
    memory follows the tiles, not the frame. Channels in the file's band order; ``shape`` and ``dtype``
    as the decoded frame would have them (rows, cols[, bands])."""

    def __init__(self, path):
        import rasterio

        self.path = str(path)
        with rasterio.open(self.path) as ds:
            self.shape = (ds.height, ds.width) + ((ds.count,) if ds.count > 1 else ())
            self.dtype = np.dtype(ds.dtypes[0])
        self.ndim = len(self.shape)
        self._local = threading.local()
        self._open = []
        self._lock = threading.Lock()

    @property
    def band_order(self) -> list[int]:
        return list(range(1, (self.shape[2] if self.ndim == 3 else 1) + 1))

    def read(self, x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
        """Columns x0..x1, rows y0..y1 (end exclusive, inside the frame) as (rows, cols[, bands])."""
        import rasterio
        from rasterio.windows import Window

        ds = getattr(self._local, "ds", None)
        if ds is None:
            try:
                ds = self._local.ds = rasterio.open(self.path)
            except rasterio.errors.RasterioIOError as exc:
                raise InputError(f"{self.path}: cannot read the frame ({exc})") from None
            with self._lock:
                self._open.append(ds)
        try:
            a = ds.read(window=Window(x0, y0, x1 - x0, y1 - y0))
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{self.path}: cannot read the frame (truncated or corrupt? {exc})") from None
        return np.ascontiguousarray(np.moveaxis(a, 0, -1)) if self.ndim == 3 else a[0]

    def close(self) -> None:
        with self._lock:
            for ds in self._open:
                ds.close()
            self._open.clear()


def rectify_frame(image: np.ndarray, camera: Camera, centre_m, R, dem_dataset: HeightRaster, grid: OrthoGrid,
                  *, interpolation: str = "bilinear", to_project: GridToProject | None = None,
                  occlusion_dsm: HeightRaster | None = None, tile_px: int = 1024, sink=None, threads: int | None = None,
                  sink_bands_first: bool = False, max_view_angle_deg: float = 90.0, earth: bool = True,
                  occluder: FootprintOccluder | None = None, sides: OutlineHeights | None = None,
                  source_valid: np.ndarray | None = None, ground: np.ndarray | None = None):
    """Orthorectify one frame onto ``grid``; returns (ortho (H, W[, bands]) of image dtype, mask uint8 255/0).

    ``image`` is (rows, cols[, bands]) in the camera's pixel convention, in memory, or a ``FrameFile``
    read by windows as the tiles need them (the same ortho, memory set by the tiles); ``centre_m`` and ``R``
    (camera -> object, omega-phi-kappa) are in the project CRS, as is ``dem_dataset`` (a
    HeightRaster; the DSM for a true ortho). ``to_project`` maps the grid CRS to the project CRS
    (default: identical). With ``occlusion_dsm`` pixels hidden by the DSM are masked (true ortho); ``occluder``
    (``ortho.footprints.footprint_occluder`` of that DSM): building footprints in the occlusion test; ``sides``
    (``ortho.footprints.outline_heights`` of that DSM): each cell's height from its own side of the roof outlines
    (``fixed_point_maps``); ``ground`` (``ground_cells`` of that DSM and the DEM): where the occlusion test takes
    the DSM for continuous surface (``occlusion_mask``; None: nowhere).
    With ``sink(row0, col0, ortho_tile, mask_tile)`` the tiles are handed over in row-major order as
    they are made (e.g. written to a file, overlapping with the computation of the next tiles)
    instead of assembled: the returned ortho and mask are then None. With ``sink_bands_first`` the sink gets
    (bands, rows, cols) C-contiguous tiles, the layout rasterio writes without another copy (made
    here by the tile threads, not by the writer). The tiles given to the sink are reused once it
    returns: copy them if they must outlive the call.

    Cells whose ray to the projection centre is more than ``max_view_angle_deg`` from the vertical (90: no
    limit), or beyond the fold of the lens model, are invalid (``RayLimits``, tested in the kernels); so are the cells
    whose samples read a pixel the frame itself declares invalid (``source_valid``, uint8 (rows, cols) of the frame,
    0 there: ``frame_validity``; None: every pixel valid).

    Tiles of ``tile_px`` are computed by ``threads`` threads (default: all cores); the result does
    not depend on the number of threads.

    ``earth``: project-CRS points reach the camera through the ENU frame at the centre (``FrameGeometry``), as the
    adjustment's orientations and the simulator's frames mean them; False: map coordinates taken as a Cartesian
    frame (the rectifier until issue 42, kept for comparisons; the same in an engineering CRS).
    """
    if image.shape[0] != camera.height or image.shape[1] != camera.width:
        raise InputError(f"image is {image.shape[1]} x {image.shape[0]} px but the camera is {camera.width} x {camera.height} px")
    if source_valid is not None and source_valid.shape != tuple(image.shape[:2]):
        raise ValueError(f"frame validity of {source_valid.shape} px for a frame of {tuple(image.shape[:2])}")
    flag = _interpolation_flag(interpolation)
    to_project = to_project or GridToProject(grid.crs, grid.crs)
    geometry = FrameGeometry(camera, np.asarray(centre_m, float), np.asarray(R, float), float(max_view_angle_deg),
                             CameraOnEarth(to_project.project_crs, centre_m, R) if earth else None)
    bands = () if image.ndim == 2 else (image.shape[2],)
    ortho = None if sink is not None else np.zeros((grid.height, grid.width) + bands, dtype=image.dtype)
    mask = None if sink is not None else np.zeros((grid.height, grid.width), dtype=np.uint8)
    windowed = isinstance(image, FrameFile)
    pad_px = _KERNEL_PAD_PX.get(interpolation, 5)
    wide_kernel = interpolation in ("cubic", "lanczos")
    border = cv2.BORDER_REPLICATE if wide_kernel else cv2.BORDER_CONSTANT
    nb = bands[0] if bands else 1
    # only where cv2.remap has a vectorised path that such rows miss (the others gain nothing from a copy)
    compact_source = (not windowed and flag == cv2.INTER_LINEAR and image.dtype == np.uint8 and nb <= 4
                      and image.strides[0] >= _REMAP_VECTOR_MAX_STEP)
    # the compiled kernels loaded here, in the calling thread, before the tile threads call them
    from ortho import rectify_kernels  # (``import ortho.…`` would rebind the local name ortho)

    # true ortho: the frame's z-buffer of the DSM first (the occluders of a tile can lie in any other tile)
    zbuffer = frame_zbuffer(geometry, occlusion_dsm, grid, to_project, tile_px) if occlusion_dsm is not None else None
    bound = march_bound(occlusion_dsm, occluder=occluder) if occlusion_dsm is not None else None

    local = threading.local()
    # tile outputs handed to the consumer come from a pool and go back to it once consumed: fresh
    # arrays for every tile cost a page fault per 4 KiB (as much CPU as the GeoTIFF compression)
    free = queue.SimpleQueue()

    def take_out_buffers(rows, cols):
        try:
            o_flat, m_flat = free.get_nowait()
        except queue.Empty:
            o_flat, m_flat = np.empty(nb * tile_px * tile_px, image.dtype), np.empty(tile_px * tile_px, np.uint8)
        n = rows * cols
        o_shape = (nb, rows, cols) if sink_bands_first else (rows, cols) + bands
        return (o_flat, m_flat), o_flat[:nb * n].reshape(o_shape), m_flat[:n].reshape(rows, cols)

    def tile_task(rc):
        r0, c0 = rc
        tile = grid.window(c0, r0, min(tile_px, grid.width - c0), min(tile_px, grid.height - r0))
        if not hasattr(local, "buffers"):
            local.buffers = MapBuffers(tile_px)
            local.interleaved = np.empty(nb * tile_px * tile_px, image.dtype)
            local.bounds = np.empty(4, np.int32)
            local.window = SourceWindow()
            local.occluded = np.empty(tile_px * tile_px, np.bool_)
            local.near_share = np.empty(tile_px * tile_px, np.float32)
        handle, o, m = take_out_buffers(tile.height, tile.width)
        map_int, map_frac, _, z, anchors = fixed_point_maps(geometry, dem_dataset, tile, to_project,
                                                            buffers=local.buffers, mask_out=m, bounds_out=local.bounds,
                                                            sides=sides)
        if zbuffer is not None:
            # the z-buffer is fast but coarse (where a wall spans few DSM cells it puts visible points behind the
            # roof edge above them): the points it puts behind a nearer surface are decided by the march
            occ_out = local.occluded[:tile.height * tile.width].reshape(tile.height, tile.width)
            # (the tile's cell centres affine in the project CRS: the vectorised tests; else the anchors')
            affine = None if to_project.identity else to_project.affine(tile)
            near = local.near_share[:tile.height * tile.width].reshape(tile.height, tile.width) \
                if to_project.identity or affine is not None else None
            if near is not None:
                # the points tested are the maps' own (at the heights ``z`` they were made at, on the DSM of the
                # ortho whichever surface the z-buffer holds): the test reads their image positions instead of
                # projecting every pixel again
                behind = zbuffer_occlusion_from_maps(geometry, zbuffer, tile, map_int, m, z, out=occ_out,
                                                     near_share=near, affine=affine)
            else:
                behind = zbuffer_occlusion(geometry, zbuffer, z, anchors, out=occ_out)
            if behind.any():
                occluded = occlusion_mask(geometry, occlusion_dsm, tile, z, anchors, candidates=behind, bound=bound,
                                          near_share=near, occluder=occluder, ground=ground)
                rectify_kernels._clear_cells(occluded, m, map_int)
        if source_valid is not None and m.any():
            # the frame's own nodata (grown by the kernel's reach): the maps' integer positions, before any shift
            seen = cv2.remap(source_valid, map_int, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                             borderValue=0)
            rectify_kernels._clear_cells((seen == 0) & (m != 0), m, map_int)
        if not m.any():
            o[...] = 0
            return r0, c0, handle, o, m
        if windowed:  # the part of the frame this tile samples, read now; the maps shifted to it
            h_img, w_img = image.shape[:2]
            b = local.bounds
            x0, x1 = max(0, int(b[0]) - pad_px), min(w_img, int(b[1]) + 2 + pad_px)
            y0, y1 = max(0, int(b[2]) - pad_px), min(h_img, int(b[3]) + 2 + pad_px)
            src = image.read(x0, x1, y0, y1)
            cv2.subtract(map_int, (x0, y0, 0, 0), dst=map_int)
        else:
            src = local.window.source(image, map_int, local.bounds) if compact_source else image
        if nb > 4:  # cv2.remap takes at most 4 channels
            o[...] = np.moveaxis(_remap_bands(src, map_int, map_frac, flag, border), -1, 0) if sink_bands_first else \
                _remap_bands(src, map_int, map_frac, flag, border)
        elif sink_bands_first and nb > 1:
            pix = local.interleaved[:nb * tile.height * tile.width].reshape(tile.height, tile.width, nb)
            cv2.remap(src, map_int, map_frac, flag, dst=pix, borderMode=border, borderValue=0)
            cv2.split(pix, list(o))  # (rows, cols, bands) -> (bands, rows, cols) into the pooled planes
        else:
            cv2.remap(src, map_int, map_frac, flag, dst=o.reshape(tile.height, tile.width, *bands),
                      borderMode=border, borderValue=0)
        if wide_kernel or source_valid is not None:
            # cubic and Lanczos reach past the valid pixels into the replicated border; a frame's own nodata
            if sink_bands_first:
                o[:, m == 0] = 0
            else:
                o[m == 0] = 0
        return r0, c0, handle, o, m

    tiles = [(r0, c0) for r0 in range(0, grid.height, tile_px) for c0 in range(0, grid.width, tile_px)]
    with contextlib.closing(ordered_thread_map(tile_task, tiles, threads or default_threads())) as made:
        for r0, c0, handle, o, m in made:
            if sink is not None:
                sink(r0, c0, o, m)
            else:
                ortho[r0:r0 + m.shape[0], c0:c0 + m.shape[1]] = o
                mask[r0:r0 + m.shape[0], c0:c0 + m.shape[1]] = m
            free.put(handle)
    return ortho, mask


# -- footprints -------------------------------------------------------------------------------------

def border_pixels(camera: Camera, per_side: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates along the outer edge of the frame (closed ring, counter-clockwise in the image)."""
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    W, H = camera.width - 1.0, camera.height - 1.0
    x = np.concatenate([t * W, np.full_like(t, W), W - t * W, np.zeros_like(t)])
    y = np.concatenate([np.zeros_like(t), t * H, np.full_like(t, H), H - t * H])
    return x, y


def _extent_text(heights: HeightRaster, extent_m) -> str:
    """The raster's extent for an error: the whole file's (``extent_m``, xmin, ymin, xmax, ymax) when known,
    not the window read of it."""
    b = extent_m if extent_m is not None else heights.bounds
    return f"(its extent: X {b[0]:.1f} .. {b[2]:.1f}, Y {b[1]:.1f} .. {b[3]:.1f})"


_HEIGHTS_CRS = object()  # ``intersect_rays_with_heights``'s default: the height raster's CRS


def intersect_rays_with_heights(camera: Camera, centre_m, R, x_px, y_px, heights: HeightRaster, *, z_start_m: float,
                                iterations: int = 30, image_id: str = "frame", uncovered: str = "raise",
                                extent_m=None, crs=_HEIGHTS_CRS):
    """Ground points (N, 3) where the rays of pixels meet the height raster (fixed-point iteration on Z).

    The rays leave the camera over the earth (``FramesOnEarth``; ``crs``: the project CRS of ``centre_m``, ``R``
    and the heights, default ``heights.crs``; None: a Cartesian frame): in a projected CRS a ray is no straight line
    of easting, northing and height (400 ppm at the presets' origin: a DMC frame's footprint 0.28 m short 700 m from
    the nadir, against the grid's 2-cell pad).

    A ray that leaves the raster or meets nodata: ``uncovered="raise"`` raises InputError naming the frame
    and the raster's extent (``extent_m``: the whole file's, xmin, ymin, xmax, ymax; default the window in
    ``heights``); ``uncovered="plane"`` returns it on the plane Z = ``z_start_m`` and, as a second result,
    which rays met the raster (bool (N,)). Rays that do not point downwards always raise.
    """
    frame = FramesOnEarth(heights.crs if crs is _HEIGHTS_CRS else crs, centre_m, R)
    d = frame.rays_local(camera, 0, x_px, y_px)
    if np.any(d[:, 2] >= -1e-6):
        raise InputError(f"{image_id}: some rays of the frame do not point downwards (check omega/phi/kappa)")
    Z = np.full(len(d), float(z_start_m))
    covered = np.ones(len(d), bool)
    for _ in range(iterations):
        X, Y, _ = frame.at_height(0, d, Z).T
        Zn = heights.sample(X, Y)
        lost = ~np.isfinite(Zn)
        if np.any(lost & covered):
            if uncovered == "raise":
                bad = int(np.argmax(lost))
                raise InputError(
                    f"{heights.source}: the DEM does not cover frame {image_id}: its ray through pixel "
                    f"({x_px[bad]:.0f}, {y_px[bad]:.0f}) meets the ground near X={X[bad]:.1f} Y={Y[bad]:.1f}, outside the "
                    f"DEM or on nodata {_extent_text(heights, extent_m)}")
            covered &= ~lost  # from here on on the plane: a ray that left the raster is not brought back
        Zn = np.where(covered, Zn, float(z_start_m))
        # damped update: converges also where the terrain slope approaches the ray slope
        if np.max(np.abs(Zn - Z)) < 1e-3:
            Z = Zn
            break
        Z = np.where(covered, 0.5 * (Z + Zn), float(z_start_m))
    ground = frame.at_height(0, d, Z)
    return (ground, covered) if uncovered == "plane" else ground


@dataclasses.dataclass(frozen=True)
class FrameCoverage:
    """Shares of a frame's pixels (a lattice) whose rays meet a height raster on valid heights (``covered``), and
    whose rays miss it beyond the box ``extent`` given (``beyond``; the rest of the uncovered share falls on its
    nodata cells inside it)."""

    covered: float
    beyond: float

    @property
    def on_nodata(self) -> float:
        return max(0.0, 1.0 - self.covered - self.beyond)


def frame_coverage(camera: Camera, centre_m, R, heights: HeightRaster, per_side: int = 33, crs=_HEIGHTS_CRS,
                   extent=None) -> FrameCoverage:
    """``FrameCoverage`` of the frame (a ``per_side`` x ``per_side`` lattice of its pixels) on the height raster;
    ``extent`` (x0, y0, x1, y1, project CRS; default the raster's bounds) the box beyond which a miss counts as
    ``beyond`` (the rays that miss on the plane of the raster's mid height). ``crs``: as
    ``intersect_rays_with_heights``."""
    if not np.isfinite(heights.heights_m).any():
        return FrameCoverage(0.0, 0.0)
    zlo, zhi = heights.finite_range()
    u = np.linspace(0.0, camera.width - 1.0, per_side)
    v = np.linspace(0.0, camera.height - 1.0, per_side)
    x, y = (a.ravel() for a in np.meshgrid(u, v))
    g, covered = intersect_rays_with_heights(camera, centre_m, R, x, y, heights, z_start_m=0.5 * (zlo + zhi),
                                             uncovered="plane", crs=crs)
    x0, y0, x1, y1 = heights.bounds if extent is None else extent
    outside = ~covered & ((g[:, 0] < x0) | (g[:, 0] > x1) | (g[:, 1] < y0) | (g[:, 1] > y1))
    return FrameCoverage(float(np.mean(covered)), float(np.mean(outside)))


def covered_share(camera: Camera, centre_m, R, heights: HeightRaster, per_side: int = 33, crs=_HEIGHTS_CRS) -> float:
    """Share of the frame (a ``per_side`` x ``per_side`` lattice of its pixels) whose rays meet the height
    raster on valid heights (1.0: all of it; 0.0: none). ``crs``: as ``intersect_rays_with_heights``."""
    return frame_coverage(camera, centre_m, R, heights, per_side, crs).covered


def frame_grid(camera: Camera, centre_m, R, heights: HeightRaster, res_m: float, output_crs, *,
               to_project: GridToProject, image_id: str = "frame", partial: bool = False,
               max_view_angle_deg: float = 90.0) -> OrthoGrid:
    """The snapped output grid covering the ground footprint of a frame on the height raster
    (``grid_around_footprint`` of its ``footprint_polygon_xy`` of 64 rays a side).

    ``partial``: border rays that miss the raster (a DEM covering part of the frame) count with their
    point on the plane of the raster's mid height, cut to the raster's bounds, so the grid holds what the raster
    reaches of the frame and the uncovered part within it (nodata cells) becomes nodata in the ortho;
    otherwise such a ray is an InputError. With ``max_view_angle_deg``
    the footprint is cut to the cone of rays within that angle of the vertical (at the raster's lowest
    height, where the cone is widest): an oblique frame's far field, which the ortho masks, takes no grid. The
    frame's rays over the earth (``intersect_rays_with_heights``) in ``to_project.project_crs``."""
    ring = footprint_polygon_xy(camera, centre_m, R, heights, to_project=to_project, image_id=image_id, per_side=64,
                                partial=partial, max_view_angle_deg=max_view_angle_deg, min_cone_radius_m=res_m)
    return grid_around_footprint(ring, res_m, output_crs)


def grid_around_footprint(ring: np.ndarray, res_m: float, output_crs) -> OrthoGrid:
    """The snapped grid of ``res_m`` over a footprint ring (N, 2) in ``output_crs``, two cells of margin."""
    pad = 2 * res_m
    return OrthoGrid.snapped(output_crs, (float(np.min(ring[:, 0])) - pad, float(np.min(ring[:, 1])) - pad,
                                          float(np.max(ring[:, 0])) + pad, float(np.max(ring[:, 1])) + pad), res_m)


def footprint_polygon_xy(camera: Camera, centre_m, R, heights: HeightRaster, *, to_project: GridToProject,
                         image_id: str = "frame", per_side: int = 16, partial: bool = False,
                         max_view_angle_deg: float = 90.0, min_cone_radius_m: float = 0.0,
                         within_m: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """Footprint ring (N, 2) in output-CRS coordinates: the frame's border rays (``per_side`` a side) over the
    earth; ``partial`` and ``max_view_angle_deg`` as in ``frame_grid`` (a ray that misses the raster on the plane
    of its mid height; the ring cut to the cone of rays within that angle of the vertical, of at least
    ``min_cone_radius_m``). With ``partial`` the ring is also cut to the box ``within_m`` (project CRS; default the
    raster's bounds, which a window read ends at the raster's edge): beyond the raster the ortho is nodata whatever
    the grid, and a grid reaching there made the mosaic count 12 % of a drone block "seen by no frame" beyond its DSM
    (Tuniu trial). Nodata inside the raster stays in the ring: the mosaic counts it as ground no frame sees."""
    x, y = border_pixels(camera, per_side)
    zlo, zhi = heights.finite_range()
    g = intersect_rays_with_heights(camera, centre_m, R, x, y, heights, z_start_m=0.5 * (zlo + zhi), image_id=image_id,
                                    uncovered="plane" if partial else "raise", crs=to_project.project_crs)
    if partial:
        x0, y0, x1, y1 = heights.bounds if within_m is None else within_m
        g = g[0].copy()
        g[:, 0] = np.clip(g[:, 0], x0, x1)
        g[:, 1] = np.clip(g[:, 1], y0, y1)
    if max_view_angle_deg < 90.0:
        r = max((float(centre_m[2]) - zlo) * math.tan(math.radians(max_view_angle_deg)), min_cone_radius_m)
        g = g.copy()
        g[:, 0] = np.clip(g[:, 0], centre_m[0] - r, centre_m[0] + r)
        g[:, 1] = np.clip(g[:, 1], centre_m[1] - r, centre_m[1] + r)
    ox, oy = to_project.to_output(g[:, 0], g[:, 1])
    return np.stack([ox, oy], axis=-1)
