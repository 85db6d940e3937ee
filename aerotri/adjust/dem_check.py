"""The adjusted tie points against a DEM: a systematic height offset the adjustment cannot see by itself.

Whenever a DEM is at hand (the surface control's, or a DEM given only to check against: ``check_dem``), the
tie points on the ground (inside the DEM; with an nDSM, not on objects; not rejected by the surface
control's gate) are compared with it: count, median of (tie point height - DEM height), robust spread
(NMAD = 1.4826 median |d - median|). The median is a systematic offset when it exceeds
``OFFSET_SIGMAS`` times its own precision

    sigma_offset^2 = sigma_height^2 + sigma_DEM^2 + (1.2533 NMAD)^2 / n

with ``sigma_height`` the a-posteriori sigma of the block's height mode (``geometry_modes``), ``sigma_DEM``
the DEM's stated sigma (``surface_sigma_m``; taken as wholly systematic: a DEM's height datum does not
average out over its cells) and the last term the median's own sampling precision. Such an offset fails
the solution: the heights of the block and of the DEM disagree by more than either can be wrong.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from aerotri.adjust.surface import SurfaceControl

OFFSET_SIGMAS = 3.0
MIN_POINTS = 10  # fewer tie points on the DEM: reported, not tested


@dataclasses.dataclass(frozen=True)
class DemCheck:
    """Tie points against a DEM (metres; residual = tie point height - DEM height)."""

    dem: str
    role: str  # "surface control" (the DEM held the tie points) or "check" (not used in the solve)
    n: int
    median_m: float | None
    nmad_m: float | None
    dem_sigma_m: float
    height_sigma_m: float | None  # a-posteriori sigma of the block's height mode
    sigma_offset_m: float | None  # the median's precision (module docstring)
    limit_m: float | None  # OFFSET_SIGMAS x sigma_offset_m
    failed: bool

    @property
    def tested(self) -> bool:
        return self.limit_m is not None

    def summary(self) -> str:
        """One line: the numbers and the verdict."""
        if self.n == 0:
            return f"tie points vs DEM ({self.role}): no tie point on the ground inside the DEM"
        s = (f"tie points - DEM ({self.role}): median {self.median_m:+.3f} m, NMAD {self.nmad_m:.3f} m, "
             f"{self.n} points")
        if not self.tested:
            return s + f" (fewer than {MIN_POINTS}: not tested)"
        return s + (f"; {OFFSET_SIGMAS:g} sigma of the offset {self.limit_m:.3f} m (DEM {self.dem_sigma_m:.3f} m, "
                    f"block height {self.height_sigma_m:.3f} m): " + ("FAILED" if self.failed else "passed"))


def tie_dem_check(surface: SurfaceControl, points_local: np.ndarray, ground_tie: np.ndarray, dem: str, role: str,
                  height_sigma_m: float | None) -> DemCheck:
    """``DemCheck`` of the points ``ground_tie`` (bool mask over ``points_local``, the local frame) against the
    DEM of ``surface`` (its stated sigma ``sigma_m``)."""
    e, _, _ = surface.observe(np.asarray(points_local, dtype=float), jacobian=False)
    d = e[np.asarray(ground_tie, dtype=bool) & np.isfinite(e)]
    n = int(len(d))
    s_dem = float(surface.sigma_m)
    if n == 0:
        return DemCheck(dem, role, 0, None, None, s_dem, height_sigma_m, None, None, False)
    med = float(np.median(d))
    nmad = float(1.4826 * np.median(np.abs(d - med)))
    if n < MIN_POINTS:
        return DemCheck(dem, role, n, med, nmad, s_dem, height_sigma_m, None, None, False)
    s_h = height_sigma_m if height_sigma_m is not None and math.isfinite(height_sigma_m) else 0.0
    sigma = math.sqrt(s_h**2 + s_dem**2 + (1.2533 * nmad) ** 2 / n)
    limit = OFFSET_SIGMAS * sigma
    return DemCheck(dem, role, n, med, nmad, s_dem, height_sigma_m, sigma, limit, bool(abs(med) > limit))
