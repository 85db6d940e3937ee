"""Roof segmentation: building points -> roofs (connected, height-continuous clusters) -> roof planes.

Conventions: coordinates in metres of a projected CRS, z up. A roof plane is ``z = a (x - x0) + b (y - y0) + c``
with (x0, y0) the centroid of its points, so that (a, b, c) are nearly uncorrelated; slope_deg is the
tilt of the plane from horizontal.

Steps (all vectorised):
1. ``point_spacing_m``: mean point spacing 1/sqrt(density), density from occupied grid cells.
2. ``cluster_roofs``: connected components of building points, linked when closer than a link radius
   horizontally and apart in height by less than ``max_step_m`` plus what a 55 deg roof face rises
   between them, so a lower annex or a roof behind a step becomes its own roof (own eave outline).
3. ``segment_planes``: local normals by PCA of the k nearest neighbours; normal-guided sequential
   RANSAC finds the roof faces (least-squares refit); every point goes to the plane that fits it best.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def point_spacing_m(xy: np.ndarray, cell_m: float = 2.0) -> float:
    """Mean point spacing (m) = 1/sqrt(points per m^2 over occupied ``cell_m`` cells)."""
    xy = np.asarray(xy, float)
    if len(xy) < 2:
        return float("nan")
    ij = np.floor((xy - xy.min(axis=0)) / cell_m).astype(np.int64)
    n_cells = len(np.unique(ij[:, 0] * (ij[:, 1].max() + 1) + ij[:, 1]))
    return float(np.sqrt(n_cells * cell_m * cell_m / len(xy)))


SCAN_GAP_SAMPLE = 5000  # points whose neighbourhoods measure the gap between scan lines
SCAN_GAP_NEIGHBOURS = 40
SCAN_GAP_POINTS = 2_000_000  # the first points (file order: one strip's, lying together) the gap is measured on


def scan_line_gap_m(xy: np.ndarray, percentile: float = 90.0) -> float:
    """The gap a roof's points must be linked across to hold together (m): per point the distance to its nearest
    neighbour in each of the four quadrants around it (of the map axes and of the axes turned 45 deg), the largest,
    at ``percentile`` over a seeded sample of the first ``SCAN_GAP_POINTS`` points. A line scanner's points lie close
    along its scan lines and farther apart across them; the mean spacing (``point_spacing_m``, from the density) is
    below the gap between lines when the pulse rate is high for the scan rate (the trial's 13 points/m2: spacing
    0.28 m, gap 0.85 m, and roofs linked over 2 spacings fell apart into pieces of scan lines). In two of the
    quadrants the nearest point lies across a line. NaN for fewer than 5 points."""
    from scipy.spatial import cKDTree

    xy = np.asarray(xy, float)[:SCAN_GAP_POINTS]
    if len(xy) < 5:
        return float("nan")
    rng = np.random.default_rng(0)
    s = np.sort(rng.choice(len(xy), min(SCAN_GAP_SAMPLE, len(xy)), replace=False))
    d, i = cKDTree(xy).query(xy[s], k=min(SCAN_GAP_NEIGHBOURS, len(xy)))
    v = xy[i[:, 1:]] - xy[s][:, None, :]
    # quadrants of the map axes and of the axes turned 45 deg: lines along an axis put their own points in the
    # quadrants on either side of it (jitter), never in both frames
    turned = np.stack([v[..., 0] - v[..., 1], v[..., 0] + v[..., 1]], axis=-1)
    widest = np.zeros(len(s))
    for w in (v, turned):
        quadrant = (w[..., 0] >= 0).astype(np.int64) * 2 + (w[..., 1] >= 0)
        nearest = np.stack([np.where(quadrant == q, d[:, 1:], np.inf).min(axis=1) for q in range(4)], axis=1)
        widest = np.maximum(widest, nearest.max(axis=1))
    widest = widest[np.isfinite(widest)]  # points at a roof's edge have an empty side
    return float(np.percentile(widest, percentile)) if len(widest) else float("nan")


SCAN_LINES_SPACINGS = 2.5  # a gap wider than this many mean spacings is that of scan lines


def effective_spacing_m(xy: np.ndarray, spacing_m: float) -> float:
    """The spacing the roof work is scaled by (linking roofs over 2 of it, tracing outlines, binning edges): the
    mean spacing ``spacing_m``, or half the gap between scan lines (``scan_line_gap_m``) where that gap is wider
    than ``SCAN_LINES_SPACINGS`` mean spacings (a line scanner at a high pulse rate for its scan rate: the trial's
    13 points/m2, mean spacing 0.28 m, lines up to 0.85 m apart, 3.0 spacings; roofs linked over 2 mean spacings
    fell apart into strips of scan lines, their "corners" along the roof edges). Points spread evenly have their
    gap at about 2 spacings (the demo's building points 1.97, the sparse trial block's 2.01, AHN3 Delft 1.54):
    the mean spacing, as before."""
    gap = scan_line_gap_m(xy)
    if np.isfinite(gap) and gap > SCAN_LINES_SPACINGS * spacing_m:
        return float(gap / 2.0)
    return float(spacing_m)


def cluster_roofs(xyz: np.ndarray, link_radius_m: float, max_step_m: float = 1.0, min_points: int = 30) -> np.ndarray:
    """Roof id per point (-1: cluster smaller than ``min_points``), ids ordered by decreasing size."""
    xyz = np.asarray(xyz, float)
    n = len(xyz)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(xyz[:, :2]).query_pairs(link_radius_m, output_type="ndarray")
    # a step is a height jump beyond what a roof face up to ~55 deg rises over the same distance
    dxy = np.hypot(*(xyz[pairs[:, 0], :2] - xyz[pairs[:, 1], :2]).T)
    keep = np.abs(xyz[pairs[:, 0], 2] - xyz[pairs[:, 1], 2]) < max_step_m + 1.5 * dxy
    pairs = pairs[keep]
    graph = sparse.coo_matrix((np.ones(len(pairs), bool), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    sizes = np.bincount(comp)
    order = np.argsort(-sizes, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    labels = rank[comp]
    labels[sizes[comp] < min_points] = -1
    return labels


def local_normals(xyz: np.ndarray, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (z >= 0) and curvature lambda_min / sum(lambda) from the k nearest neighbours."""
    xyz = np.asarray(xyz, float)
    k = min(k, len(xyz))
    _, idx = cKDTree(xyz).query(xyz, k=k)
    nb = xyz[idx] - xyz[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb) / k
    evals, evecs = np.linalg.eigh(cov)
    normals = evecs[:, :, 0]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    curvature = evals[:, 0] / np.maximum(evals.sum(axis=1), 1e-12)
    return normals, curvature


