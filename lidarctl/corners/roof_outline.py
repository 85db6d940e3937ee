"""Roof outline: trace, regularise and fit the edges of one roof; corners with covariance.

Conventions
-----------
Coordinates in metres (projected CRS). A ring is a closed polygon without the repeated first vertex,
oriented so that the roof lies on the LEFT of each edge (outer ring counter-clockwise, courtyard rings
clockwise). An edge line is ``cos(phi) x + sin(phi) y = d`` with ``(cos phi, sin phi)`` the outward
normal (pointing away from the roof), so ``u = n.p - d`` is positive outside the roof.

Method
------
1. ``trace_rings``: rasterise the roof points (cell = spacing/2), close the gaps between points, trace the
   outer boundary and courtyards (OpenCV contours), simplify (Douglas-Peucker).
2. ``regularise_rings``: the dominant direction theta (length-weighted circular mean of edge directions
   modulo 90 deg); edges within ``snap_tol_deg`` of theta or theta + 90 deg become parallel/perpendicular,
   consecutive collinear edges merge, parallel neighbours at different offsets get a connecting step,
   short free edges are dropped.
3. ``edge_observations``: per bin of one spacing along the edge, the outermost roof point, moved
   outwards by the mean depth at which the outermost point of a bin lies inside an edge. That depth
   (about half the spacing across the edge) and its scatter are learnt from the roof itself by laying
   virtual edges across its interior (``outermost_depth``), so the correction fits the scan pattern at
   hand, and the scatter gives the observation's sigma, including the part common to the whole edge
   (scan lines parallel to the edge). Fitting the outermost points alone would put the edge about half a
   spacing inside the roof; the points outside the roof are not used (under eaves and next to walls they
   are occluded or lie under the roof).
4. ``fit_edges``: one Gauss-Markov adjustment per roof, twice: ``reweight_observations`` in between gives each
   edge its own variance factor and drops its outlying bins (a ragged edge does not degrade the clean ones). Parameters: a shared direction theta for all snapped edges
   (parallel and perpendicular by construction), their offsets d, and phi, d of the free edges; weak
   pseudo-observations keep edges without enough boundary points determined (with large sigma).
5. ``corners_from_edges``: corners are intersections of consecutive fitted edges; their covariance is the
   adjustment covariance propagated through the intersection (first order).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np


# Bins left out at each end of an edge (spacings), where the other edge and the rounded trace interfere.
CORNER_MARGIN_SPACINGS = 1.5


# ----------------------------------------------------------------------------------------------- tracing
def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def trace_rings(
    xy: np.ndarray, spacing_m: float, simplify_m: float | None = None, min_hole_m2: float = 16.0
) -> list[np.ndarray]:
    """Rough outline rings of one roof: [outer (CCW), courtyard rings (CW)...] in map coordinates."""
    xy = np.asarray(xy, float)
    cell = float(np.clip(spacing_m / 2.0, 0.05, 0.5))
    origin = xy.min(axis=0) - 4 * spacing_m
    ij = np.floor((xy - origin) / cell).astype(np.int64)
    pad = int(np.ceil(4 * spacing_m / cell))
    shape = (int(ij[:, 1].max()) + 1 + pad, int(ij[:, 0].max()) + 1 + pad)
    mask = np.zeros(shape, np.uint8)
    mask[ij[:, 1], ij[:, 0]] = 1
    r = int(np.ceil(1.0 * spacing_m / cell))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return []
    hierarchy = hierarchy[0]
    outer_ids = [i for i in range(len(contours)) if hierarchy[i][3] < 0]
    outer = max(outer_ids, key=lambda i: cv2.contourArea(contours[i]))
    eps_px = (simplify_m if simplify_m is not None else max(0.5, 1.5 * spacing_m)) / cell
    rings = []
    for i in [outer] + [i for i in range(len(contours)) if hierarchy[i][3] == outer]:
        c = contours[i]
        area_m2 = cv2.contourArea(c) * cell * cell
        if i != outer and area_m2 < min_hole_m2:
            continue
        poly = cv2.approxPolyDP(c, eps_px, True)[:, 0, :].astype(float)
        if len(poly) < 3:
            continue
        ring = origin + (poly + 0.5) * cell
        want_ccw = i == outer
        if (_signed_area(ring) > 0) != want_ccw:
            ring = ring[::-1]
        rings.append(ring)
    return rings


# ----------------------------------------------------------------------------------------- regularising
@dataclasses.dataclass
class Edge:
    """One edge line. ``q`` in 0..3: snapped, outward normal phi = theta_fam + q*90 deg (``fam``: 0 the roof's
    dominant direction, 1 its second direction family); q = -1: free edge."""

    ring: int
    q: int
    phi: float  # outward normal direction, rad (for snapped edges: theta + q pi/2)
    d: float  # line offset, m
    param_phi: int = -1  # index of phi (theta for snapped edges) in the parameter vector
    param_d: int = -1
    n_obs: int = 0
    depth_m: float = float("nan")  # mean depth of the outermost roof point inside the edge
    p_start: np.ndarray | None = None  # rough trace vertices the edge came from (for inserting steps)
    p_end: np.ndarray | None = None
    fam: int = 0  # direction family of a snapped edge (0: theta, 1: the second family)

    def normal(self) -> np.ndarray:
        return np.array([np.cos(self.phi), np.sin(self.phi)])

    def direction(self) -> np.ndarray:
        # roof on the left: direction = normal rotated by +90 deg
        return np.array([-np.sin(self.phi), np.cos(self.phi)])


def dominant_direction(rings: list[np.ndarray]) -> float:
    """theta in [0, pi/2): length^2-weighted circular mean of edge normal directions modulo 90 deg."""
    s = c = 0.0
    for ring in rings:
        e = np.roll(ring, -1, axis=0) - ring
        w = np.einsum("ij,ij->i", e, e)
        a = np.arctan2(e[:, 1], e[:, 0])
        s += float(np.sum(w * np.sin(4 * a)))
        c += float(np.sum(w * np.cos(4 * a)))
    return float(np.mod(np.arctan2(s, c) / 4.0, np.pi / 2))


def _dev_deg(a: np.ndarray, theta: float) -> np.ndarray:
    """Angle (deg) between directions ``a`` (rad) and the nearest of theta + q 90 deg."""
    k = (a - theta) / (np.pi / 2)
    return np.abs(k - np.round(k)) * 90.0


def second_direction(rings: list[np.ndarray], theta: float, snap_tol_deg: float, min_edges: int = 4,
                     min_edge_m: float = 1.0) -> float | None:
    """A second direction family of a roof, or None: a terraced block whose houses are staggered along a
    street that runs at an angle to the houses, or two wings at an angle, has right-angled corners in two
    orientations. The edges (of at least ``min_edge_m``) more than ``snap_tol_deg`` off theta form a family
    when at least ``min_edges`` of them (two steps) lie within ``snap_tol_deg`` of their length-weighted mean
    direction modulo 90 deg."""
    segs = [np.roll(r, -1, axis=0) - r for r in rings]
    e = np.concatenate(segs) if segs else np.zeros((0, 2))
    length = np.hypot(e[:, 0], e[:, 1])
    a = np.arctan2(e[:, 1], e[:, 0])
    off = (_dev_deg(a, theta) > snap_tol_deg) & (length >= min_edge_m)
    if off.sum() < min_edges:
        return None
    w = length[off]
    t2 = float(np.mod(np.arctan2(np.sum(w * np.sin(4 * a[off])), np.sum(w * np.cos(4 * a[off]))) / 4.0, np.pi / 2))
    if (_dev_deg(a[off], t2) <= snap_tol_deg).sum() < min_edges or _dev_deg(np.array([t2]), theta)[0] <= snap_tol_deg:
        return None
    return t2


def _intersect(e1: Edge, e2: Edge) -> np.ndarray | None:
    a = np.array([[np.cos(e1.phi), np.sin(e1.phi)], [np.cos(e2.phi), np.sin(e2.phi)]])
    if abs(np.linalg.det(a)) < np.sin(np.radians(10)):
        return None
    return np.linalg.solve(a, [e1.d, e2.d])


def _edges_of_ring(
    ring: np.ndarray, ring_id: int, thetas: list[float], snap_tol_deg: float, min_free_edge_m: float
) -> list[Edge]:
    """Edges of a traced ring, snapped to the nearer family theta_f + q 90 deg when close; short edges that
    do not snap (corner rounding of the trace) are left out, so their neighbours meet directly."""
    edges = []
    for p, p_next in zip(ring, np.roll(ring, -1, axis=0)):
        e = p_next - p
        if np.hypot(*e) < 1e-9:
            continue
        phi = np.arctan2(e[1], e[0]) - np.pi / 2  # outward normal, roof on the left
        devs = [float(_dev_deg(np.array([phi]), t)[0]) for t in thetas]
        fam = int(np.argmin(devs))
        theta, dev_deg = thetas[fam], devs[fam]
        q = int(np.round((phi - theta) / (np.pi / 2))) % 4
        short = np.hypot(*e) < min_free_edge_m
        # short edges have poorly defined directions: a wider tolerance, and dropped when they still miss
        if dev_deg <= (2.0 * snap_tol_deg if short else snap_tol_deg):
            phi = theta + q * np.pi / 2
        elif short:
            continue
        else:
            q, fam = -1, 0
        n = np.array([np.cos(phi), np.sin(phi)])
        edges.append(Edge(ring_id, q, float(phi), float(n @ (0.5 * (p + p_next))), p_start=p, p_end=p_next,
                          fam=fam))
    return edges


def _edge_length(edges: list[Edge], i: int) -> float:
    prev, cur, nxt = edges[i - 1], edges[i], edges[(i + 1) % len(edges)]
    a, b = _intersect(prev, cur), _intersect(cur, nxt)
    if a is None or b is None:
        return float("nan")
    return float(cur.direction() @ (b - a))


def _clean_ring(
    edges: list[Edge], thetas: list[float], merge_tol_m: float, min_edge_m: float, min_free_edge_m: float
) -> list[Edge]:
    """Merge collinear neighbours, insert steps between parallel neighbours, drop short/negative edges."""
    for _ in range(4 * len(edges) + 10):
        if len(edges) < 3:
            return []
        changed = False
        for i in range(len(edges)):
            a, b = edges[i], edges[(i + 1) % len(edges)]
            if a.q >= 0 and a.q == b.q and a.fam == b.fam:
                if abs(a.d - b.d) < merge_tol_m:
                    la, lb = np.hypot(*(a.p_end - a.p_start)), np.hypot(*(b.p_end - b.p_start))
                    d = (la * a.d + lb * b.d) / max(la + lb, 1e-9)
                    edges[i] = dataclasses.replace(a, d=float(d), p_end=b.p_end)
                    del edges[(i + 1) % len(edges)]
                else:
                    # a step between two parallel lines: it runs outward (normal = direction - 90 deg)
                    # when the second line lies outward of the first, inward otherwise
                    q = (a.q + (3 if b.d > a.d else 1)) % 4
                    phi = thetas[a.fam] + q * np.pi / 2
                    p = 0.5 * (a.p_end + b.p_start)
                    n = np.array([np.cos(phi), np.sin(phi)])
                    edges.insert(i + 1, Edge(a.ring, q, float(phi), float(n @ p), p_start=p, p_end=p, fam=a.fam))
                changed = True
                break
            if a.q >= 0 and b.q >= 0 and a.fam == b.fam and (a.q - b.q) % 2 == 0:
                # opposite normals on consecutive edges: a spike; drop the shorter
                i_next = (i + 1) % len(edges)
                del edges[i if _edge_length(edges, i) < _edge_length(edges, i_next) else i_next]
                changed = True
                break
        if changed:
            continue
        lengths = np.array([_edge_length(edges, i) for i in range(len(edges))])
        lengths = np.where(np.isnan(lengths), -np.inf, lengths)
        # drop the worst offender: non-positive length first, then short free edges, then short steps
        bad = np.flatnonzero(lengths <= 0.0)
        if len(bad) == 0:
            short = [i for i in range(len(edges))
                     if lengths[i] < (min_edge_m if edges[i].q >= 0 else min_free_edge_m)]
            if short:
                bad = np.array([min(short, key=lambda i: lengths[i])])
        if len(bad):
            del edges[int(bad[np.argmin(lengths[bad])])]
            continue
        break
    return edges if len(edges) >= 3 else []


def regularise_rings(
    rings: list[np.ndarray], spacing_m: float, snap_tol_deg: float = 15.0, min_edge_m: float | None = None,
    min_free_edge_m: float | None = None,
) -> tuple[float, list[list[Edge]]]:
    """Dominant direction theta (rad) and the regularised edge list of every ring (cyclic order).

    Edges within ``snap_tol_deg`` of theta + q 90 deg are snapped to it; a second direction family
    (``second_direction``: staggered houses along a street at an angle, wings at an angle) snaps the edges
    near it the same way (``Edge.fam`` 1), so its right angles are kept too instead of fitting each of its
    edges on its own.

    Parallel neighbours closer than ``min_edge_m`` (default max(1.5 m, 2 spacings)) merge, farther ones
    get a step; free (not snapped) edges shorter than ``min_free_edge_m`` (default max(3 m, 5 spacings))
    are dropped: at the trace's resolution they are corner rounding, not building edges.
    """
    min_edge_m = max(1.5, 2.0 * spacing_m) if min_edge_m is None else min_edge_m
    min_free_edge_m = max(3.0, 5.0 * spacing_m) if min_free_edge_m is None else min_free_edge_m
    theta = dominant_direction(rings)
    theta2 = second_direction(rings, theta, snap_tol_deg, min_edge_m=min_edge_m)
    thetas = [theta] if theta2 is None else [theta, theta2]
    out = []
    for r, ring in enumerate(rings):
        edges = _edges_of_ring(ring, r, thetas, snap_tol_deg, min_free_edge_m)
        edges = _clean_ring(edges, thetas, min_edge_m, min_edge_m, min_free_edge_m)
        if edges:
            out.append(edges)
    return theta, out


# --------------------------------------------------------------------------------------- observations
@dataclasses.dataclass
class EdgeObservations:
    """Observed edge points (x, y) with their standard deviation across the edge (m), per edge.

    ``sigma_common_m``: the part of the edge-offset error shared by all bins of the edge (a scan pattern
    whose lines run parallel to the edge puts the outermost points of every bin at the same depth);
    it is added to the offset variance after the adjustment, since averaging along the edge cannot
    reduce it.
    """

    xy: np.ndarray
    sigma_m: np.ndarray
    depth_m: float = float("nan")  # mean depth of the outermost roof point inside the edge
    sigma_common_m: float = 0.0


def outermost_depth(u: np.ndarray, t: np.ndarray, spacing_m: float, bin_m: float, n_lines: int = 16):
    """How far inside an edge the outermost roof point of a bin lies, learnt from the roof itself.

    ``u``: roof point coordinates across the edge (outward positive), ``t``: along it. Virtual edges
    parallel to the real one are laid across the roof interior; for each, the depth of the outermost
    point inside it per bin of ``bin_m`` is exactly what the real edge sees, for whatever scan pattern
    the roof was sampled with. Returns (mean depth, std per bin, std of the mean over one edge's bins
    that is common to all bins, i.e. not reduced by averaging) in metres; None when the roof is too
    narrow to calibrate.
    """
    lo, hi = np.percentile(u, 2.0), np.percentile(u, 98.0)
    if hi - lo < 4.0 * spacing_m or len(u) < 50:
        return None
    t_bin = np.floor((t - t.min()) / bin_m).astype(np.int64)
    n_bins = int(t_bin.max()) + 1
    depths, line_means, line_counts = [], [], []
    for u_v in np.linspace(lo + 2.5 * spacing_m, hi - 1.0 * spacing_m, n_lines):
        inside = (u <= u_v) & (u > u_v - 3.0 * spacing_m)
        beyond = (u > u_v) & (u < u_v + 2.0 * spacing_m)
        u_max = np.full(n_bins, -np.inf)
        np.maximum.at(u_max, t_bin[inside], u[inside])
        has_beyond = np.zeros(n_bins, bool)
        has_beyond[t_bin[beyond]] = True
        ok = np.isfinite(u_max) & has_beyond
        if ok.sum() < 3:
            continue
        d = u_v - u_max[ok]
        depths.append(d)
        line_means.append(d.mean())
        line_counts.append(ok.sum())
    if len(depths) < 4:
        return None
    all_d = np.concatenate(depths)
    mean, sd = float(all_d.mean()), float(all_d.std(ddof=1))
    line_means, line_counts = np.array(line_means), np.array(line_counts)
    # scatter of the per-line means beyond what independent bins would give
    excess = np.mean((line_means - mean) ** 2 - sd**2 / line_counts)
    return mean, sd, float(np.sqrt(max(excess, 0.0)))


def edge_observations(
    edges: list[Edge],
    roof_xy: np.ndarray,
    spacing_m: float,
    corner_margin_m: float | None = None,
) -> list[EdgeObservations]:
    """Edge points: the outermost roof point of each bin along the edge, moved outwards by the mean
    depth at which the outermost point lies inside an edge (``outermost_depth``).

    Fitting the outermost points alone puts the edge about half a spacing inside the roof. Points outside
    the roof are not used: under eaves and next to walls they are hidden or lie under the roof.
    Bins are one spacing long; ``corner_margin_m`` (default ``CORNER_MARGIN_SPACINGS`` spacings) is left out
    at both ends where the other edge and the rounded trace interfere.
    """
    margin = corner_margin_m if corner_margin_m is not None else CORNER_MARGIN_SPACINGS * spacing_m
    band = 2.0 * spacing_m + 1.0
    out = []
    for i, e in enumerate(edges):
        prev, nxt = edges[i - 1], edges[(i + 1) % len(edges)]
        a, b = _intersect(prev, e), _intersect(e, nxt)
        n, t_dir = e.normal(), e.direction()
        empty = EdgeObservations(np.zeros((0, 2)), np.zeros(0))
        if a is None or b is None:
            out.append(empty)
            continue
        t0, t1 = float(t_dir @ a) + margin, float(t_dir @ b) - margin
        if t1 - t0 < spacing_m:
            out.append(empty)
            continue
        n_bins = max(1, int(np.floor((t1 - t0) / spacing_m)))
        bin_w = (t1 - t0) / n_bins
        u_all = roof_xy @ n - e.d
        t_all = roof_xy @ t_dir
        sel = (u_all > -band) & (u_all < band) & (t_all >= t0) & (t_all < t1)
        k = np.minimum(((t_all[sel] - t0) / bin_w).astype(np.int64), n_bins - 1)
        u_max = np.full(n_bins, -np.inf)
        np.maximum.at(u_max, k, u_all[sel])
        has_roof = np.isfinite(u_max)
        cal = outermost_depth(u_all, t_all, spacing_m, bin_w)
        if cal is None:  # narrow roof: uniform depth within one spacing
            cal = (0.5 * spacing_m, spacing_m / np.sqrt(12.0), 0.5 * spacing_m / np.sqrt(12.0))
        depth, sd, sd_common = cal
        t_mid = t0 + (np.arange(n_bins) + 0.5) * bin_w
        xy = t_mid[has_roof, None] * t_dir + (e.d + u_max[has_roof, None] + depth) * n
        e.n_obs = int(has_roof.sum())
        e.depth_m = depth
        sigma = np.full(e.n_obs, sd)  # the calibration sees the point noise too
        out.append(EdgeObservations(xy, sigma, depth, sd_common))
    return out


# ------------------------------------------------------------------------------------------ adjustment
@dataclasses.dataclass
class EdgeFit:
    theta: float
    params: np.ndarray
    cov: np.ndarray  # covariance of params (rad^2, m^2)
    sigma0: float  # a posteriori sigma naught (unitless, a priori 1)
    dof: int


def fit_edges(
    theta: float,
    rings: list[list[Edge]],
    observations: list[list[EdgeObservations]],
    *, prior_d_m: float = 1.0,
    prior_phi_deg: float = 5.0,
    min_sigma0: float = 1.0,
    iterations: int = 6,
) -> EdgeFit:
    """Least-squares fit of all edges of one roof (Gauss-Newton, weighted by 1/sigma^2).

    Parameters: theta (shared by the snapped edges of family 0; a second theta for family 1, started from
    its edges' direction), d per edge, phi per free edge. The covariance is
    ``max(sigma0, min_sigma0)^2 (J^T P J)^-1``: the a posteriori variance factor is used when the
    residuals are larger than their a priori sigmas, never to shrink them.
    """
    n_par = 1
    theta2 = next((e.phi - e.q * np.pi / 2 for edges in rings for e in edges if e.q >= 0 and e.fam == 1), None)
    if theta2 is not None:
        n_par = 2  # the second family's direction
    for edges in rings:
        for e in edges:
            if e.q >= 0:
                e.param_phi = 1 if (e.fam == 1 and theta2 is not None) else 0
            else:
                e.param_phi = n_par
                n_par += 1
            e.param_d = n_par
            n_par += 1
    p = np.zeros(n_par)
    p[0] = theta
    if theta2 is not None:
        p[1] = theta2
    for edges in rings:
        for e in edges:
            if e.q < 0:
                p[e.param_phi] = e.phi
            p[e.param_d] = e.d
    p0 = p.copy()
    # Centre coordinates for conditioning: d is re-expressed relative to the centre.
    all_xy = [o.xy for obs in observations for o in obs if len(o.xy)]
    centre = np.concatenate(all_xy).mean(axis=0) if all_xy else np.zeros(2)
    for edges in rings:
        for e in edges:
            p[e.param_d] -= e.normal() @ centre
            p0[e.param_d] = p[e.param_d]

    def phi_of(e, p):
        return p[e.param_phi] + e.q * np.pi / 2 if e.q >= 0 else p[e.param_phi]

    rows_j, res, w = [], [], []
    for _ in range(iterations):
        rows_j, res, w = [], [], []
        for edges, obs in zip(rings, observations):
            for e, o in zip(edges, obs):
                phi = phi_of(e, p)
                if len(o.xy):
                    xy = o.xy - centre
                    c, s = np.cos(phi), np.sin(phi)
                    f = xy[:, 0] * c + xy[:, 1] * s - p[e.param_d]
                    j = np.zeros((len(xy), n_par))
                    j[:, e.param_phi] = -xy[:, 0] * s + xy[:, 1] * c
                    j[:, e.param_d] = -1.0
                    rows_j.append(j)
                    res.append(f)
                    w.append(1.0 / o.sigma_m**2)
                # weak priors: keep every parameter determined
                j = np.zeros((1, n_par))
                j[0, e.param_d] = 1.0
                rows_j.append(j)
                res.append(np.array([p[e.param_d] - p0[e.param_d]]))
                w.append(np.array([1.0 / prior_d_m**2]))
                if e.q < 0:
                    j = np.zeros((1, n_par))
                    j[0, e.param_phi] = 1.0
                    rows_j.append(j)
                    res.append(np.array([p[e.param_phi] - p0[e.param_phi]]))
                    w.append(np.array([1.0 / np.radians(prior_phi_deg) ** 2]))
        # weak prior on theta too: a roof without boundary points (or without snapped edges) stays solvable
        for k_theta in range(2 if theta2 is not None else 1):
            j = np.zeros((1, n_par))
            j[0, k_theta] = 1.0
            rows_j.append(j)
            res.append(np.array([p[k_theta] - p0[k_theta]]))
            w.append(np.array([1.0 / np.radians(prior_phi_deg) ** 2]))
        jac = np.vstack(rows_j)
        f = np.concatenate(res)
        wt = np.concatenate(w)
        n_mat = jac.T @ (wt[:, None] * jac)
        step = np.linalg.solve(n_mat, -jac.T @ (wt * f))
        p += step
        if np.max(np.abs(step)) < 1e-9:
            break
    jac = np.vstack(rows_j)
    wt = np.concatenate(w)
    n_obs = sum(len(o.xy) for obs in observations for o in obs)
    dof = max(n_obs - n_par, 1)
    # sigma0 from the edge observations only (the priors are not observations of the roof)
    v_data = []
    for edges, obs in zip(rings, observations):
        for e, o in zip(edges, obs):
            if len(o.xy):
                xy = o.xy - centre
                phi = phi_of(e, p)
                v_data.append((xy[:, 0] * np.cos(phi) + xy[:, 1] * np.sin(phi) - p[e.param_d]) / o.sigma_m)
    vv = float(np.sum(np.concatenate(v_data) ** 2)) if v_data else 0.0
    sigma0 = float(np.sqrt(vv / dof)) if n_obs > n_par else 1.0
    cov = max(sigma0, min_sigma0) ** 2 * np.linalg.inv(jac.T @ (wt[:, None] * jac))
    for edges, obs in zip(rings, observations):
        for e, o in zip(edges, obs):
            if len(o.xy):
                cov[e.param_d, e.param_d] += o.sigma_common_m**2
    # back to map coordinates: d_map = d_centre + n.centre (the covariance of d_map follows via phi)
    for edges in rings:
        for e in edges:
            e.phi = float(phi_of(e, p))
    t = np.eye(n_par)
    p_map = p.copy()
    for edges in rings:
        for e in edges:
            n = e.normal()
            p_map[e.param_d] = p[e.param_d] + n @ centre
            dn = np.array([-np.sin(e.phi), np.cos(e.phi)])
            t[e.param_d, e.param_phi] = dn @ centre
            e.d = float(p_map[e.param_d])
    cov_map = t @ cov @ t.T
    return EdgeFit(float(p[0]), p_map, cov_map, sigma0, dof)


def reweight_observations(
    rings: list[list[Edge]], observations: list[list[EdgeObservations]], sigma0: float,
    k_reject: float = 3.0, prior_dof: float = 3.0,
) -> list[list[EdgeObservations]]:
    """Per-edge precision after a first ``fit_edges`` (the edges hold the fitted lines).

    Real eaves are not equally clean: gutters, dormers, a branch over one edge. One variance factor per
    roof (the fit's sigma0) lets a ragged edge inflate the sigmas of the clean ones. Per edge: bins whose
    normalised residual exceeds ``k_reject`` times the edge's robust scale (1.4826 MAD, at least 1) are
    dropped, and the sigmas of the rest are scaled by the edge's own variance factor, pooled with
    ``prior_dof`` degrees of freedom of the roof's ``sigma0`` (a few bins alone do not know their scatter);
    never below the a priori sigma. Refit with the returned observations.
    """
    out = []
    for edges, obs in zip(rings, observations):
        ring_out = []
        for e, o in zip(edges, obs):
            if len(o.xy) < 3:
                ring_out.append(o)
                continue
            v = (o.xy @ e.normal() - e.d) / o.sigma_m
            scale = max(1.0, 1.4826 * float(np.median(np.abs(v))))
            keep = np.abs(v) <= k_reject * scale
            if keep.sum() < 2:
                keep[:] = True
            s2 = (float(np.sum(v[keep] ** 2)) + prior_dof * sigma0**2) / (keep.sum() - 1 + prior_dof)
            e.n_obs = int(keep.sum())
            ring_out.append(dataclasses.replace(o, xy=o.xy[keep], sigma_m=o.sigma_m[keep] * np.sqrt(max(s2, 1.0))))
        out.append(ring_out)
    return out


# ---------------------------------------------------------------------------------------------- corners
@dataclasses.dataclass
class RingCorners:
    """Corners of one ring: corner i joins edge i-1 (incoming) and edge i (outgoing)."""

    xy: np.ndarray  # (n, 2)
    cov_xy: np.ndarray  # (n, 2, 2) m^2
    angle_deg: np.ndarray  # interior angle of the roof polygon (90 convex, 270 concave right angle)
    edge_in: list[Edge]
    edge_out: list[Edge]


def corners_from_edges(edges: list[Edge], fit: EdgeFit) -> RingCorners:
    """Intersections of consecutive edges and their covariance (first-order propagation)."""
    xy, covs, angles, e_in, e_out = [], [], [], [], []
    n_par = len(fit.params)
    for i in range(len(edges)):
        e1, e2 = edges[i - 1], edges[i]
        a = np.array([[np.cos(e1.phi), np.sin(e1.phi)], [np.cos(e2.phi), np.sin(e2.phi)]])
        if abs(np.linalg.det(a)) < 1e-6:
            continue
        a_inv = np.linalg.inv(a)
        x = a_inv @ np.array([e1.d, e2.d])
        jac = np.zeros((2, n_par))
        jac[:, e1.param_d] += a_inv[:, 0]
        jac[:, e2.param_d] += a_inv[:, 1]
        # d(A x)/d phi_k = (-sin phi_k, cos phi_k).x in row k  ->  dx/dphi_k = -A^-1 (that)
        jac[:, e1.param_phi] += -a_inv[:, 0] * (np.array([-np.sin(e1.phi), np.cos(e1.phi)]) @ x)
        jac[:, e2.param_phi] += -a_inv[:, 1] * (np.array([-np.sin(e2.phi), np.cos(e2.phi)]) @ x)
        xy.append(x)
        covs.append(jac @ fit.cov @ jac.T)
        d1, d2 = e1.direction(), e2.direction()
        turn = np.degrees(np.arctan2(d1[0] * d2[1] - d1[1] * d2[0], d1 @ d2))
        angles.append(180.0 - turn)
        e_in.append(e1)
        e_out.append(e2)
    return RingCorners(np.array(xy).reshape(-1, 2), np.array(covs).reshape(-1, 2, 2), np.array(angles), e_in, e_out)


def edge_length_m(edges: list[Edge], i: int) -> float:
    """Length of edge i between its two corners (m)."""
    return _edge_length(edges, i)
