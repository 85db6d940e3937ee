"""The whole cloud's level regions labelled tile by tile (``level_tiles``, level-tiles): the regions, areas and
levels of the whole cloud's labelling (``pipeline._level_regions`` over all cells) from the tiles' borders and
spanning regions only -- the parent never holds an array per core cell."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
from scipy import ndimage

from lidarctl.classify import level_tiles as lt
from lidarctl.classify import pipeline as classify

from tests.lidarctl.test_classify_water_level_bodies import corridor_cells, lake_cells, quay_cells


def whole_regions(cells, heights, tol):
    """Region per cell, its area (cells) and level (``np.median``) from the labelling of all cells at once."""
    med = lt.level_medians(cells, heights, tol)
    g = np.full(tuple(cells.max(axis=0) + 1), np.nan)
    g[cells[:, 0], cells[:, 1]] = med
    lab = classify._level_regions(g, tol)[cells[:, 0], cells[:, 1]]
    size = np.bincount(lab)
    level = np.r_[np.nan, ndimage.median(med[lab > 0], lab[lab > 0], np.arange(1, len(size)))]
    return lab, size[lab], level[lab]


def tiled_regions(cells, heights, tol, side, stream=True, exact=False):
    """The same from the tiles (squares of ``side`` cells): per cell its region (unique over the cloud), area and
    level, and what each tile sent the parent (``stream``: the tiles' borders dropped once their neighbours came;
    else held to the end; ``exact``: the levels of the spanning regions made exact by the tiles' second answer)."""
    ncols = int(cells[:, 1].max()) + 1
    tiles = lt.split_into_tiles(cells, side)
    done = [lt.tile_level_regions(cells[i], heights[i], core, ncols, tol, pos) for pos, i, core in tiles]
    answers = lt.join_tile_regions((sent for sent, _ in done),
                                   positions=[pos for pos, _, _ in tiles] if stream else None)
    if exact:   # the tiles' further answers: a finer histogram, then the values of the middle bins
        med = lt.level_medians(cells, heights, tol)[:, None]
        mine = [(kept.label, med[i][core]) for (_, i, core), (_, kept) in zip(tiles, done)]
        answers = lt.refine_medians(answers, [lt.median_histogram(lab, v, a) for (lab, v), a in zip(mine, answers)])
        answers = lt.exact_levels(answers, [lt.values_in_median_bins(lab, v, a) for (lab, v), a in zip(mine, answers)])
    region = np.zeros(len(cells), np.int64)
    area = np.zeros(len(cells), np.int64)
    level = np.full(len(cells), np.nan)
    own_id = 1 << 40
    for (_, idx, core), (sent, kept), answer in zip(tiles, done, answers):
        k, lab, m = idx[core], kept.label, sent.n_spanning
        span, inner = (lab > 0) & (lab <= m), lab > m
        region[k[span]], area[k[span]], level[k[span]] = (answer.region_id[lab[span]], answer.cells[lab[span]],
                                                         answer.level_m[lab[span]])
        region[k[inner]], area[k[inner]], level[k[inner]] = (own_id + lab[inner], kept.cells[lab[inner]],
                                                            kept.level_m[lab[inner]])
        own_id += 1 << 20
    return region, area, level, [sent for sent, _ in done], tiles


def test_tiled_regions_are_the_whole_clouds(monkeypatch):
    """A lake larger than a tile (36 cells across; a ring of level patches, land, crowns, 10 % empty cells) in tiles
    of 17 and 24 cells (the tiles' borders dropped as the tiles come or held to the end; the histograms merged as
    they come or at the end): the same regions (a one-to-one map of the labels), the same areas, the levels of the
    regions wholly in a tile exact and of the spanning ones within half a bin of the first histogram, to the last bit
    after a finer histogram of the two middle bins and the values of its two middle bins (``exact_levels``)."""
    p = classify.ClassifySettings()
    cells, heights, _ = lake_cells(seed=1)
    lab, size, level = whole_regions(cells, heights, p.level_water_tol_m)
    lake = size[lab > 0].max()
    assert lake > 24 * 24
    for side, stream, merge in ((17, True, 1), (24, False, 1 << 20)):
        monkeypatch.setattr(lt, "HISTOGRAM_MERGE_ENTRIES", merge)
        region, area, lev, _, _ = tiled_regions(cells, heights, p.level_water_tol_m, side, stream)
        a = lab > 0
        assert np.array_equal(a, region > 0)
        pairs = np.unique(np.column_stack([lab[a], region[a]]), axis=0)
        assert len(pairs) == len(np.unique(lab[a])) == len(np.unique(region[a]))
        assert np.array_equal(area[a], size[a]) and area.max() == lake
        inner = a & (region >= 1 << 40)
        assert np.array_equal(lev[inner], level[inner])
        assert np.max(np.abs(lev[a] - level[a])) <= lt.LEVEL_BIN_M / 2 + 1e-9
        exact = tiled_regions(cells, heights, p.level_water_tol_m, side, stream, exact=True)[2]
        assert np.array_equal(exact[a], level[a])


def test_the_parent_gets_no_array_per_core_cell():
    """What a tile hands the parent is its border (the ring of cells about its core and the core's edge cells) and
    its spanning regions' histograms: at most 12 entries per cell of the core's side on the lake (cores of 40 x 40
    cells: 1,600 cells, 480 entries at most), never an array of the core's cells."""
    p = classify.ClassifySettings()
    cells, heights, _ = lake_cells(seed=1)
    side = 40
    _, _, _, sent, tiles = tiled_regions(cells, heights, p.level_water_tol_m, side)
    for t, (_, _, core) in zip(sent, tiles):
        for f in dataclasses.fields(t):
            v = getattr(t, f.name)
            if isinstance(v, np.ndarray):
                assert len(v) <= 12 * side, (f.name, len(v))
        assert len(t.halo_keys) <= 4 * side + 4 and len(t.edge_keys) <= 4 * side


def test_tiled_bodies_are_the_whole_clouds():
    """``whole_level_bodies_tiled`` (rounds over the tiles' windows and the parent's per-region sums) finds the bodies
    of ``whole_level_bodies`` cell for cell in tiles of 24 cells: the lake (36 cells across, larger than a tile) and
    the ring of patches joined across a dropout, the survey's coverage on and off; a basin with 3 m quays (a wall's
    land behind it across the tiles; coverage on); a diagonal corridor 0.8 km long (tiles of 30 cells: the 133 of
    its box's 224 without a return all skipped as beyond the survey; coverage on); the levels to the last bit (the
    medians of regions spanning tiles from three answers of the tiles; a histogram's median alone lost the big
    pond of ``bench/level_tiles_bodies.py``, its bank fraction 0.793 against 0.8)."""
    lake = lake_cells(seed=1)
    for coverage, scenes in ((True, (lake, quay_cells(3.0)[:3], corridor_cells(0.8))), (False, (lake,))):
        p = dataclasses.replace(classify.ClassifySettings(), water_survey_coverage=coverage)
        for cells, heights, wg in scenes:
            whole = classify.whole_level_bodies(cells, heights, wg, p)
            tiled = lt.whole_level_bodies_tiled(cells, heights, wg, p, 24 if len(cells) < 20_000 else 30)
            assert len(whole.keys) > 900 and np.array_equal(whole.keys, tiled.keys)
            assert np.array_equal(whole.level_m, tiled.level_m)


def test_medians_from_the_tiles_histograms_are_exact():
    """Values of one region in five tiles (their histograms not merged: a bin comes once a tile): the middle bins and
    ranks, a finer histogram of them, then their values give ``np.median`` to the last bit (a bin counted from its
    tile's entry rather than from its first lost 5 of 44 joined bodies' levels on Topography, by up to 29 mm)."""
    rng = np.random.default_rng(4)
    for n in (1, 2, 7, 400, 401):
        v = 800.0 + rng.normal(0, 0.3, n)
        part = rng.integers(0, 5, n)
        bins = [np.floor(v[part == k] / lt.LEVEL_BINS_M[0]).astype(np.int64) for k in range(5)]
        entries = [np.unique(b, return_counts=True) for b in bins]
        b = np.concatenate([e[0] for e in entries])
        c = np.concatenate([e[1] for e in entries])
        o = np.argsort(b, kind="stable")
        b1, b2, k1, k2 = lt._median_bins(b[o], c[o])
        answer = lt.RegionDecisions(np.arange(2), np.r_[0, n], np.full(2, np.nan),
                                    np.array([[[0, 0]], [[b1, b2]]], np.int64), np.array([[0, 0], [k1, k2]]))
        tiles = [(np.ones(int(np.sum(part == k)), np.int64), v[part == k][:, None]) for k in range(5)]
        answers = lt.refine_medians([answer] * 5, [lt.median_histogram(lab, x, answer) for lab, x in tiles])
        answers = lt.exact_levels(answers, [lt.values_in_median_bins(lab, x, a) for (lab, x), a in zip(tiles, answers)])
        assert answers[0].level_m[1] == np.median(v), n


def test_tiles_run_finds_the_whole_clouds_bodies_from_the_spool(tmp_path, monkeypatch):
    """level-wire: in a tiled run (40 m tiles, 20 m buffer) the tiles' workers spool their water cells by level tile
    and return none of them (no array of the cells to the parent: their lowest intensities counted too); the level
    bodies found tile by tile over the spool (level tiles of the halo's 40 cells: the lake, 170 m across, spans 5 of
    them a side; 8,611 body cells) are those of ``whole_level_bodies`` on every cell, cell for cell and to the last
    bit, and the tiles read them back from the run's scratch (``SpooledLevelBodies``)."""
    import laspy

    from aerotri.core.executor import local_executor
    from lidarctl import synthetic, tiles
    from tests.lidarctl.test_classify_water_tiles import big_lake_scene

    cloud, *_ = big_lake_scene("lake", size_m=240.0, radius_m=85.0, density=1.5)
    src = tmp_path / "lake.laz"
    synthetic.write_las(src, cloud, crs="EPSG:32610")
    p = classify.ClassifySettings(water_whole_level_bodies=True)
    with laspy.open(src) as f:
        grid = tiles.plan_tiles(f.header, tile_size_m=40.0, buffer_m=20.0)
    lowest = []
    tasks = tiles.split_into_tiles([src], grid, tmp_path, p, lowest=lowest)
    monkeypatch.setattr(lt, "LEVEL_TILE_M", 40.0)   # the level tiles as small as the halo allows
    wired, seen = lt.whole_level_bodies_spooled, {}

    def checked(store, wg, p, footprint=None):
        cells = np.concatenate([store.get("cells", t) for t in store.tiles])
        heights = np.concatenate([store.get("heights", t) for t in store.tiles])
        seen["whole"], seen["n_tiles"] = classify.whole_level_bodies(cells, heights, wg, p), len(store.tiles)
        seen["cells"] = cells
        return wired(store, wg, p, footprint)

    monkeypatch.setattr(lt, "whole_level_bodies_spooled", checked)

    class Recorded:
        def __init__(self):
            self.inner, self.results = local_executor(), []

        def map(self, fn, items, desc="", unit=""):
            out = self.inner.map(fn, items, desc=desc, unit=unit)
            self.results.append((desc, copy.deepcopy(out)))   # (the parent adds into the arrays it gets)
            return out

    ex = Recorded()
    wg = tiles.water_grid(tasks, grid, p, lowest, ex, work_dir=tmp_path)
    (_, water_cells), = [(d, r) for d, r in ex.results if d == "tiles: water cells"]
    for hist, ij, heights, intensity in water_cells:
        assert len(ij) == 0 and len(heights) == 0 and intensity.sum() == hist.sum()
    whole, cells = seen["whole"], seen["cells"]
    assert seen["n_tiles"] >= 16 and len(whole.keys) > 5_000
    assert isinstance(wg.level_bodies, lt.SpooledLevelBodies) and not wg.level_bodies.empty
    keys, levels = [], []
    for t in sorted(wg.level_bodies.tiles):
        keys.append(np.fromfile(tmp_path / "level_bodies" / f"out_keys_{t[0]}_{t[1]}.bin", np.int64))
        levels.append(np.fromfile(tmp_path / "level_bodies" / f"out_level_{t[0]}_{t[1]}.bin"))
    keys, levels = np.concatenate(keys), np.concatenate(levels)
    o = np.argsort(keys)
    assert np.array_equal(keys[o], whole.keys) and np.array_equal(levels[o], whole.level_m)
    rows, cols = cells[:, 0] - 2, cells[:, 1] + 1   # any cells, some beyond the cloud's
    assert np.array_equal(wg.level_bodies.level_at(rows, cols), whole.level_at(rows, cols), equal_nan=True)
    # the land's reflectance as without the option (the tiles' counts, not the cells' intensities)
    assert wg.land_intensity == tiles.water_grid(tasks, grid, classify.ClassifySettings(), lowest,
                                                 local_executor()).land_intensity


def test_the_parents_memory_is_a_windows_not_the_clouds(tmp_path, monkeypatch):
    """level-wire: the spooled pass (the store in files, as in a tiled run) holds one level tile's window and the
    per-region tables: 1 and 3 copies of the lake scene side by side (the lake with its ring of patches joined
    across a dropout in each: 964 body cells), 3 times the cells and bodies, the pass's tracemalloc peak within 1.5
    times (4 copies before: 9.7 of the test's 14-16 s)."""
    import tracemalloc

    cells, heights, wg = lake_cells()
    p = classify.ClassifySettings()
    monkeypatch.setattr(lt, "LEVEL_TILE_M", 40.0)   # level tiles of the halo's 40 cells: a window of 3 x 3 tiles
    width = int(cells[:, 1].max()) + 4
    peaks, bodies = [], []
    for k in (1, 3):
        many = np.concatenate([cells + (0, i * width) for i in range(k)])
        occ = np.ones((int(many[:, 0].max() * wg.cell_m / 10) + 2, int(many[:, 1].max() * wg.cell_m / 10) + 2), bool)
        wg_k = dataclasses.replace(wg, footprint_10m=classify.survey_footprint(occ))
        side = lt.level_tile_cells(wg.cell_m, p)
        folder = tmp_path / str(k)
        folder.mkdir()
        lt.spool_cells(folder, side, (0, 0), many, np.tile(heights, (k, 1)))
        store = lt.CellSpool.from_fragments(folder, side)
        del many
        peak = []
        # the lower of two runs (now and then a one-off 2-4 MB more, not the cells'): the second of the small
        # scene's, of the large one's only when the first is over the bound
        while len(peak) < 2 and (k == 1 or not peak or peak[0] >= 1.5 * peaks[0]):
            tracemalloc.start()
            ncols = lt.whole_level_bodies_spooled(store, wg_k, p)
            peak.append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
        peaks.append(min(peak))
        keys = np.concatenate([np.fromfile(f, np.int64) for f in folder.glob("out_keys_*.bin")])
        bodies.append(len(keys))
        assert ncols == (k - 1) * width + int(cells[:, 1].max()) + 1
    assert bodies[0] > 900 and bodies[1] == 3 * bodies[0]
    assert peaks[1] < 1.5 * peaks[0], peaks
