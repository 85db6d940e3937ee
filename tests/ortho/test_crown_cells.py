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


def _crown_sub_cells_per_tree(crowns, *, x0_m, y_top_m, res_m, shape, sub, reach_m=1.0, window=None):
    """``crown_sub_cells`` as it was (a numpy pass per tree, up to 126fd31): the reference of the compiled one."""
    w_r0, w_c0, w_rows, w_cols = window if window is not None else (0, 0, *shape)
    off = (np.arange(sub) + 0.5) / sub
    cells, margins, bases, tops = [], [], [], []
    for t in range(len(crowns)):
        cx, cy, r = crowns.x_m[t], crowns.y_m[t], crowns.radius_m[t]
        r0 = max(w_r0, int((y_top_m - cy - r - reach_m) / res_m))
        r1 = min(w_r0 + w_rows, int((y_top_m - cy + r + reach_m) / res_m) + 1)
        c0 = max(w_c0, int((cx - r - reach_m - x0_m) / res_m))
        c1 = min(w_c0 + w_cols, int((cx + r + reach_m - x0_m) / res_m) + 1)
        if r1 <= r0 or c1 <= c0:
            continue
        rr, cc = np.meshgrid(np.arange(r0, r1), np.arange(c0, c1), indexing="ij")
        ys = y_top_m - (rr.ravel()[:, None, None] + off[None, :, None]) * res_m
        xs = x0_m + (cc.ravel()[:, None, None] + off[None, None, :]) * res_m
        m = r - np.hypot(xs - cx, ys - cy)
        cells.append(rr.ravel() * shape[1] + cc.ravel())
        margins.append(m)
        covers = (np.round(m * 100.0) >= 0).any(axis=(1, 2))
        bases.append(np.where(covers, crowns.base_m[t], np.inf))
        tops.append(np.where(covers, crowns.top_m[t], -np.inf))
    if not cells:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros((0, sub, sub), np.int16), np.zeros(0, np.float32), np.zeros(0, np.float32)
    flat = np.concatenate(cells)
    order = np.argsort(flat, kind="stable")
    flat = flat[order]
    first = np.flatnonzero(np.concatenate([[True], flat[1:] != flat[:-1]]))
    margin = np.maximum.reduceat(np.concatenate(margins)[order], first, axis=0)
    base = np.minimum.reduceat(np.concatenate(bases)[order], first)
    top = np.maximum.reduceat(np.concatenate(tops)[order], first)
    rows, cols = np.divmod(flat[first], shape[1])
    cm = np.clip(np.round(margin * 100.0), -32000, 32000).astype(np.int16)
    return (rows, cols, cm, np.where(np.isfinite(base), base, np.nan).astype(np.float32),
            np.where(np.isfinite(top), top, np.nan).astype(np.float32))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_compiled_crown_sub_cells_are_the_per_tree_numpy_ones_bit_for_bit(seed):
    """``aerotri.geom.crown_disks.crown_sub_cells`` (compiled: the ortho calls it once a frame) gives the arrays of
    the numpy pass per tree it replaced, dtype and bits: 300 overlapping crowns (some beyond the grid's edges, on
    both sides of its origin), cell sizes 0.25 .. 1 m, 3 or 5 sub-cells, reach 0 and 1 m, the whole grid and
    windows."""
    from aerotri.geom.crown_disks import TreeCrowns, crown_sub_cells

    rng = np.random.default_rng(seed)
    n = 300
    x, y = rng.uniform(-20.0, 120.0, n), rng.uniform(-20.0, 100.0, n)
    crowns = TreeCrowns(x, y, rng.uniform(0.4, 6.5, n), rng.uniform(8.0, 25.0, n), rng.uniform(1.0, 6.0, n),
                        np.zeros(n, np.int64), np.zeros(n, bool), 0.0)
    checked = 0
    for res, sub, reach, window in [(0.5, 5, 0.0, None), (0.25, 3, 1.0, None), (1.0, 5, 1.0, (10, 20, 40, 30)),
                                    (0.5, 5, 0.0, (37, 3, 61, 99))]:
        shape = (int(80 / res), int(100 / res))
        kw = dict(x0_m=0.3, y_top_m=80.7, res_m=res, shape=shape, sub=sub, reach_m=reach, window=window)
        new, old = crown_sub_cells(crowns, **kw), _crown_sub_cells_per_tree(crowns, **kw)
        for a, b in zip(new, old):
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
        checked += len(new[0])
    assert checked > 20_000


