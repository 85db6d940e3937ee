"""Full classification into ASPRS classes: noise, ground, buildings, vegetation, water.

Pipeline (``classify_points``):
1. Noise (lidarctl.noise): low outliers -> 7, high outliers -> 18; isolated points -> 7 when below
   the ground DEM, else 18.
2. Ground (lidarctl.ground) -> 2; ground points more than ``deep_m`` below the mean ground of
   their 15 m neighbourhood (a deep patch of low noise that slipped through) become low noise
   and the ground is filtered again; height above ground (HAG) from a DEM of the ground points;
   non-ground points more than ``deep_m`` below that DEM are low noise too.
3. Buildings from planar roof segments: on a ``cell_m`` grid of the highest non-ground point (object
   DSM), a least-squares plane is fitted in every 3x3 window; cells with plane RMS below
   ``roof_rms_m``, HAG above ``building_min_height_m`` and few multi-return points (laser
   penetrates trees, not roofs) are roof cells; 8-connected roof segments of at least
   ``building_min_area_m2`` are buildings (-> 6, points within ``roof_depth_m`` below the DSM).
   Small segments (sheds, garages: at least ``small_building_min_area_m2``) count by their whole
   area when their median plane RMS is below ``rough_rms_m`` and they are mostly single-return
   (the 3x3 fit eats a cell on every side of a small roof). Wall points: single returns in the
   ring of cells around a building. Roof-edge completion (``roof_edge_completion``): region
   growing of building points over eaves and low roof parts by local-plane continuity (kNN
   least-squares plane of the neighbouring building points, ``edge_tolerance_m``).
4. Vegetation by HAG: low (3) <= ``low_veg_max_m`` < medium (4) <= ``medium_veg_max_m`` < high (5).
   Where the cloud has multiple returns, a non-ground point above ``low_veg_max_m`` counts as
   vegetation only in cells with multi-return or rough (non-planar) structure; smooth single-return
   objects that are too small for a building (cars, walls) stay unclassified (1).
5. Water (9): ground cells that are flat and horizontal (plane RMS and slope tiny), where the point
   density drops below ``water_density_ratio`` of the cloud's median (water absorbs the pulse).
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from lidarctl import grid
from lidarctl import ground as ground_mod
from lidarctl import noise as noise_mod
from lidarctl.raster_ops import fill_nodata, reduce_grid, sample_bilinear, slope_tan

UNCLASSIFIED, GROUND, LOW_VEG, MED_VEG, HIGH_VEG, BUILDING, LOW_NOISE, WATER, HIGH_NOISE = 1, 2, 3, 4, 5, 6, 7, 9, 18
CLASS_NAMES = {1: "unclassified", 2: "ground", 3: "low veg", 4: "medium veg", 5: "high veg",
               6: "building", 7: "low noise", 9: "water", 18: "high noise"}


@dataclasses.dataclass
class ClassifyParams:
    ground_method: str = "morph"
    preset: str | None = None
    cell_m: float = 0.0                 # 0: max(0.5 m, 2 x mean point spacing)
    building_min_height_m: float = 2.0
    building_min_area_m2: float = 20.0
    roof_rms_m: float = 0.15
    roof_depth_m: float = 100.0
    wall_min_height_m: float = 0.5
    max_multi_return_fraction: float = 0.3
    grow_multi_return_fraction: float = 0.7
    low_veg_max_m: float = 2.0
    medium_veg_max_m: float = 5.0
    rough_rms_m: float = 0.3
    water_density_ratio: float = 0.3
    water_rms_m: float = 0.05
    deep_cell_m: float = 5.0
    deep_m: float = 5.0
    small_building_min_area_m2: float = 6.0
    small_building_max_multi_fraction: float = 0.2
    edge_neighbours: int = 8
    edge_radius_m: float = 1.0
    edge_tolerance_m: float = 0.1
    edge_iterations: int = 8
    edge_zone_m: float = 3.0
    noise: noise_mod.NoiseParams = dataclasses.field(default_factory=noise_mod.NoiseParams)


def _plane_rms(a: np.ndarray, cell_m: float) -> np.ndarray:
    """RMS residual of the least-squares plane in each 3x3 window of a filled raster (m)."""
    k = np.ones((3, 3)) / 9.0
    u = np.array([[-1, 0, 1]] * 3, float) * cell_m      # x offsets (columns)
    v = u.T                                              # y offsets (rows)
    mean = ndimage.correlate(a, k, mode="nearest")
    mean2 = ndimage.correlate(a * a, k, mode="nearest")
    sxz = ndimage.correlate(a, u / 9.0, mode="nearest")
    syz = ndimage.correlate(a, v / 9.0, mode="nearest")
    var_uv = (2.0 / 3.0) * cell_m * cell_m              # mean of u^2 over the window
    resid2 = mean2 - mean ** 2 - sxz ** 2 / var_uv - syz ** 2 / var_uv
    return np.sqrt(np.maximum(resid2, 0.0))


def ground_dem(x, y, z, ground, cell_m, x0, y0, nrows, ncols) -> np.ndarray:
    """Filled DEM (mean height of ground points per cell), rows growing with y."""
    dem = reduce_grid(x[ground], y[ground], z[ground], cell_m, x0, y0, nrows, ncols, "mean")
    return fill_nodata(dem)


def deep_ground_outliers(x, y, z, ground, cell_m: float = 5.0, deep_m: float = 5.0) -> np.ndarray:
    """Ground-labelled points far below the mean ground of their 3x3 cell neighbourhood.

    Catches patches of low noise at mixed depths that support each other in the gap tests and
    slipped into the ground set: a point is flagged when it lies more than ``deep_m`` plus the
    local relief (slope of the mean-ground grid times the window radius) below the windowed mean.
    """
    out = np.zeros(len(x), bool)
    gi = np.flatnonzero(ground)
    if len(gi) < 10:
        return out
    cid, nrows, ncols, x0, y0 = grid.cell_ids(x[gi], y[gi], cell_m)
    s = np.bincount(cid, z[gi], minlength=nrows * ncols).reshape(nrows, ncols)
    c = np.bincount(cid, minlength=nrows * ncols).reshape(nrows, ncols).astype(float)
    k = np.ones((3, 3))
    ss = ndimage.correlate(s, k, mode="constant")
    cc = ndimage.correlate(c, k, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cc > 0, ss / np.maximum(cc, 1), np.nan)
    filled = fill_nodata(mean)
    relief = slope_tan(filled, cell_m) * 1.5 * cell_m
    ref = (filled - relief).ravel()[cid]
    out[gi[z[gi] < ref - deep_m]] = True
    return out


@numba.njit(cache=True, parallel=True)
def _plane_offsets(x, y, z, query, nb, dist, min_points):
    """Per query point: height above the LSQ plane z = a dx + b dy + c through its valid
    neighbours ``nb`` (point indices; dx, dy relative to the query point, so c is the plane
    height there), and the plane's RMS residual. NaN with fewer than ``min_points`` neighbours."""
    n, k = nb.shape
    dz = np.full(n, np.nan)
    rms = np.full(n, np.nan)
    for i in numba.prange(n):
        q = query[i]
        s_uu = s_uv = s_u = s_vv = s_v = s_1 = s_uh = s_vh = s_h = 0.0
        m = 0
        for t in range(k):
            if not np.isfinite(dist[i, t]):
                continue
            r = nb[i, t]
            u, v, h = x[r] - x[q], y[r] - y[q], z[r] - z[q]
            s_uu += u * u; s_uv += u * v; s_u += u; s_vv += v * v; s_v += v; s_1 += 1.0
            s_uh += u * h; s_vh += v * h; s_h += h
            m += 1
        if m < min_points:
            continue
        a = np.array([[s_uu, s_uv, s_u], [s_uv, s_vv, s_v], [s_u, s_v, s_1]]) + 1e-9 * np.eye(3)
        coef = np.linalg.solve(a, np.array([s_uh, s_vh, s_h]))
        ss = 0.0
        for t in range(k):
            if not np.isfinite(dist[i, t]):
                continue
            r = nb[i, t]
            e = z[r] - z[q] - (coef[0] * (x[r] - x[q]) + coef[1] * (y[r] - y[q]) + coef[2])
            ss += e * e
        rms[i] = np.sqrt(ss / m)
        dz[i] = -coef[2]
    return dz, rms


