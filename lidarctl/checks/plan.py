"""Plan check of the LiDAR against surveyed roof / building corners (issue 24).

The LiDAR's corners are the roof corners of ``lidarctl.corners.roof_corners`` (eave corners of the regularised roof
outlines, the same extraction as the AT control; every reported corner, usable as control or not). For
each surveyed point the nearest LiDAR corner within ``radius_m`` horizontally is its match;
dx, dy = LiDAR - surveyed, the plan offset hypot(dx, dy); dz = LiDAR - surveyed when the CSV has z
(the corner's height is the roof plane at the corner, i.e. the eave: survey the eave corner).
Statistics over the matched points: RMS x / y / plan, mean dx, dy (bias), largest plan offset, counts
found and not found.

Tolerance: the plan RMS of well-defined map features of the map scale's table
(``aerotri.core.tolerances`` ``feature_rms_xy_m``; ../shared/design/reports.md: 1:5000 and 1:10000,
0.50 m flat / hilly, 0.75 m mountainous): the corners of the LiDAR feed the line map (lidarctl vectors)
and the AT; pass when the plan RMS is within it.

Units: the surveyed points are in the cloud's CRS (x, y in its horizontal unit, z in its vertical unit);
``radius_m`` and every ``_m`` key are metres, also for clouds in feet; per-point coordinates are in the
CRS's units (``xy_unit``, ``z_unit``). Surveyed wall corners (a cadastre's footprint) differ from the
LiDAR's eave corners by the roof overhang: the offsets then include it.

``check_plan_file`` returns a ``PlanCheckResult``; its JSON (``--json``) is ``to_json()``, read back by
``read_plan_check``.
"""

from __future__ import annotations

import dataclasses
import logging
import tempfile
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from aerotri.core.records import to_record
from aerotri.core.settings import setting
from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.core.textio import read_record, record_error
from aerotri.core.figures import pyplot, save_png
from lidarctl.units import LengthUnits

if TYPE_CHECKING:
    from lidarctl.checks.heights import SurveyedPoints

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

SCHEMA_VERSION = 1  # the --json file: the layout of ``PlanCheckResult.to_json``


@dataclasses.dataclass(frozen=True)
class PlanCheckSettings:
    """``lidarctl check-plan``: how surveyed corners are paired with the LiDAR's and judged."""

    radius_m: float = setting(2.0, min=0.0, min_open=True, help="Largest distance (m) from a surveyed point to its "
                                                                "LiDAR corner.")
    min_edge_m: float | None = setting(None, min=0.0, min_open=True, help="LiDAR corners whose two roof edges are at "
                                       "least this long (m), as lidarctl corners --min-edge-m. Default: max(2 m, 8 point "
                                       "spacings) of the measured spacing.")
    scale: str = setting("1:10000", help="Map scale of the tolerance table: 1:500, 1:1000, 1:2000 (GB/T 7931's 0.6 mm "
                                        "on the map), 1:5000, 1:10000 (the design table's 0.5 m, unconfirmed) or "
                                        "'ASPRS2023 H<cm>cm V<cm>cm'.")
    terrain: str = setting("flat", help="Terrain class of the tolerance table.")

    def validate(self) -> None:
        for name, opt in (("radius_m", "--radius-m"), ("min_edge_m", "--min-edge-m")):
            v = getattr(self, name)
            if v is None and name == "min_edge_m":
                continue
            if not (np.isfinite(v) and v > 0):
                raise OptionError(f"{opt} {v}: must be a positive distance in metres", param=opt)


def _rms(v: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(v**2))) if len(v) else None


def match_corners(survey_xy_m: np.ndarray, corner_xy_m: np.ndarray, radius_m: float) -> np.ndarray:
    """Index of the nearest corner within ``radius_m`` of each surveyed point, -1 where there is none."""
    from scipy.spatial import cKDTree

    if len(corner_xy_m) == 0:
        return np.full(len(survey_xy_m), -1)
    d, j = cKDTree(corner_xy_m).query(survey_xy_m, distance_upper_bound=radius_m)
    return np.where(np.isfinite(d), j, -1)


