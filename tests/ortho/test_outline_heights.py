"""Heights from the cell's own side of the roof outline (issue 42). Constructed: a box building (walls 10.2 .. 20.6 m,
roof 10 m, eave 0.3 m: the roof outline 9.9 .. 20.9 m) on flat ground (0 m), its DSM of 0.5 m sampled at the cell
centres. The DSM's bilinear height of a 0.1 m output cell just beyond the outline lies part way up the wall; with
footprints it is the ground's (0 m), and the cell is imaged where the ground point is (the maps of a DSM without the
building); within the outline it is the roof's (10 m). Without footprints nothing changes."""

from __future__ import annotations

import numpy as np
import shapely

from aerotri.geom.camera import BrownCamera
from aerotri.geom.rotation import rotation_matrix_opk
from ortho.dem import HeightRaster
from ortho.footprints import footprint_cells, outline_heights
from ortho.grid import GridToProject, OrthoGrid
from ortho.rectify import FrameGeometry, fixed_point_maps, heights_by_side, heights_on_grid
# the scene of the roof outline's tests: a 40 x 40 m grid of 0.5 m cells, one building with a 0.3 m eave
from tests.ortho.test_roof_outline_and_crowns import CRS_UTM, EAVE_M, N, RES_M, ROOF_M, WALL


def _dsm(roof_m: float) -> HeightRaster:
    c = (np.arange(N) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 40.0 - c)
    x0, y0, x1, y1 = WALL
    roof = (X > x0 - EAVE_M) & (X < x1 + EAVE_M) & (Y > y0 - EAVE_M) & (Y < y1 + EAVE_M)
    return HeightRaster(np.where(roof, roof_m, 0.0).astype(np.float32), 0.0, 40.0, RES_M, CRS_UTM, "DSM")


def _outline_distance_m(grid: OrthoGrid) -> np.ndarray:
    """Per output cell centre its signed distance to the true roof outline (m, positive beyond it)."""
    x = grid.x_left_m + (np.arange(grid.width) + 0.5) * grid.res_m
    y = grid.y_top_m - (np.arange(grid.height) + 0.5) * grid.res_m
    X, Y = np.meshgrid(x, y)
    outline = shapely.box(*WALL).buffer(EAVE_M)
    pts = shapely.points(X.ravel(), Y.ravel())
    d = shapely.distance(outline.exterior, pts)
    return np.where(shapely.contains(outline, pts), -d, d).reshape(X.shape)


def test_a_ground_cell_beside_a_wall_is_imaged_at_the_ground_height_with_footprints():
    dsm = _dsm(ROOF_M)
    ground = np.zeros(dsm.heights_m.shape, np.float32)
    cells = footprint_cells(0.0, 40.0, RES_M, dsm.heights_m.shape, np.array([shapely.box(*WALL)], dtype=object))
    sides = outline_heights(dsm, ground, cells)
    grid = OrthoGrid(CRS_UTM, 5.0, 26.0, 0.1, 210, 210)  # 5 .. 26 m: the building and 4.9 m around it
    beyond = _outline_distance_m(grid)
    bilinear = heights_on_grid(dsm, grid)
    by_side = heights_by_side(sides, grid)
    # the DSM's bilinear height beyond the outline: part way up the wall within half a DSM cell of it
    ramp = (beyond > 0.02) & (bilinear > 0.5)
    assert ramp.sum() > 100 and bilinear[beyond > 0.02].max() > 5.0
    # with footprints: the ground's beyond the outline (the DSM's eave width 0.3 m within 2 cm), the roof's within
    assert np.all(by_side[beyond > 0.02] == 0.0)
    assert np.all(by_side[beyond < -0.02] == ROOF_M)
    # imaged where the ground point is: the maps at the ground's height (a DSM without the building) beside the walls
    cam = BrownCamera(focal_mm=8.77, pixel_um=9.6, width=684, height=456)
    C, R = np.array([15.0, 15.0, 60.0]), rotation_matrix_opk(0.0, 0.0, 0.0)
    geometry, to_project = FrameGeometry(cam, C, R), GridToProject(CRS_UTM, CRS_UTM)
    flat = fixed_point_maps(geometry, _dsm(0.0), grid, to_project)
    side = fixed_point_maps(geometry, dsm, grid, to_project, sides=sides)
    plain = fixed_point_maps(geometry, dsm, grid, to_project)
    seen = ramp & (flat[2] > 0)
    assert seen.sum() > 100
    assert np.array_equal(side[0][seen], flat[0][seen]) and np.array_equal(side[1][seen], flat[1][seen])
    assert np.array_equal(side[3], by_side)
    # without footprints: the bilinear DSM, as before (the ramp's cells imaged elsewhere)
    assert np.array_equal(plain[3], bilinear)
    assert np.mean(np.any(plain[0][seen] != flat[0][seen], axis=-1)) > 0.9


