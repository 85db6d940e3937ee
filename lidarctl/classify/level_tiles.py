"""The whole cloud's level regions labelled tile by tile (issue 44, level-tiles): the first step of
``pipeline.whole_level_bodies`` -- the level cells (returns spanning at most 2 ``level_water_tol_m``) joined to
their 8 neighbours whose median return differs by at most the tolerance, each region's area and level (the median
of its cells' median returns) -- with the parent's memory bounded by the tiles' borders, not by the cloud's cells.

Each tile (in its worker) labels its own cells (those whose centre lies in its core) and the ring of cells about
its core (the halo: its buffer holds them), and hands the parent only (``TileRegions``): the regions that reach
the halo (they continue in another tile), with their area and level histogram over the tile's core cells, the
halo cells they hold and the tile's own edge cells (keys on the whole grid and local labels). A region that
reaches no halo cell is wholly in the core: the tile decides its area and exact level itself. The parent joins the
regions across the tiles' borders by union-find on the cells two tiles share (a halo cell of one is an edge cell
of its owner), adds their areas and histograms (``join_tile_regions``) and gives each tile back its regions'
area and level only (``RegionDecisions``).

Exact: the regions (the same partition of the cells as ``pipeline._components``) and their areas. Not exact: the
level of a region spanning tiles, the median of a histogram of ``LEVEL_BIN_M`` bins (the mean of the two middle
values' bin centres: within half a bin of ``np.median``; exact where the heights are on a LAS quantum of twice the
bin). Not done yet: the rest of ``whole_level_bodies`` (each region cut to its level, the rim's banks and a quay's
wall within ``WALL_BEHIND_M``, shore and open sky, the join across dropouts and the bodies' own medians) on the
same pattern; until then the option ``water_whole_level_bodies`` keeps the parent's pass on every occupied cell."""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from lidarctl import grid
from lidarctl.classify import pipeline as cl

# The bins (m) of the level histograms of the regions that span tiles: a median within 0.25 mm of ``np.median``'s,
# 1/200 of the default ``level_water_tol_m`` (5 cm); exact for heights on a LAS quantum of 1 mm (medians of two
# returns: multiples of 0.5 mm).
LEVEL_BIN_M = 0.0005


