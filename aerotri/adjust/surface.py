"""LiDAR surface control: tie points on open ground observe the height of the DEM.

A tie point ``P`` (local frame) at map position ``(x, y, h) = map(P)`` observes ``h = DEM(x, y)`` (cubic
convolution of the DEM, continuous in height and slope):
the residual ``e = h - DEM(x, y)`` (metres, along the vertical) with the standard deviation

    sigma^2 = sigma_dem^2 + (|grad DEM| * cell / 2)^2

(the DEM's stated precision and what interpolation loses on a slope over half a cell). Its
Jacobian with respect to the point is ``de/dP = (dh/dP) - DEM_x (dx/dP) - DEM_y (dy/dP)``, the rows of
``d map / d local`` at the point. The observation joins each point's 3 x 3 normal block before the
Schur elimination (``schur.reduced_camera_system``), so it costs nothing per image.

Which tie point lies on the ground: points where the nDSM (when given) is above ``max_ndsm_m`` are
not candidates (roofs, trees); robust solves weigh the observations with Huber's kernel, and after
every robust round the adjustment (``solve._surface_gate``) keeps those whose height from their rays
alone is within ``gate_sigmas`` of the DEM (cars, low vegetation, DEM gaps are left out). Heights: the DEM must be in the project's horizontal CRS
and height system (its heights are read like the project's, as the local frame reads them).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from aerotri.core.errors import CrsError
from aerotri.geom.local_frame import LocalFrame

log = logging.getLogger(__name__)


@dataclasses.dataclass
class HeightGrid:
    """A north-up height raster in memory: ``z[row, col]`` (NaN = no height), pixel centres at
    ``x0 + (col + 0.5) res``, ``y0 - (row + 0.5) res``."""

    z: np.ndarray
    x0: float
    y0: float
    res: float

    def sample(self, x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Height and its gradient (dz/dx, dz/dy) at map positions by cubic convolution (Catmull-Rom, 4 x 4
        cells): the surface and its slope are continuous, so Gauss-Newton steps of the points do not
        stall on the kinks a bilinear surface has at every cell edge. Exact for planes. NaN outside the
        grid or where one of the 16 cells has no height."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        u = (x - self.x0) / self.res - 0.5
        v = (self.y0 - y) / self.res - 0.5
        c0, r0 = np.floor(u), np.floor(v)
        tu, tv = u - c0, v - r0
        H, W = self.z.shape
        inside = (c0 >= 1) & (r0 >= 1) & (c0 < W - 2) & (r0 < H - 2)
        c = np.where(inside, c0, 1).astype(np.int64)
        r = np.where(inside, r0, 1).astype(np.int64)
        wu, du = _catmull_rom(tu)
        wv, dv = _catmull_rom(tv)
        h = np.zeros(x.shape)
        hu = np.zeros(x.shape)
        hv = np.zeros(x.shape)
        for i in range(4):
            for j in range(4):
                z = self.z[r - 1 + i, c - 1 + j]
                h += wv[i] * wu[j] * z
                hu += wv[i] * du[j] * z
                hv += dv[i] * wu[j] * z
        nan = np.full(x.shape, np.nan)
        ok = inside & np.isfinite(h)
        return np.where(ok, h, nan), np.where(ok, hu / self.res, nan), np.where(ok, -hv / self.res, nan)  # rows run south


def _catmull_rom(t: np.ndarray) -> tuple[list, list]:
    """Weights of the 4 taps (-1, 0, 1, 2) of cubic convolution at fraction ``t`` and their derivatives."""
    t2, t3 = t * t, t * t * t
    w = [(-t3 + 2 * t2 - t) / 2, (3 * t3 - 5 * t2 + 2) / 2, (-3 * t3 + 4 * t2 + t) / 2, (t3 - t2) / 2]
    d = [(-3 * t2 + 4 * t - 1) / 2, (9 * t2 - 10 * t) / 2, (-9 * t2 + 8 * t + 1) / 2, (3 * t2 - 2 * t) / 2]
    return w, d


def read_height_grid(path, project_crs, project_heights=None, what: str = "DEM", bounds=None) -> HeightGrid:
    """A height raster in the project's CRS and height system (``bounds`` = (xmin, ymin, xmax, ymax) in
    map units: read only that window, plus a cell). Refuses another horizontal CRS or height system."""
    import rasterio
    from rasterio.windows import from_bounds

    from aerotri.geom.crs import crs_label, parse_crs, same_horizontal, same_vertical, vertical_crs
    from aerotri.geom.raster_warp import open_north_up

    path = Path(path)
    with open_north_up(path, what, square=True, heights=True) as ds:
        crs = parse_crs(ds.crs.to_wkt(), f"{path} CRS")
        if not same_horizontal(crs, project_crs):
            raise CrsError(f"{path}: the {what} is in {crs_label(crs)}, the project in {crs_label(project_crs)}; "
                           f"warp it first (aerotri crs warp)")
        dem_v = vertical_crs(crs)
        if dem_v is not None and (project_heights is None or not same_vertical(dem_v, project_heights)):
            theirs = crs_label(project_heights) if project_heights is not None else "ellipsoidal heights"
            raise CrsError(f"{path}: the {what}'s heights are in {crs_label(dem_v)}, the project's in {theirs} "
                           "([project] heights); convert the heights first (aerotri crs warp)")
        if dem_v is None:
            log.info(f"{path}: the {what} declares no vertical CRS; its heights are taken as the project's")
        t = ds.transform
        if bounds is not None:
            xmin, ymin, xmax, ymax = bounds
            pad = 2 * t.a
            win = from_bounds(xmin - pad, ymin - pad, xmax + pad, ymax + pad, t).round_offsets().round_lengths()
            win = win.intersection(rasterio.windows.Window(0, 0, ds.width, ds.height))
        else:
            win = rasterio.windows.Window(0, 0, ds.width, ds.height)
        a = ds.read(1, window=win, masked=True).astype(float).filled(np.nan)
        wt = ds.window_transform(win)
    return HeightGrid(a, float(wt.c), float(wt.f), float(t.a))


@dataclasses.dataclass
class SurfaceControl:
    """The DEM (and optionally the nDSM) a block's tie points are held to, in the block's local frame."""

    dem: HeightGrid
    frame: LocalFrame
    sigma_m: float = 0.15  # stated precision of the DEM heights
    ndsm: HeightGrid | None = None
    max_ndsm_m: float = 1.0  # above this height over the ground a point is on an object
    gate_sigmas: float = 3.0
    sigma_factor: float = 1.0  # the variance component's factor on the stated sigmas (reweighting)

    def observe(self, coords_local: np.ndarray, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(e_m, J, sigma_m) for points (M, 3) in the local frame: residual height above the DEM (NaN where
        the DEM has none), its Jacobian (M, 3) with respect to the local coordinates (None unless
        ``jacobian``: it costs six more coordinate conversions per point), its sigma (M,)."""
        p = np.asarray(coords_local, dtype=float)
        m = self.frame.to_map(p)
        h, hx, hy = self.dem.sample(m[:, 0], m[:, 1])
        e = m[:, 2] - h
        sigma = self.sigma_factor * np.sqrt(self.sigma_m**2 + (np.hypot(hx, hy) * 0.5 * self.dem.res) ** 2)
        if not jacobian:
            return e, None, sigma
        # d map / d local: the inverse of the frame's Jacobian at the point
        J_ml = np.linalg.inv(self.frame.jacobian_local_from_map(m))
        J = J_ml[:, 2, :] - hx[:, None] * J_ml[:, 0, :] - hy[:, None] * J_ml[:, 1, :]
        return e, J, sigma

    def candidates(self, coords_local: np.ndarray) -> np.ndarray:
        """Points that may lie on the ground: inside the DEM and, with an nDSM, not on an object."""
        p = np.asarray(coords_local, dtype=float)
        m = self.frame.to_map(p)
        ok = np.isfinite(self.dem.sample(m[:, 0], m[:, 1])[0])
        if self.ndsm is not None:
            nd = self.ndsm.sample(m[:, 0], m[:, 1])[0]
            ok &= np.isfinite(nd) & (nd <= self.max_ndsm_m)
        return ok

