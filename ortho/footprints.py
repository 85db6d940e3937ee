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
  ``SUB_CELL_M`` sub-cells, a sub-cell inside when its centre is) stays a solid column up to the cell's top;
- the roof outline: an overhang's slab (and the half cell beside it) covers only the sub-cells within the footprint
  grown by the building's eave width (``eave_widths_m``: the roof's area outside the walls that the DSM's cells
  sample, over the footprint's perimeter, at most ``EAVE_MAX_M``), not the part of a roof cell the DSM's 0.5 m cell
  (or the LiDAR DSM's wider roof) spills beyond the eave; the march finds the outline between the sub-cells'
  centres (their distances to the footprint interpolated, ``FootprintOccluder.sub_margin_cm``), not at the edges of
  the sub-cells whose centres lie within it (half a sub-cell beyond the eave);
- tree crowns (``with_crown_base``, a crown-base raster): a cell near no footprint blocks only between its crown
  base and its top.

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

import numba
import numpy as np

from aerotri.core.errors import InputError

if TYPE_CHECKING:
    from pyproj import CRS

    from ortho.dem import HeightRaster

OVERHANG_SLAB_M = 0.3  # depth of the roof's edge (fascia) below the eave line: a ray passes beneath it
OVERHANG_REACH_M = 1.5  # furthest a roof reaches beyond its wall line and counts as an overhang
OVERHANG_ABOVE_M = 2.0  # an overhang cell stands at least this much above the DEM (a roof, not the ground)
SUB_CELL_M = 0.1  # the walls within an overhang cell are resolved to sub-cells of at most this size
EAVE_MAX_M = 1.0  # widest eave overhang (beyond the wall line) a building's roof outline is given: eaves reach 0.3-1 m
CROWN = -2  # ``sub_index`` of a tree crown's cell: a slab from its crown base to its top
HALO = -3  # ``sub_index`` HALO - k: a cell beside an overhang, its own solid column and the overhang's slab over the
# sub-cells of ``sub_masks[k]``
MARGIN_ALL = 1000  # ``sub_margin_cm`` of a sub-cell of a cell without distances to a footprint: within the outline
MARGIN_NONE = -32768  # ``sub_margin_cm`` of a sub-cell outside the half cell beside an overhang: no slab


@dataclasses.dataclass(frozen=True)
class FootprintOccluder:
    """What the march reads beside the DSM (same shape as its heights): ``base_m`` the underside of each cell's
    slab (-inf: none, the cell a solid column; else an overhang's soffit: its building's eave line minus
    ``OVERHANG_SLAB_M``; a tree's crown base), ``slab_top_m`` the slab's top (an overhang cell's DSM top; beside an
    overhang, the eave line), ``sub_index`` (int32: -1 a slab over the whole cell; ``CROWN`` a tree crown's; k >= 0 an overhang cell a wall
    or the roof outline crosses: ``sub_masks[k]`` bit 1 its sub-cells inside a footprint (a column up to the top),
    bit 2 those within the roof outline (the slab), bit 4 at [0, 0] the slab over the whole cell; ``HALO`` - k a cell
    beside an overhang: its own solid column, and the slab over the sub-cells of bit 2 of ``sub_masks[k]``),
    ``sub_masks`` ((K, sub, sub) uint8; rows from the north, columns from the west), ``sub`` (sub-cells per cell
    side) and ``sub_margin_cm`` ((K, sub, sub) int16: how far each sub-cell's centre lies within the roof outline, cm,
    negative beyond it; ``MARGIN_NONE`` outside the half cell beside an overhang): the march interpolates it between
    the centres, so that the slab ends at the outline, not at the edge of the last sub-cell whose centre it holds."""

    base_m: np.ndarray
    slab_top_m: np.ndarray
    sub_index: np.ndarray
    sub_masks: np.ndarray
    sub: int
    sub_margin_cm: np.ndarray

    @property
    def overhang_cells(self) -> int:
        """Cells with a slab (overhangs and crowns), not those beside an overhang."""
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


@dataclasses.dataclass(frozen=True)
class FootprintCells:
    """The footprints rasterised on a DSM grid: the part of ``footprint_occluder`` that depends neither on the heights
    nor on the window read, so that a block's frames share it (``window``). ``label`` (int32): per cell the 1-based
    index in ``polygons`` of a footprint whose reach (the footprint grown by ``reach_m``, every cell it touches) covers
    the cell, 0 none (where two reaches overlap, the later polygon's); ``inside`` (uint16): the cell's sub-cells inside
    a footprint (``sub`` x ``sub`` a cell, a sub-cell inside when its centre is); ``wall_index`` (int32): for a cell
    that a wall crosses (0 < ``inside`` < sub x sub) its sub-cells inside, ``wall_masks[k]`` ((K, sub, sub) uint8,
    rows from the north, columns from the west), else -1; ``polygons``: the footprints near the grid (shapely).
    The roof outline: ``edge_index`` (int32) for a cell in a footprint's reach not wholly inside one, the index in
    ``edge_cm`` ((K, sub, sub) uint8) of its sub-cells' distances (their centres') to the nearest footprint's wall
    line (cm, 0 inside, at most 255), else -1; per polygon its ``area_m2``, ``perimeter_m`` and ``reach_cells`` (row0, row1, col0, col1 of the
    cells its reach touches, in the cells of the grid the view ``origin`` (row, col) lies in)."""

    label: np.ndarray
    inside: np.ndarray
    wall_index: np.ndarray
    wall_masks: np.ndarray
    polygons: np.ndarray
    sub: int
    edge_index: np.ndarray
    edge_cm: np.ndarray
    area_m2: np.ndarray
    perimeter_m: np.ndarray
    reach_cells: np.ndarray
    origin: tuple[int, int] = (0, 0)

    def window(self, row0: int, col0: int, rows: int, cols: int) -> FootprintCells:
        """The cells ``row0 .. row0 + rows``, ``col0 .. col0 + cols`` (views; the masks and polygons shared)."""
        cut = np.s_[row0:row0 + rows, col0:col0 + cols]
        return dataclasses.replace(self, label=self.label[cut], inside=self.inside[cut],
                                   wall_index=self.wall_index[cut], edge_index=self.edge_index[cut],
                                   origin=(self.origin[0] + row0, self.origin[1] + col0))


def footprint_cells(x_left_m: float, y_top_m: float, res_m: float, shape: tuple[int, int], footprints: np.ndarray, *,
                    reach_m: float = OVERHANG_REACH_M, sub_cell_m: float = SUB_CELL_M) -> FootprintCells:
    """The ``FootprintCells`` of the north-up grid of ``shape`` (rows, cols) cells of ``res_m`` from its top-left
    corner (``x_left_m``, ``y_top_m``; project CRS) with the footprint polygons (project CRS)."""
    import shapely
    from rasterio.features import rasterize
    from rasterio.transform import from_origin

    dh, dw = shape
    res = res_m
    sub = max(1, int(math.ceil(res / sub_cell_m - 1e-9)))
    left, right, top_y, bottom = x_left_m, x_left_m + dw * res, y_top_m, y_top_m - dh * res
    polys = footprints[shapely.intersects(footprints, shapely.box(left - reach_m, bottom - reach_m,
                                                                   right + reach_m, top_y + reach_m))]
    inside = np.zeros((dh, dw), np.uint16)
    wall_index = np.full((dh, dw), -1, np.int32)
    edge_index = np.full((dh, dw), -1, np.int32)
    if len(polys) == 0:
        return FootprintCells(np.zeros((dh, dw), np.int32), inside, wall_index, np.zeros((0, sub, sub), np.uint8),
                              polys, sub, edge_index, np.zeros((0, sub, sub), np.uint8), np.zeros(0), np.zeros(0),
                              np.zeros((0, 4), np.int64))
    label = rasterize(((shapely.geometry.mapping(g), k + 1) for k, g in enumerate(shapely.buffer(polys, reach_m))),
                      out_shape=(dh, dw), transform=from_origin(x_left_m, y_top_m, res, res), all_touched=True,
                      dtype="int32")
    # sub-cells inside a footprint, rasterised over each footprint's cells (a window of whole cells around it and its
    # reach, with every footprint that reaches into it): a few % of the grid, not all of it at sub x sub the cells
    masks, count = [], 0
    edges, n_edge = [], 0
    shapes = [shapely.geometry.mapping(g) for g in polys]  # converted once, not by every rasterize
    rings = _wall_segments(polys)
    x0, y0, x1, y1 = shapely.bounds(polys).T
    grow = int(math.ceil(reach_m / res)) + 1
    reach_cells = np.stack([np.floor((y_top_m - y1) / res).astype(np.int64) - grow,
                            np.ceil((y_top_m - y0) / res).astype(np.int64) + grow,
                            np.floor((x0 - x_left_m) / res).astype(np.int64) - grow,
                            np.ceil((x1 - x_left_m) / res).astype(np.int64) + grow], axis=1)
    r0, r1 = np.clip(reach_cells[:, 0], 0, dh), np.clip(reach_cells[:, 1], 0, dh)
    c0, c1 = np.clip(reach_cells[:, 2], 0, dw), np.clip(reach_cells[:, 3], 0, dw)
    windows = shapely.box(x_left_m + c0 * res, y_top_m - r1 * res, x_left_m + c1 * res, y_top_m - r0 * res)
    which, there = shapely.STRtree(polys).query(windows, predicate="intersects")
    for k in range(len(polys)):
        h, w = int(r1[k] - r0[k]), int(c1[k] - c0[k])
        if h <= 0 or w <= 0:
            continue
        fine = rasterize(((shapes[q], 1) for q in there[which == k]), out_shape=(h * sub, w * sub),
                         transform=from_origin(x_left_m + c0[k] * res, y_top_m - r0[k] * res, res / sub, res / sub),
                         dtype="uint8")
        n_in = fine.reshape(h, sub, w * sub).sum(axis=1, dtype=np.uint16).reshape(h, w, sub).sum(axis=2,
                                                                                                 dtype=np.uint16)
        cells = fine.reshape(h, sub, w, sub).transpose(0, 2, 1, 3)  # (rows, cols, sub, sub)
        win = np.s_[r0[k]:r1[k], c0[k]:c1[k]]
        inside[win] = n_in
        # a wall's cell in two windows: its sub-cells once
        rr, cc = np.nonzero((n_in > 0) & (n_in < sub * sub) & (wall_index[win] < 0))
        wall_index[r0[k] + rr, c0[k] + cc] = count + np.arange(len(rr), dtype=np.int32)
        count += len(rr)
        masks.append(cells[rr, cc].astype(np.uint8))
        # the roof outline: each sub-cell's distance to the nearest footprint edge (the distance between sub-cell
        # centres less half a sub-cell), for the cells of this footprint's reach not wholly inside one
        rr, cc = np.nonzero((label[win] == k + 1) & (n_in < sub * sub) & (edge_index[win] < 0))
        if len(rr):
            # the distance of each sub-cell's centre to the walls of the footprints rasterised here (their edges,
            # not the centres of the sub-cells inside them: those put the wall up to half a sub-cell off)
            near = [rings[k]] + [rings[q] for q in there[which == k] if q != k]
            cm = _edge_distances_cm(cells[rr, cc], rr, cc, x_left_m + c0[k] * res, y_top_m - r0[k] * res, res, sub,
                                    np.concatenate(near))
            edge_index[r0[k] + rr, c0[k] + cc] = n_edge + np.arange(len(rr), dtype=np.int32)
            n_edge += len(rr)
            edges.append(cm)
    wall_masks = np.concatenate(masks) if masks else np.zeros((0, sub, sub), np.uint8)
    edge_cm = np.concatenate(edges) if edges else np.zeros((0, sub, sub), np.uint8)
    return FootprintCells(label, inside, wall_index, wall_masks, polys, sub, edge_index, edge_cm,
                          shapely.area(polys), shapely.length(polys), reach_cells)


def _wall_segments(polys: np.ndarray) -> list:
    """Per polygon its walls: the segments of its rings (exterior and holes), (n, 4) float64 x0, y0, x1, y1."""
    import shapely

    out = []
    for g in polys:
        rings = shapely.get_rings(g)
        segs = []
        for r in rings:
            xy = shapely.get_coordinates(r)
            segs.append(np.hstack([xy[:-1], xy[1:]]))
        out.append(np.concatenate(segs) if segs else np.zeros((0, 4)))
    return out


@numba.njit(cache=True, nogil=True)
def _edge_distances_cm(fine_cells, rr, cc, x_left_m, y_top_m, res_m, sub, segments):
    """Per cell (rr, cc) of a window (top-left corner ``x_left_m``, ``y_top_m``; cells of ``res_m``) the distance (cm,
    rounded, at most 255) of each of its ``sub`` x ``sub`` sub-cells' centres to the nearest wall segment
    (``segments``: (n, 4) x0, y0, x1, y1), 0 where the sub-cell is inside a footprint (``fine_cells`` (cells, sub,
    sub) nonzero); (cells, sub, sub) uint8."""
    n = len(rr)
    out = np.zeros((n, sub, sub), np.uint8)
    step = res_m / sub
    for k in range(n):
        for a in range(sub):
            y = y_top_m - rr[k] * res_m - (a + 0.5) * step
            for b in range(sub):
                if fine_cells[k, a, b]:
                    continue
                x = x_left_m + cc[k] * res_m + (b + 0.5) * step
                best = 1e30
                for q in range(segments.shape[0]):
                    x0, y0, x1, y1 = segments[q, 0], segments[q, 1], segments[q, 2], segments[q, 3]
                    dx, dy = x1 - x0, y1 - y0
                    ll = dx * dx + dy * dy
                    t = ((x - x0) * dx + (y - y0) * dy) / ll if ll > 0.0 else 0.0
                    t = min(max(t, 0.0), 1.0)
                    ex, ey = x0 + t * dx - x, y0 + t * dy - y
                    d2 = ex * ex + ey * ey
                    if d2 < best:
                        best = d2
                out[k, a, b] = np.uint8(min(255.0, math.floor(math.sqrt(best) * 100.0 + 0.5)))
    return out


def footprint_occluder(dsm: HeightRaster, ground_m: np.ndarray, footprints: np.ndarray, *,
                       slab_m: float = OVERHANG_SLAB_M, reach_m: float = OVERHANG_REACH_M,
                       above_m: float = OVERHANG_ABOVE_M, sub_cell_m: float = SUB_CELL_M,
                       crown_base_m: np.ndarray | None = None) -> FootprintOccluder:
    """The ``FootprintOccluder`` of ``dsm`` (a window in the project CRS) with the footprint polygons (project CRS)
    and ``ground_m``, the DEM at the DSM's cell centres (same shape; ``ortho.rectify.heights_on_grid``);
    ``crown_base_m`` as ``occluder_of_cells``."""
    cells = footprint_cells(dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.heights_m.shape, footprints, reach_m=reach_m,
                            sub_cell_m=sub_cell_m)
    return occluder_of_cells(dsm, ground_m, cells, slab_m=slab_m, above_m=above_m, crown_base_m=crown_base_m)


def eave_widths_m(cells: FootprintCells, taken: np.ndarray, res_m: float) -> np.ndarray:
    """Per label (0 .. len(polygons)) the width of the building's eave overhang beyond its wall line: the roof's area
    outside the footprint (the roof cells of its reach, ``taken``, by their sub-cells outside every footprint: the
    DSM samples the roof at its cell centres, so the count of roof cells is the roof's area without bias) over the
    footprint's perimeter, within 0 .. ``EAVE_MAX_M``; ``EAVE_MAX_M`` for a footprint whose reach the window cuts
    (and label 0)."""
    n = len(cells.polygons) + 1
    sub2 = cells.sub * cells.sub
    lab = cells.label[taken]
    outside_m2 = np.bincount(lab, weights=(sub2 - cells.inside[taken].astype(np.float64)) / sub2 * res_m * res_m,
                             minlength=n)
    dh, dw = cells.label.shape
    rc = cells.reach_cells - np.array([cells.origin[0], cells.origin[0], cells.origin[1], cells.origin[1]])
    whole = (rc[:, 0] >= 0) & (rc[:, 1] <= dh) & (rc[:, 2] >= 0) & (rc[:, 3] <= dw)
    out = np.full(n, EAVE_MAX_M)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.clip(outside_m2[1:] / cells.perimeter_m, 0.0, EAVE_MAX_M)
    out[1:] = np.where(whole & np.isfinite(w), w, EAVE_MAX_M)
    return out


@dataclasses.dataclass(frozen=True)
class RoofCandidates:
    """A window's roof cells near the footprints (``roof_candidates``): ``taken`` (bool) the cells of a footprint's
    reach more than ``above_m`` above the ground, ``over`` those of them not wholly inside a footprint (the
    overhangs), their rows and columns ``rows``, ``cols`` (row-major), and per label the eave widths
    ``eave_width_m`` (``eave_widths_m``). What the occluder and the heights by the roof outlines both take from one
    surface: made once a frame when both read the same (``occluder_of_cells``, ``outline_heights``)."""

    taken: np.ndarray
    over: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    eave_width_m: np.ndarray
    above_m: float


def roof_candidates(cells: FootprintCells, top_m: np.ndarray, ground_m: np.ndarray, res_m: float,
                    above_m: float = OVERHANG_ABOVE_M) -> RoofCandidates:
    """The ``RoofCandidates`` of a window: its ``FootprintCells``, surface ``top_m`` (float32), ``ground_m`` (the DEM
    at its cell centres) and cell size ``res_m``."""
    dh, dw = top_m.shape
    taken = np.zeros((dh, dw), np.bool_)
    over = np.zeros((dh, dw), np.bool_)
    rr, cc = _overhang_cells(cells.label, cells.inside, top_m, ground_m.astype(np.float32, copy=False),
                             np.float32(above_m), cells.sub * cells.sub, taken, over)
    return RoofCandidates(taken, over, rr, cc, eave_widths_m(cells, taken, res_m), float(above_m))


def _candidates_of(given: RoofCandidates | None, cells: FootprintCells, top_m, ground_m, res_m: float,
                   above_m: float) -> RoofCandidates:
    if given is None:
        return roof_candidates(cells, top_m, ground_m, res_m, above_m)
    if given.above_m != float(above_m) or given.taken.shape != top_m.shape:
        raise ValueError(f"roof candidates of another window or height above the ground ({given.above_m} m, "
                         f"{given.taken.shape}) than asked ({above_m} m, {top_m.shape})")
    return given


def occluder_of_cells(dsm: HeightRaster, ground_m: np.ndarray, cells: FootprintCells, *,
                      slab_m: float = OVERHANG_SLAB_M, above_m: float = OVERHANG_ABOVE_M,
                      crown_base_m: np.ndarray | None = None,
                      candidates: RoofCandidates | None = None) -> FootprintOccluder:
    """The ``FootprintOccluder`` of ``dsm`` (a window in the project CRS) from its ``FootprintCells`` (same grid, e.g.
    ``FootprintCells.window`` of a larger one) and ``ground_m`` (float32, as ``footprint_occluder``). What depends on
    the window (a building's eave line and eave width from its cells in the window, the cells beside an overhang) is
    taken here, so the occluder is the same whether the cells were rasterised for this window or cut from a larger
    one. The slab of an overhang (and beside it) spans only the sub-cells within the building's roof outline: the
    footprint grown by its eave width (``eave_widths_m``). ``crown_base_m`` (same shape, NaN: none): a cell near no
    footprint whose crown base lies below its top blocks only between the two (``with_crown_base``). The cell loops
    compiled (``_overhang_cells``, ``_beside_overhangs``). ``candidates``: ``roof_candidates`` of this window, ``dsm``
    and ``ground_m`` when the caller has them (made here otherwise)."""
    top = dsm.heights_m
    dh, dw = top.shape
    sub = cells.sub
    base = np.full((dh, dw), -np.inf, np.float32)
    slab_top = np.full((dh, dw), -np.inf, np.float32)
    sub_index = np.full((dh, dw), -1, np.int32)
    # candidates: overhangs, or roof inside the walls
    cand = _candidates_of(candidates, cells, top, ground_m, dsm.res_m, above_m)
    taken, over, rr, cc_ = cand.taken, cand.over, cand.rows, cand.cols
    lab = cells.label[rr, cc_]
    # the underside: the building's eave line less the slab, flat under the whole overhang (a pitched roof's
    # overhang rises inwards and up its gable ends; what lies under it is the soffit at the eave line's level, or
    # the roof itself); the slab reaches up to the eave line at least (a cell lower than it, e.g. filled between
    # the LiDAR's returns in a wall's shadow, lies under the eave)
    eave = _eave_lines(lab, top[rr, cc_], len(cells.polygons) + 1)[lab]
    over_base = eave - slab_m
    base[rr, cc_] = over_base
    slab_top[rr, cc_] = np.maximum(top[rr, cc_], eave)
    # the eave's edge lies anywhere within the cell beyond the last one sampled on the roof (a DSM samples the roof
    # at its cell centres): the cells beside an overhang that are not roof nor candidates (the ground, lower than
    # the overhang) carry its soffit slab as well (the lowest of the overhangs beside it), so that no ray passes
    # through the part of the eave the DSM missed; the slab reaches half a cell into such a cell from each overhang
    # beside it: the sub-cells whose centres lie within half a cell of that side (or corner)
    hr, hc, halo_masks = _beside_overhangs(rr, cc_, over_base.astype(np.float32), taken, over, sub, np.float32(slab_m),
                                           base, slab_top)
    # the roof outline (the footprint grown by the building's eave width): an overhang's slab, and the half cell
    # beside it, only over the sub-cells within it; the wall's sub-cells (inside the footprint) a column as before.
    # Masks: 1 a wall sub-cell, 2 a slab sub-cell, 4 (at [0, 0]) the slab over the whole cell. The march takes the
    # outline between sub-cell centres from their margins (``sub_margin_cm``): a sub-cell's centre samples the
    # distance to the footprint, its square does not lie within the outline because its centre does (its outer half
    # reached up to half a sub-cell beyond the eave, where rays that clear the roof's edge passed)
    width_cm = np.rint(cand.eave_width_m * 100.0)
    margin = _outline_margin_cm(cells, rr, cc_, lab, width_cm)
    outline = margin >= 0
    half_cm = 50.0 * dsm.res_m / sub  # half a sub-cell
    # the slab over the whole cell where every sub-cell lies within the outline (its centre half a sub-cell inside)
    whole = (margin >= half_cm).all(axis=(1, 2))
    walls = cells.inside[rr, cc_] > 0
    # an overhang cell wholly beyond the roof outline (every sub-cell centre more than half a sub-cell beyond it), no
    # wall in it, stops no ray: base +inf (``_cell_blocks``: the same answer as its empty mask's walk, without it),
    # and out of the march's bounds
    void = ~walls & (margin < -half_cm).all(axis=(1, 2))
    base[rr[void], cc_[void]] = np.inf
    slab_top[rr[void], cc_[void]] = -np.inf
    masked = (walls | ~whole) & ~void
    wall_bits = np.zeros((int(masked.sum()), sub, sub), np.uint8)
    wall_bits[walls[masked]] = cells.wall_masks[cells.wall_index[rr[walls], cc_[walls]]]
    over_masks = wall_bits | (2 * outline[masked]).astype(np.uint8)
    over_masks[whole[masked], 0, 0] |= 4
    over_margin = margin[masked]
    sub_index[rr[masked], cc_[masked]] = np.arange(int(masked.sum()), dtype=np.int32)
    near = halo_masks.astype(np.bool_)  # the half cell next to an overhang
    halo_margin = np.where(near, _outline_margin_cm(cells, hr, hc, cells.label[hr, hc], width_cm), MARGIN_NONE)
    halo_masks = (2 * (near & (halo_margin >= 0))).astype(np.uint8)
    # a cell beside an overhang whose half cell lies wholly beyond the roof outline carries no slab: its own column
    # only (the same answer, without the sub-cell walk)
    empty = ~(near & (halo_margin >= -half_cm)).any(axis=(1, 2))
    base[hr[empty], hc[empty]] = -np.inf
    slab_top[hr[empty], hc[empty]] = -np.inf
    hr, hc, halo_masks, halo_margin = hr[~empty], hc[~empty], halo_masks[~empty], halo_margin[~empty]
    sub_index[hr, hc] = HALO - (len(over_masks) + np.arange(len(hr), dtype=np.int32))
    occluder = FootprintOccluder(base, slab_top, sub_index, np.concatenate([over_masks, halo_masks]), sub,
                                 np.concatenate([over_margin, halo_margin]).astype(np.int16))
    if crown_base_m is None:
        return occluder
    return with_crown_base(occluder, top, crown_base_m, cells.label == 0)


@dataclasses.dataclass(frozen=True)
class OutlineHeights:
    """The heights of the true ortho's cells on their own side of the roof outlines (``outline_heights``): ``ground``
    the DSM window with its cells within a roof outline replaced by the DEM (what a cell beyond every outline lies
    on), ``roof`` the same window with its cells beyond every outline replaced by the nearest roof cell's height (what
    a cell within an outline lies on; at the cells such a cell reads, ``outline_reach``: the others keep the DSM's),
    ``outlines`` the roof outlines that reach into the window (shapely polygons, project CRS: each footprint grown by
    its building's eave width, ``eave_widths_m``), their ``tree`` (shapely STRtree) and ``shapes`` (their GeoJSON-like
    mappings, as rasterio burns them: converted once a frame, not once a tile). A cell beside a wall then lies at its
    own side's height, not part way up the bilinear ramp between the roof and the ground."""

    ground: HeightRaster
    roof: HeightRaster
    outlines: np.ndarray
    tree: object
    shapes: tuple


def outline_heights(dsm: HeightRaster, ground_m: np.ndarray, cells: FootprintCells, *,
                    above_m: float = OVERHANG_ABOVE_M, outline_top_m: np.ndarray | None = None,
                    candidates: RoofCandidates | None = None) -> OutlineHeights:
    """The ``OutlineHeights`` of ``dsm`` (a window, project CRS) from its ``FootprintCells`` and ``ground_m`` (the DEM
    at its cell centres, as ``occluder_of_cells``): the roof outlines are those of the occluder (the same eave widths:
    from ``outline_top_m``, the occlusion test's surface on the same window, where it has its own, else ``dsm``'s);
    a DSM cell is roof where its centre lies within an outline. With ``outline_top_m`` the cells of ``dsm`` beyond
    every outline that stand as a roof within a footprint's reach (more than ``above_m`` above the ground: the
    highest return per cell stands a roof up to a cell wider than the outline) are the ground's too, as the occluder
    has them (an overhang cell beyond the outline stops no ray). Only the outlines that reach into the window are
    grown and burnt (``cells.polygons`` are the block's when the cells were cut from the block's): the others burn
    no cell of it. ``candidates``: ``roof_candidates`` of the outlines' surface (``outline_top_m``, else ``dsm``) on
    this window when the caller has them (the occluder's: made here otherwise)."""
    import shapely
    from rasterio.features import rasterize
    from rasterio.transform import from_origin

    from ortho.dem import HeightRaster

    top = dsm.heights_m
    dh, dw = top.shape
    ground32 = ground_m.astype(np.float32, copy=False)
    cand = _candidates_of(candidates, cells, top if outline_top_m is None else outline_top_m, ground32, dsm.res_m,
                          above_m)
    width_m = np.rint(cand.eave_width_m[1:] * 100.0) / 100.0  # as the margins' cm
    # an outline lies within its footprint's bounds grown by its eave width (at most EAVE_MAX_M)
    boxes = outline_cell_boxes(cells.polygons, dsm.x_left_m, dsm.y_top_m, dsm.res_m, (dh, dw), grow_m=EAVE_MAX_M)
    here = (boxes[:, 1] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 2])
    outlines = shapely.buffer(cells.polygons[here], width_m[here]) if here.any() else cells.polygons[here]
    shapes = tuple(shapely.geometry.mapping(g) for g in outlines)
    roof = np.zeros((dh, dw), np.bool_)
    near = roof
    if shapes:
        transform = from_origin(dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.res_m)
        roof = rasterize(((g, 1) for g in shapes), out_shape=(dh, dw), transform=transform,
                         dtype="uint8").astype(np.bool_)
        near = outline_reach(rasterize(((g, 1) for g in shapes), out_shape=(dh, dw), transform=transform,
                                       all_touched=True, dtype="uint8"))
    beyond = np.zeros((dh, dw), np.bool_)
    if outline_top_m is not None:
        beyond = ~roof & (cells.label > 0) & (top - ground32 > above_m)
    ground = np.where(roof | beyond, ground32, top).astype(np.float32)
    roof_heights = top.copy()
    if roof.any() and not roof.all():
        nearest_roof_heights(top, roof, near, out=roof_heights)
    return OutlineHeights(HeightRaster(ground, dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.crs, dsm.source),
                          HeightRaster(roof_heights, dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.crs, dsm.source),
                          outlines, shapely.STRtree(outlines), shapes)


