"""Building footprints in the true ortho's occlusion test (issue 42): a line of sight that passes beneath a roof's
overhang (outside the walls) reaches the ground; without footprints the DSM's solid columns hide it. Constructed: one
box building, walls 10.2 .. 20 m, the roof 10 m high reaching 0.5 m beyond the walls (a DSM of 0.5 m cells, the
exact roof outline), flat ground at 0 m; the truth of each line of sight is computed from the box and its eave
here (a segment against boxes), not from the march."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import rasterio
import shapely
from click.testing import CliRunner
from pyproj import CRS

from aerotri.core.errors import InputError
from ortho.dem import HeightRaster
from ortho.footprints import OVERHANG_SLAB_M, footprint_cells, footprint_occluder, occluder_of_cells, read_footprints
from ortho.rectify import FrameGeometry, occlusion_mask

WALL = (10.2, 10.2, 20.0, 20.0)  # x0, y0, x1, y1 (m)
EAVE_M = 0.5
ROOF_M = 10.0
RES_M = 0.5
CRS_UTM = CRS.from_epsg(32633)


def _rasters():
    """DSM (the roof over the eave outline, sampled at the cell centres) of 40 x 40 m and the DEM (0 m) on it."""
    n = int(40 / RES_M)
    c = (np.arange(n) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 40.0 - c)
    x0, y0, x1, y1 = WALL
    roof = (X > x0 - EAVE_M) & (X < x1 + EAVE_M) & (Y > y0 - EAVE_M) & (Y < y1 + EAVE_M)
    dsm = HeightRaster(np.where(roof, ROOF_M, 0.0).astype(np.float32), 0.0, 40.0, RES_M, CRS_UTM, "DSM")
    return dsm, np.zeros((n, n), np.float32)


def _truth_sees(p, centre) -> bool:
    """The segment from ground point p to the centre misses the walls' box (0 .. roof) and the eave's slab (the
    roof outline, roof - slab .. roof): sampled every mm."""
    t = np.linspace(0.0, 1.0, 200_001)
    q = np.asarray(p)[None, :] + t[:, None] * (np.asarray(centre) - np.asarray(p))[None, :]
    x0, y0, x1, y1 = WALL
    in_walls = (q[:, 0] > x0) & (q[:, 0] < x1) & (q[:, 1] > y0) & (q[:, 1] < y1) & (q[:, 2] < ROOF_M)
    in_eave = ((q[:, 0] > x0 - EAVE_M) & (q[:, 0] < x1 + EAVE_M) & (q[:, 1] > y0 - EAVE_M) & (q[:, 1] < y1 + EAVE_M)
               & (q[:, 2] < ROOF_M) & (q[:, 2] > ROOF_M - OVERHANG_SLAB_M))
    return not (in_walls | in_eave)[1:].any()


# ground points and the projection centre (m): south of the building, lines of sight rising to the north-west
# (x + y about constant), at about 40 degrees
CENTRE = (-7000.0, 7020.0, 8000.0)
POINTS = {
    "beneath the eave's south-west corner (outside the walls)": (10.6, 9.0),
    "beneath the eave, through the cell the wall's corner stands in": (11.25, 9.0),
    "through the wall": (12.25, 9.0),
    "open ground beside the building": (5.0, 9.0),
}


def _march(footprints, occluder=None):
    dsm, dem = _rasters()
    if occluder is None and footprints is not None:
        occluder = footprint_occluder(dsm, dem, footprints)
    xy = np.array(list(POINTS.values()))
    # each point its own anchor (1 x 4 points padded to the 2 x 2 anchors the kernel reads at least)
    AX = np.vstack([xy[:, 0], xy[:, 0]])
    AY = np.vstack([xy[:, 1], xy[:, 1]])
    grid = type("Grid", (), {"height": 2, "width": len(xy)})()
    geometry = FrameGeometry(None, np.asarray(CENTRE, float), np.eye(3))
    occ = occlusion_mask(geometry, dsm, grid, np.zeros((2, len(xy)), np.float32), (AX, AY, 1.0), occluder=occluder)
    return dict(zip(POINTS, occ[0])), occluder


def test_a_line_of_sight_beneath_the_eave_is_visible_with_footprints_and_occluded_without():
    footprints = np.array([shapely.box(*WALL)], dtype=object)
    with_fp, occluder = _march(footprints)
    without, _ = _march(None)
    truth = {k: _truth_sees((*p, 0.0), CENTRE) for k, p in POINTS.items()}
    assert truth == {k: not k.startswith("through") for k in POINTS}
    # the eave's cells (outside the walls, 10 m above the DEM) are overhangs; the ones the wall crosses carry it
    assert occluder.overhang_cells > 0 and len(occluder.sub_masks) > 0
    for k in POINTS:
        assert with_fp[k] == (not truth[k]), k
    # without footprints the roof's columns hide both lines of sight beneath the eave
    assert without["beneath the eave's south-west corner (outside the walls)"]
    assert without["beneath the eave, through the cell the wall's corner stands in"]
    assert without["through the wall"] and not without["open ground beside the building"]
    # the second line of sight runs through the cell (10 .. 10.5 m) the walls' corner stands in, outside the walls:
    # with that cell's sub-cells all inside a footprint it is hidden
    r, c = int((40.0 - 10.5) / RES_M), int(10.0 / RES_M)
    k = occluder.sub_index[r, c]
    assert k >= 0 and 0 < (occluder.sub_masks[k] & 1).sum() < occluder.sub ** 2
    walled = occluder.sub_masks.copy()
    walled[k] |= 1
    hidden, _ = _march(None, dataclasses.replace(occluder, sub_masks=walled))
    assert hidden["beneath the eave, through the cell the wall's corner stands in"]


def test_footprints_file_errors_name_the_file_and_what_was_expected(tmp_path):
    import pyogrio.raw

    missing = tmp_path / "none.gpkg"
    with pytest.raises(InputError, match="none.gpkg: footprints file not found"):
        read_footprints(missing, CRS_UTM)
    text = tmp_path / "bad.gpkg"
    text.write_text("not a geopackage\n")
    with pytest.raises(InputError, match="bad.gpkg: cannot read it as a vector layer"):
        read_footprints(text, CRS_UTM)
    wrong = tmp_path / "wrong_crs.gpkg"
    pyogrio.raw.write(str(wrong), shapely.to_wkb(np.array([shapely.box(*WALL)], dtype=object)), [], [],
                      driver="GPKG", geometry_type="Polygon", crs="EPSG:4326")
    with pytest.raises(InputError, match="wrong_crs.gpkg: the footprints are in EPSG:4326; expected"):
        read_footprints(wrong, CRS_UTM)
    lines = tmp_path / "lines.gpkg"
    pyogrio.raw.write(str(lines), shapely.to_wkb(np.array([shapely.LineString([(0, 0), (1, 1)])], dtype=object)), [],
                      [], driver="GPKG", geometry_type="LineString", crs="EPSG:32633")
    with pytest.raises(InputError, match="lines.gpkg: feature 1 is a LineString; expected"):
        read_footprints(lines, CRS_UTM)


def _write_boxes_gpkg(path, boxes, crs):
    import pyogrio.raw

    geoms = np.array([shapely.box(x0, y0, x1, y1) for x0, y0, x1, y1, _ in boxes], dtype=object)
    pyogrio.raw.write(str(path), shapely.to_wkb(geoms), [], [], driver="GPKG", geometry_type="Polygon", crs=crs)


def test_rectify_with_footprints_of_walls_without_overhangs_masks_as_without(tmp_path, monkeypatch):
    """The synthetic block's boxes stand on whole DSM cells with no overhang: their footprints make every roof cell
    a solid column, as without footprints, so the frame orthos are the same with the DSM's bilinear heights
    (``ortho.block.HEIGHTS_BY_OUTLINE`` off); with the heights from each cell's own side of the roof outline (the
    default) they differ only within a DSM cell of a wall; a footprints file in another CRS is refused (exit 2,
    naming it) before any frame is written."""
    import hashlib

    import ortho.block
    from ortho.cli import main
    from tests.shared_builds import write_synthetic_project

    info = write_synthetic_project(tmp_path / "p", strips=1, frames_per_strip=2, buildings=8, seed=3)
    root = info.root
    fp = tmp_path / "walls.gpkg"
    _write_boxes_gpkg(fp, info.buildings, "EPSG:32649")
    digests, orthos = {}, {}
    for way, extra, by_outline in (("without", [], True), ("with", ["--footprints", str(fp)], False),
                                   ("by outline", ["--footprints", str(fp)], True)):
        monkeypatch.setattr(ortho.block, "HEIGHTS_BY_OUTLINE", by_outline)
        r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dsm", str(root / "truth" / "dsm.tif"),
                                      *extra])
        assert r.exit_code == 0, r.output
        frames = sorted((root / "ortho" / "frames").glob("*.tif"))
        assert frames
        digests[way] = [hashlib.sha256(p.read_bytes()).hexdigest() for p in frames]
        orthos[way] = []
        for p in frames:
            with rasterio.open(p) as ds:
                orthos[way].append((ds.read(), ds.read_masks(1), ds.transform))
    index = (root / "ortho" / "frames" / "index.json").read_text()
    assert str(fp) in index
    assert digests["with"] == digests["without"]
    with rasterio.open(root / "truth" / "dsm.tif") as ds:
        dsm_res = ds.res[0]
    walls = shapely.union_all([shapely.box(x0, y0, x1, y1).exterior for x0, y0, x1, y1, _ in info.buildings])
    changed = 0
    for (a, ma, t), (b, mb, _) in zip(orthos["without"], orthos["by outline"]):
        rows, cols = np.nonzero((a != b).any(axis=0) | (ma != mb))
        x, y = t.c + (cols + 0.5) * t.a, t.f + (rows + 0.5) * t.e
        far = shapely.distance(walls, shapely.points(x, y)) > dsm_res + abs(t.a)
        # beyond a DSM cell of the walls the same cells imaged from the same image positions (cv2.remap's vector and
        # scalar paths round a sample 1 DN apart where the imaged cells of a row change, e.g. 7 of 2,327 here)
        assert np.array_equal(ma[rows[far], cols[far]], mb[rows[far], cols[far]])
        assert np.abs(a[:, rows[far], cols[far]].astype(int) - b[:, rows[far], cols[far]].astype(int)).max(
            initial=0) <= 1 and far.sum() < 0.01 * len(rows)
        changed += len(rows)
    assert changed > 0
    wrong = tmp_path / "walls_4326.gpkg"
    _write_boxes_gpkg(wrong, [(0.0, 0.0, 1.0, 1.0, 0.0)], "EPSG:4326")
    before = (root / "ortho" / "frames" / "index.json").stat().st_mtime_ns
    r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dsm", str(root / "truth" / "dsm.tif"),
                                  "--footprints", str(wrong)])
    assert r.exit_code == 2 and "walls_4326.gpkg: the footprints are in EPSG:4326" in r.output, r.output
    assert "Traceback" not in r.output
    assert (root / "ortho" / "frames" / "index.json").stat().st_mtime_ns == before


def test_the_simulator_writes_the_wall_lines_as_footprints(tiny_project):
    """truth/footprints.gpkg: the buildings' wall lines (part "footprint" of truth/buildings.geojson) in the project
    CRS, read as ``ortho rectify --footprints`` reads them; inside the roof outlines (the eaves reach beyond)."""
    import json

    from aerotri.core.project import Project

    t = tiny_project / "truth"
    got = read_footprints(t / "footprints.gpkg", CRS.from_user_input(Project.open(tiny_project).crs))
    feats = json.loads((t / "buildings.geojson").read_text())["features"]
    walls = [shapely.geometry.shape(f["geometry"]) for f in feats if f["properties"]["part"] == "footprint"]
    eaves = [shapely.geometry.shape(f["geometry"]) for f in feats if f["properties"]["part"] == "roof_outline"]
    assert len(got) == len(walls) > 0
    assert all(g.equals_exact(w, 1e-6) for g, w in zip(got, walls))
    assert all(e.contains(g) and e.area > g.area for g, e in zip(got, eaves))


def test_the_eave_line_stands_above_the_cells_a_lidar_dsm_fills_low_in_a_walls_shadow():
    """A few overhang cells lower than the roof (a LiDAR DSM fills cells without returns in a wall's shadow between
    ground and roof) neither lower the building's soffit nor open a gap in its overhang: the eave line is a low
    quantile of the overhang's tops, and a low cell's slab reaches up to it."""
    dsm, ground = _rasters()
    z = dsm.heights_m.copy()
    c = (np.arange(z.shape[0]) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 40.0 - c)
    x0, y0, x1, y1 = WALL
    rr, cc = np.nonzero((z > 0) & ~((X > x0) & (X < x1) & (Y > y0) & (Y < y1)))  # the eave's cells
    low = (rr[:3], cc[:3])
    z[low] = 4.0
    occ = footprint_occluder(HeightRaster(z, dsm.x_left_m, dsm.y_top_m, RES_M, CRS_UTM, "DSM"), ground,
                             np.array([shapely.box(*WALL)], dtype=object))
    assert np.allclose(occ.base_m[low], ROOF_M - OVERHANG_SLAB_M)
    assert np.allclose(occ.slab_top_m[low], ROOF_M)


def test_the_occluder_cut_from_a_blocks_footprint_cells_is_the_windows_own():
    """A block's frames share one rasterisation of the footprints (``footprint_cells`` over the block's DSM window,
    ``FootprintCells.window`` per frame): the occluder from the cut is the one rasterised for the frame's window
    itself, array for array, also where the window cuts a building (its eave line then from its cells in the window)
    and beside the window's edges. Three box buildings with 0.5 m eaves on 60 x 50 m, rotated walls for the third."""
    n_r, n_c = int(50 / RES_M), int(60 / RES_M)
    X, Y = np.meshgrid((np.arange(n_c) + 0.5) * RES_M, 50.0 - (np.arange(n_r) + 0.5) * RES_M)
    walls = [shapely.box(10.2, 10.2, 20.0, 20.0), shapely.box(30.05, 28.3, 41.7, 36.0),
             shapely.affinity.rotate(shapely.box(40.0, 8.0, 52.0, 18.0), 20.0)]
    z = np.zeros((n_r, n_c), np.float32)
    for k, w in enumerate(walls):
        roof = shapely.contains_xy(w.buffer(EAVE_M, join_style="mitre"), X, Y)
        z[roof] = ROOF_M + 2.0 * k + 0.1 * (X[roof] - X[roof].min())  # pitched: the eave line a quantile
    ground = np.zeros_like(z)
    footprints = np.array(walls, dtype=object)
    cells = footprint_cells(0.0, 50.0, RES_M, z.shape, footprints)
    windows = [(0, 0, n_r, n_c), (30, 25, 40, 40), (0, 0, 35, 90), (41, 50, 59, 70), (55, 90, 45, 30)]
    checked = 0
    for r0, c0, h, w in windows:
        dsm = HeightRaster(z[r0:r0 + h, c0:c0 + w].copy(), c0 * RES_M, 50.0 - r0 * RES_M, RES_M, CRS_UTM, "DSM")
        own = footprint_occluder(dsm, ground[r0:r0 + h, c0:c0 + w], footprints)
        cut = occluder_of_cells(dsm, ground[r0:r0 + h, c0:c0 + w], cells.window(r0, c0, h, w))
        for name in ("base_m", "slab_top_m", "sub_index", "sub_masks"):
            a, b = getattr(own, name), getattr(cut, name)
            assert a.dtype == b.dtype and np.array_equal(a, b), (r0, c0, name)
        checked += own.overhang_cells
        assert own.overhang_cells > 0 and (own.sub_index >= 0).any() and (own.sub_index <= -3).any()
    # a window that cuts a building takes the eave line of its cells in the window: not the whole building's
    whole = footprint_occluder(HeightRaster(z, 0.0, 50.0, RES_M, CRS_UTM, "DSM"), ground, footprints)
    part = footprint_occluder(HeightRaster(z[:, :104].copy(), 0.0, 50.0, RES_M, CRS_UTM, "DSM"), ground[:, :104],
                              footprints)
    assert not np.array_equal(whole.base_m[:, :104], part.base_m)
    assert checked > 500


