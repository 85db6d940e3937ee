"""Leave-one-out check of the control points: each in turn left out of the adjustment and compared with the
position the block, held by the others, gives it.

Units: the given and adjusted positions are in the project CRS's units (``given``, ``adjusted``); the differences,
RMS and scatter (``_m``) are metres, converted with the CRS's units (a feet project's were feet under "m" names,
3.28 times too large in the QA report). ``at/leave_one_out.json`` states its CRS.

For every control point measured in at least 2 frames, the project is adjusted with that point as a check point
(the same settings otherwise; a block without GNSS orients its images once, ``work/relative/``, and takes its
datum from the remaining points), the point is intersected with the adjusted orientations and its position is
compared with the given one: ``d = adjusted - given`` (project CRS axes, metres). Plan-only control points are
compared in plan only (their heights were never measured).

What such a check can show is bounded by the control points' own accuracy: the **scatter of the control points
about the block** (``ControlScatter``) is the plan RMS of their residuals in the adjustment with all of them,
scaled by ``sqrt(n / (n - 2))`` for the 4 plan parameters (shift, scale, rotation) they determine. When the block
adds no error of its own, the leave-one-out plan RMS is about that figure.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import time
from pathlib import Path

import numpy as np

from aerotri.adjust.pipeline import AdjustSettings, BlockAdjustment, adjust_project
from aerotri.adjust.report_record import map_unit_m
from aerotri.core.log import track

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class LeftOutPoint:
    """One control point left out: given and adjusted positions (project CRS units), the difference in metres."""

    id: str
    kind: str  # its kind as control: full, horizontal, height
    rays: int  # rays the check intersected (0 or 1: not checked)
    given: tuple[float, float, float]  # project CRS units
    adjusted: tuple[float, float, float]  # NaN when not checked
    sigma_m: tuple[float, float, float]  # of the adjusted position (image noise and orientations), metres
    seconds: float
    unit_m: tuple[float, float, float] = (1.0, 1.0, 1.0)  # metres per CRS unit (x, y, z)

    @property
    def d_m(self) -> np.ndarray:
        return np.subtract(self.adjusted, self.given) * np.asarray(self.unit_m)

    @property
    def plan_given(self) -> bool:
        """Whether its plan position was given (a height-only point's was not)."""
        return self.kind != "height"

    @property
    def height_given(self) -> bool:
        """Whether its height was given (a plan-only point's was not)."""
        return self.kind in ("full", "height")

    @property
    def checked(self) -> bool:
        return bool(np.all(np.isfinite(self.adjusted[:2])))



@dataclasses.dataclass(frozen=True)
class ControlScatter:
    """The control points' plan residuals in the adjustment with all of them: their own accuracy as the block
    sees it."""

    n: int
    rms_xy_m: float  # plan RMS of the residuals
    rms_xy_dof_m: float  # ... scaled by sqrt(n / (n - 2)) for the 4 plan parameters the points determine
    residual_xy_m: dict  # id -> (dx, dy) adjusted - given


@dataclasses.dataclass(frozen=True)
class LeaveOneOut:
    points: tuple[LeftOutPoint, ...]
    scatter: ControlScatter
    seconds: float
    crs: str | None = None  # the project CRS of the points' positions

    def _d(self, kinds) -> np.ndarray:
        return np.array([p.d_m for p in self.points if p.checked and p.kind in kinds]).reshape(-1, 3)

    @property
    def rms_xy_m(self) -> float:
        d = self._d(("full", "horizontal"))
        return float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))) if len(d) else float("nan")

    @property
    def rms_m(self) -> tuple[float, float, float]:
        """X, Y RMS over the checked points with plan control, Z over those with height control (NaN: none)."""
        d, dz = self._d(("full", "horizontal")), self._d(("full", "height"))[:, 2]
        nan = float("nan")
        return (float(np.sqrt(np.mean(d[:, 0] ** 2))) if len(d) else nan,
                float(np.sqrt(np.mean(d[:, 1] ** 2))) if len(d) else nan,
                float(np.sqrt(np.mean(dz**2))) if len(dz) else nan)

    @property
    def n_checked(self) -> int:
        """Checked points with plan control (those in the plan RMS)."""
        return len(self._d(("full", "horizontal")))

    def table(self) -> str:
        """A console table, one line per point, and the RMS against the control points' scatter."""
        lines = [f"{'id':>12} {'kind':>10} {'rays':>4} {'dX m':>8} {'dY m':>8} {'dXY m':>8} {'dZ m':>8}"]
        for p in self.points:
            d = p.d_m
            if not p.checked:
                lines.append(f"{p.id:>12} {p.kind:>10} {p.rays:4d}  not checked (fewer than 2 rays)")
                continue
            dz = f"{d[2]:8.3f}" if p.height_given else f"{'-':>8}"
            # (trial s102 txt M3: a height-only point's plan difference, 0.396 m, read against the plan limit)
            plan = (f"{d[0]:8.3f} {d[1]:8.3f} {math.hypot(d[0], d[1]):8.3f}" if p.plan_given
                    else f"{'-':>8} {'-':>8} {'-':>8}")
            lines.append(f"{p.id:>12} {p.kind:>10} {p.rays:4d} {plan} {dz}")
        if self.n_checked:  # the table shows the record's rounded figures (at/leave_one_out.json)
            rx, ry = (_f(v) for v in self.rms_m[:2])
            s = self.scatter
            lines.append(f"leave-one-out plan RMS {_f(self.rms_xy_m):.3f} m over {self.n_checked} points (X {rx:.3f}, "
                         f"Y {ry:.3f}); the control points' own plan scatter about the block "
                         f"{s.rms_xy_dof_m:.3f} m ({s.n} points in 2 frames or more, all in the adjustment: their "
                         f"plan RMS {s.rms_xy_m:.3f} m x sqrt(n / (n - 2)) for the shift, scale and rotation they fix)")
        n_z = len(self._d(("full", "height")))
        if n_z:  # (trial s102 txt M2: the height RMS was in the JSON only)
            lines.append(f"leave-one-out height RMS {_f(self.rms_m[2]):.3f} m over {n_z} points")
        return "\n".join(lines)


