"""The frame renderer: z-buffer rasterisation of the scene's exact geometry through the true camera (numba).

A pixel shows the first surface its ray meets, as in the ray caster (``aerotri.sim.raycast``, which the
LiDAR and the visibility checks use), found the other way round: every terrain triangle (the height
field's cells, split as the caster splits them), building triangle and crown spheroid in view is
rasterised into the frame with a depth test. Relief displacement, occlusion, the principal point and
the lens distortion of the true camera are exact, as they were with a ray per pixel.

- Pixel rays: the undistorted normalised coordinates (xn, yn) of the pixel centres come from a
  ``GRID_STEP_PX`` grid of ``Camera.pixel_to_normalized`` by bilinear interpolation (the distortion's
  curvature over 16 px leaves about 1e-4 px).
- Coverage: the ray d = (xn, yn, 1) (camera frame, computer-vision axes) passes through a triangle with
  camera-frame vertices A, B, C when d . (A x B), d . (B x C), d . (C x A) have one sign (zero included:
  neighbouring triangles leave no crack). Depth along the optical axis: (n . A) / (n . d), n the plane
  normal. Crowns: the ray-spheroid equation per pixel.
- The earth (``aerotri.sim.earth``): the scene is in map coordinates; a frame's camera-frame vertices are
  its map offsets through the frame's second-order map -> ENU -> camera transformation (``FrameEarth``:
  scale factor, convergence, (R + h) / R and the earth's curvature), each crown a spheroid linearised at its
  centre, and a pixel's surface point goes back to the map by the inverse. ``FrameEarth.flat`` (the default
  of ``FrameSetup``) is the flat world of the ray caster.
- Work: the terrain nodes, building triangles and crowns in view are projected once per frame and
  binned into tiles of ``BAND_ROWS`` rows x ``TILE_COLS`` columns; bands of rows are rendered on threads (one a
  core: ``numba.get_num_threads()``), each a tile at a time with one depth buffer of a tile (held in the core's
  cache), so a frame of any size needs memory for a few tiles only. A thread takes the next band when it is done
  (numba's prange gave each thread a fixed half of the bands: the thread with the costlier half, or one waiting
  for a core taken by other work, held the other up at the end of every call), and the kernel runs without the
  GIL, so a caller can write rows already rendered while the next are rendered (``FrameRenderer.submit_rows``).
- Shading (``aerotri.sim.shading``), exposure (gain, radial vignetting), tone curve (8-bit: the gamma of
  ``render.tone_map``; 12-bit: linear) and sensor noise (a counter-based hash of the frame's noise seed,
  pixel and band: triangular, zero mean, the preset's sigma) are fused into the same pass.

``ortho_render`` renders the scene straight down (true orthophoto, DSM, land-cover ids): the terrain
height at each pixel centre, then building triangles and crown tops rasterised over it, the highest
surface winning (what a vertical ray meets first).

Note numba's cache checks only the source file of a cached function: after editing ``shading``, ``earth`` (or
``lens_kernels``), clear ``aerotri/sim/__pycache__/*.nbi|*.nbc``.
"""

from __future__ import annotations

import math
from concurrent.futures import Future, ThreadPoolExecutor

import numba
import numpy as np

from aerotri.geom import lens_kernels
from aerotri.geom.camera import Camera
from aerotri.geom.rotation import FLIP_YZ
from aerotri.sim import shading
from aerotri.sim.earth import FrameEarth, to_camera_nb, to_map_nb
from aerotri.sim.scene import KIND_NONE, KIND_TERRAIN, KIND_TREE, Scene

BAND_ROWS = 32
# Columns of a tile: a band is rendered a tile at a time so that the tile's rays, depth buffer and primitive
# codes (4 x 32 x 512 x 8 bytes) stay in the core's L2 cache; a band's whole width (13824 px: 14 MB) did not,
# and every primitive's pixels came from memory (a multiple of 64, so that the vectorised loops over a row of a
# tile leave the same last columns of the row to their scalar remainder as a loop over the whole row).
TILE_COLS = 512
GRID_STEP_PX = 16
# A terrain cell's edges curve under the lens distortion by ~1e-5 px over the cell (they are straight in
# normalised coordinates); its vertices' pixel box grown by this margin holds every pixel centre it covers.
CELL_MARGIN_PX = 0.05
# primitive codes in the depth buffer: type << 56 | index
_T_NONE, _T_TERRAIN_A, _T_TERRAIN_B, _T_TRI, _T_TREE = 0, 1, 2, 3, 4
_SHIFT = 56
_MASK = (1 << _SHIFT) - 1
# a terrain triangle's code holds its cell's row << _CELL_SHIFT | column (from the frame's first node): decoded by
# shifts, as a division by the row length per pixel cost more than the rest of the normal
_CELL_SHIFT = 28
_CELL_MASK = (1 << _CELL_SHIFT) - 1
TONE_LUT_SIZE = 16384
SQRT6 = math.sqrt(6.0)


def tone_lut() -> np.ndarray:
    """The 8-bit tone curve of ``render.tone_map`` (255 x^(1/2.2), x = 1.25 radiance clipped to 0..1) at
    x = k / (TONE_LUT_SIZE - 1), with one extra entry for the linear interpolation (float32: 64 KB)."""
    x = np.minimum(np.arange(TONE_LUT_SIZE + 1, dtype=np.float64) / (TONE_LUT_SIZE - 1), 1.0)
    return (255.0 * x ** (1.0 / 2.2)).astype(np.float32)


