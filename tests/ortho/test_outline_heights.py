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