def _f(v) -> float | None:
    v = float(v)
    return round(v, 4) if math.isfinite(v) else None


def _finite(v) -> list:
    return [_f(x) for x in v]


@contextlib.contextmanager
def _quiet():
    """Only errors from the adjustment's loggers while the block runs."""
    logger = logging.getLogger("aerotri.adjust")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def control_scatter(ba: BlockAdjustment) -> ControlScatter:
    """Plan residuals (adjusted - given, project CRS axes, metres) of the control points with plan coordinates that
    the adjustment used, measured in 2 or more frames."""
    b, r = ba.block, ba.result
    unit_xy = np.asarray(map_unit_m(ba.crs, "the adjustment's CRS")[:2])
    rays = np.bincount(b.obs_point[r.obs_active], minlength=b.n_points)
    res = {}
    for c, j in enumerate(b.control_point):
        if r.control_active[c] and ba.control.kind[c] in ("full", "horizontal") and rays[j] >= 2:
            d = (ba.points_map[j, :2] - ba.control.xyz_m[c, :2]) * unit_xy
            if np.all(np.isfinite(d)):
                res[str(ba.control.id[c])] = (float(d[0]), float(d[1]))
    v = np.array(list(res.values())).reshape(-1, 2)
    n = len(v)
    rms = float(np.sqrt(np.mean(np.sum(v**2, axis=1)))) if n else float("nan")
    dof = rms * math.sqrt(n / (n - 2)) if n > 2 else float("nan")
    return ControlScatter(n, rms, dof, res)


def leave_one_out(root, settings: AdjustSettings | None = None, full: BlockAdjustment | None = None) -> LeaveOneOut:
    """Adjust the project once per control point with that point as a check point (see the module docstring).
    ``full``: the adjustment with every control point (made here when not given)."""
    t0 = time.perf_counter()
    st = settings or AdjustSettings()
    if full is None:
        full = adjust_project(root, st)
    rays = np.bincount(full.block.obs_point[full.result.obs_active], minlength=full.block.n_points)
    unit = map_unit_m(full.crs, "the adjustment's CRS")
    out = []
    # one full adjustment per point, told by nothing else (the runs are quiet): the kite's 9 took 4 of its 6.5 min wall
    for c, pid in track(list(enumerate(full.control.id)), "leave-one-out", "control point"):
        pid, kind = str(pid), str(full.control.kind[c])
        j = full.block.control_point[c]
        given = tuple(float(v) for v in full.control.xyz_m[c])
        if rays[j] < 2:
            out.append(LeftOutPoint(pid, kind, int(rays[j]), given, (math.nan,) * 3, (math.nan,) * 3, 0.0, unit))
            continue
        t1 = time.perf_counter()
        with _quiet():  # the full adjustment said it all; each run would repeat its warnings
            ba = adjust_project(root, dataclasses.replace(st, check=tuple(st.check) + (pid,), point_covariances=False))
        chk = ba.check[pid]
        out.append(LeftOutPoint(pid, kind, int(chk["rays"]), given, tuple(chk["adjusted_m"]),
                                tuple(float(v) * u for v, u in zip(chk["sigma_m"], unit)), time.perf_counter() - t1,
                                unit))
        d = out[-1].d_m
        log.debug(f"leave-one-out {pid}: dX {d[0]:+.3f} dY {d[1]:+.3f} m ({chk['rays']} rays)")
    return LeaveOneOut(tuple(out), control_scatter(full), time.perf_counter() - t0, crs=str(full.crs))


def run_leave_one_out(root, settings: AdjustSettings | None = None, full: BlockAdjustment | None = None) -> LeaveOneOut:
    """``leave_one_out``, its record ``at/leave_one_out.json`` (the stage's output) and its table at the end of
    ``at/report.txt`` when the adjustment wrote one (one commit: both or neither)."""
    import json

    from aerotri.core.atomic import commit_outputs, write_text_atomic
    from aerotri.core.project import Project

    loo = leave_one_out(root, settings, full)
    at = Project.open(root).at_dir
    report = at / "report.txt"
    with commit_outputs(at):
        write_text_atomic(at / "leave_one_out.json", json.dumps(_record(loo), indent=1) + "\n")
        if report.is_file():  # trial s100 rc2 L7: the result was in the JSON and the QA report only
            write_text_atomic(report, with_leave_one_out_section(report.read_text(), loo))
    return loo