@dataclasses.dataclass
class RoofPlane:
    """z = a (x - x0) + b (y - y0) + c; cov_abc: covariance of (a, b, c) in m^2 (slopes unitless)."""

    roof_id: int
    x0: float
    y0: float
    abc: np.ndarray
    cov_abc: np.ndarray
    n_points: int
    rms_m: float

    @property
    def slope_deg(self) -> float:
        return float(np.degrees(np.arctan(np.hypot(self.abc[0], self.abc[1]))))

    def height_m(self, x, y) -> np.ndarray:
        return self.abc[0] * (np.asarray(x) - self.x0) + self.abc[1] * (np.asarray(y) - self.y0) + self.abc[2]

    def height_sigma_m(self, x, y) -> np.ndarray:
        """Standard deviation of the plane height at (x, y) from the fit covariance (m)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        j = np.stack([x - self.x0, y - self.y0, np.ones_like(x)], -1)
        return np.sqrt(np.einsum("...i,ij,...j->...", j, self.cov_abc, j))


def fit_plane(xyz: np.ndarray, roof_id: int = -1) -> RoofPlane:
    """Least-squares plane z = a dx + b dy + c with a posteriori covariance (sigma0^2 (A^T A)^-1)."""
    x0, y0 = xyz[:, 0].mean(), xyz[:, 1].mean()
    a = np.column_stack([xyz[:, 0] - x0, xyz[:, 1] - y0, np.ones(len(xyz))])
    abc, *_ = np.linalg.lstsq(a, xyz[:, 2], rcond=None)
    v = a @ abc - xyz[:, 2]
    dof = max(len(xyz) - 3, 1)
    s0_sq = float(v @ v) / dof
    cov = s0_sq * np.linalg.pinv(a.T @ a)
    return RoofPlane(roof_id, float(x0), float(y0), abc, cov, len(xyz), float(np.sqrt(s0_sq)))


def segment_planes(
    xyz: np.ndarray,
    roof_id: int = -1,
    *, k: int = 24,
    max_normal_angle_deg: float = 15.0,
    max_curvature: float = 0.02,
    inlier_m: float = 0.15,
    max_residual_m: float = 0.3,
    min_points: int = 20,
    max_planes: int = 12,
    n_candidates: int = 150,
) -> tuple[np.ndarray, list[RoofPlane]]:
    """Planes of one roof: plane index per point (-1: none fits) and the fitted planes.

    Normal-guided sequential RANSAC: candidate planes are the tangent planes (PCA over the k nearest
    neighbours, k = 24 spans more than one scan line) of planar points (small curvature); the candidate
    with most points within ``inlier_m`` and normals within ``max_normal_angle_deg`` wins, is refitted
    by least squares and removed; repeat. Normal agreement keeps the faces of a hip roof apart where
    a distance test alone would merge them near the hips. Finally every point goes to the plane with
    the smallest residual (below ``max_residual_m``) and the planes are refitted on their members.
    Deterministic: candidates are evenly spaced over the planar points.
    """
    xyz = np.asarray(xyz, float)
    n = len(xyz)
    if n < max(k, min_points):
        if n >= 3:
            return np.zeros(n, np.int64), [fit_plane(xyz, roof_id)]
        return np.full(n, -1, np.int64), []
    normals, curvature = local_normals(xyz, k)
    cos_max = np.cos(np.radians(max_normal_angle_deg))
    # walls and noise do not seed roof planes: planar and less steep than 70 deg
    seedable = (curvature < max_curvature) & (normals[:, 2] > np.cos(np.radians(70.0)))
    remaining = np.arange(n)
    planes: list[RoofPlane] = []
    while len(remaining) >= min_points and len(planes) < max_planes:
        cand = remaining[seedable[remaining]]
        if len(cand) < min_points:
            break
        seeds = cand[np.linspace(0, len(cand) - 1, min(n_candidates, len(cand))).astype(np.int64)]
        centre = xyz[remaining].mean(axis=0)  # numerically kinder than absolute map coordinates
        n_seed = normals[seeds]
        offset = np.einsum("ci,ci->c", n_seed, xyz[seeds] - centre)
        # score the candidates on an even subsample; the winner's inliers come from all points
        sub = remaining[np.linspace(0, len(remaining) - 1, min(len(remaining), 4000)).astype(np.int64)]
        dist = np.abs(n_seed @ (xyz[sub] - centre).T - offset[:, None])
        agree = np.abs(n_seed @ normals[sub].T) > cos_max
        counts = ((dist < inlier_m) & agree).sum(axis=1)
        best = int(np.argmax(counts))
        dist_best = np.abs((xyz[remaining] - centre) @ n_seed[best] - offset[best])
        inl = remaining[(dist_best < inlier_m) & (np.abs(normals[remaining] @ n_seed[best]) > cos_max)]
        if len(inl) < min_points:
            break
        plane = fit_plane(xyz[inl], roof_id)
        # refine once with the fitted plane
        pn = np.array([-plane.abc[0], -plane.abc[1], 1.0]) / np.sqrt(1.0 + plane.abc[0] ** 2 + plane.abc[1] ** 2)
        res = np.abs(plane.height_m(xyz[remaining, 0], xyz[remaining, 1]) - xyz[remaining, 2]) * pn[2]
        inl = remaining[(res < inlier_m) & (np.abs(normals[remaining] @ pn) > cos_max)]
        if len(inl) < min_points:
            break
        planes.append(fit_plane(xyz[inl], roof_id))
        remaining = np.setdiff1d(remaining, inl, assume_unique=True)
    if not planes:
        return np.zeros(n, np.int64), [fit_plane(xyz, roof_id)]
    # Every point to the plane with the smallest residual, if small enough; then refit on the members.
    resid = np.abs(np.stack([p.height_m(xyz[:, 0], xyz[:, 1]) - xyz[:, 2] for p in planes], axis=1))
    best = resid.argmin(axis=1)
    plane_of = np.where(resid[np.arange(n), best] < max_residual_m, best, -1)
    refit = []
    for p_idx in range(len(planes)):
        members = plane_of == p_idx
        if members.sum() >= min_points:
            refit.append((p_idx, fit_plane(xyz[members], roof_id)))
    remap = np.full(len(planes) + 1, -1, np.int64)
    for new, (old, _) in enumerate(refit):
        remap[old] = new
    plane_of = remap[plane_of]
    return plane_of, [p for _, p in refit]