class _GrowingNeighbours:
    """k nearest neighbours (horizontal) in a point set that grows: a KD-tree of the initial set,
    built once, and one of the points added since, merged per query."""

    def __init__(self, x, y, ref, radius_m: float):
        self.x, self.y, self.r = x, y, radius_m
        self.x0, self.y0 = float(np.min(x[ref])), float(np.min(y[ref]))
        self.base = np.asarray(ref, np.int64)
        self.base_tree = cKDTree(np.column_stack([x[ref] - self.x0, y[ref] - self.y0]))
        self.added = np.zeros(0, np.int64)

    def add(self, idx):
        self.added = np.concatenate([self.added, idx])

    def query(self, idx, k: int):
        q = np.column_stack([self.x[idx] - self.x0, self.y[idx] - self.y0])
        d, n = self.base_tree.query(q, k=k, distance_upper_bound=self.r)
        d, n = d.reshape(len(idx), k), n.reshape(len(idx), k)
        n = self.base[np.minimum(n, len(self.base) - 1)]
        if len(self.added):
            ka = min(k, len(self.added))
            tree = cKDTree(np.column_stack([self.x[self.added] - self.x0, self.y[self.added] - self.y0]))
            da, na = tree.query(q, k=ka, distance_upper_bound=self.r)
            da, na = da.reshape(len(idx), ka), na.reshape(len(idx), ka)
            d = np.concatenate([d, da], axis=1)
            n = np.concatenate([n, self.added[np.minimum(na, len(self.added) - 1)]], axis=1)
            first = np.argsort(d, axis=1, kind="stable")[:, :k]
            d, n = np.take_along_axis(d, first, 1), np.take_along_axis(n, first, 1)
        return d, n


