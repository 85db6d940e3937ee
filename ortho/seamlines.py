"""Seamlines: which frame supplies each mosaic cell.

Computed on a coarse "seam grid" (an integer multiple of the mosaic pixel) so that blocks of thousands
of frames stay in memory:

1. Voronoi partition by nadir distance: each cell goes to the valid frame whose nadir point (the
   projection centre's ground position) is nearest - the least relief displacement.
2. Least-cost seams: for each pair of neighbouring frames, the seam is re-routed along the cheapest
   8-connected path (Dijkstra, ``scipy.sparse.csgraph``) through their common overlap between the ends
   of the Voronoi seam. Cost per cell = 1 + ``object_cost`` where the nDSM shows buildings or trees
   (height above ground > ``object_height_m``, dilated by one cell) + ``difference_cost`` x the
   normalised grey-value difference of the two frames. The cells of the overlap on either side of the
   new path go to the frame whose exclusive area they touch.
3. Objects still split (where seams meet, at seam ends) go whole to a frame that sees all of them.

Labels are frame indices (int32), -1 where no frame is valid.
"""

from __future__ import annotations

import numpy as np

# scipy (ndimage, sparse, csgraph: about 0.3 s to import) is imported by the functions that need it: this
# module comes with ortho.settings into every ``ortho`` command, also ``ortho rectify``, which has no seams.


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


def neighbour_pairs(labels: np.ndarray) -> list[tuple[int, int]]:
    """Pairs (i < j) of labels that touch (4-neighbourhood)."""
    pairs = set()
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        m = (a != b) & (a >= 0) & (b >= 0)
        for i, j in zip(a[m].ravel(), b[m].ravel()):
            pairs.add((int(min(i, j)), int(max(i, j))))
    return sorted(pairs)


def _grid_graph(cost: np.ndarray, nodes: np.ndarray):
    """Sparse 8-connected graph over cells where ``nodes``; edge weight = mean cost x step length."""
    from scipy.sparse import coo_matrix

    h, w = cost.shape
    idx = np.full((h, w), -1, np.int64)
    idx[nodes] = np.arange(int(nodes.sum()))
    rows, cols, wts = [], [], []
    for dr, dc, length in ((0, 1, 1.0), (1, 0, 1.0), (1, 1, 2 ** 0.5), (1, -1, 2 ** 0.5)):
        # cell (r, c) and its neighbour (r + dr, c + dc)
        sa = (slice(0, h - dr), slice(max(0, -dc), w - max(0, dc)))
        sb = (slice(dr, h), slice(max(0, dc), w - max(0, -dc)))
        a, b, ca, cb = idx[sa], idx[sb], cost[sa], cost[sb]
        m = (a >= 0) & (b >= 0)
        rows.append(a[m])
        cols.append(b[m])
        wts.append(0.5 * (ca[m] + cb[m]) * length)
    n = int(nodes.sum())
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    wv = np.concatenate(wts)
    g = coo_matrix((np.concatenate([wv, wv]), (np.concatenate([r, c]), np.concatenate([c, r]))), shape=(n, n)).tocsr()
    return g, idx


def _seam_ends(boundary: np.ndarray):
    """The two cells of a seam farthest apart along its principal direction."""
    rc = np.argwhere(boundary).astype(float)
    if len(rc) < 2:
        return None
    centred = rc - rc.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    s = centred @ vt[0]
    return tuple(rc[np.argmin(s)].astype(int)), tuple(rc[np.argmax(s)].astype(int))


def _near(mask, rc, radius, idx, at_least_one: bool = True):
    """Graph nodes of the cells of ``mask`` within ``radius`` cells of ``rc`` (optionally the nearest one at least)."""
    cells = np.argwhere(mask)
    if len(cells) == 0:
        return np.zeros(0, np.int64)
    d = np.hypot(cells[:, 0] - rc[0], cells[:, 1] - rc[1])
    sel = cells[d <= radius] if np.any(d <= radius) or not at_least_one else cells[[int(np.argmin(d))]]
    return idx[sel[:, 0], sel[:, 1]] if len(sel) else np.zeros(0, np.int64)


def least_cost_seams(labels: np.ndarray, valid: list, offsets: list, gray: list | None = None,
                     object_mask: np.ndarray | None = None, object_cost: float = 50.0,
                     difference_cost: float = 5.0, min_overlap_cells: int = 16, end_reach: float = 0.1,
                     end_reach_cells: float = 0.0, passes: int = 2) -> np.ndarray:
    """Re-route every Voronoi seam along a least-cost path through the pair's overlap (module doc)."""
    from scipy import ndimage

    obj = None
    if object_mask is not None:
        obj = ndimage.binary_dilation(object_mask, structure=np.ones((3, 3), bool))
    done = set()
    for _ in range(passes):
        todo = [p for p in neighbour_pairs(labels) if p not in done]
        for i, j in todo:
            done.add((i, j))
            labels = _reroute_pair(labels, i, j, valid, offsets, gray, obj, object_cost, difference_cost,
                                   min_overlap_cells, end_reach, end_reach_cells)
    return labels


