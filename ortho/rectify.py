"""Orthorectification of one frame by back-projection (ground -> image) onto a height raster.

For every pixel of the output grid (processed in tiles): the ground position in the project CRS
(interpolated from an anchor grid of the output->project CRS transform, exact for an identical CRS),
the height bilinearly from the DEM (or DSM for a true ortho), the collinearity equations with Brown
lens distortion (``aerotri.camera`` conventions) to image coordinates, then ``cv2.remap``
(bilinear default, cubic or Lanczos) with fixed-point maps written directly by the kernel. Pixels
outside the frame, behind the camera or over DEM nodata are invalid (mask 0, value 0).

The collinearity is evaluated exactly at every output pixel in a compiled kernel: it costs about as
much as interpolating image coordinates from a coarse anchor grid, and unlike that interpolation it
stays exact where the DEM is rough (relief displacement reaches several pixels per metre of height
at the edge of a large-format frame), so the mapping error is zero instead of merely < 0.1 px.

True ortho: with ``occlusion_dsm`` every ground point is tested for visibility by marching along its
ray towards the projection centre over the DSM; occluded pixels are invalid (mask 0), so the mosaic
fills them from other frames.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numba
import numpy as np

from aerotri.camera import FrameCamera
from aerotri.errors import InputError
from aerotri.rotation import FLIP_YZ
from ortho.dem import HeightRaster
from ortho.grid import GridToProject, OrthoGrid

INTERPOLATION = {"nearest": cv2.INTER_NEAREST, "bilinear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "lanczos": cv2.INTER_LANCZOS4}

_INVALID = -1.0e5  # image coordinate written for invalid pixels (far outside any frame)


INTER_BITS = 5  # cv2.remap fixed-point maps: 1/32 px sub-pixel positions (what it uses internally anyway)
INTER_TAB_SIZE = 1 << INTER_BITS


# fast-math without "nnan"/"ninf": the NaN test for DEM nodata must survive
_FASTMATH = {"contract", "arcp", "reassoc", "nsz", "afn"}


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _ground_to_image(r, c, inv_s, anchor_x, anchor_y, dem, dem_x0, dem_y0, dem_res, centre, M, cam, width, height,
                     margin):
    """Ground point of output pixel (r, c), its height and image position; ok False if not imaged."""
    ar = r * inv_s
    i0 = min(int(ar), anchor_x.shape[0] - 2)
    fr = ar - i0
    ac = c * inv_s
    j0 = min(int(ac), anchor_x.shape[1] - 2)
    fc = ac - j0
    w00 = (1.0 - fr) * (1.0 - fc)
    w01 = (1.0 - fr) * fc
    w10 = fr * (1.0 - fc)
    w11 = fr * fc
    X = anchor_x[i0, j0] * w00 + anchor_x[i0, j0 + 1] * w01 + anchor_x[i0 + 1, j0] * w10 + anchor_x[i0 + 1, j0 + 1] * w11
    Y = anchor_y[i0, j0] * w00 + anchor_y[i0, j0 + 1] * w01 + anchor_y[i0 + 1, j0] * w10 + anchor_y[i0 + 1, j0 + 1] * w11
    dh, dw = dem.shape
    # bilinear height, clamped half a pixel beyond the outer centres
    u = (X - dem_x0) / dem_res - 0.5
    v = (dem_y0 - Y) / dem_res - 0.5
    if not (u >= -0.5 and u <= dw - 0.5 and v >= -0.5 and v <= dh - 0.5):
        return np.nan, 0.0, 0.0, False
    u = min(max(u, 0.0), dw - 1.0)
    v = min(max(v, 0.0), dh - 1.0)
    di = min(int(v), max(dh - 2, 0))
    dj = min(int(u), max(dw - 2, 0))
    fv = v - di
    fu = u - dj
    di1 = min(di + 1, dh - 1)
    dj1 = min(dj + 1, dw - 1)
    Z = (dem[di, dj] * (1.0 - fu) * (1.0 - fv) + dem[di, dj1] * fu * (1.0 - fv)
         + dem[di1, dj] * (1.0 - fu) * fv + dem[di1, dj1] * fu * fv)
    if Z != Z:  # DEM nodata
        return Z, 0.0, 0.0, False
    dx = X - centre[0]
    dy = Y - centre[1]
    dz = Z - centre[2]
    zc = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
    if zc <= 0.0:  # behind the camera
        return Z, 0.0, 0.0, False
    xn = (M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz) / zc
    yn = (M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz) / zc
    k1, k2, k3, p1, p2 = cam[3], cam[4], cam[5], cam[6], cam[7]
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    x = cam[0] * xd + cam[1]
    y = cam[0] * yd + cam[2]
    ok = x >= margin and x <= width - 1 - margin and y >= margin and y <= height - 1 - margin
    return Z, x, y, ok


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _backproject_kernel(anchor_x, anchor_y, spacing, rows, cols, dem, dem_x0, dem_y0, dem_res,
                        centre, M, cam, width, height, margin, map_x, map_y, height_out):
    """Float image coordinates (map_x, map_y; -1e5 where not imaged) and heights of a rows x cols tile.

    cam = (f_px, cx_px, cy_px, k1, k2, k3, p1, p2); M = (R @ FLIP_YZ).T maps object offsets to the
    computer-vision camera frame.
    """
    inv_s = 1.0 / spacing
    for r in numba.prange(rows):
        for c in range(cols):
            Z, x, y, ok = _ground_to_image(r, c, inv_s, anchor_x, anchor_y, dem, dem_x0, dem_y0, dem_res, centre, M,
                                           cam, width, height, margin)
            map_x[r, c] = x if ok else _INVALID
            map_y[r, c] = y if ok else _INVALID
            height_out[r, c] = Z


@numba.njit(cache=True, inline="always")
def _store_map(map_int, map_frac, mask, r, c, x, y, ok):
    """One pixel of cv2.remap's fixed-point map (integer part + interpolation-table index) and its mask."""
    if ok:
        ix = int(x * INTER_TAB_SIZE + 0.5)  # x, y >= 0 here: truncation rounds
        iy = int(y * INTER_TAB_SIZE + 0.5)
        map_int[r, c, 0] = ix >> INTER_BITS
        map_int[r, c, 1] = iy >> INTER_BITS
        map_frac[r, c] = (iy & (INTER_TAB_SIZE - 1)) * INTER_TAB_SIZE + (ix & (INTER_TAB_SIZE - 1))
        mask[r, c] = 255
    else:
        map_int[r, c, 0] = -32768
        map_int[r, c, 1] = -32768
        map_frac[r, c] = 0
        mask[r, c] = 0


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _fixed_point_kernel(anchor_x, anchor_y, spacing, rows, cols, dem, dem_x0, dem_y0, dem_res,
                        centre, M, cam, width, height, margin, map_int, map_frac, mask, height_out):
    """As _backproject_kernel, but writes cv2.remap's fixed-point maps directly (CV_16SC2 integer
    positions + CV_16UC1 1/32 px fractions, as cv2.convertMaps would) and the validity mask (255/0).
    Not-imaged pixels point far outside the image, so cv2.remap with a constant border gives 0."""
    inv_s = 1.0 / spacing
    for r in numba.prange(rows):
        for c in range(cols):
            Z, x, y, ok = _ground_to_image(r, c, inv_s, anchor_x, anchor_y, dem, dem_x0, dem_y0, dem_res, centre, M,
                                           cam, width, height, margin)
            height_out[r, c] = Z
            _store_map(map_int, map_frac, mask, r, c, x, y, ok)