def _robust_cost(x: np.ndarray, huber_k: float) -> float:
    """``sum rho(x)`` of whitened residual sizes: twice Huber's robust cost (``huber_k`` > 0), or x'x."""
    if huber_k > 0:
        return float(np.sum(np.where(x > huber_k, 2 * huber_k * x - huber_k**2, x * x)))
    return float(np.sum(x * x))


def whitened(surface: SurfaceControl, coords_local: np.ndarray, active: np.ndarray, huber_k: float = 0.0):
    """The surface observations of points ``coords_local`` (M, 3) as the Schur kernel takes them: whitened
    residual ``r`` (observed - computed, M) and Jacobian of the prediction ``B`` (M, 3), zero for the inactive
    ones; with ``huber_k`` > 0 scaled by the square root of Huber's weight. Also the cost (``surface_cost``)."""
    e, J, sigma = surface.observe(coords_local)
    use = np.asarray(active, dtype=bool) & np.isfinite(e) & np.isfinite(J).all(axis=1)
    r = np.where(use, -e / sigma, 0.0)
    B = np.where(use[:, None], J / sigma[:, None], 0.0)
    x = np.abs(r)
    cost = _robust_cost(x, huber_k)
    if huber_k > 0:
        big = x > huber_k
        s = np.where(big, np.sqrt(huber_k / np.where(big, x, 1.0)), 1.0)
        r, B = r * s, B * s[:, None]
    return np.ascontiguousarray(r), np.ascontiguousarray(B), cost


def surface_cost(surface: SurfaceControl, coords_local: np.ndarray, active: np.ndarray, huber_k: float = 0.0) -> float:
    """``sum rho(r)`` of the active points' whitened surface residuals (what ``whitened`` adds to the cost),
    without the Jacobian: the cost of every trial step of the solve."""
    e, _, sigma = surface.observe(coords_local, jacobian=False)
    use = np.asarray(active, dtype=bool) & np.isfinite(e)
    return _robust_cost(np.abs(np.where(use, e / sigma, 0.0)), huber_k)


@dataclasses.dataclass
class SurfaceStats:
    """What the surface control did, for the report (heights in metres)."""

    candidates: int  # tie points inside the DEM (and on the ground by the nDSM)
    used: int  # in the final solve
    rejected: int  # candidates the gate removed
    rms_m: float | None  # of the used points' residuals (point height - DEM)
    median_m: float | None
    rms_normalised: float | None  # of the used residuals in their sigmas (about 1 when the sigmas are right)
    sigma_m: float
    max_ndsm_m: float | None

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def surface_stats(surface: SurfaceControl, coords_local: np.ndarray, candidates: np.ndarray, active: np.ndarray
                  ) -> SurfaceStats:
    e, _, sigma = surface.observe(coords_local, jacobian=False)
    used = active & np.isfinite(e)
    v, w = e[used], e[used] / sigma[used]
    return SurfaceStats(int(candidates.sum()), int(used.sum()), int((candidates & ~active).sum()),
                        float(np.sqrt(np.mean(v * v))) if len(v) else None, float(np.median(v)) if len(v) else None,
                        float(np.sqrt(np.mean(w * w))) if len(w) else None,
                        surface.sigma_m, surface.max_ndsm_m if surface.ndsm is not None else None)
