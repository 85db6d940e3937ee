"""Patch displacements between two orthoimages on the same grid (DOM checks and seam misalignment).

Each textured square patch of the first image is located in the second by normalised cross-correlation
(``cv2.matchTemplate``, TM_CCOEFF_NORMED) within a search radius, to the whole pixel; a parabola through the peak in x
and y (``parabola_peak``) gives a first sub-pixel estimate, and ``refine_shift`` from there the shift maximising the
NCC with the second image resampled (bicubic) between whole pixels, by Gauss-Newton. A patch whose refinement fails
(it leaves the search, moves farther than ``MAX_REFINE_PX`` or does not settle) is not measured but counted
(``unsettled_*``): its NCC has no single peak near the parabolas' (a periodic texture, crop rows: the parabolas read
0.7-1.3 px off on every one), and their estimate is no better. The displacement is the first image's position minus
the second's, in pixels (x right, y down) and in metres (dE east, dN north).

Why not the parabolas alone: on a patch dominated by thin lines (a road's edge lines at a slant) the NCC surface is a
narrow ridge along the lines; its samples at whole-pixel shifts are highest where the ridge passes nearest a whole
pixel, not where the patch fits best, and the parabolas across x and y at that sample keep it: a cross-road shift of
a fifth of a pixel was read as up to a pixel along the road (the demo DOM's band of 0.6-1 GSD displacements along its
north-south roads, docs/true-ortho.md "The DOM check's sub-pixel peak on roads").

The aperture problem: a patch whose texture runs in one direction only (a road's edges, a field's furrows) fixes the
shift across that direction but not along it: the NCC peak slides along the road. Such patches are left out before
matching by the second image's (the reference's) gradient structure tensor: the ratio of its small to its large
eigenvalue below ``MIN_TEXTURE_RATIO`` (``texture_ratio``); they are counted (``one_direction_*``), not measured.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import cv2
import numpy as np

from aerotri.core.errors import InputError


@dataclasses.dataclass
class PatchDisplacements:
    row_px: np.ndarray  # patch centre rows in the DOM grid
    col_px: np.ndarray
    dx_px: np.ndarray  # DOM minus reference, x right
    dy_px: np.ndarray  # DOM minus reference, y down
    ncc: np.ndarray
    res_m: float
    # centres (rows, cols in the DOM grid) of the patches left out as textured in one direction only
    # (``MIN_TEXTURE_RATIO``): counted, not measured
    one_direction_row_px: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    one_direction_col_px: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    # +1, or -1 where the DOM's x runs west / its y south (a south-oriented grid: ``map_axis_signs``)
    east_sign: float = 1.0
    north_sign: float = 1.0
    # centres of the patches whose sub-pixel refinement failed (``refine_shift`` None): counted, not measured
    unsettled_row_px: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    unsettled_col_px: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    # centres of the textured patches (above the texture floor) that found no match: NCC peak below ``min_ncc`` or on
    # the edge of the +-search_px search (the two images off by more than it, or not the same ground there):
    # counted, not measured
    unmatched_row_px: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    unmatched_col_px: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    @property
    def de_m(self):
        return self.east_sign * self.dx_px * self.res_m

    @property
    def dn_m(self):
        return -self.north_sign * self.dy_px * self.res_m

    def select(self, keep) -> "PatchDisplacements":
        keep = np.asarray(keep, bool)
        return PatchDisplacements(self.row_px[keep], self.col_px[keep], self.dx_px[keep], self.dy_px[keep],
                                  self.ncc[keep], self.res_m, self.one_direction_row_px, self.one_direction_col_px,
                                  self.east_sign, self.north_sign, self.unsettled_row_px, self.unsettled_col_px,
                                  self.unmatched_row_px, self.unmatched_col_px)

    def __len__(self):
        return len(self.dx_px)


MIN_PATCH_PX = 8  # smaller patches carry too little texture for a correlation peak

# Smallest ratio of the small to the large eigenvalue of a reference patch's gradient structure tensor for the
# patch to be matched (0: texture in one direction only, 1: the same in every direction). Chosen on the DMC 2x4
# block (cccbc0a run, its 136,098 open-ground 48 px patches against the truth): RMS 0.888 -> 0.727 / 0.390 / 0.354
# GSD at 0.05 / 0.1 / 0.2, share above 3 GSD 3.11 -> 1.89 / 0.06 / 0.01 % (0.1 the knee, 13.1 % left out); scored
# on the 2x6: 0.889 -> 0.335 GSD, 13.1 % left out (bench/eval_dom_aperture.py, dmc_dom_measure.json "aperture_test")
MIN_TEXTURE_RATIO = 0.1


def to_gray(image: np.ndarray) -> np.ndarray:
    """(rows, cols[, bands]) -> float32 luminance (mean of the first three bands)."""
    a = np.asarray(image)
    if a.ndim == 3:  # one band: itself (its mean; a DMC DOM's block in 2 ms, not 20-70)
        a = a[:, :, 0] if a.shape[2] == 1 else a[:, :, :3].astype(np.float32).mean(axis=2)
    return a.astype(np.float32)


def texture_ratio(patch: np.ndarray) -> float:
    """Ratio (0 .. 1) of the small to the large eigenvalue of the patch's gradient structure tensor (3x3 Sobel
    gradients summed over the patch): 0 for texture in one direction only (stripes), 1 for the same texture
    strength in every direction; 0 for a flat patch."""
    p = np.asarray(patch, np.float32)
    gx, gy = cv2.Sobel(p, cv2.CV_32F, 1, 0), cv2.Sobel(p, cv2.CV_32F, 0, 1)
    a, b, c = float(np.sum(gx * gx, dtype=np.float64)), float(np.sum(gx * gy, dtype=np.float64)), \
        float(np.sum(gy * gy, dtype=np.float64))
    # eigenvalues of [[a, b], [b, c]] in closed form
    half_trace, root = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    large = half_trace + root
    return max(half_trace - root, 0.0) / large if large > 0 else 0.0


# Farthest the sub-pixel refinement may move from the parabolas' estimate (px): a slanted ridge's whole-pixel peak lies
# up to 1/(2 tan a) px along it from the best fit (a the ridge's angle to the pixel axis: 2.8 px at 10 degrees);
# farther, or not settled in REFINE_ITERATIONS (a ridge converges slowly along itself: the demo's reference against
# itself moved half a pixel both ways, 80 of 1,418 patches unsettled in 10 iterations, 4 in 20, none in 40), the
# patch is not measured (``match_patches``). Settled: a step below REFINE_TOLERANCE_PX (0.002 px before review 20:
# 0.29-0.34 -> 0.22-0.24 ms a patch on the demo's check, every shift within 0.0065 px of it, the same errors on
# known shifts)
MAX_REFINE_PX = 3.0
REFINE_ITERATIONS = 40
REFINE_TOLERANCE_PX = 0.01


@functools.lru_cache(maxsize=8)
def _refine_grid(n0: int, n1: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns (float32) of a template's grid with one pixel around it (``refine_shift``'s remap maps, minus
    the shift); cached by shape: the check's patches share one (read only)."""
    rows, cols = np.mgrid[-1:n0 + 1, -1:n1 + 1].astype(np.float32)
    rows.flags.writeable = cols.flags.writeable = False
    return rows, cols