@numba.njit(parallel=True, cache=True)
def _occlusion_kernel(anchor_x, anchor_y, spacing, rows, cols, height_tile, dsm, dsm_x0, dsm_y0, dsm_res,
                      dsm_max, centre, tolerance_m, occluded):
    """Mark ground points whose ray to the projection centre passes below the DSM surface.

    March from the ground point towards the centre in steps of one DSM cell (horizontally), stop when
    the ray is above the highest DSM value; occluded if the DSM exceeds the ray by ``tolerance_m``.
    """
    dh, dw = dsm.shape
    inv_s = 1.0 / spacing
    for r in numba.prange(rows):
        ar = r * inv_s
        i0 = min(int(ar), anchor_x.shape[0] - 2)
        fr = ar - i0
        for c in range(cols):
            Z = height_tile[r, c]
            if Z != Z:
                continue
            ac = c * inv_s
            j0 = min(int(ac), anchor_x.shape[1] - 2)
            fc = ac - j0
            X = ((1 - fr) * (1 - fc) * anchor_x[i0, j0] + (1 - fr) * fc * anchor_x[i0, j0 + 1]
                 + fr * (1 - fc) * anchor_x[i0 + 1, j0] + fr * fc * anchor_x[i0 + 1, j0 + 1])
            Y = ((1 - fr) * (1 - fc) * anchor_y[i0, j0] + (1 - fr) * fc * anchor_y[i0, j0 + 1]
                 + fr * (1 - fc) * anchor_y[i0 + 1, j0] + fr * fc * anchor_y[i0 + 1, j0 + 1])
            vx = centre[0] - X
            vy = centre[1] - Y
            vz = centre[2] - Z
            hd = math.sqrt(vx * vx + vy * vy)
            if hd < 1e-9 or vz <= 0:
                continue
            rise = vz / hd  # metres of ray height per metre horizontally
            ux = vx / hd
            uy = vy / hd
            t = dsm_res
            while True:
                zr = Z + rise * t
                if zr > dsm_max:
                    break
                px = X + ux * t
                py = Y + uy * t
                u = (px - dsm_x0) / dsm_res - 0.5
                v = (dsm_y0 - py) / dsm_res - 0.5
                if u < 0 or v < 0 or u > dw - 1 or v > dh - 1:
                    break
                di = min(int(v), dh - 2)
                dj = min(int(u), dw - 2)
                fv = v - di
                fu = u - dj
                zs = (dsm[di, dj] * (1 - fu) * (1 - fv) + dsm[di, dj + 1] * fu * (1 - fv)
                      + dsm[di + 1, dj] * (1 - fu) * fv + dsm[di + 1, dj + 1] * fu * fv)
                if zs > zr + tolerance_m:
                    occluded[r, c] = True
                    break
                t += dsm_res


