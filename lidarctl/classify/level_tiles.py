"""The whole cloud's level water bodies (``pipeline.whole_level_bodies``) tile by tile (issue 44, level-tiles): the
same bodies with the parent holding the tiles' borders and per-region answers, not every occupied cell.

Labelling (``tile_components``, ``tile_level_regions``): each tile labels its own cells (those whose centre lies in
its core) and the ring of cells about its core, and hands the parent only (``TileRegions``) the regions that reach
the ring (they continue in another tile) with their core cells and level histogram, the ring cells they hold and
its own edge cells (keys on the whole grid and local labels). A region that reaches no ring cell is wholly in the
core: the tile decides its area and exact level itself. The parent joins the regions across the tiles' borders by
union-find on the cells two tiles share (a ring cell of one is an edge cell of its owner), adds their areas and
histograms (``join_tile_regions``) and gives each tile back its regions' id, area and level (``RegionDecisions``).

Medians exact in three answers (``LEVEL_BINS_M``: ``refine_medians``, ``values_in_median_bins``,
``exact_levels``). Sums and looks within a reach (rim, shore, open sky, a quay's land within ``WALL_BEHIND_M``)
exact by ownership: the tile whose core holds a cell counts its (cell, region) pairs over a window with a halo of
that reach. ``whole_level_bodies_tiled`` runs every step of ``whole_level_bodies`` so: the same cells and levels
bit for bit (bench/level_tiles_bodies.py). It holds the whole cloud's cells itself, each step reading one tile's
window: a check of the decomposition; the tiles' pass (workers spooling their cells and labels) is not done, and
the option ``water_whole_level_bodies`` keeps the parent's pass on every occupied cell."""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
from scipy import ndimage

from lidarctl import grid
from lidarctl.classify import pipeline as cl

# The bins (m) of the level histograms of the regions that span tiles: the tiles' first answer in bins of 0.1 m (a
# region creeping along a slope: a bin per 0.1 m of its rise, not one per cell), then within the two middle bins in
# bins of 0.5 mm, then the values of the two middle bins of those: ``np.median``'s median to the last bit in three
# answers, each of a few entries a region.
LEVEL_BINS_M = (0.1, 0.0005)
LEVEL_BIN_M = LEVEL_BINS_M[0]
# The parent merges the tiles' histograms by their regions' roots whenever the entries come to twice those left by
# the last merge and this many (its memory by the bins of the regions, not of the tiles they span).
HISTOGRAM_MERGE_ENTRIES = 65536


@dataclasses.dataclass(frozen=True)
class TileRegions:
    """What a tile hands the parent about its level regions (``tile_level_regions``): only the regions that reach
    its halo (local labels 1..``n_spanning``) and its border cells, no per-cell arrays of its core.
    ``core_cells[k]``: the region's cells in the core (index 0 unused); ``hist_region``, ``hist_bin``,
    ``hist_count``: its histogram of the cells' median returns over the core (bins of ``LEVEL_BIN_M`` from 0 m);
    ``row``, ``col``: the tile's place on the tile grid; ``halo_keys`` / ``halo_label``: the ring cells (about the
    core) in a spanning region (whole-grid keys ``row * ncols + col``);
    ``edge_keys`` / ``edge_label``: the core's level cells on the edge of its cells' box, sorted by key."""

    row: int
    col: int
    n_spanning: int
    core_cells: np.ndarray
    hist_region: np.ndarray
    hist_bin: np.ndarray
    hist_count: np.ndarray
    halo_keys: np.ndarray
    halo_label: np.ndarray
    edge_keys: np.ndarray
    edge_label: np.ndarray


@dataclasses.dataclass(frozen=True)
class TileLabels:
    """What a tile keeps (in its worker): the region per core cell (``label``, in the order of the cells given to
    ``tile_level_regions``: 0 not level; 1..n_spanning spanning, above wholly in the core) and the area (cells) and
    exact level (m) of the regions wholly in the core (index: label; NaN / 0 for the spanning ones)."""

    label: np.ndarray
    cells: np.ndarray
    level_m: np.ndarray


@dataclasses.dataclass(frozen=True)
class RegionDecisions:
    """The parent's answer to one tile (``join_tile_regions``): for its spanning regions 1..n (index 0 unused) the
    region's id across the cloud (1..), its area (cells) and level (m: the first histogram's median, within half a
    bin; ``refine_medians`` and ``exact_levels`` make it ``np.median``'s); ``median_bins`` (n + 1, k, 2): per
    histogram so far (bins of ``LEVEL_BINS_M[j]``) the bins holding the region's two middle values (the values
    within all k hold both), and ``median_ranks`` (n + 1, 2): the two middle values' ranks among those values."""

    region_id: np.ndarray
    cells: np.ndarray
    level_m: np.ndarray
    median_bins: np.ndarray
    median_ranks: np.ndarray


def level_medians(cells: np.ndarray, heights: np.ndarray, tol_m: float) -> np.ndarray:
    """The median return (m) of the level cells (their returns span at most 2 ``tol_m``), NaN elsewhere, as
    ``whole_level_bodies`` takes them (``heights``: lowest, median, highest return per cell)."""
    lo, med, hi = heights[:, 0], heights[:, 1], heights[:, 2]
    return np.where(hi - lo <= 2.0 * tol_m, med, np.nan)


def tile_level_regions(cells: np.ndarray, heights: np.ndarray, core: np.ndarray, ncols_whole: int,
                       tol_m: float, tile: tuple[int, int] = (0, 0)) -> tuple[TileRegions, TileLabels]:
    """A tile's level regions (in its worker): ``cells`` (k, 2) row and column on the whole grid of the tile's core
    cells (``core``) and of the cells about them (at least the ring one cell wide, from its buffer), ``heights``
    (k, 3) each cell's lowest, median and highest return (m), ``ncols_whole`` the whole grid's columns (for the
    keys), ``tile`` its (row, col) on the tile grid. Memory of the tile's window (a grid over its cells' box).
    Returns what it hands the parent and what it keeps."""
    med = level_medians(cells, heights, tol_m)
    return tile_components(cells, med, tol_m, med[:, None], core, ncols_whole, tile)