def refine_shift(template: np.ndarray, window: np.ndarray, x0: float, y0: float,
                 max_move_px: float = MAX_REFINE_PX, iterations: int = REFINE_ITERATIONS) -> tuple[float, float] | None:
    """Sub-pixel position (x, y: column and row of its top-left pixel in ``window``) of ``template`` where their
    normalised cross-correlation is approximately highest, from (``x0``, ``y0``) (the parabolas' estimate at the
    whole-pixel peak): Gauss-Newton on the difference of the zero-mean, unit-variance template and window, the window
    resampled bicubically at the shift and its central differences the Jacobian (the derivative of the window's
    normalisation ignored: the fixed point is near the NCC maximum, not exactly on it). None when it leaves the window
    (a peak on the search's edge), moves more than ``max_move_px`` from the start, or does not settle (a step below
    ``REFINE_TOLERANCE_PX``) in ``iterations``. Each step in a dozen whole-array numpy calls (numpy's ``std``,
    ``stack``, ``det`` and ``solve`` on the 2 x 2 normal equations cost 0.1 ms a step: 0.22 -> 0.13 ms a patch on the
    demo, the same shifts to 1e-14 px)."""
    t = np.asarray(template, np.float32)
    w = np.asarray(window, np.float32)
    n0, n1 = t.shape
    s = float(t.std())
    if s <= 0:
        return None
    tn = (t.astype(np.float64) - float(t.mean())) / s
    # one pixel around the template's grid: the central differences at its border
    rows, cols = _refine_grid(n0, n1)
    m = n0 * n1
    jac = np.empty((2, n0, n1))  # the Jacobian's two columns (x, y), zero-mean, over the window's deviation
    flat = jac.reshape(2, m)
    x, y = float(x0), float(y0)
    x_max, y_max = w.shape[1] - n1, w.shape[0] - n0
    for _ in range(iterations):
        warped = cv2.remap(w, cols + np.float32(x), rows + np.float32(y), cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        centred = warped[1:-1, 1:-1] - warped[1:-1, 1:-1].sum() / m
        sd = math.sqrt(float((centred * centred).sum()) / m)
        if sd <= 0:
            return None
        np.subtract(warped[1:-1, 2:], warped[1:-1, :-2], out=jac[0])
        np.subtract(warped[2:, 1:-1], warped[:-2, 1:-1], out=jac[1])
        jac *= 0.5
        jac -= (jac.sum(axis=(1, 2)) / m)[:, None, None]
        jac /= sd
        normal = flat @ flat.T
        rhs = flat @ (tn - centred / sd).ravel()
        a00, a01, a11 = float(normal[0, 0]), float(normal[0, 1]), float(normal[1, 1])
        det = a00 * a11 - a01 * a01
        if det <= 1e-12 * (a00 + a11) ** 2:  # singular: texture in one direction, or none
            return None
        step_x = (a11 * float(rhs[0]) - a01 * float(rhs[1])) / det
        step_y = (a00 * float(rhs[1]) - a01 * float(rhs[0])) / det
        x, y = x + step_x, y + step_y
        if not (0.0 < x < x_max and 0.0 < y < y_max) or math.hypot(x - x0, y - y0) > max_move_px:
            return None
        if math.hypot(step_x, step_y) < REFINE_TOLERANCE_PX:
            return x, y
    return None


def parabola_peak(c_m, c_0, c_p):
    """Offset (-0.5 .. 0.5) of the top of the parabola through three neighbouring correlation values; 0 when not
    a maximum."""
    den = c_m - 2.0 * c_0 + c_p
    return 0.0 if den >= 0 else float(np.clip(0.5 * (c_m - c_p) / den, -0.5, 0.5))


def match_patches(dom, reference, dom_valid=None, reference_valid=None, *, res_m: float = 1.0, patch_px: int = 48,
                  step_px: int = 48, search_px: int = 6, min_ncc: float = 0.7, min_std: float = 4.0,
                  keep=None, min_texture_ratio: float = MIN_TEXTURE_RATIO) -> PatchDisplacements:
    """Displacements of DOM patches against a reference on the same grid (see module doc).

    ``keep``: optional boolean raster; a patch is used only if all its pixels are True (e.g. ground
    from an nDSM). Patches with low texture (std < ``min_std`` grey levels), invalid pixels, a peak on
    the search border or a peak NCC below ``min_ncc`` are discarded; those whose reference patch (same place) has
    texture in one direction only (``texture_ratio`` < ``min_texture_ratio``; 0: none left out) are left out and
    their centres returned in ``one_direction_row_px``/``_col_px``; those whose sub-pixel refinement fails
    (``refine_shift`` None) likewise in ``unsettled_row_px``/``_col_px``, and the textured ones whose peak is below
    ``min_ncc`` or on the search border in ``unmatched_row_px``/``_col_px``.
    """
    g = to_gray(dom)
    ref = to_gray(reference)
    if g.shape != ref.shape:
        raise InputError(f"DOM ({g.shape}) and reference ({ref.shape}) are not on the same grid")
    ok = np.ones(g.shape, bool) if dom_valid is None else np.asarray(dom_valid, bool)
    if reference_valid is not None:
        ok = ok & np.asarray(reference_valid, bool)
    if keep is not None:
        ok = ok & np.asarray(keep, bool)
    # integral image of invalid pixels: patch validity in O(1) (int32: a block's counts fit; a third of int64's time)
    bad = np.zeros((ok.shape[0] + 1, ok.shape[1] + 1), np.int64 if ok.size >= 2 ** 31 else np.int32)
    np.cumsum(np.cumsum(~ok, axis=0, dtype=bad.dtype), axis=1, out=bad[1:, 1:])
    H, W = g.shape
    P, S = patch_px, search_px
    rows, cols, dxs, dys, nccs, one_rows, one_cols, unsettled_rows, unsettled_cols = [], [], [], [], [], [], [], [], []
    unmatched_rows, unmatched_cols = [], []
    for r in range(S, H - P - S + 1, step_px):
        for c in range(S, W - P - S + 1, step_px):
            r0, r1, c0, c1 = r - S, r + P + S, c - S, c + P + S
            if bad[r1, c1] - bad[r0, c1] - bad[r1, c0] + bad[r0, c0]:
                continue
            t = g[r:r + P, c:c + P]
            if t.std() < min_std:
                continue
            if min_texture_ratio > 0 and texture_ratio(ref[r:r + P, c:c + P]) < min_texture_ratio:
                one_rows.append(r + (P - 1) / 2.0)
                one_cols.append(c + (P - 1) / 2.0)
                continue
            cc = cv2.matchTemplate(ref[r0:r1, c0:c1], t, cv2.TM_CCOEFF_NORMED)
            _, peak, _, (px, py) = cv2.minMaxLoc(cc)
            if peak < min_ncc or px in (0, cc.shape[1] - 1) or py in (0, cc.shape[0] - 1):
                unmatched_rows.append(r + (P - 1) / 2.0)
                unmatched_cols.append(c + (P - 1) / 2.0)
                continue
            # the parabolas at the whole-pixel peak (module doc: biased along a slanted ridge), then the NCC's peak
            sx = parabola_peak(cc[py, px - 1], cc[py, px], cc[py, px + 1])
            sy = parabola_peak(cc[py - 1, px], cc[py, px], cc[py + 1, px])
            refined = refine_shift(t, ref[r0:r1, c0:c1], px + sx, py + sy)
            if refined is None:  # no single NCC peak near the whole-pixel one (module doc): counted, not measured
                unsettled_rows.append(r + (P - 1) / 2.0)
                unsettled_cols.append(c + (P - 1) / 2.0)
                continue
            sx, sy = refined[0] - px, refined[1] - py
            # the DOM patch at (r, c) is found in the reference at (r + py - S, c + px - S):
            # the DOM shows that content displaced by minus that offset
            rows.append(r + (P - 1) / 2.0)
            cols.append(c + (P - 1) / 2.0)
            dxs.append(-(px + sx - S))
            dys.append(-(py + sy - S))
            nccs.append(peak)
    a = lambda v: np.asarray(v, dtype=float)
    return PatchDisplacements(a(rows), a(cols), a(dxs), a(dys), a(nccs), float(res_m), a(one_rows), a(one_cols),
                              unsettled_row_px=a(unsettled_rows), unsettled_col_px=a(unsettled_cols),
                              unmatched_row_px=a(unmatched_rows), unmatched_col_px=a(unmatched_cols))