@dataclasses.dataclass
class FrameGeometry:
    """The per-frame inputs of the back-projection."""

    camera: FrameCamera
    centre_m: np.ndarray
    R: np.ndarray

    def kernel_args(self):
        cam = self.camera
        M = np.ascontiguousarray((np.asarray(self.R, float) @ FLIP_YZ).T)
        params = np.array([cam.focal_px, cam.cx_px, cam.cy_px, cam.k1, cam.k2, cam.k3, cam.p1, cam.p2], dtype=np.float64)
        return np.asarray(self.centre_m, dtype=np.float64), M, params


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _fixed_point_kernel_affine(heights, x0, y0, res, centre, M, cam, width, height, margin, map_int, map_frac, mask):
    """Fast path of _fixed_point_kernel when the output grid is in the project CRS: ground X, Y are
    affine in (row, col) and the heights on the grid are given (bilinear DEM, see heights_on_grid)."""
    rows, cols = heights.shape
    f, cx, cy, k1, k2, k3, p1, p2 = cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], cam[7]
    for r in numba.prange(rows):
        dy = y0 - r * res - centre[1]
        # camera-frame coordinates are affine along the row: start + c * step + dz * column of M
        bx = M[0, 1] * dy + M[0, 0] * (x0 - centre[0])
        by = M[1, 1] * dy + M[1, 0] * (x0 - centre[0])
        bz = M[2, 1] * dy + M[2, 0] * (x0 - centre[0])
        sx = M[0, 0] * res
        sy = M[1, 0] * res
        sz = M[2, 0] * res
        for c in range(cols):
            Z = heights[r, c]
            ok = False
            x = 0.0
            y = 0.0
            if Z == Z:
                dz = Z - centre[2]
                zc = bz + c * sz + M[2, 2] * dz
                if zc > 0.0:
                    xn = (bx + c * sx + M[0, 2] * dz) / zc
                    yn = (by + c * sy + M[1, 2] * dz) / zc
                    r2 = xn * xn + yn * yn
                    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                    x = f * (xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)) + cx
                    y = f * (yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn) + cy
                    ok = x >= margin and x <= width - 1 - margin and y >= margin and y <= height - 1 - margin
            _store_map(map_int, map_frac, mask, r, c, x, y, ok)


