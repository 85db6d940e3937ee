"""The LiDAR's shadow behind walls in the occlusion DSM: the cells the scanner could not see, lowered to the DEM
(issue 42, i42-shadow2: a trial's rule, not in the product; used by ``true_ortho_shadow_trial.py`` and
``eval_shadow_ahn3.py``, docs/true-ortho.md "A shadow rule that lowers only shadow").

The scanner does not see the ground behind a wall (on the wall's side away from it); the nearest-return DSM
(``nearest``) stands those cells at the roof's height up to half way to the first ground return, and a camera's
line of sight that clears the real wall is stopped there (docs/true-ortho.md, "Lines of sight that clear the
surface"). A cell is *shadow* here when all of:

* it is **empty**: no first return within ``EMPTY_RADIUS_SPACINGS`` local point spacings of its centre (the
  spacing of the returns around it, ``local_spacing_m``: the median over a ``SPACING_BLOCK_M`` block of each
  return's k-nearest-neighbour spacing; not the block's bounding box, which is off for scattered patches);
* its empty region (8-connected) **touches seen ground**: one of its cells lies within the radius and a cell of a
  cell holding a first return within ``GROUND_TOL_M`` of the DEM (a roof's dropout, enclosed by roof returns,
  touches none);
* the line from its ground (the DEM) **towards the scanner is blocked** by a return's cell standing more than
  ``BLOCK_TOL_M`` above the line within ``MAX_REACH_M`` (the occluder lies between the cell and the scanner), the
  first return away from the scanner is seen ground, and the empty run between them is no longer than the
  occluder's shadow and two radii, for the scanner of one of the cell's ``SCAN_NEIGHBOURS`` nearest returns (its
  strip's flight line from the strip's near-nadir returns against GPS time, its zenith angle from the return's scan
  angle);
* it is **not in a crown disk** (``keep``: the crowns' own cells stay as the crown model made them).

Those cells take the DEM's height where it is lower. Grids north-up, row 0 at ``y_top_m``; lengths in metres.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

# Chosen on the simulator's demo seed 7 (bench/true_ortho_shadow_trial.py, true_ortho_fill.json shadow2_choice):
# 0.93 and 0.8 filled 119,771 and 119,783 pixels (1.14 fewer cells), 0.8 lowered 162 roof cells by > 2 m against
# 91. In local point spacings (the k-nearest-neighbour spacing is 0.75 m on the demo where the bounding box gives
# 0.61 m), so in the cloud's own density.
EMPTY_RADIUS_SPACINGS = 0.93
# A first return this close to the DEM is seen ground (the brief's 0.3 m: the DEM's own noise on open ground).
GROUND_TOL_M = 0.3
# The occluder stands at least this far above the line from the ground to the scanner (the march's 0.3 m).
BLOCK_TOL_M = 0.3
# How far towards the scanner the occluder is looked for: a 60 m wall at 25 degrees off nadir casts 28 m.
MAX_REACH_M = 30.0
# The block over which the returns' spacings are pooled (a median: roof edges' wider spacing does not move it).
SPACING_BLOCK_M = 10.0
# Neighbours for each return's spacing: d_k * sqrt(pi / (k - 1)) is the side of the area per return.
SPACING_NEIGHBOURS = 6
# The scanners looked at for a cell: those of its nearest returns (overlapping strips see a wall from both sides).
SCAN_NEIGHBOURS = 4
# A strip's flight line needs this many near-nadir returns (|scan angle| <= NADIR_DEG) to be fitted.
NADIR_DEG = 1.0
MIN_NADIR_RETURNS = 20


@dataclasses.dataclass(frozen=True)
class ScanGeometry:
    """Per first return: the horizontal unit vector towards the scanner (east, north; NaN where unknown) and the
    tangent of the scan's zenith angle (the return's scan angle)."""

    toward_e: np.ndarray
    toward_n: np.ndarray
    tan_zenith: np.ndarray


@dataclasses.dataclass(frozen=True)
class ShadowCells:
    """The cells lowered (``lower``) and what decided them, on the DSM's grid."""

    lower: np.ndarray
    empty: np.ndarray
    touches_ground: np.ndarray
    blocked: np.ndarray
    spacing_m: np.ndarray
    strips_without_line: tuple


