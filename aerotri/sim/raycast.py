"""Ray casting of the simulated scene (numba): the one geometry kernel behind images, LiDAR and truth.

Acceleration: a uniform XY grid of coarse cells (``cell_m``, a multiple of the terrain spacing)
holding the building triangles and tree crowns that overlap each cell and the highest point in it.
A ray walks the coarse cells (2D DDA, Amanatides & Woo 1987) and tests only cells where it is
below that maximum; inside such a cell it tests the terrain triangles its segment overlaps, the
building triangles (Moeller-Trumbore) and the crown spheroids of the cell.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from aerotri.sim.scene import (
    GRASS, KIND_NONE, KIND_ROOF, KIND_TERRAIN, KIND_TREE, KIND_WALL, MARKING, ROAD, SOIL, TARGET,
    TARGET_RING, WATER, Scene,
)

NO_HIT = np.inf


def build_accel(scene: Scene, cell_m: float = 4.0):
    """Pack the scene into the tuple of arrays the kernels take."""
    res = scene.terrain_res_m
    k = max(1, int(round(cell_m / res)))
    cs = k * res
    hz = np.ascontiguousarray(scene.terrain_z, dtype=np.float64)
    ny, nx = hz.shape
    ncx = int(math.ceil((nx - 1) / k))
    ncy = int(math.ceil((ny - 1) / k))
    # Highest terrain node of each coarse cell (node blocks overlap by one row/column).
    pad = np.full((ncy * k + 1, ncx * k + 1), -np.inf)
    pad[:ny, :nx] = hz
    zmax = np.full((ncy, ncx), -np.inf)
    for di in range(k + 1):
        for dj in range(k + 1):
            zmax = np.maximum(zmax, pad[di: di + ncy * k: k, dj: dj + ncx * k: k][:ncy, :ncx])
    items_cells, items_ids = [], []

    def register(ids, xmin, xmax, ymin, ymax, ztop):
        i0 = np.clip(np.floor(ymin / cs).astype(int), 0, ncy - 1)
        i1 = np.clip(np.floor(ymax / cs).astype(int), 0, ncy - 1)
        j0 = np.clip(np.floor(xmin / cs).astype(int), 0, ncx - 1)
        j1 = np.clip(np.floor(xmax / cs).astype(int), 0, ncx - 1)
        for t in range(len(ids)):
            ii, jj = np.mgrid[i0[t]: i1[t] + 1, j0[t]: j1[t] + 1]
            cells = (ii * ncx + jj).ravel()
            items_cells.append(cells)
            items_ids.append(np.full(cells.size, ids[t], dtype=np.int64))
            zr = zmax.reshape(-1)
            zr[cells] = np.maximum(zr[cells], ztop[t])

    tv = np.ascontiguousarray(scene.tri_v, dtype=np.float64)
    if len(tv):
        register(np.arange(len(tv)), tv[:, :, 0].min(1), tv[:, :, 0].max(1), tv[:, :, 1].min(1),
                 tv[:, :, 1].max(1), tv[:, :, 2].max(1))
    tc = np.ascontiguousarray(scene.tree_c, dtype=np.float64)
    ta = np.ascontiguousarray(scene.tree_ac, dtype=np.float64)
    if len(tc):
        # Trees are encoded as negative item ids: -(index + 1).
        register(-(np.arange(len(tc)) + 1), tc[:, 0] - ta[:, 0], tc[:, 0] + ta[:, 0], tc[:, 1] - ta[:, 0],
                 tc[:, 1] + ta[:, 0], tc[:, 2] + ta[:, 1])
    if items_cells:
        cells = np.concatenate(items_cells)
        ids = np.concatenate(items_ids)
        order = np.argsort(cells, kind="stable")
        cells, ids = cells[order], ids[order]
        start = np.searchsorted(cells, np.arange(ncx * ncy + 1))
    else:
        ids = np.zeros(0, np.int64)
        start = np.zeros(ncx * ncy + 1, np.int64)
    if len(tv):
        n = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    else:
        n = np.zeros((0, 3))
    zlo = float(hz.min()) - 2.0
    zhi = float(zmax.max()) + 0.5
    return (hz, float(res), int(k), float(cs), int(ncx), int(ncy), np.ascontiguousarray(zmax),
            start.astype(np.int64), ids.astype(np.int64), tv, n, scene.tri_kind.astype(np.int64),
            scene.tri_obj.astype(np.int64), tc, ta, zlo, zhi)


@numba.njit(cache=True, inline="always")
def _tri_hit(o, d, a, b, c):
    """Moeller-Trumbore: ray parameter t of the hit or inf; ray origin ``o``, direction ``d``, triangle vertices
    ``a``, ``b``, ``c``, each an (x, y, z) tuple."""
    ox, oy, oz = o
    dx, dy, dz = d
    ax, ay, az = a
    bx, by, bz = b
    cx, cy, cz = c
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if abs(det) < 1e-14:
        return np.inf
    inv = 1.0 / det
    sx, sy, sz = ox - ax, oy - ay, oz - az
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -1e-12 or u > 1.0 + 1e-12:
        return np.inf
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < -1e-12 or u + v > 1.0 + 1e-12:
        return np.inf
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if t <= 1e-9:
        return np.inf
    return t


@numba.njit(cache=True, inline="always")
def _clip_to_scene(o, d, bounds):
    """Ray interval (t0, t1) inside the scene ``bounds`` (W, H, zlo, zhi): the z slab [zlo, zhi] and the XY box
    [0, W) x [0, H); t0 >= t1: none."""
    ox, oy, oz = o
    dx, dy, dz = d
    W, H, zlo, zhi = bounds
    t0 = max(0.0, (oz - zhi) / (-dz))
    t1 = (oz - zlo) / (-dz)
    if dx != 0.0:
        ta_ = (0.0 - ox) / dx
        tb_ = (W - ox) / dx
        t0 = max(t0, min(ta_, tb_))
        t1 = min(t1, max(ta_, tb_))
    elif ox < 0.0 or ox >= W:
        return 0.0, 0.0
    if dy != 0.0:
        ta_ = (0.0 - oy) / dy
        tb_ = (H - oy) / dy
        t0 = max(t0, min(ta_, tb_))
        t1 = min(t1, max(ta_, tb_))
    elif oy < 0.0 or oy >= H:
        return 0.0, 0.0
    return t0, t1


@numba.njit(cache=True, inline="always")
def _terrain_hits(o, d, seg, cell, terrain, hit):
    """The nearest hit so far ``hit`` (t, kind, obj, nx, ny, nz) after the terrain triangles under the ray segment
    ``seg`` (tin, tout) within coarse cell ``cell`` (ci, cj); ``terrain``: the height field ``hz``, its node
    spacing ``res`` (m) and the coarse cell's size in nodes ``k``."""
    ox, oy, oz = o
    dx, dy, dz = d
    tin, tout = seg
    ci, cj = cell
    hz, res, k = terrain
    best, bkind, bobj, bnx, bny, bnz = hit
    nfx = hz.shape[1] - 1
    nfy = hz.shape[0] - 1
    xa = ox + dx * tin
    xb = ox + dx * tout
    ya = oy + dy * tin
    yb = oy + dy * tout
    j0 = max(int(math.floor(min(xa, xb) / res)) - 0, cj * k)
    j1 = min(int(math.floor(max(xa, xb) / res)), cj * k + k - 1, nfx - 1)
    i0 = max(int(math.floor(min(ya, yb) / res)) - 0, ci * k)
    i1 = min(int(math.floor(max(ya, yb) / res)), ci * k + k - 1, nfy - 1)
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            x0 = j * res
            y0 = i * res
            x1 = x0 + res
            y1 = y0 + res
            h00 = hz[i, j]
            h10 = hz[i, j + 1]
            h01 = hz[i + 1, j]
            h11 = hz[i + 1, j + 1]
            t = _tri_hit(o, d, (x0, y0, h00), (x1, y0, h10), (x1, y1, h11))
            if t < best:
                best = t
                bkind = KIND_TERRAIN
                bobj = 0
                # normal of (00,10,11): e1 = (res,0,h10-h00), e2 = (res,res,h11-h00)
                bnx = -(h10 - h00) * res
                bny = -(h11 - h10) * res
                bnz = res * res
            t = _tri_hit(o, d, (x0, y0, h00), (x1, y1, h11), (x0, y1, h01))
            if t < best:
                best = t
                bkind = KIND_TERRAIN
                bobj = 0
                bnx = -(h11 - h01) * res
                bny = -(h01 - h00) * res
                bnz = res * res
    return best, bkind, bobj, bnx, bny, bnz


