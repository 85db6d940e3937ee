"""Tree crowns within the cells they cover, in the true ortho's occlusion test (issue 42).

The occlusion test takes each DSM cell as a column over its whole square. At a crown's rim the nearest-return DSM
(``dsm_nearest.tif``) stands a cell whose centre's nearest return is a crown's at the crown's height, and the march
stops the lines of sight that pass beside the crown over the part of the cell the crown does not cover. Given the
crown's sub-cells per cell (``lidarctl.rasters.crown_rim.crown_sub_cells``: the sub-cell centres nearer a vegetation
return than any other, the rim half way between the returns as ``dsm_nearest`` puts it between cells), such a cell
is a column up to its top over those sub-cells only: ``FootprintOccluder``'s mask of wall sub-cells (bit 1), no
slab (``ortho.rectify_kernels._cell_blocks``) (a trial, not in the chain).

The chain's since: the trees' crowns as disks fitted to their returns (``lidarctl.rasters.crown_model``,
lidar_out/crowns.gpkg; ``read_crowns``), the cells they cover a crown from the tree's base up over the disks only
(``with_crown_disks``; ``ortho rectify --crowns``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ortho.footprints import MARGIN_NONE, FootprintOccluder


def _occluder_of_sub(occluder: FootprintOccluder | None, shape: tuple[int, int], sub: int) -> FootprintOccluder:
    """``occluder``, or one of ``shape`` in which every cell is a solid column (None); ``ValueError`` for a footprint
    occluder with sub-cells of another ``sub`` per side than the crowns'."""
    if occluder is None:
        return FootprintOccluder(np.full(shape, -np.inf, np.float32), np.full(shape, -np.inf, np.float32),
                                 np.full(shape, -1, np.int32), np.zeros((0, sub, sub), np.uint8), sub,
                                 np.zeros((0, sub, sub), np.int16))
    if occluder.sub != sub and len(occluder.sub_masks):
        raise ValueError(f"the occluder's cells have {occluder.sub} sub-cells a side, the crowns' {sub}")
    return occluder


def with_crown_sub_cells(occluder: FootprintOccluder | None, top_m: np.ndarray, crown_bits: np.ndarray,
                         sub: int) -> FootprintOccluder:
    """``occluder`` (None: none, every cell a column) with each cell that is a solid column there and has crown
    bits (``crown_bits``, uint32 on its grid, bit ``u * sub + v`` the sub-cell of row u from the north, column v from
    the west; 0: none, the cell as it was) a column up to its top (``top_m``, the occlusion DSM) over those
    sub-cells only. ``sub``: the occluder's sub-cells per
    side (5 at a 0.5 m DSM with footprints); a footprint occluder of another ``sub``: ``ValueError``."""
    shape = crown_bits.shape
    occluder = _occluder_of_sub(occluder, shape, sub)
    rows, cols = np.nonzero((crown_bits != 0) & (occluder.base_m == -np.inf))
    k0 = len(occluder.sub_masks)
    u, v = np.divmod(np.arange(sub * sub), sub)
    masks = ((crown_bits[rows, cols][:, None] >> (u * sub + v).astype(np.uint32)) & 1).astype(np.uint8)
    base, slab_top, sub_index = occluder.base_m.copy(), occluder.slab_top_m.copy(), occluder.sub_index.copy()
    # no slab (its underside at +inf); ``_cell_blocks`` walks the wall sub-cells of a column the ray crosses until
    # the ray is above the "slab's" top, the cell's own (the march's bounds stay the DSM's plus the tolerance)
    base[rows, cols] = np.inf
    slab_top[rows, cols] = top_m[rows, cols]
    sub_index[rows, cols] = k0 + np.arange(len(rows), dtype=np.int32)
    return dataclasses.replace(
        occluder, base_m=base, slab_top_m=slab_top, sub_index=sub_index, sub=sub,
        sub_masks=np.concatenate([occluder.sub_masks.reshape(-1, sub, sub), masks.reshape(-1, sub, sub)]),
        sub_margin_cm=np.concatenate([occluder.sub_margin_cm.reshape(-1, sub, sub),
                                      np.full((len(rows), sub, sub), MARGIN_NONE, np.int16)]))