def _reroute_pair(labels, i, j, valid, offsets, gray, obj, object_cost, difference_cost, min_overlap_cells, end_reach,
                  end_reach_cells):
    """One seam (frames i, j) along its least-cost path; returns the updated labels."""
    from scipy import ndimage
    from scipy.sparse.csgraph import dijkstra

    # window covering both frames
    (ri, ci), (rj, cj) = offsets[i], offsets[j]
    r0, c0 = max(ri, rj), max(ci, cj)
    r1 = min(ri + valid[i].shape[0], rj + valid[j].shape[0])
    c1 = min(ci + valid[i].shape[1], cj + valid[j].shape[1])
    if r1 - r0 < 3 or c1 - c0 < 3:
        return labels
    vi = valid[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci]
    vj = valid[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj]
    lab = labels[r0:r1, c0:c1]
    corridor = vi & vj & ((lab == i) | (lab == j))
    if corridor.sum() < min_overlap_cells:
        return labels
    # the current seam inside the corridor: i cells with a j neighbour
    li = (lab == i) & corridor
    lj = (lab == j) & corridor
    seam = li & ndimage.binary_dilation(lj, structure=ndimage.generate_binary_structure(2, 1))
    ends = _seam_ends(seam)
    if ends is None:
        return labels
    cost = np.ones(corridor.shape, np.float64)
    if gray is not None:
        gi = gray[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci]
        gj = gray[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj]
        diff = np.abs(gi - gj)
        scale = np.percentile(diff[corridor], 90) + 1e-6
        cost += difference_cost * np.clip(diff / scale, 0, 3)
    if obj is not None:
        cost += object_cost * obj[r0:r1, c0:c1]
    graph, idx = _grid_graph(cost, corridor)
    # the seam may leave the overlap anywhere on the overlap's border near its Voronoi ends, so that an end
    # does not pin it onto a building: within end_reach x seam length, and within end_reach_cells where
    # the border is the edge of the block (no frame beyond it, so no other seam is disturbed)
    border = corridor & ~ndimage.binary_erosion(corridor, structure=np.ones((3, 3), bool), border_value=0)
    outside = np.pad(labels < 0, 1, constant_values=True)[r0:r1 + 2, c0:c1 + 2]
    block_edge = border & ndimage.binary_dilation(outside, structure=np.ones((3, 3), bool))[1:-1, 1:-1]
    reach = max(3.0, end_reach * float(np.hypot(ends[0][0] - ends[1][0], ends[0][1] - ends[1][1])))
    starts = np.union1d(_near(border, ends[0], reach, idx), _near(block_edge, ends[0], end_reach_cells, idx, False))
    goals = np.union1d(_near(border, ends[1], reach, idx), _near(block_edge, ends[1], end_reach_cells, idx, False))
    if len(starts) == 0 or len(goals) == 0:
        return labels
    dist, pred, src = dijkstra(graph, indices=starts, return_predecessors=True, min_only=True)
    b = int(goals[np.argmin(dist[goals])])
    if not np.isfinite(dist[b]):
        return labels
    path_nodes = [b]
    while pred[path_nodes[-1]] >= 0:
        path_nodes.append(int(pred[path_nodes[-1]]))
    node_rc = np.argwhere(corridor)
    path = np.zeros(corridor.shape, bool)
    pr = node_rc[path_nodes]
    path[pr[:, 0], pr[:, 1]] = True
    # sides of the path: 4-connected parts of the corridor (an 8-connected path separates them)
    parts, n_parts = ndimage.label(corridor & ~path)
    # exclusive areas: cells of i (or j) outside the corridor
    excl_i = (lab == i) & ~corridor
    excl_j = (lab == j) & ~corridor
    grow = ndimage.generate_binary_structure(2, 1)
    new = lab.copy()
    side = {}
    for p in range(1, n_parts + 1):
        part = parts == p
        ring = ndimage.binary_dilation(part, structure=grow) & ~part
        side[p] = (bool((ring & excl_i).any()), bool((ring & excl_j).any()))
    pure_i = [p for p, t in side.items() if t == (True, False)]
    pure_j = [p for p, t in side.items() if t == (False, True)]
    # side of each part by the majority of its Voronoi labels, for parts the path does not cut off cleanly
    major = {p: (i if (lab[parts == p] == i).sum() >= (lab[parts == p] == j).sum() else j) for p in side}
    majors_differ = len(set(major.values())) == 2
    for p, (touch_i, touch_j) in side.items():
        if touch_i and not touch_j:
            new[parts == p] = i
        elif touch_j and not touch_i:
            new[parts == p] = j
        # the path does not fully separate this part from one side (it leaks around a seam end):
        # it is the opposite side of the pure part(s); otherwise the side where most of it lay
        elif pure_i and not pure_j:
            new[parts == p] = j
        elif pure_j and not pure_i:
            new[parts == p] = i
        elif majors_differ:
            new[parts == p] = major[p]
    # path cells join the side of their original label's neighbourhood: give them to i or j by majority nearby
    near_i = ndimage.uniform_filter((new == i).astype(float), 3)
    near_j = ndimage.uniform_filter((new == j).astype(float), 3)
    new[path] = np.where(near_i[path] >= near_j[path], i, j)
    labels = labels.copy()
    labels[r0:r1, c0:c1] = new
    return labels