def heights_on_grid(dem: HeightRaster, grid: OrthoGrid) -> np.ndarray:
    """Bilinear DEM heights at the pixel centres of a grid in the DEM's CRS (float32, NaN = nodata).

    cv2.warpAffine does the resampling (vectorised; positions quantised to 1/32 DEM cell, i.e. 3 cm
    for a 1 m DEM, far below what moves a ground point in the image). NaN propagates from nodata
    cells; within half a DEM cell of the raster edge heights are NaN.
    """
    scale = grid.res_m / dem.res_m
    u0 = (grid.x_left_m + 0.5 * grid.res_m - dem.x_left_m) / dem.res_m - 0.5
    v0 = (dem.y_top_m - (grid.y_top_m - 0.5 * grid.res_m)) / dem.res_m - 0.5
    A = np.array([[scale, 0.0, u0], [0.0, scale, v0]])
    return cv2.warpAffine(dem.heights_m, A, (grid.width, grid.height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))


def image_coordinates(geometry: FrameGeometry, dem: HeightRaster, grid: OrthoGrid, to_project: GridToProject | None = None,
                      margin_px: float = 0.0):
    """Image coordinates (map_x, map_y float32) and heights (float32) for every pixel of ``grid``.

    Pixels not imaged (outside the frame, behind the camera, DEM nodata) have map = -1e5.
    Returns (map_x, map_y, heights, anchors).
    """
    to_project = to_project or GridToProject(grid.crs, grid.crs)
    AX, AY, s = to_project.anchors(grid)
    centre, M, params = geometry.kernel_args()
    shape = (grid.height, grid.width)
    map_x = np.empty(shape, np.float32)
    map_y = np.empty(shape, np.float32)
    z = np.empty(shape, np.float32)
    _backproject_kernel(AX, AY, float(s), grid.height, grid.width, dem.heights_m, dem.x_left_m, dem.y_top_m, dem.res_m,
                        centre, M, params, geometry.camera.width, geometry.camera.height, float(margin_px),
                        map_x, map_y, z)
    return map_x, map_y, z, (AX, AY, s)


def fixed_point_maps(geometry: FrameGeometry, dem: HeightRaster, grid: OrthoGrid, to_project: GridToProject | None = None,
                     margin_px: float = 0.0):
    """cv2.remap fixed-point maps (int16 (H, W, 2), uint16 (H, W)), validity mask (uint8 255/0), heights, anchors."""
    to_project = to_project or GridToProject(grid.crs, grid.crs)
    AX, AY, s = to_project.anchors(grid)
    centre, M, params = geometry.kernel_args()
    shape = (grid.height, grid.width)
    map_int = np.empty(shape + (2,), np.int16)
    map_frac = np.empty(shape, np.uint16)
    mask = np.empty(shape, np.uint8)
    if to_project.identity:
        z = heights_on_grid(dem, grid)
        _fixed_point_kernel_affine(z, grid.x_left_m + 0.5 * grid.res_m, grid.y_top_m - 0.5 * grid.res_m, grid.res_m,
                                   centre, M, params, geometry.camera.width, geometry.camera.height, float(margin_px),
                                   map_int, map_frac, mask)
        return map_int, map_frac, mask, z, (AX, AY, s)
    z = np.empty(shape, np.float32)
    _fixed_point_kernel(AX, AY, float(s), grid.height, grid.width, dem.heights_m, dem.x_left_m, dem.y_top_m, dem.res_m,
                        centre, M, params, geometry.camera.width, geometry.camera.height, float(margin_px),
                        map_int, map_frac, mask, z)
    return map_int, map_frac, mask, z, (AX, AY, s)