@dataclasses.dataclass(frozen=True)
class PlanStats:
    """Statistics of the matched offsets LiDAR - surveyed (metres; None where no point was found); the height
    fields only ``with_heights`` (surveyed z given)."""

    n_points: int
    n_found: int
    n_not_found: int
    rms_x_m: float | None
    rms_y_m: float | None
    rms_plan_m: float | None
    mean_dx_m: float | None
    mean_dy_m: float | None
    median_plan_m: float | None
    max_plan_m: float | None
    tolerance_rms_plan_m: float | None
    within_tolerance: bool | None
    with_heights: bool = False
    rms_z_m: float | None = None
    mean_dz_m: float | None = None
    max_abs_dz_m: float | None = None

    def left_out_of_json(self) -> tuple[str, ...]:
        """The fields the JSON leaves out: ``with_heights``, and the height fields without surveyed heights."""
        return ("with_heights",) + (() if self.with_heights else ("rms_z_m", "mean_dz_m", "max_abs_dz_m"))


def plan_stats(dxy_m: np.ndarray, dz_m: np.ndarray | None, n_points: int, tolerance_m: float | None) -> PlanStats:
    """Statistics of the matched offsets (metres; ``dz_m`` None without surveyed heights)."""
    plan = np.hypot(*dxy_m.T) if len(dxy_m) else np.zeros(0)
    rms_plan = float(np.sqrt(np.mean(plan**2))) if len(plan) else None
    z = {}
    if dz_m is not None:
        z = dict(with_heights=True, rms_z_m=_rms(dz_m), mean_dz_m=float(dz_m.mean()) if len(dz_m) else None,
                 max_abs_dz_m=float(np.abs(dz_m).max()) if len(dz_m) else None)
    return PlanStats(
        n_points=int(n_points), n_found=len(dxy_m), n_not_found=int(n_points - len(dxy_m)),
        rms_x_m=_rms(dxy_m[:, 0]), rms_y_m=_rms(dxy_m[:, 1]), rms_plan_m=rms_plan,
        mean_dx_m=float(dxy_m[:, 0].mean()) if len(dxy_m) else None,
        mean_dy_m=float(dxy_m[:, 1].mean()) if len(dxy_m) else None,
        median_plan_m=float(np.median(plan)) if len(plan) else None,
        max_plan_m=float(plan.max()) if len(plan) else None,
        tolerance_rms_plan_m=tolerance_m,
        within_tolerance=None if rms_plan is None or tolerance_m is None else bool(rms_plan <= tolerance_m), **z)


@dataclasses.dataclass(frozen=True)
class PlanPoint:
    """A surveyed point (x, y, z_survey in the CRS's units; z_survey None without heights) and, when ``found``,
    its LiDAR corner (id, score, usable) and the offsets LiDAR - surveyed (metres; dz_m only with heights)."""

    id: str
    x: float
    y: float
    found: bool
    z_survey: float | None = None
    lidar_corner: str | None = None
    dx_m: float | None = None
    dy_m: float | None = None
    plan_m: float | None = None
    score: float | None = None
    usable: bool | None = None
    dz_m: float | None = None


@dataclasses.dataclass(frozen=True)
class PlanCheckResult:
    """The plan check (module docstring): its settings, the LiDAR corners' count, the units of the per-point
    coordinates, the statistics and every surveyed point; ``clouds`` .. ``n_outside_cloud`` as
    ``check_plan_file`` fills them (None from ``check_plan`` alone)."""

    radius_m: float
    min_edge_m: float | None
    map_scale: str
    terrain: str
    n_lidar_corners: int
    has_z: bool
    units: LengthUnits
    overall: PlanStats
    points: tuple[PlanPoint, ...]
    clouds: tuple[str, ...] | None = None
    points_csv: str | None = None
    crs: str | None = None
    n_outside_cloud: int | None = None
    schema_version: int = SCHEMA_VERSION

    def to_json(self) -> str:
        """The --json file's text."""
        out = {"schema_version": self.schema_version}
        out.update({k: getattr(self, k) for k in ("radius_m", "min_edge_m", "map_scale", "terrain", "n_lidar_corners",
                                                  "has_z")})
        out.update(self.units.as_dict())
        out["overall"] = to_record(self.overall, exclude=self.overall.left_out_of_json())
        out["points"] = [_point_record(p, self.has_z) for p in self.points]
        if self.clouds is not None:
            out.update(clouds=list(self.clouds), points_csv=self.points_csv, crs=self.crs,
                       n_outside_cloud=self.n_outside_cloud)
        return json.dumps(out, indent=2)


