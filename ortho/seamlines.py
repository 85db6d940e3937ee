"""Seamlines: which frame supplies each mosaic cell.

Computed on a coarse "seam grid" (an integer multiple of the mosaic pixel) so that blocks of thousands
of frames stay in memory:

1. Voronoi partition by nadir distance: each cell goes to the valid frame whose nadir point (the
   projection centre's ground position) is nearest - the least relief displacement.
2. Least-cost seams: for each pair of neighbouring frames, the seam is re-routed along the cheapest
   8-connected path (Dijkstra, ``scipy.sparse.csgraph``) through their common overlap between the ends
   of the Voronoi seam. Cost per cell = 1 + ``object_cost`` within a cell of where the nDSM shows buildings
   or trees (height above ground > ``object_height_m``) + ``difference_cost`` x the normalised grey-value
   difference of the two frames; a cell of the object itself costs more than any route over open ground
   through the pair's overlap can, so the seam crosses as few object cells as it can: none where a ground
   route exists. The cells of the overlap on either side of the new path go to the frame whose exclusive
   area they touch.
3. Objects still split (where seams meet, at seam ends) go whole to a frame that sees all of them.

Labels are frame indices (int32), -1 where no frame is valid.
"""

from __future__ import annotations

import dataclasses

import numpy as np

# OpenCV (morphology, connected parts) and scipy.sparse (the path search) are imported by the functions that
# need them: this module comes with ortho.settings into every ``ortho`` command. No scipy.ndimage (0.2 CPU-s
# to import) and no numba (a compiled path search: 0.6 CPU-s to import and load, a fifth of a demo mosaic).


def voronoi_labels(valid: list, offsets: list, nadir_rc: np.ndarray, shape) -> np.ndarray:
    """Nearest-nadir labels on the seam grid.

    valid[k]: bool (h_k, w_k) of frame k at (row, col) offset offsets[k]; nadir_rc[k]: nadir point in
    seam-grid (row, col) coordinates (float).
    """
    H, W = shape
    labels = np.full((H, W), -1, np.int32)
    best = np.full((H, W), np.inf, np.float32)
    for k, (v, (r0, c0)) in enumerate(zip(valid, offsets)):
        h, w = v.shape
        rr = (np.arange(r0, r0 + h, dtype=np.float32) - nadir_rc[k, 0])[:, None]
        cc = (np.arange(c0, c0 + w, dtype=np.float32) - nadir_rc[k, 1])[None, :]
        d = np.sqrt(rr * rr + cc * cc)
        sub_b = best[r0:r0 + h, c0:c0 + w]
        sub_l = labels[r0:r0 + h, c0:c0 + w]
        better = v & (d < sub_b)
        sub_b[better] = d[better]
        sub_l[better] = k
    return labels


def covered(valid: np.ndarray) -> np.ndarray:
    """The seam cells a frame's ortho covers: its valid cells with the holes inside them filled (the ground a true
    ortho's frame does not see behind buildings, DEM nodata inside the frame). The seams are routed on these: a
    frame's region keeps the cells it does not see, which the mosaic fills from the frame of the nearest nadir
    point that sees them, instead of breaking into an island of another frame round every hole."""
    import cv2

    outside = np.pad(~valid, 1, constant_values=True).view(np.uint8).copy()
    cv2.floodFill(outside, None, (0, 0), 2)
    return outside[1:-1, 1:-1] != 2


def footprint(valid: np.ndarray) -> np.ndarray:
    """The seam cells a frame's region may hold: ``covered``, and for a frame with holes (a true ortho) the convex
    hull of its valid cells: what it does not see may also reach the edge of its ortho (a street hidden from it down
    to its edge), which is no hole and would cut its region in two (a frame's footprint on the ground is convex up to
    the relief displacement of its edge). A frame without holes (a conventional ortho): its valid cells as they are."""
    import cv2

    filled = covered(valid)
    if not (filled != valid).any():
        return filled
    contours, _ = cv2.findContours(valid.view(np.uint8).copy(), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    hull = np.zeros(valid.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.concatenate(contours)), 1)
    return filled | (hull > 0)


