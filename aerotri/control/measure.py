"""Measure a LiDAR roof corner in one frame: predicted window, edge segments, intersection, sub-pixel fit.

Pixel convention as in ``aerotri.geom.camera``: origin at the centre of the top-left pixel, x right, y down.

Method (per frame):
1. Prediction: the corner and its two roof edges (object directions from the LiDAR bearings) are
   projected with the current orientation, as a camera over the earth sees them (``FramesOnEarth``: a projected
   CRS is not Cartesian); the search radius follows from the corner's standard
   deviations propagated into the image plus the orientation uncertainty (``eo_sigma_px``).
2. Candidates: straight edges with the predicted directions (a line detector with known direction,
   i.e. a Hough transform restricted to the two LiDAR edge directions, on the colour gradient), shifted
   across the window; a pair that forms an L-junction (both edges run away from their intersection,
   neither continues through it) is a corner candidate.
3. Choice: candidates are ranked by edge contrast times a Gaussian prior on the distance from the
   prediction; a second candidate at a different position that is nearly as good makes the corner
   ambiguous (rejected). Each edge is moved to the parallel edge nearest the roof interior (the eave,
   not the foot of a wall seen beside it), and the junction must be seen: low contrast right at it
   while the edges are clear further out means something in front of the corner (occluded).
4. Sub-pixel refinement: along each edge, the maximum of the colour gradient across the edge is located
   with a parabola on profiles every pixel; a straight line is fitted to these edge points (total least
   squares with outlier rejection) and the two lines are intersected.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from scipy import ndimage

from aerotri.control.settings import MeasureSettings

# The version of the corner measurement in a frame (``measure_in_image``, ``predict``): the control transfer's
# per-frame resume key (``aerotri.control.pipeline._frame_keys``) and the chain's control stamp hold it, so frames
# measured before a change are measured again. Bump it when a frame's measurements change at the same settings.
# 1: resume-keys (the measurement as of main 195def90).
MEASURE_VERSION = 1

REASONS = ("outside_frame", "no_edges", "occluded", "ambiguous", "poor_edge_fit")  # no_edges: no contrast or hidden


@dataclasses.dataclass
class Measurement:
    x_px: float
    y_px: float
    ok: bool
    reason: str = ""  # one of REASONS when not ok
    fit_rms_px: float = float("nan")  # rms of the edge points about the two fitted lines
    support_px: float = 0.0  # edge length used in the fit (both edges)
    shift_px: float = float("nan")  # measured - predicted distance


# -- prediction -------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class CornerPoints:
    """Corners and the points that give their image edge directions and uncertainty, in the Cartesian frame of
    ``FramesOnEarth`` (``corner_points``: transformed once for all frames): the corners (N, 3), the corners moved
    +- ``step_m`` along each roof edge (N, 2, 2, 3: edge, sign +/-) and by their standard deviation along each map
    axis (N, 3, 3)."""

    xyz: np.ndarray
    along_edges: np.ndarray
    by_sigma: np.ndarray


def corner_points(frames, xyz_m, edge_dir_m, sigma_m, step_m: float = 2.0) -> CornerPoints:
    """``CornerPoints`` of corners (N, 3) with horizontal roof-edge directions (N, 2, 3) and standard deviations
    (N, 3) in the project CRS (``frames``: ``aerotri.geom.local_frame.FramesOnEarth``)."""
    xyz_m = np.atleast_2d(np.asarray(xyz_m, dtype=float))
    edge_dir_m, sigma_m = np.asarray(edge_dir_m, dtype=float), np.asarray(sigma_m, dtype=float)
    n = len(xyz_m)
    along = np.stack([np.stack([xyz_m + step_m * edge_dir_m[:, j], xyz_m - step_m * edge_dir_m[:, j]], axis=1)
                      for j in range(2)], axis=1)  # (N, 2, 2, 3)
    by_sigma = np.stack([xyz_m + np.eye(3)[a] * sigma_m[:, a : a + 1] for a in range(3)], axis=1)  # (N, 3, 3)
    local = frames.to_local(np.concatenate([xyz_m, along.reshape(-1, 3), by_sigma.reshape(-1, 3)]))
    return CornerPoints(local[:n], local[n : 5 * n].reshape(n, 2, 2, 3), local[5 * n :].reshape(n, 3, 3))


def predict(camera, frames, i: int, points: CornerPoints, *, eo_sigma_px: float = 1.0, window_k: float = 3.0,
            min_radius_px: float = 4.0, max_radius_px: float = 25.0):
    """Project corners (``corner_points``) and their edge directions into frame ``i`` of ``frames``
    (``FramesOnEarth``: a camera over the earth).

    Returns x_px, y_px (N,), image edge directions (N, 2, 2) (unit, sign arbitrary), sigma_px (N,)
    (corner standard deviations propagated into the image, radial) and the search radius (N,) in px.
    """
    x, y, depth = frames.project_local(camera, i, points.xyz)
    dirs = np.zeros((len(x), 2, 2))
    for j in range(2):
        xa, ya, _ = frames.project_local(camera, i, points.along_edges[:, j, 0])
        xb, yb, _ = frames.project_local(camera, i, points.along_edges[:, j, 1])
        d = np.stack([xa - xb, ya - yb], axis=-1)
        dirs[:, j] = d / np.linalg.norm(d, axis=-1, keepdims=True)
    var = np.zeros(len(x))
    for a in range(3):
        xs, ys, _ = frames.project_local(camera, i, points.by_sigma[:, a])
        var += (xs - x) ** 2 + (ys - y) ** 2
    sigma_px = np.sqrt(var)
    radius = np.clip(window_k * np.hypot(sigma_px, eo_sigma_px), min_radius_px, max_radius_px)
    return x, y, dirs, sigma_px, radius


# -- image helpers ----------------------------------------------------------------------------------
def gradients(chip: np.ndarray) -> np.ndarray:
    """Smoothed image gradients (C, 2, H, W): d/dx, d/dy per colour channel (grey values per px)."""
    chip = np.atleast_3d(chip).astype(np.float32)
    out = np.empty((chip.shape[2], 2, chip.shape[0], chip.shape[1]), np.float32)
    for c in range(chip.shape[2]):
        g = cv2.GaussianBlur(chip[:, :, c], (0, 0), 0.7)
        out[c, 0] = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        out[c, 1] = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return out


def _intersect(p1, u1, p2, u2):
    """Intersection of the lines p1 + s u1 and p2 + t u2 (2-vectors); None when nearly parallel."""
    A = np.array([[u1[0], -u2[0]], [u1[1], -u2[1]]])
    if abs(np.linalg.det(A)) < 0.2:
        return None
    s, _ = np.linalg.solve(A, p2 - p1)
    return p1 + s * u1


def edge_points(grad, X, v, length_px, *, t0_px: float = 2.0, half_px: float = 2.5, step_px: float = 0.25):
    """Sub-pixel edge points along the half line X + t v, t0 <= t <= length (chip pixels).

    At every pixel along the edge, the colour gradient across the edge (normal n) is sampled on a
    profile of +-half_px; the maximum is located with a parabola. Returns points (K, 2).
    """
    n = np.array([-v[1], v[0]])
    t = np.arange(t0_px, max(length_px, t0_px), 1.0)
    o = np.arange(-half_px, half_px + 1e-9, step_px)
    if len(t) == 0:
        return np.zeros((0, 2))
    P = X + t[:, None, None] * v + o[None, :, None] * n  # (T, O, 2)
    E = edge_energy(grad, P, n)
    k = np.argmax(E, axis=1)
    inner = (k > 0) & (k < len(o) - 1)
    rows = np.flatnonzero(inner)
    k = k[inner]
    y0, y1, y2 = E[rows, k - 1], E[rows, k], E[rows, k + 1]
    den = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(den < 0, 0.5 * (y0 - y2) / den, 0.0)
    off = o[k] + np.clip(frac, -0.5, 0.5) * step_px
    # weak maxima (below a quarter of the median strength) are noise, not the edge
    strong = y1 >= 0.25 * np.median(y1) if len(y1) else np.zeros(0, bool)
    return (X + t[rows, None] * v + off[:, None] * n)[strong]


def fit_line(pts, max_iter: int = 4):
    """Total-least-squares line through points (K, 2) with iterative outlier rejection.

    Returns (centroid (2,), unit direction (2,), rms_px, inlier count); None for fewer than 3 points.
    """
    keep = np.ones(len(pts), bool)
    for _ in range(max_iter):
        if keep.sum() < 3:
            return None
        c = pts[keep].mean(axis=0)
        _, _, vt = np.linalg.svd(pts[keep] - c, full_matrices=False)
        d = vt[0]
        r = (pts - c) @ np.array([-d[1], d[0]])
        mad = 1.4826 * np.median(np.abs(r[keep]))
        new = np.abs(r) <= max(3.0 * mad, 0.25)
        if np.array_equal(new, keep):
            break
        keep = new
    if keep.sum() < 3:
        return None
    rms = float(np.sqrt(np.mean(r[keep] ** 2)))
    return c, d, rms, int(keep.sum())


def refine_corner(grad, X, legs, s: MeasureSettings, iterations: int = 2):
    """Refine a junction X with its legs [(v, length)]; returns (X, rms_px, support_px) or None."""
    for _ in range(iterations):
        lines, rms, support = [], [], 0
        for v, length in legs:
            pts = edge_points(grad, X, v, min(length, s.edge_len_px))
            fit = fit_line(pts) if len(pts) >= s.min_edge_points else None
            if fit is None or fit[3] < s.min_edge_points:
                return None
            c, d, r, m = fit
            lines.append((c, d if d @ v > 0 else -d))
            rms.append(r)
            support += m
        Xn = _intersect(lines[0][0], lines[0][1], lines[1][0], lines[1][1])
        if Xn is None or np.hypot(*(Xn - X)) > 3.0:
            return None
        X = Xn
        legs = [(lines[0][1], legs[0][1]), (lines[1][1], legs[1][1])]
    return X, float(np.sqrt(np.mean(np.square(rms)))), float(support)


def edge_energy(grad, pts, n):
    """Colour gradient magnitude across the direction with unit normal n, at points (..., 2) (chip px)."""
    E = np.sqrt(np.sum((n[0] * grad[:, 0] + n[1] * grad[:, 1]) ** 2, axis=0))
    coords = np.stack([pts[..., 1].ravel(), pts[..., 0].ravel()])
    return ndimage.map_coordinates(E, coords, order=1, mode="nearest").reshape(pts.shape[:-1])


def junction_candidates(grad, pred_xy, dirs, radius_px, s: MeasureSettings, step_px: float = 0.5):
    """Roof-corner candidates: L-junctions of two straight edges with the predicted directions.

    A line detector with known direction (a Hough transform restricted to the predicted edge
    directions): the two edge lines are shifted across their direction by offsets within the search
    radius; for each of the four quadrants the corner may open into, a candidate's contrast is the
    mean gradient across each edge along its leg (2 .. ``leg_px`` from the junction) minus the mean
    on the leg's extension beyond the junction (a straight edge passing through is no corner).
    Returns the score surface maxima as a list of (score, contrast, X (2,), legs [(v, 1), (v, 1)])
    sorted by score; score = contrast * exp(-d^2 / (2 sigma^2)) with sigma = radius / 3.
    """
    leg_px = min(15.0, s.edge_len_px)
    t_leg = np.arange(2.0, leg_px + 1e-9, 1.0)
    t_ext = np.arange(2.0, 6.0 + 1e-9, 1.0)
    d = np.arange(-radius_px, radius_px + 1e-9, step_px)
    D1, D2 = np.meshgrid(d, d, indexing="ij")
    n = np.stack([[-dirs[j, 1], dirs[j, 0]] for j in range(2)])  # rows n1, n2
    if abs(np.linalg.det(n)) < 0.2:  # edges within ~12 deg of parallel: no usable corner
        return []
    X = pred_xy + np.stack([D1, D2], axis=-1) @ np.linalg.inv(n).T  # n @ (X - pred) = (d1, d2)
    inside = np.hypot(*(X - pred_xy).transpose(2, 0, 1)) <= radius_px
    sigma_win = radius_px / 3.0
    prior = np.exp(-0.5 * np.sum((X - pred_xy) ** 2, axis=-1) / sigma_win**2)
    out = []
    for s1 in (1.0, -1.0):
        for s2 in (1.0, -1.0):
            legs = [s1 * dirs[0], s2 * dirs[1]]
            contrast = None
            for j, v in enumerate(legs):
                on = edge_energy(grad, X[..., None, :] + t_leg[:, None] * v, n[j]).mean(axis=-1)
                off = edge_energy(grad, X[..., None, :] - t_ext[:, None] * v, n[j]).mean(axis=-1)
                c = on - off
                contrast = c if contrast is None else np.minimum(contrast, c)
            score = np.where(inside, np.maximum(contrast, 0.0) * prior, 0.0)
            peak = (score == ndimage.maximum_filter(score, size=5)) & (score > 0)
            for a, b in zip(*np.nonzero(peak)):
                out.append((float(score[a, b]), float(contrast[a, b]), X[a, b].copy(), [(legs[0], 1.0), (legs[1], 1.0)]))
    out.sort(key=lambda c: -c[0])
    return out


def leg_length_px(grad, X, v, max_px: float, min_px: float = 6.0) -> float:
    """How far the edge runs from the junction: until the contrast drops below 40 % of its start."""
    n = np.array([-v[1], v[0]])
    t = np.arange(2.0, max_px + 1e-9, 1.0)
    off = np.arange(-1.5, 1.51, 0.5)
    E = edge_energy(grad, X + t[:, None, None] * v + off[None, :, None] * n, n).max(axis=1)
    ref = np.median(E[: max(3, int(min_px))])
    weak = np.flatnonzero(E < 0.4 * ref)
    weak = weak[t[weak] > min_px]
    return float(t[weak[0]] - 1.0) if len(weak) else float(max_px)


def innermost_edge(grad, X, legs, pred, *, radius_px, convex: bool, min_ratio: float = 0.35):
    """Move each leg's line to the edge nearest the roof interior (the eave line).

    On the side of a building facing the nadir point the image shows roof, then the wall (relief
    displacement), then ground: two parallel edges. The eave is the one next to the roof, whose
    interior lies on the side of one leg towards the other leg (convex corner) or away from it
    (re-entrant corner). Profiles of the mean edge contrast across each leg are searched for the
    innermost local maximum of at least ``min_ratio`` of the strongest one, within the window.
    """
    offs = np.arange(-radius_px - 2.0, radius_px + 2.0 + 1e-9, 0.25)
    new_lines = []
    for j in range(2):
        v, length = legs[j]
        w = legs[1 - j][0]
        n = np.array([-v[1], v[0]])
        n_in = n * (np.sign(n @ w) if convex else -np.sign(n @ w))
        t = np.arange(3.0, max(min(length, 15.0), 4.0) + 1e-9, 1.0)
        P = X + t[:, None, None] * v + offs[None, :, None] * n_in
        prof = edge_energy(grad, P, n).mean(axis=0)
        inwin = np.hypot(*(X + offs[:, None] * n_in - pred).T) <= radius_px + 1.0
        peaks = np.flatnonzero((prof >= ndimage.maximum_filter1d(prof, 5)) & inwin)
        if len(peaks) == 0:
            new_lines.append((X, v))
            continue
        strong = peaks[prof[peaks] >= min_ratio * prof[peaks].max()]
        k = strong.max()  # offsets grow towards the interior
        new_lines.append((X + offs[k] * n_in, v))
    Xn = _intersect(new_lines[0][0], new_lines[0][1], new_lines[1][0], new_lines[1][1])
    return X if Xn is None else Xn


def junction_visible(grad, X, legs, near_px=(1.5, 6.0), far_px=(6.0, 15.0), min_ratio: float = 0.5) -> bool:
    """Both edges are seen right at the junction: contrast near it at least half of that further out.

    An object in front of the corner (tree crown, taller roof) hides the junction while the edges
    further out may still be seen; their intersection would be extrapolated, so it is rejected.
    """
    for v, length in legs:
        n = np.array([-v[1], v[0]])
        off = np.arange(-1.0, 1.01, 0.5)
        tn = np.arange(near_px[0], near_px[1] + 1e-9, 0.5)
        tf = np.arange(far_px[0], max(min(far_px[1], length), far_px[0] + 1.0) + 1e-9, 1.0)
        en = edge_energy(grad, X + tn[:, None, None] * v + off[None, :, None] * n, n).max(axis=1)
        ef = edge_energy(grad, X + tf[:, None, None] * v + off[None, :, None] * n, n).max(axis=1)
        if np.min(ndimage.uniform_filter1d(en, 3)) < min_ratio * np.median(ef):
            return False
    return True


def measure_in_image(image, x0, y0, dirs, radius_px, *, settings: MeasureSettings | None = None,
                     convex: bool = True) -> Measurement:
    """Measure one corner predicted at (x0, y0) with image edge directions dirs (2, 2) in an image (H, W[, C]): an
    array, or anything with its ``shape`` whose 2-d slices give arrays (a frame read by windows).

    ``convex``: the roof's interior angle at the corner is below 180 deg (else re-entrant).
    """
    s = settings or MeasureSettings()
    H, W = image.shape[:2]  # an array or a frame read by windows (geom.images.FrameWindows): only the chip is read
    h = int(np.ceil(radius_px + s.edge_len_px + 4))
    nan = float("nan")
    margin = radius_px + 3
    if not (np.isfinite(x0) and np.isfinite(y0)) or x0 < margin or y0 < margin or x0 > W - 1 - margin or y0 > H - 1 - margin:
        return Measurement(nan, nan, False, "outside_frame")
    cs, rs = max(int(round(x0)) - h, 0), max(int(round(y0)) - h, 0)
    chip = np.atleast_3d(image[rs : int(round(y0)) + h + 1, cs : int(round(x0)) + h + 1])
    off = np.array([cs, rs], float)
    pred = np.array([x0, y0]) - off
    grad = gradients(chip)
    cands = junction_candidates(grad, pred, dirs, radius_px, s)
    cands = [c for c in cands if c[1] >= s.min_contrast]
    if not cands:
        return Measurement(nan, nan, False, "no_edges")
    best = None
    for score, contrast, X, legs in cands[:3]:
        legs = [(v, leg_length_px(grad, X, v, s.edge_len_px)) for v, _ in legs]
        X = innermost_edge(grad, X, legs, pred, radius_px=radius_px, convex=convex)
        legs = [(v, leg_length_px(grad, X, v, s.edge_len_px)) for v, _ in legs]
        ref = refine_corner(grad, X, legs, s)
        if ref is not None:
            best = (score, ref, legs)
            break
    if best is None:
        return Measurement(nan, nan, False, "poor_edge_fit")
    score, (X, rms, support), legs = best
    Xi = X + off
    if not junction_visible(grad, X, legs):
        return Measurement(float(Xi[0]), float(Xi[1]), False, "occluded", rms, support, float(np.hypot(*(Xi - [x0, y0]))))
    shift = float(np.hypot(*(Xi - [x0, y0])))
    rivals = [c for c in cands if np.hypot(*(c[2] - X)) > s.ambiguity_dist_px and c[0] > s.ambiguity_ratio * score]
    if rivals:
        return Measurement(float(Xi[0]), float(Xi[1]), False, "ambiguous", rms, support, shift)
    if rms > s.max_fit_rms_px or np.hypot(*(X - pred)) > radius_px:
        return Measurement(float(Xi[0]), float(Xi[1]), False, "poor_edge_fit", rms, support, shift)
    return Measurement(float(Xi[0]), float(Xi[1]), True, "", rms, support, shift)