@numba.njit(cache=True, inline="always")
def _item_hits(o, d, c, cells, trees, hit):
    """The nearest hit so far ``hit`` (t, kind, obj, nx, ny, nz) after the building triangles and (``trees``:
    (use_trees, skip_tree): all crowns but ``skip_tree``) the crown spheroids registered in coarse cell ``c``;
    ``cells``: the items of each cell (start, items) and the triangles' vertices, normals, kinds and objects
    (tv, tn, tkind, tobj), the crowns' centres and semi-axes (tc, ta) of ``build_accel``."""
    ox, oy, oz = o
    dx, dy, dz = d
    start, items, tv, tn, tkind, tobj, tc, ta = cells
    use_trees, skip_tree = trees
    best, bkind, bobj, bnx, bny, bnz = hit
    for q in range(start[c], start[c + 1]):
        it = items[q]
        if it >= 0:
            t = _tri_hit(o, d, (tv[it, 0, 0], tv[it, 0, 1], tv[it, 0, 2]), (tv[it, 1, 0], tv[it, 1, 1], tv[it, 1, 2]),
                         (tv[it, 2, 0], tv[it, 2, 1], tv[it, 2, 2]))
            if t < best:
                best = t
                bkind = tkind[it]
                bobj = tobj[it]
                bnx, bny, bnz = tn[it, 0], tn[it, 1], tn[it, 2]
        elif use_trees:
            m = -it - 1
            if m == skip_tree:
                continue
            a = ta[m, 0]
            cz = ta[m, 1]
            # Spheroid ((x-cx)/a)^2 + ((y-cy)/a)^2 + ((z-cz)/c)^2 = 1
            sx = (ox - tc[m, 0]) / a
            sy = (oy - tc[m, 1]) / a
            sz = (oz - tc[m, 2]) / cz
            ux = dx / a
            uy = dy / a
            uz = dz / cz
            A = ux * ux + uy * uy + uz * uz
            B = 2.0 * (sx * ux + sy * uy + sz * uz)
            C = sx * sx + sy * sy + sz * sz - 1.0
            disc = B * B - 4.0 * A * C
            if disc > 0.0:
                t = (-B - math.sqrt(disc)) / (2.0 * A)
                if 1e-9 < t < best:
                    best = t
                    bkind = KIND_TREE
                    bobj = m
                    bnx = (sx + ux * t) / a
                    bny = (sy + uy * t) / a
                    bnz = (sz + uz * t) / cz
    return best, bkind, bobj, bnx, bny, bnz