def _point_record(p: PlanPoint, has_z: bool) -> dict:
    out = {"id": p.id, "x": p.x, "y": p.y, "found": p.found}
    if has_z:
        out["z_survey"] = p.z_survey
    if p.found:
        out.update(lidar_corner=p.lidar_corner, dx_m=p.dx_m, dy_m=p.dy_m, plan_m=p.plan_m, score=p.score,
                   usable=p.usable)
        if has_z:
            out["dz_m"] = p.dz_m
    return out


def read_plan_check(path) -> PlanCheckResult:
    """The --json file of ``lidarctl check-plan`` (InputError naming the file when it is not one)."""
    what = "plan check (check-plan --json)"
    d = read_record(path, what, SCHEMA_VERSION)
    try:
        o = dict(d["overall"])
        stats = PlanStats(**o, with_heights=d["has_z"])
        units = LengthUnits(d["xy_unit_m"], d["z_unit_m"], known=d["xy_unit"] != "file units")
        return PlanCheckResult(d["radius_m"], d["min_edge_m"], d["map_scale"], d["terrain"], d["n_lidar_corners"],
                               d["has_z"], units, stats, tuple(PlanPoint(**p) for p in d["points"]),
                               tuple(d["clouds"]) if "clouds" in d else None, d.get("points_csv"), d.get("crs"),
                               d.get("n_outside_cloud"), d.get("schema_version", SCHEMA_VERSION))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, what, exc) from None


def check_plan(corners: list[dict], points_m: SurveyedPoints, params: PlanCheckSettings, units,
               tolerance_m=None) -> PlanCheckResult:
    """Match surveyed points (``points_m``: id, x, y[, z] in metres) to LiDAR corners (``find_roof_corners``
    dicts, metres); the result without its sources (module docstring)."""
    cxyz = np.array([[c["x"], c["y"], c["z"]] for c in corners], float).reshape(-1, 3)
    sxy = np.column_stack([points_m.x, points_m.y])
    j = match_corners(sxy, cxyz[:, :2], params.radius_m)
    found = j >= 0
    dxy = cxyz[j[found], :2] - sxy[found]
    has_z = points_m.z is not None
    dz = cxyz[j[found], 2] - points_m.z[found] if has_z else None
    rows = []
    for k in range(len(sxy)):
        row = dict(id=points_m.ids[k], x=float(units.xy_from_m(sxy[k, 0])), y=float(units.xy_from_m(sxy[k, 1])),
                   found=bool(found[k]))
        if has_z:
            row["z_survey"] = float(units.z_from_m(points_m.z[k]))
        if found[k]:
            c = corners[j[k]]
            d = cxyz[j[k]] - [sxy[k, 0], sxy[k, 1], points_m.z[k] if has_z else 0.0]
            row.update(lidar_corner=c["id"], dx_m=float(d[0]), dy_m=float(d[1]), plan_m=float(np.hypot(d[0], d[1])),
                       score=c["score"], usable=bool(c["usable"]))
            if has_z:
                row["dz_m"] = float(d[2])
        rows.append(PlanPoint(**row))
    return PlanCheckResult(params.radius_m, params.min_edge_m, params.scale, params.terrain, len(corners), has_z,
                           units, plan_stats(dxy, dz, len(sxy), tolerance_m), tuple(rows))


def _cloud_extent(paths, crs, points_crs):
    """(CRS, units, (xmin, ymin, xmax, ymax) in the CRS's units) of the clouds from their headers; the
    strips must share one CRS, ``points_crs`` (the CSV's, when given) must be theirs."""
    from aerotri.geom.crs.definition import crs_label, same_horizontal
    from lidarctl import io

    first, box = None, [np.inf, np.inf, -np.inf, -np.inf]
    for p, header, crs_i, units in io.checked_headers(paths, crs):
        first = first or (p, crs_i, units)
        box = [min(box[0], header.mins[0]), min(box[1], header.mins[1]), max(box[2], header.maxs[0]),
               max(box[3], header.maxs[1])]
    if points_crs is not None:
        from aerotri.geom.crs.definition import parse_crs

        pc = parse_crs(points_crs, "--points-crs")
        if not same_horizontal(pc, first[1]):
            raise CrsError(f"--points-crs {points_crs}: the surveyed points are in {crs_label(pc)} but {first[0]} in "
                           f"{crs_label(first[1])}; give them in the cloud's CRS (aerotri crs transform)")
    return first[1], first[2], box


