"""The compiled kernels of ``ortho.rectify`` (numba): back-projection of output pixels through the DEM and
the camera into cv2.remap's fixed-point maps, and the occlusion test of a true ortho. A module of their own
so that the commands without rectification (``ortho mosaic``, ``ortho check``) do not import numba (about
0.3 CPU-s) nor load compiled code; ``ortho.rectify`` imports it when it first maps a tile.

The kernels take their repeated argument groups as the NamedTuples of ``ortho.rectify`` (built there, read here by
field name): ``HeightGrid`` (a DEM or DSM: heights, top-left corner, cell size), ``AnchorGrid`` (a tile's project
coordinates at every ``spacing``-th output pixel), ``AffineTile`` (a tile of the output grid in the project CRS:
heights, first cell centre, cell size), ``FrameArgs`` (projection centre, object -> camera matrix, lens parameters,
frame size, ``RayLimits``, the earth's 1 / radius: every kernel projects (dx, dy, ``earth_dz``) through the matrix), ``RemapMaps`` (cv2.remap's fixed-point maps, mask and bounds, written),
``ZBufferArgs`` (depth per cell, cell size, tolerance), ``MarchArgs`` and ``TilePoints`` (the march's bounds and
settings; the points of a tile it tests).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from aerotri.geom.lens_kernels import to_pixel
from aerotri.geom.local_frame import earth_dz

_INVALID = -1.0e5  # image coordinate written for invalid pixels (far outside any frame)
INTER_BITS = 5  # cv2.remap fixed-point maps: 1/32 px sub-pixel positions (what it uses internally anyway)
INTER_TAB_SIZE = 1 << INTER_BITS

# fast-math without "nnan"/"ninf": the NaN test for DEM nodata must survive
_FASTMATH = {"contract", "arcp", "reassoc", "nsz", "afn"}


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _dem_height(grid, X, Y):
    """Bilinear height of ``HeightGrid`` ``grid`` at (X, Y), clamped half a pixel beyond the outer cell centres; NaN
    outside the grid or on nodata. Computed without an early return so that loops over it stay branch-free."""
    dem = grid.heights_m
    dh, dw = dem.shape
    u = (X - grid.x_left_m) / grid.res_m - 0.5
    v = (grid.y_top_m - Y) / grid.res_m - 0.5
    inside = u >= -0.5 and u <= dw - 0.5 and v >= -0.5 and v <= dh - 0.5
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
    return Z if inside else np.nan


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _fixed_point_entry(x, y, in_front, window, far):
    """cv2.remap 1/32 px fixed-point x, y and mask (255/0) of one output pixel, imaged where ``in_front`` and within
    ``window`` (x_lo, x_hi, y_lo, y_hi). Where imaged x, y >= 0, so truncation rounds; not imaged: ``far`` outside the
    image, branch-free (a select, vectorisable)."""
    x_lo, x_hi, y_lo, y_hi = window
    ok = in_front & (x >= x_lo) & (x <= x_hi) & (y >= y_lo) & (y <= y_hi)
    return (np.int32(x * INTER_TAB_SIZE + 0.5) if ok else far, np.int32(y * INTER_TAB_SIZE + 0.5) if ok else far,
            np.uint8(255) if ok else np.uint8(0))


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _within_limits(xn, yn, dx, dy, dz, limits):
    """Whether the ray of a point in front of the camera (normalised position xn, yn; offset dx, dy, dz from the
    projection centre, m) is inside the lens model's fold and within the view angle of the vertical (``limits``:
    ``ortho.rectify.RayLimits``, inf where none). Beyond the fold the model turns back and
    puts ground far outside the field of view inside the frame: such a point must neither be imaged nor stand in a
    z-buffer. The tests are loop-invariant branches: the compiler makes loops without the tests that do not apply
    (a lens that does not fold, no view angle: the maps cost what they did without them)."""
    ok = True
    if limits.fold_r2 != np.inf:
        ok = xn * xn + yn * yn <= limits.fold_r2
    if limits.tan2_vertical != np.inf:
        ok = ok & (dz < 0.0) & (dx * dx + dy * dy <= limits.tan2_vertical * (dz * dz))
    return ok


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _ground_to_image(r, c, anchors, dem, frame, margin):
    """Ground point of output pixel (r, c) (``AnchorGrid`` ``anchors``), its height on ``HeightGrid`` ``dem`` and its
    image position in ``FrameArgs`` ``frame``; ok False if not imaged (outside the DEM, behind the camera, beyond the
    frame's ``RayLimits``, outside the frame less ``margin`` px)."""
    anchor_x, anchor_y = anchors.x_m, anchors.y_m
    centre, M = frame.centre_m, frame.M
    inv_s = 1.0 / anchors.spacing_px
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
    Z = _dem_height(dem, X, Y)
    if Z != Z:  # outside the DEM or on its nodata
        return Z, 0.0, 0.0, False
    dx = X - centre[0]
    dy = Y - centre[1]
    dz = Z - centre[2]
    dze = earth_dz(dx, dy, dz, frame.inv_radius)  # the camera sees the point there (dz in a Cartesian CRS)
    zc = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dze
    if zc <= 0.0:  # behind the camera
        return Z, 0.0, 0.0, False
    xn = (M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dze) / zc
    yn = (M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dze) / zc
    x, y = to_pixel(frame.cam, xn, yn)
    ok = (x >= margin and x <= frame.width_px - 1 - margin and y >= margin and y <= frame.height_px - 1 - margin
          and _within_limits(xn, yn, dx, dy, dz, frame.limits))
    return Z, x, y, ok


@numba.njit(cache=True, fastmath=_FASTMATH)
def _backproject_kernel(anchors, dem, frame, margin, out):
    """Float image coordinates (map_x, map_y; -1e5 where not imaged) and heights of a tile into ``out`` (map_x,
    map_y, heights: (rows, cols) each).

    ``frame.cam``: the camera's kernel parameters (``Camera.kernel_params()``, any model of
    ``aerotri.geom.lens_kernels``); ``frame.M`` = (R @ FLIP_YZ).T maps object offsets to the computer-vision camera
    frame. Serial (the reference of the fixed-point kernels; numba's parallel loops do not take the argument
    tuples).
    """
    map_x, map_y, height_out = out
    rows, cols = map_x.shape
    for r in range(rows):
        for c in range(cols):
            Z, x, y, ok = _ground_to_image(r, c, anchors, dem, frame, margin)
            map_x[r, c] = x if ok else _INVALID
            map_y[r, c] = y if ok else _INVALID
            height_out[r, c] = Z


@numba.njit(cache=True, nogil=True)
def _pack_fixed_point(ix_row, iy_row, int_row, frac_row, bounds):
    """1/32 px fixed-point positions -> cv2.remap's CV_16SC2 integer part + CV_16UC1 table index (one row).

    ``bounds`` (int32 x_min, x_max, y_min, y_max of the integer parts of the imaged pixels, which are
    >= 0; not-imaged ones are far negative) is widened by this row."""
    x_min, x_max, y_min, y_max = bounds[0], bounds[1], bounds[2], bounds[3]
    for c in range(ix_row.shape[0]):
        ix = ix_row[c]
        iy = iy_row[c]
        xi = ix >> INTER_BITS
        yi = iy >> INTER_BITS
        int_row[c, 0] = np.int16(xi)
        int_row[c, 1] = np.int16(yi)
        frac_row[c] = np.uint16(((iy & (INTER_TAB_SIZE - 1)) << INTER_BITS) | (ix & (INTER_TAB_SIZE - 1)))
        x_min = min(x_min, xi if xi >= 0 else x_min)
        x_max = max(x_max, xi)
        y_min = min(y_min, yi if yi >= 0 else y_min)
        y_max = max(y_max, yi)
    bounds[0], bounds[1], bounds[2], bounds[3] = x_min, x_max, y_min, y_max


@numba.njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _fixed_point_kernel(anchors, dem, frame, margin, maps, height_out):
    """As _backproject_kernel, but writes cv2.remap's fixed-point maps directly (``RemapMaps`` ``maps``: CV_16SC2
    integer positions + CV_16UC1 1/32 px fractions, as cv2.convertMaps would), the validity mask (255/0) and
    the integer bounds of the imaged positions (``bounds``, see _pack_fixed_point), and the heights.
    Not-imaged pixels point far outside the image, so cv2.remap with a constant border gives 0.
    Loop invariants are hoisted by hand (LLVM cannot prove the output arrays do not alias them)."""
    anchor_x, anchor_y = anchors.x_m, anchors.y_m
    centre, M, cam, limits, inv_r = frame.centre_m, frame.M, frame.cam, frame.limits, frame.inv_radius
    map_int, map_frac, mask, bounds = maps
    rows, cols = height_out.shape
    inv_s = 1.0 / anchors.spacing_px
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = (M[0, 0], M[0, 1], M[0, 2], M[1, 0], M[1, 1], M[1, 2],
                                                   M[2, 0], M[2, 1], M[2, 2])
    c0, c1, c2 = centre[0], centre[1], centre[2]
    window = (margin, frame.width_px - 1 - margin, margin, frame.height_px - 1 - margin)
    na = anchor_x.shape[1]
    far = np.int32(-32768 * INTER_TAB_SIZE)
    ix_row = np.empty(cols, np.int32)
    iy_row = np.empty(cols, np.int32)
    for r in range(rows):
        ar = r * inv_s
        i0 = min(int(ar), anchor_x.shape[0] - 2)
        fr = ar - i0
        ax0, ax1, ay0, ay1 = anchor_x[i0], anchor_x[i0 + 1], anchor_y[i0], anchor_y[i0 + 1]
        mask_row, z_row = mask[r], height_out[r]
        for c in range(cols):
            ac = c * inv_s
            j0 = min(int(ac), na - 2)
            fc = ac - j0
            X = (1.0 - fr) * ((1.0 - fc) * ax0[j0] + fc * ax0[j0 + 1]) + fr * ((1.0 - fc) * ax1[j0] + fc * ax1[j0 + 1])
            Y = (1.0 - fr) * ((1.0 - fc) * ay0[j0] + fc * ay0[j0 + 1]) + fr * ((1.0 - fc) * ay1[j0] + fc * ay1[j0 + 1])
            Z = _dem_height(dem, X, Y)
            z_row[c] = Z
            dx = X - c0
            dy = Y - c1
            dz = Z - c2
            dze = earth_dz(dx, dy, dz, inv_r)
            zc = m20 * dx + m21 * dy + m22 * dze
            inv_zc = 1.0 / zc
            xn = (m00 * dx + m01 * dy + m02 * dze) * inv_zc
            yn = (m10 * dx + m11 * dy + m12 * dze) * inv_zc
            x, y = to_pixel(cam, xn, yn)
            seen = (zc > 0.0) & _within_limits(xn, yn, dx, dy, dz, limits)
            ix_row[c], iy_row[c], mask_row[c] = _fixed_point_entry(x, y, seen, window, far)
        _pack_fixed_point(ix_row, iy_row, map_int[r], map_frac[r], bounds)


@numba.njit(cache=True, inline="always")
def _next_boundary(g, e, k):
    """Parameter s at which g + e s leaves cell k ([k, k + 1)) of a grid axis (1e30 when it runs along it)."""
    if e > 1e-12:
        return (k + 1 - g) / e
    if e < -1e-12:
        return (k - g) / e
    return 1e30


@numba.njit(cache=True, inline="always")
def _boundary_in(g, e, k):
    """Parameter s at which g + e s enters cell k of a grid axis (-1e30 when it runs along it)."""
    if e > 1e-12:
        return (k - g) / e
    if e < -1e-12:
        return (k + 1 - g) / e
    return -1e30


@numba.njit(cache=True, inline="always")
def _dda_step(boundary, between, cell, step):
    """One step of the 2D DDA: into the next cell across the nearer of the column and row boundaries (``boundary``:
    their parameters sx, sy; ``between``: the parameter between two column / row boundaries; ``cell``: i, j;
    ``step``: the row and column steps); returns the parameter s where the ray enters that cell, the next
    boundaries and the cell (i, j)."""
    sx, sy = boundary
    i, j = cell
    if sx < sy:
        return sx, sx + between[0], sy, i, j + step[1]
    return sy, sx, sy + between[1], i + step[0], j


_MARGIN_NONE = -32768  # ``ortho.footprints.MARGIN_NONE``: a sub-cell that carries no slab


@numba.njit(cache=True, inline="always")
def _in_slab(sub_masks, sub_margin_cm, m, v, u, sub):
    """Whether the point at sub-cell coordinates (``v`` rows from the north, ``u`` columns from the west, 0 .. sub)
    of mask ``m`` lies within the roof outline: the sub-cells' margins within it (cm, at their centres) interpolated
    bilinearly (extrapolated over the outer half sub-cell), >= 0; where a neighbour carries no slab (``_MARGIN_NONE``)
    or a cell has one sub-cell, its sub-cell's bit 2."""
    a = min(max(int(v), 0), sub - 1)
    b = min(max(int(u), 0), sub - 1)
    if sub < 2:
        return (sub_masks[m, a, b] & 2) != 0
    fv = v - 0.5
    fu = u - 0.5
    a0 = min(max(int(math.floor(fv)), 0), sub - 2)
    b0 = min(max(int(math.floor(fu)), 0), sub - 2)
    m00 = sub_margin_cm[m, a0, b0]
    m01 = sub_margin_cm[m, a0, b0 + 1]
    m10 = sub_margin_cm[m, a0 + 1, b0]
    m11 = sub_margin_cm[m, a0 + 1, b0 + 1]
    if min(min(m00, m01), min(m10, m11)) == _MARGIN_NONE:
        return (sub_masks[m, a, b] & 2) != 0
    tv = fv - a0
    tu = fu - b0
    return (1.0 - tv) * ((1.0 - tu) * m00 + tu * m01) + tv * ((1.0 - tu) * m10 + tu * m11) >= 0.0


@numba.njit(cache=True, inline="always")
def _cell_blocks(top, i, j, ray, span, walls):
    """Whether DSM cell (i, j) of height ``top`` stops the ray that crosses it from ``span`` = (s_in, s_out) (its
    horizontal parameters where it enters and leaves the cell, in cells): ``ray`` = (Z, rise, gx, gy, ex, ey,
    tolerance_m) as in ``_occlusion_kernel``, ``walls`` = (footprinted, base_m, slab_top_m, sub_index, sub_masks,
    sub, sub_margin_cm) (a ``FootprintOccluder``; ``footprinted`` False: every cell a solid column).

    A solid column stops the ray where it is more than the tolerance above the ray where it enters (the ray's
    lowest in the cell). A cell with a slab (a finite ``base_m``) stops it where the slab's top is above the ray
    where it enters (a tree crown's, ``sub_index`` -2: more than the tolerance above) and the ray reaches the slab's
    underside where it leaves (its highest); a slab cell (``sub_index`` -1: an overhang; -2) is nothing more; an overhang cell with a mask
    (``sub_index`` >= 0) also stops it at its sub-cells inside a footprint (bit 1: the wall, a column up to ``top``)
    that the ray crosses more than the tolerance below ``top``, and its slab covers the whole cell (bit 4 at [0, 0])
    or only within the roof outline (``_in_slab``: where the ray first and last crosses it); a cell beside an
    overhang (``sub_index`` <= -3) is its own solid column, and the slab within the outline over the half cell next to
    the overhang only."""
    Z, rise, gx, gy, ex, ey, tolerance_m = ray
    s_in, s_out = span
    z_in = Z + rise * s_in
    footprinted, base_m, slab_top_m, sub_index, sub_masks, sub, sub_margin_cm = walls
    column = top > z_in + tolerance_m  # (NaN: no surface)
    if not footprinted:
        return column
    base = base_m[i, j]
    if base == -np.inf:
        return column
    k = sub_index[i, j]
    if k == -2:  # a tree crown: a slab of the whole cell from its crown base up to its top (the DSM's, with the
        # tolerance of a column's top)
        return top > z_in + tolerance_m and Z + rise * s_out > base
    # an overhang's slab: its top the eave line, not a sampled height, so without the tolerance (with it a ray
    # through the fascia, the 0.3 m between the soffit and the eave line, passed as soon as the roof outline bounds
    # the slab instead of the DSM's whole cells)
    ds = 0.25 / sub  # the ray's sub-cells within the cell, at quarter sub-cell steps
    if k <= -3:  # beside an overhang: its own column, and the slab over the sub-cells of its mask
        if column:
            return True
        # the ray rises: where it passes above the slab's top where it enters, or below its underside where it
        # leaves, no sub-cell can stop it (the same answer as the walk over them, without it)
        if not (slab_top_m[i, j] > z_in and Z + rise * s_out > base):
            return False
        return _slab_walk(top, ray, span, walls, i, j, -3 - k, False)
    if k < 0 or sub_masks[k, 0, 0] & 4:  # the slab over the whole cell
        if slab_top_m[i, j] > z_in and Z + rise * s_out > base:
            return True
        if k < 0 or not column:
            return False
        # the wall: the sub-cells inside a footprint the ray crosses while below the cell's top (it rises: once
        # above, it stays above)
        s = s_in
        while s <= s_out and top > Z + rise * s + tolerance_m:
            a = min(max(int((gy + ey * s - i) * sub), 0), sub - 1)
            b = min(max(int((gx + ex * s - j) * sub), 0), sub - 1)
            if sub_masks[k, a, b] & 1:
                return True
            s += ds
        return False
    # the slab over the sub-cells within the roof outline only (where the ray first and last crosses them), the
    # wall's sub-cells a column up to the top
    if not (column or (slab_top_m[i, j] > z_in and Z + rise * s_out > base)):
        return False
    return _slab_walk(top, ray, span, walls, i, j, k, True)


@numba.njit(cache=True, inline="always")
def _continuous_patch(dsm, ground, a, b, wall_rise_m):
    """Whether the bilinear patch between the centres of DSM cells (a, b), (a, b + 1), (a + 1, b), (a + 1, b + 1) is
    continuous surface: all four within the DSM, heights and the ground (``ground``, uint8 per DSM cell,
    ``ortho.rectify.ground_cells``; another shape: no cell is), and none of its four sides rising more than
    ``wall_rise_m`` (else a wall, or an object on the ground: the cells' columns)."""
    dh, dw = dsm.shape
    if a < 0 or b < 0 or a + 1 >= dh or b + 1 >= dw:
        return False
    if ground.shape[0] != dh or ground.shape[1] != dw or not (ground[a, b] and ground[a, b + 1] and ground[a + 1, b]
                                                              and ground[a + 1, b + 1]):
        return False
    h00 = dsm[a, b]
    h01 = dsm[a, b + 1]
    h10 = dsm[a + 1, b]
    h11 = dsm[a + 1, b + 1]
    # (NaN: False)
    return (abs(h01 - h00) <= wall_rise_m and abs(h11 - h10) <= wall_rise_m and abs(h10 - h00) <= wall_rise_m
            and abs(h11 - h01) <= wall_rise_m)


@numba.njit(cache=True, inline="always")
def _patch_height(dsm, a, b, u, v):
    """The bilinear height within the patch of ``_continuous_patch`` at (``u``, ``v``) cells east and south of the
    centre of cell (a, b)."""
    h00 = dsm[a, b]
    h01 = dsm[a, b + 1]
    h10 = dsm[a + 1, b]
    return h00 + (h01 - h00) * u + (h10 - h00) * v + (dsm[a + 1, b + 1] - h01 - h10 + h00) * u * v


@numba.njit(cache=True)
def _surface_blocks(dsm, ground, wall_rise_m, i, j, ray, span):
    """Whether the surface of DSM cell (i, j), whose column (``_cell_blocks``) stops the ray, stops it: over each
    quarter of the cell within a continuous bilinear patch (``_continuous_patch``) the lower of the column's top and
    the bilinear surface (on which the ground points stand), elsewhere the column. ``ray`` and ``span`` as in
    ``_cell_blocks``. Only the part of the cell the ray crosses while more than the tolerance below the column's top
    can stop it (there the lower of the two is the bilinear surface's); along the ray within a patch the bilinear
    surface less the ray's height is a quadratic: its ends and its vertex are tested (exact)."""
    Z, rise, gx, gy, ex, ey, tolerance_m = ray
    s_in, s_out = span
    top = dsm[i, j]
    s_end = min(s_out, (top - tolerance_m - Z) / rise) if rise > 0.0 else s_out
    # the ray's parameters where it crosses the cell's centre lines (the patches' edges)
    cx = (j + 0.5 - gx) / ex if abs(ex) > 1e-12 else 1e30
    cy = (i + 0.5 - gy) / ey if abs(ey) > 1e-12 else 1e30
    s0 = s_in
    while True:
        s1 = s_end
        if s0 < cx < s1:
            s1 = cx
        if s0 < cy < s1:
            s1 = cy
        sm = 0.5 * (s0 + s1)
        b = j if gx + ex * sm >= j + 0.5 else j - 1
        a = i if gy + ey * sm >= i + 0.5 else i - 1
        if not _continuous_patch(dsm, ground, a, b, wall_rise_m):
            return True  # the column, more than the tolerance above the ray here
        h00 = dsm[a, b]
        du = dsm[a, b + 1] - h00
        dv = dsm[a + 1, b] - h00
        t = dsm[a + 1, b + 1] - dsm[a, b + 1] - dv
        u0 = gx - (b + 0.5)
        v0 = gy - (a + 0.5)
        # f(s) = bilinear - ray - tolerance = f0 + f1 s + f2 s^2
        f0 = h00 + du * u0 + dv * v0 + t * u0 * v0 - Z - tolerance_m
        f1 = du * ex + dv * ey + t * (u0 * ey + v0 * ex) - rise
        f2 = t * ex * ey
        if f0 + (f1 + f2 * s0) * s0 > 0.0 or f0 + (f1 + f2 * s1) * s1 > 0.0:
            return True
        if f2 < 0.0:
            sv = -f1 / (2.0 * f2)
            if s0 < sv < s1 and f0 + (f1 + f2 * sv) * sv > 0.0:
                return True
        if s1 >= s_end:
            return False
        s0 = s1


@numba.njit(cache=True)
def _cell_stops(dsm, ground, wall_rise_m, i, j, ray, span, walls):
    """Whether DSM cell (i, j) stops the ray, as ``_occlusion_kernel`` decides it: ``_cell_blocks``, and for a cell
    without a slab (no footprint, no crown) ``_surface_blocks`` too. (The kernel spells this out at its two calls: a
    function of the arrays inlined there made the march 50-80 % slower on the demo, measured.)"""
    if not _cell_blocks(dsm[i, j], i, j, ray, span, walls):
        return False
    if walls[0] and walls[1][i, j] != -np.inf:
        return True
    return _surface_blocks(dsm, ground, wall_rise_m, i, j, ray, span)


@numba.njit(cache=True, inline="always")
def _slab_walk(top, ray, span, walls, i, j, m, with_walls):
    """The walk of ``_cell_blocks`` over the sub-cells of cell (i, j) (DSM height ``top``) with mask ``m``, at quarter
    sub-cell steps: the slab within the roof outline stops the ray where its top is above the ray at the first point
    within it and the ray reaches its underside at the last; ``with_walls``: the mask's wall sub-cells (bit 1) are a
    column up to ``top``. The ray rises, so the walk ends as soon as the answer is known: at a point within the
    outline above the underside (True, the first one lay below the top), or with the ray at the slab's top (at least
    the cell's) before any point within the outline (False: neither the slab nor a wall can stop it further on)."""
    Z, rise, gx, gy, ex, ey, tolerance_m = ray
    s_in, s_out = span
    _, base_m, slab_top_m, _, sub_masks, sub, sub_margin_cm = walls
    base = base_m[i, j]
    slab_top = slab_top_m[i, j]
    ds = 0.25 / sub
    seen = False  # a point within the outline met (the first one below the slab's top)
    s = s_in
    while s <= s_out:
        z = Z + rise * s
        if with_walls:
            a = min(max(int((gy + ey * s - i) * sub), 0), sub - 1)
            b = min(max(int((gx + ex * s - j) * sub), 0), sub - 1)
            if sub_masks[m, a, b] & 1 and top > z + tolerance_m:
                return True
        if not seen and not slab_top > z:
            return False
        if _in_slab(sub_masks, sub_margin_cm, m, (gy + ey * s - i) * sub, (gx + ex * s - j) * sub, sub):
            seen = True
            if z > base:
                return True
        s += ds
    return False


@numba.njit(cache=True, inline="always")
def _log2_exact(n):
    """k where n == 2 ** k (n >= 1), else -1."""
    k = 0
    while (1 << k) < n:
        k += 1
    return k if (1 << k) == n else -1


@numba.njit(cache=True, nogil=True)
def _occlusion_kernel(anchors, points, grid, march, walls, centre, occluded):
    """Mark ground points whose ray to the projection centre passes below the DSM surface (``HeightGrid``
    ``grid``): the points of a tile (``AnchorGrid`` ``anchors``) at heights ``points.heights_m`` (``TilePoints``), the
    ``MarchArgs`` ``march`` (bounds, ``tolerance_m``, ``own_column_m``, ``wall_rise_m`` and ``ground``: continuous
    surface, ``_continuous_patch``), the ``FootprintWalls`` ``walls`` (building
    footprints: overhang cells block only within a slab under their top, ``_cell_blocks``; none: (1, 1) arrays),
    into ``occluded``.

    The DSM is taken as columns: each cell a flat top at its height over its whole square (the edge of a roof
    half way between a roof sample and a ground sample, where a point-sampled DSM puts it on average). The ray is
    walked cell by cell (2D DDA, every cell it crosses, Amanatides & Woo) from the cell after the point's own
    towards the centre; occluded where a cell's height exceeds the ray's height where it enters the cell (the
    lowest of the ray in the cell: it rises) by ``tolerance_m``; the walk stops when the ray is above the highest
    DSM height or leaves the DSM. (A march in steps of one cell over the bilinear surface missed the corner of a
    roof whenever the ray passed under it for less than a step, and rounded the corner off by half a cell: the
    ground just inside the edge of a hidden area was left visible, 9 % of the hidden ground of the tall block.)
    Only the points where ``candidates`` is True are walked (the others are left as they are). A point whose height
    (``height_tile``, the bilinear DSM) lies more than ``own_column_m`` (>= 0; negative: never) above the top of its
    own column is walked from that top: within half a cell of a wall the bilinear DSM puts the ground part way up
    the wall, and the ray from there passed over the roof that hides the ground (on the synthetic block's exact
    boxes, 4.5 % of the ground hidden in the nadir-most frame and seen by another came from such a frame).
    ``block_max`` (``_block_max`` of the DSM by ``block`` cells) and ``coarse_max`` (by ``coarse`` cells): where
    the ray is above the highest height of the current block plus the tolerance, no cell in that block can occlude
    (the ray rises), so the walk jumps to where the ray leaves the block (the coarse block first); the cells
    tested are the same as cell by cell, so the result is the same.
    ``near_share`` (float32 like the tile, or (1, 1) for none): where positive, the depth of the surface the
    z-buffer puts in front of the point as a share of the point's depth; the walk runs first from two cells before
    where the ray meets that depth to two cells after it, and a hit there decides ("occluded" is whether any cell
    hits), else from the start up to there and on from where it paused: every cell once, as one walk from the start.
    (Tried at nine half-cell probes before a walk from the start, the hint cost the visible points, about a quarter
    of the candidates on the full-size DMC frames, 30 % more than no hint; the probed cells were walked again.)
    """
    anchor_x, anchor_y = anchors.x_m, anchors.y_m
    height_tile, candidates, near_share = points
    dsm, dsm_x0, dsm_y0, dsm_res = grid
    dsm_max, block_max, block, coarse_max, coarse, tolerance_m, own_column_m, wall_rise_m, ground = march
    base_m, slab_top_m, sub_index, sub_masks, sub, sub_margin_cm = walls
    footprinted = base_m.shape[0] == dsm.shape[0] and base_m.shape[1] == dsm.shape[1]
    cell_walls = (footprinted, base_m, slab_top_m, sub_index, sub_masks, sub, sub_margin_cm)
    rows, cols = height_tile.shape
    hinted = near_share.shape[0] == rows and near_share.shape[1] == cols
    dh, dw = dsm.shape
    inv_s = 1.0 / anchors.spacing_px
    inv_res = 1.0 / dsm_res
    block_shift = _log2_exact(block)
    coarse_shift = _log2_exact(coarse)
    pow2 = block_shift >= 0 and coarse_shift >= 0
    for r in range(rows):
        ar = r * inv_s
        i0 = min(int(ar), anchor_x.shape[0] - 2)
        fr = ar - i0
        for c in range(cols):
            Z = height_tile[r, c]
            if Z != Z or not candidates[r, c]:
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
            # grid coordinates (column gx, row gy) along s, the horizontal distance in DSM cells; ray height zr
            # snapped to 1/1024 cell: a point on a cell boundary (an output grid that shares lines with the DSM's)
            # is in the same cell whichever tile's anchors gave its position (which differ in the last bits)
            gx = math.floor((X - dsm_x0) * inv_res * 1024.0 + 0.5) * (1.0 / 1024.0)
            gy = math.floor((dsm_y0 - Y) * inv_res * 1024.0 + 0.5) * (1.0 / 1024.0)
            ex = vx / hd
            ey = -vy / hd
            j_own = int(math.floor(gx))
            i_own = int(math.floor(gy))
            if own_column_m >= 0.0 and i_own >= 0 and j_own >= 0 and i_own < dh and j_own < dw:
                # the point at the top of its own column where the bilinear height lies more than own_column_m above
                # it: a ground point within half a cell of a wall is part way up the wall there, and a ray from there
                # passes over the roof that hides the ground (smaller steps, the DSM's noise and roof slopes, kept)
                # (not a point that stands on continuous surface, ``_continuous_patch``, within own_column_m of its
                # bilinear height: a slope's ground; a point of another height raster well above the occlusion DSM
                # there, e.g. beneath a crown, is lowered as before)
                zo = dsm[i_own, j_own]
                if zo < Z - own_column_m:
                    a = int(math.floor(gy - 0.5))
                    b = int(math.floor(gx - 0.5))
                    if not (_continuous_patch(dsm, ground, a, b, wall_rise_m)
                            and Z <= _patch_height(dsm, a, b, gx - (b + 0.5), gy - (a + 0.5)) + own_column_m):
                        Z = zo
                        vz = centre[2] - Z
            rise = vz / hd * dsm_res  # metres of ray height per cell horizontally
            # DDA: the cell after the point's own, the parameters of its next column and row boundaries, and the
            # step between boundaries
            step_j = 1 if ex > 0 else -1
            step_i = 1 if ey > 0 else -1
            dsx = 1.0 / abs(ex) if abs(ex) > 1e-12 else 1e30
            dsy = 1.0 / abs(ey) if abs(ey) > 1e-12 else 1e30
            s_first, sx_first, sy_first, i_first, j_first = _dda_step(
                (_next_boundary(gx, ex, j_own), _next_boundary(gy, ey, i_own)), (dsx, dsy), (i_own, j_own),
                (step_i, step_j))
            # with the z-buffer's hint the walk runs in three parts, every cell once: from the cell the ray is in
            # two cells before it meets the depth of the surface in front (where an occluded point's occluder lies)
            # to two cells after it; then from the start up to that cell; then on from where the first part paused
            hinting = hinted and near_share[r, c] > 0.0
            hint_i, hint_j, hint_s, hint_end = -1, -1, 1e30, 1e30
            if hinting:
                # the ray's depth falls linearly to 0 at the centre: it reaches the near surface's depth after a
                # horizontal distance hd * (1 - share)
                s0 = hd * (1.0 - near_share[r, c]) * inv_res
                hint_j = int(math.floor(gx + ex * (s0 - 2.0)))
                hint_i = int(math.floor(gy + ey * (s0 - 2.0)))
                hint_s = max(_boundary_in(gx, ex, hint_j), _boundary_in(gy, ey, hint_i), 0.0)
                hint_end = s0 + 2.0
                if not hint_s > s_first:  # the start's own cells: the walk from the start alone
                    hinting = False
                    hint_i, hint_j, hint_s, hint_end = -1, -1, 1e30, 1e30
            paused = False  # the first part stopped at hint_end (not beyond the DSM or above it): a third part
            ps, psx, psy, pi, pj = 0.0, 0.0, 0.0, 0, 0
            hit = False
            for part in range(3):
                if part == 0:
                    if not hinting:
                        continue
                    s, i, j = hint_s, hint_i, hint_j
                    sx = _next_boundary(gx, ex, j)
                    sy = _next_boundary(gy, ey, i)
                    stop_s, stop_i, stop_j = hint_end, -1, -1
                elif part == 1:
                    s, sx, sy, i, j = s_first, sx_first, sy_first, i_first, j_first
                    # (the cell where the first part began, or past it: a jump over a block, or the boundary
                    # arithmetic's last bits)
                    stop_s, stop_i, stop_j = hint_s + 1e-6, hint_i, hint_j
                else:
                    if not paused:
                        break
                    s, sx, sy, i, j = ps, psx, psy, pi, pj
                    stop_s, stop_i, stop_j = 1e30, -1, -1
                while True:  # the ray enters cell (i, j) at s
                    zr = Z + rise * s
                    if zr > dsm_max or i < 0 or j < 0 or i >= dh or j >= dw:
                        break
                    if s >= stop_s or (i == stop_i and j == stop_j):
                        if part == 0:
                            paused = True
                            ps, psx, psy, pi, pj = s, sx, sy, i, j
                        break
                    b = coarse
                    # (i, j >= 0 here: with blocks of powers of two the block index is a shift, not a 64-bit
                    # division)
                    if (coarse_max[i >> coarse_shift, j >> coarse_shift] if pow2
                            else coarse_max[i // coarse, j // coarse]) > zr + tolerance_m:
                        b = block if (block_max[i >> block_shift, j >> block_shift] if pow2
                                      else block_max[i // block, j // block]) <= zr + tolerance_m else 0
                    if b > 0:  # the ray passes above the block: on from the cell it enters when it leaves the block
                        bi0 = (i & -b) if pow2 else (i // b) * b
                        bj0 = (j & -b) if pow2 else (j // b) * b
                        ox = (bj0 + (b if ex > 0 else 0) - gx) / ex if abs(ex) > 1e-12 else 1e30
                        oy = (bi0 + (b if ey > 0 else 0) - gy) / ey if abs(ey) > 1e-12 else 1e30
                        if ox < oy:
                            s = max(ox, s)
                            j = bj0 + b if ex > 0 else bj0 - 1
                            i = min(max(int(math.floor(gy + ey * s)), bi0), bi0 + b - 1)
                        else:
                            s = max(oy, s)
                            i = bi0 + b if ey > 0 else bi0 - 1
                            j = min(max(int(math.floor(gx + ex * s)), bj0), bj0 + b - 1)
                        sx = _next_boundary(gx, ex, j)
                        sy = _next_boundary(gy, ey, i)
                        continue
                    ray = (Z, rise, gx, gy, ex, ey, tolerance_m)
                    if _cell_blocks(dsm[i, j], i, j, ray, (s, min(sx, sy)), cell_walls) and (
                            footprinted and base_m[i, j] != -np.inf
                            or _surface_blocks(dsm, ground, wall_rise_m, i, j, ray, (s, min(sx, sy)))):
                        hit = True
                        break
                    s, sx, sy, i, j = _dda_step((sx, sy), (dsx, dsy), (i, j), (step_i, step_j))
                if hit:
                    occluded[r, c] = True
                    break


@numba.njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _fixed_point_kernel_affine(tile, frame, margin, maps):
    """Fast path of _fixed_point_kernel when the output grid is in the project CRS (``AffineTile`` ``tile``): ground
    X, Y are affine in (row, col) and the heights on the grid are given (bilinear DEM, see heights_on_grid).

    Branch-free inner loop with everything loop-invariant hoisted and plain int32 row outputs, so
    LLVM vectorises it (AVX-512: ~5x faster than a branching loop storing the interleaved int16 map);
    the packing into cv2's layout is a second, cheap pass. NaN heights (DEM nodata) make x, y NaN and
    fail the range test.
    """
    heights, res = tile.heights_m, tile.col_dx_m  # the project grid's own tile: columns east, rows south
    centre, M, cam, limits, inv_r = frame.centre_m, frame.M, frame.cam, frame.limits, frame.inv_radius
    map_int, map_frac, mask, bounds = maps
    rows, cols = heights.shape
    window = (margin, frame.width_px - 1 - margin, margin, frame.height_px - 1 - margin)
    m02, m12, m22 = M[0, 2], M[1, 2], M[2, 2]
    sx, sy, sz = M[0, 0] * res, M[1, 0] * res, M[2, 0] * res
    far = np.int32(-32768 * INTER_TAB_SIZE)
    ix_row = np.empty(cols, np.int32)
    iy_row = np.empty(cols, np.int32)
    for r in range(rows):
        # camera-frame coordinates are affine along the row: start + c * step + dz * column of M
        dx0, dy, bx, by, bz = _affine_row(tile, r, centre, M)
        z_row, mask_row = heights[r], mask[r]
        for c in range(cols):
            dz = np.float64(z_row[c]) - centre[2]
            dze = earth_dz(dx0 + c * res, dy, dz, inv_r)
            zc = bz + c * sz + m22 * dze
            inv_zc = 1.0 / zc
            xn = (bx + c * sx + m02 * dze) * inv_zc
            yn = (by + c * sy + m12 * dze) * inv_zc
            x, y = to_pixel(cam, xn, yn)
            seen = (zc > 0.0) & _within_limits(xn, yn, dx0 + c * res, dy, dz, limits)
            ix_row[c], iy_row[c], mask_row[c] = _fixed_point_entry(x, y, seen, window, far)
        _pack_fixed_point(ix_row, iy_row, map_int[r], map_frac[r], bounds)


@numba.njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _fixed_point_kernel_affine_map(affine, dem, frame, margin, maps, height_out):
    """``_fixed_point_kernel`` where the tile's project coordinates are affine in (row, col) but not the project
    grid's own (``ortho.grid.GridAffine`` ``affine``: a contract CRS's tile, e.g. Gauss-Krueger from UTM): per row,
    a scalar pass of the heights (``_dem_height`` on ``HeightGrid`` ``dem``, as the general kernel: the same
    bilinear heights in float64) into a row array, then the branch-free, vectorised projection of
    ``_fixed_point_kernel_affine`` with the ground offsets affine along the row in both X and Y."""
    x0, y0, col_dx, col_dy, row_dx, row_dy = (affine.x0_m, affine.y0_m, affine.col_dx_m, affine.col_dy_m,
                                              affine.row_dx_m, affine.row_dy_m)
    centre, M, cam, limits, inv_r = frame.centre_m, frame.M, frame.cam, frame.limits, frame.inv_radius
    map_int, map_frac, mask, bounds = maps
    rows, cols = height_out.shape
    window = (margin, frame.width_px - 1 - margin, margin, frame.height_px - 1 - margin)
    m02, m12, m22 = M[0, 2], M[1, 2], M[2, 2]
    # a column's step of the camera-frame coordinates (before the height's share)
    sx = M[0, 0] * col_dx + M[0, 1] * col_dy
    sy = M[1, 0] * col_dx + M[1, 1] * col_dy
    sz = M[2, 0] * col_dx + M[2, 1] * col_dy
    c0, c1, c2 = centre[0], centre[1], centre[2]
    far = np.int32(-32768 * INTER_TAB_SIZE)
    ix_row = np.empty(cols, np.int32)
    iy_row = np.empty(cols, np.int32)
    z64 = np.empty(cols, np.float64)
    for r in range(rows):
        xr = x0 + r * row_dx
        yr = y0 + r * row_dy
        z_row, mask_row = height_out[r], mask[r]
        for c in range(cols):  # the DEM's gather: scalar, kept out of the projection's loop
            Z = _dem_height(dem, xr + c * col_dx, yr + c * col_dy)
            z64[c] = Z
            z_row[c] = Z
        dx0 = xr - c0
        dy0 = yr - c1
        bx = M[0, 0] * dx0 + M[0, 1] * dy0
        by = M[1, 0] * dx0 + M[1, 1] * dy0
        bz = M[2, 0] * dx0 + M[2, 1] * dy0
        for c in range(cols):
            dx = dx0 + c * col_dx
            dy = dy0 + c * col_dy
            dz = z64[c] - c2
            dze = earth_dz(dx, dy, dz, inv_r)
            zc = bz + c * sz + m22 * dze
            inv_zc = 1.0 / zc
            xn = (bx + c * sx + m02 * dze) * inv_zc
            yn = (by + c * sy + m12 * dze) * inv_zc
            x, y = to_pixel(cam, xn, yn)
            seen = (zc > 0.0) & _within_limits(xn, yn, dx, dy, dz, limits)
            ix_row[c], iy_row[c], mask_row[c] = _fixed_point_entry(x, y, seen, window, far)
        _pack_fixed_point(ix_row, iy_row, map_int[r], map_frac[r], bounds)


@numba.njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _zbuffer_kernel(anchors, heights, frame, zbuffer, occluded, scatter):
    """Z-buffer occlusion of a true ortho: the surface points of a tile (``AnchorGrid`` ``anchors``, its pixels at
    their DSM ``heights``) projected into the frame (``FrameArgs``), their depth along the optical axis (zc, m)
    compared by cells of ``zbuffer.cell_px`` image pixels (``ZBufferArgs``). ``scatter``: keep the nearest depth per
    cell in ``zbuffer.depth_m`` (first pass, over every tile of the frame); else mark ``occluded`` the points more
    than ``zbuffer.tolerance_m`` behind the nearest surface of their cell (points outside the frame or on nodata are
    left as they are). Points beyond the lens fold (``frame.limits.fold_r2``) are neither: the model puts them at a
    wrong place in the image. (The view angle does not apply: a surface seen beyond it may still hide ground within
    it.)"""
    anchor_x, anchor_y = anchors.x_m, anchors.y_m
    centre, M, cam, fold_r2, inv_r = frame.centre_m, frame.M, frame.cam, frame.limits.fold_r2, frame.inv_radius
    width, height = frame.width_px, frame.height_px
    zbuf, cell_px, tolerance_m = zbuffer
    inv_s = 1.0 / anchors.spacing_px
    rows, cols = heights.shape
    zh, zw = zbuf.shape
    inv_cell = 1.0 / cell_px
    na = anchor_x.shape[1]
    for r in range(rows):
        ar = r * inv_s
        i0 = min(int(ar), anchor_x.shape[0] - 2)
        fr = ar - i0
        ax0, ax1, ay0, ay1 = anchor_x[i0], anchor_x[i0 + 1], anchor_y[i0], anchor_y[i0 + 1]
        for c in range(cols):
            Z = np.float64(heights[r, c])
            if Z != Z:
                continue
            ac = c * inv_s
            j0 = min(int(ac), na - 2)
            fc = ac - j0
            X = (1.0 - fr) * ((1.0 - fc) * ax0[j0] + fc * ax0[j0 + 1]) + fr * ((1.0 - fc) * ax1[j0] + fc * ax1[j0 + 1])
            Y = (1.0 - fr) * ((1.0 - fc) * ay0[j0] + fc * ay0[j0 + 1]) + fr * ((1.0 - fc) * ay1[j0] + fc * ay1[j0 + 1])
            dx = X - centre[0]
            dy = Y - centre[1]
            dz = earth_dz(dx, dy, Z - centre[2], inv_r)
            zc = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
            if zc <= 0.0:
                continue
            xn = (M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz) / zc
            yn = (M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz) / zc
            if not xn * xn + yn * yn <= fold_r2:
                continue
            x, y = to_pixel(cam, xn, yn)
            if not (x >= 0.0 and y >= 0.0 and x < width and y < height):
                continue
            i = min(int(y * inv_cell), zh - 1)
            j = min(int(x * inv_cell), zw - 1)
            if scatter:
                if zc < zbuf[i, j]:
                    zbuf[i, j] = zc
            elif zc > zbuf[i, j] + tolerance_m:
                occluded[r, c] = True


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _fill_gap(p0, p1, flat, cell_px, inv_cell, zbuf):
    """Where two neighbouring surface points of the output grid (``p0``, ``p1``: image x, y and depth) land more than
    a cell apart in the image (a wall: the DSM's ramp between roof edge and ground spans a DSM cell on the ground but
    many pixels in the image), the surface between them, sampled along the image segment at less than a cell's
    spacing, depth perspective-correct (1 / depth linear in the image), into the z-buffer: without it the ground seen
    through the wall's image has no nearer surface in its cell and is not a candidate. ``flat`` (x, y): the image
    direction of the same ground step on flat ground; a gap against it is a fold (a wall facing away, whose image the
    roof in front of it covers): not filled."""
    x0, y0, z0 = p0
    x1, y1, z1 = p1
    flat_x, flat_y = flat
    dx = x1 - x0
    dy = y1 - y0
    span = max(abs(dx), abs(dy))
    if not span > cell_px or dx * flat_x + dy * flat_y <= 0.0:
        return
    zh, zw = zbuf.shape
    n = int(span * inv_cell) + 1
    inv0 = 1.0 / z0
    inv1 = 1.0 / z1
    for k in range(1, n):
        t = k / n
        x = x0 + t * dx
        y = y0 + t * dy
        i = min(int(y * inv_cell), zh - 1)
        j = min(int(x * inv_cell), zw - 1)
        z = 1.0 / ((1.0 - t) * inv0 + t * inv1)
        if z < zbuf[i, j]:
            zbuf[i, j] = z


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _affine_row(tile, r, centre, M):
    """Row ``r`` of an ``AffineTile`` for ``_affine_pixel``: its first column's ground offsets from the projection
    centre (dx, dy) and camera-frame coordinates at the centre's height (x, y, z: affine along the row, start + c *
    step + dz * column of M)."""
    dx0 = tile.x0_m + r * tile.row_dx_m - centre[0]
    dy = tile.y0_m + r * tile.row_dy_m - centre[1]
    return dx0, dy, M[0, 1] * dy + M[0, 0] * dx0, M[1, 1] * dy + M[1, 0] * dx0, M[2, 1] * dy + M[2, 0] * dx0


@numba.njit(cache=True, inline="always")
def _affine_steps(tile, M):
    """A column's step of an ``AffineTile``'s camera-frame coordinates (M[:, :2] @ the column's ground step), M's
    third column and the column's ground step (dx, dy): the ``steps`` of ``_affine_pixel``."""
    ex, ey = tile.col_dx_m, tile.col_dy_m
    return (M[0, 0] * ex + M[0, 1] * ey, M[1, 0] * ex + M[1, 1] * ey, M[2, 0] * ex + M[2, 1] * ey,
            M[0, 2], M[1, 2], M[2, 2], ex, ey)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _affine_pixel(row, c, z, steps, z_centre, inv_r, cam, limits):
    """Column ``c`` of an ``_affine_row`` ``row`` at height ``z``: image position x, y (px), depth along the optical
    axis zc and whether it is imaged (in front, within the lens fold, inside the frame; branch-free, so that the
    loops calling it stay vectorised). ``steps``: ``_affine_steps``; ``limits``: the fold's squared radius, the
    frame's width and height (px)."""
    dx0, dy, bx, by, bz = row
    sx, sy, sz, m02, m12, m22, ex, ey = steps
    fold_r2, width, height = limits
    dz = earth_dz(dx0 + c * ex, dy + c * ey, np.float64(z) - z_centre, inv_r)
    zc = bz + c * sz + m22 * dz
    inv_zc = 1.0 / zc
    xn = (bx + c * sx + m02 * dz) * inv_zc
    yn = (by + c * sy + m12 * dz) * inv_zc
    x, y = to_pixel(cam, xn, yn)
    ok = (zc > 0.0) & (xn * xn + yn * yn <= fold_r2) & (x >= 0.0) & (y >= 0.0) & (x < width) & (y < height)
    return x, y, zc, ok


@numba.njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _zbuffer_scatter_affine(tile, frame, zbuffer):
    """The scatter pass of ``_zbuffer_kernel`` when the output grid is in the project CRS (``AffineTile`` ``tile``:
    ground X, Y affine in (row, col), heights given on the grid): the projection is branch-free and vectorised as in
    ``_fixed_point_kernel_affine``, positions and depth go to row arrays, and a second, scalar loop keeps the
    nearest depth per cell and fills the gaps between neighbours (left and above) that land more than a cell apart
    (``_fill_gap``). NaN heights fail the range test; points beyond the lens fold (``frame.limits.fold_r2``,
    as ``_zbuffer_kernel``) are not surface points, nor ends of a gap. Tiles must overlap by a row and a column for
    the gaps across their edges."""
    heights = tile.heights_m
    centre, M, cam, inv_r = frame.centre_m, frame.M, frame.cam, frame.inv_radius
    limits = (frame.limits.fold_r2, frame.width_px, frame.height_px)
    zbuf, cell_px = zbuffer.depth_m, zbuffer.cell_px
    rows, cols = heights.shape
    zh, zw = zbuf.shape
    inv_cell = 1.0 / cell_px
    # a row's step of the camera-frame coordinates, negated (the step up a row; M's second column in the project
    # grid's own tile, up to the positive factor res, which the gap test's sign does not see)
    ux, uy = -tile.row_dx_m, -tile.row_dy_m
    m01, m11, m21 = M[0, 0] * ux + M[0, 1] * uy, M[1, 0] * ux + M[1, 1] * uy, M[2, 0] * ux + M[2, 1] * uy
    steps = _affine_steps(tile, M)
    sx, sy, sz = steps[0], steps[1], steps[2]
    z_centre = centre[2]
    xs = np.empty((2, cols), np.float32)
    ys = np.empty((2, cols), np.float32)
    zcs = np.empty((2, cols), np.float32)
    oks = np.zeros((2, cols), np.bool_)
    for r in range(rows):
        cur = r & 1
        x_row, y_row, zc_row, ok_row = xs[cur], ys[cur], zcs[cur], oks[cur]
        x_up, y_up, zc_up, ok_up = xs[1 - cur], ys[1 - cur], zcs[1 - cur], oks[1 - cur]
        row = _affine_row(tile, r, centre, M)
        z_row = heights[r]
        for c in range(cols):
            x, y, zc, ok = _affine_pixel(row, c, z_row[c], steps, z_centre, inv_r, cam, limits)
            ok_row[c] = ok
            x_row[c] = x
            y_row[c] = y
            zc_row[c] = zc
        for c in range(cols):
            if not ok_row[c]:
                continue
            x, y, zc = x_row[c], y_row[c], zc_row[c]
            i = min(int(y * inv_cell), zh - 1)
            j = min(int(x * inv_cell), zw - 1)
            if zc < zbuf[i, j]:
                zbuf[i, j] = zc
            # the image direction of a step of one column (one row) on flat ground is that of the normalised
            # position's change (the sign of the dot product is all that is used: the lens model is left out)
            if c > 0 and ok_row[c - 1] and max(abs(x - x_row[c - 1]), abs(y - y_row[c - 1])) > cell_px:
                xn = (x - cam.cx) / cam.f
                yn = (y - cam.cy) / cam.f
                _fill_gap((x_row[c - 1], y_row[c - 1], zc_row[c - 1]), (x, y, zc), (sx - xn * sz, sy - yn * sz),
                          cell_px, inv_cell, zbuf)
            if r > 0 and ok_up[c] and max(abs(x - x_up[c]), abs(y - y_up[c])) > cell_px:
                xn = (x - cam.cx) / cam.f
                yn = (y - cam.cy) / cam.f
                _fill_gap((x_up[c], y_up[c], zc_up[c]), (x, y, zc), (xn * m21 - m01, yn * m21 - m11), cell_px,
                          inv_cell, zbuf)


@numba.njit(cache=True, nogil=True, fastmath=_FASTMATH, error_model="numpy")
def _zbuffer_test_maps(imaged, tile, frame, zbuffer, occluded, near_share):
    """The test pass of ``_zbuffer_kernel`` reusing the tile's cv2.remap maps (``imaged``: the integer map and the
    mask of ``RemapMaps``, the image position of every imaged pixel of ``AffineTile`` ``tile`` at the same heights,
    ``_fixed_point_kernel_affine``): the cell from the integer position, the
    depth along the optical axis affine in (row, col) and height; ``occluded`` where the imaged pixel
    (``mask`` != 0) lies more than ``tolerance_m`` behind its cell's nearest surface (set, never cleared), and
    there ``near_share`` = that surface's depth / the pixel's (where the march looks first)."""
    map_int, mask = imaged
    heights = tile.heights_m
    centre, M, inv_r = frame.centre_m, frame.M, frame.inv_radius
    zbuf, cell_px, tolerance_m = zbuffer
    rows, cols = heights.shape
    zh, zw = zbuf.shape
    _, _, sz, _, _, m22, ex, ey = _affine_steps(tile, M)
    # cell of an integer position p >= 0: (p + 0.5) / cell_px lies strictly inside (p // cell_px, + 1), so the
    # float product truncates to the integer division (which would cost tens of cycles per pixel)
    inv_cell = 1.0 / cell_px
    for r in range(rows):
        dx0, dy, _, _, bz = _affine_row(tile, r, centre, M)
        z_row, mask_row, occ_row, int_row, near_row = heights[r], mask[r], occluded[r], map_int[r], near_share[r]
        for c in range(cols):
            if mask_row[c] == 0:
                continue
            zc = bz + c * sz + m22 * earth_dz(dx0 + c * ex, dy + c * ey, np.float64(z_row[c]) - centre[2], inv_r)
            i = min(np.int32((int_row[c, 1] + 0.5) * inv_cell), zh - 1)
            j = min(np.int32((int_row[c, 0] + 0.5) * inv_cell), zw - 1)
            if zc > zbuf[i, j] + tolerance_m:
                occ_row[c] = True
                near_row[c] = zbuf[i, j] / zc


@numba.njit(cache=True, nogil=True)
def _block_max(dsm, block, slab_top=None, raise_m=np.float32(0.0)):
    """Highest DSM height over blocks of ``block`` x ``block`` cells and the row and column after them (the
    cells a bilinear sample in the block reads), NaN left out (-inf where all are NaN): the march's bound. With
    ``slab_top`` (same shape, float32) each cell's height is the higher of its DSM height and its slab top +
    ``raise_m`` (float32, as ``np.fmax``). Also returns the highest height of all (NaN where every cell is NaN).
    Row by row, each row's maximum per block of columns, so that no cell is read more than twice."""
    dh, dw = dsm.shape
    bh = (dh + block - 1) // block
    bw = (dw + block - 1) // block
    out = np.full((bh, bw), -np.inf, np.float32)
    row_max = np.empty(bw, np.float32)
    seen = False
    for i in range(dh):
        for bj in range(bw):
            m = -np.inf
            for j in range(bj * block, min(bj * block + block + 1, dw)):
                v = dsm[i, j]
                if slab_top is not None:
                    t = slab_top[i, j] + raise_m
                    if v != v or t > v:
                        v = t
                if v > m:
                    m = v
                elif v == v:
                    seen = True
            if m > -np.inf:
                seen = True
            row_max[bj] = m
        bi = i // block
        # row i is read by samples in its own block and, on the block's first row, by the block before it
        for ii in range(max(bi - (1 if i % block == 0 else 0), 0), bi + 1):
            for bj in range(bw):
                if row_max[bj] > out[ii, bj]:
                    out[ii, bj] = row_max[bj]
    return out, seen


@numba.njit(cache=True, nogil=True)
def _coarser_max(fine, ratio):
    """``_block_max`` by blocks ``ratio`` times as large from the one by the fine blocks (the union of the fine blocks'
    cells, each with its row and column after, is the coarse block's with its own): the same maxima."""
    fh, fw = fine.shape
    out = np.full(((fh + ratio - 1) // ratio, (fw + ratio - 1) // ratio), -np.inf, np.float32)
    for i in range(fh):
        for j in range(fw):
            if fine[i, j] > out[i // ratio, j // ratio]:
                out[i // ratio, j // ratio] = fine[i, j]
    return out


@numba.njit(cache=True, nogil=True)
def _clear_cells(cells, mask, map_int):
    """Where ``cells`` (bool (rows, cols), e.g. a tile's occluded points): ``mask`` (uint8, same shape) 0 and the
    fixed-point map ``map_int`` (int16 (rows, cols, 2)) -32768 (outside any image: ``cv2.remap`` reads its border).
    Compiled: numpy's boolean assignment to the two took 3.6 ms a 1024 x 1024 tile (1.8 CPU-s a block of 4 DMC
    frames), this one pass a tenth of it."""
    rows, cols = cells.shape
    for r in range(rows):
        for c in range(cols):
            if cells[r, c]:
                mask[r, c] = 0
                map_int[r, c, 0] = -32768
                map_int[r, c, 1] = -32768
