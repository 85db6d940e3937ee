"""The accuracy formulas of the standards (ASPRS 2023, USGS LBS, the Chinese AT specifications), in one place.

Conventions: errors are product minus reference, in metres; an RMSE is sqrt(mean(d^2)) (no mean removed);
RMSE_H is the radial horizontal RMSE sqrt(RMSE_x^2 + RMSE_y^2); a class is named by the RMSE it allows
(cm in the ASPRS names, metres here). Where each rule comes from: aerotri/qa/standards/*.toml and
docs/standards.md (rules marked there as unconfirmed are used as such and reported as such).
"""

from __future__ import annotations

import math

import numpy as np

NSSDA_VERTICAL_95 = 1.9600  # 95 % confidence of a normal height error: 1.96 RMSE_V (NSSDA; LBS 2020 rev. A quotes it)


def rmse(d) -> float:
    """Root mean square of errors ``d`` (m): sqrt(mean(d^2)); NaN for none."""
    d = np.asarray(d, dtype=float)
    return float(np.sqrt(np.mean(d * d))) if d.size else math.nan


def rmse_h(rmse_x: float, rmse_y: float) -> float:
    """Radial horizontal RMSE (m) from the per-axis RMSEs: sqrt(RMSE_x^2 + RMSE_y^2)."""
    return math.hypot(rmse_x, rmse_y)


def rmse_h_of_points(dx, dy) -> float:
    """Radial horizontal RMSE (m) of per-point plan errors (dx, dy)."""
    return rmse_h(rmse(dx), rmse(dy))


def with_checkpoint_accuracy(rmse_measured: float, rmse_checkpoints: float | None) -> float:
    """ASPRS 2023: the product's accuracy with the check points' own survey accuracy included,
    sqrt(RMSE_measured^2 + RMSE_checkpoints^2) (same component: both horizontal or both vertical). With
    the check points' accuracy unknown (None) the measured figure is returned unchanged."""
    if rmse_checkpoints is None:
        return rmse_measured
    return math.hypot(rmse_measured, rmse_checkpoints)


def checkpoint_rmse_h(sigma_xy_m: float | None) -> float | None:
    """Radial RMSE (m) of check points surveyed with a per-axis standard deviation ``sigma_xy_m``:
    sqrt(2) sigma (the same sigma in x and y)."""
    return None if sigma_xy_m is None else math.sqrt(2.0) * sigma_xy_m


def checkpoints_accurate_enough(rmse_checkpoints: float | None, class_m: float, factor: float) -> bool | None:
    """Are the check points ``factor`` times more accurate than the class tested (RMSE_checkpoints <=
    class / factor)? None when their accuracy is unknown."""
    if rmse_checkpoints is None:
        return None
    return rmse_checkpoints <= class_m / factor + 1e-12


def vva_p95(dz) -> float:
    """Vegetated vertical accuracy as the LBS states it: the 95th percentile of |dz| (m); NaN for none."""
    a = np.abs(np.asarray(dz, dtype=float))
    return float(np.percentile(a, 95.0)) if a.size else math.nan


def nssda_vertical_95(rmse_v: float) -> float:
    """Vertical accuracy at the 95 % confidence level (NSSDA, ASPRS Edition 1, LBS to 2020): 1.96 RMSE_V."""
    return NSSDA_VERTICAL_95 * rmse_v


def map_mm_to_ground_m(mm: float, scale: str | int) -> float:
    """A limit in millimetres on the map at ``scale`` ("1:2000" or 2000) as metres on the ground."""
    return mm * scale_denominator(scale) / 1000.0


def scale_denominator(scale: str | int) -> int:
    """2000 from "1:2000" (or 2000)."""
    if isinstance(scale, int):
        return scale
    text = str(scale).replace(" ", "")
    if not text.startswith("1:") or not text[2:].isdigit():
        raise ValueError(f"map scale {scale!r}: expected 1:N")
    return int(text[2:])


def finest_class(measured: float, ladder_m) -> float | None:
    """The finest (smallest) class of ``ladder_m`` (metres) that a measured RMSE meets (class >= measured);
    None when even the coarsest does not."""
    met = [c for c in sorted(ladder_m) if measured <= c + 1e-12]
    return met[0] if met else None


def anpd(first_returns: int, area_m2: float) -> float:
    """Aggregate nominal pulse density (first returns per m2) over ``area_m2``."""
    return first_returns / area_m2 if area_m2 > 0 else math.nan


def anps(density_per_m2: float) -> float:
    """Aggregate nominal pulse spacing (m) of a density: 1 / sqrt(density)."""
    return 1.0 / math.sqrt(density_per_m2) if density_per_m2 > 0 else math.nan
