"""Surface appearance of the simulated scene: ground materials through a grid index, texture and shading.

The frame renderer (``aerotri.sim.raster``) and the true orthophoto shade every surface point with
``shade``; the LiDAR intensities and the land-cover truth take the ground material from
``ground_materials``.

Ground material: the one ``raycast.ground_material`` defines (painted targets, ponds, roads with their
markings, then soil or grass by a 60 m noise field), found through ``GroundIndex``: a grid of 4 m cells
listing the targets, ponds and roads that reach into each cell (in the order the reference tests them)
and the soil field interpolated on a grid of half the cell (2 m). A point is tested against its cell's
features only, and the soil field is evaluated exactly only where the interpolated value lies within
``SOIL_EPS`` of the threshold (the bilinear interpolation error of that field on 2 m cells is below
0.0034); a cell without features whose soil nodes all lie on one side of that band has one material
(``GroundIndex.plain``): the material of every point is the reference's, at a few ns instead of a loop
over every road, pond and target of the scene.

Texture: value noise (a 64-bit integer hash of the lattice corners, smoothstep interpolation) summed
over octaves that halve from each material's coarsest scale down to the scene's finest texture scale
``fine_m`` (about the GSD, so that a 0.10 m GSD block has ground texture at 0.1-0.2 m, and a coarse one
does not alias). Palette and octave weights are those of the reference shading (``raycast.surface_albedo``).
Radiance = albedo x (0.45 + 0.55 max(0, normal . sun)).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from aerotri.sim import raycast
from aerotri.sim.scene import (
    GRASS, KIND_NONE, KIND_ROOF, KIND_TERRAIN, KIND_TREE, KIND_WALL, MARKING, ROAD, SOIL, TARGET, TARGET_RING, WATER,
)

GROUND_CELL_M = 4.0
SOIL_THRESHOLD = 0.62
# The 60 m, 2-octave soil field has second derivatives below 6 sum(w_o f_o^2) = 3.4e-3 / m2, so bilinear
# interpolation on 2 m cells is within 2^2/8 x 2 x 3.4e-3 = 0.0034 of it: 0.005 leaves a margin. (On 4 m
# cells the band was 0.02 wide and a fifth of the ground points needed the exact field, 17 ns each.)
SOIL_EPS = 0.005
SOIL_SUB = 2  # soil nodes per cell side: every cell_m / SOIL_SUB
HAZE = (0.55, 0.65, 0.8)  # radiance of a ray that leaves the scene
SUN = raycast.SUN
_FEATURE_SHIFT = 32  # feature code = type << 32 | index; types in the reference's test order
_TARGETS, _PONDS, _ROADS = 0, 1, 2


class GroundIndex(NamedTuple):
    """The grid index of the ground features (numba-ready)."""

    cell_m: float
    nx: int
    ny: int
    start: np.ndarray  # (nx * ny + 1,) int64: features of cell i * nx + j at codes[start[c]:start[c + 1]]
    codes: np.ndarray  # int64 feature codes, type-major in the reference's order
    soil: np.ndarray  # (SOIL_SUB ny + 1, SOIL_SUB nx + 1) float32: the soil field at (j, i) * cell_m / SOIL_SUB
    roads: np.ndarray
    ponds: np.ndarray
    targets: np.ndarray
    seed: int
    road_axes: np.ndarray  # (R, 3): the unit direction (ex, ey) and length L of each road, as the reference computes them
    pond_axes: np.ndarray  # (P, 2): cos and sin of each pond's angle
    plain: np.ndarray  # (nx * ny,) int8: the material of every point of a cell without features whose soil nodes
    # all lie on one side of the threshold band (SOIL or GRASS), else -1


def build_ground_index(scene, cell_m: float = GROUND_CELL_M) -> GroundIndex:
    """The ``GroundIndex`` of a scene: cells from the local origin over the scene and every feature (the
    simulator places them all inside the scene)."""
    x_hi, y_hi = scene.width_m, scene.height_m
    lo = []
    for x, y, r in scene.targets:
        lo.append((x - 1.8 * r, y - 1.8 * r))
        x_hi, y_hi = max(x_hi, x + 1.8 * r), max(y_hi, y + 1.8 * r)
    for cx, cy, a, b, _, _ in scene.ponds:
        lo.append((cx - max(a, b), cy - max(a, b)))
        x_hi, y_hi = max(x_hi, cx + max(a, b)), max(y_hi, cy + max(a, b))
    for x0, y0, x1, y1, w in scene.roads:
        lo.append((min(x0, x1) - w, min(y0, y1) - w))
        x_hi, y_hi = max(x_hi, x0 + w, x1 + w), max(y_hi, y0 + w, y1 + w)
    if lo and min(min(p) for p in lo) < 0.0:
        raise ValueError("a ground feature reaches west or south of the scene origin")
    nx = max(1, int(math.ceil(x_hi / cell_m)) + 1)
    ny = max(1, int(math.ceil(y_hi / cell_m)) + 1)
    cells, codes = [], []

    def add(kind, k, cols, rows, keep=None):
        # cols, rows: the (first, last) cell columns and rows of the feature's box
        j0, j1 = max(cols[0], 0), min(cols[1], nx - 1)
        i0, i1 = max(rows[0], 0), min(rows[1], ny - 1)
        if j0 > j1 or i0 > i1:
            return
        ii, jj = np.mgrid[i0: i1 + 1, j0: j1 + 1]
        if keep is not None:
            m = keep(ii, jj)
            ii, jj = ii[m], jj[m]
        c = (ii * nx + jj).ravel()
        cells.append(c)
        codes.append(np.full(c.size, (kind << _FEATURE_SHIFT) | k, np.int64))

    def span(lo, hi):
        return int(math.floor(lo / cell_m)), int(math.floor(hi / cell_m))

    for k, (x, y, r) in enumerate(scene.targets):
        reach = 1.8 * r + 1e-6
        add(_TARGETS, k, span(x - reach, x + reach), span(y - reach, y + reach))
    for k, (cx, cy, a, b, ang, _) in enumerate(scene.ponds):
        hx = math.hypot(a * math.cos(ang), b * math.sin(ang)) + 1e-6
        hy = math.hypot(a * math.sin(ang), b * math.cos(ang)) + 1e-6
        add(_PONDS, k, span(cx - hx, cx + hx), span(cy - hy, cy + hy))
    half_diag = cell_m / math.sqrt(2.0)
    for k, (x0, y0, x1, y1, w) in enumerate(scene.roads):
        ex, ey = x1 - x0, y1 - y0
        L = math.hypot(ex, ey)
        ux, uy = ex / L, ey / L
        reach = w / 2.0 + half_diag + 1e-6

        def near(ii, jj, *, x0=x0, y0=y0, ux=ux, uy=uy, L=L, reach=reach):
            # cell centres within reach of the road's rectangle (segment +- w/2, flat ends)
            px, py = (jj + 0.5) * cell_m - x0, (ii + 0.5) * cell_m - y0
            s = np.clip(px * ux + py * uy, 0.0, L)
            return np.hypot(px - s * ux, py - s * uy) <= reach

        add(_ROADS, k, span(min(x0, x1) - reach, max(x0, x1) + reach), span(min(y0, y1) - reach, max(y0, y1) + reach),
            keep=near)
    if cells:
        c = np.concatenate(cells)
        q = np.concatenate(codes)
        order = np.argsort(c, kind="stable")  # within a cell: the order added (targets, ponds, roads by index)
        c, q = c[order], q[order]
        start = np.searchsorted(c, np.arange(nx * ny + 1)).astype(np.int64)
    else:
        q = np.zeros(0, np.int64)
        start = np.zeros(nx * ny + 1, np.int64)
    soil = _soil_nodes(SOIL_SUB * nx + 1, SOIL_SUB * ny + 1, cell_m / SOIL_SUB, int(scene.seed))
    roads = np.ascontiguousarray(scene.roads, dtype=np.float64).reshape(-1, 5)
    ponds = np.ascontiguousarray(scene.ponds, dtype=np.float64).reshape(-1, 6)
    road_axes, pond_axes = _feature_axes(roads, ponds)
    return GroundIndex(float(cell_m), nx, ny, start, q, soil, roads, ponds,
                       np.ascontiguousarray(scene.targets, dtype=np.float64).reshape(-1, 3), int(scene.seed),
                       road_axes, pond_axes, _plain_cells(start, soil))


def _plain_cells(start, soil):
    """``GroundIndex.plain``: an interpolated soil value lies between the least and the greatest of its four nodes
    (each rounded step of ``ground_material``'s interpolation is monotone and exact at u, v = 0, 1), so where
    all nodes of a cell are beyond the same side of the band its material is decided without interpolating."""
    k = SOIL_SUB
    ny, nx = (soil.shape[0] - 1) // k, (soil.shape[1] - 1) // k
    S = soil.astype(np.float64)
    lo = np.full((ny, nx), np.inf)
    hi = np.full((ny, nx), -np.inf)
    for a in range(k + 1):
        for b in range(k + 1):
            node = S[a: a + k * ny: k, b: b + k * nx: k]
            lo = np.minimum(lo, node)
            hi = np.maximum(hi, node)
    lo, hi = lo.ravel(), hi.ravel()
    plain = np.full(lo.size, -1, np.int8)
    plain[lo > SOIL_THRESHOLD + SOIL_EPS] = SOIL
    plain[hi < SOIL_THRESHOLD - SOIL_EPS] = GRASS
    plain[np.diff(start) > 0] = -1
    return plain


def ground_index(scene) -> GroundIndex:
    """The scene's ``GroundIndex``, built on first use and kept on the scene object."""
    G = getattr(scene, "_ground_index", None)
    if G is None:
        G = build_ground_index(scene)
        scene._ground_index = G
    return G


@numba.njit(cache=True)
def _feature_axes(roads, ponds):
    """Each road's unit direction and length, each pond's cos and sin, by the reference's expressions in
    compiled code (the same bits as it computes per point)."""
    ra = np.empty((roads.shape[0], 3))
    for q in range(roads.shape[0]):
        ex = roads[q, 2] - roads[q, 0]
        ey = roads[q, 3] - roads[q, 1]
        L = math.sqrt(ex * ex + ey * ey)
        ex /= L
        ey /= L
        ra[q, 0] = ex
        ra[q, 1] = ey
        ra[q, 2] = L
    pa = np.empty((ponds.shape[0], 2))
    for q in range(ponds.shape[0]):
        pa[q, 0] = math.cos(ponds[q, 4])
        pa[q, 1] = math.sin(ponds[q, 4])
    return ra, pa


@numba.njit(cache=True, parallel=True)
def _soil_nodes(nx, ny, cell_m, seed):
    out = np.empty((ny, nx), np.float32)
    for i in numba.prange(ny):
        for j in range(nx):
            out[i, j] = raycast.fbm(j * cell_m, i * cell_m, seed + 5, 60.0, 2)
    return out


@numba.njit(cache=True, inline="always")
def ground_material(x, y, G):
    """Material code of the ground at local (x, y): ``raycast.ground_material``'s, through the grid index."""
    cell = G.cell_m
    fx = x / cell
    fy = y / cell
    if not (fx >= 0.0 and fy >= 0.0 and fx < G.nx and fy < G.ny):
        # no target, pond or road reaches outside the grid (build_ground_index): the soil field decides
        return SOIL if raycast.fbm(x, y, G.seed + 5, 60.0, 2) > SOIL_THRESHOLD else GRASS
    j = int(fx)
    i = int(fy)
    c = i * G.nx + j
    plain = G.plain[c]
    if plain >= 0:
        return numba.int64(plain)
    targets = G.targets
    ponds = G.ponds
    roads = G.roads
    for p in range(G.start[c], G.start[c + 1]):
        code = G.codes[p]
        kind = code >> _FEATURE_SHIFT
        q = code & 0xFFFFFFFF
        # The tests below are the reference's, expression for expression (same decisions to the last bit).
        if kind == _TARGETS:
            ddx = x - targets[q, 0]
            ddy = y - targets[q, 1]
            r = math.sqrt(ddx * ddx + ddy * ddy)
            if r <= targets[q, 2]:
                return TARGET
            if r <= 1.8 * targets[q, 2]:
                return TARGET_RING
        elif kind == _PONDS:
            ddx = x - ponds[q, 0]
            ddy = y - ponds[q, 1]
            ca = G.pond_axes[q, 0]
            sa = G.pond_axes[q, 1]
            u = (ddx * ca + ddy * sa) / ponds[q, 2]
            v = (-ddx * sa + ddy * ca) / ponds[q, 3]
            if u * u + v * v <= 1.0:
                return WATER
        else:
            x0, y0, w = roads[q, 0], roads[q, 1], roads[q, 4]
            ex = G.road_axes[q, 0]
            ey = G.road_axes[q, 1]
            L = G.road_axes[q, 2]
            s = (x - x0) * ex + (y - y0) * ey
            if s < 0.0 or s > L:
                continue
            lat = -(x - x0) * ey + (y - y0) * ex
            if abs(lat) <= w / 2.0:
                return raycast.road_surface(lat, s, w)
    # the soil node grid: SOIL_SUB x the cell coordinates (a power of two: the same bits as x / (cell / SOIL_SUB))
    sx = fx * SOIL_SUB
    sy = fy * SOIL_SUB
    j = int(sx)
    i = int(sy)
    u = sx - j
    v = sy - i
    S = G.soil
    a = S[i, j] + (S[i, j + 1] - S[i, j]) * u
    b = S[i + 1, j] + (S[i + 1, j + 1] - S[i + 1, j]) * u
    s = a + (b - a) * v
    if s > SOIL_THRESHOLD + SOIL_EPS:
        return SOIL
    if s < SOIL_THRESHOLD - SOIL_EPS:
        return GRASS
    return SOIL if raycast.fbm(x, y, G.seed + 5, 60.0, 2) > SOIL_THRESHOLD else GRASS


@numba.njit(cache=True, parallel=True)
def ground_materials(x, y, G):
    """``ground_material`` of many points (1-D arrays)."""
    n = x.shape[0]
    out = np.empty(n, np.int64)
    for i in numba.prange(n):
        out[i] = ground_material(x[i], y[i], G)
    return out


# ----------------------------------------------------------------------------------------------
# Texture and shading, a row of surface points at a time


@numba.njit(cache=True, inline="always", fastmath=True)
def _h32(h):
    """A 32-bit integer hash (two multiply-xorshift rounds; numba widens integer arithmetic, so every step
    is cut back to 32 bits) as a float in [0, 2^24)."""
    h = numba.uint32(h ^ (h >> numba.uint32(16)))
    h = numba.uint32(h * numba.uint32(0x7FEB352D))
    h = numba.uint32(h ^ (h >> numba.uint32(15)))
    h = numba.uint32(h * numba.uint32(0x846CA68B))
    h = numba.uint32(h ^ (h >> numba.uint32(16)))
    return numba.float32(h >> numba.uint32(8))


@numba.njit(cache=True, inline="always", fastmath=True)
def value_noise(x, y, seed):
    """Value noise in [0, 1) with unit lattice spacing at float32 (x, y) (> -65536): smoothstep interpolation
    of hashed lattice values. Float32 and 32-bit integers so that loops over many points vectorise."""
    xo = x + numba.float32(65536.0)
    yo = y + numba.float32(65536.0)
    ix = numba.int32(xo)
    iy = numba.int32(yo)
    fx = xo - numba.float32(ix)
    fy = yo - numba.float32(iy)
    h = numba.uint32(numba.uint32(ix) * numba.uint32(0x9E3779B9) + numba.uint32(iy) * numba.uint32(0x85EBCA6B) + seed)
    sx = fx * fx * (numba.float32(3.0) - numba.float32(2.0) * fx)
    sy = fy * fy * (numba.float32(3.0) - numba.float32(2.0) * fy)
    a = _h32(h)
    b = _h32(numba.uint32(h + numba.uint32(0x9E3779B9)))
    c = _h32(numba.uint32(h + numba.uint32(0x85EBCA6B)))
    e = _h32(numba.uint32(h + numba.uint32(0x9E3779B9) + numba.uint32(0x85EBCA6B)))
    ab = a + (b - a) * sx
    return (ab + (c + (e - c) * sx - ab) * sy) * numba.float32(1.0 / 16777216.0)


@numba.njit(cache=True, inline="always")
def _cell_hash(x, y, size_m, seed):
    """A uniform [0, 1) value per ``size_m`` square."""
    ix = numba.int64(math.floor(x / size_m))
    iy = numba.int64(math.floor(y / size_m))
    return _h32(numba.uint32((ix * 0x9E3779B9 + iy * 0x85EBCA6B + seed) & 0xFFFFFFFF)) * (1.0 / 16777216.0)


MAX_OCTAVES = 8
# The amplitude falls by 0.55 an octave over the first four octaves (each surface's look at the demo's GSD)
# and stays at that level below: a finer GSD sees texture of the same contrast at its own pixel scale
# (grass, gravel, roofing at 0.1-0.2 m), as real ground has, not a fading copy of the coarse texture.
DECAY_OCTAVES = 3


def _weight_sums():
    """The sum of the octaves' weights of 0..MAX_OCTAVES octaves, added in the octaves' order in float64 as the
    per-point sum of ``shade_into`` was (the same bits): the texture's normalisation, out of the points' loop."""
    sums = [0.0]
    a = 0.5
    for o in range(MAX_OCTAVES):
        sums.append(sums[-1] + a)
        if o < DECAY_OCTAVES:
            a *= 0.55
    return np.array(sums)


_WEIGHT_SUMS = _weight_sums()  # a global array: a constant of the compiled code
# coarsest lattice spacing of each surface's texture (m): ground, roof, wall, crown
SCALE_GROUND_M, SCALE_ROOF_M, SCALE_WALL_M, SCALE_CROWN_M = 4.0, 3.0, 2.0, 1.2


@numba.njit(cache=True, inline="always")
def n_octaves(scale_m, fine_m):
    """Octaves of lattice spacing scale, scale/2, ... kept while at least 0.9 ``fine_m`` (at least one)."""
    n = 1
    s = scale_m * 0.5
    while n < MAX_OCTAVES and s >= 0.9 * fine_m:
        n += 1
        s *= 0.5
    return n


@numba.njit(cache=True, fastmath=True)
def _octave(acc, texture, o, amp, fo, n):
    """acc += amp x value noise of octave ``o`` (frequency f0 x fo, seed sd + 17 o) where o < noct, per point
    0..n-1 of ``texture`` (tu, tv, f0, sd, noct): texture coordinates, coarsest frequency, seed, octaves."""
    tu, tv, f0, sd, noct = texture
    ds = numba.uint32(17 * o)
    for p in range(n):
        w = amp if o < noct[p] else numba.float32(0.0)
        acc[p] += w * value_noise(tu[p] * f0[p] * fo, tv[p] * f0[p] * fo, numba.uint32(sd[p] + ds))


def shade_scratch(n):
    """Work arrays of ``shade_into`` for up to ``n`` points (numba and Python)."""
    return (np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.uint32),
            np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32),
            np.empty(n, np.float32))