def keep_objects_whole(labels: np.ndarray, object_mask: np.ndarray, valid: list, offsets: list,
                       max_cells: int = 20000) -> np.ndarray:
    """Give every object (building, tree: connected cells of ``object_mask``) still split between frames
    to one of those frames that sees all of it (the one holding most of it).

    The seams then run round the object along its outline; objects no single frame covers stay split.
    """
    from scipy import ndimage

    labels = labels.copy()
    parts, n = ndimage.label(object_mask)
    if n == 0:
        return labels
    boxes = ndimage.find_objects(parts)
    for k, sl in enumerate(boxes, start=1):
        if sl is None:
            continue
        # one cell of margin so the seam does not run along the wall
        r0, r1 = max(sl[0].start - 1, 0), min(sl[0].stop + 1, labels.shape[0])
        c0, c1 = max(sl[1].start - 1, 0), min(sl[1].stop + 1, labels.shape[1])
        obj = ndimage.binary_dilation(parts[r0:r1, c0:c1] == k, structure=np.ones((3, 3), bool))
        if obj.sum() > max_cells:
            continue
        lab = labels[r0:r1, c0:c1]
        present, counts = np.unique(lab[obj], return_counts=True)
        keep = present >= 0
        present, counts = present[keep], counts[keep]
        if len(present) < 2:
            continue
        for f in present[np.argsort(-counts)]:
            (fr, fc), v = offsets[f], valid[f]
            rr, cc = np.nonzero(obj)
            rr, cc = rr + r0 - fr, cc + c0 - fc
            inside = (rr >= 0) & (rr < v.shape[0]) & (cc >= 0) & (cc < v.shape[1])
            if inside.all() and v[rr, cc].all():
                lab[obj] = f
                break
    return labels


def label_polygons(labels: np.ndarray, transform, names: list[str]) -> list[dict]:
    """GeoJSON features (one MultiPolygon per frame) of the label raster; ``transform`` is the seam grid's affine."""
    from rasterio import features
    from shapely.geometry import mapping, shape
    from shapely.ops import unary_union

    polys: dict[int, list] = {}
    for geom, value in features.shapes(labels, mask=labels >= 0, transform=transform, connectivity=4):
        polys.setdefault(int(value), []).append(shape(geom))
    out = []
    for k in sorted(polys):
        g = unary_union(polys[k])
        out.append({"type": "Feature", "properties": {"image_id": names[k], "area_m2": float(g.area)},
                    "geometry": mapping(g)})
    return out


def seam_lines(labels: np.ndarray, transform, names: list[str]) -> list[dict]:
    """GeoJSON LineString features of the seams between neighbouring frames (shared polygon edges)."""
    from rasterio import features
    from shapely.geometry import MultiLineString, mapping, shape
    from shapely.ops import linemerge, unary_union

    polys: dict[int, object] = {}
    for geom, value in features.shapes(labels, mask=labels >= 0, transform=transform, connectivity=4):
        polys.setdefault(int(value), []).append(shape(geom))
    polys = {k: unary_union(v) for k, v in polys.items()}
    out = []
    for i, j in neighbour_pairs(labels):
        if i not in polys or j not in polys:
            continue
        shared = polys[i].boundary.intersection(polys[j].boundary)
        # keep the line parts (boundaries can also touch in single points)
        parts = [g for g in getattr(shared, "geoms", [shared]) if g.geom_type in ("LineString", "MultiLineString")]
        segs = [ls for g in parts for ls in getattr(g, "geoms", [g]) if ls.length > 0]
        if not segs:
            continue
        line = linemerge(MultiLineString(segs))
        out.append({"type": "Feature", "properties": {"image_a": names[i], "image_b": names[j],
                                                      "length_m": float(line.length)}, "geometry": mapping(line)})
    return out