class PixelGrid:
    """Undistorted normalised coordinates of the pixel centres (plus a sub-pixel offset) on a coarse grid:
    node (i, j) is pixel (row i * step + oy, column j * step + ox)."""

    def __init__(self, camera: Camera, ox: float = 0.0, oy: float = 0.0, step: int = GRID_STEP_PX):
        self.step = int(step)
        cols = np.arange(camera.width // step + 2) * step + ox
        rows = np.arange(camera.height // step + 2) * step + oy
        cc, rr = np.meshgrid(cols.astype(np.float64), rows.astype(np.float64))
        xn, yn = camera.pixel_to_normalized(cc, rr)
        self.xn = np.ascontiguousarray(xn)
        self.yn = np.ascontiguousarray(yn)


class SceneLook:
    """What the kernels need of a scene: the packed geometry and the shading inputs (built once)."""

    def __init__(self, scene: Scene, fine_m: float):
        self.scene = scene
        self.G = shading.ground_index(scene)
        self.roof_albedo = np.ascontiguousarray(scene.roof_albedo, dtype=np.float64)
        self.fine_m = float(fine_m)
        self.sun = np.ascontiguousarray(shading.SUN, dtype=np.float64)
        self.hz = np.ascontiguousarray(scene.terrain_z, dtype=np.float64)
        self.res = float(scene.terrain_res_m)
        tv = np.ascontiguousarray(scene.tri_v, dtype=np.float64).reshape(-1, 3, 3)
        self.tv = tv
        if len(tv):
            n = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
            n /= np.linalg.norm(n, axis=1, keepdims=True)
        else:
            n = np.zeros((0, 3))
        self.tn = np.ascontiguousarray(n)
        self.tkind = np.ascontiguousarray(scene.tri_kind, dtype=np.int64)
        self.tobj = np.ascontiguousarray(scene.tri_obj, dtype=np.int64)
        self.tri_lo = tv.min(axis=1) if len(tv) else np.zeros((0, 3))
        self.tri_hi = tv.max(axis=1) if len(tv) else np.zeros((0, 3))
        self.tc = np.ascontiguousarray(scene.tree_c, dtype=np.float64).reshape(-1, 3)
        self.ta = np.ascontiguousarray(scene.tree_ac, dtype=np.float64).reshape(-1, 2)
        z_items = [float(self.hz.max())]
        if len(tv):
            z_items.append(float(tv[:, :, 2].max()))
        if len(self.tc):
            z_items.append(float((self.tc[:, 2] + self.ta[:, 1]).max()))
        self.zlo = float(self.hz.min()) - 2.0
        self.zhi = max(z_items) + 0.5


# ----------------------------------------------------------------------------------------------
# Per-frame set-up: what is in view, projected and binned into bands


class FrameSetup:
    """The primitives of one frame, projected into it and binned into bands of rows."""

    def __init__(self, look: SceneLook, camera: Camera, centre_m, R, *, band_rows: int = BAND_ROWS,
                 sample_reach_px: float = 0.0, earth: FrameEarth | None = None):
        """``earth``: the frame's map -> camera-frame transformation (``aerotri.sim.earth``); default the flat
        world (scene coordinates taken as a Cartesian frame)."""
        self.camera = camera
        self.C = np.ascontiguousarray(centre_m, dtype=np.float64)
        self.M = np.ascontiguousarray(np.asarray(R, dtype=np.float64) @ FLIP_YZ)  # camera (cv) -> object (flat)
        self.earth = earth if earth is not None else FrameEarth.flat(R)
        e = self.earth
        self.band_rows = int(band_rows)
        W, H = camera.width, camera.height
        self.nbands = (H + band_rows - 1) // band_rows
        self.tile_cols = TILE_COLS
        self.nblocks = (W + TILE_COLS - 1) // TILE_COLS
        tiles = (self.band_rows, self.nbands, self.tile_cols, self.nblocks)
        params = camera.kernel_params()
        xmin, xmax, ymin, ymax = self._ground_region(look)
        res = look.res
        ny, nx = look.hz.shape
        # terrain nodes (the cell of each node pair plus one cell of margin)
        self.ti0 = int(np.clip(math.floor(ymin / res) - 1, 0, ny - 2))
        ti1 = int(np.clip(math.ceil(ymax / res) + 1, self.ti0 + 1, ny - 1))
        self.tj0 = int(np.clip(math.floor(xmin / res) - 1, 0, nx - 2))
        tj1 = int(np.clip(math.ceil(xmax / res) + 1, self.tj0 + 1, nx - 1))
        self.V, PX, PY = _project_nodes(look.hz, res, i0=self.ti0, i1=ti1, j0=self.tj0, j1=tj1, C=self.C, A=e.A, q=e.q,
                                        params=params)
        # sub-pixel samples sit up to sample_reach_px from the pixel centres
        margin = CELL_MARGIN_PX + float(sample_reach_px)
        rmin, rmax = _cell_rows(PX, PY, W, H, margin)
        self.cell_box = _cell_boxes(PX, PY, margin)
        self.cell_start, self.cell_list = _bin(*_int64(rmin, rmax, np.maximum(self.cell_box[:, 0], 0),
                                                       np.minimum(self.cell_box[:, 1], W - 1)), tiles)
        # building triangles whose ground box meets the region
        if len(look.tv):
            sel = np.flatnonzero((look.tri_hi[:, 0] >= xmin) & (look.tri_lo[:, 0] <= xmax)
                                 & (look.tri_hi[:, 1] >= ymin) & (look.tri_lo[:, 1] <= ymax))
        else:
            sel = np.zeros(0, np.int64)
        self.tri_ids = sel.astype(np.int64)
        TV = np.ascontiguousarray(e.to_camera(look.tv[sel] - self.C).reshape(-1, 3, 3))  # camera-frame vertices
        self.TV = TV
        self.tri_box = _vertex_boxes(TV.reshape(-1, 3), 3, params, W, H)
        self.tri_start, self.tri_list = _bin(*_int64(self.tri_box[:, 2], self.tri_box[:, 3], self.tri_box[:, 0],
                                                     self.tri_box[:, 1]), tiles)
        # crowns: the 8 corners of each crown's box
        if len(look.tc):
            reach = look.ta[:, 0]
            selk = np.flatnonzero((look.tc[:, 0] + reach >= xmin) & (look.tc[:, 0] - reach <= xmax)
                                  & (look.tc[:, 1] + reach >= ymin) & (look.tc[:, 1] - reach <= ymax))
        else:
            selk = np.zeros(0, np.int64)
        self.tree_ids = selk.astype(np.int64)
        corners = np.empty((len(selk), 8, 3))
        for k, (sx, sy, sz) in enumerate(np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T):
            corners[:, k, 0] = look.tc[selk, 0] + sx * look.ta[selk, 0]
            corners[:, k, 1] = look.tc[selk, 1] + sy * look.ta[selk, 0]
            corners[:, k, 2] = look.tc[selk, 2] + sz * look.ta[selk, 1]
        KV = np.ascontiguousarray(e.to_camera(corners - self.C).reshape(-1, 3))
        self.tree_box = _vertex_boxes(KV, 8, params, W, H)
        # each crown in the camera frame: unit-sphere coordinates u = G v + s of camera-frame points v (the
        # map -> camera transformation linearised at the crown's centre: exact to ~(crown radius)^2 / R)
        D_inv = np.zeros((len(selk), 3, 3))
        D_inv[:, 0, 0] = D_inv[:, 1, 1] = 1.0 / look.ta[selk, 0]
        D_inv[:, 2, 2] = 1.0 / look.ta[selk, 1]
        d_c = look.tc[selk] - self.C
        self.tree_G = np.ascontiguousarray(D_inv @ np.linalg.inv(e.jacobian(d_c)))
        self.tree_s = np.ascontiguousarray(-np.einsum("kij,kj->ki", self.tree_G, e.to_camera(d_c)))
        self.tree_start, self.tree_list = _bin(*_int64(self.tree_box[:, 2], self.tree_box[:, 3], self.tree_box[:, 0],
                                                       self.tree_box[:, 1]), tiles)

    def _ground_region(self, look: SceneLook):
        """Ground box (local x, y) that the frame's rays cross between the scene's lowest and highest
        surface: the border pixels' rays cut at both heights."""
        cam = self.camera
        W, H = cam.width, cam.height
        n = max(8, max(W, H) // 64)
        t = np.linspace(0.0, 1.0, n)
        xs = np.concatenate([t * (W - 1), np.full(n, W - 1.0), t * (W - 1), np.zeros(n)])
        ys = np.concatenate([np.zeros(n), t * (H - 1), np.full(n, H - 1.0), t * (H - 1)])
        xn, yn = cam.pixel_to_normalized(xs, ys)
        d = np.stack([xn, yn, np.ones_like(xn)], axis=1) @ self.earth.A_inv.T
        pts = []
        for z in (look.zlo, look.zhi):
            s = (z - self.C[2]) / d[:, 2]
            pts.append(self.C[None, :2] + s[:, None] * d[:, :2])
        p = np.concatenate(pts)
        # on the earth the rays are straight in ENU, not in map coordinates: they meet the ground up to
        # (distance)^2 / 2R (0.1 m at 1.1 km) off the linear cut; 1 m of margin holds that
        m = 1.0 if self.earth.q.any() else 0.0
        return float(p[:, 0].min()) - m, float(p[:, 0].max()) + m, float(p[:, 1].min()) - m, float(p[:, 1].max()) + m


@numba.njit(cache=True, parallel=True)
def _project_nodes(hz, res, *, i0, i1, j0, j1, C, A, q, params):
    """Camera-frame coordinates (ni, nj, 3) and pixel positions of the terrain nodes i0..i1 x j0..j1 (map offsets
    from ``C`` -> camera frame: ``earth.FrameEarth`` ``A``, ``q``)."""
    ni = i1 - i0 + 1
    nj = j1 - j0 + 1
    V = np.empty((ni, nj, 3))
    PX = np.empty((ni, nj))
    PY = np.empty((ni, nj))
    for a in numba.prange(ni):
        i = i0 + a
        Y = i * res - C[1]
        for b in range(nj):
            j = j0 + b
            X = j * res - C[0]
            Z = hz[i, j] - C[2]
            vx, vy, vz = to_camera_nb(A, q, X, Y, Z)
            V[a, b, 0] = vx
            V[a, b, 1] = vy
            V[a, b, 2] = vz
            PX[a, b], PY[a, b] = lens_kernels.to_pixel(params, vx / vz, vy / vz)
    return V, PX, PY


@numba.njit(cache=True)
def _cell_rows(PX, PY, W, H, margin):
    """First and last image row whose pixel centres (or samples, within ``margin``) a terrain cell may cover;
    rmin > rmax for cells outside the frame."""
    ni, nj = PX.shape
    n = (ni - 1) * (nj - 1)
    rmin = np.empty(n, np.int64)
    rmax = np.empty(n, np.int64)
    for a in range(ni - 1):
        for b in range(nj - 1):
            k = a * (nj - 1) + b
            x0 = min(min(PX[a, b], PX[a, b + 1]), min(PX[a + 1, b], PX[a + 1, b + 1]))
            x1 = max(max(PX[a, b], PX[a, b + 1]), max(PX[a + 1, b], PX[a + 1, b + 1]))
            y0 = min(min(PY[a, b], PY[a, b + 1]), min(PY[a + 1, b], PY[a + 1, b + 1]))
            y1 = max(max(PY[a, b], PY[a, b + 1]), max(PY[a + 1, b], PY[a + 1, b + 1]))
            if x1 < -1.0 or x0 > W or y1 < -1.0 or y0 > H:
                rmin[k] = 1
                rmax[k] = 0
                continue
            rmin[k] = max(0, int(math.ceil(y0 - margin)))
            rmax[k] = min(H - 1, int(math.floor(y1 + margin)))
    return rmin, rmax


@numba.njit(cache=True)
def _cell_boxes(PX, PY, margin):
    """Pixel box (col0, col1, row0, row1) of each terrain cell: the pixels whose centre lies within ``margin``
    of its vertices' box, unclipped."""
    ni, nj = PX.shape
    box = np.empty(((ni - 1) * (nj - 1), 4), np.int32)
    for a in range(ni - 1):
        for b in range(nj - 1):
            k = a * (nj - 1) + b
            x0 = min(min(PX[a, b], PX[a, b + 1]), min(PX[a + 1, b], PX[a + 1, b + 1]))
            x1 = max(max(PX[a, b], PX[a, b + 1]), max(PX[a + 1, b], PX[a + 1, b + 1]))
            y0 = min(min(PY[a, b], PY[a, b + 1]), min(PY[a + 1, b], PY[a + 1, b + 1]))
            y1 = max(max(PY[a, b], PY[a, b + 1]), max(PY[a + 1, b], PY[a + 1, b + 1]))
            box[k, 0] = max(-1, min(1 << 30, int(math.ceil(x0 - margin))))
            box[k, 1] = max(-1, min(1 << 30, int(math.floor(x1 + margin))))
            box[k, 2] = max(-1, min(1 << 30, int(math.ceil(y0 - margin))))
            box[k, 3] = max(-1, min(1 << 30, int(math.floor(y1 + margin))))
    return box


@numba.njit(cache=True)
def _vertex_boxes(Vc, per_item, params, W, H):
    """Pixel box (col0, col1, row0, row1) of items given by ``per_item`` camera-frame points each (2 px
    margin); row0 > row1 for items outside the frame or reaching behind the camera."""
    n = Vc.shape[0] // per_item
    box = np.empty((n, 4), np.int64)
    for k in range(n):
        x0 = np.inf
        x1 = -np.inf
        y0 = np.inf
        y1 = -np.inf
        behind = False
        for q in range(per_item):
            v = Vc[k * per_item + q]
            if v[2] <= 1e-6:
                behind = True
                break
            px, py = lens_kernels.to_pixel(params, v[0] / v[2], v[1] / v[2])
            x0 = min(x0, px)
            x1 = max(x1, px)
            y0 = min(y0, py)
            y1 = max(y1, py)
        if behind or x1 < -2.0 or x0 > W + 1 or y1 < -2.0 or y0 > H + 1:
            box[k, 0] = 1
            box[k, 1] = 0
            box[k, 2] = 1
            box[k, 3] = 0
            continue
        box[k, 0] = max(0, int(math.floor(x0)) - 2)
        box[k, 1] = min(W - 1, int(math.ceil(x1)) + 2)
        box[k, 2] = max(0, int(math.floor(y0)) - 2)
        box[k, 3] = min(H - 1, int(math.ceil(y1)) + 2)
    return box


def _int64(*arrays) -> list[np.ndarray]:
    """``_bin``'s index arrays as contiguous int64 (the cells' are int32, the boxes' column slices): numba compiles
    it for one signature."""
    return [np.ascontiguousarray(a, dtype=np.int64) for a in arrays]


@numba.njit(cache=True)
def _bin(rmin, rmax, cmin, cmax, tiles):
    """CSR lists of the items overlapping each tile (items with rows rmin..rmax and columns cmin..cmax; none where
    rmin > rmax or cmin > cmax); ``tiles`` (band_rows, nbands, tile_cols, nblocks): tile b * nblocks + j holds
    rows of band b and columns of block j. Each list keeps the items' order (the depth test keeps the first of
    equally near surfaces: the same one as in one list for the whole frame)."""
    band_rows, nbands, tile_cols, nblocks = tiles
    counts = np.zeros(nbands * nblocks + 1, np.int64)
    for k in range(rmin.shape[0]):
        if rmin[k] > rmax[k] or cmin[k] > cmax[k]:
            continue
        for b in range(rmin[k] // band_rows, rmax[k] // band_rows + 1):
            for j in range(cmin[k] // tile_cols, cmax[k] // tile_cols + 1):
                counts[b * nblocks + j + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    items = np.empty(start[-1], np.int64)
    for k in range(rmin.shape[0]):
        if rmin[k] > rmax[k] or cmin[k] > cmax[k]:
            continue
        for b in range(rmin[k] // band_rows, rmax[k] // band_rows + 1):
            for j in range(cmin[k] // tile_cols, cmax[k] // tile_cols + 1):
                t = b * nblocks + j
                items[fill[t]] = k
                fill[t] += 1
    return start, items


# ----------------------------------------------------------------------------------------------
# The band kernel


@numba.njit(cache=True, inline="always")
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@numba.njit(cache=True, inline="always")
def _mix32(h):
    """A 32-bit integer hash (cut back to 32 bits at every step: numba widens integer arithmetic)."""
    h = numba.uint32(h ^ (h >> numba.uint32(16)))
    h = numba.uint32(h * numba.uint32(0x7FEB352D))
    h = numba.uint32(h ^ (h >> numba.uint32(15)))
    h = numba.uint32(h * numba.uint32(0x846CA68B))
    return numba.uint32(h ^ (h >> numba.uint32(16)))


@numba.njit(cache=True, inline="always")
def _raster_tri(a, b, c, box, band, code_val):
    """Depth-test one camera-frame triangle (vertices ``a``, ``b``, ``c``: (x, y, z) tuples) into the band
    buffers over the pixel ``box`` (c0, c1, r0, r1); ``band``: the tile's first row ``rb0`` and column ``cb0``, the
    pixel rays ``xnb``, ``ynb``, the inverse depth ``wb`` (larger = nearer) and the primitive ``code`` of each
    pixel, set to ``code_val`` where the triangle is nearer."""
    ax, ay, az = a
    bx, by, bz = b
    cx, cy, cz = c
    c0, c1, r0, r1 = box
    rb0, cb0, xnb, ynb, wb, code = band
    e1x, e1y, e1z = _cross(ax, ay, az, bx, by, bz)
    e2x, e2y, e2z = _cross(bx, by, bz, cx, cy, cz)
    e3x, e3y, e3z = _cross(cx, cy, cz, ax, ay, az)
    nx, ny, nz = _cross(bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az)
    k = nx * ax + ny * ay + nz * az
    if k == 0.0:
        return  # the plane passes through the projection centre: seen edge-on
    ik = 1.0 / k
    nx *= ik
    ny *= ik
    nz *= ik
    for r in range(r0, r1 + 1):
        rr = r - rb0
        for cc in range(c0 - cb0, c1 - cb0 + 1):
            xn = xnb[rr, cc]
            yn = ynb[rr, cc]
            s1 = e1x * xn + e1y * yn + e1z
            s2 = e2x * xn + e2y * yn + e2z
            s3 = e3x * xn + e3y * yn + e3z
            if (s1 >= 0.0 and s2 >= 0.0 and s3 >= 0.0) or (s1 <= 0.0 and s2 <= 0.0 and s3 <= 0.0):
                w = nx * xn + ny * yn + nz
                if w > wb[rr, cc]:
                    wb[rr, cc] = w
                    code[rr, cc] = code_val


@numba.njit(cache=True, inline="always")
def _surface_normal(typ, idx, p, cells, surfaces):
    """The surface normal (nx, ny, nz), not unit, and the kind and object id of a z-buffer hit at ``p`` (x, y, z)
    (local metres): ``typ`` terrain triangle A or B of terrain cell ``idx`` (row ``idx >> _CELL_SHIFT``, column
    ``idx & _CELL_MASK`` of the cells from node ``cells`` (gi0, gj0)), ``_T_TRI`` mesh triangle ``idx``, or else
    the crown of tree ``idx``. ``surfaces``: the height field ``hz`` (nodes ``res`` apart), the mesh triangles'
    normals ``tn``, kinds ``tkind`` and objects ``tobj``, the crowns (ellipsoids: centres ``tc``, semi-axes
    ``ta``)."""
    x, y, z = p
    # each branch takes its arrays from ``surfaces`` itself: an array unpacked once for all branches costs a
    # reference count per pixel (numba prunes the pair only within one block)
    if typ == _T_TERRAIN_A or typ == _T_TERRAIN_B:
        gi0, gj0 = cells
        hz, res = surfaces[0], surfaces[1]
        gi = gi0 + (idx >> _CELL_SHIFT)
        gj = gj0 + (idx & _CELL_MASK)
        h00 = hz[gi, gj]
        h10 = hz[gi, gj + 1]
        h01 = hz[gi + 1, gj]
        h11 = hz[gi + 1, gj + 1]
        if typ == _T_TERRAIN_A:
            nx = -(h10 - h00) * res
            ny = -(h11 - h10) * res
        else:
            nx = -(h11 - h01) * res
            ny = -(h01 - h00) * res
        nz = res * res
        k = KIND_TERRAIN
        o = 0
    elif typ == _T_TRI:
        tn, tkind, tobj = surfaces[2], surfaces[3], surfaces[4]
        nx, ny, nz = tn[idx, 0], tn[idx, 1], tn[idx, 2]
        k = tkind[idx]
        o = tobj[idx]
    else:
        tc, ta = surfaces[5], surfaces[6]
        nx = (x - tc[idx, 0]) / (ta[idx, 0] * ta[idx, 0])
        ny = (y - tc[idx, 1]) / (ta[idx, 0] * ta[idx, 0])
        nz = (z - tc[idx, 2]) / (ta[idx, 1] * ta[idx, 1])
        k = KIND_TREE
        o = idx
    return nx, ny, nz, k, o


@numba.njit(cache=True, inline="always")
def _hit_normal(typ, idx, p, d, cells, surfaces):
    """``_surface_normal`` as a unit normal facing against the viewing direction ``d`` (dx, dy, dz)."""
    nx, ny, nz, k, o = _surface_normal(typ, idx, p, cells, surfaces)
    dx, dy, dz = d
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if nx * dx + ny * dy + nz * dz > 0.0:
        nn = -nn
    return nx / nn, ny / nn, nz / nn, k, o


@numba.njit(cache=True, error_model="numpy")
def _hit_points(ray, n, C, earth, P, D):
    """Surface points ``P`` (X, Y, Z: map offsets from the frame's centre ``C`` plus ``C``) and viewing directions
    ``D`` (DX, DY, DZ, map axes) of the first ``n`` pixels of a row of a tile: ``ray`` (xn, yn, w) their rays and
    inverse depths; ``earth`` (A_inv, quad, curved): the frame's camera -> map transformation
    (``aerotri.sim.earth.to_map_nb`` where ``curved``). A pixel that shows nothing (w = 0) gets a point at
    infinity, which the caller replaces. A loop of its own, with numpy's error model (no check of w for zero),
    so that it vectorises."""
    xnr, ynr, wr = ray
    A_inv, quad, curved = earth
    X, Y, Z = P
    DX, DY, DZ = D
    for c in range(n):
        xn = xnr[c]
        yn = ynr[c]
        # the viewing direction in map axes (its sign turns the normal) and the hit point: the camera-frame
        # point at depth 1 / w back to the map
        dx = A_inv[0, 0] * xn + A_inv[0, 1] * yn + A_inv[0, 2]
        dy = A_inv[1, 0] * xn + A_inv[1, 1] * yn + A_inv[1, 2]
        dz = A_inv[2, 0] * xn + A_inv[2, 1] * yn + A_inv[2, 2]
        t = 1.0 / wr[c]
        if curved:
            ox, oy, oz = to_map_nb(A_inv, quad, t * xn, t * yn, t)
            X[c] = C[0] + ox
            Y[c] = C[1] + oy
            Z[c] = C[2] + oz
        else:
            X[c] = C[0] + t * dx
            Y[c] = C[1] + t * dy
            Z[c] = C[2] + t * dz
        DX[c] = dx
        DY[c] = dy
        DZ[c] = dz


@numba.njit(cache=True, error_model="numpy")
def _face_viewer(N, D, n):
    """``_hit_normal``'s last step over the first ``n`` normals ``N`` (NX, NY, NZ), in place: each made unit and
    turned against its viewing direction in ``D`` (DX, DY, DZ). Apart from the per-pixel branches of
    ``_surface_normal`` this loop vectorises (its square roots and divisions were a fifth of a frame's time);
    the same operations, so the same bits."""
    NX, NY, NZ = N
    DX, DY, DZ = D
    for c in range(n):
        nx = NX[c]
        ny = NY[c]
        nz = NZ[c]
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        if nx * DX[c] + ny * DY[c] + nz * DZ[c] > 0.0:
            nn = -nn
        NX[c] = nx / nn
        NY[c] = ny / nn
        NZ[c] = nz / nn


@numba.njit(cache=True, nogil=True)
def _render_bands(band0, band1, row_out0, *, W, H, band_rows, tile_cols, step, XN, YN, C, A_inv, quad, curved,
                  V, ti0, tj0, cell_start, cell_list, cell_box,
                  TV, tri_ids, tri_start, tri_list, tri_box,
                  tree_ids, tree_start, tree_list, tree_box, tree_G, tree_s,
                  hz, res, tn, tkind, tobj, tc, ta,
                  G, roof_albedo, fine_m, sun,
                  gain, vignetting, noise_dn, noise_seed, bits, lut,
                  out, ids_out, want_ids):
    """Render bands band0..band1-1 of a frame into ``out`` (rows from ``row_out0``; (rows, W, 3) uint8 or
    uint16), each band a tile of ``tile_cols`` columns at a time (the primitive lists are per tile: band b, block
    j at b * nblocks + j); ``XN``/``YN`` (S, rows, cols) hold the pixel grid of each of the S sub-pixel samples.
    One thread; without the GIL (``FrameRenderer`` runs bands on its threads)."""
    S = XN.shape[0]
    ncj = V.shape[1] - 1
    inv_step = 1.0 / step
    nblocks = (W + tile_cols - 1) // tile_cols
    for b in range(band0, band1):
        rb0 = b * band_rows
        rb1 = min(H, rb0 + band_rows)
        hb = rb1 - rb0
        TW = min(tile_cols, W)
        acc = np.zeros((hb if S > 1 else 0, TW, 3), np.float32)
        wb = np.empty((hb, TW))
        code = np.empty((hb, TW), np.int64)
        xnb = np.empty((hb, TW))
        ynb = np.empty((hb, TW))
        rowx = np.empty(XN.shape[2])
        rowy = np.empty(XN.shape[2])
        X = np.empty(TW)
        Y = np.empty(TW)
        Z = np.empty(TW)
        NX = np.empty(TW)
        NY = np.empty(TW)
        NZ = np.empty(TW)
        DX = np.empty(TW)
        DY = np.empty(TW)
        DZ = np.empty(TW)
        kind = np.empty(TW, np.int64)
        obj = np.empty(TW, np.int64)
        rad = np.empty((TW, 3), np.float32)
        scratch = shading.shade_scratch_nb(TW)
        expo_scratch = (np.empty(TW, np.float32), np.empty(TW, np.uint32), np.empty(TW, np.uint32))
        surfaces = (hz, res, tn, tkind, tobj, tc, ta)
        exposure = (gain, vignetting, noise_dn, noise_seed, bits, lut)
        look = (G, roof_albedo, fine_m, sun)
        for jb in range(nblocks):
            cb0 = jb * tile_cols
            cb1 = min(W, cb0 + tile_cols)
            tw = cb1 - cb0
            t = b * nblocks + jb
            band = (rb0, cb0, xnb, ynb, wb, code)  # the tuples of arrays once a tile, not once a pixel
            if S > 1:
                acc[:] = 0.0
            for s in range(S):
                # pixel rays of the tile: the coarse grid interpolated along its rows, then along the columns
                g0 = int(cb0 * inv_step)
                g1 = int((cb1 - 1) * inv_step) + 1
                for rr in range(hb):
                    gy = (rb0 + rr) * inv_step
                    gi = int(gy)
                    v = gy - gi
                    for j in range(g0, g1 + 1):
                        rowx[j] = XN[s, gi, j] + (XN[s, gi + 1, j] - XN[s, gi, j]) * v
                        rowy[j] = YN[s, gi, j] + (YN[s, gi + 1, j] - YN[s, gi, j]) * v
                    for c in range(cb0, cb1):
                        gx = c * inv_step
                        gj = int(gx)
                        u = gx - gj
                        xnb[rr, c - cb0] = rowx[gj] + (rowx[gj + 1] - rowx[gj]) * u
                        ynb[rr, c - cb0] = rowy[gj] + (rowy[gj + 1] - rowy[gj]) * u
                        wb[rr, c - cb0] = 0.0
                        code[rr, c - cb0] = 0
                # terrain cells: triangles (00, 10, 11) and (00, 11, 01) as the ray caster splits them
                for q in range(cell_start[t], cell_start[t + 1]):
                    cell = cell_list[q]
                    ca = cell // ncj
                    cb = cell - ca * ncj
                    c0 = max(cb0, cell_box[cell, 0])
                    c1 = min(cb1 - 1, cell_box[cell, 1])
                    r0 = max(rb0, cell_box[cell, 2])
                    r1 = min(rb1 - 1, cell_box[cell, 3])
                    if c0 > c1 or r0 > r1:
                        continue
                    p00x, p00y, p00z = V[ca, cb, 0], V[ca, cb, 1], V[ca, cb, 2]
                    p10x, p10y, p10z = V[ca, cb + 1, 0], V[ca, cb + 1, 1], V[ca, cb + 1, 2]
                    p01x, p01y, p01z = V[ca + 1, cb, 0], V[ca + 1, cb, 1], V[ca + 1, cb, 2]
                    p11x, p11y, p11z = V[ca + 1, cb + 1, 0], V[ca + 1, cb + 1, 1], V[ca + 1, cb + 1, 2]
                    e1x, e1y, e1z = _cross(p00x, p00y, p00z, p10x, p10y, p10z)
                    e2x, e2y, e2z = _cross(p10x, p10y, p10z, p11x, p11y, p11z)
                    e3x, e3y, e3z = _cross(p11x, p11y, p11z, p00x, p00y, p00z)
                    f2x, f2y, f2z = _cross(p11x, p11y, p11z, p01x, p01y, p01z)
                    f3x, f3y, f3z = _cross(p01x, p01y, p01z, p00x, p00y, p00z)
                    # inverse depth on each triangle's plane: (n . d) / (n . P0), linear in (xn, yn)
                    nax, nay, naz = _cross(p10x - p00x, p10y - p00y, p10z - p00z, p11x - p00x, p11y - p00y,
                                           p11z - p00z)
                    ka = nax * p00x + nay * p00y + naz * p00z
                    nbx, nby, nbz = _cross(p11x - p00x, p11y - p00y, p11z - p00z, p01x - p00x, p01y - p00y,
                                           p01z - p00z)
                    kb = nbx * p00x + nby * p00y + nbz * p00z
                    if ka == 0.0 or kb == 0.0:
                        continue
                    nax /= ka
                    nay /= ka
                    naz /= ka
                    nbx /= kb
                    nby /= kb
                    nbz /= kb
                    code_a = (numba.int64(_T_TERRAIN_A) << _SHIFT) | (ca << _CELL_SHIFT) | cb
                    code_b = (numba.int64(_T_TERRAIN_B) << _SHIFT) | (ca << _CELL_SHIFT) | cb
                    for r in range(r0, r1 + 1):
                        rr = r - rb0
                        for cc in range(c0 - cb0, c1 - cb0 + 1):
                            xn = xnb[rr, cc]
                            yn = ynb[rr, cc]
                            s1 = e1x * xn + e1y * yn + e1z
                            s2 = e2x * xn + e2y * yn + e2z
                            s3 = e3x * xn + e3y * yn + e3z
                            if (s1 >= 0.0 and s2 >= 0.0 and s3 >= 0.0) or (s1 <= 0.0 and s2 <= 0.0 and s3 <= 0.0):
                                w = nax * xn + nay * yn + naz
                                if w > wb[rr, cc]:
                                    wb[rr, cc] = w
                                    code[rr, cc] = code_a
                                continue
                            t2 = f2x * xn + f2y * yn + f2z
                            t3 = f3x * xn + f3y * yn + f3z
                            if (s3 <= 0.0 and t2 >= 0.0 and t3 >= 0.0) or (s3 >= 0.0 and t2 <= 0.0 and t3 <= 0.0):
                                w = nbx * xn + nby * yn + nbz
                                if w > wb[rr, cc]:
                                    wb[rr, cc] = w
                                    code[rr, cc] = code_b
                # building triangles
                for q in range(tri_start[t], tri_start[t + 1]):
                    k = tri_list[q]
                    r0 = max(rb0, tri_box[k, 2])
                    r1 = min(rb1 - 1, tri_box[k, 3])
                    c0 = max(cb0, tri_box[k, 0])
                    c1 = min(cb1 - 1, tri_box[k, 1])
                    if r0 > r1 or c0 > c1:
                        continue
                    _raster_tri((TV[k, 0, 0], TV[k, 0, 1], TV[k, 0, 2]), (TV[k, 1, 0], TV[k, 1, 1], TV[k, 1, 2]),
                                (TV[k, 2, 0], TV[k, 2, 1], TV[k, 2, 2]), (c0, c1, r0, r1),
                                band, (numba.int64(_T_TRI) << _SHIFT) | tri_ids[k])
                # crowns (spheroids with vertical axis), in object coordinates
                for q in range(tree_start[t], tree_start[t + 1]):
                    k = tree_list[q]
                    m = tree_ids[k]
                    r0 = max(rb0, tree_box[k, 2])
                    r1 = min(rb1 - 1, tree_box[k, 3])
                    c0 = max(cb0, tree_box[k, 0])
                    c1 = min(cb1 - 1, tree_box[k, 1])
                    if r0 > r1 or c0 > c1:
                        continue
                    Gk = tree_G[k]
                    sx, sy, sz = tree_s[k, 0], tree_s[k, 1], tree_s[k, 2]
                    Cq = sx * sx + sy * sy + sz * sz - 1.0
                    tcode = (numba.int64(_T_TREE) << _SHIFT) | m
                    for r in range(r0, r1 + 1):
                        rr = r - rb0
                        for cc in range(c0 - cb0, c1 - cb0 + 1):
                            xn = xnb[rr, cc]
                            yn = ynb[rr, cc]
                            ux = Gk[0, 0] * xn + Gk[0, 1] * yn + Gk[0, 2]
                            uy = Gk[1, 0] * xn + Gk[1, 1] * yn + Gk[1, 2]
                            uz = Gk[2, 0] * xn + Gk[2, 1] * yn + Gk[2, 2]
                            A = ux * ux + uy * uy + uz * uz
                            B = 2.0 * (sx * ux + sy * uy + sz * uz)
                            disc = B * B - 4.0 * A * Cq
                            if disc > 0.0:
                                tt = (-B - math.sqrt(disc)) / (2.0 * A)
                                if tt > 1e-9 and 1.0 > tt * wb[rr, cc]:
                                    wb[rr, cc] = 1.0 / tt
                                    code[rr, cc] = tcode
                # the surface point, normal and kind of every pixel, shaded a row of the tile at a time
                for rr in range(hb):
                    _hit_points((xnb[rr], ynb[rr], wb[rr]), tw, C, (A_inv, quad, curved), (X, Y, Z), (DX, DY, DZ))
                    for cc in range(tw):
                        cv = code[rr, cc]
                        typ = cv >> _SHIFT
                        idx = cv & _MASK
                        if typ == _T_NONE:
                            kind[cc] = KIND_NONE
                            obj[cc] = 0
                            X[cc] = 0.0
                            Y[cc] = 0.0
                            Z[cc] = 0.0
                            NX[cc] = 0.0
                            NY[cc] = 0.0
                            NZ[cc] = 1.0
                            DX[cc] = 0.0  # (0, 0, 1) stays as it is
                            DY[cc] = 0.0
                            DZ[cc] = 0.0
                            continue
                        NX[cc], NY[cc], NZ[cc], kind[cc], obj[cc] = _surface_normal(
                            typ, idx, (X[cc], Y[cc], Z[cc]), (ti0, tj0), surfaces)
                    _face_viewer((NX, NY, NZ), (DX, DY, DZ), tw)
                    shading.shade_into((X, Y, Z), (kind, obj), (NX, NY, NZ), look, (rad, tw), scratch)
                    r = rb0 + rr
                    if want_ids and s == 0:
                        for cc in range(tw):
                            ids_out[r - row_out0, cb0 + cc] = (kind[cc] * 1000000 + obj[cc]
                                                               if kind[cc] != KIND_NONE else 0)
                    if S == 1:
                        _expose_row(rad, (r, cb0, cb1), (W, H), exposure, out[r - row_out0], expo_scratch)
                    else:
                        for cc in range(tw):
                            acc[rr, cc, 0] += rad[cc, 0] / S
                            acc[rr, cc, 1] += rad[cc, 1] / S
                            acc[rr, cc, 2] += rad[cc, 2] / S
            if S > 1:
                for rr in range(hb):
                    _expose_row(acc[rr], (rb0 + rr, cb0, cb1), (W, H), exposure, out[rb0 + rr - row_out0],
                                expo_scratch)


@numba.njit(cache=True, fastmath=True)
def _expose_row(rad, span, size, exposure, out, scratch):
    """Exposure of columns c0..c1-1 of image row r (``span``: (r, c0, c1)) of a frame of ``size`` (W, H) px; ``exposure``:
    (gain, vignetting, noise_dn, noise_seed, bits, lut). Radiance (``rad`` (c1 - c0, 3), from column c0) x gain x
    radial vignetting (the fraction ``vignetting`` lost at the corners), the tone curve (8-bit: ``lut``; 12-bit:
    linear 0..4095 for 1.25 x radiance 0..1), sensor noise (the sum of two 10-bit uniforms from a hash of seed,
    pixel and band: triangular, zero mean, sigma ``noise_dn``), rounding, clipping -> ``out`` (W, 3), or (W, 1):
    panchromatic, the mean of R, G and B; ``scratch``: three work arrays of at least c1 - c0."""
    W, H = size
    r, c0, c1 = span
    gain, vignetting, noise_dn, noise_seed, bits, lut = exposure
    fac, h1, h2 = scratch
    cw = (W - 1) / 2.0
    ch = (H - 1) / 2.0
    rnorm = 1.0 / (cw * cw + ch * ch)
    dyc = r - ch
    ry = numba.float32(dyc * dyc)
    out_max = numba.float32(255.0 if bits == 8 else 4095.0)
    nlut = numba.float32(lut.shape[0] - 2)
    g = numba.float32(1.25 * gain)
    vig = numba.float32(vignetting * rnorm)
    scale = numba.float32(SQRT6 * noise_dn / 1024.0)
    base = numba.uint32((r * W) & 0xFFFFFFFF)
    zero = numba.float32(0.0)
    one = numba.float32(1.0)
    half = numba.float32(0.5)
    for c in range(c0, c1):
        dxc = numba.float32(c - cw)
        fac[c - c0] = g * (one - vig * (dxc * dxc + ry))
        h = _mix32(numba.uint32(noise_seed ^ numba.uint32(base + numba.uint32(c))))
        h1[c - c0] = h
        h2[c - c0] = _mix32(numba.uint32(h ^ numba.uint32(0x9E3779B9)))
    nb = out.shape[1]
    third = numba.float32(1.0 / 3.0)
    for band in range(nb):
        sh = numba.uint32(10 * band)
        if nb == 1:  # panchromatic: the mean of the R, G, B radiance
            for c in range(c1 - c0):
                fac[c] *= (numba.float32(rad[c, 0]) + numba.float32(rad[c, 1]) + numba.float32(rad[c, 2])) * third
        if bits == 8:
            for c in range(c1 - c0):
                x = min(max((numba.float32(rad[c, band]) if nb > 1 else one) * fac[c], zero), one)
                fi = x * nlut
                i = numba.int32(fi)
                dn = lut[i] + (lut[i + 1] - lut[i]) * (fi - numba.float32(i))
                u = numba.float32((h1[c] >> sh) & numba.uint32(1023)) + numba.float32((h2[c] >> sh) & numba.uint32(1023))
                # round half up: truncation of the non-negative value + 0.5
                out[c0 + c, band] = numba.int32(min(max(dn + (u - numba.float32(1023.0)) * scale + half, zero),
                                                    out_max + half))
        else:
            for c in range(c1 - c0):
                dn = out_max * min(max((numba.float32(rad[c, band]) if nb > 1 else one) * fac[c], zero), one)
                u = numba.float32((h1[c] >> sh) & numba.uint32(1023)) + numba.float32((h2[c] >> sh) & numba.uint32(1023))
                out[c0 + c, band] = numba.int32(min(max(dn + (u - numba.float32(1023.0)) * scale + half, zero),
                                                    out_max + half))


# ----------------------------------------------------------------------------------------------
# Public API


class RenderedRows:
    """Rows being rendered (``FrameRenderer.submit_rows``): ``result()`` waits for their bands and gives
    (rows, width, bands) samples and the surface ids (None unless asked for)."""

    def __init__(self, tasks: list[Future], out: np.ndarray, ids: np.ndarray | None):
        self._tasks, self._out, self._ids = tasks, out, ids

    def result(self):
        for t in self._tasks:
            t.result()  # a band's error is raised here
        return self._out, self._ids


class FrameRenderer:
    """Renders the frames of a block: ``render_rows`` gives any range of rows of a frame as output samples.

    ``bits`` 8: uint8 through the gamma tone curve of ``render.tone_map``; 12: uint16 in 0..4095, linear.
    ``samples``: sub-pixel samples per axis (anti-aliasing), averaged before exposure. ``bands`` 3: R, G, B;
    1: panchromatic (the mean of the R, G, B radiance).
    """

    def __init__(self, scene: Scene, camera: Camera, fine_m: float, *, samples: int = 1, bits: int = 8,
                 look: SceneLook | None = None, bands: int = 3):
        if bits not in (8, 12):
            raise ValueError(f"bits must be 8 or 12, got {bits}")
        if bands not in (1, 3):
            raise ValueError(f"bands must be 1 or 3, got {bands}")
        self.bands = int(bands)
        self.look = look or SceneLook(scene, fine_m)
        self.camera = camera
        self.bits = int(bits)
        offsets = (np.arange(samples) + 0.5) / samples - 0.5 if samples > 1 else np.zeros(1)
        grids = [PixelGrid(camera, ox, oy) for oy in offsets for ox in offsets]
        self.sample_reach_px = float(np.abs(offsets).max())
        self.XN = np.ascontiguousarray(np.stack([g.xn for g in grids]))
        self.YN = np.ascontiguousarray(np.stack([g.yn for g in grids]))
        self.step = grids[0].step
        self.lut = tone_lut()
        self.dtype = np.uint8 if bits == 8 else np.uint16
        self._pool: ThreadPoolExecutor | None = None  # started at the first rows (threads: numba's count then)

    def setup(self, centre_m, R, earth: FrameEarth | None = None) -> FrameSetup:
        """A frame at scene-local ``centre_m`` with attitude ``R`` (grid axes at the centre); ``earth``: its
        ``aerotri.sim.earth.FrameEarth`` (default: the flat world)."""
        return FrameSetup(self.look, self.camera, centre_m, R, sample_reach_px=self.sample_reach_px, earth=earth)

    def render_rows(self, frame: FrameSetup, r0: int, r1: int, *, gain: float = 1.0, vignetting: float = 0.0,
                    noise_dn: float = 0.0, noise_seed: int = 0, with_ids: bool = False):
        """Rows r0..r1-1 (r0 a multiple of ``BAND_ROWS``) as (rows, width, bands) samples, and optionally the
        surface id of each pixel centre (kind * 1_000_000 + object, 0 where the ray leaves the scene)."""
        return self.submit_rows(frame, r0, r1, gain=gain, vignetting=vignetting, noise_dn=noise_dn,
                                noise_seed=noise_seed, with_ids=with_ids).result()

    def submit_rows(self, frame: FrameSetup, r0: int, r1: int, *, gain: float = 1.0, vignetting: float = 0.0,
                    noise_dn: float = 0.0, noise_seed: int = 0, with_ids: bool = False) -> RenderedRows:
        """``render_rows`` started on the renderer's threads, a band (``BAND_ROWS`` rows) a task; its
        ``result()`` waits for them. The calling thread is free meanwhile (the kernel holds no GIL)."""
        cam = self.camera
        br = frame.band_rows
        if r0 % br:
            raise ValueError(f"row {r0} is not at a band boundary ({br} rows)")
        r1 = min(r1, cam.height)
        out = np.empty((r1 - r0, cam.width, self.bands), self.dtype)
        ids = np.empty((r1 - r0, cam.width) if with_ids else (1, 1), np.int64)
        L = self.look
        args = dict(W=cam.width, H=cam.height, band_rows=br, tile_cols=frame.tile_cols, step=float(self.step),
                    XN=self.XN, YN=self.YN, C=frame.C, A_inv=frame.earth.A_inv, quad=frame.earth.q,
                    curved=bool(frame.earth.q.any()), V=frame.V, ti0=frame.ti0, tj0=frame.tj0,
                    cell_start=frame.cell_start, cell_list=frame.cell_list, cell_box=frame.cell_box, TV=frame.TV,
                    tri_ids=frame.tri_ids, tri_start=frame.tri_start, tri_list=frame.tri_list,
                    tri_box=frame.tri_box, tree_ids=frame.tree_ids, tree_start=frame.tree_start,
                    tree_list=frame.tree_list, tree_box=frame.tree_box, tree_G=frame.tree_G, tree_s=frame.tree_s,
                    hz=L.hz, res=L.res, tn=L.tn, tkind=L.tkind, tobj=L.tobj, tc=L.tc, ta=L.ta, G=L.G,
                    roof_albedo=L.roof_albedo, fine_m=L.fine_m, sun=L.sun, gain=float(gain),
                    vignetting=float(vignetting), noise_dn=float(noise_dn),
                    noise_seed=np.uint32(noise_seed & 0xFFFFFFFF), bits=self.bits, lut=self.lut, want_ids=with_ids)

        def band(a: int) -> None:
            b = min(r1, a + br)
            rows_ids = ids[a - r0:b - r0] if with_ids else ids
            if self.dtype == np.uint16:
                _render_bands(a // br, a // br + 1, a, out=out[a - r0:b - r0], ids_out=rows_ids, **args)
            else:
                # the kernel always writes uint16 samples: one compiled signature for 8- and 12-bit frames (each
                # costs about 22 CPU-s to compile, docs/testing.md); 8-bit ones (0..255) are narrowed a band at a time
                buf = np.empty((b - a, cam.width, self.bands), np.uint16)
                _render_bands(a // br, a // br + 1, a, out=buf, ids_out=rows_ids, **args)
                out[a - r0:b - r0] = buf

        return RenderedRows([self._threads().submit(band, a) for a in range(r0, r1, br)], out,
                            ids if with_ids else None)

    def _threads(self) -> ThreadPoolExecutor:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max(1, numba.get_num_threads()), thread_name_prefix="render")
        return self._pool

    def render(self, centre_m, R, **kw):
        """A whole frame (for small frames and tests)."""
        frame = self.setup(centre_m, R)
        return self.render_rows(frame, 0, self.camera.height, **kw)


# ----------------------------------------------------------------------------------------------
# Straight down: true orthophoto, DSM, land-cover ids


@numba.njit(cache=True, parallel=True)
def _ortho_rows(x0, ytop, step_m, r0, *, nrows, ncols, hz, res, tv, tri_ids, tree_ids, tc, ta, sub_rows, zout, code):
    """Highest surface at pixel centres (x0 + (c + 0.5) step, ytop - (r + 0.5) step), rows r0..r0+nrows-1:
    height into ``zout`` and primitive code into ``code``."""
    ny, nx = hz.shape
    nsub = (nrows + sub_rows - 1) // sub_rows
    for sb in numba.prange(nsub):
        a0 = sb * sub_rows
        a1 = min(nrows, a0 + sub_rows)
        ylo = ytop - (r0 + a1 - 0.5) * step_m  # lowest pixel-centre y of the sub-block
        yhi = ytop - (r0 + a0 + 0.5) * step_m
        for a in range(a0, a1):
            y = ytop - (r0 + a + 0.5) * step_m
            fy = min(max(y / res, 0.0), ny - 1 - 1e-9)
            i = int(math.floor(fy))
            v = fy - i
            for c in range(ncols):
                x = x0 + (c + 0.5) * step_m
                fx = min(max(x / res, 0.0), nx - 1 - 1e-9)
                j = int(math.floor(fx))
                u = fx - j
                h00 = hz[i, j]
                h10 = hz[i, j + 1]
                h01 = hz[i + 1, j]
                h11 = hz[i + 1, j + 1]
                if u >= v:
                    zout[a, c] = h00 + u * (h10 - h00) + v * (h11 - h10)
                    code[a, c] = (numba.int64(_T_TERRAIN_A) << _SHIFT) | (i << _CELL_SHIFT) | j
                else:
                    zout[a, c] = h00 + v * (h01 - h00) + u * (h11 - h01)
                    code[a, c] = (numba.int64(_T_TERRAIN_B) << _SHIFT) | (i << _CELL_SHIFT) | j
        for q in range(tri_ids.shape[0]):
            k = tri_ids[q]
            ax, ay, az = tv[k, 0, 0], tv[k, 0, 1], tv[k, 0, 2]
            bx, by, bz = tv[k, 1, 0], tv[k, 1, 1], tv[k, 1, 2]
            cx, cy, cz = tv[k, 2, 0], tv[k, 2, 1], tv[k, 2, 2]
            if max(ay, max(by, cy)) < ylo or min(ay, min(by, cy)) > yhi:
                continue
            area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            if abs(area) < 1e-12:
                continue  # a wall: no area seen from above
            xmn = min(ax, min(bx, cx))
            xmx = max(ax, max(bx, cx))
            ymn = min(ay, min(by, cy))
            ymx = max(ay, max(by, cy))
            cc0 = max(0, int(math.ceil((xmn - x0) / step_m - 0.5)))
            cc1 = min(ncols - 1, int(math.floor((xmx - x0) / step_m - 0.5)))
            aa0 = max(a0, int(math.ceil((ytop - ymx) / step_m - 0.5)) - r0)
            aa1 = min(a1 - 1, int(math.floor((ytop - ymn) / step_m - 0.5)) - r0)
            inv = 1.0 / area
            tcode = (numba.int64(_T_TRI) << _SHIFT) | k
            for a in range(aa0, aa1 + 1):
                y = ytop - (r0 + a + 0.5) * step_m
                for c in range(cc0, cc1 + 1):
                    x = x0 + (c + 0.5) * step_m
                    w0 = ((bx - x) * (cy - y) - (by - y) * (cx - x)) * inv
                    w1 = ((cx - x) * (ay - y) - (cy - y) * (ax - x)) * inv
                    w2 = ((ax - x) * (by - y) - (ay - y) * (bx - x)) * inv
                    if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                        z = w0 * az + w1 * bz + w2 * cz
                        if z > zout[a, c]:
                            zout[a, c] = z
                            code[a, c] = tcode
        for q in range(tree_ids.shape[0]):
            m = tree_ids[q]
            ra = ta[m, 0]
            if tc[m, 1] + ra < ylo or tc[m, 1] - ra > yhi:
                continue
            cc0 = max(0, int(math.ceil((tc[m, 0] - ra - x0) / step_m - 0.5)))
            cc1 = min(ncols - 1, int(math.floor((tc[m, 0] + ra - x0) / step_m - 0.5)))
            aa0 = max(a0, int(math.ceil((ytop - tc[m, 1] - ra) / step_m - 0.5)) - r0)
            aa1 = min(a1 - 1, int(math.floor((ytop - tc[m, 1] + ra) / step_m - 0.5)) - r0)
            tcode = (numba.int64(_T_TREE) << _SHIFT) | m
            for a in range(aa0, aa1 + 1):
                y = ytop - (r0 + a + 0.5) * step_m
                for c in range(cc0, cc1 + 1):
                    x = x0 + (c + 0.5) * step_m
                    dx = (x - tc[m, 0]) / ra
                    dy = (y - tc[m, 1]) / ra
                    qq = dx * dx + dy * dy
                    if qq < 1.0:
                        z = tc[m, 2] + ta[m, 1] * math.sqrt(1.0 - qq)
                        if z > zout[a, c]:
                            zout[a, c] = z
                            code[a, c] = tcode


@numba.njit(cache=True, parallel=True)
def _ortho_shade(x0, ytop, step_m, r0, *, zin, code, hz, res, tn, tkind, tobj, tc, ta, G, roof_albedo, fine_m, sun,
                 rad, ids):
    nrows, ncols = zin.shape
    for a in numba.prange(nrows):
        y = ytop - (r0 + a + 0.5) * step_m
        X = np.empty(ncols)
        Y = np.full(ncols, y)
        Z = np.empty(ncols)
        NX = np.empty(ncols)
        NY = np.empty(ncols)
        NZ = np.empty(ncols)
        kind = np.empty(ncols, np.int64)
        obj = np.empty(ncols, np.int64)
        surfaces = (hz, res, tn, tkind, tobj, tc, ta)
        for c in range(ncols):
            x = x0 + (c + 0.5) * step_m
            z = zin[a, c]
            X[c] = x
            Z[c] = z
            cv = code[a, c]
            typ = cv >> _SHIFT
            idx = cv & _MASK
            # seen straight down: facing up (the ray's direction is (0, 0, -1))
            NX[c], NY[c], NZ[c], kind[c], obj[c] = _hit_normal(
                typ, idx, (X[c], Y[c], Z[c]), (0.0, 0.0, -1.0), (0, 0), surfaces)
            ids[a, c] = kind[c] * 1000000 + obj[c]
        shading.shade_points((X, Y, Z), kind, obj, (NX, NY, NZ), (G, roof_albedo, fine_m, sun), rad[a])


def ortho_render(look: SceneLook, x0_m: float, ytop_m: float, step_m: float, *, r0: int, r1: int, ncols: int,
                 shade: bool = True):
    """Straight-down view of rows r0..r1-1 of the grid with pixel centres (x0 + (c + 0.5) step,
    ytop - (r + 0.5) step) (local metres): surface height (rows, cols), and with ``shade`` the radiance
    (rows, cols, 3) float32 and the surface ids (kind * 1_000_000 + object)."""
    nrows = r1 - r0
    ylo = ytop_m - r1 * step_m
    yhi = ytop_m - r0 * step_m
    xhi = x0_m + ncols * step_m
    if len(look.tv):
        tri = np.flatnonzero((look.tri_hi[:, 1] >= ylo) & (look.tri_lo[:, 1] <= yhi)
                             & (look.tri_hi[:, 0] >= x0_m) & (look.tri_lo[:, 0] <= xhi)).astype(np.int64)
    else:
        tri = np.zeros(0, np.int64)
    if len(look.tc):
        ra = look.ta[:, 0]
        trees = np.flatnonzero((look.tc[:, 1] + ra >= ylo) & (look.tc[:, 1] - ra <= yhi)
                               & (look.tc[:, 0] + ra >= x0_m) & (look.tc[:, 0] - ra <= xhi)).astype(np.int64)
    else:
        trees = np.zeros(0, np.int64)
    z = np.empty((nrows, ncols))
    code = np.empty((nrows, ncols), np.int64)
    _ortho_rows(float(x0_m), float(ytop_m), float(step_m), int(r0), nrows=nrows, ncols=int(ncols), hz=look.hz,
                res=look.res, tv=look.tv, tri_ids=tri, tree_ids=trees, tc=look.tc, ta=look.ta, sub_rows=16, zout=z,
                code=code)
    if not shade:
        return z, None, None
    rad = np.empty((nrows, ncols, 3), np.float32)
    ids = np.empty((nrows, ncols), np.int64)
    _ortho_shade(float(x0_m), float(ytop_m), float(step_m), int(r0), zin=z, code=code, hz=look.hz, res=look.res,
                 tn=look.tn, tkind=look.tkind, tobj=look.tobj, tc=look.tc, ta=look.ta, G=look.G,
                 roof_albedo=look.roof_albedo, fine_m=look.fine_m, sun=look.sun, rad=rad, ids=ids)
    return z, rad, ids


_ = KIND_NONE  # re-exported kind codes live in aerotri.sim.scene


@numba.njit(cache=True, parallel=True)
def _tone8(x, lut, out):
    nlut = lut.shape[0] - 2
    for i in numba.prange(x.shape[0]):
        v = min(max(x[i], 0.0), 1.0)
        f = v * nlut
        k = int(f)
        dn = lut[k] + (lut[k + 1] - lut[k]) * (f - k)
        out[i] = int(dn + 0.5)


def tone8(radiance: np.ndarray) -> np.ndarray:
    """Radiance (any shape) to 8-bit display values through the tone curve of ``render.tone_map`` (a table:
    within 0.001 DN of it), rounded (for the true orthophoto and its NIR band)."""
    x = np.ascontiguousarray(radiance, dtype=np.float32).ravel() * np.float32(1.25)
    out = np.empty(x.shape, np.uint8)
    _tone8(x, tone_lut(), out)
    return out.reshape(np.shape(radiance))