OUTLINE_BOX_PAD_CELLS = 2  # an output cell within an outline reads the DSM cells around it: at most 1 beyond its box
NEAREST_ROOF_RADIUS_CELLS = 32  # how far from a cell its nearest roof cell is looked for before the whole window's


def outline_cell_boxes(outlines: np.ndarray, x_left_m: float, y_top_m: float, res_m: float,
                       shape: tuple[int, int], grow_m: float = 0.0) -> np.ndarray:
    """Per polygon (shapely, project CRS) the cells of the north-up grid (top-left corner, cell size, ``shape``) its
    bounds grown by ``grow_m`` touch, ``OUTLINE_BOX_PAD_CELLS`` more each side, clipped to the grid: int64 (N, 4)
    row0, row1, col0, col1 (row1 <= row0 or col1 <= col0: none, e.g. a polygon off the grid or empty)."""
    import shapely

    dh, dw = shape
    b = shapely.bounds(outlines).reshape(-1, 4) + np.array([-grow_m, -grow_m, grow_m, grow_m])
    ok = np.isfinite(b).all(axis=1)
    b = np.where(ok[:, None], b, 0.0)
    pad = OUTLINE_BOX_PAD_CELLS
    boxes = np.stack([np.floor((y_top_m - b[:, 3]) / res_m) - pad, np.ceil((y_top_m - b[:, 1]) / res_m) + pad,
                      np.floor((b[:, 0] - x_left_m) / res_m) - pad, np.ceil((b[:, 2] - x_left_m) / res_m) + pad],
                     axis=1).astype(np.int64)
    boxes[:, :2] = np.clip(boxes[:, :2], 0, dh)
    boxes[:, 2:] = np.clip(boxes[:, 2:], 0, dw)
    boxes[~ok] = 0
    return boxes