def test_an_eave_is_an_overhang_wherever_the_window_rows_fall():
    """The eave on the south side of a building whose walls end 0.05 m above row 256 of the window is an overhang
    as on its other sides (the rasterisation by bands of 256 rows had left a band that no wall crosses without
    overhang cells: the occluder then depended on where the window began)."""
    n_r, n_c = 300, 60
    X, Y = np.meshgrid((np.arange(n_c) + 0.5) * RES_M, 150.0 - (np.arange(n_r) + 0.5) * RES_M)
    wall = shapely.box(10.2, 22.05, 20.0, 40.0)  # row 256 spans y 21.5 .. 22.0: the walls stay in rows 0 .. 255
    roof = shapely.contains_xy(wall.buffer(EAVE_M, join_style="mitre"), X, Y)
    z = np.where(roof, ROOF_M, 0.0).astype(np.float32)
    occ = footprint_occluder(HeightRaster(z, 0.0, 150.0, RES_M, CRS_UTM, "DSM"), np.zeros_like(z),
                             np.array([wall], dtype=object))
    south = roof & (Y < 22.05)  # the eave's cells south of the walls: row 256
    north = roof & (Y > 40.0)
    assert south.sum() == north.sum() > 15
    assert np.isfinite(occ.base_m[south]).all() and np.isfinite(occ.base_m[north]).all()
    assert np.allclose(occ.base_m[south], ROOF_M - OVERHANG_SLAB_M)