shade_scratch_nb = numba.njit(cache=True)(shade_scratch)


@numba.njit(cache=True)
def shade_points(points, kind, obj, normals, look, rad):
    """``shade_into`` all points, with work arrays of its own."""
    n = points[0].shape[0]
    shade_into(points, (kind, obj), normals, look, (rad, n), shade_scratch_nb(n))


@numba.njit(cache=True)
def shade_into(points, surface, normals, look, out, scratch):
    """Radiance (R, G, B) into ``rad`` (n, 3) of the first ``n`` surface ``points`` (X, Y, Z) (local metres)
    (``out``: (rad, n)) of ``surface`` (kind, obj): scene KIND_* (KIND_NONE: haze) and object, with unit ``normals``
    (NX, NY, NZ) facing the viewer; ``look``: the scene's ``GroundIndex`` ``G`` and ``roof_albedo``, the finest texture scale ``fine_m``
    and the unit vector towards the ``sun`` (G, roof_albedo, fine_m, sun); ``scratch``: work arrays of at least
    ``n`` (``shade_scratch``), so that a renderer shading a row at a time allocates nothing per row.

    Albedo x (0.45 + 0.55 max(0, normal . sun)). Texture: fractal value noise, octaves from the surface's
    coarsest spacing (ground 4 m, roof 3 m, wall 2 m, crown 1.2 m) halving down to 0.9 ``fine_m``,
    amplitude x 0.55 per octave over the first four (``DECAY_OCTAVES``); ground markings and targets are
    plain.
    """
    X, Y, Z = points
    kind, obj = surface
    NX, NY, NZ = normals
    G, roof_albedo, fine_m, sun = look
    rad, n = out
    tu, tv, f0, sd, noct, mat, spot, lam, acc = scratch
    for p in range(n):
        noct[p] = 0
        spot[p] = 0.0
        acc[p] = 0.0
    seed = G.seed
    no = (n_octaves(SCALE_GROUND_M, fine_m), n_octaves(SCALE_ROOF_M, fine_m), n_octaves(SCALE_WALL_M, fine_m),
          n_octaves(SCALE_CROWN_M, fine_m))
    max_oct = 0
    for p in range(n):
        k = kind[p]
        x = X[p]
        y = Y[p]
        z = Z[p]
        d = NX[p] * sun[0] + NY[p] * sun[1] + NZ[p] * sun[2]
        lam[p] = 0.45 + 0.55 * max(d, 0.0)
        mat[p] = -1
        if k == KIND_TERRAIN:
            m = ground_material(x, y, G)
            mat[p] = m
            if m == MARKING or m == TARGET or m == TARGET_RING:
                continue
            tu[p] = x
            tv[p] = y
            f0[p] = 1.0 / SCALE_GROUND_M
            sd[p] = numba.uint32((seed + 1) & 0xFFFFFFFF)
            noct[p] = no[0]
            spot[p] = _cell_hash(x, y, 2.0, seed + 9)
        elif k == KIND_ROOF:
            tu[p] = x
            tv[p] = y
            f0[p] = 1.0 / SCALE_ROOF_M
            sd[p] = numba.uint32((seed + 3) & 0xFFFFFFFF)
            noct[p] = no[1]
            spot[p] = _cell_hash(x, y, 2.5, seed + 11 + obj[p])
        elif k == KIND_WALL:
            tu[p] = x + z
            tv[p] = y + z
            f0[p] = 1.0 / SCALE_WALL_M
            sd[p] = numba.uint32((seed + 4) & 0xFFFFFFFF)
            noct[p] = no[2]
        elif k == KIND_TREE:
            tu[p] = x + 0.7 * z
            tv[p] = y - 0.7 * z
            f0[p] = 1.0 / SCALE_CROWN_M
            sd[p] = numba.uint32((seed + 6 + obj[p] % 7) & 0xFFFFFFFF)
            noct[p] = no[3]
        else:
            continue
        max_oct = max(max_oct, noct[p])
    for p in range(n):
        if noct[p] == 0:
            tu[p] = 0.0
            tv[p] = 0.0
            f0[p] = 0.0
            sd[p] = 0
    # the octaves, one vectorised sweep each
    texture = (tu, tv, f0, sd, noct)
    amp = numba.float32(0.5)
    fo = numba.float32(1.0)
    for o in range(max_oct):
        _octave(acc, texture, o, amp, fo, n)
        if o < DECAY_OCTAVES:
            amp *= numba.float32(0.55)
        fo *= numba.float32(2.0)
    for p in range(n):
        k = kind[p]
        if k == KIND_NONE:
            rad[p, 0] = HAZE[0]
            rad[p, 1] = HAZE[1]
            rad[p, 2] = HAZE[2]
            continue
        norm = _WEIGHT_SUMS[noct[p]]
        t = acc[p] / norm if norm > 0.0 else 0.5
        L = lam[p]
        if k == KIND_TERRAIN:
            m = mat[p]
            if m == MARKING:
                r, g, b = 0.85, 0.85, 0.82
            elif m == TARGET:
                r, g, b = 0.95, 0.95, 0.95
            elif m == TARGET_RING:
                r, g, b = 0.04, 0.04, 0.04
            else:
                # Small clutter (stones, bushes, manholes): square 2 m patches with their own tone.
                if spot[p] > 0.9:
                    t = t * 0.5 + (spot[p] - 0.9) * 6.0
                if m == GRASS:
                    f = 1.0 + 1.0 * (t - 0.5)
                    r, g, b = 0.16 * f, 0.32 * f, 0.11 * f
                elif m == SOIL:
                    f = 1.0 + 0.9 * (t - 0.5)
                    r, g, b = 0.42 * f, 0.33 * f, 0.22 * f
                elif m == ROAD:
                    f = 1.0 + 0.36 * (t - 0.5)
                    r, g, b = 0.23 * f, 0.23 * f, 0.24 * f
                else:  # WATER
                    f = 1.0 + 0.2 * (t - 0.5)
                    r, g, b = 0.05 * f, 0.09 * f, 0.12 * f
        elif k == KIND_ROOF:
            f = 0.7 + 0.6 * t
            # Roof furniture (vents, air conditioners, skylights) on a 2.5 m grid.
            if spot[p] > 0.9:
                f *= 0.45 if spot[p] > 0.95 else 1.5
            q = obj[p]
            r, g, b = roof_albedo[q, 0] * f, roof_albedo[q, 1] * f, roof_albedo[q, 2] * f
        elif k == KIND_WALL:
            f = 0.8 + 0.4 * t
            r, g, b = 0.55 * f, 0.53 * f, 0.5 * f
        else:  # KIND_TREE
            f = 0.55 + 0.9 * t
            r, g, b = 0.07 * f, 0.17 * f, 0.06 * f
        rad[p, 0] = r * L
        rad[p, 1] = g * L
        rad[p, 2] = b * L

