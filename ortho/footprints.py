"""Building footprints in the true ortho's occlusion test (``ortho rectify --true-ortho --dsm DSM --footprints
FOOTPRINTS.gpkg``, ``[rectify] footprints``).

A 2.5D DSM stands every roof as a solid column down to the ground, so a line of sight that passes beneath an eave
(the roof outside the walls) is judged occluded although it reaches the ground. Production true-ortho tools take
the walls from cadastral footprints (BGT, OSM, a user's GeoPackage); so does this module. Per DSM cell
(``footprint_occluder``):

- a cell inside a footprint, or one that no footprint is near, is a solid column from the ground to its top, as
  without footprints (roofs inside the walls, trees, the ground);
- a cell outside every footprint but within ``OVERHANG_REACH_M`` of one, standing more than ``OVERHANG_ABOVE_M``
  above the DEM, is an overhang: it blocks a ray only from its top (at least the eave line) down to the building's
  soffit, ``OVERHANG_SLAB_M`` (the fascia) under the building's eave line (``EAVE_QUANTILE`` of the tops of its
  overhang cells), so a ray that stays beneath the soffit across the cell passes; the cells beside an overhang that
  are not roof carry its slab too, over the half cell next to it (the DSM samples the roof at cell centres: the
  eave's edge lies anywhere within half a cell of the roof cell's edge);
- where a footprint's wall crosses an overhang cell, the part inside the footprint (the cell split in
  ``SUB_CELL_M`` sub-cells, a sub-cell inside when its centre is) stays a solid column up to the cell's top.

The march (``ortho.rectify_kernels._occlusion_kernel``) reads this as ``FootprintOccluder``. The thresholds are
physical values, not fitted to a score: a fascia (the roof's edge below the eave line) is 0.2-0.4 m; eaves reach
0.3-1 m beyond the wall (more is a canopy or balcony); a storey is about 3 m, so a roof stands at least 2 m above the
ground. The half cell beside an overhang and the eave-line quantile were chosen on the simulated blocks
(docs/true-ortho.md, "Building footprints in the occlusion test").
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from aerotri.core.errors import InputError

if TYPE_CHECKING:
    from pyproj import CRS

    from ortho.dem import HeightRaster

OVERHANG_SLAB_M = 0.3  # depth of the roof's edge (fascia) below the eave line: a ray passes beneath it
OVERHANG_REACH_M = 1.5  # furthest a roof reaches beyond its wall line and counts as an overhang
OVERHANG_ABOVE_M = 2.0  # an overhang cell stands at least this much above the DEM (a roof, not the ground)
SUB_CELL_M = 0.1  # the walls within an overhang cell are resolved to sub-cells of at most this size
HALO = -3  # ``sub_index`` HALO - k: a cell beside an overhang, its own solid column and the overhang's slab over the
# sub-cells of ``sub_masks[k]``
_ROWS_PER_CHUNK = 256  # DSM rows rasterised at a time (the sub-cell raster of a chunk: 256 x 5 rows)


@dataclasses.dataclass(frozen=True)
class FootprintOccluder:
    """What the march reads beside the DSM (same shape as its heights): ``base_m`` the underside of each cell's
    slab (-inf: none, the cell a solid column; else an overhang's soffit: its building's eave line minus
    ``OVERHANG_SLAB_M``), ``slab_top_m`` the slab's top (an overhang cell's DSM top; beside an overhang, the eave
    line), ``sub_index`` (int32: -1 an overhang cell; k >= 0 an overhang cell a wall crosses, its sub-cells inside a
    footprint ``sub_masks[k]``; ``HALO`` - k a cell beside an overhang: its own solid column, and the slab over the
    sub-cells ``sub_masks[k]``), ``sub_masks`` ((K, sub, sub) uint8; rows from the north, columns from the west)
    and ``sub`` (sub-cells per cell side)."""

    base_m: np.ndarray
    slab_top_m: np.ndarray
    sub_index: np.ndarray
    sub_masks: np.ndarray
    sub: int

    @property
    def overhang_cells(self) -> int:
        return int((np.isfinite(self.base_m) & (self.sub_index > HALO)).sum())


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


EAVE_QUANTILE = 0.25  # the eave line: this quantile of the tops of a building's overhang cells


def _eave_lines(labels: np.ndarray, tops: np.ndarray, n: int) -> np.ndarray:
    """Per label (0 .. n - 1) the ``EAVE_QUANTILE`` of its cells' tops (inf for a label without cells): the eave line
    most of an overhang's cells stand at (a flat roof's all, a pitched roof's long sides, the gable ends above it),
    below the few the LiDAR DSM fills lower, between ground and roof, in a wall's shadow."""
    order = np.lexsort((tops, labels))
    lab, z = labels[order], tops[order]
    start = np.searchsorted(lab, np.arange(n), "left")
    count = np.searchsorted(lab, np.arange(n), "right") - start
    out = np.full(n, np.inf, np.float32)
    has = count > 0
    out[has] = z[start[has] + np.floor(EAVE_QUANTILE * (count[has] - 1)).astype(np.int64)]
    return out