def outline_reach(touched: np.ndarray) -> np.ndarray:
    """The DSM cells an output cell within a roof outline reads (bool): ``touched`` (uint8, the cells the outlines
    touch, ``all_touched``) grown by ``OUTLINE_BOX_PAD_CELLS`` (a cell's bilinear heights read the cells around it)."""
    import cv2

    k = 2 * OUTLINE_BOX_PAD_CELLS + 1
    return cv2.dilate(touched, np.ones((k, k), np.uint8)).astype(np.bool_)


def nearest_roof_heights(top_m: np.ndarray, roof: np.ndarray, need: np.ndarray, out: np.ndarray,
                         max_radius: int = NEAREST_ROOF_RADIUS_CELLS) -> np.ndarray:
    """Into ``out`` at the cells ``need`` (bool; e.g. ``outline_reach``) that are not ``roof`` the height ``top_m``
    of their nearest roof cell, the cell ``scipy.ndimage.distance_transform_edt``'s feature transform of the whole
    grid gives (its ties: the smallest column, then the smallest row; ``_nearest_roof_cells``), looked for within
    ``max_radius`` cells of each, not over the whole window (the band around the outlines: on the demo a few % of
    its windows' cells); a cell with none that near is compared with every roof cell. ``out`` elsewhere untouched;
    returned."""
    dh, dw = roof.shape
    missed = np.zeros((dh, dw), np.bool_)
    n_missed = _nearest_roof_cells(roof, need, top_m, out, int(max_radius), missed)
    if n_missed:  # e.g. beside an outline the window cuts, its roof beyond the window: every roof cell compared
        rr, cc = np.nonzero(roof)
        mr, mc = np.nonzero(missed)
        _nearest_roof_of_all(rr, cc, mr, mc, top_m, out)
    return out


