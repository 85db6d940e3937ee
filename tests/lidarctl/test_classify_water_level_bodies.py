"""The whole cloud's level water bodies on grid arrays (``pipeline.whole_level_bodies``, i44-edge-fixes): the
bodies ``level_water`` finds on three returns a cell (lowest, median, highest at its centre), at the cost of a
grid pass (reviewer 12d: 1.2 kB and 7 CPU-s per million cells through the returns); on the occupied blocks only
(level-bodies-sparse: the same bodies as the grid over the cloud's bounding box, ``whole_level_bodies_dense``, with
memory by the occupied cells)."""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np

from lidarctl.classify import pipeline as classify

CELL_M = 2.0   # exact in binary: the cell centres' distances are exact, as the grid's neighbours are


def lake_cells(s: int = 120, seed: int = 1):
    """Cells of an s x s grid: a level lake (30 % of the side, returns within 3 cm) on 2 % terrain 1 m above it,
    5 % of the land cells (none within 6 m of the water) and 0.3 % of the water's under a crown (15 m); a ring of
    four level patches (each below ``level_water_min_area_m2``) around a lake that returned nothing (the join
    across a dropout) in the south-east; 10 % of the cells empty. Returns (cells, heights, WaterGrid)."""
    rng = np.random.default_rng(seed)
    ii, jj = np.divmod(np.arange(s * s), s)
    d = np.hypot(ii - s / 3, jj - s / 3) * CELL_M - 0.3 * s * CELL_M / 2
    d2 = np.hypot(ii - 0.8 * s, jj - 0.8 * s) * CELL_M - 18.0
    lake, ring = d < 0, (d2 < 0) & (d2 > -4.0) & (np.abs(ii - 0.8 * s) > 1) & (np.abs(jj - 0.8 * s) > 1)
    level = lake | ring
    base = np.where(level, 100.0, 101.0 + 0.02 * np.clip(np.minimum(d, d2), 0, None))
    lo = base + rng.normal(0, 0.01, s * s)
    span = np.where(level, rng.uniform(0, 0.03, s * s), rng.uniform(0, 0.2, s * s))
    crown = rng.random(s * s) < np.where(level, 0.003, np.where(np.minimum(d, d2) < 6.0, 0.0, 0.05))
    hi = lo + np.where(crown, 15.0, span)
    med = np.where(crown, lo + 12.0, lo + span / 2)
    keep = (rng.random(s * s) > 0.1) & ~((d2 <= -4.0) & ~ring)
    cells = np.column_stack([ii, jj])[keep] + 3
    occ = np.ones(((s + 3) * 2 // 10 + 1,) * 2, bool)
    wg = classify.WaterGrid(cell_m=CELL_M, x0_m=0.0, y0_m=0.0, median_count=3.0,
                            footprint_10m=classify.survey_footprint(occ))
    return cells, np.column_stack([lo, med, hi])[keep], wg


def level_water_bodies(cells, heights, wg, p):
    """The bodies as ``level_water`` finds them on the returns (three a cell at its centre, the median the ground):
    the reference, i44-edge's implementation."""
    c = wg.cell_m
    px = np.repeat(wg.x0_m + (cells[:, 1] + 0.5) * c, 3)
    py = np.repeat(wg.y0_m + (cells[:, 0] + 0.5) * c, 3)
    pz = np.asarray(heights, float).ravel()
    middle = np.zeros(len(pz), bool)
    middle[1::3] = True
    water = classify.level_water(px, py, pz, np.ones(len(pz), bool), middle, c / 2.0, p=p, water_grid=wg)
    ncols = int(cells[:, 1].max()) + 1
    k = np.flatnonzero(water) // 3
    return ncols, cells[k, 0] * ncols + cells[k, 1], pz[water]


def test_whole_level_bodies_are_level_waters_bodies():
    p = classify.ClassifySettings()
    for seed in (1, 2, 3):
        cells, heights, wg = lake_cells(seed=seed)
        bodies = classify.whole_level_bodies(cells, heights, wg, p)
        ncols, keys, z = level_water_bodies(cells, heights, wg, p)
        assert bodies.ncols == ncols
        assert np.array_equal(bodies.keys, np.unique(keys))
        rows = bodies.keys // ncols
        assert np.sum(rows < 80) > 850 and np.sum(rows > 80) > 50   # the lake; the ring joined across its dropout
        # each cell's level: the median of its body's water returns
        lake = bodies.level_at(*np.divmod(keys, ncols))
        assert np.all(np.abs(lake - z) <= p.level_water_tol_m)


def test_whole_level_bodies_cost_a_grid_pass():
    """At most 100 bytes of memory per cell (the returns' way: about 1,200)."""
    classify.whole_level_bodies(*lake_cells(s=60), classify.ClassifySettings())   # compiled first
    cells, heights, wg = lake_cells(s=300)
    tracemalloc.start()
    classify.whole_level_bodies(cells, heights, wg, classify.ClassifySettings())
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 100 * 300 * 300, peak


def same_bodies(a, b) -> bool:
    return a.ncols == b.ncols and np.array_equal(a.keys, b.keys) and np.array_equal(a.level_m, b.level_m)


def test_sparse_bodies_are_the_dense_bodies():
    """The same cells and levels to the last bit as the grid over the bounding box, on a corridor (bodies across the
    blocks, a road creeping along it, gaps open to beyond the survey) and the lake scenes, with the survey's coverage
    on and off (off: the blocks not stored are one gap with the empty cells beside them)."""
    for coverage in (True, False):
        p = dataclasses.replace(classify.ClassifySettings(), water_survey_coverage=coverage)
        scenes = [corridor_cells(1.6), lake_cells(seed=1), courtyard_cells("land")]
        for cells, heights, wg in scenes:
            sparse = classify.whole_level_bodies(cells, heights, wg, p)
            assert same_bodies(sparse, classify.whole_level_bodies_dense(cells, heights, wg, p))
            assert len(sparse.keys) > 900


def test_bodies_far_from_the_grids_origin():
    """A lake 47,000 cells north and east of the whole grid's origin (a 46 km square at 1 m cells: the flat keys
    ``row * ncols + col`` pass 2**31): every lake cell found by ``level_at``, the keys those of the dense reference
    (review 19: int32 rows wrapped, 0 of 964 found)."""
    p = classify.ClassifySettings()
    cells, heights, wg = lake_cells(seed=1)
    near = classify.whole_level_bodies(cells, heights, wg, p)
    off = 47_000
    wg = dataclasses.replace(wg, footprint_10m=None)   # the footprint of the cells themselves
    far = classify.whole_level_bodies(cells + off, heights, wg, p)
    assert far.ncols * int(cells[:, 0].max() + off) > 2**31
    assert same_bodies(far, classify.whole_level_bodies_dense(cells + off, heights, wg, p))
    rows, cols = np.divmod(near.keys, near.ncols)
    assert len(near.keys) > 900
    assert np.array_equal(far.level_at(rows + off, cols + off), near.level_m)


def test_sparse_bodies_memory_by_the_occupied_cells():
    """A diagonal corridor whose bounding box holds 8.8 cells for each occupied one: at most 120 bytes per occupied
    cell (the grid over the box: 69 a cell of the box, about 600 per occupied cell)."""
    classify.whole_level_bodies(*corridor_cells(0.3), classify.ClassifySettings())   # compiled first
    cells, heights, wg = corridor_cells(2.0)
    assert np.prod(cells.max(axis=0) - cells.min(axis=0) + 1) > 8 * len(cells)
    tracemalloc.start()
    classify.whole_level_bodies(cells, heights, wg, classify.ClassifySettings())
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 120 * len(cells), peak / len(cells)


def courtyard_cells(ring: str, s: int = 150, seed: int = 3, street_m: float = 1.0, rise: float = 0.02):
    """A level paved courtyard (100 x 100 cells of 2 m, within 3 cm) in an s x s grid, enclosed by a ring 10 cells
    deep of ``roofs`` (flat, 12 m up, level to 2 cm) or of ``land`` rising 1 m from the yard; beyond it land
    ``street_m`` above the yard rising ``rise`` (reviewer 12d's scene: water in tiles, none in the whole run)."""
    rng = np.random.default_rng(seed)
    ii, jj = np.divmod(np.arange(s * s), s)
    d = np.maximum(np.abs(ii - s / 2 + 0.5), np.abs(jj - s / 2 + 0.5)) - 50   # > 0 outside the yard (cells)
    lo = np.where(d <= 0, 100.0, np.where(d <= 10, 101.0, 100.0 + street_m) + rise * CELL_M * np.clip(d - 10, 0, None))
    lo = lo + rng.normal(0, 0.01, s * s)
    span = np.where(d <= 0, rng.uniform(0, 0.03, s * s), rng.uniform(0, 0.2, s * s))
    if ring == "roofs":
        on_roof = (d > 0) & (d <= 10)
        lo = np.where(on_roof, 112.0 + rng.normal(0, 0.005, s * s), lo)
        span = np.where(on_roof, rng.uniform(0, 0.02, s * s), span)
    occ = np.ones((s * 2 // 10 + 1,) * 2, bool)
    wg = classify.WaterGrid(cell_m=CELL_M, x0_m=0.0, y0_m=0.0, median_count=3.0,
                            footprint_10m=classify.survey_footprint(occ))
    return np.column_stack([ii, jj]), np.column_stack([lo, lo + span / 2, lo + span]), wg


def test_a_courtyard_among_roofs_is_no_level_body():
    """A roof ring is no bank (its cells stand higher than any bank rises across the rim, ``BANK_MAX_SLOPE``) and
    its level cells are no part of the yard's region: no body, as in the whole run, where roofs are no ground and
    no candidates. The same yard in land rising 1 m from it lies in a bed: a body. The roofs are no quay's walls
    (``WALL_BEHIND_M``) with the street beyond them at the yard's level or below it either (review 19: before, only
    land above the level counted as lower land, and the 9,604 cells of the yard were a body)."""
    p = classify.ClassifySettings()
    for street_m, rise in ((1.0, 0.02), (0.0, 0.0), (-0.5, 0.0)):   # level streets 30 m wide
        scene = courtyard_cells("roofs", street_m=street_m, rise=rise)
        assert len(classify.whole_level_bodies(*scene, p).keys) == 0, street_m
        assert len(classify.whole_level_bodies_dense(*scene, p).keys) == 0, street_m
    assert len(classify.whole_level_bodies(*courtyard_cells("land"), p).keys) > 0.9 * 100 * 100


def quay_cells(freeboard_m: float, s: int = 120, c: float = 1.41):
    """A basin 120 m across (cells of 1.41 m) whose quays stand ``freeboard_m`` above the water, the land behind them
    rising 1 % (reviewer 15's ``quay.py``): a vertical wall, returns on its top only. (With 2 m cells the cells
    beside the wall are 6.7 % of the basin, above the open-sky test's 5 %: no body in either pass.)"""
    rng = np.random.default_rng(0)
    ii, jj = np.divmod(np.arange(s * s), s)
    d = np.hypot(ii - s / 2, jj - s / 2) * c - 60.0
    lo = np.where(d < 0, 100.0, 100.0 + freeboard_m + 0.01 * np.clip(d, 0, None)) + rng.normal(0, 0.01, s * s)
    span = np.where(d < 0, rng.uniform(0, 0.03, s * s), rng.uniform(0, 0.1, s * s))
    occ = np.ones((int((s + 3) * c / 10) + 2,) * 2, bool)
    wg = classify.WaterGrid(cell_m=c, x0_m=0.0, y0_m=0.0, median_count=3.0,
                            footprint_10m=classify.survey_footprint(occ))
    return np.column_stack([ii, jj]) + 3, np.column_stack([lo, lo + span / 2, lo + span]), wg, int(np.sum(d < 0))


def test_a_quay_wall_is_a_bank(monkeypatch):
    """Quays standing 3-6 m above the water (above the steepest bank across the rim) are the land, not objects on
    lower land: banks, as the ground they are in the tile's own pass (``level_water``). Before: 0 cells of the
    basin (review 15), the tile's pass all of it -- seams between tiles. The same bodies with the land behind the
    walls looked up a few cells at a time (``LOWEST_LAND_CHUNK_CELLS``) and on the grid (the dense reference)."""
    p = classify.ClassifySettings()
    for freeboard_m in (3.0, 6.0):
        cells, heights, wg, basin = quay_cells(freeboard_m)
        bodies = classify.whole_level_bodies(cells, heights, wg, p)
        assert same_bodies(bodies, classify.whole_level_bodies_dense(cells, heights, wg, p))
        with monkeypatch.context() as m:
            m.setattr(classify, "LOWEST_LAND_CHUNK_CELLS", 37)
            assert same_bodies(bodies, classify.whole_level_bodies(cells, heights, wg, p))
        _, keys, _ = level_water_bodies(cells, heights, wg, p)
        assert len(bodies.keys) > 0.95 * basin
        # the cells beside the wall: its top is within one cell (open sky), which the returns' KD-tree misses in
        # float round-off at 1.41 m (78 cells)
        assert abs(len(bodies.keys) - len(np.unique(keys))) <= 0.02 * basin


CORRIDOR_CELL_M = 2 * 0.7071   # 2 spacings of 0.707 m (2 returns / m2)


def corridor_cells(length_km: float, width_m: float = 200.0, seed: int = 0):
    """A survey corridor along the grid's diagonal (cells of 1.414 m, ``width_m`` across along a row, 10 % of the cells
    empty): land rising 0.2 % along it, 5 % of its cells under a crown (15 m); every 400 m a feature across it, in
    turn: a level lake 90 m across returning the pulse (banks 1 m, then 2 %), a lake 80 m across that mirrored every
    pulse but in a ring of shore patches each smaller than a body (the join across a dropout), a lake cut by the
    corridor's edge returning nothing but in level shore patches (a gap open to beyond the survey), a level courtyard
    60 m across among 12 m roofs; and a level road 4 m wide along the whole corridor (falling 0.2 %: one region
    creeping along it). Returns (cells (k, 2), heights (k, 3) lowest / median / highest return, WaterGrid with the
    footprint of the occupied 10 m cells)."""
    rng = np.random.default_rng(seed)
    c = CORRIDOR_CELL_M
    n = int(length_km * 1000 / np.sqrt(2) / c)   # rows of the diagonal
    half = int(width_m / 2 / c)
    i = np.repeat(np.arange(n), 2 * half + 1)
    j = i + np.tile(np.arange(-half, half + 1), n)
    ok = j >= 0
    i, j = i[ok], j[ok]
    along = (i + j) * c / np.sqrt(2)               # m along the strip
    across = (j - i) * c / np.sqrt(2)              # m across it (perpendicular)
    k = len(i)
    land = 100.0 + 0.002 * along + 0.005 * np.abs(across)
    z = land.copy()
    level = np.zeros(k, bool)
    keep = rng.random(k) > 0.1
    feature = np.floor(along / 400.0).astype(int) % 4
    at = along - (np.floor(along / 400.0) * 400.0 + 200.0)   # m from the feature's centre along the strip
    d = np.hypot(at, across)
    lake_level = 100.0 + 0.002 * (along - at) - 1.0
    # a lake returning the pulse
    m = feature == 0
    water = m & (d < 45.0)
    z = np.where(m & ~water & (d < 45.0 + 20), lake_level + 1.0 + 0.02 * (d - 45.0), z)
    z = np.where(water, lake_level, z)
    level |= water
    # a lake that mirrored every pulse but at a ring of shore patches
    m = feature == 1
    ring = m & (d < 40.0) & (d > 36.0) & (np.abs(at) > 4) & (np.abs(across) > 4)
    keep &= ~(m & (d <= 36.0))
    z = np.where(m & (d < 40.0), lake_level, np.where(m & (d < 60.0), lake_level + 1.0 + 0.02 * (d - 40.0), z))
    level |= ring
    # a lake cut by the strip's edge, returning nothing
    m = feature == 2
    d2 = np.hypot(at, across - width_m / 2)
    keep &= ~(m & (d2 < 50.0))
    sector = np.mod(np.degrees(np.arctan2(across - width_m / 2, at)), 45.0) < 25.0
    edge_ring = m & (d2 >= 50.0) & (d2 < 54.0) & sector
    bank = m & (d2 >= 54.0) & (d2 < 70.0)
    z = np.where(edge_ring, lake_level, np.where(bank, lake_level + 1.0 + 0.02 * (d2 - 54.0), z))
    level |= edge_ring
    # a courtyard among roofs
    m = feature == 3
    box = np.maximum(np.abs(at), np.abs(across))
    yard, roof = m & (box < 30.0), m & (box >= 30.0) & (box < 45.0)
    z = np.where(yard, lake_level + 1.0, np.where(roof, lake_level + 13.0, z))
    level |= yard | roof
    # a level road along the strip
    road = (np.abs(across - 20.0) < 2.0) & ~level & (feature != 1)
    z = np.where(road, 100.0 + 0.002 * along + 0.3, z)
    level |= road
    lo = z + rng.normal(0, 0.01, k)
    span = np.where(level, rng.uniform(0, 0.03, k), rng.uniform(0, 0.2, k))
    crown = ~level & (rng.random(k) < 0.05) & ~((feature <= 1) & (d < 52.0)) & ~((feature == 2) & (d2 < 64.0))
    hi = lo + np.where(crown, 15.0, span)
    med = np.where(crown, lo + 12.0, lo + span / 2)
    cells = np.column_stack([i, j])[keep].astype(np.int64)
    heights = np.column_stack([lo, med, hi])[keep]
    # the survey's footprint as ``tiles.water_grid`` gives it (occupied 10 m cells from the grid's origin)
    xc, yc = (cells[:, 1] + 0.5) * c, (cells[:, 0] + 0.5) * c
    wg = classify.WaterGrid(cell_m=c, x0_m=0.0, y0_m=0.0, median_count=3.0,
                            footprint_10m=classify.survey_footprint(classify.occupied_10m(xc, yc, 0.0, 0.0)))
    return cells, heights, wg