def local_plane_offsets(x, y, z, ref, query, k: int = 8, radius_m: float = 1.0, neighbours=None):
    """Height of each query point above the least-squares plane through its k nearest reference
    points (horizontal distance, within ``radius_m``), and that plane's RMS residual (m).

    Returns (dz, rms, ok); ``ok`` is False where fewer than 5 reference points are near.
    """
    n = len(query)
    if len(ref) < 5 or n == 0:
        return np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, bool)
    nbrs = neighbours or _GrowingNeighbours(x, y, ref, radius_m)
    dist, nb = nbrs.query(np.asarray(query, np.int64), min(k, len(ref)))
    dz, rms = _plane_offsets(np.asarray(x, float), np.asarray(y, float), np.asarray(z, float),
                             np.asarray(query, np.int64), nb, dist, 5)
    return dz, rms, np.isfinite(dz)


def _near_mask(xa, ya, xb, yb, cell_m: float) -> np.ndarray:
    """Mask over points a lying in the 3x3 ``cell_m`` cells around any point b (so every a within
    ``cell_m`` of some b is included)."""
    if len(xb) == 0 or len(xa) == 0:
        return np.zeros(len(xa), bool)
    x0, y0 = float(min(np.min(xa), np.min(xb))) - cell_m, float(min(np.min(ya), np.min(yb))) - cell_m
    ncols = int(np.floor((max(np.max(xa), np.max(xb)) - x0) / cell_m)) + 3
    ia = np.floor((ya - y0) / cell_m).astype(np.int64) * ncols + np.floor((xa - x0) / cell_m).astype(np.int64)
    ib = np.floor((yb - y0) / cell_m).astype(np.int64) * ncols + np.floor((xb - x0) / cell_m).astype(np.int64)
    ib = np.unique(ib)
    keys = np.unique((ib[:, None] + (np.array([-1, 0, 1])[:, None] * ncols + np.array([-1, 0, 1])).ravel()).ravel())
    return np.isin(ia, keys)