def test_the_roof_candidates_made_once_give_the_same_occluder_and_heights_by_side():
    """``roof_candidates`` of a window, made once a frame (``ortho.block._frame_occluder``) and handed to the occluder
    and the heights by the roof outlines, give both the arrays each makes alone; candidates of another window are
    refused. Three box buildings, pitched roofs (the eave line a quantile), the window cutting one of them."""
    from ortho.footprints import outline_heights, roof_candidates

    n_r, n_c = int(50 / RES_M), int(60 / RES_M)
    X, Y = np.meshgrid((np.arange(n_c) + 0.5) * RES_M, 50.0 - (np.arange(n_r) + 0.5) * RES_M)
    walls = [shapely.box(10.2, 10.2, 20.0, 20.0), shapely.box(30.05, 28.3, 41.7, 36.0),
             shapely.affinity.rotate(shapely.box(40.0, 8.0, 52.0, 18.0), 20.0)]
    z = np.zeros((n_r, n_c), np.float32)
    for k, w in enumerate(walls):
        roof = shapely.contains_xy(w.buffer(EAVE_M, join_style="mitre"), X, Y)
        z[roof] = ROOF_M + 2.0 * k + 0.1 * (X[roof] - X[roof].min())
    ground = np.zeros_like(z)
    cells = footprint_cells(0.0, 50.0, RES_M, z.shape, np.array(walls, dtype=object))
    for r0, c0, h, w in [(0, 0, n_r, n_c), (0, 0, 35, 90)]:
        dsm = HeightRaster(z[r0:r0 + h, c0:c0 + w].copy(), c0 * RES_M, 50.0 - r0 * RES_M, RES_M, CRS_UTM, "DSM")
        win, g = cells.window(r0, c0, h, w), ground[r0:r0 + h, c0:c0 + w]
        cand = roof_candidates(win, dsm.heights_m, g, RES_M)
        assert cand.over.sum() > 40
        alone, shared = occluder_of_cells(dsm, g, win), occluder_of_cells(dsm, g, win, candidates=cand)
        for name in ("base_m", "slab_top_m", "sub_index", "sub_masks", "sub_margin_cm"):
            assert np.array_equal(getattr(alone, name), getattr(shared, name)), name
        a, b = outline_heights(dsm, g, win), outline_heights(dsm, g, win, candidates=cand)
        assert np.array_equal(a.ground.heights_m, b.ground.heights_m)
        assert np.array_equal(a.roof.heights_m, b.roof.heights_m)
        assert all(x.equals(y) for x, y in zip(a.outlines, b.outlines)) and len(a.outlines) == len(b.outlines)
    with pytest.raises(ValueError, match="another window"):
        occluder_of_cells(dsm, g, win, candidates=roof_candidates(cells, z, ground, RES_M))