@numba.njit(cache=True)
def cast(o, d, S, use_trees, skip_tree):
    """First hit of the ray o + t d (d need not be unit; t in units of |d|).

    Returns (t, kind, obj, nx, ny, nz); kind KIND_NONE and t = inf when nothing is hit. ``skip_tree``
    ignores one crown (index) so that a LiDAR pulse can continue through it. The ray walks the coarse
    cells (2D DDA) and tests those where it is below the cell's highest point. Jitted callers pass
    ``numba.boolean(...)`` and ``numba.int64(...)``, not constants: numba compiles a callee once per literal
    constant, and each compilation of this one costs about 4 CPU-s (docs/testing.md).
    """
    (hz, res, k, cs, ncx, ncy, zmax, start, items, tv, tn, tkind, tobj, tc, ta, zlo, zhi) = S
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    best = np.inf
    bkind = KIND_NONE
    bobj = -1
    bnx, bny, bnz = 0.0, 0.0, 1.0
    if dz >= 0.0:
        return best, bkind, bobj, bnx, bny, bnz
    o3 = (ox, oy, oz)
    d3 = (dx, dy, dz)
    t0, t1 = _clip_to_scene(o3, d3, (ncx * cs, ncy * cs, zlo, zhi))
    if t0 >= t1:
        return best, bkind, bobj, bnx, bny, bnz
    # DDA set-up: the cell of the entry point, the ray parameter of the next cell boundary in x and y
    px = ox + dx * t0
    py = oy + dy * t0
    cj = min(max(int(px / cs), 0), ncx - 1)
    ci = min(max(int(py / cs), 0), ncy - 1)
    stepx = 1 if dx > 0 else -1
    stepy = 1 if dy > 0 else -1
    if dx != 0.0:
        nxb = (cj + (1 if dx > 0 else 0)) * cs
        tmx = (nxb - ox) / dx
        tdx = cs / abs(dx)
    else:
        tmx = np.inf
        tdx = np.inf
    if dy != 0.0:
        nyb = (ci + (1 if dy > 0 else 0)) * cs
        tmy = (nyb - oy) / dy
        tdy = cs / abs(dy)
    else:
        tmy = np.inf
        tdy = np.inf
    tin = t0
    while True:
        tout = min(tmx, tmy, t1)
        zin = oz + dz * tin
        zout = oz + dz * tout
        if min(zin, zout) <= zmax[ci, cj]:
            best, bkind, bobj, bnx, bny, bnz = _terrain_hits(o3, d3, (tin, tout), (ci, cj), (hz, res, k),
                                                             (best, bkind, bobj, bnx, bny, bnz))
            best, bkind, bobj, bnx, bny, bnz = _item_hits(o3, d3, ci * ncx + cj, (start, items, tv, tn, tkind, tobj, tc,
                                                                                 ta), (use_trees, skip_tree),
                                                          (best, bkind, bobj, bnx, bny, bnz))
            if best <= tout + 1e-9:
                break
        if tout >= t1:
            break
        if tmx < tmy:
            cj += stepx
            tin = tmx
            tmx += tdx
            if cj < 0 or cj >= ncx:
                break
        else:
            ci += stepy
            tin = tmy
            tmy += tdy
            if ci < 0 or ci >= ncy:
                break
    if bkind != KIND_NONE:
        nn = math.sqrt(bnx * bnx + bny * bny + bnz * bnz)
        bnx /= nn
        bny /= nn
        bnz /= nn
        if bnx * dx + bny * dy + bnz * dz > 0.0:
            bnx, bny, bnz = -bnx, -bny, -bnz
    return best, bkind, bobj, bnx, bny, bnz


