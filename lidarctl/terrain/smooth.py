"""Edge-preserving DEM smoothing: anisotropic diffusion of second or fourth order (seed 002 §3.1).

Fourth order (the default; You & Kaveh 2000): each iteration moves every cell by ``-step`` times the
Laplacian of g(L) L, where L is the cell's 4-neighbour Laplacian (the sum of the height differences to
its four neighbours, metres) and g(L) = exp(-(L / edge)^2). Its steady states are planes: slopes,
embankment sides and the valley side stay straight and the breaklines between them (crests, toes,
road embankments) stay sharp, where second-order diffusion rounds every crease like a Gaussian.
Stable for ``step`` <= 1/32; a cell's result after n iterations depends on the cells within 2n.

Second order (Perona & Malik 1990): each iteration moves every cell towards its four neighbours by ``step`` times the sum of the height
differences, each weighted by the conductance g(d) = exp(-(d / edge)^2): differences well below
``edge`` (noise) diffuse almost as in the heat equation (Gaussian smoothing), differences above it
(breaklines, embankments, the valley edge) not at all (g = 0.018 at twice the edge height). Perona &
Malik (1990), their first conductance, which keeps high-contrast edges (their second, 1/(1 + (d/edge)^2),
still let a 3 m step leak over 20 iterations at a 0.5 m edge). It keeps steps (walls, cliffs) but
rounds creases. Stable for ``step`` <= 0.25; reach n cells after n iterations.

Conventions: heights and ``edge_m`` in metres (a DEM in feet is converted by its CRS's height unit);
nodata cells keep their value and exchange nothing with their neighbours. A cell takes part along the
rows (or the columns) only where both its neighbours in that direction hold data: at the raster's
border and around nodata the terrain is continued as the plane it is, instead of being bent flat as a
closed boundary would (a tilted plane is then a steady state of both orders, up to the border). As a cell's result depends only on the cells within its reach, a
raster smoothed window by window with a halo of that reach is identical to the raster smoothed whole:
that is how large rasters are processed.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numba
import numpy as np

from aerotri.core.errors import OptionError

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

DEFAULT_WINDOW_PX = 2048


MAX_STEP = {2: 0.25, 4: 1.0 / 32.0}


@dataclasses.dataclass(frozen=True, kw_only=True)
class DiffusionSettings:
    """``order``: 4 (keeps planes and creases) or 2 (keeps steps); ``edge_m``: the height measure at which the
    conductance is 1/e, i.e. what counts as a breakline rather than noise: for order 4 the 4-neighbour
    Laplacian (m), for order 2 the height difference between neighbouring cells (m); ``iterations``:
    diffusion steps; ``step``: the time step (at most 1/32 for order 4, 0.25 for order 2; None: the most
    that is stable with a margin, 0.03 / 0.2)."""

    order: int = 4
    edge_m: float = 1.0
    iterations: int = 100
    step: float | None = None

    @property
    def time_step(self) -> float:
        return self.step if self.step is not None else (0.03 if self.order == 4 else 0.2)

    @property
    def reach_px(self) -> int:
        """Cells a result depends on in each direction (the halo of a window)."""
        return int(self.iterations) * (2 if self.order == 4 else 1)

    def validate(self) -> None:
        if self.order not in MAX_STEP:
            raise OptionError(f"the diffusion order is 2 or 4, got {self.order}", param="--order")
        if not (np.isfinite(self.edge_m) and self.edge_m > 0):
            raise OptionError(f"the edge height must be a positive number of metres, got {self.edge_m}", param="--edge-m")
        if self.iterations < 1:
            raise OptionError(f"at least one iteration, got {self.iterations}", param="--iterations")
        if not (0 < self.time_step <= MAX_STEP[self.order]):
            raise OptionError(f"the diffusion step of order {self.order} must be in (0, {MAX_STEP[self.order]:g}] to be "
                              f"stable, got {self.time_step}", param="--step")


@numba.njit(cache=True, parallel=True)
def _diffuse(z, valid, iterations, step, inv_edge2):
    """``iterations`` Perona-Malik steps on ``z`` (float64, modified in place) where ``valid``."""
    ny, nx = z.shape
    nxt = z.copy()
    for _ in range(iterations):
        for i in numba.prange(ny):
            for j in range(nx):
                if not valid[i, j]:
                    continue
                c = z[i, j]
                flux = 0.0
                if 0 < i < ny - 1 and valid[i - 1, j] and valid[i + 1, j]:
                    d1, d2 = z[i - 1, j] - c, z[i + 1, j] - c
                    flux += d1 * math.exp(-d1 * d1 * inv_edge2) + d2 * math.exp(-d2 * d2 * inv_edge2)
                if 0 < j < nx - 1 and valid[i, j - 1] and valid[i, j + 1]:
                    d1, d2 = z[i, j - 1] - c, z[i, j + 1] - c
                    flux += d1 * math.exp(-d1 * d1 * inv_edge2) + d2 * math.exp(-d2 * d2 * inv_edge2)
                nxt[i, j] = c + step * flux
        for i in numba.prange(ny):
            for j in range(nx):
                z[i, j] = nxt[i, j]
    return z


@numba.njit(cache=True, parallel=True)
def _laplacian(z, valid, out, weighted, inv_edge2):
    """Second differences along the rows and the columns, each where both neighbours are valid (elsewhere the
    surface continues as a plane), summed into ``out`` (times exp(-(L/edge)^2) when ``weighted``)."""
    ny, nx = z.shape
    for i in numba.prange(ny):
        for j in range(nx):
            if not valid[i, j]:
                continue
            c2 = 2.0 * z[i, j]
            s = 0.0
            if 0 < i < ny - 1 and valid[i - 1, j] and valid[i + 1, j]:
                s += z[i - 1, j] + z[i + 1, j] - c2
            if 0 < j < nx - 1 and valid[i, j - 1] and valid[i, j + 1]:
                s += z[i, j - 1] + z[i, j + 1] - c2
            out[i, j] = s * math.exp(-s * s * inv_edge2) if weighted else s


@numba.njit(cache=True, parallel=True)
def _diffuse4(z, valid, iterations, step, inv_edge2):
    """``iterations`` fourth-order steps on ``z`` (float64, modified in place) where ``valid``."""
    ny, nx = z.shape
    g = np.zeros_like(z)
    lap = np.zeros_like(z)
    for _ in range(iterations):
        _laplacian(z, valid, g, True, inv_edge2)
        _laplacian(g, valid, lap, False, inv_edge2)
        for i in numba.prange(ny):
            for j in range(nx):
                if valid[i, j]:
                    z[i, j] -= step * lap[i, j]
    return z


def anisotropic_diffusion(dem_m: np.ndarray, params: DiffusionSettings = DiffusionSettings(), valid=None) -> np.ndarray:
    """The DEM (2-D heights in metres; NaN or ``~valid`` = nodata) after Perona-Malik diffusion; nodata stays
    NaN. Returns float64."""
    params.validate()
    z = np.asarray(dem_m, dtype=np.float64)
    ok = np.isfinite(z) if valid is None else (np.asarray(valid, bool) & np.isfinite(z))
    work = np.where(ok, z, 0.0)
    kernel = _diffuse4 if params.order == 4 else _diffuse
    out = kernel(work, ok, int(params.iterations), float(params.time_step), 1.0 / params.edge_m ** 2)
    return np.where(ok, out, np.nan)


def gaussian_equivalent_sigma_px(params: DiffusionSettings) -> float:
    """Order 2: the Gaussian (in cells) that linear diffusion of the same steps gives, sqrt(2 * step *
    iterations) (the reach of the smoothing away from edges)."""
    if params.order != 2:
        raise ValueError("a Gaussian equivalent exists for second-order diffusion only")
    return float(np.sqrt(2.0 * params.time_step * params.iterations))


@dataclasses.dataclass(frozen=True)
class SmoothResult:
    path: Path
    cells: int
    valid_cells: int
    windows: int
    rms_change_m: float  # RMS of (smoothed - input) over the valid cells
    max_change_m: float


def smooth_dem(in_path, out_path, params: DiffusionSettings = DiffusionSettings(),
               window_px: int = DEFAULT_WINDOW_PX) -> SmoothResult:
    """Smooth a DEM GeoTIFF into a float32 COG by windows of ``window_px`` with a halo of the diffusion's reach
    (identical to smoothing it whole). Heights are converted to metres by the raster CRS's height unit for
    the edge test and written back in the input's unit; nodata, CRS, transform, band unit and tags kept."""
    import rasterio
    from rasterio.windows import Window

    from aerotri.core.atomic import temporary_dir
    from lidarctl.terrain.dem_io import open_dem, write_dem_cog

    params.validate()
    if window_px < 16:
        raise OptionError(f"windows of at least 16 cells, got {window_px}", param="--window-px")
    in_path, out_path = Path(in_path), Path(out_path)
    src, z_m = open_dem(in_path, out_path, say_unit=True)
    with src:
        nodata = src.nodata
        profile = dict(driver="GTiff", width=src.width, height=src.height, count=1, dtype="float32", crs=src.crs,
                       transform=src.transform, nodata=nodata if nodata is not None else -9999.0, tiled=True,
                       blockxsize=512, blockysize=512, compress="DEFLATE", predictor=3, zlevel=1, bigtiff="IF_SAFER")
        halo = params.reach_px
        tmpdir = temporary_dir(out_path.parent if out_path.parent != Path("") else Path("."), out_path.name)
        n_valid = 0
        sum_d2 = 0.0
        max_d = 0.0
        n_windows = 0
        from aerotri.core.limits import check_task_count

        check_task_count(math.ceil(src.height / window_px) * math.ceil(src.width / window_px),
                         f"{in_path}: {src.width} x {src.height} cells in windows of {window_px}", "--window-px",
                         "use a larger --window-px")
        try:
            work = tmpdir / "smoothed.tif"
            with rasterio.open(work, "w", **profile) as dst:
                if src.units and src.units[0]:
                    dst.units = (src.units[0],)
                if src.descriptions and src.descriptions[0]:
                    dst.set_band_description(1, src.descriptions[0])
                from lidarctl.terrain.dem_io import HYDRO_TAG

                tags = src.tags()
                if HYDRO_TAG in tags:
                    # trial-hydro: the lakes flat at 800.163 m came out 799.58 .. 801.09 m, 8 cells in from the shore
                    log.warning(f"{in_path} is hydro-flattened ({tags[HYDRO_TAG]}): smoothing moves its flat water "
                                "surfaces and their shores; smooth first, then hydro-flatten the smoothed DEM")
                    tags.pop(HYDRO_TAG)
                dst.update_tags(**tags)
                for r0 in range(0, src.height, window_px):
                    for c0 in range(0, src.width, window_px):
                        h, w = min(window_px, src.height - r0), min(window_px, src.width - c0)
                        # the halo outside the raster reads as nodata: the border is closed, as for the whole raster
                        big = Window(c0 - halo, r0 - halo, w + 2 * halo, h + 2 * halo)
                        a = src.read(1, window=big, boundless=True, masked=True)
                        z = a.filled(np.nan).astype(np.float64) * z_m
                        out = anisotropic_diffusion(z, params)
                        core = (slice(halo, halo + h), slice(halo, halo + w))
                        zc, oc = z[core], out[core]
                        ok = np.isfinite(zc)
                        d = (oc - zc)[ok]
                        n_valid += int(ok.sum())
                        sum_d2 += float(np.sum(d * d))
                        max_d = max(max_d, float(np.abs(d).max()) if d.size else 0.0)
                        res = np.where(ok, oc / z_m, profile["nodata"]).astype(np.float32)
                        dst.write(res, 1, window=Window(c0, r0, w, h))
                        n_windows += 1
            write_dem_cog(work, out_path)
        finally:
            import shutil

            shutil.rmtree(tmpdir, ignore_errors=True)
        cells = src.width * src.height
    rms = float(np.sqrt(sum_d2 / n_valid)) if n_valid else 0.0
    log.debug(f"{in_path} -> {out_path}: {n_valid:,} of {cells:,} cells smoothed in {n_windows} window(s); "
             f"changes RMS {rms:.3f} m, max {max_d:.3f} m (order {params.order}, edge {params.edge_m:g} m, "
              f"{params.iterations} iterations)")
    return SmoothResult(out_path, cells, n_valid, n_windows, rms, max_d)
