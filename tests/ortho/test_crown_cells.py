"""Tree crowns within the cells they cover in the march (``ortho.crown_cells``, issue 42)."""

import numpy as np
import pytest

from ortho.crown_cells import with_crown_sub_cells
from ortho.rectify_kernels import _cell_blocks

SUB, TOP_M, TOL_M = 5, 10.0, 0.3


def _walls(occ):
    if occ is None:  # main: every cell a solid column
        return (False, np.zeros((1, 1), np.float32), np.zeros((1, 1), np.float32), np.zeros((1, 1), np.int32),
                np.zeros((1, 1, 1), np.uint8), 1, np.zeros((1, 1, 1), np.int16))
    return (True, occ.base_m, occ.slab_top_m, occ.sub_index, occ.sub_masks, occ.sub, occ.sub_margin_cm)


@pytest.mark.parametrize(("gx", "blocked"), [(1.2, True), (1.35, True), (1.45, False), (1.7, False)])
def test_a_ray_beside_the_crowns_sub_cells_passes(gx, blocked):
    # a 3 x 3 DSM of 0.5 m cells, the middle one a crown 10 m high over its two western sub-cell columns only (the
    # returns' rim at 0.4 of the cell); a ray from the ground north across it, 0.05 m up where it enters
    top = np.zeros((3, 3), np.float32)
    top[1, 1] = TOP_M
    bits = np.zeros((3, 3), np.uint32)
    bits[1, 1] = sum(1 << (u * SUB + v) for u in range(SUB) for v in range(2))
    occ = with_crown_sub_cells(None, top, bits, SUB)
    ray = (0.0, 0.1, gx, 2.5, 0.0, -1.0, TOL_M)  # Z, rise per cell, gx, gy, ex, ey (north), tolerance
    span = (0.5, 1.5)
    assert _cell_blocks(top[1, 1], 1, 1, ray, span, _walls(None))  # main: the whole cell a column
    assert _cell_blocks(top[1, 1], 1, 1, ray, span, _walls(occ)) == blocked
    # above the crown's top it passes either way; the other cells are as they were (solid columns, here ground)
    high = (TOP_M, 0.1, gx, 2.5, 0.0, -1.0, TOL_M)
    assert not _cell_blocks(top[1, 1], 1, 1, high, span, _walls(occ))
    assert occ.sub_index[1, 1] == 0 and (np.delete(occ.base_m.ravel(), 4) == -np.inf).all()


def test_crowns_kept_where_the_occluder_has_a_slab_and_sub_cells_must_agree():
    top = np.full((2, 2), TOP_M, np.float32)
    bits = np.full((2, 2), 3, np.uint32)
    occ = with_crown_sub_cells(None, top, bits, SUB)
    again = with_crown_sub_cells(occ, top, bits, SUB)  # the cells have masks now: left as they are
    assert (again.sub_index == occ.sub_index).all() and len(again.sub_masks) == 4
    with pytest.raises(ValueError, match="sub-cells a side"):
        with_crown_sub_cells(occ, top, bits, 4)
