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


def _disk_window(top_middle=TOP_M):
    # a 3 x 3 DSM of 0.5 m cells (north-west corner at 0, 1.5), the middle cell 10 m high; a crown's disk (top 10 m,
    # base 4 m) so large that its rim crosses the middle cell nearly straight, at x = 0.7 m (0.4 of the cell)
    from ortho.crown_cells import CrownDisks

    top = np.zeros((3, 3), np.float32)
    top[1, 1] = top_middle
    crowns = CrownDisks(np.array([0.7 - 50.0]), np.array([0.75]), np.array([50.0]), np.array([TOP_M]),
                        np.array([4.0]))
    return top, crowns


@pytest.mark.parametrize(("gx", "z_m", "blocked"), [(1.2, 5.0, True), (1.35, 5.0, True), (1.45, 5.0, False),
                                                    (1.2, 2.0, False), (1.2, 9.0, True), (1.2, 10.5, False)])
def test_a_fitted_crown_stops_rays_within_its_disk_and_above_its_base_only(gx, z_m, blocked):
    from ortho.crown_cells import with_crown_disks

    top, crowns = _disk_window()
    occ = with_crown_disks(None, top, 0.0, 1.5, 0.5, crowns, SUB, TOL_M)
    ray = (z_m, 0.0, gx, 2.5, 0.0, -1.0, TOL_M)  # level, northwards across the middle cell
    span = (0.5, 1.5)
    assert _cell_blocks(top[1, 1], 1, 1, ray, span, _walls(None)) == (z_m < TOP_M - TOL_M)  # main: a column
    assert _cell_blocks(top[1, 1], 1, 1, ray, span, _walls(occ)) == blocked
    # the cells west of it lie within the disk whole but stand at the ground (below the base): as they were
    assert occ.sub_index[1, 1] == 0 and (np.delete(occ.base_m.ravel(), 4) == -np.inf).all()


def test_a_cell_within_a_crown_whole_is_a_crown_slab_and_a_roof_above_it_stays_a_column():
    from ortho.crown_cells import with_crown_disks
    from ortho.footprints import CROWN

    top, crowns = _disk_window()
    top[1, 0] = TOP_M - 1.0
    occ = with_crown_disks(None, top, 0.0, 1.5, 0.5, crowns, SUB, TOL_M)
    assert occ.sub_index[1, 0] == CROWN and occ.base_m[1, 0] == 4.0 and occ.slab_top_m[1, 0] == TOP_M - 1.0
    roof, _ = _disk_window(TOP_M + 3.0)  # higher than the tree's top: not the crown
    occ = with_crown_disks(None, roof, 0.0, 1.5, 0.5, crowns, SUB, TOL_M)
    assert occ.base_m[1, 1] == -np.inf


def test_crowns_file_errors_name_the_file(tmp_path):
    import shapely
    from pyproj import CRS

    from aerotri.core.errors import InputError
    from aerotri.core.vector_files import VectorLayer, write_layers
    from ortho.crown_cells import read_crowns

    crs = CRS.from_epsg(32611)
    with pytest.raises(InputError, match="crowns file not found"):
        read_crowns(tmp_path / "none.gpkg", crs)
    disk = shapely.Point(0, 0).buffer(2.0)
    good = {"x_m": np.array([0.0]), "y_m": np.array([0.0]), "radius_m": np.array([2.0]), "top_m": np.array([9.0]),
            "base_m": np.array([4.0])}
    write_layers(tmp_path / "c.gpkg", [VectorLayer("crowns", "Polygon", [disk], good)], crs="EPSG:32611")
    assert read_crowns(tmp_path / "c.gpkg", crs).radius_m[0] == 2.0
    with pytest.raises(InputError, match="the crowns are in"):
        read_crowns(tmp_path / "c.gpkg", CRS.from_epsg(32612))
    write_layers(tmp_path / "b.gpkg", [VectorLayer("crowns", "Polygon", [disk], {**good, "radius_m": np.array([0.0])})],
                 crs="EPSG:32611")
    with pytest.raises(InputError, match="crown 1 has a missing value or a radius <= 0"):
        read_crowns(tmp_path / "b.gpkg", crs)
    write_layers(tmp_path / "n.gpkg", [VectorLayer("crowns", "Polygon", [disk], {"x_m": np.array([0.0])})],
                 crs="EPSG:32611")
    with pytest.raises(InputError, match="no field y_m"):
        read_crowns(tmp_path / "n.gpkg", crs)