def occlusion_mask(geometry: FrameGeometry, dsm: HeightRaster, grid: OrthoGrid, heights_m: np.ndarray, anchors,
                   tolerance_m: float = 0.3) -> np.ndarray:
    """True where the ground point (grid pixel at ``heights_m``) is hidden from the camera by the DSM."""
    AX, AY, s = anchors
    occ = np.zeros((grid.height, grid.width), dtype=np.bool_)
    zmax = float(np.nanmax(dsm.heights_m))
    _occlusion_kernel(AX, AY, float(s), grid.height, grid.width, heights_m.astype(np.float32), dsm.heights_m,
                      dsm.x_left_m, dsm.y_top_m, dsm.res_m, zmax, np.asarray(geometry.centre_m, np.float64),
                      float(tolerance_m), occ)
    return occ


def remap(image: np.ndarray, map1: np.ndarray, map2: np.ndarray, interpolation: str = "bilinear",
          border=cv2.BORDER_CONSTANT) -> np.ndarray:
    """cv2.remap with float maps (x, y) or fixed-point maps (int16 pairs, uint16 fractions).

    Not-imaged pixels point far outside the image and get 0 from the constant border; valid pixels
    lie within the outer pixel centres, so bilinear never blends with the border. Cubic and Lanczos
    reach 1-3 px further: use ``border=cv2.BORDER_REPLICATE`` and zero the invalid pixels afterwards.
    """
    try:
        flag = INTERPOLATION[interpolation]
    except KeyError:
        raise InputError(f"unknown interpolation {interpolation!r}; expected one of {sorted(INTERPOLATION)}") from None
    if image.ndim == 3 and image.shape[2] > 4:
        return np.stack([cv2.remap(image[:, :, b], map1, map2, flag, borderMode=border, borderValue=0)
                         for b in range(image.shape[2])], axis=-1)
    out = cv2.remap(image, map1, map2, flag, borderMode=border, borderValue=0)
    if image.ndim == 3 and out.ndim == 2:
        out = out[:, :, None]
    return out


def rectify_frame(image: np.ndarray, camera: FrameCamera, centre_m, R, dem_dataset: HeightRaster, grid: OrthoGrid,
                  interpolation: str = "bilinear", to_project: GridToProject | None = None,
                  occlusion_dsm: HeightRaster | None = None, tile_px: int = 1024, sink=None):
    """Orthorectify one frame onto ``grid``; returns (ortho (H, W[, bands]) of image dtype, mask uint8 255/0).

    ``image`` is (rows, cols[, bands]) in the camera's pixel convention; ``centre_m`` and ``R``
    (camera -> object, omega-phi-kappa) are in the project CRS, as is ``dem_dataset`` (a
    HeightRaster; the DSM for a true ortho). ``to_project`` maps the grid CRS to the project CRS
    (default: identical). With ``occlusion_dsm`` pixels hidden by the DSM are masked (true ortho).
    With ``sink(row0, col0, ortho_tile, mask_tile)`` the tiles are handed over as they are made
    (e.g. written to a file) instead of assembled: the returned ortho is then None.
    """
    if image.shape[0] != camera.height or image.shape[1] != camera.width:
        raise InputError(f"image is {image.shape[1]} x {image.shape[0]} px but the camera is {camera.width} x {camera.height} px")
    geometry = FrameGeometry(camera, np.asarray(centre_m, float), np.asarray(R, float))
    to_project = to_project or GridToProject(grid.crs, grid.crs)
    bands = () if image.ndim == 2 else (image.shape[2],)
    ortho = None if sink is not None else np.zeros((grid.height, grid.width) + bands, dtype=image.dtype)
    mask = np.zeros((grid.height, grid.width), dtype=np.uint8)
    wide_kernel = interpolation in ("cubic", "lanczos")
    for r0 in range(0, grid.height, tile_px):
        for c0 in range(0, grid.width, tile_px):
            tile = grid.window(c0, r0, min(tile_px, grid.width - c0), min(tile_px, grid.height - r0))
            map_int, map_frac, m, z, anchors = fixed_point_maps(geometry, dem_dataset, tile, to_project)
            if occlusion_dsm is not None:
                occluded = occlusion_mask(geometry, occlusion_dsm, tile, z, anchors)
                m[occluded] = 0
                map_int[occluded] = -32768
            mask[r0:r0 + tile.height, c0:c0 + tile.width] = m
            if not m.any():
                if sink is not None:
                    sink(r0, c0, np.zeros((tile.height, tile.width) + bands, image.dtype), m)
                continue
            if wide_kernel:
                o = remap(image, map_int, map_frac, interpolation, cv2.BORDER_REPLICATE)
                o[m == 0] = 0
            else:
                o = remap(image, map_int, map_frac, interpolation)
            if sink is not None:
                sink(r0, c0, o, m)
            else:
                ortho[r0:r0 + tile.height, c0:c0 + tile.width] = o
    return ortho, mask