def neighbour_pairs(labels: np.ndarray) -> list[tuple[int, int]]:
    """Pairs (i < j) of labels that touch (4-neighbourhood)."""
    keys = []
    n = int(labels.max()) + 1 if labels.size else 0
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        m = (a != b) & (a >= 0) & (b >= 0)
        lo, hi = np.minimum(a[m], b[m]).astype(np.int64), np.maximum(a[m], b[m]).astype(np.int64)
        keys.append(np.unique(lo * n + hi))
    keys = np.unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)
    return [(int(k // n), int(k % n)) for k in keys]


# the 8 neighbours of a cell in row-major order (so that each row of the graph lists its columns in order)
_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def _grid_graph(cost: np.ndarray, nodes: np.ndarray):
    """Sparse 8-connected graph over cells where ``nodes``; edge weight = mean cost x step length. Returns
    the graph (CSR, built row by row without sorting) and the node index of every cell (-1: not a node)."""
    from scipy.sparse import csr_matrix

    h, w = cost.shape
    idx = np.full((h + 2, w + 2), -1, np.int32)  # a frame of non-nodes: every cell has 8 neighbour slots
    n = int(np.count_nonzero(nodes))
    core = idx[1:-1, 1:-1]
    core[nodes] = np.arange(n, dtype=np.int32)
    cpad = np.zeros((h + 2, w + 2), np.float64)
    cpad[1:-1, 1:-1] = cost
    W = w + 2
    flat_idx, flat_cost = idx.ravel(), cpad.ravel()
    here = np.flatnonzero(np.pad(nodes, 1))  # the nodes' positions in the framed grid, in node order
    # one contiguous row per neighbour slot (writing the columns of an (n, 8) array took twice as long), read
    # node by node through the transpose: the same arrays as before
    nbr = np.empty((8, n), np.int32)
    wts = np.empty((8, n), np.float64)
    c_here = flat_cost[here]
    there = np.empty(n, here.dtype)
    for k, (dr, dc) in enumerate(_NEIGHBOURS):
        np.add(here, dr * W + dc, out=there)
        np.take(flat_idx, there, out=nbr[k])
        np.take(flat_cost, there, out=wts[k])
        wts[k] += c_here
        wts[k] *= 0.5 * (2 ** 0.5 if dr and dc else 1.0)
    nbr, wts = nbr.T, wts.T
    ok = nbr >= 0
    # int32 row pointers where they fit, as scipy stores them (given int64 it scans them and casts a copy)
    indptr = np.zeros(n + 1, np.int32 if 8 * n < 2 ** 31 else np.int64)
    np.cumsum(np.count_nonzero(ok, axis=1), out=indptr[1:])
    g = csr_matrix((wts[ok], nbr[ok], indptr), shape=(n, n))
    g.has_sorted_indices = True
    return g, core


_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
_SQUARE = np.ones((3, 3), np.uint8)


def _dilate(mask: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Binary dilation (cells beyond the array count as unset)."""
    import cv2

    return cv2.dilate(mask.view(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)


def _erode(mask: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Binary erosion (cells beyond the array count as unset)."""
    import cv2

    return cv2.erode(mask.view(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)


def _seam_ends(boundary: np.ndarray):
    """The two cells of a seam farthest apart along its principal direction."""
    rc = np.argwhere(boundary).astype(float)
    if len(rc) < 2:
        return None
    centred = rc - rc.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    s = centred @ vt[0]
    return tuple(rc[np.argmin(s)].astype(int)), tuple(rc[np.argmax(s)].astype(int))


def _near(mask, rc, radius, at_least_one: bool = True):
    """Flat indices of the cells of ``mask`` within ``radius`` cells of ``rc`` (optionally the nearest one at least)."""
    cells = np.argwhere(mask)
    if len(cells) == 0:
        return np.zeros(0, np.int64)
    d = np.hypot(cells[:, 0] - rc[0], cells[:, 1] - rc[1])
    sel = cells[d <= radius] if np.any(d <= radius) or not at_least_one else cells[[int(np.argmin(d))]]
    return (sel[:, 0] * mask.shape[1] + sel[:, 1]).astype(np.int64)


def import_path_search() -> None:
    """Import what the least-cost seams import (``scipy.sparse``, ``scipy.sparse.csgraph``: 0.2 CPU-s), e.g. on a
    thread while the frames are read."""
    import scipy.sparse  # noqa: F401
    import scipy.sparse.csgraph  # noqa: F401


def least_cost_seams(labels: np.ndarray, valid: list, offsets: list, *, gray: list | None = None,
                     object_mask: np.ndarray | None = None, object_cost: float = 50.0,
                     difference_cost: float = 5.0, min_overlap_cells: int = 16, end_reach: float = 0.1,
                     end_reach_cells: float = 0.0, passes: int = 2, seen: list | None = None) -> np.ndarray:
    """Re-route every Voronoi seam along a least-cost path through the pair's overlap (module doc).

    ``gray``: per frame, its grey values on the seam grid (an array, or a function of the frame index
    returning one, so that the caller need not hold all of them). ``seen``: per frame, the cells it sees when
    ``valid`` are the cells it covers (``covered``: a true ortho's occlusion holes filled); a cell one of the two
    frames does not see has the highest grey-value difference cost (its difference is unknown), still far below a
    building's."""
    obj = None
    if object_mask is not None:
        core = np.ascontiguousarray(object_mask, bool)
        # 2 on the object's cells, 1 on the cell round them (the margin, which costs object_cost), 0 elsewhere
        obj = _dilate(core, _SQUARE).view(np.uint8) + core.view(np.uint8)
    done = set()
    labels = labels.copy()
    # the cells no frame covers, framed by more of them: a re-routing only moves cells between the pair's two frames,
    # so these stay the same for every seam (made once, not once a seam)
    outside = np.pad(labels < 0, 1, constant_values=True)
    for _ in range(passes):
        todo = [p for p in neighbour_pairs(labels) if p not in done]
        for i, j in todo:
            done.add((i, j))
            _reroute_pair(labels, i, j, valid=valid, offsets=offsets, gray=gray, obj=obj, object_cost=object_cost,
                          difference_cost=difference_cost, min_overlap_cells=min_overlap_cells, end_reach=end_reach,
                          end_reach_cells=end_reach_cells, seen=seen, outside=outside)
    return labels


def _reroute_pair(labels, i, j, *, valid, offsets, gray, obj, object_cost, difference_cost, min_overlap_cells,
                  end_reach, end_reach_cells, seen=None, outside=None) -> None:
    """One seam (frames i, j) along its least-cost path; updates ``labels`` in place. ``outside``: the cells of no
    frame (``labels < 0``) padded by one cell of them, if already made."""
    import cv2

    # window covering both frames
    (ri, ci), (rj, cj) = offsets[i], offsets[j]
    r0, c0 = max(ri, rj), max(ci, cj)
    r1 = min(ri + valid[i].shape[0], rj + valid[j].shape[0], labels.shape[0])
    c1 = min(ci + valid[i].shape[1], cj + valid[j].shape[1], labels.shape[1])
    if r1 - r0 < 3 or c1 - c0 < 3:
        return
    lab = labels[r0:r1, c0:c1]
    is_i, is_j = lab == i, lab == j
    corridor = valid[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci] & valid[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj] & (is_i | is_j)
    if np.count_nonzero(corridor) < min_overlap_cells:
        return
    # the current seam inside the corridor: i cells with a j neighbour
    seam = is_i & corridor & _dilate(is_j & corridor, _CROSS)
    ends = _seam_ends(seam)
    if ends is None:
        return
    cost = np.ones(corridor.shape, np.float64)
    if gray is not None:
        gi_all = gray(i) if callable(gray) else gray[i]
        gj_all = gray(j) if callable(gray) else gray[j]
        diff = np.abs(gi_all[r0 - ri:r1 - ri, c0 - ci:c1 - ci].astype(np.float32)
                      - gj_all[r0 - rj:r1 - rj, c0 - cj:c1 - cj].astype(np.float32))
        both = corridor
        if seen is not None:
            both = corridor & seen[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci] & seen[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj]
        scale = np.percentile(diff[both if both.any() else corridor], 90) + 1e-6
        d = np.clip(diff / scale, 0, 3)
        d[corridor & ~both] = 3.0  # a frame does not see the cell: its difference is unknown
        cost += difference_cost * d
    if obj is not None:
        o = obj[r0:r1, c0:c1]
        # an object's own cell costs more than the most a route over open ground through the corridor can (each
        # of its cells at most 1 + 3 x difference_cost + object_cost on a margin, over at most a step of sqrt(2);
        # a path's end cell counts half an edge), so the path has the fewest object cells there are; the margin
        # and the grey values decide among those paths
        through = 3.0 * (1.0 + 3.0 * difference_cost + object_cost) * np.count_nonzero(corridor) + 1.0
        cost += np.where(o == 2, through, object_cost * (o == 1))
    # the seam may leave the overlap anywhere on the overlap's border near its Voronoi ends, so that an end
    # does not pin it onto a building: within end_reach x seam length, and within end_reach_cells where
    # the border is the edge of the block (no frame beyond it, so no other seam is disturbed)
    border = corridor & ~_erode(corridor, _SQUARE)
    if outside is None:
        outside = np.pad(labels < 0, 1, constant_values=True)
    block_edge = border & _dilate(np.ascontiguousarray(outside[r0:r1 + 2, c0:c1 + 2]), _SQUARE)[1:-1, 1:-1]
    reach = max(3.0, end_reach * float(np.hypot(ends[0][0] - ends[1][0], ends[0][1] - ends[1][1])))
    starts = np.union1d(_near(border, ends[0], reach), _near(block_edge, ends[0], end_reach_cells, False))
    goals = np.union1d(_near(border, ends[1], reach), _near(block_edge, ends[1], end_reach_cells, False))
    if len(starts) == 0 or len(goals) == 0:
        return
    from scipy.sparse.csgraph import dijkstra

    graph, idx = _grid_graph(cost, corridor)
    starts, goals = idx.flat[starts], idx.flat[goals]
    dist, pred, _ = dijkstra(graph, indices=starts, return_predecessors=True, min_only=True)
    b = int(goals[np.argmin(dist[goals])])
    if not np.isfinite(dist[b]):
        return
    path_nodes = [b]
    while pred[path_nodes[-1]] >= 0:
        path_nodes.append(int(pred[path_nodes[-1]]))
    path = np.zeros(corridor.shape, bool)
    # node k is the k-th corridor cell in row-major order (``_grid_graph``)
    path.flat[np.flatnonzero(corridor)[path_nodes]] = True
    # sides of the path: 4-connected parts of the corridor (an 8-connected path separates them)
    n_parts, parts = cv2.connectedComponents((corridor & ~path).view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
    # which parts touch the exclusive areas (cells of i, or j, outside the corridor)
    inside = parts > 0
    touch_i = np.zeros(n_parts, bool)
    touch_j = np.zeros(n_parts, bool)
    touch_i[parts[_dilate(is_i & ~corridor, _CROSS) & inside]] = True
    touch_j[parts[_dilate(is_j & ~corridor, _CROSS) & inside]] = True
    ids = np.arange(1, n_parts)
    pure_i = bool(np.any(touch_i[1:] & ~touch_j[1:]))
    pure_j = bool(np.any(touch_j[1:] & ~touch_i[1:]))
    # side of each part by the majority of its Voronoi labels, for parts the path does not cut off cleanly
    count_i = np.bincount(parts[is_i], minlength=n_parts)
    count_j = np.bincount(parts[is_j], minlength=n_parts)
    major = np.where(count_i >= count_j, i, j)
    majors_differ = len(set(major[1:].tolist())) == 2
    side = np.full(n_parts, -2, np.int64)  # -2: unchanged
    for p in ids:
        ti, tj = touch_i[p], touch_j[p]
        if ti and not tj:
            side[p] = i
        elif tj and not ti:
            side[p] = j
        # the path does not fully separate this part from one side (it leaks around a seam end):
        # it is the opposite side of the pure part(s); otherwise the side where most of it lay
        elif pure_i and not pure_j:
            side[p] = j
        elif pure_j and not pure_i:
            side[p] = i
        elif majors_differ:
            side[p] = major[p]
    to = side[parts]
    change = inside & (to >= -1)
    new = lab.copy()
    new[change] = to[change]
    # path cells join the side of their original label's neighbourhood: give them to i or j by majority nearby
    near_i = cv2.blur((new == i).astype(np.float32), (3, 3))
    near_j = cv2.blur((new == j).astype(np.float32), (3, 3))
    new[path] = np.where(near_i[path] >= near_j[path], i, j)
    lab[...] = new


def keep_objects_whole(labels: np.ndarray, object_mask: np.ndarray, valid: list, offsets: list,
                       max_cells: int = 20000) -> np.ndarray:
    """Give every object (building, tree: connected cells of ``object_mask``) still split between frames
    to one of those frames that sees all of it (the one holding most of it); all of it is its cells in the
    mosaic (label >= 0), so an object the block's edge cuts goes whole to a frame as well.

    The seams then run round the object a cell away from its outline; an object that no frame covers with that
    margin goes whole to a frame that covers the object itself (the seam along its wall: a building in the corner of
    an overlap, against one frame's edge); objects no single frame covers stay split.
    """
    import cv2

    labels = labels.copy()
    n, parts, stats, _ = cv2.connectedComponentsWithStats(np.ascontiguousarray(object_mask, bool).view(np.uint8),
                                                          connectivity=4, ltype=cv2.CV_32S)
    for k in range(1, n):
        x, y, w, h = (int(v) for v in stats[k, :4])
        # one cell of margin so the seam does not run along the wall
        r0, r1 = max(y - 1, 0), min(y + h + 1, labels.shape[0])
        c0, c1 = max(x - 1, 0), min(x + w + 1, labels.shape[1])
        lab = labels[r0:r1, c0:c1]
        # its cells no frame covers are not in the mosaic (the block's edge): a frame that covers the rest covers
        # all of it there is, else a building the block's edge cut kept the seam along a frame's edge across it
        own = parts[r0:r1, c0:c1] == k
        obj = _dilate(own, _SQUARE) & (lab >= 0)
        if np.count_nonzero(obj) > max_cells:
            continue
        present, counts = np.unique(lab[obj], return_counts=True)
        keep = present >= 0
        present, counts = present[keep], counts[keep]
        if len(present) < 2:
            continue
        order = present[np.argsort(-counts, kind="stable")]
        f = _frame_covering(obj, order, valid, offsets, r0, c0)
        if f is not None:
            lab[obj] = f
            continue
        cells = own & (lab >= 0)
        if len(np.unique(lab[cells])) < 2:  # the object itself is whole already; only its margin is shared
            continue
        f = _frame_covering(cells, order, valid, offsets, r0, c0)
        if f is not None:
            lab[cells] = f
    return labels


def _frame_covering(cells: np.ndarray, frames, valid: list, offsets: list, r0: int, c0: int) -> int | None:
    """The first of ``frames`` whose valid cells hold every cell of ``cells`` (a window of the seam grid at row
    ``r0``, column ``c0``), None if none does."""
    rr0, cc0 = np.nonzero(cells)
    for f in frames:
        (fr, fc), v = offsets[f], valid[f]
        rr, cc = rr0 + r0 - fr, cc0 + c0 - fc
        inside = (rr >= 0) & (rr < v.shape[0]) & (cc >= 0) & (cc < v.shape[1])
        if inside.all() and v[rr, cc].all():
            return int(f)
    return None


@dataclasses.dataclass(frozen=True)
class FrameRegions:
    """The cells of each label of a label raster as one shapely (Multi)Polygon, labels ascending (a label without
    cells has none)."""

    labels: tuple[int, ...]
    polygons: tuple

    def __contains__(self, label) -> bool:
        return label in self.labels

    def polygon(self, label: int):
        return self.polygons[self.labels.index(label)]


def frame_regions(labels: np.ndarray, transform) -> FrameRegions:
    """Each label's cells as one shapely (Multi)Polygon (the union of the label raster's 4-connected parts;
    ``transform`` is the seam grid's affine): what ``label_polygons`` and ``seam_lines`` are made of, computed once
    for both by a caller that writes the two."""
    from rasterio import features
    from shapely.geometry import shape
    from shapely.ops import unary_union

    polys: dict[int, list] = {}
    for geom, value in features.shapes(labels, mask=labels >= 0, transform=transform, connectivity=4):
        polys.setdefault(int(value), []).append(shape(geom))
    keys = sorted(polys)
    return FrameRegions(tuple(keys), tuple(unary_union(polys[k]) for k in keys))


def label_polygons(labels: np.ndarray, transform, names: list[str],
                   regions: FrameRegions | None = None) -> list[dict]:
    """GeoJSON features (one MultiPolygon per frame) of the label raster; ``transform`` is the seam grid's affine;
    ``regions``: ``frame_regions`` of the same labels, if already made."""
    from shapely.geometry import mapping

    regions = frame_regions(labels, transform) if regions is None else regions
    out = []
    for k, g in zip(regions.labels, regions.polygons):
        out.append({"type": "Feature", "properties": {"image_id": names[k], "area_m2": float(g.area)},
                    "geometry": mapping(g)})
    return out


def seam_lines(labels: np.ndarray, transform, names: list[str], regions: FrameRegions | None = None) -> list[dict]:
    """GeoJSON LineString features of the seams between neighbouring frames (shared polygon edges); ``regions``:
    ``frame_regions`` of the same labels, if already made."""
    from shapely.geometry import MultiLineString, mapping
    from shapely.ops import linemerge

    polys = frame_regions(labels, transform) if regions is None else regions
    boundary: dict[int, object] = {}  # a frame's outline, made once for all its seams
    out = []
    for i, j in neighbour_pairs(labels):
        if i not in polys or j not in polys:
            continue
        for k in (i, j):
            if k not in boundary:
                boundary[k] = polys.polygon(k).boundary
        shared = boundary[i].intersection(boundary[j])
        # keep the line parts (boundaries can also touch in single points)
        parts = [g for g in getattr(shared, "geoms", [shared]) if g.geom_type in ("LineString", "MultiLineString")]
        segs = [ls for g in parts for ls in getattr(g, "geoms", [g]) if ls.length > 0]
        if not segs:
            continue
        line = linemerge(MultiLineString(segs))
        out.append({"type": "Feature", "properties": {"image_a": names[i], "image_b": names[j],
                                                      "length_m": float(line.length)}, "geometry": mapping(line)})
    return out