def footprint_occluder(dsm: HeightRaster, ground_m: np.ndarray, footprints: np.ndarray, *,
                       slab_m: float = OVERHANG_SLAB_M, reach_m: float = OVERHANG_REACH_M,
                       above_m: float = OVERHANG_ABOVE_M, sub_cell_m: float = SUB_CELL_M) -> FootprintOccluder:
    """The ``FootprintOccluder`` of ``dsm`` (a window in the project CRS) with the footprint polygons (project CRS)
    and ``ground_m``, the DEM at the DSM's cell centres (same shape; ``ortho.rectify.heights_on_grid``)."""
    import shapely
    from rasterio.features import rasterize
    from rasterio.transform import from_origin

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
        return FootprintOccluder(base, base.copy(), sub_index, np.zeros((0, sub, sub), np.uint8), sub)
    # each cell near a footprint labelled with it (1-based; where two buildings' reaches overlap, one of them)
    label = rasterize(((shapely.geometry.mapping(g), k + 1) for k, g in enumerate(shapely.buffer(polys, reach_m))),
                      out_shape=(dh, dw),
                      transform=from_origin(dsm.x_left_m, dsm.y_top_m, res, res), all_touched=True, dtype="int32")
    with np.errstate(invalid="ignore"):
        candidate = (label > 0) & (top - ground_m > above_m)
    masks, count = [], 0
    shapes = [shapely.geometry.mapping(g) for g in polys]  # converted once, not by every rasterize
    for r0 in range(0, dh, _ROWS_PER_CHUNK):
        r1 = min(dh, r0 + _ROWS_PER_CHUNK)
        if not candidate[r0:r1].any():
            continue
        y1, y0 = dsm.y_top_m - r0 * res, dsm.y_top_m - r1 * res
        here = [shapes[k] for k in np.flatnonzero(shapely.intersects(polys, shapely.box(left, y0, right, y1)))]
        if not here:
            continue
        # sub-cells inside a footprint, each the value sub x sub x 100: cv2's area average per cell (exact for a
        # whole factor) is then 100 x the number inside
        fine = rasterize(((g, sub * sub * 100) for g in here), out_shape=((r1 - r0) * sub, dw * sub),
                         transform=from_origin(dsm.x_left_m, y1, res / sub, res / sub), dtype="uint16")
        inside = (cv2.resize(fine, (dw, r1 - r0), interpolation=cv2.INTER_AREA) + 50) // 100
        cells = fine.reshape(r1 - r0, sub, dw, sub).transpose(0, 2, 1, 3)  # (rows, cols, sub, sub)
        over = candidate[r0:r1] & (inside < sub * sub)
        rr, cc = np.nonzero(over)
        base[r0 + rr, cc] = 1.0  # an overhang; its underside set below, per building
        walls = inside[rr, cc] > 0
        sub_index[r0 + rr[walls], cc[walls]] = count + np.arange(int(walls.sum()), dtype=np.int32)
        count += int(walls.sum())
        masks.append((cells[rr[walls], cc[walls]] > 0).astype(np.uint8))
    sub_masks = np.concatenate(masks) if masks else np.zeros((0, sub, sub), np.uint8)
    # the underside: the building's eave line less the slab, flat under the whole overhang (a pitched roof's
    # overhang rises inwards and up its gable ends; what lies under it is the soffit at the eave line's level, or
    # the roof itself); the slab reaches up to the eave line at least (a cell lower than it, e.g. filled between
    # the LiDAR's returns in a wall's shadow, lies under the eave)
    over = np.isfinite(base)
    rr, cc = np.nonzero(over)
    eave = _eave_lines(label[rr, cc], top[rr, cc], len(polys) + 1)[label[rr, cc]]
    base[rr, cc] = eave - slab_m
    slab_top = np.full((dh, dw), -np.inf, np.float32)
    slab_top[rr, cc] = np.maximum(top[rr, cc], eave)
    # the eave's edge lies anywhere within the cell beyond the last one sampled on the roof (a DSM samples the roof
    # at its cell centres): the cells beside an overhang that are not roof (the ground, lower than the overhang)
    # carry its soffit slab as well, so that no ray passes through the part of the eave the DSM missed
    beside = cv2.erode(np.where(over, base, np.inf).astype(np.float32), np.ones((3, 3), np.uint8),
                       borderType=cv2.BORDER_CONSTANT, borderValue=float("inf"))
    halo = ~over & ~candidate & np.isfinite(beside)
    base[halo] = beside[halo]
    slab_top[halo] = beside[halo] + slab_m
    # the slab reaches half a cell into such a cell from each overhang beside it: the sub-cells whose centres lie
    # within half a cell of that side (or corner)
    hr, hc = np.nonzero(halo)
    near_side = (np.arange(sub) + 0.5) / sub <= 0.5
    halo_masks = np.zeros((len(hr), sub, sub), np.uint8)
    over_pad = np.pad(over, 1)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == dj == 0:
                continue
            hit = over_pad[hr + 1 + di, hc + 1 + dj]
            rows = near_side if di < 0 else near_side[::-1] if di > 0 else np.ones(sub, bool)
            cols = near_side if dj < 0 else near_side[::-1] if dj > 0 else np.ones(sub, bool)
            halo_masks[hit] |= (rows[:, None] & cols[None, :]).astype(np.uint8)
    sub_index[hr, hc] = HALO - (len(sub_masks) + np.arange(len(hr), dtype=np.int32))
    sub_masks = np.concatenate([sub_masks, halo_masks])
    return FootprintOccluder(base, slab_top, sub_index, sub_masks, sub)
