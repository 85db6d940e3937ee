"""Fusion of the LiDAR classes with an orthophoto (``lidarctl classify ... --image DOM.tif [--nir BAND|FILE]``).

Runs on every tile after the LiDAR-only classification (``classify.classify_points``), on the tile's
points with their height above ground (HAG), so it works by tiles like ``classify``. The image is read
by the window of the tile only (nearest pixel at each point).

Spectral feature: greenness. With a near-infrared band, NDVI = (NIR - R) / (NIR + R); without one the
excess green of the chromatic coordinates, ExG = 2g - r - b (r = R / (R + G + B), ...). A point is
*green* above ``FusionSettings.ndvi_min`` (``exg_min``).

Rules (ASPRS codes):
1. Vegetation: vegetation points (3, 4, 5) and unclassified points (1) that are green split at
   ``tree_min_height_m`` above ground (the seeds' 1 m grass/tree split): below -> low vegetation /
   grass 3, above -> tree 5 (medium vegetation joins the trees).
2. Ground (2): green ground is grass (3); ground that is not green, darker than ``road_intensity_ratio``
   times the tile's median ground intensity and smooth (3x3 plane RMS of the ground grid below
   ``road_roughness_m``) is a road candidate; candidate cells (``road_cell_m``, small gaps closed: road
   markings are bright) form connected regions, and a region is road surface (11) when it is shaped
   like a road: mean width 2 A / P between ``road_min_width_m`` and ``road_max_width_m`` and elongation
   P^2 / (4 A) at least ``road_min_elongation`` (a long strip L x w: about L / w; a square: 4), and it is
   bounded by land: a region more than ``road_max_water_rim_share`` of whose rim cells with returns hold
   water returns and whose ground lies at the water's level (within ``water_level_tol_m`` of the nearest water
   return on its rim; a causeway's road stands above it) lies in the water (a riffle or rapid the LiDAR water
   rule left as ground: dark, smooth, not green, shaped by the river) and stays ground (``in_water``).
   Points of the other ground stay bare ground (2). Water (9) stays water.
3. Building confirmation, per candidate (a connected region of building cells of ``road_cell_m``):
   a. mostly green (share of its points above ``building_max_green``): a tree the roof test took for a
      plane;
   b. penetrable (first-minus-last return height, below): the share of its cells whose FML is at least
      ``building_max_fml_m`` above ``building_max_fml_share``: pulses went through it, a crown;
   c. straight lines (seed 000): Canny edges of the orthophoto's grey values, straight segments by the
      probabilistic Hough transform (OpenCV), segments shorter than ``building_min_line_m`` dropped;
      a segment belongs to the candidate its midpoint lies in or within ``building_line_reach_m`` of
      (roof outlines and ridges; relief displacement moves them off the LiDAR outline). A candidate
      with fewer than ``building_min_lines`` segments is not a building (0: no line check). Candidates
      the image does not cover are kept.
   Points of a rejected candidate get the class the other rules give: green -> tree (5) or grass (3)
   by height; not green -> tree (5) above ``tree_min_height_m`` (an object that is not a building is
   vegetation, as in the LiDAR-only rules), else ground (2, then the ground rules below).
Without intensity (all zero) the road rule uses the image alone (not green, smooth, road-shaped).

First-minus-last return height (FML) per cell: the highest first return minus the lowest last return
of the cell's pulses that have more than one return; cells without such pulses have 0 (so a cloud of
single returns gives 0 everywhere and rule 3b never fires). Roofs stop the pulses (0 but at the
eaves); canopy lets them through to the ground (the tree height).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from aerotri.core.errors import CrsError, InputError, OptionError
from lidarctl.raster_ops import plane_rms

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

UNCLASSIFIED, GROUND, LOW_VEG, MED_VEG, HIGH_VEG, BUILDING, WATER, ROAD = 1, 2, 3, 4, 5, 6, 9, 11
_EIGHT = np.ones((3, 3), bool)


@dataclasses.dataclass(frozen=True)
class FusionSettings:
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
    # A road is bounded by land (verges, kerbs, quays); a road-shaped patch whose border is mostly water lies in
    # the water (a riffle's returns the LiDAR water rule left as ground): a majority, no fitted value.
    road_max_water_rim_share: float = 0.5
    building_max_green: float = 0.5
    building_max_fml_m: float = 2.0
    building_max_fml_share: float = 0.3
    building_min_lines: int = 2
    building_min_line_m: float = 2.0
    building_line_reach_m: float = 1.5
    canny_low: float = 50.0
    canny_high: float = 150.0


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

    from aerotri.geom.crs.definition import crs_label, same_horizontal

    def opened(p, option):
        try:
            return rasterio.open(p)
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{p}: not a readable raster ({exc}) ({option})") from None

    from aerotri.geom.inputs import check_raster_size

    with opened(path, "--image") as src:
        check_raster_size(src, path, "orthophoto")
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


def greenness(rgb: np.ndarray, nir: np.ndarray | None, p: FusionSettings = FusionSettings()):
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


def road_shaped(mask: np.ndarray, cell_m: float, p: FusionSettings = FusionSettings()) -> np.ndarray:
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


def in_water(regions: np.ndarray, row, col, cls, max_share: float, z=None, level_tol_m: float | None = None
             ) -> np.ndarray:
    """Cells of the 8-connected regions of ``regions`` lying in water: more than ``max_share`` of the
    cells with returns on their rim (two cells wide) hold a water return (class 9; cells without returns,
    dropouts and the data's edge, say nothing) and, given the returns' heights ``z`` (m), the region lies at
    the water's level: the median height of its ground returns above the nearest water return on its rim is
    within ``level_tol_m`` (m; the LiDAR water rule's ``water_level_tol_m``) (a road on a causeway or embankment
    across a lake stands above the water)."""
    if z is not None and level_tol_m is None:
        raise ValueError("in_water: the returns' heights z need level_tol_m")
    labels, n = ndimage.label(regions, structure=_EIGHT)
    if n == 0:
        return np.zeros_like(regions, bool)
    occupied = np.zeros(regions.shape, bool)
    occupied[row, col] = True
    wet = np.zeros(regions.shape, bool)
    w = cls == WATER
    wet[row[w], col[w]] = True
    # the nearest region of each cell within two cells (rim cells of two regions go to one of them)
    near = ndimage.grey_dilation(labels, footprint=np.ones((5, 5), bool))
    rim = (labels == 0) & (near > 0) & occupied
    total = np.bincount(near[rim], minlength=n + 1)
    on_water = np.bincount(near[rim], weights=wet[rim], minlength=n + 1)
    keep = on_water > max_share * np.maximum(total, 1)
    keep[0] = False
    if z is not None and keep.any():
        # each of the region's ground returns against the nearest water return on its rim: a river slopes
        zz = np.asarray(z, float)
        lab_pt = labels[row, col]
        wet_rim_near = np.where(w & rim[row, col], near[row, col], 0)
        for k in np.flatnonzero(keep):
            wet_rim = np.flatnonzero(wet_rim_near == k)
            own = np.flatnonzero((lab_pt == k) & (cls == GROUND))
            if len(wet_rim) == 0 or len(own) == 0:
                keep[k] = False
                continue
            nearest = cKDTree(np.column_stack([row[wet_rim], col[wet_rim]])).query(
                np.column_stack([row[own], col[own]]))[1]
            keep[k] = abs(np.median(zz[own] - zz[wet_rim[nearest]])) <= level_tol_m
    return keep[labels]


def read_grey(img: ImageSource, xmin: float, ymin: float, xmax: float, ymax: float):
    """(grey uint8 array, (x of column 0's centre, y of row 0's centre, pixel size), all in metres) of the
    orthophoto over the box (metres; clipped to the image), or None when the image does not cover it.
    Grey is the mean of R, G, B stretched between the window's 1st and 99th percentiles, so Canny's
    thresholds mean the same on 8- and 16-bit images."""
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(img.path) as src:
        t = src.transform
        c0 = max(int(np.floor((xmin / img.xy_m - t.c) / t.a)), 0)
        c1 = min(int(np.ceil((xmax / img.xy_m - t.c) / t.a)), src.width)
        r0 = max(int(np.floor((ymax / img.xy_m - t.f) / t.e)), 0)
        r1 = min(int(np.ceil((ymin / img.xy_m - t.f) / t.e)), src.height)
        if c1 - c0 < 3 or r1 - r0 < 3:
            return None
        win = Window(c0, r0, c1 - c0, r1 - r0)
        bands = np.stack([src.read(b, window=win, masked=True).astype(np.float64) for b in img.rgb_bands])
    grey = np.ma.mean(bands, axis=0)
    valid = ~np.ma.getmaskarray(grey)
    if not valid.any():
        return None
    lo, hi = np.percentile(grey.compressed(), (1, 99))
    g = np.clip((np.ma.filled(grey, lo) - lo) / max(hi - lo, 1e-9) * 255.0, 0, 255).astype(np.uint8)
    px_m = t.a * img.xy_m
    return g, ((t.c + (c0 + 0.5) * t.a) * img.xy_m, (t.f + (r0 + 0.5) * t.e) * img.xy_m, px_m)


def line_segments(grey: np.ndarray, px_m: float, p: FusionSettings = FusionSettings()) -> np.ndarray:
    """Straight segments (n, 4: u0 v0 u1 v1 in pixels, column/row) of the Canny edges of ``grey`` (uint8)
    at least ``building_min_line_m`` long (``px_m``: pixel size in metres); probabilistic Hough transform
    with a gap of up to a quarter of the minimum length bridged."""
    import cv2

    min_px = max(p.building_min_line_m / px_m, 3.0)
    edges = cv2.Canny(cv2.GaussianBlur(grey, (3, 3), 0), p.canny_low, p.canny_high)
    lines = cv2.HoughLinesP(edges, 1, np.pi / 180, threshold=max(int(0.5 * min_px), 3),
                            minLineLength=min_px, maxLineGap=max(0.25 * min_px, 1.0))
    if lines is None:
        return np.zeros((0, 4), np.float64)
    seg = lines.reshape(-1, 4).astype(np.float64)
    length_m = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) * px_m
    return seg[length_m >= p.building_min_line_m]


def first_minus_last(z, row, col, shape, return_number=None, number_of_returns=None) -> np.ndarray:
    """FML per cell (module docstring): highest first return minus lowest last return of the pulses with
    more than one return; 0 where a cell has none (and everywhere without return numbers)."""
    fml = np.zeros(shape, np.float64)
    if return_number is None or number_of_returns is None:
        return fml
    rn, nr = np.asarray(return_number), np.asarray(number_of_returns)
    multi = nr > 1
    first, last = multi & (rn == 1), multi & (rn >= nr)
    if not (first.any() and last.any()):
        return fml
    flat = row * shape[1] + col
    top = np.full(fml.size, -np.inf)
    np.maximum.at(top, flat[first], z[first])
    bottom = np.full(fml.size, np.inf)
    np.minimum.at(bottom, flat[last], z[last])
    both = np.isfinite(top) & np.isfinite(bottom)
    fml.ravel()[both] = np.maximum(top[both] - bottom[both], 0.0)
    return fml


def lines_per_building(labels: np.ndarray, nb: int, x0: float, y0: float, cell_m: float, img: ImageSource,
                       *, p: FusionSettings = FusionSettings()):
    """(segments per candidate (nb + 1,), covered (nb + 1,) bool) for the candidates ``labels`` (grid rows
    northwards from ``y0``, columns from ``x0``, cells of ``cell_m``): one Canny/Hough pass over the
    orthophoto window of all candidates; a segment counts for the candidate nearest its midpoint within
    ``building_line_reach_m``."""
    count = np.zeros(nb + 1, np.int64)
    covered = np.zeros(nb + 1, bool)
    rows, cols = np.nonzero(labels)
    reach = p.building_line_reach_m
    box = (x0 + cols.min() * cell_m - reach, y0 + rows.min() * cell_m - reach,
           x0 + (cols.max() + 1) * cell_m + reach, y0 + (rows.max() + 1) * cell_m + reach)
    got = read_grey(img, *box)
    if got is None:
        return count, covered
    grey, (gx0, gy0, px_m) = got
    # candidates the image covers: their cells' centres fall inside the window
    h, w = grey.shape
    xc, yc = x0 + (cols + 0.5) * cell_m, y0 + (rows + 0.5) * cell_m
    u, v = (xc - gx0) / px_m, (gy0 - yc) / px_m
    inside = (u >= 0) & (u < w - 1) & (v >= 0) & (v < h - 1)
    covered[np.unique(labels[rows[inside], cols[inside]])] = True
    seg = line_segments(grey, px_m, p)
    if len(seg) == 0:
        return count, covered
    mx = gx0 + 0.5 * (seg[:, 0] + seg[:, 2]) * px_m
    my = gy0 - 0.5 * (seg[:, 1] + seg[:, 3]) * px_m
    # nearest candidate cell of every cell, and how far it is
    dist, idx = ndimage.distance_transform_edt(labels == 0, return_indices=True)
    nearest = labels[tuple(idx)]
    c = np.floor((mx - x0) / cell_m).astype(np.int64)
    r = np.floor((my - y0) / cell_m).astype(np.int64)
    ok = (r >= 0) & (r < labels.shape[0]) & (c >= 0) & (c < labels.shape[1])
    r, c = r[ok], c[ok]
    near = dist[r, c] * cell_m <= reach
    count += np.bincount(nearest[r[near], c[near]], minlength=nb + 1)
    count[0] = 0
    return count, covered


@dataclasses.dataclass(frozen=True)
class Fusion:
    """What ``classify_points`` needs to fuse: the image and the rule thresholds."""

    image: ImageSource
    params: FusionSettings = FusionSettings()


def fuse(x, y, z, hag, cls, intensity, *, img: ImageSource, p: FusionSettings = FusionSettings(),
         water_level_tol_m: float, return_number=None, number_of_returns=None) -> np.ndarray:
    """Classes after the fusion rules (module docstring) for one tile's points (x, y, z in metres; ``hag``:
    height above the ground DEM; ``cls``: the LiDAR-only classes; return numbers for the first-minus-last
    height, optional; ``water_level_tol_m``: the LiDAR classification's setting, m).
    Returns a new array."""
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

    # 3. building confirmation: green, penetrable or without straight lines -> not a building
    c = p.road_cell_m
    x0, y0 = float(np.min(x)), float(np.min(y))
    col = np.floor((x - x0) / c).astype(np.int64)
    row = np.floor((y - y0) / c).astype(np.int64)
    shape = (int(row.max()) + 1, int(col.max()) + 1)
    bld = cls == BUILDING
    if bld.any():
        bcell = np.zeros(shape, bool)
        bcell[row[bld], col[bld]] = True
        # one cell of dilation joins a roof's cells across the gaps of a point spacing above the cell
        labels, nb = ndimage.label(ndimage.binary_dilation(bcell, _EIGHT), structure=_EIGHT)
        lab = labels[row[bld], col[bld]]
        n_green = np.bincount(lab, weights=(green & seen)[bld], minlength=nb + 1)
        n_seen = np.bincount(lab, weights=seen[bld], minlength=nb + 1)
        tree_like = (n_seen > 0) & (n_green > p.building_max_green * n_seen)
        fml = first_minus_last(np.asarray(z, float), row, col, shape, return_number, number_of_returns)
        ids = np.arange(nb + 1)
        deep = ndimage.sum_labels(fml >= p.building_max_fml_m, labels, ids)
        cells = np.maximum(ndimage.sum_labels(np.ones(shape), labels, ids), 1)
        penetrable = deep > p.building_max_fml_share * cells
        no_lines = np.zeros(nb + 1, bool)
        if p.building_min_lines > 0:
            n_lines, covered = lines_per_building(labels, nb, x0, y0, c, img, p=p)
            no_lines = covered & (n_lines < p.building_min_lines)
        rejected = (tree_like | penetrable | no_lines)
        rejected[0] = False
        log.debug("building candidates %d: green %d, penetrable %d, without %d straight lines %d", nb,
                  tree_like[1:].sum(), penetrable[1:].sum(), p.building_min_lines, no_lines[1:].sum())
        gone = np.flatnonzero(bld)[rejected[lab]]
        high = hag[gone] >= p.tree_min_height_m
        cls[gone] = np.where(high, HIGH_VEG, np.where(green[gone], LOW_VEG, GROUND))

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
        if np.any(cls == WATER) and road.any():
            road &= ~in_water(road, row, col, cls, p.road_max_water_rim_share, z, water_level_tol_m)
        cls[bare & road[row, col]] = ROAD
    return cls