# ----------------------------------------------------------------------------------------------
# Materials and shading


@numba.njit(cache=True, inline="always")
def _hash01(ix, iy, seed):
    h = (ix * 374761393 + iy * 668265263 + seed * 2246822519) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF) / 16777216.0


@numba.njit(cache=True)
def value_noise(x, y, seed):
    ix = math.floor(x)
    iy = math.floor(y)
    fx = x - ix
    fy = y - iy
    ix = int(ix)
    iy = int(iy)
    sx = fx * fx * (3.0 - 2.0 * fx)
    sy = fy * fy * (3.0 - 2.0 * fy)
    a = _hash01(ix, iy, seed)
    b = _hash01(ix + 1, iy, seed)
    c = _hash01(ix, iy + 1, seed)
    e = _hash01(ix + 1, iy + 1, seed)
    return (a + (b - a) * sx) + ((c + (e - c) * sx) - (a + (b - a) * sx)) * sy


@numba.njit(cache=True)
def fbm(x, y, seed, scale, octaves):
    """Fractal value noise in [0, 1): octaves from ``scale`` metres downwards."""
    s = 0.0
    amp = 0.5
    norm = 0.0
    f = 1.0 / scale
    for o in range(octaves):
        s += amp * value_noise(x * f, y * f, seed + 17 * o)
        norm += amp
        amp *= 0.55
        f *= 2.0
    return s / norm