@numba.njit(cache=True, nogil=True)
def _nearest_roof_of_all(roof_rows, roof_cols, rows, cols, top, out):
    """``_nearest_roof_cells`` of the cells (``rows``, ``cols``) among every roof cell (``roof_rows``, ``roof_cols``,
    row-major), the same ties."""
    for t in range(len(rows)):
        r = rows[t]
        c = cols[t]
        best = -1
        br = -1
        bc = -1
        for q in range(len(roof_rows)):
            i = roof_rows[q]
            j = roof_cols[q]
            d = (i - r) * (i - r) + (j - c) * (j - c)
            if best < 0 or d < best or (d == best and (j < bc or (j == bc and i < br))):
                best = d
                br = i
                bc = j
        out[r, c] = top[br, bc]


@numba.njit(cache=True, nogil=True)
def _nearest_roof_cells(roof, need, top, out, max_radius, missed):
    """For each cell ``need`` and not ``roof``: ``top`` of its nearest ``roof`` cell into ``out``, ties as
    ``scipy.ndimage.distance_transform_edt``'s feature transform breaks them (its pass down each column keeps the upper
    of two equally near cells, its pass along each row the leftmost column of the equally near: of the equally near
    cells the smallest column, then the smallest row); searched ring by ring (Chebyshev radius k holds no cell nearer
    than k) up to ``max_radius``; a cell with none that near is set in ``missed``. Returns how many were missed."""
    dh, dw = roof.shape
    n_missed = 0
    for r in range(dh):
        for c in range(dw):
            if not need[r, c] or roof[r, c]:
                continue
            best = -1
            br = -1
            bc = -1
            for k in range(1, max_radius + 1):
                if best >= 0 and k * k > best:
                    break
                for i in range(max(r - k, 0), min(r + k, dh - 1) + 1):
                    di = i - r
                    step = 1 if di == -k or di == k else 2 * k
                    for j in range(c - k, c + k + 1, step):
                        if j < 0 or j >= dw or not roof[i, j]:
                            continue
                        dj = j - c
                        d = di * di + dj * dj
                        if best < 0 or d < best or (d == best and (j < bc or (j == bc and i < br))):
                            best = d
                            br = i
                            bc = j
            if best < 0:
                missed[r, c] = True
                n_missed += 1
            else:
                out[r, c] = top[br, bc]
    return n_missed


