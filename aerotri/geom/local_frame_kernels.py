"""The numba kernels of ``aerotri.geom.local_frame`` (``earth_dz``, ``MapAnchors``' Taylor step), in a module of their own
so that importing ``local_frame`` does not import numba (0.3 CPU-s: ``ortho mosaic`` imports it through
``ortho.rectify`` and never calls them)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def earth_dz(dx, dy, dz, inv_radius):
    """The height offset that puts a map offset (dx, dy, dz) from the projection centre where the camera sees it
    through ``CameraOnEarth.M``: the earth's curvature and the scale's change with height (1 / (1 + dz / R) as
    1 - dz / R: 3e-8 off at 1 km). Exactly dz when ``inv_radius`` is 0 (a Cartesian CRS)."""
    return (dz - (dx * dx + dy * dy) * (0.5 * inv_radius)) * (1.0 - dz * inv_radius)


@numba.njit(cache=True)
def _taylor(p0, m0, J0, idx, p, *, tol, m, stale):
    """``m = m0 + J0 (p - p0)`` at each point's slot, or ``stale`` (a finite point farther than ``tol`` from its
    anchor, or without one); NaN for a non-finite point."""
    for n in range(len(idx)):
        q = idx[n]
        d0, d1, d2 = p[n, 0] - p0[q, 0], p[n, 1] - p0[q, 1], p[n, 2] - p0[q, 2]
        if not (abs(d0) <= tol and abs(d1) <= tol and abs(d2) <= tol):
            m[n, 0] = m[n, 1] = m[n, 2] = np.nan
            stale[n] = np.isfinite(p[n, 0]) and np.isfinite(p[n, 1]) and np.isfinite(p[n, 2])
            continue
        for r in range(3):
            m[n, r] = m0[q, r] + J0[q, r, 0] * d0 + J0[q, r, 1] * d1 + J0[q, r, 2] * d2
