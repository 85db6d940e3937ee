"""The DOM check's kernels made faster (issue 41, branch domcheck-speed) give the numbers they gave: the sub-pixel
refinement in whole-array steps against its form before (numpy's std, stack, det and solve each step), and the
masked NCC by OpenCV's DFT, each spectrum once, against numpy's FFT of each template for every sum, on a small
synthetic pair with known shifts."""

from __future__ import annotations

import cv2
import numpy as np

from ortho.check import masked_ncc_surface
import math

from ortho.patches import REFINE_TOLERANCE_PX, refine_shift


def textured_pair(shift_x_px: float, shift_y_px: float, size: int = 96, seed: int = 0):
    """Ground texture (blurred noise, float32 grey 60-200) and the same moved ``shift_x_px`` right and
    ``shift_y_px`` down (bicubic)."""
    rng = np.random.default_rng(seed)
    ground = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), 1.5)
    ground = 130.0 + 70.0 * ground / np.abs(ground).max()
    y, x = np.mgrid[0:size, 0:size].astype(np.float32)
    moved = cv2.remap(ground, x - np.float32(shift_x_px), y - np.float32(shift_y_px), cv2.INTER_CUBIC,
                      borderMode=cv2.BORDER_REFLECT)
    return ground, moved


def refine_shift_as_it_was(template, window, x0, y0, max_move_px=3.0, iterations=40):
    """``refine_shift`` before branch domcheck-speed: numpy's std, stack, det and solve each step."""
    t = np.asarray(template, np.float32)
    w = np.asarray(window, np.float32)
    n0, n1 = t.shape
    s = float(t.std())
    if s <= 0:
        return None
    tn = (t.astype(np.float64) - float(t.mean())) / s
    rows, cols = np.mgrid[-1:n0 + 1, -1:n1 + 1].astype(np.float32)
    x, y = float(x0), float(y0)
    x_max, y_max = w.shape[1] - n1, w.shape[0] - n0
    for _ in range(iterations):
        warped = cv2.remap(w, cols + np.float32(x), rows + np.float32(y), cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        gx = 0.5 * (warped[1:-1, 2:] - warped[1:-1, :-2])
        gy = 0.5 * (warped[2:, 1:-1] - warped[:-2, 1:-1])
        core = warped[1:-1, 1:-1]
        sd = core.std()
        if sd <= 0:
            return None
        jac = np.stack([(gx - gx.mean()).ravel(), (gy - gy.mean()).ravel()], axis=1) / sd
        normal = jac.T @ jac
        if np.linalg.det(normal) <= 1e-12 * float(np.trace(normal)) ** 2:
            return None
        step = np.linalg.solve(normal, jac.T @ (tn - (core - core.mean()) / sd).ravel())
        x, y = x + float(step[0]), y + float(step[1])
        if not (0.0 < x < x_max and 0.0 < y < y_max) or math.hypot(x - x0, y - y0) > max_move_px:
            return None
        if math.hypot(step[0], step[1]) < REFINE_TOLERANCE_PX:
            return x, y
    return None


def test_refine_shift_gives_the_shifts_it_gave():
    found = 0
    for k, (sx, sy) in enumerate([(0.3, -0.4), (-0.45, 0.2), (0.0, 0.0), (1.25, -0.7), (0.1, 0.9)]):
        ref, dom = textured_pair(sx, sy, seed=k)
        for r, c in [(20, 20), (24, 30), (30, 18)]:
            t, window = dom[r:r + 40, c:c + 40], ref[r - 6:r + 46, c - 6:c + 46]
            for x0, y0, move in [(6.0 - sx, 6.0 - sy, 3.0), (6.0, 6.0, 3.0), (6.0, 6.0, 0.05), (0.5, 0.5, 3.0)]:
                new = refine_shift(t, window, x0, y0, max_move_px=move)
                old = refine_shift_as_it_was(t, window, x0, y0, max_move_px=move)
                assert (new is None) == (old is None)
                if new is not None:
                    assert np.allclose(new, old, rtol=0, atol=1e-9)
                    if (x0, move) == (6.0 - sx, 3.0):  # from the known shift: it stays there
                        assert np.allclose(new, (6.0 - sx, 6.0 - sy), atol=0.05)
                        found += 1
    assert found >= 12
    assert refine_shift(np.full((40, 40), 7.0, np.float32), window, 6.0, 6.0) is None  # nothing to fit


def masked_ncc_surface_per_sum(dom, dom_weight, reference, reference_valid, search_px, min_overlap=0.5):
    """``masked_ncc_surface`` as it was: numpy's FFT, each template transformed for every sum."""
    n0, n1 = dom.shape
    S = int(search_px)
    N0, N1 = n0 + 2 * S, n1 + 2 * S
    w = np.where(np.isfinite(dom), np.asarray(dom_weight, np.float64), 0.0)
    v = (np.asarray(reference_valid, bool) & np.isfinite(reference)).astype(np.float64)
    t = np.where(w > 0, dom, 0.0).astype(np.float64)
    t = np.where(w > 0, t - (w * t).sum() / w.sum(), 0.0)
    s = np.where(v > 0, reference, 0.0).astype(np.float64)
    s = np.where(v > 0, s - (v * s).sum() / v.sum(), 0.0)
    rfft, irfft = np.fft.rfft2, np.fft.irfft2
    fv, fs, fss = rfft(v), rfft(s), rfft(s * s)

    def corr(f_ref, tmpl):
        return irfft(f_ref * np.conj(rfft(tmpl, (N0, N1))), (N0, N1))[:2 * S + 1, :2 * S + 1]

    sw, st, stt = corr(fv, w), corr(fv, w * t), corr(fv, w * t * t)
    ss, sss, sts = corr(fs, w), corr(fss, w), corr(fs, w * t)
    with np.errstate(invalid="ignore", divide="ignore"):
        var_t, var_s = stt - st * st / sw, sss - ss * ss / sw
        ncc = (sts - st * ss / sw) / np.sqrt(var_t * var_s)
    scale = max(float(np.abs(stt).max()), float(np.abs(sss).max()), 1e-300)
    ok = (sw >= min_overlap * w.sum()) & (var_t > 1e-9 * scale) & (var_s > 1e-9 * scale) & np.isfinite(ncc)
    return np.where(ok, ncc, -1.0) if ok.any() else None


def test_masked_ncc_surface_by_opencvs_dft_gives_numpys_surface():
    ref, dom = textured_pair(2.0, -3.0)
    n, S = 32, 16
    rng = np.random.default_rng(5)
    win = np.outer(np.hanning(n), np.hanning(n))
    patch, reference = dom[32:32 + n, 32:32 + n], ref[32 - S:32 + n + S, 32 - S:32 + n + S]
    valid, reference_valid = rng.random((n, n)) > 0.2, rng.random(reference.shape) > 0.05
    new = masked_ncc_surface(np.where(valid, patch, 0.0), win * valid, reference, reference_valid, S)
    old = masked_ncc_surface_per_sum(np.where(valid, patch, 0.0), win * valid, reference, reference_valid, S)
    assert np.abs(new - old).max() < 1e-12  # OpenCV's DFT for numpy's FFT: the same NCC to rounding
    py, px = np.unravel_index(int(np.argmax(new)), new.shape)
    assert (px - S, py - S) == (-2, 3)  # the patch found 2 px left and 3 px up in the reference
