"""Control points for ``lidarctl strips adjust --control``: surveyed points on smooth surfaces that fix the datum.

File: CSV with a header line naming the columns ``id,x,y,z`` (also ``e/n/h``; lidarctl.checks.heights's
surveyed-points table), coordinates in the strips' CRS and units. Every point lies on a smooth surface
(open ground, a flat or sloped roof face; not on an edge, under trees or on a car). A control *surface*
is given as several points on the same patch: each point is its own observation.

Observation: for every strip whose planar cell holds the point q, its distance to the cell plane
y = n . (c - q) (n the plane's unit normal, c its centroid), i.e. how far the strip lies above (along
n) the surveyed surface; the model y = n . e(c) like an overlap observation with a fixed second strip.
Sigma^2 = rms^2 / n_pts (1 + 12 |q - c|_xy^2 / cell^2) (the plane's height at q: its centroid and its
tilt, points spread evenly over the cell) + sigma_control^2. On flat surfaces a point controls the
height; on sloped roof faces also the horizontal position across the slope.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from lidarctl.checks.heights import read_points_csv
from lidarctl.strips import overlap as ov

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


@dataclasses.dataclass
class ControlPoints:
    path: Path
    ids: list[str]
    xyz: np.ndarray  # (n, 3) metres


@dataclasses.dataclass
class ControlObservations:
    """One row per (strip, control point) on a planar cell of the strip."""

    strip: np.ndarray  # (m,) strip index in the StripSet
    cell: np.ndarray  # (m,) index into that strip's planar cells
    point: np.ndarray  # (m,) control point index
    normal: np.ndarray  # (m, 3)
    y: np.ndarray  # (m,) n . (c - q), metres
    sigma: np.ndarray  # (m,)


def read_control(path, units) -> ControlPoints:
    """The control points of ``path`` in metres (``units``: the strips' LengthUnits)."""
    path = Path(path)
    t = read_points_csv(path).in_crs_units(units, path)  # (a header's x_ft, z_usft: into the strips' units)
    xyz = np.column_stack([t.x * units.xy_m, t.y * units.xy_m, t.z * units.z_m])
    seen = set()
    for i in t.ids:
        if i in seen:
            raise InputError(f"{path}: control point id {i!r} appears twice")
        seen.add(i)
    return ControlPoints(path, list(t.ids), xyz)


def control_observations(ss: ov.StripSet, control: ControlPoints, sigma_m: float,
                         max_slope_deg: float) -> ControlObservations:
    """The point-to-plane distances of the control points to the strips' planar cells that hold them.
    InputError naming the file when no control point lies on a planar cell of any strip."""
    g = ss.grid
    q = control.xyz
    j = np.floor((q[:, 0] - g.x0) / g.cell_m).astype(np.int64)
    i = np.floor((q[:, 1] - g.y0) / g.cell_m).astype(np.int64)
    inside = (i >= 0) & (i < g.nrows) & (j >= 0) & (j < g.ncols)
    cell_id = np.where(inside, i * g.ncols + j, -1)
    rows = {k: [] for k in ("strip", "cell", "point", "normal", "y", "sigma")}
    for si, s in enumerate(ss.strips):
        k = np.minimum(np.searchsorted(s.ids, cell_id), max(len(s.ids) - 1, 0))
        hit = np.flatnonzero(inside & (len(s.ids) > 0) & (s.ids[k] == cell_id))
        hit = hit[s.slope_deg[k[hit]] <= max_slope_deg]
        if not len(hit):
            continue
        kc = k[hit]
        n = s.normals()[kc]
        d = s.centroid[kc] - q[hit]
        var = s.rms_m[kc] ** 2 / s.n[kc] * (1.0 + 12.0 * np.sum(d[:, :2] ** 2, 1) / g.cell_m ** 2) + sigma_m ** 2
        for key, v in (("strip", np.full(len(hit), si)), ("cell", kc), ("point", hit), ("normal", n),
                       ("y", np.einsum("ij,ij->i", n, d)), ("sigma", np.sqrt(var))):
            rows[key].append(v)
    if not rows["y"]:
        raise InputError(f"{control.path}: none of its {len(control.ids)} control points lies on a smooth surface "
                         f"(a planar cell of {g.cell_m:g} m) of a strip: check the CRS and the units")
    out = ControlObservations(*[np.concatenate(rows[k]) for k in ("strip", "cell", "point", "normal", "y", "sigma")])
    log.info("%d control observations from %d of %d control points", len(out.y), len(np.unique(out.point)),
             len(control.ids))
    return out
