"""The whole cloud's level water bodies (``pipeline.whole_level_bodies``) tile by tile (issue 44, level-tiles,
level-wire): the same bodies with the parent holding the tiles' borders and per-region answers, not every occupied
cell.

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
that reach.

In a tiled run (level-wire) the run tiles' workers write their water cells by level tile (``spool_cells``:
squares of ``LEVEL_TILE_M`` on the whole water grid, at least the halo) under the run's scratch; the parent joins
each level tile's fragments (``CellSpool.from_fragments``) and runs every step of ``whole_level_bodies`` so
(``whole_level_bodies_spooled``): each round reads one level tile's window at a time (its own and its neighbours'
files) and writes its core cells' results back to its files; the bodies stay there (``SpooledLevelBodies``), each
run tile reading its window's. ``whole_level_bodies_tiled``: the same on cells held in memory (tests, benches)."""

from __future__ import annotations

import collections
import dataclasses
from pathlib import Path

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
    within their region's middle bins of every histogram: (region id over the cloud, value, count) of each distinct
    pair (heights stored to 1 cm repeat: review 40's quantised lake sent 45 % of its cells, 25 bytes a cell in the
    parent; counted, a few entries a region and tile)."""
    lab, v = _core_values(label, values, answer)
    rid = answer.region_id[lab]
    o = np.lexsort((v, rid))
    rid, v = rid[o], v[o]
    first = np.r_[True, (rid[1:] != rid[:-1]) | (v[1:] != v[:-1])] if len(rid) else np.zeros(0, bool)
    at = np.flatnonzero(first)
    return rid[at], v[at], np.diff(np.r_[at, len(rid)])


def exact_levels(answers: list[RegionDecisions], sent) -> list[RegionDecisions]:
    """The parent's exact medians of the spanning regions (``np.median``'s: the mean of the two middle values) from
    the values the tiles sent from the regions' middle bins (``sent``: per tile ``values_in_median_bins``, (region,
    value, count); a pair without counts counts once); the answers with those levels. Memory of the distinct values
    of two bins a region."""
    rid = np.concatenate([s[0] for s in sent]) if sent else np.zeros(0, np.int64)
    val = np.concatenate([s[1] for s in sent]) if sent else np.zeros(0)
    cnt = (np.concatenate([s[2] if len(s) > 2 else np.ones(len(s[0]), np.int64) for s in sent]) if sent
           else np.zeros(0, np.int64))
    o = np.lexsort((val, rid))
    rid, val, cnt = rid[o], val[o], cnt[o]
    n = max((int(a.region_id.max(initial=0)) for a in answers), default=0) + 1
    start = np.searchsorted(rid, np.arange(n))
    has = np.bincount(rid, minlength=n) > 0   # (a region without values has no level)
    upto = np.cumsum(cnt)  # the values counted up to and with each entry
    before = np.r_[0, upto][start]  # each region's values before its first entry
    level = np.full(n, np.nan)
    for a in answers:
        k = np.flatnonzero(has[a.region_id[1:]]) + 1
        ids = a.region_id[k]
        lo = np.searchsorted(upto, before[ids] + a.median_ranks[k, 0], side="right")
        hi = np.searchsorted(upto, before[ids] + a.median_ranks[k, 1], side="right")
        level[ids] = (val[lo] + val[hi]) / 2
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


# The side (m) of the squares the whole water grid is cut into for the level bodies of a tiled run (at least the
# halo the sums need, ~56 m at 1.4 m cells): a tile's window reads its own and its neighbours' files. Not the run's
# tiles (their cores fall on the water grid's cells unevenly): each run tile's worker writes its core cells by these
# squares (``spool_cells``).
LEVEL_TILE_M = 200.0
# The level tiles whose cells the parent keeps read (``CellSpool``; a window reads its tile's and 8 neighbours').
CACHED_TILES = 12


def level_tile_cells(cell_m: float, p) -> int:
    """The side (cells) of the level bodies' tiles on a water grid of ``cell_m``: ``LEVEL_TILE_M``, at least the
    halo (``_halo_cells``)."""
    return max(_halo_cells(cell_m, p), int(round(LEVEL_TILE_M / cell_m)))


def _halo_cells(cell_m: float, p) -> int:
    """The halo (cells) of a tile's window for the sums and looks within a reach: the quay wall's land
    (``WALL_BEHIND_M``) or the shore, and the rim's two cells and more."""
    return max(int(np.ceil(cl.WALL_BEHIND_M / cell_m)), max(1, int(np.ceil(p.water_shore_m / cell_m)))) + 4


