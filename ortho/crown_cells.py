"""Tree crowns within the cells they cover, in the true ortho's occlusion test (issue 42).

The occlusion test takes each DSM cell as a column over its whole square. At a crown's rim the nearest-return DSM
(``dsm_nearest.tif``) stands a cell whose centre's nearest return is a crown's at the crown's height, and the march
stops the lines of sight that pass beside the crown over the part of the cell the crown does not cover. Given the
crown's sub-cells per cell (``lidarctl.rasters.crown_rim.crown_sub_cells``: the sub-cell centres nearer a vegetation
return than any other, the rim half way between the returns as ``dsm_nearest`` puts it between cells), such a cell
is a column up to its top over those sub-cells only: ``FootprintOccluder``'s mask of wall sub-cells (bit 1), no
slab (``ortho.rectify_kernels._cell_blocks``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ortho.footprints import MARGIN_NONE, FootprintOccluder


def with_crown_sub_cells(occluder: FootprintOccluder | None, top_m: np.ndarray, crown_bits: np.ndarray,
                         sub: int) -> FootprintOccluder:
    """``occluder`` (None: none, every cell a column) with each cell that is a solid column there and has crown
    bits (``crown_bits``, uint32 on its grid, bit ``u * sub + v`` the sub-cell of row u from the north, column v from
    the west; 0: none, the cell as it was) a column up to its top (``top_m``, the occlusion DSM) over those
    sub-cells only. ``sub``: the occluder's sub-cells per
    side (5 at a 0.5 m DSM with footprints); a footprint occluder of another ``sub``: ``ValueError``."""
    shape = crown_bits.shape
    if occluder is None:
        occluder = FootprintOccluder(np.full(shape, -np.inf, np.float32), np.full(shape, -np.inf, np.float32),
                                     np.full(shape, -1, np.int32), np.zeros((0, sub, sub), np.uint8), sub,
                                     np.zeros((0, sub, sub), np.int16))
    if occluder.sub != sub and len(occluder.sub_masks):
        raise ValueError(f"the occluder's cells have {occluder.sub} sub-cells a side, the crowns' {sub}")
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