LOO_HEADING = "LEAVE-ONE-OUT CHECK OF THE CONTROL POINTS (at/leave_one_out.json)"


def with_leave_one_out_section(report_txt: str, loo: LeaveOneOut) -> str:
    """``report_txt`` (at/report.txt) with the leave-one-out section at its end, in place of one there before."""
    text = report_txt.split("\n" + LOO_HEADING + "\n")[0].rstrip("\n")
    lines = [LOO_HEADING, "  each control point left out in turn, adjusted again and intersected: adjusted - given "
             "(project CRS axes, m); plan-only points in plan, height-only points in height only;",
             "  rays: those the check intersected, its own blunder test on the image rays alone (a ray the adjustment "
             "left out as control is judged again: that rejection rested on the given position the check tests);",
             "  control, not independent check points: bounded by their own accuracy"]
    lines += ["  " + ln for ln in loo.table().splitlines()]
    return text + "\n\n" + "\n".join(lines) + "\n"


# -- at/leave_one_out.json: the record the stage writes, built from the dataclasses --------------------------

def _point_record(p: LeftOutPoint) -> dict:
    d, plan = p.d_m, p.plan_given
    return {"id": p.id, "kind": p.kind, "rays": p.rays, "given": list(p.given),
            "adjusted": _finite(p.adjusted), "dx_m": _f(d[0]) if plan else None, "dy_m": _f(d[1]) if plan else None,
            "dz_m": _f(d[2]) if p.height_given else None, "dxy_m": _f(math.hypot(d[0], d[1])) if plan else None,
            "sigma_m": _finite(p.sigma_m), "seconds": round(p.seconds, 2)}


def _scatter_record(s: ControlScatter) -> dict:
    return {"n": s.n, "rms_xy_m": _f(s.rms_xy_m), "rms_xy_dof_corrected_m": _f(s.rms_xy_dof_m),
            "residual_xy_m": {k: [_f(v[0]), _f(v[1])] for k, v in s.residual_xy_m.items()}}


def _record(loo: LeaveOneOut) -> dict:
    n = loo.n_checked
    rx, ry, rz = loo.rms_m
    return {
        "crs": loo.crs,
        "checked": int(n), "not_checked": [p.id for p in loo.points if not p.checked],
        "rms_x_m": _f(rx) if n else None,
        "rms_y_m": _f(ry) if n else None,
        "rms_xy_m": _f(loo.rms_xy_m) if n else None,
        "rms_z_m": _f(rz) if math.isfinite(rz) else None,
        "control_scatter": _scatter_record(loo.scatter),
        "points": [_point_record(p) for p in loo.points], "seconds": round(loo.seconds, 1),
        "note": "each control point left out in turn; adjusted (intersected with the orientations the others "
                "hold) minus given, on the project CRS's axes; given and adjusted in the CRS's units, every _m "
                "figure in metres; plan-only points in plan only, height-only points in height only. rays: those "
                "the check intersected after its own blunder test on the image rays alone (a ray the adjustment "
                "left out as control is judged again: that rejection rested on the given position the check "
                "tests). control_scatter: the points' plan residuals with all of them in the adjustment, the "
                "reference for the plan RMS (rms_xy_dof_corrected_m: x sqrt(n / (n - 2)))"}


@dataclasses.dataclass(frozen=True)
class LeaveOneOutSummary:
    """``at/leave_one_out.json`` as the report reads it: plan (height) RMS of the checked points (m, None: none),
    the points not checked (fewer than 2 rays) and the control points' own plan scatter about the block."""

    checked: int
    not_checked: tuple[str, ...]
    rms_xy_m: float | None
    rms_z_m: float | None
    scatter_n: int
    scatter_rms_xy_dof_m: float | None


def read_leave_one_out(path) -> LeaveOneOutSummary:
    """The record ``run_leave_one_out`` writes; InputError naming the file when it is not one."""
    from aerotri.core.textio import read_json, record_error

    d = read_json(path, "leave-one-out record")

    scale = 1.0
    if isinstance(d, dict) and "crs" not in d:
        # written before its figures were metres: they are in the CRS's units, that of the adjustment beside it
        report = Path(path).parent / "report.json"
        crs = read_json(report, "adjustment report").get("crs") if report.is_file() else None
        scale = map_unit_m(crs, f"{report} crs (for {Path(path).name}, which states none)")[0]

    def opt(v):
        return None if v is None else float(v) * scale

    try:
        s = d["control_scatter"]
        return LeaveOneOutSummary(int(d["checked"]), tuple(str(i) for i in d["not_checked"]), opt(d["rms_xy_m"]),
                                  opt(d["rms_z_m"]), int(s["n"]), opt(s["rms_xy_dof_corrected_m"]))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, "leave-one-out record", exc) from None
