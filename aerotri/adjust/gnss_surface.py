"""The GNSS heights against the surface control: a height-system mix-up the frames' tilts would absorb.

With GNSS positions held without a correction and a DEM (or roof planes) as surface control, the block's height is
given twice: by the GNSS heights, and by the tie points on the surface. Where the two disagree the adjustment need
not show it: the frames tilt against each other until the rays meet the surface again (a change of convergence moves
a model's depth), the GNSS residuals stay at millimetres and the tie points at the DEM. The NGI DMC trial (s95,
gnss.txt 30 m high: ellipsoidal heights in a project of EGM2008 heights) tilted its 4 frames by 0.1-0.2 deg, tie
points - DEM median -0.001 m ("passed"), GNSS residuals <= 5 mm, "Solution weak" naming the principal point, and
orthos 19 m RMS off.

The GNSS heights' common offset is added to the solution's normal equations (``height_datum.plane_normals``: its
Schur complement against every other unknown, one Gauss-Newton step) and judged against its formal sigma together
with the surface's stated sigma (taken as wholly systematic, as ``dem_check`` takes it): beyond ``OFFSET_SIGMAS`` of
that it is significant, and beyond the tolerance table's height limit too it fails the solution
(``DemCheck.gnss_beyond``; a simulated block's 0.2 m, significant at 1:2000, is a compromise the tie-point check
judges, not a height system). Linearised at the solution that absorbed it, the step falls short of a large offset
(20.8 m of the trial's 30): a significant one is measured again by one solve from there with the GNSS heights' offset
for the block free (``gnss_correction = "offset"``, the plan held), 25.0 m there (a fresh adjustment with that offset
free, ``[gnss] offset_sigma_z_m``, finds 30.9 m: the solve from the tilted frames stops short, the size is "about").
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from aerotri.adjust import graph as G
from aerotri.adjust.dem_check import OFFSET_SIGMAS  # as the tie-point check's: beyond it systematic, not noise
from aerotri.adjust.height_datum import beyond_correction, plane_normals
from aerotri.adjust.variance_components import gnss_rows

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class GnssSurfaceOffset:
    """The GNSS heights minus the block height the surface control gives (metres, up; positive: GNSS higher)."""

    offset_m: float  # the estimate: the free-offset solve's where the step was significant, else the step's
    sigma_m: float  # its formal standard deviation (a-posteriori, the images' and GNSS's noise)
    surface_sigma_m: float  # the surface's stated sigma, taken as systematic
    n_surface: int  # surface observations in the solve
    step_m: float  # the one-step estimate at the solution
    measured_free: bool = False  # offset_m from the solve with the offset free

    @property
    def limit_m(self) -> float:
        return OFFSET_SIGMAS * math.hypot(self.sigma_m, self.surface_sigma_m)

    @property
    def significant(self) -> bool:
        return math.isfinite(self.offset_m) and abs(self.offset_m) > self.limit_m


def gnss_surface_offset(block: G.Block, opts: G.SolveSettings, state: G.State, rc, *, sigma0: float, obs_active,
                        control_active) -> GnssSurfaceOffset | None:
    """``GnssSurfaceOffset`` at the solution ``state`` (``rc`` the unit-weight reduced covariance). None without
    GNSS, without surface observations in use, or where the GNSS correction takes a common offset."""
    if block.gnss_local is None or block.surface is None or block.surface_active is None:
        return None
    n_surface = int(np.count_nonzero(block.surface_active))
    if not n_surface or not math.isfinite(sigma0):
        return None
    pred, rows = gnss_rows(block, opts, state)
    w_z = 1.0 / np.asarray(block.gnss_sigma_m, dtype=float)[:, 2] ** 2
    g = np.asarray(block.gnss_local, dtype=float)
    P = beyond_correction(block, opts, np.ones((len(g), 1)), w_z)
    if P.shape[1] == 0:
        return None
    S, grad = plane_normals(rc, P, w_z, g[:, 2] - pred[:, 2], rows)
    if not S[0, 0] > 1e-12 * float(np.sum(w_z)):  # the surface does not fix the block's height apart from the GNSS
        return None
    step = float(grad[0] / S[0, 0])
    out = GnssSurfaceOffset(step, math.sqrt(1.0 / S[0, 0]) * sigma0, float(block.surface.sigma_m), n_surface, step)
    if not out.significant:
        return out
    free = _free_offset_z(block, opts, state, obs_active, control_active)
    return out if free is None else dataclasses.replace(out, offset_m=free, measured_free=True)


def _free_offset_z(block: G.Block, opts: G.SolveSettings, state: G.State, obs_active, control_active) -> float | None:
    """The GNSS heights' offset for the block estimated free from the solution (m; None: the solve failed): the
    rotations the step linearises about undo themselves, as far as the solve from there undoes them."""
    free_opts = dataclasses.replace(opts, gnss_correction="offset")
    # the offset's height free, its plan held (a plan offset is not what is judged, and on a small block wanders)
    free_block = dataclasses.replace(block, gnss_offset_sigma_m=np.array([1e-3, 1e-3, 1e4]))
    start = state.copy()
    start.shift[:] = 0.0
    try:
        gr = G.build_graph(free_block, free_opts, start, obs_active, control_active, robust=False)
        values, info = G.optimize(gr, free_opts)
    except RuntimeError as e:  # gtsam's indeterminant system: keep the step's estimate
        log.info("GNSS - surface offset: the solve with the offset free failed (%s)", e)
        return None
    if not info.converged:
        return None
    return float(G.state_from_values(values, free_block, free_opts, start, tie=gr.tie).shift[0][2])