def roof_edge_completion(x, y, z, is_building, candidates, p: ClassifyParams) -> None:
    """Grow building points (in place) over roof edges and low roof parts the cell rules missed.

    Edge cells of a roof hold pulses split between the eave and the wall or ground below, so they
    fail the multi-return and 3x3-plane tests; a lean-to roof sloping down to 1.5 m above the
    ground falls below the building height threshold. A candidate point joins the building when it
    lies within ``edge_tolerance_m`` of the local plane through its ``edge_neighbours`` nearest
    building points (within ``edge_radius_m``) and that plane fits them to the same tolerance (a
    planar roof continues; tree crowns beside the eave do not). Region growing: up to
    ``edge_iterations`` passes, each testing only the candidates next to the points added before.
    """
    cand = np.flatnonzero(candidates & ~is_building)
    ref = np.flatnonzero(is_building)
    if len(cand) == 0 or len(ref) < 5:
        return
    r = p.edge_radius_m
    # Only building points near a candidate can be its neighbours; the growth adds to them.
    ref = ref[_near_mask(x[ref], y[ref], x[cand], y[cand], r)]
    if len(ref) < 5:
        return
    neighbours = _GrowingNeighbours(x, y, ref, r)
    query = cand
    for _ in range(p.edge_iterations):
        if len(query) == 0:
            return
        dz, rms, ok = local_plane_offsets(x, y, z, ref, query, p.edge_neighbours, r, neighbours)
        add = ok & (np.abs(np.nan_to_num(dz, nan=np.inf)) < p.edge_tolerance_m)
        add &= np.nan_to_num(rms, nan=np.inf) < p.edge_tolerance_m
        if not add.any():
            return
        new = query[add]
        is_building[new] = True
        neighbours.add(new)
        cand = cand[~is_building[cand]]
        query = cand[_near_mask(x[cand], y[cand], x[new], y[new], r)]


