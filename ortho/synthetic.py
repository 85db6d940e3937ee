"""Synthetic truth for tests and benchmarks: a textured orthophoto on a known DEM, and frames rendered
from it by inverse mapping (for each image pixel, intersect its ray with the DEM by iteration and sample
the orthophoto there).

Rectifying such a frame with the same camera, EO and DEM must reproduce the orthophoto; the
displacement measured by ``ortho.check`` is then the error of the rectification alone.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numba
import numpy as np

from aerotri.geom.camera import Camera, BrownCamera
from aerotri.geom.lens_kernels import to_normalised
from aerotri.geom.local_frame import CameraOnEarth, earth_dz
from aerotri.geom.rotation import FLIP_YZ
from ortho.dem import HeightRaster
from ortho.grid import OrthoGrid


def textured_orthophoto(height: int, width: int, bands: int = 3, seed: int = 0) -> np.ndarray:
    """Band-limited texture (uint8): blurred noise at several scales plus sharp-edged blocks blurred by 1 px."""
    rng = np.random.default_rng(seed)
    out = np.zeros((height, width, bands), np.float32)
    for b in range(bands):
        acc = np.zeros((height, width), np.float32)
        for sigma, amp in ((1.5, 1.0), (4.0, 1.6), (12.0, 2.5)):
            n = rng.standard_normal((height, width)).astype(np.float32)
            acc += amp * cv2.GaussianBlur(n, (0, 0), sigma) * sigma
        out[:, :, b] = acc
    # blocks (fields, roofs): piecewise constant patches give well-defined edges
    n_blocks = max(4, height * width // 4000)
    ys = rng.integers(0, height, n_blocks)
    xs = rng.integers(0, width, n_blocks)
    hs = rng.integers(4, 40, n_blocks)
    ws = rng.integers(4, 40, n_blocks)
    vals = rng.normal(0, 8, (n_blocks, bands)).astype(np.float32)
    blocks = np.zeros_like(out)
    for y, x, h, w, v in zip(ys, xs, hs, ws, vals):
        blocks[y:y + h, x:x + w] = v
    out += cv2.GaussianBlur(blocks, (0, 0), 1.0).reshape(out.shape)
    out -= out.mean()
    out *= 40.0 / max(float(out.std()), 1e-6)
    return np.clip(out + 128.0, 0, 255).astype(np.uint8)


def smooth_dem(bounds, res_m: float, base_m: float = 100.0, amplitude_m: float = 15.0, wavelength_m: float = 300.0,
               slope: float = 0.03) -> HeightRaster:
    """A smooth hill-and-valley DEM (sines plus a tilt) as a HeightRaster covering ``bounds``."""
    left, bottom, right, top = bounds
    w = int(math.ceil((right - left) / res_m))
    h = int(math.ceil((top - bottom) / res_m))
    x = left + (np.arange(w) + 0.5) * res_m
    y = top - (np.arange(h) + 0.5) * res_m
    X, Y = np.meshgrid(x, y)
    k = 2 * np.pi / wavelength_m
    Z = base_m + amplitude_m * np.sin(k * X) * np.cos(0.7 * k * Y) + slope * (X - left) - 0.5 * slope * (Y - bottom)
    return HeightRaster(Z.astype(np.float32), left, top, res_m, None, "synthetic DEM")


def add_box_buildings(dem: HeightRaster, n: int, size_m=(10.0, 25.0), height_m=(6.0, 20.0), seed: int = 0, bounds=None):
    """A DSM: ``dem`` plus ``n`` flat-roofed box buildings (inside ``bounds``, default the whole DEM) that do
    not touch each other; returns (dsm, list of (x0, y0, x1, y1, roof_z))."""
    rng = np.random.default_rng(seed)
    a = dem.heights_m.copy()
    h, w = a.shape
    left, bottom, right, top = bounds or dem.bounds
    boxes = []
    for _ in range(50 * n):
        if len(boxes) == n:
            break
        sx, sy = rng.uniform(*size_m, 2)
        cx = rng.uniform(left + sx, right - sx)
        cy = rng.uniform(bottom + sy, top - sy)
        gap = 6.0  # keep streets between buildings
        if any(cx + sx / 2 + gap > b[0] and cx - sx / 2 - gap < b[2] and cy + sy / 2 + gap > b[1] and cy - sy / 2 - gap < b[3]
               for b in boxes):
            continue
        c0 = int((cx - sx / 2 - dem.x_left_m) / dem.res_m)
        c1 = int((cx + sx / 2 - dem.x_left_m) / dem.res_m)
        r0 = int((dem.y_top_m - (cy + sy / 2)) / dem.res_m)
        r1 = int((dem.y_top_m - (cy - sy / 2)) / dem.res_m)
        roof = float(np.nanmax(a[r0:r1, c0:c1]) + rng.uniform(*height_m))
        a[r0:r1, c0:c1] = roof
        boxes.append((dem.x_left_m + c0 * dem.res_m, dem.y_top_m - r1 * dem.res_m, dem.x_left_m + c1 * dem.res_m,
                      dem.y_top_m - r0 * dem.res_m, roof))
    return HeightRaster(a, dem.x_left_m, dem.y_top_m, dem.res_m, dem.crs, "synthetic DSM"), boxes


@numba.njit(cache=True, inline="always")
def _sample_bilinear(a, u, v):
    h, w = a.shape
    if not (u >= 0 and v >= 0 and u <= w - 1 and v <= h - 1):
        return np.nan
    i = min(int(v), h - 2)
    j = min(int(u), w - 2)
    fv = v - i
    fu = u - j
    return (a[i, j] * (1 - fu) * (1 - fv) + a[i, j + 1] * fu * (1 - fv) + a[i + 1, j] * (1 - fu) * fv
            + a[i + 1, j + 1] * fu * fv)


SKIP_BLOCK_CELLS = 8  # the march's block of surface cells whose highest point it may skip down to


def _block_maxima(heights: np.ndarray, block: int = SKIP_BLOCK_CELLS) -> np.ndarray:
    """(ceil(h / block), ceil(w / block)) the highest surface value that bilinear samples at positions inside each
    block of cells can take (the block and 2 cells around it, as a bilinear sample reads the next cell); +inf for a
    block with a NaN there (a march must sample it: NaN ends the ray)."""
    from scipy.ndimage import maximum_filter

    h, w = heights.shape
    a = np.pad(np.where(np.isfinite(heights), heights, np.inf).astype(np.float64), ((2, 2 + block), (2, 2 + block)),
               mode="edge")  # (the edge once more past the end: each block has its window's centre)
    size = block + 4  # padded rows i * block .. i * block + block + 3: the window centred at i * block + size // 2
    m = maximum_filter(a, size=size, mode="nearest")
    return np.ascontiguousarray(m[size // 2::block, size // 2::block][:-(-h // block), :-(-w // block)])


@numba.njit(cache=True, inline="always")
def _skip_until(t, X, Y, d0, d1, d2, centre, inv_r, dem_x0, dem_y0, dem_res, h, w, maxima, block):
    """The ray parameter below which the march's samples from ``t`` on cannot meet the surface nor leave its
    block of cells (``_block_maxima``): its exit from the block and its descent to the block's highest point,
    less a margin; ``t`` itself (no skip) off the raster, in a block with NaN or when the ray is at that height."""
    u = (X - dem_x0) / dem_res - 0.5
    v = (dem_y0 - Y) / dem_res - 0.5
    if not (u >= 0 and v >= 0 and u <= w - 1 and v <= h - 1):
        return t
    bi = int(v) // block
    bj = int(u) // block
    top = maxima[bi, bj]
    if not top < np.inf:
        return t
    t_end = np.inf  # leaving the block's cells (and the raster's sampled area)
    du = d0 / dem_res
    dv = -d1 / dem_res
    if du > 0:
        t_end = min(t_end, t + (min((bj + 1) * block, w - 1) - u) / du)
    elif du < 0:
        t_end = min(t_end, t + (bj * block - u) / du)
    if dv > 0:
        t_end = min(t_end, t + (min((bi + 1) * block, h - 1) - v) / dv)
    elif dv < 0:
        t_end = min(t_end, t + (bi * block - v) / dv)
    # descent to the top: s d2 > earth_dz(s d0, s d1, top - cz) while A s^2 + d2 s + C > 0 (earth_dz linear in its
    # height, minus the curvature's drop), its first root by the stable form
    beta = top - centre[2]
    gamma = 1.0 - beta * inv_r
    C = -beta * gamma
    if C <= 0:
        return t
    A = 0.5 * (d0 * d0 + d1 * d1) * inv_r * gamma
    disc = d2 * d2 - 4.0 * A * C
    t_top = np.inf if disc < 0 else 2.0 * C / (-d2 + math.sqrt(disc))
    t_end = min(t_end, t_top)
    return t_end - 1e-7 * abs(t_end) - 1e-9


@numba.njit(parallel=True, cache=True)
def _render_kernel(reference, surface, pose, cam, out, valid, *, z_start, march, z_top, maxima, block):
    """The frame ``out`` (H, W, B) and its ``valid`` mask: each pixel's ray (camera ``pose`` (centre, Rcv: camera
    (cv) to object axes, the earth's 1 / radius: the ray is straight in (dx, dy, ``earth_dz``), see
    ``aerotri.geom.local_frame.CameraOnEarth``), ``cam``: ``Camera.kernel_params``, a NamedTuple: numba's parallel
    loops do not take one inside a tuple) meets the raster ``surface`` (heights, x_left, y_top, res; m),
    at the fixed point of Z from ``z_start`` or (``march``) marching down from ``z_top``, and takes the bilinear
    sample of the orthophoto ``reference`` (bands, x_left, y_top, res) there."""
    ref, ref_x0, ref_y0, ref_res = reference
    dem, dem_x0, dem_y0, dem_res = surface
    centre, Rcv, inv_r = pose
    dem_h, dem_w = dem.shape
    H, W, B = out.shape
    for r in numba.prange(H):
        for c in range(W):
            xn, yn = to_normalised(cam, float(c), float(r), 20)  # as Camera.pixel_to_normalized
            # object-space ray d = Rcv @ (xn, yn, 1)
            d0 = Rcv[0, 0] * xn + Rcv[0, 1] * yn + Rcv[0, 2]
            d1 = Rcv[1, 0] * xn + Rcv[1, 1] * yn + Rcv[1, 2]
            d2 = Rcv[2, 0] * xn + Rcv[2, 1] * yn + Rcv[2, 2]
            if d2 >= 0:
                continue
            Z = z_start
            X = centre[0]
            Y = centre[1]
            ok = True
            if march:
                # first crossing below the surface, stepping 0.25 cell along the ray from above the top
                step = 0.25 * dem_res / math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                t = (z_top - centre[2]) / d2
                t_prev = t
                hit = False
                n = 0
                while n < 200000:
                    X = centre[0] + t * d0
                    Y = centre[1] + t * d1
                    # the samples before t_skip are neither NaN nor under the surface: stepped over on the same
                    # sequence of t as one by one, so that the frames are the same (a near-nadir ray took about 400
                    # samples from the top of the buildings down to the ground)
                    t_skip = _skip_until(t, X, Y, d0, d1, d2, centre, inv_r, dem_x0, dem_y0, dem_res, dem_h, dem_w,
                                         maxima, block)
                    if t < t_skip:
                        while n < 200000 and t < t_skip:
                            t_prev = t
                            t += step
                            n += 1
                        continue
                    zs = _sample_bilinear(dem, (X - dem_x0) / dem_res - 0.5, (dem_y0 - Y) / dem_res - 0.5)
                    if zs != zs:
                        break
                    if t * d2 <= earth_dz(t * d0, t * d1, zs - centre[2], inv_r):
                        hit = True
                        break
                    t_prev = t
                    t += step
                    n += 1
                if not hit:
                    continue
                lo = t_prev
                hi = t
                for _ in range(30):
                    tm = 0.5 * (lo + hi)
                    X = centre[0] + tm * d0
                    Y = centre[1] + tm * d1
                    zs = _sample_bilinear(dem, (X - dem_x0) / dem_res - 0.5, (dem_y0 - Y) / dem_res - 0.5)
                    if tm * d2 <= earth_dz(tm * d0, tm * d1, zs - centre[2], inv_r):
                        hi = tm
                    else:
                        lo = tm
                X = centre[0] + hi * d0
                Y = centre[1] + hi * d1
            for _ in range(0 if march else 60):
                t = earth_dz(X - centre[0], Y - centre[1], Z - centre[2], inv_r) / d2  # X, Y: the last estimate
                X = centre[0] + t * d0
                Y = centre[1] + t * d1
                Zn = _sample_bilinear(dem, (X - dem_x0) / dem_res - 0.5, (dem_y0 - Y) / dem_res - 0.5)
                if Zn != Zn:
                    ok = False
                    break
                if abs(Zn - Z) < 1e-5:
                    Z = Zn
                    break
                Z = Zn
            if not ok:
                continue
            if not march:
                t = earth_dz(X - centre[0], Y - centre[1], Z - centre[2], inv_r) / d2
                X = centre[0] + t * d0
                Y = centre[1] + t * d1
            u = (X - ref_x0) / ref_res - 0.5
            v = (ref_y0 - Y) / ref_res - 0.5
            if not (u >= 0 and v >= 0 and u <= ref.shape[1] - 1 and v <= ref.shape[0] - 1):
                continue
            for b in range(B):
                val = _sample_bilinear(ref[:, :, b], u, v)
                out[r, c, b] = min(255.0, max(0.0, val + 0.5))
            valid[r, c] = True


def render_frame(reference: np.ndarray, reference_grid: OrthoGrid, dem: HeightRaster, camera: Camera, centre_m, R,
                 *, march: bool = False, crs=None, maxima: np.ndarray | None = None):
    """Render a frame (height, width, bands) uint8 and its validity mask from a ground-truth orthophoto.

    ``march``: intersect rays by marching (needed for a DSM with vertical walls); otherwise by
    fixed-point iteration on Z (smooth DEMs). The world is in ``crs`` (default the reference grid's; None: map
    coordinates taken as a Cartesian frame): the camera sees it through the ENU frame at its centre, as a camera
    over the earth does and ``ortho.rectify`` maps it (``aerotri.geom.local_frame.CameraOnEarth``), ``R`` referring
    to the grid axes at the centre as eo.txt does. ``maxima``: ``_block_maxima`` of ``dem`` when the caller renders
    several frames on it (made here otherwise).
    """
    ref = np.ascontiguousarray(reference if reference.ndim == 3 else reference[:, :, None]).astype(np.float32)
    out = np.zeros((camera.height, camera.width, ref.shape[2]), np.uint8)
    valid = np.zeros((camera.height, camera.width), np.bool_)
    crs = reference_grid.crs if crs is None else crs
    C = np.asarray(centre_m, float)
    z0 = float(np.nanmean(dem.heights_m))
    if crs is None:
        Rcv, inv_r = np.ascontiguousarray(np.asarray(R, float) @ FLIP_YZ), 0.0
    else:  # camera-frame coordinates M (dx, dy, earth_dz): the rays (dx, dy, earth_dz) = t M^-1 (xn, yn, 1)
        earth = CameraOnEarth(crs, C, R)
        Rcv, inv_r = np.ascontiguousarray(np.linalg.inv(earth.M)), earth.inv_radius
    cam = camera.kernel_params()
    _render_kernel((ref, reference_grid.x_left_m, reference_grid.y_top_m, reference_grid.res_m),
                   (dem.heights_m, dem.x_left_m, dem.y_top_m, dem.res_m), (C, Rcv, float(inv_r)), cam,
                   out, valid, z_start=z0, march=bool(march), z_top=float(np.nanmax(dem.heights_m)) + 0.1,
                   maxima=(_block_maxima(dem.heights_m) if maxima is None else maxima) if march else np.zeros((1, 1)),
                   block=SKIP_BLOCK_CELLS)
    return (out if reference.ndim == 3 else out[:, :, 0]), valid


def write_geotiff(path, array: np.ndarray, x_left_m: float, y_top_m: float, res_m: float, crs, *, nodata=None) -> None:
    """A north-up GeoTIFF from (rows, cols[, bands])."""
    import rasterio
    from rasterio.transform import Affine

    from aerotri.core.atomic import atomic_path

    a = array if array.ndim == 3 else array[:, :, None]
    with atomic_path(path) as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=a.shape[1], height=a.shape[0], count=a.shape[2],
                           dtype=a.dtype.name, crs=crs, transform=Affine(res_m, 0, x_left_m, 0, -res_m, y_top_m),
                           nodata=nodata) as dst:
            dst.write(np.moveaxis(a, -1, 0))


@dataclasses.dataclass(frozen=True)
class SyntheticProject:
    """``write_synthetic_project``'s truth: the folder, camera, exterior orientations, the buildings (boxes x0, y0,
    x1, y1, roof height, metres), the pixel size (m) and the truth orthophoto's grid."""

    root: Path
    camera: object  # aerotri.geom.camera.BrownCamera
    eo: object  # aerotri.geom.eo.ExteriorOrientations
    buildings: list
    res_m: float
    truth_grid: object  # ortho.grid.OrthoGrid