def spool_cells(folder, side: int, source: tuple[int, int], cells: np.ndarray, heights: np.ndarray) -> None:
    """A run tile's worker (``tiles.cell_count_histogram``): its core's water cells (``cells`` (k, 2) row and column
    on the whole grid, ``heights`` (k, 3) lowest, median and highest return, m) written under ``folder`` by the
    level tiles (squares of ``side`` cells) they fall in, one file pair per (level tile, run tile ``source``)."""
    if not len(cells):   # a tile whose cells' centres all lie in its neighbours' cores
        return
    folder = Path(folder)
    t = cells // side
    order = np.lexsort((t[:, 1], t[:, 0]))
    t, cells, heights = t[order], cells[order], heights[order]
    first = np.flatnonzero(np.r_[True, np.any(t[1:] != t[:-1], axis=1)])
    for s, e in zip(first, np.r_[first[1:], len(t)]):
        stem = f"{t[s, 0]}_{t[s, 1]}_{source[0]}_{source[1]}"
        np.ascontiguousarray(cells[s:e], np.int64).tofile(folder / f"fc_{stem}.bin")
        np.ascontiguousarray(heights[s:e], np.float64).tofile(folder / f"fh_{stem}.bin")


@dataclasses.dataclass(frozen=True)
class _Window:
    """A level tile's window: its core cells (first, in the tile's order) and its neighbours' cells within ``halo``
    of its core (``parts``: per tile read, which of its cells), ``near``: the core and the ring one cell wide."""

    tile: tuple
    side: int
    cells: np.ndarray
    heights: np.ndarray
    n_core: int
    near: np.ndarray
    parts: tuple

    @property
    def core(self) -> np.ndarray:
        return np.arange(len(self.cells)) < self.n_core