def classify_points(x, y, z, return_number=None, number_of_returns=None, intensity=None,
                    params: ClassifyParams | None = None, progress=None) -> np.ndarray:
    """ASPRS class per point (uint8). Arrays are per point; heights in metres."""
    p = params or ClassifyParams()
    n = len(x)
    if n < 10:
        raise ValueError("classification needs at least 10 points")
    step = progress or (lambda name: None)
    cls = np.full(n, UNCLASSIFIED, np.uint8)

    step("noise")
    code = noise_mod.detect_noise(x, y, z, p.noise)
    clean = code == 0
    # Only a last (or single) return can be bare earth: the pulse went on below the others.
    last = np.ones(n, bool)
    if return_number is not None and number_of_returns is not None:
        last = np.asarray(return_number) >= np.asarray(number_of_returns)
    idx = np.flatnonzero(clean & last)

    step("ground")
    is_ground = np.zeros(n, bool)
    for _ in range(2):
        g = ground_mod.ground_filter(x[idx], y[idx], z[idx], method=p.ground_method, preset=p.preset)
        is_ground[:] = False
        is_ground[idx[g]] = True
        deep = deep_ground_outliers(x, y, z, is_ground, p.deep_cell_m, p.deep_m)
        if not deep.any():
            break
        # Deep noise in the ground set bent the surface: flag it and filter the ground again.
        code[deep] = noise_mod.LOW
        is_ground &= ~deep
        idx = idx[code[idx] == 0]

    spacing = noise_mod.mean_spacing_m(x, y)
    c = p.cell_m or max(0.5, 2.0 * spacing)
    x0, y0 = float(x.min()), float(y.min())
    ncols = int(np.floor((x.max() - x0) / c)) + 1
    nrows = int(np.floor((y.max() - y0) / c)) + 1
    dem = ground_dem(x, y, z, is_ground, c, x0, y0, nrows, ncols)
    hag = z - sample_bilinear(dem, x, y, c, x0, y0)

    # Points far below the bare-earth DEM cannot be objects: low noise the gap tests missed.
    code[(code == 0) & ~is_ground & (hag < -p.deep_m)] = noise_mod.LOW
    clean = code == 0
    cls[code == noise_mod.LOW] = LOW_NOISE
    cls[code == noise_mod.HIGH] = HIGH_NOISE
    iso = code == noise_mod.ISOLATED
    cls[iso] = np.where(hag[iso] < 0.0, LOW_NOISE, HIGH_NOISE)
    cls[is_ground] = GROUND

    step("buildings")
    obj = clean & ~is_ground
    flat = grid.cell_ids(x, y, c, x0, y0)[0]
    dsm = reduce_grid(x[obj], y[obj], z[obj], c, x0, y0, nrows, ncols, "max")
    has_obj = np.isfinite(dsm)
    dsm_f = np.where(has_obj, dsm, dem)
    rms = _plane_rms(dsm_f, c)
    multi = np.zeros(n, bool)
    has_multi = False
    if return_number is not None and number_of_returns is not None:
        multi = np.asarray(number_of_returns) > 1
        has_multi = bool(multi.any())
    cnt = np.bincount(flat[obj], minlength=nrows * ncols).reshape(nrows, ncols)
    cnt_multi = np.bincount(flat[obj & multi], minlength=nrows * ncols).reshape(nrows, ncols)
    with np.errstate(invalid="ignore", divide="ignore"):
        multi_frac = np.where(cnt > 0, cnt_multi / np.maximum(cnt, 1), 0.0)
    high_obj = has_obj & (dsm_f - dem > p.building_min_height_m)
    roof = high_obj & (rms < p.roof_rms_m)
    if has_multi:
        roof &= multi_frac <= p.max_multi_return_fraction
        candidate = high_obj & (multi_frac <= p.grow_multi_return_fraction)
    else:
        candidate = high_obj & (rms < p.rough_rms_m)
    # Roof segments grow into connected object cells that are not tree-like (ridges, dormers and
    # roof edges break the 3x3 plane fit); a segment is a building when its planar part is large.
    candidate = ndimage.binary_closing(candidate, np.ones((3, 3), bool)) & high_obj | roof
    labels, nlab = ndimage.label(candidate, np.ones((3, 3), int))
    if nlab:
        ids = np.arange(1, nlab + 1)
        roof_area = ndimage.sum_labels(roof, labels, ids) * c * c
        big = roof_area >= p.building_min_area_m2
        # Sheds and garages: the planar interior of a small roof loses a cell on every side to the
        # 3x3 fit, so a small segment counts by its whole area when it is planar and single-return.
        small = ~big & (ndimage.sum_labels(candidate, labels, ids) * c * c >= p.small_building_min_area_m2)
        if small.any():
            small &= ndimage.median(rms, labels, ids) < p.rough_rms_m
            small &= ndimage.mean(multi_frac, labels, ids) <= p.small_building_max_multi_fraction
        building_cells = np.concatenate([[False], big | small])[labels]
    else:
        building_cells = np.zeros_like(roof)
    # Wall points fall in the ring of cells just outside the roof outline.
    ring = ndimage.binary_dilation(building_cells, np.ones((3, 3), bool)) & ~building_cells
    in_bld = (building_cells.ravel()[flat]) | (ring.ravel()[flat] & ~multi)
    is_building = obj & in_bld & (hag > p.wall_min_height_m) & (z >= dsm_f.ravel()[flat] - p.roof_depth_m)
    zone = max(1, int(round(p.edge_zone_m / c)))
    near = ndimage.binary_dilation(building_cells, np.ones((2 * zone + 1, 2 * zone + 1), bool)).ravel()[flat]
    roof_edge_completion(x, y, z, is_building, obj & near & (hag > p.wall_min_height_m), p)
    cls[is_building] = BUILDING

    step("vegetation")
    veg = obj & ~is_building
    low = veg & (hag <= p.low_veg_max_m)
    med = veg & (hag > p.low_veg_max_m) & (hag <= p.medium_veg_max_m)
    high = veg & (hag > p.medium_veg_max_m)
    if has_multi:
        structured = ((multi_frac > 0) | (rms >= p.rough_rms_m)).ravel()[flat]
        med &= structured
        high &= structured
    cls[low] = LOW_VEG
    cls[med] = MED_VEG
    cls[high] = HIGH_VEG

    step("water")
    gcnt = np.bincount(flat[is_ground], minlength=nrows * ncols).reshape(nrows, ncols)
    occupied = np.bincount(flat, minlength=nrows * ncols).reshape(nrows, ncols)
    median_density = np.median(occupied[occupied > 0])
    dem_rms = _plane_rms(dem, c)
    sparse = ndimage.uniform_filter(occupied.astype(float), 5) < p.water_density_ratio * median_density
    water_cells = sparse & (dem_rms < p.water_rms_m) & (slope_tan(dem, c) < 0.02) & (gcnt > 0)
    water_cells = ndimage.binary_opening(water_cells, np.ones((3, 3), bool))
    cls[is_ground & water_cells.ravel()[flat]] = WATER
    return cls