def write_synthetic_project(root, *, strips: int = 2, frames_per_strip: int = 3, buildings: int = 20, seed: int = 7,
                            res_m: float = 0.2, crs: str = "EPSG:32649") -> SyntheticProject:
    """A small project folder with truth, for tests: textured true orthophoto, smooth DEM, box buildings.

    Camera 600 x 400 px, 12 um, f 24 mm with distortion, 400 m above ground (GSD 0.2 m); strips run
    north-south (image rows along track), 60 % forward and about 33 % side overlap. Frames are rendered
    from the truth orthophoto on the DSM (buildings lean in the images). Writes project.toml,
    camera.toml, at/eo.txt (= truth), images/, lidar_out/dem.tif + ndsm.tif, truth/{eo.txt, dem.tif,
    dsm.tif, ortho.tif, roof_corners.csv}. Returns the folder and the truth (``SyntheticProject``).
    """
    from aerotri.geom.eo import ExteriorOrientations, write_eo
    from aerotri.core.atomic import write_text_atomic

    root = Path(root)
    rng = np.random.default_rng(seed)
    e0, n0, base = 452000.0, 3407000.0, 300.0
    width_m, height_m = 200.0 + 80.0 * (strips - 1), 160.0 + 32.0 * (frames_per_strip - 1)
    grid = OrthoGrid(None, e0, n0 + height_m, res_m, int(width_m / res_m), int(height_m / res_m))
    ortho_truth = textured_orthophoto(grid.height, grid.width, 3, seed)
    margin = 40.0
    dem = smooth_dem((e0 - margin, n0 - margin, e0 + width_m + margin, n0 + height_m + margin), 0.5, base_m=base,
                     amplitude_m=6.0, wavelength_m=250.0, slope=0.02)
    # buildings inside the central part of the scene only (kept inside the image overlaps)
    inner = HeightRaster(dem.heights_m, dem.x_left_m, dem.y_top_m, dem.res_m)
    dsm, boxes = add_box_buildings(inner, buildings, size_m=(8.0, 16.0), height_m=(8.0, 15.0), seed=seed,
                                   bounds=(e0 + 30, n0 + 30, e0 + width_m - 30, n0 + height_m - 30)) if buildings \
        else (dem, [])
    camera = BrownCamera(focal_mm=24.0, pixel_um=12.0, width=600, height=400, ppx_mm=0.03, ppy_mm=-0.02, k1=-0.02,
                         k2=0.004, name="synthetic")
    agl = camera.focal_mm * 1e-3 * res_m / (camera.pixel_um * 1e-6)
    ids, centres, opks = [], [], []
    for s in range(strips):
        x = e0 + 100.0 + 80.0 * s
        for k in range(frames_per_strip):
            y = n0 + 80.0 + 32.0 * k
            if s % 2:
                y = n0 + 80.0 + 32.0 * (frames_per_strip - 1 - k)
            z = base + agl + rng.normal(0, 2.0)
            ids.append(f"s{s + 1:02d}_{k + 1:03d}")
            centres.append([x + rng.normal(0, 1.0), y + rng.normal(0, 1.0), z])
            opks.append([rng.normal(0, 1.0), rng.normal(0, 1.0), 180.0 * (s % 2) + rng.normal(0, 2.0)])
    eo = ExteriorOrientations(ids, np.array(centres), np.array(opks))
    (root / "images").mkdir(parents=True, exist_ok=True)
    write_text_atomic(root / "project.toml", f'[project]\nname = "synthetic"\ncrs = "{crs}"\n')
    write_text_atomic(root / "camera.toml", camera.to_toml())
    write_eo(root / "at" / "eo.txt", eo)
    # the camera at/eo.txt belongs to, as an adjustment writes it beside its orientations (the true one)
    write_text_atomic(root / "at" / "camera.toml", camera.to_toml())
    write_eo(root / "truth" / "eo.txt", eo)
    maxima = _block_maxima(dsm.heights_m) if buildings else None  # one DSM for every frame
    for i, iid in enumerate(ids):
        img, _ = render_frame(ortho_truth, grid, dsm, camera, eo.centre_m[i], eo.rotation(i), march=bool(buildings),
                              crs=crs, maxima=maxima)
        cv2.imwrite(str(root / "images" / f"{iid}.tif"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    for name, hr in (("lidar_out/dem.tif", dem), ("truth/dem.tif", dem), ("truth/dsm.tif", dsm)):
        write_geotiff(root / name, hr.heights_m, hr.x_left_m, hr.y_top_m, hr.res_m, crs)
    write_geotiff(root / "lidar_out" / "ndsm.tif", dsm.heights_m - dem.heights_m, dem.x_left_m, dem.y_top_m, dem.res_m, crs)
    write_geotiff(root / "truth" / "ndsm.tif", dsm.heights_m - dem.heights_m, dem.x_left_m, dem.y_top_m, dem.res_m, crs)
    write_geotiff(root / "truth" / "ortho.tif", ortho_truth, grid.x_left_m, grid.y_top_m, res_m, crs)
    # the roof corners (as the simulator's truth/roof_corners.csv): where the DOM check measures the roofs
    write_text_atomic(root / "truth" / "roof_corners.csv", "id,x,y,z\n" + "".join(
        f"B{k + 1:03d}_{j + 1},{x:.3f},{y:.3f},{z:.3f}\n" for k, (x0, y0, x1, y1, z) in enumerate(boxes)
        for j, (x, y) in enumerate(((x0, y0), (x1, y0), (x1, y1), (x0, y1)))))
    return SyntheticProject(root, camera, eo, boxes, res_m, grid)