@numba.njit(cache=True, inline="always")
def road_surface(lat, s, w):
    """Material of a road of width ``w`` (m) at ``lat`` (m) across its axis and ``s`` (m) along it (``|lat| <= w /
    2``): a dashed centre line (3 m on, 6 m off) and solid edge lines are MARKING, the rest ROAD."""
    if abs(lat) < 0.2 and (s % 9.0) < 3.0:
        return MARKING
    if abs(abs(lat) - (w / 2.0 - 0.6)) < 0.15:
        return MARKING
    return ROAD


@numba.njit(cache=True)
def ground_material(x, y, roads, ponds, targets, seed):
    """Material code of the ground at local (x, y)."""
    for q in range(targets.shape[0]):
        ddx = x - targets[q, 0]
        ddy = y - targets[q, 1]
        r = math.sqrt(ddx * ddx + ddy * ddy)
        if r <= targets[q, 2]:
            return TARGET
        if r <= 1.8 * targets[q, 2]:
            return TARGET_RING
    for q in range(ponds.shape[0]):
        ddx = x - ponds[q, 0]
        ddy = y - ponds[q, 1]
        ca = math.cos(ponds[q, 4])
        sa = math.sin(ponds[q, 4])
        u = (ddx * ca + ddy * sa) / ponds[q, 2]
        v = (-ddx * sa + ddy * ca) / ponds[q, 3]
        if u * u + v * v <= 1.0:
            return WATER
    for q in range(roads.shape[0]):
        x0, y0, x1, y1, w = roads[q, 0], roads[q, 1], roads[q, 2], roads[q, 3], roads[q, 4]
        ex = x1 - x0
        ey = y1 - y0
        L = math.sqrt(ex * ex + ey * ey)
        ex /= L
        ey /= L
        s = (x - x0) * ex + (y - y0) * ey
        if s < 0.0 or s > L:
            continue
        lat = -(x - x0) * ey + (y - y0) * ex
        if abs(lat) <= w / 2.0:
            return road_surface(lat, s, w)
    if fbm(x, y, seed + 5, 60.0, 2) > 0.62:
        return SOIL
    return GRASS


@numba.njit(cache=True)
def surface_albedo(x, y, z, kind, obj, materials):
    """RGB albedo (0..1) and material code at a surface point (local metres) of ``kind`` (scene KIND_*) and
    object ``obj``; ``materials``: the scene's (roads, ponds, targets, roof_albedo, seed)."""
    roads, ponds, targets, roof_albedo, seed = materials
    if kind == KIND_TERRAIN:
        m = ground_material(x, y, roads, ponds, targets, seed)
        n1 = fbm(x, y, seed + 1, 4.0, 4)
        n2 = fbm(x, y, seed + 2, 0.8, 2)
        # Small clutter (stones, bushes, manholes): square 2 m patches with their own tone.
        spot = _hash01(int(math.floor(x / 2.0)), int(math.floor(y / 2.0)), seed + 9)
        if spot > 0.9 and m != MARKING and m != TARGET and m != TARGET_RING:
            n1 = n1 * 0.5 + (spot - 0.9) * 6.0
        if m == GRASS:
            g = 0.6 + 0.8 * n1 + 0.4 * (n2 - 0.5)
            return 0.16 * g, 0.32 * g, 0.11 * g, m
        if m == SOIL:
            g = 0.65 + 0.7 * n1 + 0.4 * (n2 - 0.5)
            return 0.42 * g, 0.33 * g, 0.22 * g, m
        if m == ROAD:
            g = 0.85 + 0.3 * n1 + 0.2 * (n2 - 0.5)
            return 0.23 * g, 0.23 * g, 0.24 * g, m
        if m == MARKING:
            return 0.85, 0.85, 0.82, m
        if m == WATER:
            g = 0.9 + 0.2 * n1
            return 0.05 * g, 0.09 * g, 0.12 * g, m
        if m == TARGET:
            return 0.95, 0.95, 0.95, m
        return 0.04, 0.04, 0.04, m  # TARGET_RING
    if kind == KIND_ROOF:
        n1 = fbm(x, y, seed + 3, 3.0, 4)
        g = 0.7 + 0.6 * n1
        # Roof furniture (vents, air conditioners, skylights) on a 2.5 m grid.
        h = _hash01(int(math.floor(x / 2.5)), int(math.floor(y / 2.5)), seed + 11 + obj)
        if h > 0.9:
            g *= 0.45 if h > 0.95 else 1.5
        return roof_albedo[obj, 0] * g, roof_albedo[obj, 1] * g, roof_albedo[obj, 2] * g, -1
    if kind == KIND_WALL:
        n1 = fbm(x + z, y + z, seed + 4, 2.0, 3)
        g = 0.8 + 0.4 * n1
        return 0.55 * g, 0.53 * g, 0.5 * g, -1
    if kind == KIND_TREE:
        n1 = fbm(x + 0.7 * z, y - 0.7 * z, seed + 6 + obj % 7, 1.2, 3)
        g = 0.55 + 0.9 * n1
        return 0.07 * g, 0.17 * g, 0.06 * g, -1
    return 0.55, 0.65, 0.8, -1  # outside the scene: haze