def test_the_crowns_put_in_the_frames_own_occluder_are_the_same_as_in_a_copy():
    """``with_crown_disks(..., own=True)`` (the frame's occluder changed in place, not copied) gives the arrays of
    the copy; without ``own`` the occluder given is left as it was."""
    from ortho.crown_cells import with_crown_disks
    from ortho.footprints import with_crown_base

    top, crowns = _disk_window()
    given = with_crown_base(None, top, np.full(top.shape, np.nan, np.float32))
    before = [a.copy() for a in (given.base_m, given.slab_top_m, given.sub_index)]
    copied = with_crown_disks(given, top, 0.0, 1.5, 0.5, crowns, SUB, TOL_M)
    assert all(np.array_equal(a, b) for a, b in zip(before, (given.base_m, given.slab_top_m, given.sub_index)))
    in_place = with_crown_disks(given, top, 0.0, 1.5, 0.5, crowns, SUB, TOL_M, own=True)
    for name in ("base_m", "slab_top_m", "sub_index", "sub_masks", "sub_margin_cm"):
        assert np.array_equal(getattr(copied, name), getattr(in_place, name)), name
    assert in_place.base_m is given.base_m and copied.sub_index[1, 1] == 0


def test_crowns_in_metres_read_in_the_grids_units_and_files_of_before_as_they_were(tmp_path):
    """crowns.gpkg holds metres in its _m fields (noted in a foot CRS's file); ``read_crowns`` gives the grid's
    units (Oregon's international-foot grid, heights in feet: 7.4 m radius -> 24.28 ft). A file of a foot CRS
    without the note was written before, in feet: read as it was."""
    import shapely
    from pyproj import CRS

    from aerotri.core.vector_files import VectorLayer, write_layers
    from aerotri.geom.crown_disks import CROWNS_IN_METRES_NOTE
    from ortho.crown_cells import read_crowns

    ft = 0.3048
    crs = CRS.from_epsg(2994)  # NAD83(HARN) / Oregon GIC Lambert (ft), Autzen's
    x_ft, y_ft = 637000.0, 853000.0
    disk = shapely.Point(x_ft, y_ft).buffer(7.4 / ft)
    metres = {"x_m": np.array([x_ft * ft]), "y_m": np.array([y_ft * ft]), "radius_m": np.array([7.4]),
              "top_m": np.array([158.6]), "base_m": np.array([130.0])}
    feet = {k: v / ft for k, v in metres.items()}
    write_layers(tmp_path / "new.gpkg", [VectorLayer("crowns", "Polygon", [disk], metres, note=CROWNS_IN_METRES_NOTE)],
                 crs=crs)
    write_layers(tmp_path / "old.gpkg", [VectorLayer("crowns", "Polygon", [disk], feet)], crs=crs)
    for name in ("new", "old"):
        c = read_crowns(tmp_path / f"{name}.gpkg", crs)
        np.testing.assert_allclose([c.x_m[0], c.y_m[0]], [x_ft, y_ft], rtol=0, atol=1e-6)
        np.testing.assert_allclose([c.radius_m[0], c.top_m[0], c.base_m[0]], [7.4 / ft, 158.6 / ft, 130.0 / ft],
                                   rtol=1e-12)
    # heights asked in metres (a DSM in metres on the foot grid): the new file's as held, the old file's converted
    for name in ("new", "old"):
        c = read_crowns(tmp_path / f"{name}.gpkg", crs, height_unit_m=1.0)
        np.testing.assert_allclose([c.top_m[0], c.base_m[0]], [158.6, 130.0], rtol=1e-12)
        assert abs(c.radius_m[0] - 7.4 / ft) < 1e-9