def check_plan_file(cloud_paths, points_csv, params: PlanCheckSettings = PlanCheckSettings(), crs=None,
                    points_crs=None) -> tuple[PlanCheckResult, list[dict]]:
    """Plan check of surveyed corners (CSV id,x,y[,z] in the clouds' CRS and units) against the roof corners of
    classified LAS/LAZ file(s) (strips in one CRS). Returns (result, the LiDAR corners in the CRS's units).
    InputError when no surveyed point lies within the clouds' extent (wrong CRS or units, or the wrong area)."""
    from aerotri.core.tolerances import TERRAINS, feature_limit
    from lidarctl.corners.roof_corners import find_roof_corners_tiled
    from lidarctl.checks.heights import read_points_csv

    params.validate()
    if params.terrain not in TERRAINS:
        raise OptionError(f"{params.terrain!r}: expected one of {', '.join(TERRAINS)}", param="--terrain")
    tol = feature_limit(params.scale, params.terrain).limit_m
    paths = [Path(p) for p in cloud_paths]
    if not paths:
        raise OptionError("give the classified cloud(s) before POINTS_CSV", param="CLOUD")
    points = read_points_csv(points_csv, require_z=False)
    crs_found, units, box = _cloud_extent(paths, crs, points_crs)
    points = points.in_crs_units(units, points_csv)  # (a header's x_ft, x_usft: into the cloud's units)
    inside = (points.x >= box[0]) & (points.x <= box[2]) & (points.y >= box[1]) & (points.y <= box[3])
    if not inside.any():
        raise InputError(f"{points_csv}: none of its {len(inside)} points lies within the extent of "
                         f"{', '.join(map(str, paths))} (x {box[0]:.1f} .. {box[2]:.1f}, y {box[1]:.1f} .. {box[3]:.1f} "
                         f"{units.xy_name}); the points must be in the cloud's CRS and units")
    result, _, _, _ = find_roof_corners_tiled(paths, crs=crs, min_edge_m=params.min_edge_m, roof="any",
                                              work_dir=tempfile.gettempdir())
    points_m = points.in_metres(units)
    out = dataclasses.replace(
        check_plan(result.corners, points_m, params, units, tol),
        min_edge_m=result.stats.min_edge_m,  # the value used (resolved from the spacing by default)
        clouds=tuple(str(p) for p in paths), points_csv=str(points_csv),
        crs=crs_found.to_string() if crs_found is not None else None, n_outside_cloud=int((~inside).sum()))
    return out, result.in_crs_units(units).corners