def _wide_dsm() -> HeightRaster:
    """The building's DSM as the highest return per cell stands it: the roof a cell (0.5 m) wider than its outline."""
    c = (np.arange(N) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 40.0 - c)
    x0, y0, x1, y1 = WALL
    w = EAVE_M + RES_M
    roof = (X > x0 - w) & (X < x1 + w) & (Y > y0 - w) & (Y < y1 + w)
    return HeightRaster(np.where(roof, ROOF_M, 0.0).astype(np.float32), 0.0, 40.0, RES_M, CRS_UTM, "DSM")


def test_with_an_occlusion_surface_of_its_own_the_heights_take_the_occluders_outline(tmp_path, monkeypatch):
    """The chain's true ortho: heights on the highest-return DSM (the roof a cell wider than its outline), the
    occlusion test on a surface of its own (here the exact one, as the nearest-return DSM on average). The heights'
    roof outlines are the occluder's (eave widths from the occlusion surface: 0.3 m within 2 cm, not 0.8 m from the
    wide roof), and the wide DSM's roof cells beyond them are the ground's: every output cell beyond the true outline
    lies at the ground's height, every one within it at the roof's. Main's rule (the outlines from the heights DSM)
    put the ground within half a metre of the eave at the roof's height."""
    import types

    import pyogrio.raw

    import ortho.block

    fp = tmp_path / "walls.gpkg"
    pyogrio.raw.write(str(fp), shapely.to_wkb(np.array([shapely.box(*WALL)], dtype=object)), [], [], driver="GPKG",
                      geometry_type="Polygon", crs="EPSG:32633")
    task = types.SimpleNamespace(footprints_path=str(fp), occluder_bounds_m=None)
    wide, exact = _wide_dsm(), _dsm(ROOF_M)
    dem = HeightRaster(np.zeros((N, N), np.float32), 0.0, 40.0, RES_M, CRS_UTM, "DEM")
    grid = OrthoGrid(CRS_UTM, 5.0, 26.0, 0.1, 210, 210)
    beyond = _outline_distance_m(grid)
    by_side = {}
    for rule in (True, False):
        monkeypatch.setattr(ortho.block, "OUTLINES_OF_THE_OCCLUSION_TEST", rule)
        occluder, sides = ortho.block._frame_occluder(task, exact, dem, CRS_UTM, None, wide)
        by_side[rule] = heights_by_side(sides, grid)
        widths = [WALL[0] - o.bounds[0] for o in sides.outlines]  # the footprint grown by the eave width
        assert (abs(widths[0] - EAVE_M) < 0.02) if rule else (widths[0] > EAVE_M + 0.4), (rule, widths)
    assert np.all(by_side[True][beyond > 0.02] == 0.0)
    assert np.all(by_side[True][beyond < -0.02] == ROOF_M)
    # main's: the ground out to half a metre beyond the eave at the roof's height, or part way up the wide roof's ramp
    ring = (beyond > 0.02) & (beyond < RES_M - 0.02)
    assert np.mean(by_side[False][ring] > 0.0) > 0.9
    # the occluder is the occlusion surface's either way (the outline's rule changes the heights only)
    same, _ = ortho.block._frame_occluder(task, exact, dem, CRS_UTM, None, None)
    assert np.array_equal(same.sub_margin_cm, occluder.sub_margin_cm) and np.array_equal(same.base_m, occluder.base_m)


def test_nearest_roof_heights_is_the_distance_transforms_cell():
    """Each cell's nearest roof cell by the ring search is the cell scipy's Euclidean feature transform of the whole
    grid gives (its ties too), dense or sparse roofs, within the search radius or beyond it (every roof cell)."""
    from scipy import ndimage

    from ortho.footprints import nearest_roof_heights

    rng = np.random.default_rng(20261130)
    for share, radius in ((0.5, 32), (0.05, 32), (0.002, 32), (0.05, 2)):
        roof = rng.random((61, 73)) < share
        roof[30, 36] = True
        top = rng.random(roof.shape).astype(np.float32)
        rows, cols = ndimage.distance_transform_edt(~roof, return_distances=False, return_indices=True)
        got = nearest_roof_heights(top, roof, np.ones(roof.shape, bool), top.copy(), max_radius=radius)
        assert np.array_equal(got, top[rows, cols])
    # only the cells asked for that are not roof are written
    need = np.zeros(roof.shape, bool)
    need[10:20, 5:9] = True
    got = nearest_roof_heights(top, roof, need, np.full(roof.shape, -1.0, np.float32))
    assert np.array_equal(got[need & ~roof], top[rows, cols][need & ~roof])
    assert np.all(got[~(need & ~roof)] == -1.0) and (need & ~roof).sum() > 30