SUN = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])


@numba.njit(cache=True, parallel=True)
def render_rays(origins, dirs, S, *, roads, ponds, targets, roof_albedo, seed, sun):
    """Radiance (N, 3) float32 and surface ids (N,) for rays; ``origins`` is (N, 3) or (1, 3).

    ids: kind * 1_000_000 + object id (building id, tree index; 0 for terrain).
    """
    n = dirs.shape[0]
    out = np.empty((n, 3), np.float32)
    ids = np.empty(n, np.int64)
    single = origins.shape[0] == 1
    for r in numba.prange(n):
        materials = (roads, ponds, targets, roof_albedo, seed)
        origin = origins[0] if single else origins[r]
        t, kind, obj, nx, ny, nz = cast(origin, dirs[r], S, numba.boolean(True), numba.int64(-1))
        if kind == KIND_NONE:
            out[r, 0], out[r, 1], out[r, 2] = 0.55, 0.65, 0.8
            ids[r] = 0
            continue
        x = origin[0] + dirs[r, 0] * t
        y = origin[1] + dirs[r, 1] * t
        z = origin[2] + dirs[r, 2] * t
        ar, ag, ab, m = surface_albedo(x, y, z, kind, obj, materials)
        lam = nx * sun[0] + ny * sun[1] + nz * sun[2]
        if lam < 0.0:
            lam = 0.0
        shade = 0.45 + 0.55 * lam
        out[r, 0] = ar * shade
        out[r, 1] = ag * shade
        out[r, 2] = ab * shade
        ids[r] = kind * 1000000 + obj
    return out, ids


@numba.njit(cache=True, parallel=True)
def cast_many(origins, dirs, S, use_trees):
    """First hits of many rays: t, kind, obj, normal z (for LiDAR and truth rasters)."""
    n = dirs.shape[0]
    t_out = np.empty(n)
    kind_out = np.empty(n, np.int64)
    obj_out = np.empty(n, np.int64)
    nz_out = np.empty(n)
    for r in numba.prange(n):
        t, kind, obj, nx, ny, nz = cast(origins[r], dirs[r], S, use_trees, numba.int64(-1))
        t_out[r] = t
        kind_out[r] = kind
        obj_out[r] = obj
        nz_out[r] = nz
    return t_out, kind_out, obj_out, nz_out


@numba.njit(cache=True, parallel=True)
def ground_materials(x, y, roads, ponds, targets, seed):
    n = x.shape[0]
    out = np.empty(n, np.int64)
    for i in numba.prange(n):
        out[i] = ground_material(x[i], y[i], roads, ponds, targets, seed)
    return out