def scan_geometry(x_m, y_m, gps_time_s, strip_id, scan_angle_deg) -> tuple[ScanGeometry, tuple]:
    """The scanner's direction from each return (``ScanGeometry``) and the strips without a flight line: per strip (``strip_id``, the LAS point source),
    the flight line is the straight line through its near-nadir returns' positions against GPS time (a least
    squares fit); the scanner is over it at the return's time. Strips with fewer than ``MIN_NADIR_RETURNS``
    near-nadir returns, or a time span of zero, get NaN (their returns never make a shadow)."""
    x, y, t = (np.asarray(a, float) for a in (x_m, y_m, gps_time_s))
    sid, ang = np.asarray(strip_id), np.asarray(scan_angle_deg, float)
    te, tn = np.full(len(x), np.nan), np.full(len(x), np.nan)
    missing = []
    for s in np.unique(sid):
        m = sid == s
        nad = m & (np.abs(ang) <= NADIR_DEG)
        if nad.sum() < MIN_NADIR_RETURNS or np.ptp(t[nad]) <= 0:
            missing.append(int(s))
            continue
        tt = t[nad] - t[nad].mean()
        A = np.column_stack([np.ones_like(tt), tt])
        (ax, bx), (ay, by) = (np.linalg.lstsq(A, v, rcond=None)[0] for v in (x[nad], y[nad]))
        ts = t[m] - t[nad].mean()
        dx, dy = ax + bx * ts - x[m], ay + by * ts - y[m]
        h = np.hypot(dx, dy)
        with np.errstate(invalid="ignore", divide="ignore"):
            te[m], tn[m] = np.where(h > 0, dx / h, np.nan), np.where(h > 0, dy / h, np.nan)
    return ScanGeometry(te, tn, np.tan(np.radians(np.abs(ang)))), tuple(missing)


