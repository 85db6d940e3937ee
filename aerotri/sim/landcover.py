"""Land-cover truth of the true orthophoto: the class of every ortho pixel and a near-infrared band.

From the same straight-down view as ``truth/ortho.tif`` (``raster.ortho_render``: radiance and surface id
per pixel), so the class raster, the NIR band and the RGB ortho agree pixel for pixel.

Classes (ASPRS codes, as ``lidarctl.class_grid`` scores them): roof and wall -> building 6, tree crown
-> tree 5; terrain by its ground material: grass 3, soil and painted targets -> bare ground 2, road
and road markings -> road 11, pond -> water 9; no hit -> 255 (nodata).

NIR: the pixel's visible radiance (mean of R, G, B, so shading, shadows and texture carry over) times
the ratio of a near-infrared to the visible albedo of its material (``NIR_ALBEDO`` over the mean of
the RGB albedo of ``shading.shade_points`` gives it): vegetation is bright in the NIR (chlorophyll's
red edge), roofs, roads and water are dark; tone-mapped like the RGB bands.
"""

from __future__ import annotations

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
    kind * 1_000_000 + object), radiance ``rad`` (..., 3) and local coordinates ``x_m``, ``y_m``."""
    ids = np.asarray(ids)
    kind, obj = ids // 1_000_000, ids % 1_000_000
    classes = np.full(ids.shape, NODATA, np.uint8)
    ratio = np.zeros(ids.shape, np.float32)
    classes[(kind == KIND_ROOF) | (kind == KIND_WALL)] = BUILDING
    classes[kind == KIND_TREE] = TREE
    ratio[kind == KIND_TREE] = TREE_ALBEDO[1] / TREE_ALBEDO[0]
    ratio[kind == KIND_WALL] = WALL_ALBEDO[1] / WALL_ALBEDO[0]
    roof = kind == KIND_ROOF
    if roof.any():
        vis = np.asarray(scene.roof_albedo, float).mean(axis=1)
        ratio[roof] = ROOF_NIR_ALBEDO / np.maximum(vis[obj[roof]], 1e-3)
    terrain = kind == KIND_TERRAIN
    if terrain.any():
        m = shading.ground_materials(np.ascontiguousarray(x_m[terrain], float), np.ascontiguousarray(y_m[terrain], float),
                                     shading.ground_index(scene))
        cls_lut = np.full(max(GROUND_CLASS) + 1, NODATA, np.uint8)
        ratio_lut = np.zeros(max(GROUND_CLASS) + 1, np.float32)
        for mat, c in GROUND_CLASS.items():
            cls_lut[mat] = c
            vis, nir = GROUND_ALBEDO[mat]
            ratio_lut[mat] = nir / vis
        classes[terrain] = cls_lut[m]
        ratio[terrain] = ratio_lut[m]
    nir = np.asarray(rad, np.float32).mean(axis=-1) * ratio
    nir[kind == KIND_NONE] = 0.0
    return classes, nir