@dataclasses.dataclass(frozen=True)
class CrownDisks:
    """Tree crowns as disks (``lidarctl rasters``' lidar_out/crowns.gpkg): centre ``x_m``, ``y_m``, ``radius_m``,
    ``top_m`` and crown base ``base_m`` in the units of the grid they meet (``read_crowns``: lengths in the project
    CRS's unit, as the occlusion DSM's cells; heights in the DSM's height unit and system)."""

    x_m: np.ndarray
    y_m: np.ndarray
    radius_m: np.ndarray
    top_m: np.ndarray
    base_m: np.ndarray

    def __len__(self) -> int:
        return len(self.x_m)


CROWN_FIELDS = ("x_m", "y_m", "radius_m", "top_m", "base_m")


def read_crowns(path, project_crs, height_unit_m: float | None = None) -> CrownDisks:
    """The crowns of the GeoPackage ``path`` (its first layer, in ``project_crs``, with the fields
    ``CROWN_FIELDS``) in the grid's units: lengths in ``project_crs``'s unit, heights in ``height_unit_m`` metres
    per unit (None: the height unit of the file's CRS, the DSM's the crowns were fitted on: its vertical CRS's, else
    its horizontal unit). The fields hold metres (``aerotri.geom.crown_disks.CROWNS_IN_METRES_NOTE``); a file in a
    CRS whose lengths or heights are not metres without that note in its layer's description was written before
    (main up to 2026-12-01) and holds them in its CRS's units: read so. ``InputError`` naming the file and what
    was expected otherwise."""
    from pathlib import Path

    import pyogrio
    from pyproj import CRS as _CRS

    from aerotri.core.errors import InputError
    from aerotri.geom.crown_disks import CROWNS_IN_METRES_NOTE
    from aerotri.geom.crs.definition import height_unit_m as _height_unit_m
    from aerotri.geom.crs.definition import linear_unit_m, same_horizontal

    path = Path(path)
    what = (f"expected the tree crowns of lidarctl rasters (lidar_out/crowns.gpkg: fields {', '.join(CROWN_FIELDS)}) "
            "in the project CRS")
    if not path.is_file():
        raise InputError(f"{path}: crowns file not found; {what}")
    try:
        meta, _, _, fields = pyogrio.raw.read(str(path), read_geometry=False, columns=list(CROWN_FIELDS))
    except Exception as e:  # pyogrio's DataSourceError, a missing field, ...
        raise InputError(f"{path}: cannot read its crowns ({str(e).splitlines()[0]}); {what}") from None
    if meta.get("crs") is None or not same_horizontal(_CRS.from_user_input(meta["crs"]), project_crs):
        raise InputError(f"{path}: the crowns are in {meta.get('crs') or 'no CRS'}; {what} "
                         f"({project_crs.to_string()})")
    names = list(meta.get("fields", []))
    missing = [f for f in CROWN_FIELDS if f not in names]
    if missing:
        raise InputError(f"{path}: no field {', '.join(missing)}; {what}")
    cols = {f: np.asarray(fields[names.index(f)], np.float64) for f in CROWN_FIELDS}
    file_crs = _CRS.from_user_input(meta["crs"])
    try:
        description = (pyogrio.read_info(str(path)).get("layer_metadata") or {}).get("DESCRIPTION") or ""
    except Exception:  # (read above: not expected; a file without a description is read as one written before)
        description = ""
    # the fields' units: metres, or the file CRS's (a file written before the note, in a CRS not in metres)
    xy_m, z_m = ((1.0, 1.0) if CROWNS_IN_METRES_NOTE in description else
                 (linear_unit_m(file_crs), _height_unit_m(file_crs)))
    grid_xy_m = linear_unit_m(project_crs)
    grid_z_m = height_unit_m if height_unit_m is not None else _height_unit_m(file_crs)
    if xy_m != grid_xy_m:  # (the same units: the numbers as read)
        cols.update({k: cols[k] * xy_m / grid_xy_m for k in ("x_m", "y_m", "radius_m")})
    if z_m != grid_z_m:
        cols.update({k: cols[k] * z_m / grid_z_m for k in ("top_m", "base_m")})
    bad = ~np.all([np.isfinite(v) for v in cols.values()], axis=0) | (cols["radius_m"] <= 0)
    if bad.any():
        raise InputError(f"{path}: crown {int(np.flatnonzero(bad)[0]) + 1} has a missing value or a radius <= 0; "
                         f"{what}, {int(bad.sum())} such crown(s)")
    return CrownDisks(**cols)