# -- footprints -------------------------------------------------------------------------------------

def border_pixels(camera: FrameCamera, per_side: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates along the outer edge of the frame (closed ring, counter-clockwise in the image)."""
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    W, H = camera.width - 1.0, camera.height - 1.0
    x = np.concatenate([t * W, np.full_like(t, W), W - t * W, np.zeros_like(t)])
    y = np.concatenate([np.zeros_like(t), t * H, np.full_like(t, H), H - t * H])
    return x, y


def intersect_rays_with_heights(camera: FrameCamera, centre_m, R, x_px, y_px, heights: HeightRaster, z_start_m: float,
                                iterations: int = 30, image_id: str = "frame"):
    """Ground points (N, 3) where the rays of pixels meet the height raster (fixed-point iteration on Z).

    Raises InputError naming the frame when a ray leaves the raster or meets nodata (the DEM does not
    cover the frame) or does not point downwards.
    """
    C = np.asarray(centre_m, float)
    d = camera.rays(x_px, y_px, R)
    if np.any(d[:, 2] >= -1e-6):
        raise InputError(f"{image_id}: some rays of the frame do not point downwards (check omega/phi/kappa)")
    Z = np.full(len(d), float(z_start_m))
    for _ in range(iterations):
        t = (Z - C[2]) / d[:, 2]
        X = C[0] + t * d[:, 0]
        Y = C[1] + t * d[:, 1]
        Zn = heights.sample(X, Y)
        if np.any(~np.isfinite(Zn)):
            bad = int(np.argmax(~np.isfinite(Zn)))
            raise InputError(
                f"{heights.source}: the DEM does not cover frame {image_id}: its ray through pixel "
                f"({x_px[bad]:.0f}, {y_px[bad]:.0f}) meets the ground near X={X[bad]:.1f} Y={Y[bad]:.1f}, outside the "
                f"DEM or on nodata (DEM bounds {tuple(round(b, 1) for b in heights.bounds)})"
            )
        # damped update: converges also where the terrain slope approaches the ray slope
        if np.max(np.abs(Zn - Z)) < 1e-3:
            Z = Zn
            break
        Z = 0.5 * (Z + Zn)
    t = (Z - C[2]) / d[:, 2]
    return np.stack([C[0] + t * d[:, 0], C[1] + t * d[:, 1], Z], axis=-1)


def frame_grid(camera: FrameCamera, centre_m, R, heights: HeightRaster, res_m: float, output_crs, to_project: GridToProject,
               image_id: str = "frame") -> OrthoGrid:
    """The snapped output grid covering the ground footprint of a frame on the height raster."""
    x, y = border_pixels(camera)
    zlo, zhi = heights.finite_range()
    ground = intersect_rays_with_heights(camera, centre_m, R, x, y, heights, 0.5 * (zlo + zhi), image_id=image_id)
    ox, oy = to_project.to_output(ground[:, 0], ground[:, 1])
    pad = 2 * res_m
    return OrthoGrid.snapped(output_crs, (np.min(ox) - pad, np.min(oy) - pad, np.max(ox) + pad, np.max(oy) + pad), res_m)


def footprint_polygon_xy(camera: FrameCamera, centre_m, R, heights: HeightRaster, to_project: GridToProject,
                         image_id: str = "frame", per_side: int = 16) -> np.ndarray:
    """Footprint ring (N, 2) in output-CRS coordinates."""
    x, y = border_pixels(camera, per_side)
    zlo, zhi = heights.finite_range()
    g = intersect_rays_with_heights(camera, centre_m, R, x, y, heights, 0.5 * (zlo + zhi), image_id=image_id)
    ox, oy = to_project.to_output(g[:, 0], g[:, 1])
    return np.stack([ox, oy], axis=-1)
