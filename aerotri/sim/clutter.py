"""Tie points off the ground for a geometric block: trees (static, above the DEM) and moving cars.

What a matcher finds in real blocks besides the bare ground: points on tree crowns and hedges, seen
consistently in every frame but metres above the LiDAR DEM (bare earth); and points on moving cars,
whose image points in each frame come from where the car was at that exposure, so their rays do not
meet. ``clutter_ties`` draws all three classes for a ``GeometricBlock`` (local ENU metres of its
frame), ``write_terrain_rasters`` writes the block's DEM (the terrain) and nDSM (the tree crowns,
height above ground; the cars are not in it: the LiDAR flew at another time) as GeoTIFFs in the
project CRS, the DEM's heights the project's.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from aerotri.geom.observations import ImageObservations
from aerotri.sim.observations import GeometricBlock, write_block_project, write_image_points, write_truth_observations

CLASSES = ("ground", "vegetation", "moving")
PREFIX = {"ground": "g", "vegetation": "v", "moving": "m"}


@dataclasses.dataclass
class Trees:
    """Tree crowns: domes of radius ``radius_m`` and top height ``top_m`` above the ground at local xy
    ``centre`` (T, 2); the crown surface lies ``top * sqrt(1 - (r / radius)^2)`` above the ground."""

    centre: np.ndarray
    radius_m: np.ndarray
    top_m: np.ndarray

    @classmethod
    def random(cls, block: GeometricBlock, cover: float, rng, radius_m=(3.0, 8.0), top_m=(3.5, 20.0)) -> Trees:
        """Trees over about ``cover`` of the block's ground; a third of them in hedgerows (rows of
        crowns 1.5 radii apart)."""
        x0, x1, y0, y1 = block.extent_local
        r_mean = np.mean(radius_m)
        n = int(cover * (x1 - x0) * (y1 - y0) / (np.pi * r_mean**2 * 1.1))
        n_hedge = n // 3
        c = np.column_stack([rng.uniform(x0, x1, n - n_hedge), rng.uniform(y0, y1, n - n_hedge)])
        rows = []
        while sum(len(r) for r in rows) < n_hedge:
            start = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
            ang = rng.uniform(0, np.pi)
            k = np.arange(rng.integers(5, 20))
            rows.append(start + np.outer(k * 1.5 * r_mean, [np.cos(ang), np.sin(ang)]))
        c = np.vstack([c] + rows)[:n]
        return cls(c, rng.uniform(*radius_m, len(c)), rng.uniform(*top_m, len(c)))

    def canopy_m(self, x, y) -> np.ndarray:
        """Height of the crowns above the ground at local x, y (0 outside every crown)."""
        from scipy.spatial import cKDTree

        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        q = np.column_stack([x.ravel(), y.ravel()])
        # the 8 nearest centres within the largest radius (more crowns never overlap at one place)
        d, k = cKDTree(self.centre).query(q, k=min(8, len(self.centre)), distance_upper_bound=float(self.radius_m.max()))
        d, k = d.reshape(len(q), -1), k.reshape(len(q), -1)
        found = k < len(self.centre)
        kk = np.where(found, k, 0)
        r = np.where(found, d / self.radius_m[kk], np.inf)
        h = np.max(np.where(r < 1, self.top_m[kk] * np.sqrt(np.clip(1 - r**2, 0, None)), 0.0), axis=1)
        return h.reshape(x.shape)

    def sample(self, block: GeometricBlock, n: int, rng, max_r: float = 0.8) -> np.ndarray:
        """``n`` points on the crown surfaces (within ``max_r`` of each radius, so at least 0.6 of the top
        above the ground), local (n, 3); crowns drawn by their area."""
        w = self.radius_m**2
        t = rng.choice(len(w), n, p=w / w.sum())
        r = max_r * np.sqrt(rng.random(n)) * self.radius_m[t]
        a = rng.uniform(0, 2 * np.pi, n)
        xy = self.centre[t] + np.column_stack([np.cos(a), np.sin(a)]) * r[:, None]
        z = block.terrain(xy[:, 0], xy[:, 1]) + self.canopy_m(xy[:, 0], xy[:, 1])
        return np.column_stack([xy, z])


@dataclasses.dataclass(frozen=True)
class ClassCount:
    """Tie points of one class and their image observations."""

    points: int
    observations: int


@dataclasses.dataclass(frozen=True)
class ClutterCounts:
    """Tie points and observations per class (``CLASSES``)."""

    ground: ClassCount
    vegetation: ClassCount
    moving: ClassCount

    @property
    def points(self) -> int:
        return self.ground.points + self.vegetation.points + self.moving.points


@dataclasses.dataclass
class ClutterTies:
    """Tie observations of the three classes and their truth."""

    obs: ImageObservations
    point_class: dict  # point id -> "ground" | "vegetation" | "moving"
    ground_truth_local: dict  # ground point id -> true local position (3,)
    trees: Trees

    def counts(self) -> ClutterCounts:
        """Points and observations per class."""
        cls = np.array([self.point_class[p] for p in self.obs.point_id])
        return ClutterCounts(**{c: ClassCount(points=int(sum(v == c for v in self.point_class.values())),
                                              observations=int((cls == c).sum())) for c in CLASSES})


def _noisy(block, P, pi, ii, xy, *, prefix, sigma_px, min_rays, rng):
    """Keep points with >= ``min_rays`` and add image noise; ids ``<prefix>000001``..."""
    rays = np.bincount(pi, minlength=len(P))
    keep = rays >= min_rays
    m = keep[pi]
    new = np.cumsum(keep) - 1
    pi, ii, xy = new[pi[m]], ii[m], xy[m] + rng.normal(0.0, sigma_px, (int(m.sum()), 2))
    ids = np.array([f"{prefix}{k + 1:06d}" for k in range(int(keep.sum()))], dtype=object)
    obs = ImageObservations(ids[pi], np.asarray(block.image_id, dtype=object)[ii], xy)
    return obs, ids, P[keep]


def _subset_points(obs: ImageObservations, ids: np.ndarray, n: int, rng) -> tuple[ImageObservations, np.ndarray]:
    """``n`` of the points (random), with their observations."""
    keep = np.sort(rng.choice(len(ids), min(n, len(ids)), replace=False))
    return obs.subset(np.isin(obs.point_id, ids[keep])), keep


def moving_points(block: GeometricBlock, n: int, rng, *, step_m=(3.0, 15.0), height_m=(0.3, 1.6), sigma_px=0.3,
                  min_rays: int = 2):
    """Points on cars that move ``step_m`` between consecutive exposures of a strip (straight, at a
    constant speed, in a random direction), ``height_m`` above the ground. A car is matched within one
    strip (the one that sees its first position most often; minutes later, in the next strip, it is
    gone): in frame ``i`` its point is where the car was then, ``base + v (i - i0)``.
    Returns (observations, ids, base positions local)."""
    m_cand = 3 * n
    base = block.ground_points(m_cand, rng)
    base[:, 2] += rng.uniform(*height_m, m_cand)
    ang = rng.uniform(0, 2 * np.pi, m_cand)
    v = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(m_cand)]) * rng.uniform(*step_m, m_cand)[:, None]
    pi, ii, _ = block.project(base)
    S = int(block.strip.max()) + 1
    seen = np.bincount(pi * S + block.strip[ii], minlength=m_cand * S).reshape(m_cand, S)
    strip_of = np.argmax(seen, axis=1)
    # every frame of that strip is a candidate exposure; the car is where it is at that exposure
    i0 = np.full(m_cand, np.iinfo(np.int64).max)
    first = strip_of[pi] == block.strip[ii]
    np.minimum.at(i0, pi[first], ii[first])
    out_p, out_i, out_xy = [], [], []
    for i in range(len(block.image_id)):
        pts = np.flatnonzero((strip_of == block.strip[i]) & (i0 < np.iinfo(np.int64).max))
        X = base[pts] + v[pts] * (i - i0[pts])[:, None]
        x, y, depth = block.camera_true.project(X, block.centre_local[i], block.R_local[i])
        ok = (depth > 0) & block.camera_true.inside(x, y, 20.0)
        out_p.append(pts[ok])
        out_i.append(np.full(int(ok.sum()), i))
        out_xy.append(np.column_stack([x[ok], y[ok]]))
    pi, ii, xy = np.concatenate(out_p), np.concatenate(out_i), np.concatenate(out_xy)
    order = np.lexsort((ii, pi))
    obs, ids, P = _noisy(block, base, pi[order], ii[order], xy[order], prefix=PREFIX["moving"], sigma_px=sigma_px,
                         min_rays=min_rays, rng=rng)
    obs, keep = _subset_points(obs, ids, n, rng)
    return obs, ids[keep], P[keep]


def clutter_ties(block: GeometricBlock, *, points_per_image: int = 150, vegetation_share: float = 0.1,
                 moving_share: float = 0.1, tree_cover: float = 0.1, sigma_px: float = 0.3, seed: int = 0) -> ClutterTies:
    """Tie points of a block: ground points (not under a crown, >= 3 rays), ``vegetation_share`` of all
    tie points on tree crowns (>= 3 rays, consistent in every frame) and ``moving_share`` on moving cars
    (>= 2 rays, one strip). Shares by points."""
    rng = np.random.default_rng(seed)
    trees = Trees.random(block, tree_cover, rng)
    n_cand = int(points_per_image * len(block.image_id) / 1.5)
    P = block.ground_points(n_cand, rng)
    P = P[trees.canopy_m(P[:, 0], P[:, 1]) == 0]  # hidden under the crowns
    g_obs, g_ids, g_P = _noisy(block, P, *block.project(P), prefix=PREFIX["ground"], sigma_px=sigma_px, min_rays=3,
                               rng=rng)
    n_g = len(g_ids)
    n_total = n_g / (1 - vegetation_share - moving_share)
    n_veg, n_mov = round(vegetation_share * n_total), round(moving_share * n_total)
    V = trees.sample(block, 2 * n_veg + 100, rng)
    v_obs, v_ids, _ = _noisy(block, V, *block.project(V), prefix=PREFIX["vegetation"], sigma_px=sigma_px, min_rays=3,
                             rng=rng)
    v_obs, keep = _subset_points(v_obs, v_ids, n_veg, rng)
    v_ids = v_ids[keep]
    m_obs, m_ids, _ = moving_points(block, n_mov, rng, sigma_px=sigma_px)
    obs = ImageObservations(np.concatenate([g_obs.point_id, v_obs.point_id, m_obs.point_id]),
                            np.concatenate([g_obs.image_id, v_obs.image_id, m_obs.image_id]),
                            np.vstack([g_obs.xy_px, v_obs.xy_px, m_obs.xy_px]))
    cls = {**{p: "ground" for p in g_ids}, **{p: "vegetation" for p in v_ids}, **{p: "moving" for p in m_ids}}
    return ClutterTies(obs, cls, dict(zip(g_ids, g_P)), trees)


def terrain_grid(block: GeometricBlock, cell_m: float = 2.0, margin_m: float = 200.0, local_xy: bool = False,
                 step: int = 8):
    """The block's terrain as a north-up grid in the project CRS over its extent plus ``margin_m``: map
    heights whose local point lies on the terrain (``HeightGrid``), and with ``local_xy`` the local x, y of
    every cell centre (H, W) each. Exact at every ``step``-th cell, a bicubic spline between (the terrain's
    shortest wavelength is 1.6 km, the frame's curvature smoother still: sub-millimetre; a 2 m grid of a
    1000-frame block has 50 million cells)."""
    from scipy.interpolate import RectBivariateSpline

    from aerotri.adjust.surface import HeightGrid

    xmin, xmax, ymin, ymax = block.extent_local
    corners = block.frame.to_map(np.array([[xmin, ymin, 0.0], [xmax, ymax, 0.0]]))
    x0, y1 = corners[0, 0] - margin_m, corners[1, 1] + margin_m
    W = int(np.ceil((corners[1, 0] + margin_m - x0) / cell_m))
    H = int(np.ceil((y1 - (corners[0, 1] - margin_m)) / cell_m))
    cols = np.unique(np.r_[np.arange(0, W, step), W - 1])
    rows = np.unique(np.r_[np.arange(0, H, step), H - 1])
    X, Y = np.meshgrid(x0 + (cols + 0.5) * cell_m, y1 - (rows + 0.5) * cell_m)
    h = np.zeros_like(X)
    for _ in range(4):  # the map height whose local point lies on the terrain
        p = block.frame.to_local(np.column_stack([X.ravel(), Y.ravel(), h.ravel()]))
        h = h + (block.terrain(p[:, 0], p[:, 1]) - p[:, 2]).reshape(h.shape)
    r_all, c_all = np.arange(H, dtype=float), np.arange(W, dtype=float)

    def fill(coarse):
        return RectBivariateSpline(rows, cols, coarse)(r_all, c_all)

    grid = HeightGrid(fill(h), float(x0), float(y1), float(cell_m))
    if not local_xy:
        return grid, None
    return grid, (fill(p[:, 0].reshape(h.shape)), fill(p[:, 1].reshape(h.shape)))


def rasterise_canopy(trees: Trees, block: GeometricBlock, grid, local_x: np.ndarray, local_y: np.ndarray) -> np.ndarray:
    """The crowns' height above the ground at the cells of ``grid`` (whose local x, y are given), crown by crown
    over the cells around it."""
    ndsm = np.zeros(grid.z.shape)
    c_map = block.frame.to_map(np.column_stack([trees.centre, block.terrain(*trees.centre.T)]))
    H, W = ndsm.shape
    for (cx, cy), (lx, ly), R, top in zip(c_map[:, :2], trees.centre, trees.radius_m, trees.top_m):
        reach = 1.01 * R + grid.res  # the frame's scale differs from the map's by far less than 1 %
        c0, c1 = int(max((cx - reach - grid.x0) / grid.res, 0)), int(min((cx + reach - grid.x0) / grid.res + 1, W))
        r0, r1 = int(max((grid.y0 - cy - reach) / grid.res, 0)), int(min((grid.y0 - cy + reach) / grid.res + 1, H))
        if c0 >= c1 or r0 >= r1:
            continue
        r = np.hypot(local_x[r0:r1, c0:c1] - lx, local_y[r0:r1, c0:c1] - ly) / R
        crown = np.where(r < 1, top * np.sqrt(np.clip(1 - r * r, 0, None)), 0.0)
        np.maximum(ndsm[r0:r1, c0:c1], crown, out=ndsm[r0:r1, c0:c1])
    return ndsm


def write_terrain_rasters(block: GeometricBlock, dem_path, ndsm_path=None, trees: Trees | None = None, cell_m: float = 2.0,
                          margin_m: float = 200.0) -> None:
    """The block's terrain as a DEM GeoTIFF (``terrain_grid``) and with ``ndsm_path`` the crowns' height above
    it, both in the project CRS."""
    import rasterio
    from rasterio.transform import from_origin

    grid, lxy = terrain_grid(block, cell_m, margin_m, local_xy=ndsm_path is not None)
    rasters = [(Path(dem_path), grid.z)]
    if ndsm_path is not None:
        rasters.append((Path(ndsm_path), rasterise_canopy(trees, block, grid, *lxy) if trees is not None
                        else np.zeros_like(grid.z)))
    H, W = grid.z.shape
    for path, z in rasters:
        with rasterio.open(path, "w", driver="GTiff", width=W, height=H, count=1, dtype="float32", crs=block.crs,
                           transform=from_origin(grid.x0, grid.y0, cell_m, cell_m), nodata=-9999.0) as ds:
            ds.write(z.astype(np.float32), 1)


def write_clutter_projects(block: GeometricBlock, out_dir, *, points_per_image: int = 150, n_check: int = 30,
                           vegetation_share: float = 0.1, moving_share: float = 0.1, sigma_px: float = 0.3,
                           cell_m: float = 2.0, seed: int = 0) -> tuple[ClutterTies, Path, Path]:
    """Two projects of the block under ``out_dir``: ``clean`` (ground tie points only) and ``dirty`` (all
    three classes), with the same check points (surveyed to 5 mm, not in the adjustment), ``dem.tif`` and
    ``ndsm.tif``. Returns (ties, clean root, dirty root)."""
    import shutil

    out = Path(out_dir)
    clean = write_block_project(block, out / "clean")
    # check points and their image points; the tie points it writes are replaced below
    write_truth_observations(clean, tie_sigma_px=sigma_px, n_control=0, points_per_image=2, n_check=n_check, seed=seed)
    ties = clutter_ties(block, points_per_image=points_per_image, vegetation_share=vegetation_share,
                        moving_share=moving_share, sigma_px=sigma_px, seed=seed + 1)
    write_terrain_rasters(block, clean / "dem.tif", clean / "ndsm.tif", ties.trees, cell_m=cell_m)
    dirty = out / "dirty"
    shutil.copytree(clean, dirty)
    is_ground = np.array([ties.point_class[p] == "ground" for p in ties.obs.point_id])
    write_image_points(clean / "at" / "tiepoints.csv", ties.obs.subset(is_ground))
    write_image_points(dirty / "at" / "tiepoints.csv", ties.obs)
    return ties, clean, dirty