def _outline_margin_cm(cells: FootprintCells, rr, cc, lab, width_cm) -> np.ndarray:
    """(len(rr), sub, sub) int16: per sub-cell of cells (rr, cc) how far (cm) its centre lies within the roof outline
    of footprint ``lab`` (``width_cm`` its eave width less the centre's distance to the footprint; negative beyond
    it); ``MARGIN_ALL`` where the cell has no distances (label 0, none rasterised)."""
    sub = cells.sub
    out = np.full((len(rr), sub, sub), MARGIN_ALL, np.int16)
    e = cells.edge_index[rr, cc]
    has = (e >= 0) & (lab > 0)
    out[has] = width_cm[lab[has]][:, None, None].astype(np.int16) - cells.edge_cm[e[has]].astype(np.int16)
    return out


def with_crown_base(occluder: FootprintOccluder | None, top_m: np.ndarray, crown_base_m: np.ndarray,
                    where: np.ndarray | None = None) -> FootprintOccluder:
    """``occluder`` (None: none, every cell a column) with tree crowns: a cell that is a solid column there (and
    ``where``, e.g. near no footprint) whose crown base (``crown_base_m``, the lowest vegetation return of the cell;
    NaN: none) lies below its top ``top_m`` blocks a ray only between the two, the crown (``_cell_blocks``: a slab
    of the whole cell); a ray beneath the crown base passes (the trunk ignored)."""
    if occluder is None:
        occluder = FootprintOccluder(np.full(top_m.shape, -np.inf, np.float32), np.full(top_m.shape, -np.inf, np.float32),
                                     np.full(top_m.shape, -1, np.int32), np.zeros((0, 1, 1), np.uint8), 1,
                                     np.zeros((0, 1, 1), np.int16))
    crown = (occluder.base_m == -np.inf) & (crown_base_m < top_m)  # NaN: False
    if where is not None:
        crown &= where
    base = occluder.base_m.copy()
    slab_top = occluder.slab_top_m.copy()
    sub_index = occluder.sub_index.copy()
    base[crown] = crown_base_m[crown]
    slab_top[crown] = top_m[crown]
    sub_index[crown] = CROWN
    return dataclasses.replace(occluder, base_m=base, slab_top_m=slab_top, sub_index=sub_index)


