"""Land-cover truth of the true orthophoto: the class of every ortho pixel and a near-infrared band.

From the same straight-down view as ``truth/ortho.tif`` (``raster.ortho_render``: radiance and surface id
per pixel), so the class raster, the NIR band and the RGB ortho agree pixel for pixel.

Classes (ASPRS codes, as ``lidarctl.classify.class_grid`` scores them): roof and wall -> building 6, tree crown
-> tree 5; terrain by its ground material: grass 3, soil and painted targets -> bare ground 2, road
and road markings -> road 11, pond -> water 9; no hit -> 255 (nodata).

NIR: the pixel's visible radiance (mean of R, G, B, so shading, shadows and texture carry over) times
the ratio of a near-infrared to the visible albedo of its material (``NIR_ALBEDO`` over the mean of
the RGB albedo of ``shading.shade_points`` gives it): vegetation is bright in the NIR (chlorophyll's
red edge), roofs, roads and water are dark; tone-mapped like the RGB bands.
"""

from __future__ import annotations

import numba
import numpy as np

from aerotri.sim import shading
from aerotri.sim.scene import (GRASS, KIND_NONE, KIND_ROOF, KIND_TERRAIN, KIND_TREE, KIND_WALL, MARKING, ROAD, SOIL,
                               TARGET, TARGET_RING, WATER)

NODATA = 255
BUILDING, TREE, GRASS_CLASS, ROAD_CLASS, BARE, WATER_CLASS = 6, 5, 3, 11, 2, 9
GROUND_CLASS = {GRASS: GRASS_CLASS, SOIL: BARE, ROAD: ROAD_CLASS, MARKING: ROAD_CLASS, WATER: WATER_CLASS,
                TARGET: BARE, TARGET_RING: BARE}
# (visible albedo = mean of the base RGB albedo in shading.shade_points, NIR albedo): typical spectra of
# grass and broadleaf crowns (NIR 0.45-0.5), dry soil, asphalt, water, roofing and plaster.
GROUND_ALBEDO = {GRASS: ((0.16 + 0.32 + 0.11) / 3, 0.45), SOIL: ((0.42 + 0.33 + 0.22) / 3, 0.30),
                 ROAD: ((0.23 + 0.23 + 0.24) / 3, 0.16), MARKING: (0.84, 0.60), WATER: ((0.05 + 0.09 + 0.12) / 3, 0.02),
                 TARGET: (0.95, 0.80), TARGET_RING: (0.04, 0.04)}
TREE_ALBEDO = ((0.07 + 0.17 + 0.06) / 3, 0.50)
WALL_ALBEDO = ((0.55 + 0.53 + 0.50) / 3, 0.35)
ROOF_NIR_ALBEDO = 0.10


def classes_and_nir(ids: np.ndarray, rad: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, scene):
    """(uint8 classes, float32 NIR radiance) of pixels with surface ids ``ids`` (``vertical_render``:
    kind * 1_000_000 + object), radiance ``rad`` (..., 3) and local coordinates ``x_m``, ``y_m``.

    One compiled pass over the pixels (a 4 GP true orthophoto has as many): the float32 arithmetic of the
    numpy expressions it replaced (NIR = ((R + G) + B) / 3 x ratio), so the same bytes."""
    ids = np.asarray(ids)
    shape = ids.shape
    cls_lut = np.full(max(GROUND_CLASS) + 1, NODATA, np.uint8)
    ratio_lut = np.zeros(max(GROUND_CLASS) + 1, np.float32)
    for mat, c in GROUND_CLASS.items():
        cls_lut[mat] = c
        vis, nir = GROUND_ALBEDO[mat]
        ratio_lut[mat] = nir / vis
    vis_roof = np.asarray(scene.roof_albedo, float).mean(axis=1) if len(scene.roof_albedo) else np.zeros(1)
    roof_ratio = (ROOF_NIR_ALBEDO / np.maximum(vis_roof, 1e-3)).astype(np.float32)
    kind_ratio = np.float32([TREE_ALBEDO[1] / TREE_ALBEDO[0], WALL_ALBEDO[1] / WALL_ALBEDO[0]])
    classes = np.empty(ids.size, np.uint8)
    nir = np.empty(ids.size, np.float32)
    _classes_and_nir(ids.reshape(-1).astype(np.int64), np.ascontiguousarray(rad, np.float32).reshape(-1, 3),
                     np.ascontiguousarray(x_m, float).reshape(-1), np.ascontiguousarray(y_m, float).reshape(-1),
                     G=shading.ground_index(scene), cls_lut=cls_lut, ratio_lut=ratio_lut, roof_ratio=roof_ratio,
                     kind_ratio=kind_ratio, classes=classes, nir=nir)
    return classes.reshape(shape), nir.reshape(shape)


@numba.njit(cache=True, parallel=True)
def _classes_and_nir(ids, rad, x_m, y_m, *, G, cls_lut, ratio_lut, roof_ratio, kind_ratio, classes, nir):
    three = numba.float32(3.0)
    for p in numba.prange(ids.shape[0]):
        kind = ids[p] // 1_000_000
        obj = ids[p] % 1_000_000
        c = NODATA
        r = numba.float32(0.0)
        if kind == KIND_ROOF:
            c = BUILDING
            r = roof_ratio[obj]
        elif kind == KIND_WALL:
            c = BUILDING
            r = kind_ratio[1]
        elif kind == KIND_TREE:
            c = TREE
            r = kind_ratio[0]
        elif kind == KIND_TERRAIN:
            m = shading.ground_material(x_m[p], y_m[p], G)
            c = cls_lut[m]
            r = ratio_lut[m]
        classes[p] = c
        if kind == KIND_NONE:
            nir[p] = numba.float32(0.0)
        else:
            nir[p] = ((rad[p, 0] + rad[p, 1]) + rad[p, 2]) / three * r
