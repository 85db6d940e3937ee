"""Noise detection: isolated points, low outliers, high outliers.

Methods
-------
* Isolated points: a point whose cube of edge ``3 x voxel_m`` centred on it holds fewer than
  ``min_neighbours`` other points is isolated (birds, dust, sensor blunders).
* Low outliers (multipath under water, reflections "below ground"): a *gap* test, not a
  "below the local median" test, so that sparse true ground under canopy survives.  A point p is
  supported when some other point q within ``radius_m`` horizontally lies not more than
  ``gap_m + slope * d_pq`` above p (or anywhere below it).  True ground under trees has other
  ground points at about its height nearby; a low outlier has nothing near its height and only
  points far above it.
* Low outlier clusters (a patch of multipath points that support each other): cell minima are
  linked into terrain-connected components (neighbours within ``2.5 cells`` whose heights differ by
  at most ``gap_m + slope * d``); a small component (at most ``cluster_max_cells``) whose every
  non-linked neighbour lies higher is a low cluster, and its points near the cluster height are low
  outliers. Clouds of multipath points at mixed depths (under a pond: outliers below outliers)
  never link into a coherent surface: scraps of at most 40 m^2 lying below the terrain surface
  interpolated from the large components, with no coherent terrain at their height within 50 m,
  are low clusters too. Later passes peel the next layer around what the previous pass flagged.
* High outliers: the mirrored test, with a larger gap (``high_gap_m``).
* High outlier clusters (birds, low clouds, smoke: a few returns that support each other in the gap
  test): in the window of 3 x 3 cells of ``high_cluster_radius_m`` around a cell, the heights sorted
  from the top; at most ``high_cluster_max_points`` returns standing more than ``high_cluster_gap_m``
  above the next return below them in that window are noise. The gap is larger than a canopy's layers
  (a crown base is rarely more than ~40 m up, and a crown holds more returns), and any real structure
  that high (mast, chimney, pylon, bridge) returns points down its height within the window.

Only the few lowest/highest points of each grid cell can fail the gap test, so only those are
tested (numba loop over sorted cells, early exit on the z order).
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
from scipy.spatial import cKDTree

from aerotri.core.settings import setting
from lidarctl import grid

ISOLATED, LOW, HIGH = 1, 2, 3


@dataclasses.dataclass(frozen=True)
class NoiseSettings:
    """Noise removal (``[classify.noise]``): isolated points, low and high outliers, low clusters."""

    voxel_m: float = setting(0.0, min=0.0, help="Voxel of the isolation test (m): its cube is 3 voxels wide, centred on "
                                                "the point; 0: 2.5 x the mean point spacing, at least 2 m.")
    min_neighbours: int = setting(1, min=0, help="A point with fewer other points within 1.5 voxel_m on every axis is "
                                                  "isolated.")
    radius_m: float = setting(0.0, min=0.0, help="Search radius of the low and high outlier tests (m); 0: max(5 m, 5 x "
                                                 "the mean point spacing).")
    gap_m: float = setting(1.0, min=0.0, help="A low point needs another point within radius_m at most this (plus "
                                              "slope x distance) above it (m).")
    slope: float = setting(0.4, min=0.0, help="Terrain slope tolerated between neighbours (tan; 0.4 is about 22 deg).")
    high_gap_m: float = setting(10.0, min=0.0, help="The high outlier test's gap (m).")
    candidates_per_cell: int = setting(3, min=1, help="Lowest (highest) points per cell tested as outliers.")
    cluster_cell_m: float = setting(0.0, min=0.0, help="Cell of the low cluster test (m); 0: max(2 m, 2 x the mean "
                                                       "point spacing).")
    cluster_max_cells: int = setting(400, min=1, help="Low clusters of at most this many cells are noise.")
    cluster_passes: int = setting(3, min=0, help="Passes of the low cluster test.")
    high_cluster_gap_m: float = setting(50.0, min=0.0, help="High clusters: a small group of returns standing more than "
                                                            "this above every other return within the window (m); 0: "
                                                            "no high cluster test.")
    high_cluster_max_points: int = setting(20, min=1, help="High clusters of at most this many returns in the window "
                                                           "(3 x 3 cells of high_cluster_radius_m) are noise.")
    high_cluster_radius_m: float = setting(0.0, min=0.0, help="Cell of the high cluster test's 3 x 3 window (m); 0: "
                                                              "2 x radius_m.")


# Half-edge of the isolation cube in voxels (1.5: the volume of the 3 x 3 x 3 voxels it replaced).
CUBE_HALF_EDGE_VOXELS = 1.5


def isolated_points(x, y, z, voxel_m: float, min_neighbours: int = 1) -> np.ndarray:
    """Boolean mask: fewer than ``min_neighbours`` other points in the cube of edge ``3 * voxel_m``
    centred on the point (|dx|, |dy|, |dz| <= 1.5 voxel_m; the volume of 3 x 3 x 3 voxels).

    The cube moves with the point, not with a voxel lattice: a point's verdict does not depend on where
    the lattice starts, so one stray point far below the scene (which moved a lattice anchored at the
    data's minimum) or a tile boundary changes no other point's verdict.
    """
    x, y, z = (np.asarray(a, float) for a in (x, y, z))
    isolated = np.zeros(len(x), bool)
    if min_neighbours <= 0 or len(x) == 0:
        return isolated
    # Voxels of edge voxel_m on the global lattice: the points sharing a voxel are within voxel_m of each
    # other on every axis, inside each other's cube, so only points of voxels holding at most
    # min_neighbours points can be isolated (CUBE_HALF_EDGE_VOXELS >= 1); their cubes reach two voxels away.
    v = [np.floor(a / voxel_m).astype(np.int64) for a in (x, y, z)]
    lo = [a.min() - 3 for a in v]
    size = [int(a.max() - b) + 4 for a, b in zip(v, lo)]
    key = ((v[0] - lo[0]) * size[1] + (v[1] - lo[1])) * size[2] + (v[2] - lo[2])
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    first = np.flatnonzero(np.r_[True, sorted_key[1:] != sorted_key[:-1]])
    voxel_start = np.r_[first, len(key)]
    counts = np.diff(voxel_start)
    sparse_voxel = counts <= min_neighbours
    if not sparse_voxel.any():
        return isolated
    candidate = order[np.repeat(sparse_voxel, counts)]
    reach = int(np.floor(CUBE_HALF_EDGE_VOXELS)) + 1   # one more where a division rounds up
    steps = np.arange(-reach, reach + 1)
    offsets = ((steps[:, None, None] * size[1] + steps[None, :, None]) * size[2] + steps[None, None, :]).ravel()
    isolated[candidate] = _fewer_in_cube((x, y, z), candidate, key, (order, sorted_key[first], voxel_start),
                                         offsets, CUBE_HALF_EDGE_VOXELS * voxel_m, min_neighbours)
    return isolated


@numba.njit(cache=True, parallel=True)
def _fewer_in_cube(xyz, candidate, key, voxels, offsets, half_edge_m, min_neighbours):
    """For each candidate: fewer than ``min_neighbours`` other points within ``half_edge_m`` on every axis.
    ``voxels``: the points in key order, each occupied voxel's key and first position (sorted)."""
    x, y, z = xyz
    order, voxel_key, voxel_start = voxels
    out = np.empty(len(candidate), np.bool_)
    for c in numba.prange(len(candidate)):
        p = candidate[c]
        found = 0
        for o in offsets:
            if found >= min_neighbours:
                break
            v = np.searchsorted(voxel_key, key[p] + o)
            if v >= len(voxel_key) or voxel_key[v] != key[p] + o:
                continue
            for t in range(voxel_start[v], voxel_start[v + 1]):
                q = order[t]
                if (q != p and abs(x[q] - x[p]) <= half_edge_m and abs(y[q] - y[p]) <= half_edge_m
                        and abs(z[q] - z[p]) <= half_edge_m):
                    found += 1
                    if found >= min_neighbours:
                        break
        out[c] = found < min_neighbours
    return out


@numba.njit(cache=True)
def _k_lowest_in_cells(order, cell_start, key, k):
    """Positions (into ``order``) of the k smallest ``key`` values of every cell (k passes per cell)."""
    out = np.empty(len(order), np.int64)
    m = 0
    for c in range(len(cell_start) - 1):
        a, b = cell_start[c], cell_start[c + 1]
        if b - a <= k:
            for t in range(a, b):
                out[m] = t
                m += 1
            continue
        last = -np.inf
        last_pos = -1
        for _ in range(k):
            best, best_pos = np.inf, -1
            for t in range(a, b):
                v = key[order[t]]
                if (v > last or (v == last and t > last_pos)) and v < best:
                    best, best_pos = v, t
            out[m] = best_pos
            m += 1
            last, last_pos = best, best_pos
    return out[:m]


@numba.njit(cache=True, parallel=True)
def _gap_test(pts, cells, cand, rule):
    """True for candidates (positions into ``order``) without a supporter: some other point q
    within ``radius_m`` with key_q - key_p <= gap_m + slope * d_pq (key = z, or -z for high).
    ``pts``: (px, py, key); ``cells``: the points in cell order, each cell's first, each point's cell and the
    grid's size (order, cell_start, cell_of, nrows, ncols); ``rule``: (radius_m, gap_m, slope)."""
    px, py, key = pts
    order, cell_start, cell_of, nrows, ncols = cells
    radius_m, gap_m, slope = rule
    out = np.zeros(len(cand), np.bool_)
    r2 = radius_m * radius_m
    for c in numba.prange(len(cand)):
        p = order[cand[c]]
        cp = cell_of[p]
        ci = cp // ncols
        cj = cp - ci * ncols
        kp = key[p]
        supported = False
        for di in range(-1, 2):
            ii = ci + di
            if supported or ii < 0 or ii >= nrows:
                continue
            for dj in range(-1, 2):
                jj = cj + dj
                if supported or jj < 0 or jj >= ncols:
                    continue
                cc = ii * ncols + jj
                for t in range(cell_start[cc], cell_start[cc + 1]):
                    q = order[t]
                    dk = key[q] - kp
                    if q == p or dk > gap_m + slope * radius_m:
                        continue
                    dx = px[q] - px[p]
                    dy = py[q] - py[p]
                    d2 = dx * dx + dy * dy
                    if d2 <= r2 and dk <= gap_m + slope * np.sqrt(d2):
                        supported = True
                        break
        out[c] = not supported
    return out


def _gap_outliers(x, y, z, radius_m, gap_m, slope, *, per_cell, sign):
    cell, nrows, ncols, _, _ = grid.cell_ids(x, y, radius_m)
    order, cell_start = grid._counting_sort(cell, nrows * ncols)
    key = sign * np.asarray(z, float)
    cand = _k_lowest_in_cells(order, cell_start, key, per_cell)
    flags = _gap_test((np.asarray(x, float), np.asarray(y, float), key), (order, cell_start, cell, nrows, ncols),
                      cand, (float(radius_m), float(gap_m), float(slope)))
    mask = np.zeros(len(x), bool)
    mask[order[cand[flags]]] = True
    return mask


def low_outliers(x, y, z, radius_m: float, gap_m: float = 1.0, slope: float = 1.2,
                 *, candidates_per_cell: int = 3) -> np.ndarray:
    """Boolean mask of points with no other point near their height within ``radius_m``, only points above."""
    return _gap_outliers(x, y, z, radius_m, gap_m, slope, per_cell=candidates_per_cell, sign=+1.0)


def high_outliers(x, y, z, radius_m: float, gap_m: float = 10.0, slope: float = 1.2,
                  *, candidates_per_cell: int = 3) -> np.ndarray:
    """Boolean mask of points with nothing within ``gap_m + slope*d`` below them (mirror of low test)."""
    return _gap_outliers(x, y, z, radius_m, gap_m, slope, per_cell=candidates_per_cell, sign=-1.0)


@numba.njit(cache=True)
def _high_cluster_floor(zs, cell_start, occupied, nrows, ncols, gap_m, max_points):
    """Per occupied cell: the lowest height of a group of at most ``max_points`` returns standing more than
    ``gap_m`` above every other return of the cell's 3 x 3 window (inf: none). ``zs``: heights in cell order,
    each cell's returns from the highest down."""
    out = np.full(len(occupied), np.inf)
    top = np.empty(9 * (max_points + 1))
    for k in range(len(occupied)):
        c = occupied[k]
        ci = c // ncols
        cj = c - ci * ncols
        m = 0
        for di in range(-1, 2):
            ii = ci + di
            if ii < 0 or ii >= nrows:
                continue
            for dj in range(-1, 2):
                jj = cj + dj
                if jj < 0 or jj >= ncols:
                    continue
                cc = ii * ncols + jj
                # a cell's highest max_points + 1 returns: the window's highest max_points + 1 are among them
                for t in range(cell_start[cc], min(cell_start[cc + 1], cell_start[cc] + max_points + 1)):
                    top[m] = zs[t]
                    m += 1
        w = -np.sort(-top[:m])
        for i in range(min(m - 1, max_points)):
            if w[i] - w[i + 1] > gap_m:
                out[k] = w[i]
    return out


def high_clusters(x, y, z, window_cell_m: float, gap_m: float = 50.0, max_points: int = 20) -> np.ndarray:
    """Boolean mask of small groups of returns (birds, clouds) standing far above everything around them.

    For every cell of ``window_cell_m`` the heights of its 3 x 3 window are sorted from the top; when at
    most ``max_points`` returns lie above a gap of more than ``gap_m`` to the next return below, the cell's
    returns above that gap are noise. Such a group supports itself in the single-point gap test
    (``high_outliers``); no canopy layer or structure leaves so large an empty height band within the window.
    """
    x, y, z = (np.asarray(a, float) for a in (x, y, z))
    mask = np.zeros(len(x), bool)
    if len(x) < 2 or gap_m <= 0:
        return mask
    cell, nrows, ncols, _, _ = grid.cell_ids(x, y, window_cell_m)
    order = np.lexsort((-z, cell))
    cell_start = np.r_[0, np.cumsum(np.bincount(cell, minlength=nrows * ncols))]
    occupied = np.flatnonzero(np.diff(cell_start) > 0)
    floor = _high_cluster_floor(z[order], cell_start, occupied, nrows, ncols, float(gap_m), int(max_points))
    cell_floor = np.full(nrows * ncols, np.inf)
    cell_floor[occupied] = floor
    return z >= cell_floor[cell]


def low_clusters(x, y, z, cell_m: float, gap_m: float = 1.0, slope: float = 1.2,
                 *, max_cells: int = 400, ring_m: float = 50.0, ring_slope: float = 0.3,
                 patch_max_m2: float = 40.0) -> np.ndarray:
    """Boolean mask of points in small terrain-connected patches of cell minima lying below the terrain.

    Two ways a small component (at most ``max_cells``) is "below":
    (a) every unlinked neighbour lies higher (a single patch of multipath points);
    (b) it is a scrap of at most ``patch_max_m2`` and all its cells lie more than ``gap_m`` below the
        terrain surface interpolated (pull-push) from the large components: a cloud of outliers at
        mixed depths (multipath under a pond) has outliers below outliers, so (a) would only peel
        its deepest layer, but its scattered depths never link into a coherent surface.
    Courtyards also lie below all their unlinked neighbours (roofs); unlike an outlier patch they
    have terrain at about their height further out (the street beyond the buildings), so a
    component with terrain within ``ring_m`` no higher than ``gap_m + ring_slope * d`` above it is
    kept. For (b) only coherent components (larger than ``patch_max_m2``) count as that terrain:
    ground split into levels by walls or data gaps (ISPRS samp41) keeps its scraps, pond outliers
    have only other scraps at their depths.
    """
    from lidarctl.raster_ops import fill_nodata

    seg = grid.segment_cell_minima(x, y, z, cell_m, gap_m, slope)
    if seg is None:
        return np.zeros(len(x), bool)
    cid, nrows, ncols, lowest, label, size = seg.cid, seg.nrows, seg.ncols, seg.lowest, seg.label, seg.size
    ua, ub, dzu = seg.ua, seg.ub, seg.dz
    mx, my, mz = x[lowest], y[lowest], z[lowest]
    ncomp = len(size)
    small = (size <= max_cells) & (size < 0.5 * size.max())
    # (a) A component is "below" when no unlinked neighbour lies lower than it.
    has_higher = np.zeros(ncomp, bool)
    has_lower = np.zeros(ncomp, bool)
    has_higher[label[ua[dzu > 0]]] = True   # b above a -> a's component has a higher neighbour
    has_lower[label[ua[dzu < 0]]] = True
    has_higher[label[ub[dzu < 0]]] = True
    has_lower[label[ub[dzu > 0]]] = True
    low_a = small & has_higher & ~has_lower
    # (b) Below the terrain of the large components, interpolated over the patch.
    terrain = ~small[label]
    coherent = size[label] * cell_m * cell_m > patch_max_m2
    low_b = np.zeros(ncomp, bool)
    if terrain.any() and not terrain.all():
        surf = np.full(nrows * ncols, np.nan)
        surf[cid[lowest[terrain]]] = mz[terrain]
        surf = fill_nodata(surf.reshape(nrows, ncols)).ravel()
        below = mz < surf[cid[lowest]] - gap_m
        n_below = np.bincount(label, below.astype(float), minlength=ncomp)
        low_b = (size * cell_m * cell_m <= patch_max_m2) & (n_below == size)
    tree = cKDTree(np.column_stack([mx, my]))
    low_comp = low_a | low_b
    by_label = np.argsort(label, kind="stable")
    first = np.concatenate([[0], np.cumsum(size)])
    for comp in np.flatnonzero(low_comp):
        members = by_label[first[comp]:first[comp + 1]]
        for k, nb in zip(members, tree.query_ball_point(np.column_stack([mx[members], my[members]]),
                                                         ring_m)):
            nb = np.asarray(nb)
            nb = nb[label[nb] != comp]
            if low_b[comp]:
                nb = nb[coherent[nb]]     # other scattered outliers around it are no evidence of terrain
            if len(nb) and np.any(mz[nb] <= mz[k] + gap_m + ring_slope * np.hypot(mx[nb] - mx[k], my[nb] - my[k])):
                low_comp[comp] = False
                break
    if not low_comp.any():
        return np.zeros(len(x), bool)
    # Points of those cells at most gap_m above the cluster's cell minimum are the outliers.
    cell_min = np.full(int(cid.max()) + 1, np.inf)
    flagged_cells = lowest[low_comp[label]]
    cell_min[cid[flagged_cells]] = z[flagged_cells]
    return np.isfinite(cell_min[cid]) & (z <= cell_min[cid] + gap_m)


def _near(x, y, fx, fy, dist_m: float) -> np.ndarray:
    """Mask of points in the ``dist_m`` blocks around any of the points (fx, fy), block size dist_m."""
    i, j, nrows, ncols, x0, y0 = grid.cell_indices(x, y, dist_m)
    fi = np.clip(np.floor((fy - y0) / dist_m).astype(np.int64), 0, nrows - 1)
    fj = np.clip(np.floor((fx - x0) / dist_m).astype(np.int64), 0, ncols - 1)
    hit = np.zeros((nrows + 2, ncols + 2), bool)
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            hit[fi + di, fj + dj] = True
    return hit[i + 1, j + 1]


def detect_noise(x, y, z, params: NoiseSettings | None = None) -> np.ndarray:
    """Noise code per point: 0 clean, 1 isolated, 2 low outlier, 3 high outlier.

    Low outliers are tested twice: a first pass removes single blunders, the second catches
    pairs that only supported each other through a blunder. High outliers: single points, then
    small clusters (``high_clusters``).
    """
    p = params or NoiseSettings()
    spacing = grid.cloud_spacing_m(x, y)
    voxel = p.voxel_m or max(2.0, 2.5 * spacing)
    radius = p.radius_m or max(5.0, 5.0 * spacing)
    code = np.zeros(len(x), np.uint8)
    iso = isolated_points(x, y, z, voxel, p.min_neighbours)
    code[iso] = ISOLATED
    keep = np.flatnonzero(code == 0)
    for _ in range(2):
        low = low_outliers(x[keep], y[keep], z[keep], radius, p.gap_m, p.slope,
                           candidates_per_cell=p.candidates_per_cell)
        if not low.any():
            break
        code[keep[low]] = LOW
        keep = keep[~low]
    cell = p.cluster_cell_m or max(2.0, 2.0 * spacing)
    # Later passes peel the next layer of a patch; they only need the surroundings of what the
    # previous pass flagged (its patches and their 50 m ring), not the whole cloud again.
    test = keep
    for _ in range(p.cluster_passes):
        low = low_clusters(x[test], y[test], z[test], cell, p.gap_m, p.slope, max_cells=p.cluster_max_cells)
        if not low.any():
            break
        code[test[low]] = LOW
        keep = keep[code[keep] == 0]
        test = keep[_near(x[keep], y[keep], x[test[low]], y[test[low]], 100.0)]
    high = high_outliers(x[keep], y[keep], z[keep], radius, p.high_gap_m, p.slope,
                         candidates_per_cell=p.candidates_per_cell)
    code[keep[high]] = HIGH
    if p.high_cluster_gap_m > 0:
        keep = keep[~high]
        high = high_clusters(x[keep], y[keep], z[keep], p.high_cluster_radius_m or 2.0 * radius,
                             p.high_cluster_gap_m, p.high_cluster_max_points)
        code[keep[high]] = HIGH
    return code