def with_crown_disks(occluder: FootprintOccluder | None, top_m: np.ndarray, x_left_m: float, y_top_m: float,
                     res_m: float, crowns: CrownDisks, sub: int = 5, tolerance_m: float = 0.3,
                     own: bool = False) -> FootprintOccluder:
    """``occluder`` (None: none) with the tree crowns' disks: each cell of the occlusion DSM window (``top_m``, its
    north-west corner at ``x_left_m``, ``y_top_m``, cells of ``res_m``) that is a solid column there, that a disk
    covers at one of its ``sub`` x ``sub`` sub-cell centres and that stands no more than ``tolerance_m`` above the
    covering trees' tops (not a roof) blocks only from the covering trees' lowest crown base up to its top: over the
    whole cell when every sub-cell centre is covered (a crown slab, as ``ortho.footprints.with_crown_base``), else
    over the disks only (the march interpolates the sub-cells' signed distances: the rim between their centres;
    the slab's top the column's less ``tolerance_m``, as the march takes a column). Cells no disk covers are left as
    they are (``lidarctl rasters``' dsm_crowns.tif stands the nearest-return crown beyond the disks at the ground).
    ``own``: ``occluder``'s window arrays are this call's to change (the caller made it for this and drops it), not
    copied (three copies of the frame's window: 0.1 CPU-s a demo block)."""
    from aerotri.geom.crown_disks import TreeCrowns, crown_sub_cells
    from ortho.footprints import CROWN

    shape = top_m.shape
    own = own or occluder is None
    occluder = _occluder_of_sub(occluder, shape, sub)
    trees = TreeCrowns(crowns.x_m, crowns.y_m, crowns.radius_m, crowns.top_m, crowns.base_m,
                       np.zeros(len(crowns), np.int64), np.zeros(len(crowns), bool), 0.0)
    rows, cols, margin_cm, base, tree_top = crown_sub_cells(trees, x0_m=x_left_m, y_top_m=y_top_m, res_m=res_m,
                                                            shape=shape, sub=sub, reach_m=0.0)
    n_in = (margin_cm >= 0).sum(axis=(1, 2))
    top = top_m[rows, cols]
    take = ((n_in > 0) & (occluder.base_m[rows, cols] == -np.inf) & (top <= tree_top + tolerance_m)
            & (base < top))
    rows, cols, margin_cm, base, top, n_in = (a[take] for a in (rows, cols, margin_cm, base, top, n_in))
    whole = n_in == sub * sub
    base_m, slab_top, sub_index = ((a if own else a.copy()) for a in (occluder.base_m, occluder.slab_top_m,
                                                                      occluder.sub_index))
    base_m[rows[whole], cols[whole]] = base[whole]
    slab_top[rows[whole], cols[whole]] = top[whole]
    sub_index[rows[whole], cols[whole]] = CROWN
    part = ~whole
    k0 = len(occluder.sub_masks)
    base_m[rows[part], cols[part]] = base[part]
    slab_top[rows[part], cols[part]] = top[part] - np.float32(tolerance_m)
    sub_index[rows[part], cols[part]] = k0 + np.arange(int(part.sum()), dtype=np.int32)
    return dataclasses.replace(
        occluder, base_m=base_m, slab_top_m=slab_top, sub_index=sub_index, sub=sub,
        sub_masks=np.concatenate([occluder.sub_masks.reshape(-1, sub, sub),
                                  np.where(margin_cm[part] >= 0, 2, 0).astype(np.uint8)]),
        sub_margin_cm=np.concatenate([occluder.sub_margin_cm.reshape(-1, sub, sub), margin_cm[part]]))