@numba.njit(cache=True, nogil=True)
def _overhang_cells(label, inside, top, ground, above_m, sub2, taken, over):
    """The candidates (near a footprint, more than ``above_m`` above the ground: ``taken``) and among them the
    overhangs (not wholly inside a footprint: ``over``) of a window; the overhangs' rows and columns, row-major."""
    dh, dw = label.shape
    n = 0
    for r in range(dh):
        for c in range(dw):
            if label[r, c] > 0 and top[r, c] - ground[r, c] > above_m:
                taken[r, c] = True
                if inside[r, c] < sub2:
                    over[r, c] = True
                    n += 1
    rr = np.empty(n, np.int64)
    cc = np.empty(n, np.int64)
    k = 0
    for r in range(dh):
        for c in range(dw):
            if over[r, c]:
                rr[k] = r
                cc[k] = c
                k += 1
    return rr, cc


@numba.njit(cache=True, nogil=True)
def _beside_overhangs(rr, cc, over_base, taken, over, sub, slab_m, base, slab_top):
    """The cells beside an overhang (a neighbour of one of the 8 directions, not ``taken``): the lowest underside of the
    overhangs beside it into ``base`` (and + ``slab_m`` into ``slab_top``); their rows, columns (row-major) and
    sub-cell masks (within half a cell of each overhang beside it)."""
    dh, dw = taken.shape
    # the cells beside the overhangs lie within their box grown by a cell: scanned there only, row-major as the
    # whole window (on the demo the box is the whole window in most frames, a third of it in the block's edge ones)
    i0, i1, j0, j1 = dh, 0, dw, 0
    for k in range(len(rr)):
        i0 = min(i0, max(rr[k] - 1, 0))
        i1 = max(i1, min(rr[k] + 2, dh))
        j0 = min(j0, max(cc[k] - 1, 0))
        j1 = max(j1, min(cc[k] + 2, dw))
    lowest = np.full((max(i1 - i0, 0), max(j1 - j0, 0)), np.inf, np.float32)
    for k in range(len(rr)):
        for di in range(-1, 2):
            for dj in range(-1, 2):
                i = rr[k] + di
                j = cc[k] + dj
                if (di != 0 or dj != 0) and i >= 0 and j >= 0 and i < dh and j < dw and not taken[i, j] \
                        and over_base[k] < lowest[i - i0, j - j0]:
                    lowest[i - i0, j - j0] = over_base[k]
    n = 0
    for i in range(i0, i1):
        for j in range(j0, j1):
            if lowest[i - i0, j - j0] < np.inf:
                n += 1
    hr = np.empty(n, np.int64)
    hc = np.empty(n, np.int64)
    masks = np.zeros((n, sub, sub), np.uint8)
    near = np.empty(sub, np.bool_)
    for t in range(sub):
        near[t] = (t + 0.5) / sub <= 0.5
    k = 0
    for i in range(i0, i1):
        for j in range(j0, j1):
            low = lowest[i - i0, j - j0]
            if not low < np.inf:
                continue
            hr[k] = i
            hc[k] = j
            base[i, j] = low
            slab_top[i, j] = low + slab_m
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    ii = i + di
                    jj = j + dj
                    if (di == 0 and dj == 0) or ii < 0 or jj < 0 or ii >= dh or jj >= dw or not over[ii, jj]:
                        continue
                    for a in range(sub):
                        row_ok = near[a] if di < 0 else near[sub - 1 - a] if di > 0 else True
                        for b in range(sub):
                            col_ok = near[b] if dj < 0 else near[sub - 1 - b] if dj > 0 else True
                            if row_ok and col_ok:
                                masks[k, a, b] = 1
            k += 1
    return hr, hc, masks