def tile_components(cells: np.ndarray, join_value: np.ndarray, join_tol: float, values: np.ndarray,
                    core: np.ndarray, ncols_whole: int, tile: tuple[int, int] = (0, 0)) -> tuple[TileRegions,
                                                                                                 TileLabels]:
    """``tile_level_regions`` for any components: the cells with a finite ``join_value`` joined to their 8
    neighbours whose value differs by at most ``join_tol`` (a label as the value, tolerance 0.5: the cells of one
    label), each component's median over ``values`` (k, m) of its core cells (NaN: not counted)."""
    core = np.asarray(core, bool)
    med_cell = join_value
    r0, c0 = cells.min(axis=0)
    nrows, ncols = (cells.max(axis=0) - (r0, c0) + 1).astype(int)
    rr, cc = cells[:, 0] - r0, cells[:, 1] - c0
    med = np.full((nrows, ncols), np.nan)
    med[rr, cc] = med_cell
    incore = np.zeros((nrows, ncols), bool)
    incore[rr[core], cc[core]] = True
    lab = cl._level_regions(med, join_tol)
    del med
    # the halo: cells beside a core cell, outside the core; only those in a region with core cells count
    ring = np.zeros((nrows + 2, ncols + 2), bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            ring[1 + dr:nrows + 1 + dr, 1 + dc:ncols + 1 + dc] |= incore
    halo = ring[1:-1, 1:-1] & ~incore
    # the core's edge: its level cells beside a cell beyond the core cells' box (any other tile's halo cell lies
    # beyond this tile's core, so beyond that box; the box's edge, not the empty cells within, bounds them)
    i, j = np.nonzero(incore)
    edge = np.zeros((nrows, ncols), bool)
    if len(i):
        edge[i.min(), :] = edge[i.max(), :] = edge[:, j.min()] = edge[:, j.max()] = True
    edge &= incore & (lab > 0)
    del ring, i, j
    n = int(lab.max())
    in_core = np.zeros(n + 1, bool)
    in_core[lab[incore]] = True
    spans = np.zeros(n + 1, bool)
    spans[lab[halo]] = True
    spans &= in_core
    spans[0] = False
    # local labels: spanning regions first (1..m), then those wholly in the core, 0 for the halo's own regions
    m = int(spans.sum())
    keep = in_core.copy()
    keep[0] = False
    order = np.r_[np.flatnonzero(spans), np.flatnonzero(keep & ~spans)]
    relabel = np.zeros(n + 1, np.int64)
    relabel[order] = np.arange(1, len(order) + 1)
    lab = relabel[lab]
    n = len(order)
    core_lab = lab[rr[core], cc[core]]
    count = np.bincount(core_lab, minlength=n + 1)
    vals = np.asarray(values, float)[core]
    vl = np.repeat(core_lab, vals.shape[1])
    vals = vals.ravel()
    take = (vl > 0) & np.isfinite(vals)
    vl, vals = vl[take], vals[take]
    level = np.full(n + 1, np.nan)
    level[m + 1:] = cl._group_median(vals, vl, n + 1)[m + 1:]
    # the spanning regions' histograms over the core
    sp = vl <= m
    b = np.floor(vals[sp] / LEVEL_BIN_M).astype(np.int64)
    pair, cnt = np.unique(np.column_stack([vl[sp], b]), axis=0, return_counts=True) if sp.any() else (
        np.zeros((0, 2), np.int64), np.zeros(0, np.int64))

    def keys(mask):
        i, j = np.nonzero(mask)
        return (i.astype(np.int64) + r0) * ncols_whole + (j + c0), lab[i, j]

    hk, hl = keys(halo & (lab > 0) & (lab <= m))
    ek, el = keys(edge)
    o = np.argsort(ek)
    sent = TileRegions(int(tile[0]), int(tile[1]), m, count[:m + 1].copy(), pair[:, 0].copy(), pair[:, 1].copy(),
                       cnt, hk, hl, ek[o], el[o])
    kept = TileLabels(core_lab, np.where(np.arange(n + 1) > m, count, 0), level)
    return sent, kept


@numba.njit(cache=True)
def _roots(parent):
    out = np.empty(len(parent), np.int64)
    for k in range(len(parent)):
        out[k] = grid._find(parent, k)
    return out


def _median_bins(bins: np.ndarray, counts: np.ndarray):
    """The bins (sorted ``bins``, a bin may come more than once: ``counts`` values each) of the two middle values and
    their ranks among the values in those two bins (the bins between them are empty)."""
    cum = np.cumsum(counts)
    n = int(cum[-1])
    i1 = int(np.searchsorted(cum, (n - 1) // 2, side="right"))
    i2 = int(np.searchsorted(cum, n // 2, side="right"))
    first = int(np.searchsorted(bins, bins[i1]))   # the values below the bin, not below this entry of it
    below = int(cum[first - 1]) if first else 0
    return bins[i1], bins[i2], (n - 1) // 2 - below, n // 2 - below


def _histogram_median(bins: np.ndarray, counts: np.ndarray) -> float:
    """The median (m) of values in ``LEVEL_BIN_M`` bins ``bins`` (sorted) counted ``counts``: the mean of the two
    middle values' bin centres."""
    cum = np.cumsum(counts)
    n = int(cum[-1])
    a = bins[np.searchsorted(cum, (n - 1) // 2, side="right")]
    b = bins[np.searchsorted(cum, n // 2, side="right")]
    return (0.5 * (a + b) + 0.5) * LEVEL_BIN_M


def _merge_histograms(parent, hists):
    """The histograms ``hists`` ((node, bin, count) arrays) merged by the nodes' roots in union-find ``parent``:
    one (root, bin, count) per root and bin, sorted by root and bin. A lake's bins recur in every tile it spans
    (merged: tens of bins, not tens a tile); a region creeping along a slope keeps about a bin a cell."""
    # one int64 key a (root, bin): roots below 2**31, bins of +-2**31 half-millimetres (+-1,000 km)
    key = _find_all(parent, np.concatenate([h[0] for h in hists])) << np.int64(32)
    key += np.concatenate([h[1] for h in hists]) + np.int64(1 << 31)
    count = np.concatenate([h[2] for h in hists])
    if not len(key):
        return key, key.copy(), count.astype(np.int64)
    o = np.argsort(key, kind="stable")
    key, count = key[o], count[o]
    del o
    first = np.r_[True, key[1:] != key[:-1]]
    total = np.add.reduceat(count, np.flatnonzero(first))
    key = key[first]
    return key >> np.int64(32), (key & np.int64(0xFFFFFFFF)) - np.int64(1 << 31), total.astype(np.int64)


@numba.njit(cache=True)
def _find_all(parent, nodes):
    out = np.empty(len(nodes), np.int64)
    for k in range(len(nodes)):
        out[k] = grid._find(parent, nodes[k])
    return out


def _match(keys_a, nodes_a, keys_b, nodes_b):
    """The node pairs of the keys in both (``keys_b`` unique); and which of ``keys_a`` found none."""
    if not len(keys_b) or not len(keys_a):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.ones(len(keys_a), bool)
    o = np.argsort(keys_b)
    kb, nb = keys_b[o], nodes_b[o]
    pos = np.minimum(np.searchsorted(kb, keys_a), len(kb) - 1)
    hit = kb[pos] == keys_a
    return nodes_a[hit], nb[pos[hit]], ~hit


def join_tile_regions(tiles, positions=None) -> list[RegionDecisions]:
    """The parent's join of the tiles' spanning regions, the tiles (``TileRegions``) taken one at a time as they
    come (an iterable): union-find on the cells two tiles share (a halo cell of one tile is an edge cell of the
    tile whose core holds it), the areas and histograms added. ``positions``: every tile's (row, col) on the tile
    grid, known before the first comes: a tile's halo cells lie in its 8 neighbours' cores, and its border cells are
    dropped once those have all come (in row order: a row of tiles' borders held; None: all borders to the end).
    Memory of the spanning regions (a node each, their histograms) and of the pending borders, never of the tiles'
    core cells."""
    parent = np.zeros(0, np.int64)
    cells: list[np.ndarray] = []
    hists: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    compacted = 0
    offsets: list[int] = []
    edges: dict = {}     # tile -> (keys, nodes) of its edge cells, until its neighbours have come
    halos: dict = {}     # tile -> (keys, nodes) of its halo cells not yet matched
    arrived: set = set()
    known = set(positions) if positions is not None else None

    def near(t):
        if known is None:
            return [u for u in arrived if u != t]
        r, c = t
        return [(r + dr, c + dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr or dc) and (r + dr, c + dc) in known]

    n = 0
    for t in tiles:
        pos = (t.row, t.col)
        off = n
        offsets.append(off)
        n += t.n_spanning + 1
        if n > len(parent):   # grown by doubling: a copy per doubling, not per tile
            parent = np.r_[parent, np.zeros(max(n, 2 * len(parent)) - len(parent), np.int64)]
        parent[off:n] = np.arange(off, n)
        cells.append(t.core_cells)
        hists.append((t.hist_region + off, t.hist_bin, t.hist_count))
        pending = sum(len(h[0]) for h in hists)
        if pending > 2 * compacted + HISTOGRAM_MERGE_ENTRIES:   # merged by the regions' roots so far
            hists = [_merge_histograms(parent, hists)]
            compacted = len(hists[0][0])
        hk, hn = t.halo_keys, t.halo_label.astype(np.int64) + off
        ek, en = t.edge_keys, t.edge_label.astype(np.int64) + off
        for u in near(pos):
            if u in edges:   # this tile's halo cells in that tile's core
                a, b, rest = _match(hk, hn, *edges[u])
                cl._union(parent, a, b)
                hk, hn = hk[rest], hn[rest]
            if u in halos:   # that tile's halo cells in this tile's core
                a, b, rest = _match(*halos[u], ek, en)
                cl._union(parent, a, b)
                halos[u] = (halos[u][0][rest], halos[u][1][rest])
        if len(hk):
            halos[pos] = (hk, hn)
        edges[pos] = (ek, en)
        arrived.add(pos)
        if known is not None:   # borders of the tiles whose neighbours have all come are no longer needed
            for u in [pos, *near(pos)]:
                if u in arrived and all(v in arrived for v in near(u)):
                    edges.pop(u, None)
                    halos.pop(u, None)
    del edges, halos
    parent = parent[:n]
    root = _roots(parent)
    area = np.bincount(root, weights=np.concatenate(cells).astype(float), minlength=n) if n else np.zeros(0)
    del cells
    hr, hb, hc = _merge_histograms(parent, hists) if hists else (np.zeros(0, np.int64),) * 3
    del hists
    level = np.full(n, np.nan)
    mbins = np.zeros((n, 2), np.int64)
    mranks = np.zeros((n, 2), np.int64)
    starts = np.flatnonzero(np.r_[True, hr[1:] != hr[:-1]]) if len(hr) else np.zeros(0, np.int64)
    for s, e in zip(starts, np.r_[starts[1:], len(hr)]):
        level[hr[s]] = _histogram_median(hb[s:e], hc[s:e])
        b1, b2, k1, k2 = _median_bins(hb[s:e], hc[s:e])
        mbins[hr[s]] = b1, b2
        mranks[hr[s]] = k1, k2
    spanning = np.ones(n, bool)
    spanning[offsets] = False
    ids = np.zeros(n, np.int64)
    roots = np.unique(root[spanning])
    ids[roots] = np.arange(1, len(roots) + 1)
    out = []
    for off, end in zip(offsets, offsets[1:] + [n]):
        r = root[off + 1:end]
        out.append(RegionDecisions(np.r_[0, ids[r]], np.r_[0, area[r]].astype(np.int64), np.r_[np.nan, level[r]],
                                   np.vstack([np.zeros((1, 2), np.int64), mbins[r]])[:, None, :],
                                   np.vstack([np.zeros((1, 2), np.int64), mranks[r]])))
    return out


def _in_median_bins(lab: np.ndarray, v: np.ndarray, answer: RegionDecisions) -> np.ndarray:
    """Which values ``v`` (of regions ``lab``) lie in their region's middle bins of every histogram so far."""
    take = np.ones(len(v), bool)
    for j in range(answer.median_bins.shape[1]):
        b = np.floor(v / LEVEL_BINS_M[j]).astype(np.int64)
        take &= (b >= answer.median_bins[lab, j, 0]) & (b <= answer.median_bins[lab, j, 1])
    return take


def _core_values(label, values, answer):
    n = len(answer.region_id) - 1
    lab = np.repeat(label, np.asarray(values).shape[1])
    v = np.asarray(values, float).ravel()
    take = (lab > 0) & (lab <= n) & np.isfinite(v)
    lab, v = lab[take], v[take]
    take = _in_median_bins(lab, v, answer)
    return lab[take], v[take]


def median_histogram(label: np.ndarray, values: np.ndarray, answer: RegionDecisions):
    """A tile's answer for the next histogram (in its worker): over the values (``values`` (k, m) of its core cells,
    NaN: not counted; ``label`` their local labels, 1..n the spanning regions of ``answer``) within their region's
    middle bins so far, bins of the next width (``LEVEL_BINS_M``): (region id over the cloud, bin, count)."""
    lab, v = _core_values(label, values, answer)
    b = np.floor(v / LEVEL_BINS_M[answer.median_bins.shape[1]]).astype(np.int64)
    if not len(b):
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    return np.unique(np.column_stack([answer.region_id[lab], b]), axis=0, return_counts=True)


def refine_medians(answers: list[RegionDecisions], sent) -> list[RegionDecisions]:
    """The parent's next histogram of the spanning regions' middle values (``sent``: per tile
    ``median_histogram``): the answers with those bins' two middle bins and the ranks within them."""
    pair = np.concatenate([s[0] for s in sent]) if sent else np.zeros((0, 2), np.int64)
    cnt = np.concatenate([s[1] for s in sent]) if sent else np.zeros(0, np.int64)
    key = pair[:, 0] << np.int64(32)
    key += pair[:, 1] + np.int64(1 << 31)
    ukey, inv = np.unique(key, return_inverse=True)
    cnt = np.bincount(inv.ravel(), weights=cnt).astype(np.int64)
    rid, b = ukey >> np.int64(32), (ukey & np.int64(0xFFFFFFFF)) - np.int64(1 << 31)
    n = max((int(a.region_id.max(initial=0)) for a in answers), default=0) + 1
    ranks = np.zeros((n, 2), np.int64)
    for a in answers:
        ranks[a.region_id[1:]] = a.median_ranks[1:]
    new_bins = np.zeros((n, 2), np.int64)
    new_ranks = np.zeros((n, 2), np.int64)
    starts = np.flatnonzero(np.r_[True, rid[1:] != rid[:-1]]) if len(rid) else np.zeros(0, np.int64)
    for s0, e in zip(starts, np.r_[starts[1:], len(rid)]):
        r = rid[s0]
        cum = np.cumsum(cnt[s0:e])
        i1 = int(np.searchsorted(cum, ranks[r, 0], side="right"))
        i2 = int(np.searchsorted(cum, ranks[r, 1], side="right"))
        below = int(cum[i1 - 1]) if i1 else 0
        new_bins[r] = b[s0 + i1], b[s0 + i2]
        new_ranks[r] = ranks[r, 0] - below, ranks[r, 1] - below
    out, done = [], {}
    for a in answers:
        if id(a) not in done:
            ids = a.region_id
            done[id(a)] = dataclasses.replace(
                a, median_bins=np.concatenate([a.median_bins, new_bins[ids][:, None, :]], axis=1),
                median_ranks=np.r_[a.median_ranks[:1], new_ranks[ids[1:]]])
        out.append(done[id(a)])
    return out


def values_in_median_bins(label: np.ndarray, values: np.ndarray, answer: RegionDecisions):
    """A tile's last answer for the exact medians (in its worker): its core cells' values (as ``median_histogram``)
    within their region's middle bins of every histogram: (region id over the cloud, value) pairs."""
    lab, v = _core_values(label, values, answer)
    return answer.region_id[lab], v


def exact_levels(answers: list[RegionDecisions], sent) -> list[RegionDecisions]:
    """The parent's exact medians of the spanning regions (``np.median``'s: the mean of the two middle values) from
    the values the tiles sent from the regions' middle bins (``sent``: per tile ``values_in_median_bins``);
    the answers with those levels. Memory of the values of two bins a region."""
    rid = np.concatenate([s[0] for s in sent]) if sent else np.zeros(0, np.int64)
    val = np.concatenate([s[1] for s in sent]) if sent else np.zeros(0)
    o = np.lexsort((val, rid))
    rid, val = rid[o], val[o]
    n = max((int(a.region_id.max(initial=0)) for a in answers), default=0) + 1
    start = np.searchsorted(rid, np.arange(n))
    has = np.bincount(rid, minlength=n) > 0   # (a region without values has no level)
    level = np.full(n, np.nan)
    for a in answers:
        k = np.flatnonzero(has[a.region_id[1:]]) + 1
        ids = a.region_id[k]
        level[ids] = (val[start[ids] + a.median_ranks[k, 0]] + val[start[ids] + a.median_ranks[k, 1]]) / 2
    done = {}
    for a in answers:
        if id(a) not in done:
            done[id(a)] = dataclasses.replace(a, level_m=np.r_[np.nan, level[a.region_id[1:]]])
    return [done[id(a)] for a in answers]


def split_into_tiles(cells: np.ndarray, side_cells: int):
    """Test and bench helper: the tiles of a whole cloud's cells in squares of ``side_cells`` cells from row and
    column 0: per tile ((row, col) on the tile grid, index of its cells among ``cells`` (core and the ring about it),
    the core mask), in row order."""
    t = cells // side_cells
    tiles = []
    for tr, tc in np.unique(t, axis=0):
        lo_r, lo_c = tr * side_cells, tc * side_cells
        near = ((cells[:, 0] >= lo_r - 1) & (cells[:, 0] <= lo_r + side_cells) & (cells[:, 1] >= lo_c - 1)
                & (cells[:, 1] <= lo_c + side_cells))
        idx = np.flatnonzero(near)
        tiles.append(((int(tr), int(tc)), idx, (t[idx, 0] == tr) & (t[idx, 1] == tc)))
    return tiles


@dataclasses.dataclass(frozen=True)
class _Window:
    """A tile's window in ``whole_level_bodies_tiled`` (what its worker reads): the index of its cells among the
    whole cloud's (core and ``halo`` cells about it, as the tile's buffer and its neighbours' spooled cells hold
    them), which are in the core, which in the core and the ring one cell wide about it."""

    tile: tuple
    side: int
    index: np.ndarray
    core: np.ndarray
    near: np.ndarray


def _windows(cells: np.ndarray, side: int, halo: int, every: bool = False) -> list[_Window]:
    """The tiles' windows (squares of ``side`` cells from row and column 0, a halo of ``halo`` cells), in row
    order: of the tiles holding cells, or (``every``) of every tile in the box of those (the empty cells of a tile
    without returns -- a lake larger than a tile that mirrored every pulse -- are a gap too)."""
    t = cells // side
    out = []
    order = np.lexsort((cells[:, 1], cells[:, 0]))
    rows = cells[order, 0]
    if every:
        (r0, c0), (r1, c1) = t.min(axis=0), t.max(axis=0)
        places = np.stack(np.meshgrid(np.arange(r0, r1 + 1), np.arange(c0, c1 + 1), indexing="ij"), -1).reshape(-1, 2)
    else:
        places = np.unique(t, axis=0)
    for tr, tc in places:
        r0, c0 = tr * side, tc * side
        a, b = np.searchsorted(rows, [r0 - halo, r0 + side + halo])
        idx = order[a:b]
        idx = np.sort(idx[(cells[idx, 1] >= c0 - halo) & (cells[idx, 1] < c0 + side + halo)])
        rr, cc = cells[idx, 0] - r0, cells[idx, 1] - c0
        core = (rr >= 0) & (rr < side) & (cc >= 0) & (cc < side)
        near = (rr >= -1) & (rr <= side) & (cc >= -1) & (cc <= side)
        out.append(_Window((int(tr), int(tc)), side, idx, core, near))
    return out


def _label_round(cells, windows, join_value, join_tol, values, ncols_whole):
    """One labelling round: every tile's components on its core and ring, the parent's join; per cell (the
    tiles' spooled core labels) the component's id over the cloud (0: none), and per id its cells and median."""
    done = [tile_components(cells[w.index[w.near]], join_value[w.index[w.near]], join_tol,
                            values[w.index[w.near]], w.core[w.near], ncols_whole, w.tile) for w in windows]
    answers = join_tile_regions((s for s, _ in done), positions=[w.tile for w in windows])
    answers = _exact(answers, [(kept.label, values[w.index[w.near]][w.core[w.near]]) for w, (_, kept) in
                               zip(windows, done)])
    n_span = max((int(a.region_id.max(initial=0)) for a in answers), default=0)
    gid = np.zeros(len(cells), np.int64)
    area, level = [np.zeros(n_span + 1, np.int64)], [np.full(n_span + 1, np.nan)]
    for a in answers:
        area[0][a.region_id[1:]] = a.cells[1:]
        level[0][a.region_id[1:]] = a.level_m[1:]
    nxt = n_span + 1
    for w, (s, kept), a in zip(windows, done, answers):
        lab = kept.label
        m, n = s.n_spanning, len(kept.cells) - 1
        ids = np.r_[a.region_id, np.arange(nxt, nxt + n - m)]
        gid[w.index[w.near][w.core[w.near]]] = ids[lab]
        area.append(kept.cells[m + 1:])
        level.append(kept.level_m[m + 1:])
        nxt += n - m
    return gid, np.concatenate(area), np.concatenate(level)


def _sum_round(cells, windows, ids, values, n):
    """A reduction round: per id (1..n-1; ``ids`` per cell, 0: none) its cells and the median of ``values`` (k, m)
    of its cells (NaN: not counted), from each tile's counts and histograms over its core (the medians of ids
    wholly in one tile's core exact: their histograms sent all the same here, a check of the spanning case)."""
    count = np.zeros(n, np.int64)
    hists = []
    for w in windows:
        k = w.index[w.core]
        idc = ids[k]
        count += np.bincount(idc, minlength=n)
        v = np.asarray(values, float)[k]
        vl = np.repeat(idc, v.shape[1])
        v = v.ravel()
        take = (vl > 0) & np.isfinite(v)
        if take.any():
            pair, cnt = np.unique(np.column_stack([vl[take], np.floor(v[take] / LEVEL_BIN_M).astype(np.int64)]),
                                  axis=0, return_counts=True)
            hists.append((pair, cnt))
    if not hists:
        return count, np.full(n, np.nan)
    pair = np.concatenate([h[0] for h in hists])
    cnt = np.concatenate([h[1] for h in hists])
    o = np.lexsort((pair[:, 1], pair[:, 0]))
    pair, cnt = pair[o], cnt[o]
    mbins = np.zeros((n, 2), np.int64)
    mranks = np.zeros((n, 2), np.int64)
    starts = np.flatnonzero(np.r_[True, pair[1:, 0] != pair[:-1, 0]])
    for s0, e in zip(starts, np.r_[starts[1:], len(pair)]):
        b1, b2, k1, k2 = _median_bins(pair[s0:e, 1], cnt[s0:e])
        mbins[pair[s0, 0]] = b1, b2
        mranks[pair[s0, 0]] = k1, k2
    # the next passes: the finer histograms and the values of each id's two middle bins (the parent: exact medians)
    answer = RegionDecisions(np.arange(n), count, np.full(n, np.nan), mbins[:, None, :], mranks)
    answers = _exact([answer] * len(windows), [(ids[w.index[w.core]], np.asarray(values, float)[w.index[w.core]])
                                               for w in windows])
    return count, answers[0].level_m


def _exact(answers, label_values):
    """The tiles' further answers and the parent's exact medians (``refine_medians``, ``exact_levels``):
    ``label_values`` per tile its core cells' labels and values."""
    for _ in LEVEL_BINS_M[1:]:
        answers = refine_medians(answers, [median_histogram(lab, v, a) for (lab, v), a in
                                           zip(label_values, answers)])
    return exact_levels(answers, [values_in_median_bins(lab, v, a) for (lab, v), a in zip(label_values, answers)])


def _void_cells(cells, windows, box):
    """Per tile, the empty cells of its core and the ring about it within the cloud's box (``box``: rows, columns
    first and last): rows and columns, and which are in the core (the tile's own cells tell them: bounded by a
    tile)."""
    out = []
    r_lo, c_lo, r_hi, c_hi = box
    for w in windows:
        tr, tc = w.tile
        side = w.side
        r0, c0 = tr * side - 1, tc * side - 1
        occ = np.zeros((side + 2, side + 2), bool)
        near = cells[w.index[w.near]]
        occ[near[:, 0] - r0, near[:, 1] - c0] = True
        i, j = np.nonzero(~occ)
        r, c = i + r0, j + c0
        inside = (r >= r_lo) & (r <= r_hi) & (c >= c_lo) & (c <= c_hi)
        r, c, i, j = r[inside], c[inside], i[inside], j[inside]
        out.append((np.column_stack([r, c]), (i >= 1) & (i <= side) & (j >= 1) & (j <= side)))
    return out


def _void_round(voids, windows, member, ncols_whole):
    """Components of the empty cells ``member`` (per tile, per its void cells): per tile its void cells' ids over
    the cloud (0: not a member) for the core and the ring, from the labelling round of ``tile_components``."""
    done = []
    for (vc, vcore), w, mem in zip(voids, windows, member):
        if not len(vc):
            done.append(None)
            continue
        done.append(tile_components(vc, np.where(mem, 0.0, np.nan), 0.5, np.zeros((len(vc), 0)), vcore,
                                    ncols_whole, w.tile))
    present = [d for d in done if d is not None]
    answers = iter(join_tile_regions((s for s, _ in present),
                                     positions=[w.tile for w, d in zip(windows, done) if d is not None]))
    n_span = 0
    per_tile = []
    for d in done:
        per_tile.append(None if d is None else next(answers))
    for a in per_tile:
        if a is not None:
            n_span = max(n_span, int(a.region_id.max(initial=0)))
    nxt = n_span + 1
    ids_core = []
    for d, a in zip(done, per_tile):
        if d is None:
            ids_core.append(np.zeros(0, np.int64))
            continue
        s, kept = d
        m, n = s.n_spanning, len(kept.cells) - 1
        ids = np.r_[a.region_id, np.arange(nxt, nxt + n - m)]
        ids_core.append(ids[kept.label])
        nxt += n - m
    return ids_core, nxt


def whole_level_bodies_tiled(cells: np.ndarray, heights: np.ndarray, wg, p, side_cells: int):
    """``pipeline.whole_level_bodies`` tile by tile (squares of ``side_cells`` cells): each round is a pass of the
    tiles over their windows (core and a halo of the wall rule's reach and the rim: what their buffers and their
    neighbours' spooled cells hold) and a reduction of per-region sums in the parent. Rounds: (1) the level
    regions, their areas and levels; (2) each large region's cells at its level, relabelled within it, areas and
    levels; (3) the banks across the rim (a quay's wall: the lowest land within ``WALL_BEHIND_M``), counted per
    region; (4) shore and open sky, counted; (5) the water cells; then the join across dropouts: (6) the empty
    cells near the survey's edge and those seeded beyond it (``water_survey_coverage``), (7) the gaps, the
    (gap, patch) pairs to the parent, which links the patches by level; (2)-(5) again for the joined bodies; (8)
    the bodies (components of the water cells) and their levels. The levels of regions spanning tiles are
    histogram medians (``LEVEL_BIN_M``), the rest is exact. A check of the decomposition (the whole cloud's cells
    are held here as the tiles would hold theirs, each tile reading only its window), not yet the tiles' pass."""
    empty = cl.LevelBodies(1, np.zeros(0, np.int64), np.zeros(0))
    tol = p.level_water_tol_m
    if not len(cells) or p.level_water_min_area_m2 <= 0:
        return empty
    c = wg.cell_m
    reach = int(np.ceil(cl.WALL_BEHIND_M / c))
    shore_cells = max(1, int(np.ceil(p.water_shore_m / c)))
    halo = max(reach, shore_cells) + 4
    ncols_whole = int(cells[:, 1].max()) + 1
    windows = _windows(cells, side_cells, halo)
    lo, ground, hi = heights[:, 0], heights[:, 1], heights[:, 2]
    med = level_medians(cells, heights, tol)
    if np.isfinite(med).sum() * c * c < p.level_water_min_area_m2:
        return empty
    min_cells = p.level_water_min_area_m2 / (c * c)
    # (1) level regions
    gid1, area1, level1 = _label_round(cells, windows, med, tol, med[:, None], ncols_whole)
    bits = np.zeros(len(cells), np.uint8)

    def window_grid(w, gid):
        """The tile's window as ``pipeline._Blocks`` (its box's blocks holding cells), its cells' slots there and
        the window's arrays."""
        rc = cells[w.index]
        r0, c0 = rc.min(axis=0)
        nr, nc = (rc.max(axis=0) - (r0, c0) + 1).astype(int)
        side = cl.LEVEL_BODIES_BLOCK_CELLS
        act = np.zeros((-(-nr // side), -(-nc // side)), bool)
        act[(rc[:, 0] - r0) // side, (rc[:, 1] - c0) // side] = True
        g = cl._Blocks(act, nr, nc, side)
        u = g.locate(rc[:, 0] - r0, rc[:, 1] - c0)
        arrays = []
        for a in (lo, ground, hi):
            x = np.full(g.n, np.nan)
            x[u] = a[w.index]
            arrays.append(x)
        ids, local = np.unique(np.r_[0, gid[w.index]], return_inverse=True)   # the window's regions, 0 first
        lab = np.zeros(g.n, np.int64)
        lab[u] = local[1:]
        incore = np.zeros(g.n, bool)
        incore[u[w.core]] = True
        return g, u, arrays, ids, lab, incore

    def bodies(region, area_r, level_r, joined: bool):
        """Rounds (2)-(5): marks in ``bits`` the water returns of the regions ``region`` (id per cell; their cells
        ``area_r`` and levels ``level_r`` per id) that are level water bodies."""
        big = area_r >= min_cells
        big[0] = False
        if not big.any():
            return
        with np.errstate(invalid="ignore"):
            at_level = big[region] & (np.abs(med - level_r[region]) <= tol)
        if joined:   # one body even where its level cells do not touch
            gid = np.where(at_level, region, 0)
            area, level = _sum_round(cells, windows, gid, med[:, None], len(area_r))
        else:
            gid, area, level = _label_round(cells, windows, np.where(at_level, region.astype(float), np.nan), 0.5,
                                            med[:, None], ncols_whole)
        good = area >= min_cells
        good[0] = False
        if not good.any():
            return
        # (3) the banks: per region, the rim cells (two cells about it) with a bank and those above the level
        n_bank = np.zeros(len(good), np.int64)
        n_above = np.zeros(len(good), np.int64)
        for w in windows:
            g, u, (wlo, wground, whi), ids, lab, incore = window_grid(w, gid)
            ok = good[ids]
            if not ok[1:].any():
                continue
            occupied = np.isfinite(wground)
            v, lv = cl._pairs_near(g, lab, ok, 2, occupied)
            lvl = level[ids[lv]]
            steepest = lvl + cl.BANK_MAX_SLOPE * 2.0 * c
            bank = np.where(wground[v] <= steepest, wground[v], np.where(wlo[v] <= steepest, wlo[v], np.nan))
            high = np.flatnonzero(np.isnan(bank) & incore[v])
            if len(high):
                stride = np.int64(len(ids)) + 1
                behind = cl._lowest_land_near(g, v[high], lv[high], reach, wlo, lab, v * stride + lv, stride)
                wall = wlo[v[high]] - behind <= cl.BANK_MAX_SLOPE * 2.0 * c
                bank[high[wall]] = wlo[v[high[wall]]]
            fin = np.isfinite(bank) & incore[v]
            n_bank += np.bincount(ids[lv[fin]], minlength=len(good))
            n_above += np.bincount(ids[lv[fin & (bank > lvl + tol)]], minlength=len(good))
        with np.errstate(invalid="ignore", divide="ignore"):
            good &= (n_bank > 0) & ~(n_above / n_bank < p.level_water_bank_fraction)
        if not good.any():
            return

        def shore(w, good):
            """The (cell, region) pairs of the shore and the region's own cells in the tile's core, whether each
            return is on the level and whether open sky is over it."""
            g, u, z, ids, lab, incore = window_grid(w, gid)
            ok = good[ids]
            if not ok[1:].any():
                return None
            occupied = np.isfinite(z[1])
            v, lv = cl._pairs_near(g, lab, ok, shore_cells, occupied)
            own = np.flatnonzero(ok[lab])
            v, lv = np.r_[own, v], np.r_[lab[own], lv]
            k = incore[v]
            v, lv = v[k], lv[k]
            sky = np.where(occupied[v], z[2][v], -np.inf)
            for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                nb = g.neighbour(v, dr, dc)
                h = np.full(len(v), -np.inf)
                h[nb >= 0] = np.nan_to_num(z[2][nb[nb >= 0]], nan=-np.inf)
                sky = np.maximum(sky, h)
            lvl = level[ids[lv]]
            covered = sky > lvl + p.low_veg_max_m
            with np.errstate(invalid="ignore"):
                on = [np.abs(a[v] - lvl) <= tol for a in z]
            slot = np.full(g.n, -1, np.int64)   # the slots back to the whole cloud's cells
            slot[u] = w.index
            return slot[v], ids[lv], ids[lab[v]] == ids[lv], on, covered

        # (4) shore and open sky: a level floor under crowns is forest floor
        n_members = np.zeros(len(good))
        n_covered = np.zeros(len(good))
        for w in windows:
            s = shore(w, good)
            if s is None:
                continue
            _, region_id, own, on, covered = s
            members = sum((o & own).astype(np.int64) for o in on)
            n_members += np.bincount(region_id, weights=members, minlength=len(good))
            n_covered += np.bincount(region_id, weights=members * covered, minlength=len(good))
        with np.errstate(invalid="ignore", divide="ignore"):
            good &= ~((n_members > 0) & (n_covered / n_members > 0.05))
        # (5) the water returns of the bodies
        for w in windows:
            s = shore(w, good)
            if s is None:
                continue
            cell, region_id, _, on, covered = s
            take = good[region_id]
            for bit, o in enumerate(on):
                m = take & o & ~covered
                np.bitwise_or.at(bits, cell[m], np.uint8(1 << bit))

    bodies(gid1, area1, level1, False)
    if p.level_water_across_dropouts:
        joined = _joined_patches(cells, windows, wg, p, gid1, area1, level1, min_cells, ncols_whole)
        if joined is not None:
            area_j, level_j = _sum_round(cells, windows, joined, med[:, None], int(joined.max()) + 1)
            bodies(joined, area_j, level_j, True)
    water = bits > 0
    if not water.any():
        return empty
    # (8) the bodies and their levels: the median of their water returns
    z = np.where((bits[:, None] & (1 << np.arange(3))) > 0, heights, np.nan)
    body, _, body_level = _label_round(cells, windows, np.where(water, 0.0, np.nan), 0.5, z, ncols_whole)
    key = cells[water, 0].astype(np.int64) * ncols_whole + cells[water, 1]
    order = np.argsort(key)
    return cl.LevelBodies(ncols_whole, key[order], body_level[body[water]][order])


def _joined_patches(cells, windows, wg, p, gid1, area1, level1, min_cells, ncols_whole):
    """Rounds (6)-(7): the level patches (regions smaller than a body) joined across the gaps they border
    (``pipeline._join_across_dropouts``): joined id per cell (0: none; only joins of two patches or more), or None.
    The gaps are the empty cells of the cloud's box but those beyond the survey (``water_survey_coverage``:
    ``pipeline.beyond_coverage``'s near cells in components seeded outside the footprint)."""
    c, tol = wg.cell_m, p.level_water_tol_m
    small = area1 < min_cells
    small[0] = False
    if small.sum() < 2:
        return None
    box = (*cells.min(axis=0), *cells.max(axis=0))
    side = windows[0].side
    every = _windows(cells, side, 1, every=True)
    coverage = p.water_survey_coverage
    if coverage:
        if wg.footprint_10m is not None:
            fp, fx0, fy0 = wg.footprint_10m, wg.x0_m, wg.y0_m
        else:   # the footprint of the cells' centres (``whole_level_bodies``)
            xc, yc = wg.x0_m + (cells[:, 1] + 0.5) * c, wg.y0_m + (cells[:, 0] + 0.5) * c
            fx0, fy0 = float(xc.min()), float(yc.min())
            fp = cl.survey_footprint(cl.occupied_10m(xc, yc, fx0, fy0))
        outside = np.pad(~fp, 1, constant_values=True)
        fringe = ndimage.binary_dilation(outside, np.ones((3, 3), bool))

        def index(rc, a):
            i = np.clip(np.floor((wg.y0_m + (rc[:, 0] + 0.5) * c - fy0) / cl.COVERAGE_CELL_M).astype(np.int64) + 1,
                        0, a.shape[0] - 1)
            j = np.clip(np.floor((wg.x0_m + (rc[:, 1] + 0.5) * c - fx0) / cl.COVERAGE_CELL_M).astype(np.int64) + 1,
                        0, a.shape[1] - 1)
            return i, j

        def at(a, rc):
            return a[index(rc, a)]

        # A tile without a return whose cells all lie in 10 m cells outside the footprint is beyond the survey as a
        # whole (the sparse pass's blocks not stored): no tile reads it, and the empty cells beside it are seeded
        # (a diagonal corridor's box is mostly such tiles).
        skipped = set()
        for w in every:
            if len(w.index) == 0:
                tr, tc = w.tile
                (i0, i1), (j0, j1) = (index(np.array([[tr * side, tc * side], [tr * side + side - 1,
                                                                                tc * side + side - 1]]), outside))
                if outside[i0:i1 + 1, j0:j1 + 1].all():
                    skipped.add(w.tile)
        every = [w for w in every if w.tile not in skipped]
    voids = _void_cells(cells, every, box)
    member = [np.ones(len(vc), bool) for vc, _ in voids]
    if coverage:
        # the skipped tiles on the tiles' grid (padded by one tile: the ring of an edge tile lies beyond the box)
        t0 = box[0] // side - 1, box[1] // side - 1
        skip_grid = np.zeros((box[2] // side - t0[0] + 2, box[3] // side - t0[1] + 2), bool)
        for tr, tc in skipped:
            skip_grid[tr - t0[0], tc - t0[1]] = True

        def beside_skipped(rc):
            """Which cells ``rc`` are in, or beside, a tile skipped as beyond the survey."""
            out = np.zeros(len(rc), bool)
            if skipped:
                for dr in (-1, 0, 1):
                    for dc in (-1, 0, 1):
                        t = (rc + (dr, dc)) // side - t0
                        out |= skip_grid[t[:, 0], t[:, 1]]
            return out

        near = [at(fringe, vc) for vc, _ in voids]
        near_ids, n = _void_round(voids, every, near, ncols_whole)
        seeded = np.zeros(n, bool)   # the parent's OR of the tiles' seeded components
        for (vc, vcore), ids, nr in zip(voids, near_ids, near):
            seed = (at(outside, vc[vcore]) | beside_skipped(vc[vcore])) & nr[vcore]
            seeded[ids[seed]] = True
        seeded[0] = False
        # the ring's cells take their owner's answer: the spooled ids of the neighbours' cores (a skipped tile's
        # cells: beyond)
        key_all = np.concatenate([vc[vcore, 0] * ncols_whole + vc[vcore, 1] for vc, vcore in voids])
        beyond_all = np.concatenate([seeded[ids] for ids in near_ids])
        o = np.argsort(key_all)
        key_all, beyond_all = key_all[o], beyond_all[o]
        member = []
        for vc, _ in voids:
            k = vc[:, 0] * ncols_whole + vc[:, 1]
            pos = np.minimum(np.searchsorted(key_all, k), len(key_all) - 1)
            owned = key_all[pos] == k
            member.append(owned & ~beyond_all[pos])
    gap_ids, _ = _void_round(voids, every, member, ncols_whole)
    # the gaps' ids of every void cell (core and ring), as the tiles' spooled ids give them
    key_all = np.concatenate([vc[vcore, 0] * ncols_whole + vc[vcore, 1] for vc, vcore in voids])
    gap_all = np.concatenate(gap_ids)
    if not gap_all.any():
        return None
    o = np.argsort(key_all)
    key_all, gap_all = key_all[o], gap_all[o]
    # (7) per tile the (gap, patch) pairs of its core's patch cells
    patch = np.where(small[gid1], gid1, 0)
    pairs = []
    for w in windows:
        k = w.index[w.core]
        k = k[patch[k] > 0]
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr or dc:
                    key = (cells[k, 0] + dr).astype(np.int64) * ncols_whole + cells[k, 1] + dc
                    ok = (cells[k, 1] + dc >= 0) & (cells[k, 1] + dc < ncols_whole)
                    pos = np.minimum(np.searchsorted(key_all, key), len(key_all) - 1)
                    hit = ok & (key_all[pos] == key) & (gap_all[pos] > 0)
                    pairs.append(np.column_stack([gap_all[pos[hit]], patch[k[hit]]]))
    pairs = np.unique(np.concatenate(pairs), axis=0) if pairs else np.zeros((0, 2), np.int64)
    if len(pairs) < 2:
        return None
    # the parent: per gap, its patches in order of level; neighbours in that order within tol join
    order = np.lexsort((level1[pairs[:, 1]], pairs[:, 0]))
    v, r = pairs[order, 0], pairs[order, 1]
    link = (v[1:] == v[:-1]) & (np.abs(level1[r[1:]] - level1[r[:-1]]) <= tol)
    if not link.any():
        return None
    parent = np.arange(len(area1), dtype=np.int64)
    cl._union(parent, r[:-1][link].astype(np.int64), r[1:][link].astype(np.int64))
    root = _roots(parent)
    parts = np.bincount(root[np.unique(pairs[:, 1])], minlength=len(area1))
    ids = np.zeros(len(area1), np.int64)
    multi = np.unique(root[small & (parts[root] >= 2)])
    ids[multi] = np.arange(1, len(multi) + 1)
    joined = ids[root]
    joined[~small] = 0
    out = joined[gid1]
    return out if out.any() else None