def local_spacing_m(x_m, y_m, grid_shape, x0_m, y_top_m, res_m) -> np.ndarray:
    """The first returns' point spacing (m) around each cell: each return's spacing from its
    ``SPACING_NEIGHBOURS``-th neighbour, the median of those in the cell's ``SPACING_BLOCK_M`` block (NaN where a
    block has none)."""
    xy = np.column_stack([x_m, y_m])
    d = cKDTree(xy).query(xy, k=SPACING_NEIGHBOURS + 1)[0][:, -1]   # the first neighbour is the return itself
    s = d * np.sqrt(np.pi / (SPACING_NEIGHBOURS - 1))
    blk = max(1, int(round(SPACING_BLOCK_M / res_m)))
    H, W = grid_shape
    bh, bw = -(-H // blk), -(-W // blk)
    bi = np.clip(((y_top_m - np.asarray(y_m)) / res_m).astype(np.int64) // blk, 0, bh - 1)
    bj = np.clip(((np.asarray(x_m) - x0_m) / res_m).astype(np.int64) // blk, 0, bw - 1)
    key = bi * bw + bj
    order = np.lexsort((s, key))
    ks, ss = key[order], s[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    ends = np.r_[starts[1:], len(ks)]
    med = np.full(bh * bw, np.nan)
    mid = (starts + ends - 1) / 2.0
    med[ks[starts]] = 0.5 * (ss[np.floor(mid).astype(np.int64)] + ss[np.ceil(mid).astype(np.int64)])
    return np.repeat(np.repeat(med.reshape(bh, bw), blk, 0), blk, 1)[:H, :W]


def shadow_cells(surface_m: np.ndarray, dem_m: np.ndarray, *, x0_m: float, y_top_m: float, res_m: float,
                 x_m, y_m, z_m, scan: ScanGeometry, keep: np.ndarray | None = None,
                 radius_spacings: float = EMPTY_RADIUS_SPACINGS, strips_without_line: tuple = ()) -> ShadowCells:
    """The occlusion DSM's shadow cells (module doc) from the first returns (``x_m``, ``y_m``, ``z_m``, noise out)
    and their ``scan``; ``surface_m``, ``dem_m``: the DSM and DEM on one grid (NaN nodata); ``keep``: cells never
    lowered (the crown disks)."""
    H, W = surface_m.shape
    x, y, z = (np.asarray(a, float) for a in (x_m, y_m, z_m))
    r = np.floor((y_top_m - y) / res_m).astype(np.int64)
    c = np.floor((x - x0_m) / res_m).astype(np.int64)
    inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
    # the highest first return per cell (NaN: no return in it) and whether one is within GROUND_TOL_M of the DEM
    top = np.full(H * W, -np.inf)
    np.maximum.at(top, r[inside] * W + c[inside], z[inside])
    top = np.where(np.isfinite(top), top, np.nan).reshape(H, W)
    seen = np.zeros(H * W, bool)
    gi = inside.copy()
    gi[inside] = np.abs(z[inside] - dem_m[r[inside], c[inside]]) <= GROUND_TOL_M
    seen[r[gi] * W + c[gi]] = True
    seen = seen.reshape(H, W)

    spacing = local_spacing_m(x, y, (H, W), x0_m, y_top_m, res_m)
    rows, cols = np.mgrid[0:H, 0:W]
    cx, cy = x0_m + (cols + 0.5) * res_m, y_top_m - (rows + 0.5) * res_m
    # the empty regions take every cell (the shadow's ground side stands at the ground already), the lowering only
    # those above the DEM
    cand = np.isfinite(surface_m) & np.isfinite(dem_m) & np.isfinite(spacing)
    empty = np.zeros((H, W), bool)
    q = np.flatnonzero(cand.ravel())
    tree = cKDTree(np.column_stack([x, y])) if len(x) else None
    if len(q) and tree is not None:
        d, _ = tree.query(np.column_stack([cx.ravel()[q], cy.ravel()[q]]))
        empty.ravel()[q[d > radius_spacings * spacing.ravel()[q]]] = True
    lab, _ = ndimage.label(empty, np.ones((3, 3), bool))
    # touching: a cell of the region lies within its radius and a cell of seen ground (between an empty cell and
    # the ground's first return lie the cells that return is within the radius of)
    to_seen_m = ndimage.distance_transform_edt(~seen) * res_m
    reach_m = radius_spacings * np.where(np.isfinite(spacing), spacing, 0.0) + res_m
    touching = np.unique(lab[empty & (to_seen_m <= reach_m)])
    touches = np.isin(lab, touching[touching > 0]) & empty

    blocked = np.zeros((H, W), bool)
    q_all = np.flatnonzero(touches.ravel())
    if len(q_all):
        # the scanners of the cell's SCAN_NEIGHBOURS nearest returns (overlapping strips: the shadow of any)
        _, jj = tree.query(np.column_stack([cx.ravel()[q_all], cy.ravel()[q_all]]), k=min(SCAN_NEIGHBOURS, len(x)))
        jj = jj.reshape(len(q_all), -1)
        for j in jj.T:
            ue, un, tz = scan.toward_e[j], scan.toward_n[j], scan.tan_zenith[j]
            ok = np.isfinite(ue) & np.isfinite(un) & (tz > 1e-3)
            hit = _walk(q_all[ok], ue[ok], un[ok], tz[ok], cx, cy, dem_m, top, seen,
                        radius_spacings * spacing.ravel()[q_all[ok]], x0_m=x0_m, y_top_m=y_top_m, res_m=res_m)
            blocked.ravel()[q_all[ok][hit]] = True
    with np.errstate(invalid="ignore"):
        lower = touches & blocked & (dem_m < surface_m)
    if keep is not None:
        lower &= ~keep
    return ShadowCells(lower, empty, touches, blocked, spacing, tuple(strips_without_line))


def _walk(q, ue, un, tz, cx, cy, dem_m, top, seen, radius, *, x0_m, y_top_m, res_m) -> np.ndarray:
    """For the cells ``q`` (flat indices) and a scanner direction each (``ue``, ``un``, tangent of the zenith
    ``tz``): True where the cell is in that scanner's shadow (``shadow_cells``)."""
    H, W = top.shape
    px, py, pz = cx.ravel()[q], cy.ravel()[q], dem_m.ravel()[q]
    # the first cell with a return towards the scanner (the occluder: its top, its distance) and away from it
    # (seen ground or not, its distance)
    s_to, top_to = np.full(len(q), np.inf), np.full(len(q), np.nan)
    s_away, seen_away = np.full(len(q), np.inf), np.zeros(len(q), bool)
    step = res_m / 2
    for s in np.arange(step, MAX_REACH_M + step / 2, step):
        for sign in (1.0, -1.0):
            rr = np.floor((y_top_m - (py + sign * s * un)) / res_m).astype(np.int64)
            cc = np.floor((px + sign * s * ue - x0_m) / res_m).astype(np.int64)
            v = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
            h = np.full(len(q), np.nan)
            h[v] = top[rr[v], cc[v]]
            first = np.isfinite(h) & np.isinf(s_to if sign > 0 else s_away)
            if sign > 0:
                s_to[first], top_to[first] = s, h[first]
            else:
                s_away[first] = s
                seen_away[first] = seen[rr[first], cc[first]]
    with np.errstate(invalid="ignore"):
        # the occluder stands above the line from the cell's ground to the scanner, the first return beyond the
        # cell away from the scanner is ground, and the empty run between them is no longer than the occluder's
        # shadow (its height over the DEM times the zenith angle's tangent) and a gap each side
        return ((top_to > pz + s_to / tz + BLOCK_TOL_M) & seen_away
                & (s_to + s_away <= (top_to - pz) * tz + 2 * radius))


def lowered(surface_m: np.ndarray, dem_m: np.ndarray, cells: ShadowCells) -> np.ndarray:
    """A copy of the surface with the shadow cells at the DEM."""
    out = surface_m.copy()
    out[cells.lower] = dem_m[cells.lower]
    return out


def disk_cells(x_m, y_m, radius_m, shape, *, x0_m: float, y_top_m: float, res_m: float) -> np.ndarray:
    """True at the cells whose centre lies within a disk (centres ``x_m``, ``y_m``, radii ``radius_m``): the crown
    disks' cells, never lowered."""
    H, W = shape
    out = np.zeros(shape, bool)
    for x, y, rad in zip(np.asarray(x_m, float), np.asarray(y_m, float), np.asarray(radius_m, float)):
        c0, c1 = max(0, int((x - rad - x0_m) / res_m)), min(W, int((x + rad - x0_m) / res_m) + 1)
        r0, r1 = max(0, int((y_top_m - y - rad) / res_m)), min(H, int((y_top_m - y + rad) / res_m) + 1)
        if c0 >= c1 or r0 >= r1:
            continue
        cx = x0_m + (np.arange(c0, c1) + 0.5) * res_m - x
        cy = y_top_m - (np.arange(r0, r1) + 0.5) * res_m - y
        out[r0:r1, c0:c1] |= cy[:, None] ** 2 + cx[None, :] ** 2 <= rad * rad
    return out
