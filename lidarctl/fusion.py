"""Fusion of the LiDAR classes with an orthophoto (``lidarctl classify ... --image DOM.tif [--nir BAND|FILE]``).

Runs on every tile after the LiDAR-only classification (``classify.classify_points``), on the tile's
points with their height above ground (HAG), so it works by tiles like ``classify``. The image is read
by the window of the tile only (nearest pixel at each point).

Spectral feature: greenness. With a near-infrared band, NDVI = (NIR - R) / (NIR + R); without one the
excess green of the chromatic coordinates, ExG = 2g - r - b (r = R / (R + G + B), ...). A point is
*green* above ``FusionParams.ndvi_min`` (``exg_min``).

Rules (ASPRS codes):
1. Vegetation: vegetation points (3, 4, 5) and unclassified points (1) that are green split at
   ``tree_min_height_m`` above ground (the seeds' 1 m grass/tree split): below -> low vegetation /
   grass 3, above -> tree 5 (medium vegetation joins the trees).
2. Ground (2): green ground is grass (3); ground that is not green, darker than ``road_intensity_ratio``
   times the tile's median ground intensity and smooth (3x3 plane RMS of the ground grid below
   ``road_roughness_m``) is a road candidate; candidate cells (``road_cell_m``, small gaps closed: road
   markings are bright) form connected regions, and a region is road surface (11) when it is shaped
   like a road: mean width 2 A / P between ``road_min_width_m`` and ``road_max_width_m`` and elongation
   P^2 / (4 A) at least ``road_min_elongation`` (a long strip L x w: about L / w; a square: 4). Points
   of the other ground stay bare ground (2). Water (9) stays water.
3. Building confirmation: a building (a connected region of building cells) whose points are mostly
   green (share above ``building_max_green``) is a tree the roof test took for a plane: its points
   become tree (5).
Without intensity (all zero) the road rule uses the image alone (not green, smooth, road-shaped).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
from scipy import ndimage

from aerotri.core.errors import CrsError, InputError, OptionError
from lidarctl.raster_ops import plane_rms

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

UNCLASSIFIED, GROUND, LOW_VEG, MED_VEG, HIGH_VEG, BUILDING, WATER, ROAD = 1, 2, 3, 4, 5, 6, 9, 11
_EIGHT = np.ones((3, 3), bool)


@dataclasses.dataclass(frozen=True)
class FusionParams:
    """Thresholds of the fusion rules (module docstring); lengths in metres.

    ``ndvi_min`` / ``exg_min`` are for 8-bit (gamma-encoded) orthophotos, whose NDVI is lower than that of
    reflectances (grass: about 0.23 in the simulator's tone-mapped ortho, 0.47 in reflectance); set on the
    simulator's tiny project, halfway between grass and the greenest non-vegetation (NDVI 0.0, ExG 0.05).
    """

    ndvi_min: float = 0.1
    exg_min: float = 0.1
    tree_min_height_m: float = 1.0
    road_intensity_ratio: float = 0.6
    road_roughness_m: float = 0.1
    road_cell_m: float = 1.0
    road_min_width_m: float = 2.5
    road_max_width_m: float = 30.0
    road_min_elongation: float = 6.0
    building_max_green: float = 0.5


@dataclasses.dataclass(frozen=True)
class ImageSource:
    """The orthophoto of a fusion: file, RGB band numbers, the NIR (a band of the same file or band 1 of
    another file on the same grid, or none) and metres per unit of its CRS (the cloud's CRS)."""

    path: str
    rgb_bands: tuple = (1, 2, 3)
    nir_path: str | None = None
    nir_band: int = 1
    xy_m: float = 1.0

    @property
    def has_nir(self) -> bool:
        return self.nir_path is not None


def open_image(path, nir=None, cloud_crs=None, xy_m: float = 1.0) -> ImageSource:
    """An ``ImageSource`` after the checks: readable, north-up, at least 3 bands, in the cloud's CRS
    (``cloud_crs``; an image without CRS is refused). ``nir``: a band number of the image, a file (band
    1, same grid), or None. Errors name the file or the option."""
    import rasterio

    from aerotri.geom.crs import crs_label, same_horizontal

    def opened(p, option):
        try:
            return rasterio.open(p)
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{p}: not a readable raster ({exc}) ({option})") from None

    with opened(path, "--image") as src:
        if src.count < 3:
            raise InputError(f"{path}: the orthophoto needs R, G, B bands (got {src.count} band(s))")
        if abs(src.transform.b) > 1e-12 or abs(src.transform.d) > 1e-12 or src.transform.e >= 0:
            raise InputError(f"{path}: only north-up images are supported (transform {tuple(src.transform)[:6]})")
        if src.crs is None:
            raise CrsError(f"{path}: the orthophoto has no CRS (it must be in the cloud's CRS)")
        import pyproj

        img_crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        if cloud_crs is not None and not same_horizontal(img_crs, cloud_crs):
            raise CrsError(f"{path}: the orthophoto is in {crs_label(img_crs)}, the cloud in {crs_label(cloud_crs)}; "
                           "give both in one CRS (aerotri crs warp)")
        count, shape, transform = src.count, src.shape, src.transform
    nir_path, nir_band = None, 1
    if nir is not None and str(nir).strip():
        text = str(nir).strip()
        if text.isdigit():
            nir_band = int(text)
            if not 4 <= nir_band <= count:
                raise OptionError(f"--nir {text}: expected a band number 4..{count} of {path} "
                                  "(bands 1-3 are R, G, B) or a file", param="--nir")
            nir_path = str(path)
        else:
            with opened(text, "--nir") as n:
                if n.shape != shape or n.transform != transform:
                    raise InputError(f"{text}: the NIR image must be on the grid of {path} (shape {n.shape} vs "
                                     f"{shape})")
            nir_path = text
    return ImageSource(str(path), (1, 2, 3), nir_path, nir_band, float(xy_m))


def _read_window(src, band, x, y, xy_m):
    """Values of ``band`` at the points (metres), nearest pixel; NaN outside the image or nodata."""
    from rasterio.windows import Window

    t = src.transform
    col = np.floor((x / xy_m - t.c) / t.a).astype(np.int64)
    row = np.floor((y / xy_m - t.f) / t.e).astype(np.int64)
    inside = (col >= 0) & (col < src.width) & (row >= 0) & (row < src.height)
    out = np.full(len(x), np.nan, np.float32)
    if not inside.any():
        return out
    c0, c1 = int(col[inside].min()), int(col[inside].max()) + 1
    r0, r1 = int(row[inside].min()), int(row[inside].max()) + 1
    a = src.read(band, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
    vals = a[row[inside] - r0, col[inside] - c0]
    out[inside] = np.ma.filled(vals.astype(np.float32), np.nan)
    return out


def sample_image(img: ImageSource, x: np.ndarray, y: np.ndarray):
    """(R, G, B as an (n, 3) float array, NIR (n,) or None) at the points (metres); NaN outside."""
    import rasterio

    with rasterio.open(img.path) as src:
        rgb = np.column_stack([_read_window(src, b, x, y, img.xy_m) for b in img.rgb_bands])
        nir = None
        if img.nir_path == img.path:
            nir = _read_window(src, img.nir_band, x, y, img.xy_m)
    if img.nir_path is not None and img.nir_path != img.path:
        with rasterio.open(img.nir_path) as src:
            nir = _read_window(src, img.nir_band, x, y, img.xy_m)
    return rgb, nir


def greenness(rgb: np.ndarray, nir: np.ndarray | None, p: FusionParams = FusionParams()):
    """(green bool, index): NDVI with a NIR band, else excess green of the chromatic coordinates; points
    without image values are not green."""
    rgb = np.asarray(rgb, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        if nir is not None:
            nir = np.asarray(nir, np.float64)
            index = (nir - rgb[:, 0]) / (nir + rgb[:, 0])
            threshold = p.ndvi_min
        else:
            s = rgb.sum(axis=1)
            r, g, b = (rgb[:, k] / s for k in range(3))
            index = 2 * g - r - b
            threshold = p.exg_min
    index = np.where(np.isfinite(index), index, np.nan)
    return np.nan_to_num(index, nan=-np.inf) > threshold, index


def road_shaped(mask: np.ndarray, cell_m: float, p: FusionParams = FusionParams()) -> np.ndarray:
    """Cells of the 8-connected regions of ``mask`` shaped like roads: mean width 2 A / P within
    [road_min_width_m, road_max_width_m] and elongation P^2 / (4 A) >= road_min_elongation."""
    labels, n = ndimage.label(mask, structure=_EIGHT)
    if n == 0:
        return np.zeros_like(mask, bool)
    ids = np.arange(1, n + 1)
    area = ndimage.sum_labels(np.ones_like(mask, float), labels, ids) * cell_m ** 2
    # Perimeter: cell edges between a region's cell and a cell outside it.
    padded = np.pad(labels, 1)
    edges = np.zeros(n + 1, np.int64)
    for axis in (0, 1):
        a, b = padded, np.roll(padded, 1, axis=axis)
        diff = a != b
        np.add.at(edges, a[diff], 1)
        np.add.at(edges, b[diff], 1)
    perim = edges[1:] * cell_m
    with np.errstate(invalid="ignore", divide="ignore"):
        width = 2.0 * area / perim
        elong = perim ** 2 / (4.0 * area)
    ok = (width >= p.road_min_width_m) & (width <= p.road_max_width_m) & (elong >= p.road_min_elongation)
    return np.r_[False, ok][labels]


@dataclasses.dataclass(frozen=True)
class Fusion:
    """What ``classify_points`` needs to fuse: the image and the rule thresholds."""

    image: ImageSource
    params: FusionParams = FusionParams()


def fuse(x, y, z, hag, cls, intensity, img: ImageSource, p: FusionParams = FusionParams()) -> np.ndarray:
    """Classes after the fusion rules (module docstring) for one tile's points (x, y, z in metres; ``hag``:
    height above the ground DEM; ``cls``: the LiDAR-only classes). Returns a new array."""
    cls = np.asarray(cls).copy()
    n = len(cls)
    if n == 0:
        return cls
    rgb, nir = sample_image(img, np.asarray(x, float), np.asarray(y, float))
    green, _ = greenness(rgb, nir, p)
    seen = np.isfinite(rgb).all(axis=1)

    # 1. vegetation split at the tree height
    veg = np.isin(cls, (LOW_VEG, MED_VEG, HIGH_VEG)) | ((cls == UNCLASSIFIED) & green)
    cls[veg & (hag < p.tree_min_height_m)] = LOW_VEG
    cls[veg & (hag >= p.tree_min_height_m)] = HIGH_VEG

    # 3. buildings that are mostly green are trees
    c = p.road_cell_m
    x0, y0 = float(np.min(x)), float(np.min(y))
    col = np.floor((x - x0) / c).astype(np.int64)
    row = np.floor((y - y0) / c).astype(np.int64)
    shape = (int(row.max()) + 1, int(col.max()) + 1)
    bld = cls == BUILDING
    if bld.any():
        bcell = np.zeros(shape, bool)
        bcell[row[bld], col[bld]] = True
        labels, nb = ndimage.label(bcell, structure=_EIGHT)
        lab = labels[row[bld], col[bld]]
        n_pts = np.bincount(lab, minlength=nb + 1)
        n_green = np.bincount(lab, weights=(green & seen)[bld], minlength=nb + 1)
        n_seen = np.bincount(lab, weights=seen[bld], minlength=nb + 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            tree_like = (n_seen > 0) & (n_green / np.maximum(n_seen, 1) > p.building_max_green) & (n_pts > 0)
        to_tree = np.flatnonzero(bld)[tree_like[lab]]
        cls[to_tree] = np.where(hag[to_tree] >= p.tree_min_height_m, HIGH_VEG, LOW_VEG)

    # 2. ground: grass, road, bare
    ground = cls == GROUND
    if ground.any():
        cls[ground & green] = LOW_VEG
        bare = ground & ~green & seen
        inten = np.asarray(intensity, float) if intensity is not None else np.zeros(n)
        if np.any(inten[ground] > 0):
            dark = inten < p.road_intensity_ratio * float(np.median(inten[ground]))
        else:
            dark = np.ones(n, bool)
        cand = bare & dark
        # roughness of the ground surface (mean ground height per cell, gaps filled by the neighbours' mean)
        zz = np.asarray(z, float)
        gsum = np.bincount(row[ground] * shape[1] + col[ground], weights=zz[ground], minlength=shape[0] * shape[1])
        gcnt = np.bincount(row[ground] * shape[1] + col[ground], minlength=shape[0] * shape[1])
        with np.errstate(invalid="ignore", divide="ignore"):
            gz = (gsum / gcnt).reshape(shape)
        has = np.isfinite(gz)
        if has.any():
            idx = ndimage.distance_transform_edt(~has, return_distances=False, return_indices=True)
            gz = gz[tuple(idx)]
            smooth = plane_rms(gz, c) < p.road_roughness_m
        else:
            smooth = np.zeros(shape, bool)
        ccount = np.zeros(shape, np.int64)
        np.add.at(ccount, (row[cand], col[cand]), 1)
        bcount = np.zeros(shape, np.int64)
        np.add.at(bcount, (row[bare], col[bare]), 1)
        # a cell is road-like when most of its bare ground points are candidates
        cells = (ccount * 2 > bcount) & (bcount > 0) & smooth
        # close the gaps of road markings (bright) and missing points
        cells = ndimage.binary_closing(cells, structure=_EIGHT, iterations=1) | cells
        road = road_shaped(cells, c, p)
        cls[bare & road[row, col]] = ROAD
    return cls
