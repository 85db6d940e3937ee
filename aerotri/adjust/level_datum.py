"""The level datum of a block whose control has no measured heights and no GNSS (nor a DEM).

Plan control points fix 4 of the 7 datum parameters: the shift in plan, the scale and the rotation about the
vertical. Height and the two tilts are left; they rest on an assumption, stated in the report:

- during the adjustment, every plan-only control point carries a pseudo height (its height in the image model,
  ``aerotri.adjust.relative``, or intersected from the approximate orientations) with a loose standard deviation
  (``HEIGHT_DATUM_SHARE`` of the flying height): enough to make the normal equations regular and the iteration
  stable, not a measurement;
- after it, the solution is **levelled**: turned about its tie points' median so that the robust mean plane of the
  tie points is horizontal (the ground under a small block taken as level on average), and shifted in height so
  that the plan control points' median height stays where it was (height 0 = their median ground when the image
  model gave the start). A similarity leaves every image residual as it is; it only undoes the tilt that metre-level
  plan errors pull into the block through the cosine of the tilt (on the Coal Oil Point kite block 8 degrees).

The control points stay horizontal: no height residual is reported against heights nobody measured.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.adjust import graph as G
from aerotri.adjust.relative import level_normal, rotation_onto

HEIGHT_DATUM_SHARE = 0.1  # sigma of the pseudo heights during the adjustment, as a share of the flying height


@dataclasses.dataclass(frozen=True)
class LevelDatum:
    """The plan-only control points (control indices) whose pseudo heights the adjustment carries."""

    plan: np.ndarray  # (n,) control indices
    sigma_z_m: float
    note: str


def height_datum(block: G.Block, state0: G.State, J_local_from_map, sigma_m, given_z: dict | None = None
                 ) -> LevelDatum | None:
    """Pseudo heights for the plan-only control points of a block without GNSS, DEM or 3 height control points
    (see the module docstring); None when the datum has heights. ``given_z``: control index -> local height of
    the point in the image model (else intersected from ``state0``; a single ray: the median of the others').
    ``J_local_from_map`` (C, 3, 3; the rotation from the grid axes to ENU, metres to metres) and ``sigma_m``
    (C, 3; metres) build the covariances. Changes ``block`` in place."""
    if block.gnss_local is not None or block.surface is not None or not len(block.control_point):
        return None
    rows = block.control_rows
    plan = np.flatnonzero(rows == 2)
    if int(np.sum(rows != 2)) >= 3 or len(plan) == 0:
        return None
    rays = np.bincount(block.obs_point, minlength=block.n_points)[block.control_point]
    z = state0.points[block.control_point, 2].copy()
    for c, zc in (given_z or {}).items():
        z[c] = zc
    multi = plan[(rays[plan] >= 2) & np.isfinite(z[plan])]
    if len(multi) == 0:
        return None
    z_plan = np.where(np.isin(plan, multi), z[plan], np.median(z[multi]))
    above_m = float(np.median(state0.centre[:, 2]) - np.median(z_plan))
    sigma_z = HEIGHT_DATUM_SHARE * abs(above_m)
    for c, zc in zip(plan, z_plan):
        block.control_local[c, 2] = zc
        sig = np.array([sigma_m[c][0], sigma_m[c][1], sigma_z])
        block.control_cov_local[c] = J_local_from_map[c] @ np.diag(sig**2) @ J_local_from_map[c].T
    note = (f"heights not measured: {len(plan)} plan-only control points and no GNSS; during the adjustment they carry "
            f"pseudo heights from the approximate orientations (sigma {sigma_z:.2f} m, {HEIGHT_DATUM_SHARE:g} of the "
            f"{abs(above_m):.1f} m flying height above them), no measurement")
    return LevelDatum(plan, sigma_z, note)


def level_result(level: LevelDatum, block: G.Block, result) -> str:
    """Level an adjustment's solution in place (``result.state``, ``result.point_cov``): its tie points' robust mean
    plane made horizontal, the plan control points' median height kept. Returns the statement for the report."""
    st = result.state
    active = np.zeros(block.n_points, dtype=bool)
    active[block.obs_point[result.obs_active]] = True
    active[block.control_point] = False
    pts = st.points[active]
    n = level_normal(pts, st.centre)
    L = rotation_onto(n, np.array([0.0, 0.0, 1.0]))
    tilt_deg = float(np.degrees(np.arccos(np.clip(n[2], -1.0, 1.0))))
    pivot = np.median(pts, axis=0) if len(pts) else st.centre.mean(axis=0)
    ctrl = block.control_point[level.plan]
    before = float(np.median(st.points[ctrl, 2]))

    def move(x):
        return (np.asarray(x) - pivot) @ L.T + pivot

    dz = before - float(np.median(move(st.points[ctrl])[:, 2]))
    st.centre = move(st.centre) + [0.0, 0.0, dz]
    st.points = move(st.points) + [0.0, 0.0, dz]
    st.R_cv = L @ st.R_cv  # the pose covariances are in the camera frame: unchanged
    if result.point_cov is not None:
        result.point_cov = L @ result.point_cov @ L.T
    block.control_local[level.plan, 2] = st.points[ctrl, 2]
    return (f"levelled after the adjustment: the tie points' mean plane made horizontal (it was tilted "
            f"{tilt_deg:.2f} deg; the ground under the block taken as level on average), the plan control points' "
            "median height kept; the image residuals do not change")