def plot_plan_check(result: PlanCheckResult, corners: list[dict], path, title: str = "") -> Path:
    """Offset vectors (exaggerated, with a scale arrow) at the surveyed points, the LiDAR corners, points without
    a match; and the histogram of the plan offsets with the tolerance."""
    plt = pyplot()

    u = result.units.xy_m
    pts = result.points
    xy = np.array([[p.x, p.y] for p in pts])
    f = np.array([p.found for p in pts])
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6.5), gridspec_kw={"width_ratios": [1.6, 1]})
    if corners:
        cxy = np.array([[c["x"], c["y"]] for c in corners])
        ax.scatter(cxy[:, 0], cxy[:, 1], s=6, c="0.6", label=f"LiDAR roof corners ({len(corners)})")
    if (~f).any():
        ax.scatter(xy[~f, 0], xy[~f, 1], marker="x", s=25, c="tab:red",
                   label=f"no LiDAR corner within {result.radius_m:g} m ({int((~f).sum())})")
    s = result.overall
    if f.any():
        d = np.array([[p.dx_m, p.dy_m] for p in pts if p.found])
        span = max(np.ptp(xy[:, 0]), np.ptp(xy[:, 1]), 10.0 / u)
        ref_m = float(np.clip(np.round(2 * np.percentile(np.hypot(*d.T), 90)) / 2, 0.5, None))  # a round key
        scale = ref_m / (0.06 * span)  # the key's offset drawn 6 % of the plot wide
        q = ax.quiver(xy[f, 0], xy[f, 1], d[:, 0], d[:, 1], np.hypot(*d.T), cmap="viridis", angles="xy",
                      scale_units="xy", scale=scale, width=0.004)
        ax.quiverkey(q, 0.82, 0.04, ref_m, f"{ref_m:g} m offset", coordinates="axes")
        fig.colorbar(q, ax=ax, shrink=0.6, label="plan offset LiDAR - surveyed (m)")
        plan = np.hypot(*d.T)
        ax2.hist(plan, bins=max(5, min(40, len(plan) // 3)), color="tab:blue", alpha=0.8)
        tol = s.tolerance_rms_plan_m
        ax2.axvline(s.rms_plan_m, color="k", ls="-", label=f"RMS {s.rms_plan_m:.2f} m")
        if tol:
            ax2.axvline(tol, color="tab:red", ls="--", label=f"tolerance (RMS) {tol:g} m ({result.map_scale}, "
                                                             f"{result.terrain})")
        ax2.legend(fontsize=8)
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_xlabel(f"easting ({result.units.xy_name})")
    ax.set_ylabel(f"northing ({result.units.xy_name})")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.09), ncol=2, fontsize=8)  # below: the map stays clear
    ax.set_title(title or "plan check: LiDAR corner - surveyed point (vectors exaggerated)")
    f_ = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    ax2.set_title(f"found {s.n_found} of {s.n_points}; RMS x {f_(s.rms_x_m)}, y {f_(s.rms_y_m)}, "
                  f"plan {f_(s.rms_plan_m)} m\nmean dx {f_(s.mean_dx_m)}, dy {f_(s.mean_dy_m)} m", fontsize=9)
    ax2.set_xlabel("plan offset (m)")
    ax2.set_ylabel("points")
    fig.tight_layout()
    save_png(fig, path, dpi=90, tight=True)
    return Path(path)


def format_report(result: PlanCheckResult) -> str:
    s = result.overall
    f = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    lines = [f"plan check: {result.points_csv} against the roof corners of {', '.join(result.clouds)} "
             f"({result.n_lidar_corners} LiDAR corners with edges >= {result.min_edge_m:.2f} m, search radius "
             f"{result.radius_m:g} m)",
             f"found {s.n_found} of {s.n_points} ({s.n_not_found} without a LiDAR corner"
             + (f", {result.n_outside_cloud} outside the cloud" if result.n_outside_cloud else "") + ")",
             f"RMS x {f(s.rms_x_m)}  y {f(s.rms_y_m)}  plan {f(s.rms_plan_m)} m; mean dx {f(s.mean_dx_m)}"
             f"  dy {f(s.mean_dy_m)} m; max plan {f(s.max_plan_m)} m"]
    if result.has_z:
        lines.append(f"heights: RMS dz {f(s.rms_z_m)} m, mean dz {f(s.mean_dz_m)} m (LiDAR eave - surveyed)")
    tol = s.tolerance_rms_plan_m
    if tol is not None and s.rms_plan_m is not None:
        from aerotri.core.tolerances import feature_limit

        limit = feature_limit(result.map_scale, result.terrain)
        lines.append(f"tolerance for well-defined features ({result.map_scale}, {result.terrain}): plan RMS "
                     f"{tol:g} m -> {'within' if s.within_tolerance else 'NOT within'} tolerance"
                     + ("" if limit.confirmed else f" (the limit is unconfirmed: {limit.source})"))
        if limit.note:
            lines.append(f"  {limit.note}")
    return "\n".join(lines)


def check_plan_files(cloud_paths, points_csv, params: PlanCheckSettings = PlanCheckSettings(), *, crs=None,
                     points_crs=None, json_path=None, png_path=None) -> PlanCheckResult:
    """``check_plan_file`` + the JSON and the PNG (atomic, written only after the check succeeded)."""
    from aerotri.core.atomic import refuse_input_as_output, write_text_atomic

    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds([cloud_paths] if isinstance(cloud_paths, (str, Path)) else cloud_paths)
    for opt, p in (("--json", json_path), ("--png", png_path)):
        if p is not None:
            refuse_input_as_output(p, [*cloud_paths, points_csv], opt)
    result, corners = check_plan_file(cloud_paths, points_csv, params, crs, points_crs)
    if png_path is not None:
        plot_plan_check(result, corners, png_path)
    if json_path is not None:
        write_text_atomic(json_path, result.to_json())
    return result
