"""Building footprints in the true ortho's occlusion test (``ortho rectify --true-ortho --dsm DSM --footprints
FOOTPRINTS.gpkg``, ``[rectify] footprints``).

A 2.5D DSM stands every roof as a solid column down to the ground, so a line of sight that passes beneath an eave
(the roof outside the walls) is judged occluded although it reaches the ground. Production true-ortho tools take
the walls from cadastral footprints (BGT, OSM, a user's GeoPackage); so does this module. Per DSM cell
(``footprint_occluder``):

- a cell inside a footprint, or one that no footprint is near, is a solid column from the ground to its top, as
  without footprints (roofs inside the walls, trees, the ground);
- a cell outside every footprint but within ``OVERHANG_REACH_M`` of one, standing more than ``OVERHANG_ABOVE_M``
  above the DEM, is an overhang: it blocks a ray only within a slab of ``OVERHANG_SLAB_M`` under its top (the roof
  and its eave boarding), so a ray that stays beneath that slab across the cell passes;
- where a footprint's wall crosses an overhang cell, the part inside the footprint (the cell split in
  ``SUB_CELL_M`` sub-cells, a sub-cell inside when its centre is) stays a solid column up to the cell's top.

The march (``ortho.rectify_kernels._occlusion_kernel``) reads this as ``FootprintOccluder``. The thresholds are
physical defaults, not fitted to a block: an eave's rafters, boarding and roofing make 0.2-0.4 m; eaves reach
0.3-1 m beyond the wall (more is a canopy or balcony); a storey is about 3 m, so a roof stands at least 2 m above the
ground.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from aerotri.core.errors import InputError

if TYPE_CHECKING:
    from pyproj import CRS

    from ortho.dem import HeightRaster

OVERHANG_SLAB_M = 0.3  # thickness of a roof overhang beyond the walls: the ray passes beneath it
OVERHANG_REACH_M = 1.5  # furthest a roof reaches beyond its wall line and counts as an overhang
OVERHANG_ABOVE_M = 2.0  # an overhang cell stands at least this much above the DEM (a roof, not the ground)
SUB_CELL_M = 0.1  # the walls within an overhang cell are resolved to sub-cells of at most this size
_ROWS_PER_CHUNK = 256  # DSM rows rasterised at a time (the sub-cell raster of a chunk: 256 x 5 rows)


@dataclasses.dataclass(frozen=True)
class FootprintOccluder:
    """What the march reads beside the DSM (same shape as its heights): ``base_m`` the underside of each cell's
    occluder (-inf: a solid column; else the top minus ``OVERHANG_SLAB_M``: an overhang), ``sub_index`` (int32,
    -1 or the index into ``sub_masks`` of an overhang cell a wall crosses), ``sub_masks`` ((K, sub, sub) uint8, 1
    where the sub-cell is inside a footprint; rows from the north, columns from the west) and ``sub`` (sub-cells
    per cell side)."""

    base_m: np.ndarray
    sub_index: np.ndarray
    sub_masks: np.ndarray
    sub: int

    @property
    def overhang_cells(self) -> int:
        return int(np.isfinite(self.base_m).sum())


def read_footprints(path, project_crs: CRS) -> np.ndarray:
    """The footprint polygons (shapely, an object array) of the first layer of the vector file ``path`` (a
    GeoPackage), which must be in ``project_crs`` (horizontal part) and hold only (multi)polygons; ``InputError``
    naming the file and what was expected otherwise."""
    import pyogrio
    import shapely
    from pyproj import CRS as _CRS

    from aerotri.geom.crs.definition import same_horizontal

    path = Path(path)
    what = "expected a GeoPackage of building footprint polygons in the project CRS"
    if not path.is_file():
        raise InputError(f"{path}: footprints file not found; {what}")
    try:
        layers = pyogrio.list_layers(str(path))
        meta, _, wkb, _ = pyogrio.raw.read(str(path), layer=str(layers[0][0]) if len(layers) else None,
                                           read_geometry=True, columns=[])
    except Exception as e:  # pyogrio's DataSourceError, DataLayerError, ... for a file that is no vector layer
        raise InputError(f"{path}: cannot read it as a vector layer ({str(e).splitlines()[0]}); {what}") from None
    if meta.get("crs") is None:
        raise InputError(f"{path}: the footprints have no CRS; {what} ({project_crs.to_string()})")
    crs = _CRS.from_user_input(meta["crs"])
    if not same_horizontal(crs, project_crs):
        raise InputError(f"{path}: the footprints are in {crs.to_string()}; {what} ({project_crs.to_string()})")
    if wkb is None or len(wkb) == 0:
        raise InputError(f"{path}: no features; {what}")
    geoms = shapely.from_wkb(wkb)
    kinds = shapely.get_type_id(geoms)
    bad = np.flatnonzero(~np.isin(kinds, (3, 6)))  # Polygon, MultiPolygon
    if bad.size:
        g = geoms[bad[0]]
        raise InputError(f"{path}: feature {int(bad[0]) + 1} is a {'missing geometry' if g is None else g.geom_type}; "
                         f"{what} (Polygon or MultiPolygon), {bad.size} such feature(s)")
    return shapely.make_valid(geoms)


def footprint_occluder(dsm: HeightRaster, dem: HeightRaster, footprints: np.ndarray, *,
                       slab_m: float = OVERHANG_SLAB_M, reach_m: float = OVERHANG_REACH_M,
                       above_m: float = OVERHANG_ABOVE_M, sub_cell_m: float = SUB_CELL_M) -> FootprintOccluder:
    """The ``FootprintOccluder`` of ``dsm`` (a window in the project CRS) with the footprint polygons (project CRS)
    and the DEM (any grid in the project CRS: sampled at the DSM's cell centres)."""
    import shapely
    from rasterio.features import rasterize
    from rasterio.transform import from_origin

    from ortho.grid import OrthoGrid
    from ortho.rectify import heights_on_grid

    top = dsm.heights_m
    dh, dw = top.shape
    res = dsm.res_m
    sub = max(1, int(math.ceil(res / sub_cell_m - 1e-9)))
    base = np.full((dh, dw), -np.inf, np.float32)
    sub_index = np.full((dh, dw), -1, np.int32)
    left, bottom, right, top_y = dsm.bounds
    polys = footprints[shapely.intersects(footprints, shapely.box(left - reach_m, bottom - reach_m,
                                                                   right + reach_m, top_y + reach_m))]
    if len(polys) == 0:
        return FootprintOccluder(base, sub_index, np.zeros((0, sub, sub), np.uint8), sub)
    near = rasterize(((g, 1) for g in shapely.buffer(polys, reach_m)), out_shape=(dh, dw),
                     transform=from_origin(dsm.x_left_m, dsm.y_top_m, res, res), all_touched=True,
                     dtype="uint8").astype(bool)
    ground = heights_on_grid(dem, OrthoGrid(dsm.crs, dsm.x_left_m, dsm.y_top_m, res, dw, dh))
    with np.errstate(invalid="ignore"):
        candidate = near & np.isfinite(top) & (top - ground > above_m)
    masks, count = [], 0
    for r0 in range(0, dh, _ROWS_PER_CHUNK):
        r1 = min(dh, r0 + _ROWS_PER_CHUNK)
        if not candidate[r0:r1].any():
            continue
        fine = rasterize(((g, 1) for g in polys), out_shape=((r1 - r0) * sub, dw * sub),
                         transform=from_origin(dsm.x_left_m, dsm.y_top_m - r0 * res, res / sub, res / sub),
                         dtype="uint8")
        cells = fine.reshape(r1 - r0, sub, dw, sub).transpose(0, 2, 1, 3)  # (rows, cols, sub, sub)
        inside = cells.sum((2, 3), dtype=np.int32)
        over = candidate[r0:r1] & (inside < sub * sub)
        rr, cc = np.nonzero(over)
        base[r0 + rr, cc] = top[r0 + rr, cc] - slab_m
        walls = inside[rr, cc] > 0
        sub_index[r0 + rr[walls], cc[walls]] = count + np.arange(int(walls.sum()), dtype=np.int32)
        count += int(walls.sum())
        masks.append(np.ascontiguousarray(cells[rr[walls], cc[walls]]))
    sub_masks = np.concatenate(masks) if masks else np.zeros((0, sub, sub), np.uint8)
    return FootprintOccluder(base, sub_index, sub_masks, sub)