class CellSpool:
    """The whole cloud's water cells by level tile (squares of ``side`` cells on the whole water grid from row and
    column 0), and what each round of ``whole_level_bodies_spooled`` wrote per core cell: files under ``folder``
    (the tiled run's scratch) or, ``folder`` None, in memory (tests, benches). A tile's window reads its own and its
    neighbours' files (``window``): the memory of a window, never of the cloud's cells. ``tiles``: the tiles holding
    cells (row order), ``box``: the cells' rows and columns first and last."""

    def __init__(self, side: int, folder=None):
        self.side = int(side)
        self.folder = None if folder is None else Path(folder)
        self._mem: dict = {}
        self._cache: collections.OrderedDict = collections.OrderedDict()   # the cells last read, a few tiles
        # each name's dtype and shape but the first (raw files: no header to parse; ``np.load``'s ``literal_eval``
        # left cycles of garbage, megabytes between collections, at a load per tile and round)
        self._kinds: dict = {"cells": (np.dtype(np.int64), (2,)), "heights": (np.dtype(np.float64), (3,))}
        self.tiles: list[tuple[int, int]] = []
        self.box = (0, 0, -1, -1)

    def put(self, name: str, t, a: np.ndarray) -> None:
        if self.folder is None:
            self._mem[(name, t)] = a
        else:
            a = np.ascontiguousarray(a)
            self._kinds[name] = (a.dtype, a.shape[1:])
            a.tofile(self.folder / f"{name}_{t[0]}_{t[1]}.bin")

    def get(self, name: str, t):
        """The tile's array ``name`` (None: none written)."""
        if self.folder is None:
            return self._mem.get((name, t))
        if name in ("cells", "heights"):   # written once: the windows of a row of tiles read them again and again
            a = self._cache.get((name, t), False)
            if a is not False:
                self._cache.move_to_end((name, t))
                return a
        f = self.folder / f"{name}_{t[0]}_{t[1]}.bin"
        a = None
        if name in self._kinds and f.exists():
            dtype, tail = self._kinds[name]
            a = np.fromfile(f, dtype).reshape((-1, *tail))
        if name in ("cells", "heights"):
            self._cache[(name, t)] = a
            if len(self._cache) > 2 * CACHED_TILES:
                self._cache.popitem(last=False)
        return a

    def _add(self, t, cells, heights):
        o = np.lexsort((cells[:, 1], cells[:, 0]))
        self.put("cells", t, cells[o])
        self.put("heights", t, heights[o])
        self.tiles.append(t)
        lo, hi = cells.min(axis=0), cells.max(axis=0)
        b = self.box
        self.box = ((int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])) if b[2] < b[0] else
                    (min(b[0], int(lo[0])), min(b[1], int(lo[1])), max(b[2], int(hi[0])), max(b[3], int(hi[1]))))

    @classmethod
    def from_cells(cls, cells: np.ndarray, heights: np.ndarray, side: int) -> "CellSpool":
        """The spool of a whole cloud's cells held in memory (tests, benches)."""
        s = cls(side)
        t = cells // side
        order = np.lexsort((t[:, 1], t[:, 0]))
        t = t[order]
        first = np.flatnonzero(np.r_[True, np.any(t[1:] != t[:-1], axis=1)]) if len(t) else np.zeros(0, int)
        for a, e in zip(first, np.r_[first[1:], len(t)]):
            s._add((int(t[a, 0]), int(t[a, 1])), cells[order[a:e]], heights[order[a:e]])
        return s

    @classmethod
    def from_fragments(cls, folder, side: int) -> "CellSpool":
        """The spool of the files the run tiles' workers wrote (``spool_cells``) under ``folder``: each level tile's
        fragments joined into one file pair (one tile in memory at a time), the fragments removed."""
        folder = Path(folder)
        s = cls(side, folder)
        groups: dict = {}
        for f in folder.glob("fc_*.bin"):
            tr, tc, _, _ = (int(v) for v in f.stem[3:].split("_"))
            groups.setdefault((tr, tc), []).append(f)
        for t in sorted(groups):
            parts = sorted(groups[t])
            cells = np.concatenate([np.fromfile(f, np.int64).reshape(-1, 2) for f in parts])
            heights = np.concatenate([np.fromfile(f.with_name("fh_" + f.name[3:]), np.float64).reshape(-1, 3)
                                      for f in parts])
            for f in parts:
                f.unlink()
                f.with_name("fh_" + f.name[3:]).unlink()
            if len(cells):
                s._add(t, cells, heights)
        return s

    def window(self, t, halo: int) -> _Window:
        """Tile ``t``'s window: its core cells and those within ``halo`` cells of its core."""
        side = self.side
        k = -(-halo // side)
        r0, c0 = t[0] * side, t[1] * side
        cells, heights, parts = [], [], []
        n_core = 0
        for dr, dc in [(0, 0)] + [(a, b) for a in range(-k, k + 1) for b in range(-k, k + 1) if a or b]:
            u = (t[0] + dr, t[1] + dc)
            cu = self.get("cells", u)
            if cu is None:
                continue
            m = ((cu[:, 0] >= r0 - halo) & (cu[:, 0] < r0 + side + halo) & (cu[:, 1] >= c0 - halo)
                 & (cu[:, 1] < c0 + side + halo))
            if not m.any():
                continue
            parts.append((u, m))
            cells.append(cu[m])
            heights.append(self.get("heights", u)[m])
            if (dr, dc) == (0, 0):
                n_core = int(m.sum())
        cells = np.concatenate(cells) if cells else np.zeros((0, 2), np.int64)
        heights = np.concatenate(heights) if heights else np.zeros((0, 3))
        rr, cc = cells[:, 0] - r0, cells[:, 1] - c0
        near = (rr >= -1) & (rr <= side) & (cc >= -1) & (cc <= side)
        return _Window(t, side, cells, heights, n_core, near, tuple(parts))

    def read(self, w: _Window, name: str, fill=0, dtype=np.int64) -> np.ndarray:
        """The window's cells' values of ``name`` (``fill`` where a tile wrote none)."""
        out = []
        for u, m in w.parts:
            a = self.get(name, u)
            out.append(np.full(int(m.sum()), fill, dtype) if a is None else a[m])
        return np.concatenate(out) if out else np.zeros(0, dtype)


@dataclasses.dataclass(frozen=True)
class SpooledLevelBodies:
    """``pipeline.LevelBodies`` kept by level tile in a tiled run's scratch (``whole_level_bodies_spooled``): a run
    tile's worker reads the level tiles its window falls in (``level_at``); the parent holds the folder's name."""

    ncols: int
    side: int
    folder: str
    tiles: frozenset

    @property
    def empty(self) -> bool:
        return not self.tiles

    def level_at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The body's level (m) at whole-grid cells ``rows``, ``cols`` (NaN: in no body)."""
        out = np.full(len(rows), np.nan)
        if self.empty or not len(rows):
            return out
        t = np.unique(np.column_stack([np.asarray(rows) // self.side, np.asarray(cols) // self.side]), axis=0)
        keys, levels = [], []
        for tr, tc in t:
            if (int(tr), int(tc)) in self.tiles:
                keys.append(np.fromfile(Path(self.folder) / f"out_keys_{tr}_{tc}.bin", np.int64))
                levels.append(np.fromfile(Path(self.folder) / f"out_level_{tr}_{tc}.bin", np.float64))
        if not keys:
            return out
        keys, levels = np.concatenate(keys), np.concatenate(levels)
        o = np.argsort(keys)
        return cl.LevelBodies(self.ncols, keys[o], levels[o]).level_at(rows, cols)


def _label_round(store: CellSpool, tiles, name: str, source, join_tol: float, ncols_whole: int, core_values=None):
    """One labelling round: every tile's components (``source(t)``: its cells -- core and the ring --, which are
    its core, the join value and the values over them), the parent's join; each tile's core cells' component id
    over the cloud written as ``name``; per id its cells and (``core_values(t)``: the values of the tile's core
    cells) exact median. The parent holds the tiles' spanning regions and per-region tables, not their cells."""
    tiles = list(tiles)
    wholly_cells, wholly_level, counts = [], [], []

    def sent():
        for t in tiles:
            cells, core, jv, vals = source(t)
            s, kept = tile_components(cells, jv, join_tol, vals, core, ncols_whole, t)
            store.put("label", t, kept.label)
            m, n = s.n_spanning, len(kept.cells) - 1
            wholly_cells.append(kept.cells[m + 1:])
            wholly_level.append(kept.level_m[m + 1:])
            counts.append((m, n))
            yield s

    answers = join_tile_regions(sent(), positions=tiles)
    if core_values is not None:
        for _ in LEVEL_BINS_M[1:]:
            answers = refine_medians(answers, [median_histogram(store.get("label", t), core_values(t), a)
                                               for t, a in zip(tiles, answers)])
        answers = exact_levels(answers, [values_in_median_bins(store.get("label", t), core_values(t), a)
                                         for t, a in zip(tiles, answers)])
    n_span = max((int(a.region_id.max(initial=0)) for a in answers), default=0)
    area, level = [np.zeros(n_span + 1, np.int64)], [np.full(n_span + 1, np.nan)]
    for a in answers:
        area[0][a.region_id[1:]] = a.cells[1:]
        level[0][a.region_id[1:]] = a.level_m[1:]
    nxt = n_span + 1
    for t, (m, n), a in zip(tiles, counts, answers):
        ids = np.r_[a.region_id, np.arange(nxt, nxt + n - m)]
        store.put(name, t, ids[store.get("label", t)])
        nxt += n - m
    return np.concatenate(area + wholly_cells), np.concatenate(level + wholly_level)


def _cell_round(store, tiles, name, make, join_tol, ncols_whole):
    """``_label_round`` on the cells: ``make(w)`` the join value and the values (k, m) over a window's cells."""
    def source(t):
        w = store.window(t, 1)
        jv, vals = make(w)
        return w.cells[w.near], w.core[w.near], jv[w.near], vals[w.near]

    def core_values(t):
        return make(store.window(t, 0))[1]

    return _label_round(store, tiles, name, source, join_tol, ncols_whole, core_values)


def _sum_round(store, tiles, make, n):
    """A reduction round: per id (1..n-1; ``make(w)``: the ids and values (k, m) of a window's cells, 0: none) its
    cells and the median of the values (NaN: not counted), from each tile's counts and histograms over its core."""
    count = np.zeros(n, np.int64)
    hists = []
    for t in tiles:
        idc, v = make(store.window(t, 0))
        count += np.bincount(idc, minlength=n)
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
    answers = [RegionDecisions(np.arange(n), count, np.full(n, np.nan), mbins[:, None, :], mranks)] * len(tiles)
    for _ in LEVEL_BINS_M[1:]:
        answers = refine_medians(answers, [median_histogram(*make(store.window(t, 0)), a)
                                           for t, a in zip(tiles, answers)])
    answers = exact_levels(answers, [values_in_median_bins(*make(store.window(t, 0)), a)
                                     for t, a in zip(tiles, answers)])
    return count, answers[0].level_m


def whole_level_bodies_tiled(cells: np.ndarray, heights: np.ndarray, wg, p, side_cells: int):
    """``whole_level_bodies_spooled`` on a whole cloud's cells held in memory (squares of ``side_cells`` cells; tests
    and benches): ``pipeline.LevelBodies``."""
    if not len(cells) or p.level_water_min_area_m2 <= 0:
        return cl.LevelBodies(1, np.zeros(0, np.int64), np.zeros(0))
    footprint = None
    if p.water_survey_coverage and wg.footprint_10m is None:   # the footprint of the cells' centres
        c = wg.cell_m
        xc, yc = wg.x0_m + (cells[:, 1] + 0.5) * c, wg.y0_m + (cells[:, 0] + 0.5) * c
        fx0, fy0 = float(xc.min()), float(yc.min())
        footprint = cl.survey_footprint(cl.occupied_10m(xc, yc, fx0, fy0)), fx0, fy0
    store = CellSpool.from_cells(cells, heights, side_cells)
    ncols = whole_level_bodies_spooled(store, wg, p, footprint)
    keys = [store.get("out_keys", t) for t in store.tiles]
    keys = [k for k in keys if k is not None]
    if not keys:
        return cl.LevelBodies(1, np.zeros(0, np.int64), np.zeros(0))
    levels = np.concatenate([store.get("out_level", t) for t in store.tiles if store.get("out_keys", t) is not None])
    keys = np.concatenate(keys)
    o = np.argsort(keys)
    return cl.LevelBodies(ncols, keys[o], levels[o])


def whole_level_bodies_spooled(store: CellSpool, wg, p, footprint=None) -> int:
    """``pipeline.whole_level_bodies`` tile by tile on the cells of ``store``: each round a pass of the level tiles
    over their windows (core and a halo of the wall rule's reach and the rim, read from their own and their
    neighbours' files), the tiles' per-core-cell results written back to their files, and a reduction of per-region
    sums in the parent. Rounds: (1) the level regions, their areas and levels; (2) each large region's cells at its
    level, relabelled within it, areas and levels; (3) the banks across the rim (a quay's wall: the lowest land
    within ``WALL_BEHIND_M``), counted per region; (4) shore and open sky, counted; (5) the water cells; then the
    join across dropouts: (6) the empty cells near the survey's edge and those seeded beyond it
    (``water_survey_coverage``), (7) the gaps, the (gap, patch) pairs to the parent, which links the patches by
    level; (2)-(5) again for the joined bodies; (8) the bodies (components of the water cells) and their levels,
    written per tile as ``out_keys`` / ``out_level`` (keys ``row * ncols + col``). Returns ``ncols`` (the whole
    grid's columns the keys count). The parent holds the tiles' spanning regions, per-region tables and the
    (gap, patch) pairs, never an array per cell. ``footprint``: the survey's footprint and its origin (10 m cells,
    x, y of the first; m), None: ``wg.footprint_10m`` from the water grid's origin (a tiled run's)."""
    tol = p.level_water_tol_m
    ncols_whole = store.box[3] + 1
    tiles = store.tiles
    if not tiles or p.level_water_min_area_m2 <= 0:
        return ncols_whole
    c = wg.cell_m
    reach = int(np.ceil(cl.WALL_BEHIND_M / c))
    shore_cells = max(1, int(np.ceil(p.water_shore_m / c)))
    halo = _halo_cells(c, p)

    def med_of(w):
        return level_medians(w.cells, w.heights, tol)

    n_level = sum(int(np.isfinite(med_of(store.window(t, 0))).sum()) for t in tiles)
    if n_level * c * c < p.level_water_min_area_m2:
        return ncols_whole
    min_cells = p.level_water_min_area_m2 / (c * c)
    # (1) level regions
    area1, level1 = _cell_round(store, tiles, "gid1", lambda w: (med_of(w), med_of(w)[:, None]), tol, ncols_whole)

    def window_grid(w, gid):
        """The tile's window as ``pipeline._Blocks`` (its box's blocks holding cells), its cells' slots there and
        the window's arrays."""
        rc = w.cells
        r0, c0 = rc.min(axis=0)
        nr, nc = (rc.max(axis=0) - (r0, c0) + 1).astype(int)
        side = cl.LEVEL_BODIES_BLOCK_CELLS
        act = np.zeros((-(-nr // side), -(-nc // side)), bool)
        act[(rc[:, 0] - r0) // side, (rc[:, 1] - c0) // side] = True
        g = cl._Blocks(act, nr, nc, side)
        u = g.locate(rc[:, 0] - r0, rc[:, 1] - c0)
        arrays = []
        for k in range(3):
            x = np.full(g.n, np.nan)
            x[u] = w.heights[:, k]
            arrays.append(x)
        ids, local = np.unique(np.r_[0, gid], return_inverse=True)   # the window's regions, 0 first
        lab = np.zeros(g.n, np.int64)
        lab[u] = local[1:]
        incore = np.zeros(g.n, bool)
        incore[u[:w.n_core]] = True
        return g, u, arrays, ids, lab, incore

    def bodies(region_of, area_r, level_r, joined: bool):
        """Rounds (2)-(5): marks in each tile's ``bits`` the water returns of the regions ``region_of(w)`` (id per
        window cell; their cells ``area_r`` and levels ``level_r`` per id) that are level water bodies."""
        big = area_r >= min_cells
        big[0] = False
        if not big.any():
            return

        def at_level(w):
            region = region_of(w)
            with np.errstate(invalid="ignore"):
                return region, big[region] & (np.abs(med_of(w) - level_r[region]) <= tol)

        if joined:   # one body even where its level cells do not touch
            def gid_of(w):
                region, at = at_level(w)
                return np.where(at, region, 0)

            area, level = _sum_round(store, tiles, lambda w: (gid_of(w), med_of(w)[:, None]), len(area_r))
        else:
            def make(w):
                region, at = at_level(w)
                return np.where(at, region.astype(float), np.nan), med_of(w)[:, None]

            area, level = _cell_round(store, tiles, "gid2", make, 0.5, ncols_whole)

            def gid_of(w):
                return store.read(w, "gid2")
        good = area >= min_cells
        good[0] = False
        if not good.any():
            return
        # (3) the banks: per region, the rim cells (two cells about it) with a bank and those above the level
        n_bank = np.zeros(len(good), np.int64)
        n_above = np.zeros(len(good), np.int64)
        for t in tiles:
            w = store.window(t, halo)
            g, u, (wlo, wground, whi), ids, lab, incore = window_grid(w, gid_of(w))
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
            """The (cell, region) pairs of the shore and the region's own cells in the tile's core (cells: index
            among the core's), whether each return is on the level and whether open sky is over it."""
            g, u, z, ids, lab, incore = window_grid(w, gid_of(w))
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
            slot = np.full(g.n, -1, np.int64)   # the slots back to the window's cells
            slot[u] = np.arange(len(u))
            return slot[v], ids[lv], ids[lab[v]] == ids[lv], on, covered

        # (4) shore and open sky: a level floor under crowns is forest floor
        n_members = np.zeros(len(good))
        n_covered = np.zeros(len(good))
        for t in tiles:
            s = shore(store.window(t, halo), good)
            if s is None:
                continue
            _, region_id, own, on, covered = s
            members = sum((o & own).astype(np.int64) for o in on)
            n_members += np.bincount(region_id, weights=members, minlength=len(good))
            n_covered += np.bincount(region_id, weights=members * covered, minlength=len(good))
        with np.errstate(invalid="ignore", divide="ignore"):
            good &= ~((n_members > 0) & (n_covered / n_members > 0.05))
        # (5) the water returns of the bodies
        for t in tiles:
            w = store.window(t, halo)
            s = shore(w, good)
            if s is None:
                continue
            cell, region_id, _, on, covered = s
            take = good[region_id]
            bits = store.get("bits", t)
            bits = np.zeros(w.n_core, np.uint8) if bits is None else bits
            for bit, o in enumerate(on):
                m = take & o & ~covered
                np.bitwise_or.at(bits, cell[m], np.uint8(1 << bit))
            store.put("bits", t, bits)

    bodies(lambda w: store.read(w, "gid1"), area1, level1, False)
    if p.level_water_across_dropouts:
        joined = _joined_patches(store, wg, p, area1, level1, min_cells, ncols_whole, footprint)
        if joined is not None:
            def joined_of(w):
                return joined[store.read(w, "gid1")]

            area_j, level_j = _sum_round(store, tiles, lambda w: (joined_of(w), med_of(w)[:, None]),
                                         int(joined.max()) + 1)
            bodies(joined_of, area_j, level_j, True)
    if not any(b is not None and b.any() for b in (store.get("bits", t) for t in tiles)):
        return ncols_whole

    # (8) the bodies and their levels: the median of their water returns
    def water(w):
        bits = store.read(w, "bits", 0, np.uint8)
        z = np.where((bits[:, None] & (1 << np.arange(3))) > 0, w.heights, np.nan)
        return np.where(bits > 0, 0.0, np.nan), z

    _, body_level = _cell_round(store, tiles, "body", water, 0.5, ncols_whole)
    for t in tiles:
        bits = store.get("bits", t)
        if bits is None or not bits.any():
            continue
        cells = store.get("cells", t)[bits > 0]
        store.put("out_keys", t, cells[:, 0].astype(np.int64) * ncols_whole + cells[:, 1])
        store.put("out_level", t, body_level[store.get("body", t)[bits > 0]])
    return ncols_whole


def _tile_keys(cells, ncols_whole):
    return cells[:, 0].astype(np.int64) * ncols_whole + cells[:, 1]


def _joined_patches(store, wg, p, area1, level1, min_cells, ncols_whole, footprint):
    """Rounds (6)-(7): the level patches (regions smaller than a body) joined across the gaps they border
    (``pipeline._join_across_dropouts``): joined id per region of round (1) (0: none; only joins of two patches or
    more), or None. The gaps are the empty cells of the cloud's box but those beyond the survey
    (``water_survey_coverage``: ``pipeline.beyond_coverage``'s near cells in components seeded outside the
    footprint). Each tile's empty cells (its core and the ring) and their ids are written to its files; a ring
    cell takes the answer of the tile whose core holds it."""
    c, tol = wg.cell_m, p.level_water_tol_m
    small = area1 < min_cells
    small[0] = False
    if small.sum() < 2:
        return None
    box = store.box
    side = store.side
    have = set(store.tiles)
    every = [(int(r), int(q)) for r in range(box[0] // side, box[2] // side + 1)
             for q in range(box[1] // side, box[3] // side + 1)]
    coverage = p.water_survey_coverage
    if coverage:
        fp, fx0, fy0 = footprint if footprint is not None else (wg.footprint_10m, wg.x0_m, wg.y0_m)
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
        for t in every:
            if t not in have:
                tr, tc = t
                (i0, i1), (j0, j1) = (index(np.array([[tr * side, tc * side], [tr * side + side - 1,
                                                                                tc * side + side - 1]]), outside))
                if outside[i0:i1 + 1, j0:j1 + 1].all():
                    skipped.add(t)
        every = [t for t in every if t not in skipped]
    # (6) per tile the empty cells of its core and the ring about it within the cloud's box
    void_tiles = []
    r_lo, c_lo, r_hi, c_hi = box
    for t in every:
        tr, tc = t
        r0, c0 = tr * side - 1, tc * side - 1
        occ = np.zeros((side + 2, side + 2), bool)
        near = store.window(t, 1)
        occ[near.cells[:, 0] - r0, near.cells[:, 1] - c0] = True
        i, j = np.nonzero(~occ)
        r, q = i + r0, j + c0
        inside = (r >= r_lo) & (r <= r_hi) & (q >= c_lo) & (q <= c_hi)
        r, q, i, j = r[inside], q[inside], i[inside], j[inside]
        if len(r):
            store.put("void_cells", t, np.column_stack([r, q]))
            store.put("void_core", t, (i >= 1) & (i <= side) & (j >= 1) & (j <= side))
            void_tiles.append(t)

    def owners(t, name):
        """The void cells of the cores of ``t`` and its 8 neighbours: sorted keys and their ``name`` ids."""
        keys, ids = [], []
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                u = (t[0] + dr, t[1] + dc)
                vc = store.get("void_cells", u)
                if vc is None:
                    continue
                core = store.get("void_core", u)
                keys.append(_tile_keys(vc[core], ncols_whole))
                ids.append(store.get(name, u))
        if not keys:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        keys, ids = np.concatenate(keys), np.concatenate(ids)
        o = np.argsort(keys)
        return keys[o], ids[o]

    def lookup(keys_sorted, ids, k):
        """``ids`` of keys ``k`` in ``keys_sorted`` (-1: not there)."""
        if not len(keys_sorted):
            return np.full(len(k), -1, np.int64)
        pos = np.minimum(np.searchsorted(keys_sorted, k), len(keys_sorted) - 1)
        return np.where(keys_sorted[pos] == k, ids[pos], -1)

    def void_round(name, member):
        def source(t):
            vc, vcore = store.get("void_cells", t), store.get("void_core", t)
            return vc, vcore, np.where(member(t, vc, vcore), 0.0, np.nan), np.zeros((len(vc), 0))

        area, _ = _label_round(store, void_tiles, name, source, 0.5, ncols_whole)
        return len(area)

    if coverage:
        side_t0 = box[0] // side - 1, box[1] // side - 1
        skip_grid = np.zeros((box[2] // side - side_t0[0] + 2, box[3] // side - side_t0[1] + 2), bool)
        for tr, tc in skipped:
            skip_grid[tr - side_t0[0], tc - side_t0[1]] = True

        def beside_skipped(rc):
            """Which cells ``rc`` are in, or beside, a tile skipped as beyond the survey."""
            out = np.zeros(len(rc), bool)
            if skipped:
                for dr in (-1, 0, 1):
                    for dc in (-1, 0, 1):
                        tt = (rc + (dr, dc)) // side - side_t0
                        out |= skip_grid[tt[:, 0], tt[:, 1]]
            return out

        n = void_round("void_near", lambda t, vc, vcore: at(fringe, vc))
        seeded = np.zeros(n, bool)   # the parent's OR of the tiles' seeded components
        for t in void_tiles:
            vc, vcore = store.get("void_cells", t), store.get("void_core", t)
            ids = store.get("void_near", t)
            seed = (at(outside, vc[vcore]) | beside_skipped(vc[vcore])) & at(fringe, vc[vcore])
            seeded[ids[seed]] = True
        seeded[0] = False

        def member(t, vc, vcore):
            # the ring's cells take their owner's answer (a skipped tile's cells: beyond)
            ids = lookup(*owners(t, "void_near"), _tile_keys(vc, ncols_whole))
            return (ids >= 0) & ~seeded[np.maximum(ids, 0)]
    else:
        def member(t, vc, vcore):
            return np.ones(len(vc), bool)
    void_round("void_gap", member)
    if not any(store.get("void_gap", t).any() for t in void_tiles):
        return None
    # (7) per tile the (gap, patch) pairs of its core's patch cells
    pairs = []
    for t in store.tiles:
        gap_keys, gap_ids = owners(t, "void_gap")
        if not len(gap_keys):
            continue
        cells = store.get("cells", t)
        gid = store.get("gid1", t)
        patch = np.where(small[gid], gid, 0)
        k = np.flatnonzero(patch > 0)
        tile_pairs = []
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr or dc:
                    key = (cells[k, 0] + dr).astype(np.int64) * ncols_whole + cells[k, 1] + dc
                    ok = (cells[k, 1] + dc >= 0) & (cells[k, 1] + dc < ncols_whole)
                    g = lookup(gap_keys, gap_ids, key)
                    hit = ok & (g > 0)
                    tile_pairs.append(np.column_stack([g[hit], patch[k[hit]]]))
        if tile_pairs:
            pairs.append(np.unique(np.concatenate(tile_pairs), axis=0))
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
    return joined if joined[1:].any() else None