def _old_outline_heights(dsm: HeightRaster, ground: np.ndarray, cells):
    """``outline_heights`` as it was (c86acb0 .. 74c5e51): every outline of the block burnt over the window, the
    nearest roof cell of every cell by the whole window's distance transform."""
    from rasterio.features import rasterize
    from rasterio.transform import from_origin
    from scipy import ndimage

    from ortho.footprints import OutlineHeights, _overhang_cells, eave_widths_m

    top = dsm.heights_m
    taken, over = np.zeros(top.shape, bool), np.zeros(top.shape, bool)
    _overhang_cells(cells.label, cells.inside, top, ground, np.float32(2.0), cells.sub ** 2, taken, over)
    width_m = np.rint(eave_widths_m(cells, taken, dsm.res_m)[1:] * 100.0) / 100.0
    outlines = shapely.buffer(cells.polygons, width_m)
    roof = rasterize(((shapely.geometry.mapping(g), 1) for g in outlines), out_shape=top.shape,
                     transform=from_origin(dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.res_m), dtype="uint8").astype(bool)
    rows, cols = ndimage.distance_transform_edt(~roof, return_distances=False, return_indices=True)
    raster = (lambda z: HeightRaster(z, dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.crs, dsm.source))
    return OutlineHeights(raster(np.where(roof, ground, top).astype(np.float32)), raster(top[rows, cols]), outlines,
                          shapely.STRtree(outlines), tuple(shapely.geometry.mapping(g) for g in outlines))


def test_outline_heights_give_the_same_heights_as_the_whole_windows_distance_transform():
    """The frame's heights by side (``heights_by_side`` at 0.1 m) from ``outline_heights`` are the same bytes as from the
    whole window's distance transform with every outline of the block burnt (the rule of "Heights from the cell's own
    side of the roof outline"): 7 buildings with eaves of 0.3 m, two with diagonal walls (equally near roof cells), one
    cut by the window's edge, one beyond the window, a sliver holding no DSM cell centre; the ground sloping."""
    c = (np.arange(N) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 40.0 - c)
    walls = [shapely.box(*WALL), shapely.box(2.2, 30.1, 7.9, 37.3), shapely.box(25.0, 2.0, 33.0, 8.0),
             shapely.Polygon([(26, 20), (32, 26), (28, 30), (22, 24)]),
             shapely.Polygon([(3, 3), (8, 5), (6, 10), (2, 8)]),
             shapely.box(35.5, 15.0, 45.0, 25.0),  # cut by the window's east edge
             shapely.box(60.0, 60.0, 70.0, 70.0),  # beyond the window
             shapely.box(14.05, 33.05, 14.2, 36.0)]  # a sliver between cell centres
    heights = [10.0, 6.5, 12.0, 8.0, 4.5, 9.0, 7.0, 3.0]
    ground = (0.02 * X + 0.01 * Y).astype(np.float32)
    top = ground.copy()
    pts = shapely.points(X.ravel(), Y.ravel())
    for w, h in zip(walls, heights):
        inside = shapely.contains(w.buffer(EAVE_M, join_style="mitre"), pts).reshape(X.shape)
        top[inside] = ground[inside] + h
    dsm = HeightRaster(top, 0.0, 40.0, RES_M, CRS_UTM, "DSM")
    # the window's cells cut from the block's (0 .. 80 m a side), as ``ortho.block`` shares them between frames
    cells = footprint_cells(0.0, 80.0, RES_M, (2 * N, 2 * N), np.array(walls, dtype=object)).window(N, 0, N, N)
    assert len(cells.polygons) == 8
    new, old = outline_heights(dsm, ground, cells), _old_outline_heights(dsm, ground, cells)
    assert len(new.outlines) == 7 and len(old.outlines) == 8
    assert np.array_equal(new.ground.heights_m, old.ground.heights_m)
    grid = OrthoGrid(CRS_UTM, 0.3, 39.7, 0.1, 394, 394)
    by_new, by_old = heights_by_side(new, grid), heights_by_side(old, grid)
    assert np.array_equal(by_new, by_old, equal_nan=True)
    # the cells beside the outlines take a roof height other than their own DSM's (the nearest roof cell's)
    assert np.sum(new.roof.heights_m != top) > 200
