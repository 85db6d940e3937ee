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
4. Vegetation by HAG: low (3) <= ``low_veg_max_m`` < medium (4) <= ``medium_veg_max_m`` < high (5).
   Where the cloud has multiple returns, a non-ground point above ``low_veg_max_m`` counts as
   vegetation only in cells with multi-return or rough (non-planar) structure; smooth single-return
   objects that are too small for a building (cars, walls) stay unclassified (1).
5. Water (9): ground cells that are flat and horizontal (plane RMS and slope tiny), where the point
   density drops below ``water_density_ratio`` of the cloud's median (water absorbs the pulse).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

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
        roof_area = ndimage.sum_labels(roof, labels, np.arange(1, nlab + 1)) * c * c
        big = np.concatenate([[False], roof_area >= p.building_min_area_m2])
        building_cells = big[labels]
    else:
        building_cells = np.zeros_like(roof)
    # Wall points fall in the ring of cells just outside the roof outline.
    ring = ndimage.binary_dilation(building_cells, np.ones((3, 3), bool)) & ~building_cells
    in_bld = (building_cells.ravel()[flat]) | (ring.ravel()[flat] & ~multi)
    is_building = obj & in_bld & (hag > p.wall_min_height_m) & (z >= dsm_f.ravel()[flat] - p.roof_depth_m)
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