@dataclasses.dataclass(frozen=True)
class TileRegions:
    """What a tile hands the parent about its level regions (``tile_level_regions``): only the regions that reach
    its halo (local labels 1..``n_spanning``) and its border cells, no per-cell arrays of its core.
    ``core_cells[k]``: the region's cells in the core (index 0 unused); ``hist_region``, ``hist_bin``,
    ``hist_count``: its histogram of the cells' median returns over the core (bins of ``LEVEL_BIN_M`` from 0 m);
    ``row``, ``col``: the tile's place on the tile grid; ``halo_keys`` / ``halo_label``: the halo cells in a spanning region (whole-grid keys ``row * ncols + col``);
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
    region's id across the cloud (1..), its area (cells) and level (m: the histogram's median)."""

    region_id: np.ndarray
    cells: np.ndarray
    level_m: np.ndarray


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
    keys), ``tile`` its (row, col) on the tile grid. Memory of the tile's window (a grid over its cells' box). Returns what it hands the parent and what it
    keeps."""
    core = np.asarray(core, bool)
    med_cell = level_medians(cells, heights, tol_m)
    r0, c0 = cells.min(axis=0)
    nrows, ncols = (cells.max(axis=0) - (r0, c0) + 1).astype(int)
    rr, cc = cells[:, 0] - r0, cells[:, 1] - c0
    med = np.full((nrows, ncols), np.nan)
    med[rr, cc] = med_cell
    incore = np.zeros((nrows, ncols), bool)
    incore[rr[core], cc[core]] = True
    lab = cl._level_regions(med, tol_m)
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
    core_med = med_cell[core]
    lv = core_lab > 0
    count = np.bincount(core_lab, minlength=n + 1)
    level = np.full(n + 1, np.nan)
    level[m + 1:] = cl._group_median(core_med[lv], core_lab[lv], n + 1)[m + 1:]
    # the spanning regions' histograms over the core
    sp = lv & (core_lab <= m)
    b = np.floor(core_med[sp] / LEVEL_BIN_M).astype(np.int64)
    pair, cnt = np.unique(np.column_stack([core_lab[sp], b]), axis=0, return_counts=True) if sp.any() else (
        np.zeros((0, 2), np.int64), np.zeros(0, np.int64))

    def keys(mask):
        i, j = np.nonzero(mask)
        return (i.astype(np.int64) + r0) * ncols_whole + (j + c0), lab[i, j]

    hk, hl = keys(halo & (lab > 0) & (lab <= m))
    ek, el = keys(edge)
    o = np.argsort(ek)
    sent = TileRegions(int(tile[0]), int(tile[1]), m, count[:m + 1].copy(), pair[:, 0].copy(), pair[:, 1].copy(), cnt, hk, hl, ek[o], el[o])
    kept = TileLabels(core_lab, np.where(np.arange(n + 1) > m, count, 0), level)
    return sent, kept


@numba.njit(cache=True)
def _union_pairs(parent, a, b):
    """Joins the sets of ``a[k]`` and ``b[k]`` (union-find ``parent``, in place; roots by ``lidarctl.grid._find``)."""
    for k in range(len(a)):
        x, y = grid._find(parent, a[k]), grid._find(parent, b[k])
        if x != y:
            if x < y:
                parent[y] = x
            else:
                parent[x] = y


@numba.njit(cache=True)
def _roots(parent):
    out = np.empty(len(parent), np.int64)
    for k in range(len(parent)):
        out[k] = grid._find(parent, k)
    return out


def _histogram_median(bins: np.ndarray, counts: np.ndarray) -> float:
    """The median (m) of values in ``LEVEL_BIN_M`` bins ``bins`` (sorted) counted ``counts``: the mean of the two
    middle values' bin centres."""
    cum = np.cumsum(counts)
    n = int(cum[-1])
    a = bins[np.searchsorted(cum, (n - 1) // 2, side="right")]
    b = bins[np.searchsorted(cum, n // 2, side="right")]
    return (0.5 * (a + b) + 0.5) * LEVEL_BIN_M


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
        hk, hn = t.halo_keys, t.halo_label.astype(np.int64) + off
        ek, en = t.edge_keys, t.edge_label.astype(np.int64) + off
        for u in near(pos):
            if u in edges:   # this tile's halo cells in that tile's core
                a, b, rest = _match(hk, hn, *edges[u])
                _union_pairs(parent, a, b)
                hk, hn = hk[rest], hn[rest]
            if u in halos:   # that tile's halo cells in this tile's core
                a, b, rest = _match(*halos[u], ek, en)
                _union_pairs(parent, a, b)
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
    hr = np.concatenate([root[h[0]] for h in hists]) if hists else np.zeros(0, np.int64)
    hb = np.concatenate([h[1] for h in hists]) if hists else np.zeros(0, np.int64)
    hc = np.concatenate([h[2] for h in hists]) if hists else np.zeros(0, np.int64)
    del hists
    o = np.lexsort((hb, hr))
    hr, hb, hc = hr[o], hb[o], hc[o]
    level = np.full(n, np.nan)
    starts = np.flatnonzero(np.r_[True, hr[1:] != hr[:-1]]) if len(hr) else np.zeros(0, np.int64)
    for s, e in zip(starts, np.r_[starts[1:], len(hr)]):
        level[hr[s]] = _histogram_median(hb[s:e], hc[s:e])
    spanning = np.ones(n, bool)
    spanning[offsets] = False
    ids = np.zeros(n, np.int64)
    roots = np.unique(root[spanning])
    ids[roots] = np.arange(1, len(roots) + 1)
    out = []
    for off, end in zip(offsets, offsets[1:] + [n]):
        r = root[off + 1:end]
        out.append(RegionDecisions(np.r_[0, ids[r]], np.r_[0, area[r]].astype(np.int64), np.r_[np.nan, level[r]]))
    return out


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
