"""Consolidated accuracy report of a project: ``reports/index.html``, ``reports/summary.json`` and,
optionally, ``reports/report.pdf``.

It gathers what the stages wrote - LiDAR strip consistency, classification and height checks, control-point quality,
the adjustment's ISAT-style numbers, the DOM check with its seam misalignment - and marks every
quantity that has a tolerance as pass or fail. The tolerance table (``aerotri.core.tolerances``; every
table and its sources in docs/tolerances.md) comes from the arguments (``--standard``, ``--scale``,
``--tolerances``), else from ``[qa]`` in ``project.toml`` (``standard``, ``map_scale``, ``terrain``,
``tolerances``, ``platform``, ``horizontal_class_cm``, ``vertical_class_cm``), else from the block's GSD and
platform (a UAS block or a GSD under 5 cm: ASPRS 2023 classes by GSD; a coarser manned block: the Chinese
map-scale table of its GSD; unknown GSD: 1:5000). The report names the table, why it was chosen, and marks
limits not confirmed in their source.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import logging
import textwrap
import time
import json
import math
from dataclasses import dataclass
from pathlib import Path

from aerotri.adjust import report_figures as RF
from aerotri.adjust.flight_acceptance import LIMIT_KEYS, project_flight_acceptance
from aerotri.adjust.report_record import (ADJUSTMENT_REPORT, SCHEMA_VERSION, KeyStatistics,
                                          inputs_changed, read_adjustment_report)
from aerotri.control.layout import empty_target_text
from aerotri.control.pipeline import read_control_transfer
from aerotri.core.atomic import atomic_path, write_text_atomic
from aerotri.core.errors import ConfigError, InputError, OptionError, StageOrderError
from aerotri.core.textio import read_json, read_record
from aerotri.core.project import Project
from aerotri.core.records import to_record
from aerotri.core.figures import pyplot
from aerotri.core.tolerances import (ASPRS_FILE, TERRAINS, TOLERANCE_DIR, ToleranceTable, choose_table,
                                     read_qa_config, sigma0_limit_px, split_key)
from aerotri.geom.block_scale import planned_terrain_height, project_block_scale
from aerotri.qa.standards import formulas as F
from aerotri.qa.rounding import round_on_its_side, text_on_its_side, within
from aerotri.qa.statements import SOURCE_NOTE as STATEMENTS_NOTE
from aerotri.qa.compliance import (NOT_TESTABLE, asprs_class_cm, lidar_only_project, project_compliance,
                                   with_asprs2014_limits, with_cn_at_limits, with_cn_at_lidar_limits,
                                   with_lbs_lidar_limits)
from lidarctl.checks.heights import read_height_check
from lidarctl.checks.vectors import read_vector_check
from lidarctl.vectors.settings import VectorsSettings

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

# the chain's report stage stamp: bump when the accuracy report (qa/) changes at the same inputs
QA_REPORT_VERSION = 1


@dataclass(frozen=True)
class QaCheck:
    """One row of the verdict table. ``id``: stable (scripts and tests find rows by it, not by the English
    quantity); ``limit_key``: the tolerance-table key of ``limit`` (its source goes into the report)."""

    id: str
    section: str
    quantity: str
    value: object  # a number, a bool, a text ("6 full + 1 height / 370 check") or None (not measured)
    limit: object
    unit: str
    note: str
    verdict: str | None  # "pass", "fail" or None (nothing to judge)
    limit_key: str | None = None
    limit_source: str | None = None
    limit_confirmed: bool | None = None


@dataclass(frozen=True)
class QaReport:
    """The consolidated accuracy report (``reports/summary.json`` is its record,
    ``to_record(report, exclude=("html",))``)."""

    project: str
    map_scale: str
    tolerance_table: str
    terrain: str
    tolerances: dict
    table: dict
    block: dict
    checks: tuple[QaCheck, ...]
    overall: str | None  # "pass", "fail", "not testable" (a standard asked for cannot test a product), None (no
    # row with a tolerance)
    passed: int
    failed: int
    details: dict
    flight_acceptance: dict | None
    compliance: dict
    html: str | None = None  # reports/index.html once written
    # the rows with a limit but no verdict (not measured, not judged: "said, not judged" like dom_not_checked, whose
    # row has no limit): the overall verdict does not cover them (review 26: a seam row not measured read "pass")
    not_judged: tuple[str, ...] = ()

    def check(self, check_id: str) -> QaCheck:
        """The row with this id (KeyError naming the ids there are)."""
        for c in self.checks:
            if c.id == check_id:
                return c
        raise KeyError(f"no check {check_id!r} in the report; there are: {', '.join(c.id for c in self.checks)}")

    def has(self, check_id: str) -> bool:
        return any(c.id == check_id for c in self.checks)


def _table_record(table: ToleranceTable, lidar_only: bool = False) -> dict:
    """The report's record of the tolerance table that judged the block: which table (its file's name), why, the
    flight specification, the limits whose source is unconfirmed and every limit's source; whether the project is
    LiDAR-only (``lidar_only_project``: the table holds its LiDAR limits only)."""
    return dict(key=table.key, name=table.name, file=table.path.name, terrain=table.terrain, reason=table.reason,
                platform=table.platform, flight_spec=table.limits.get("flight_spec"), unconfirmed=table.unconfirmed,
                provenance={k: dataclasses.asdict(p) for k, p in table.provenance.items()}, lidar_only=lidar_only,
                limits_from=table.limits_from, terrain_classes=table.terrain_classes)


# the limits that can judge a LiDAR-only project: its LiDAR products and a line map drawn from them
LIDAR_ONLY_LIMITS = ("dem_rmse_m", "height_check_max_outlier_pct", "strip_rmsdz_m", "filter_total_error_pct",
                     "feature_rms_xy_m")


def lidar_limits(table: ToleranceTable) -> ToleranceTable:
    """``table`` with the limits of a LiDAR-only project only (``LIDAR_ONLY_LIMITS``): no adjustment, DOM or flight
    limits (nor the flight specification) for a project that has no frames."""
    return dataclasses.replace(table, limits={k: v for k, v in table.limits.items() if k in LIDAR_ONLY_LIMITS},
                               provenance={k: p for k, p in table.provenance.items() if k in LIDAR_ONLY_LIMITS})


def _failed(check_id: str, section: str, name: str, why: str) -> QaCheck:
    """A check that ran but measured nothing: it cannot pass."""
    return QaCheck(check_id, section, name, None, None, "", why, "fail")


SEAM_ROWS_LISTED = 4  # seams above the worst-seam limit named in its note (the rest counted)


def _seam_rows(sec: str, dom_check, tol: dict) -> list[QaCheck]:
    """The DOM check's seam rows: the misalignment across all seams (RMS of every patch measured) with its texture
    floor and the patches left out, or "not measured" when no patch passed it (seams over fields, water, snow); and
    the worst seam (largest RMS of the seams of at least ``least_patches`` patches) against ``seam_worst_rms_px``
    (a table without it: the block's ``seam_misalignment_rms_px``): one frame off shows on its seams only, diluted
    in the block RMS. A seam most of whose textured patches found no match (``unmatched_seams``: frames off by more
    than the search) fails the worst-seam row (and the block row when nothing matched), with no value (the unmatched
    share in the note) and only against a limit (none: reported, not judged). A record measured before the
    texture floor (review 20) leaves the worst seam unjudged. Not measured is said, not judged."""
    s = dom_check.seams
    block_limit = tol.get("seam_misalignment_rms_px")
    if s is not None:  # the seams record was read: ortho.mosaic (OpenCV) is loaded already
        from ortho.mosaic import SEAM_SEARCH_PX
        from ortho.patches import MIN_TEXTURE_RATIO
    if s is None:  # a report read without its seams record
        if dom_check.seams_rms_px is None:
            return []
        return [_check("seam_misalignment_rms_px", sec, "misalignment across seamlines, RMS",
                       dom_check.seams_rms_px, block_limit, "px", note=f"{dom_check.seam_patches} patches",
                       key="seam_misalignment_rms_px", digits=3)]
    floor = f" {s.min_texture_ratio:g}" if s.min_texture_ratio is not None else ""
    name = "misalignment across seamlines, RMS"
    lost = s.unmatched_seams()
    off = f"frames off by more than the +-{SEAM_SEARCH_PX} px search, or not the same ground in the two"
    if s.patches == 0:
        if s.examined == 0:
            why = ("not measured (no seam patch valid in both frames"
                   + (" on the ground)" if s.per_seam else ": no seam)"))
        elif not s.unsettled and not s.unmatched:
            why = (f"not measured (0 of {s.examined} patches above the texture floor{floor}): the seams lie over "
                   "ground textured in one direction or none (fields, water, snow, roads)")
        else:
            counts = ", ".join([f"{s.one_direction} below the texture floor{floor}"]
                               + ([f"{s.unmatched} above it without a match"] if s.unmatched else [])
                               + ([f"{s.unsettled} above it unsettled"] if s.unsettled else []))
            why = (f"0 of {s.examined} patches matched ({counts}): {_unmatched_note(lost)}: {off}" if lost
                   else f"not measured (0 of {s.examined} patches: {counts})")
        rows = [QaCheck("seam_misalignment_rms_px", sec, name, None, block_limit, "px", why,
                        "fail" if lost and block_limit is not None else None, "seam_misalignment_rms_px")]
        if not lost:
            return rows
    else:
        left = ", ".join([f"{s.one_direction} below the texture floor{floor} left out"]
                         + ([f"{s.unmatched} without a match"] if s.unmatched else [])
                         + ([f"{s.unsettled} unsettled"] if s.unsettled else []))
        note = f"{s.patches} of {s.examined} patches on {len(s.per_seam)} seams ({left})"
        if s.min_texture_ratio is None:
            note = (f"{s.patches} of {s.examined} patches on {len(s.per_seam)} seams, measured before the texture "
                    f"floor (a record before review 20: the DOM check's floor {MIN_TEXTURE_RATIO:g}, roads and field "
                    f"edges in; {s.one_direction} left out); re-run ortho check")
        rows = [_check("seam_misalignment_rms_px", sec, name, s.rms_px, block_limit, "px", note=note,
                       key="seam_misalignment_rms_px", digits=3)]
    limit, key, whose = tol.get("seam_worst_rms_px"), "seam_worst_rms_px", ""
    if limit is None and block_limit is not None:
        limit, key = block_limit, "seam_misalignment_rms_px"
        whose = "; the table sets no seam_worst_rms_px: its block limit"
    n, judged, worst = s.least_patches, s.judged(), s.worst()
    name = "misalignment across the worst seam, RMS"
    if s.min_texture_ratio is None:  # roads read up to 0.4 px off each: not comparable with the 0.5 px limit
        rows.append(QaCheck("seam_worst_rms_px", sec, name, None, limit, "px",
                            "not judged: measured before the texture floor; re-run ortho check", None, key))
        return rows
    if lost:
        # no value: the matched seams' worst RMS under the limit beside "fail" read as a pass failed (Brighton: 1.895
        # px against 2.5, review 31); the fail is the unmatched share, said in the note. No limit: not judged
        share = (f"; the worst seam's unmatched share {100 * lost[0].unmatched_share:.0f} % of its textured patches "
                 f"(more than {100 * s.unmatched_limit:.0f} % fails the seam)")
        note = f"{_unmatched_note(lost)}: {off}{share}"
        if worst is not None:
            note += f"; of the seams matched the worst: {worst.image_a} / {worst.image_b} {worst.rms_px:.3f} px"
        rows.append(QaCheck("seam_worst_rms_px", sec, name, None, limit, "px", note + whose,
                            "fail" if limit is not None else None, key))
        return rows
    if worst is None:
        most = max(s.per_seam, key=lambda p: p.patches, default=None)
        rows.append(QaCheck("seam_worst_rms_px", sec, name, None, limit, "px",
                            f"not judged: no seam has {n} patches" + (f" (the most: {most.patches}, {most.image_a} / "
                                                                      f"{most.image_b})" if most else ""), None, key))
        return rows
    over = sorted((p for p in judged if limit is not None and p.rms_px > limit), key=lambda p: -p.rms_px)
    note = (f"{worst.image_a} / {worst.image_b}: {worst.patches} patches, largest {worst.max_px:.2f} px; "
            f"{len(judged)} of {len(s.per_seam)} seams with at least {n} patches judged{whose}")
    if len(over) > 1:
        named = ", ".join(f"{p.image_a} / {p.image_b} {p.rms_px:.2f}" for p in over[:SEAM_ROWS_LISTED])
        note += f"; {len(over)} seams above {limit:g} px: {named}" + (", ..." if len(over) > SEAM_ROWS_LISTED else "")
    rows.append(_check("seam_worst_rms_px", sec, name, worst.rms_px, limit, "px", note=note, key=key, digits=3))
    return rows


def _unmatched_note(lost) -> str:
    """The seams most of whose textured patches found no match, the first ``SEAM_ROWS_LISTED`` named."""
    named = ", ".join(f"{p.image_a} / {p.image_b} {p.unmatched} of {p.textured}" + (" textured patches unmatched"
                                                                                   if not k else "")
                      for k, p in enumerate(lost[:SEAM_ROWS_LISTED]))
    return (f"{len(lost)} seam{'s' if len(lost) > 1 else ''} did not match ({named}"
            + (", ..." if len(lost) > SEAM_ROWS_LISTED else "") + ")")


def _check(check_id: str, section: str, name: str, value, limit, unit: str, *, note: str = "",
           key: str | None = None, digits: int | None = None) -> QaCheck:
    """A verdict row; ``key``: the tolerance-table key of ``limit`` (its source goes into the report). ``value`` is
    judged as given and kept to ``digits`` decimals, more where fewer would put it across the limit
    (``round_on_its_side``: 0.100028 m against 0.1 m was kept as 0.1 and passed)."""
    if value is None or limit is None:
        verdict = None
    elif isinstance(limit, bool):
        verdict = "pass" if value == limit else "fail"
    else:
        verdict = "pass" if within(value, limit) else "fail"
    if digits is not None and value is not None:
        value = round_on_its_side(value, limit, digits)
    return QaCheck(check_id, section, name, value, limit, unit, note, verdict, key)



def leave_one_out_rows(project: Project, section: str) -> list[QaCheck]:
    """The leave-one-out check of the control points (``at/leave_one_out.json``, ``aerotri adjust
    --leave-one-out``): plan RMS (height RMS when points with measured heights were checked) beside the points'
    own plan scatter about the block. Reported, not judged: the points left out are control, not the independent
    check points a standard counts; for a block without check points (the kite block) it is the only measure of
    the block's accuracy on the ground. None without the file; a file older than ``at/report.json`` (an
    adjustment since without the check) is named as such."""
    path = project.at_dir / "leave_one_out.json"
    if not path.is_file():
        return []
    from aerotri.adjust.leave_one_out import read_leave_one_out

    loo = read_leave_one_out(path)
    if path.stat().st_mtime < project.adjustment_report_path.stat().st_mtime:
        return [_check("leave_one_out_rms_xy_m", section, "leave-one-out control points, plan RMS", None, None, "m",
                       note=f"{path.name} is older than the adjustment (at/report.json), not shown: run aerotri "
                            f"adjust --leave-one-out again")]
    left = ", ".join(loo.not_checked)
    note = f"{loo.checked} control points each left out in turn and checked" + (
        f" ({left}: fewer than 2 rays without it, not checked)" if left else "")
    if loo.scatter_rms_xy_dof_m is not None:
        note += (f"; the control points' own plan scatter about the block {loo.scatter_rms_xy_dof_m:.3f} m "
                 f"({loo.scatter_n} points): a block that adds no error of its own gives about that figure")
    note += "; control, not independent check points: not judged (at/leave_one_out.json)"
    rows = []
    if loo.rms_xy_m is not None:
        rows.append(_check("leave_one_out_rms_xy_m", section, "leave-one-out control points, plan RMS", loo.rms_xy_m,
                           None, "m", note=note))
    if loo.rms_z_m is not None:
        rows.append(_check("leave_one_out_rms_z_m", section, "leave-one-out control points, height RMS", loo.rms_z_m,
                           None, "m", note=note))
    return rows


def _roofs_row(section: str, dom_check, project: Project) -> QaCheck:
    """The DOM check's roofs row (``ortho.check.DomCheck``): RMS of the displacements at roof corners, not judged
    against the table (roofs stand in place only in a true ortho checked against a true orthophoto; in a conventional
    ortho they lean by their relief displacement), with how many corners were measured, where they came from and
    whether the frames are a true ortho."""
    r = dom_check.roofs
    source = dom_check.roof_corners_from or ""
    if source.startswith("nDSM "):
        source = "the outline corners of the nDSM's buildings"
    elif source:
        path = Path(source)
        source = str(path.relative_to(project.root)) if path.is_relative_to(project.root) else str(path)
    kind = ""
    if project.frames_index_path.is_file():
        from ortho.block import read_index

        true_ortho = read_index(project.root).true_ortho
        kind = "; true ortho on the DSM" if true_ortho else "; conventional ortho (roofs lean)"
    if not r.count:
        why = dom_check.roofs_why or f"{dom_check.roof_corners or 0} roof corners, none measurable"
        return _check("dom_roofs_rms_xy_m", section, "displacement at roof corners, plan RMS", None, None, "m",
                      note=f"none measured ({why})")
    gsd = r.rms_xy_gsd if r.rms_xy_gsd is not None else float("nan")
    # corners whose evidence lies in the DOM's nodata: counted, not measured (``ortho.check.roof_evidence_in_nodata``)
    from ortho.check import roofs_not_measured_words

    in_nodata = roofs_not_measured_words(dom_check)
    if dom_check.roofs_in_nodata_warning:  # the rule may be hiding roofs that moved (``ROOF_MAX_IN_NODATA_PCT``)
        in_nodata += f" (warning: {dom_check.roofs_in_nodata_warning})"
    median_gsd = r.median_xy_m / r.gsd_m if r.median_xy_m is not None and r.gsd_m else float("nan")
    return _check("dom_roofs_rms_xy_m", section, "displacement at roof corners, plan RMS", round(r.rms_xy_m, 4), None,
                  "m", note=f"{r.count} of {dom_check.roof_corners} corners{in_nodata}, {gsd:.2f} GSD"
                  f"{_dom_cell_words(r)}, median {median_gsd:.2f} GSD; "
                  f"corners: {source}{kind}; not judged")


@dataclass(frozen=True)
class Asprs2023Figures:
    """The check points' own accuracy (m) ASPRS 2023 combines with a measured RMSE (sqrt(RMSE_measured^2 +
    RMSE_checkpoints^2), ``formulas.with_checkpoint_accuracy``) for the verdict table's limits that are ASPRS 2023's
    (``keys``), read as the compliance section reads it (``aerotri.qa.compliance``: the survey's [qa]
    survey_sigma_*, the AT check points' sx, sy, sz or [control] sigma_*), so that both sections judge one figure
    (trial audit F5: the table passed a DEM at 0.0998 m, the compliance section failed it at 0.1003 m against 0.1 m
    with a 0.01 m survey). ``by_key``: (accuracy m, its source) per limit key, None where it is not stated."""

    keys: frozenset
    by_key: tuple[tuple[str, float | None, str], ...] = ()

    @classmethod
    def of_project(cls, project: Project, keys: frozenset) -> "Asprs2023Figures":
        if not keys:
            return cls(keys)
        from aerotri.qa.compliance import _json, _survey_accuracy, at_checks

        h, v, src = _survey_accuracy(project.qa)
        at = at_checks(_json(project.adjustment_report_path), project.control_points,
                       str(project.adjustment_report_path))
        at_h, at_v, at_src = (at.cp_rmse_h_m, at.cp_rmse_v_m, at.cp_source) if at is not None else (None, None, "")
        return cls(keys, (("dem_rmse_m", v, src), ("feature_rms_xy_m", h, src), ("rms_xy_m", at_h, at_src),
                          ("rms_z_m", at_v, at_src)))

    def _accuracy(self, key: str) -> tuple[float | None, str]:
        if key not in self.keys:
            return None, ""
        return next(((m, src) for k, m, src in self.by_key if k == key), (None, ""))

    def figure(self, measured_m: float | None, key: str) -> tuple[float | None, str]:
        """(the figure judged against ``key``'s limit, the note saying how it was made: "" when it is the measured
        one)."""
        cp_m, src = self._accuracy(key)
        if measured_m is None or cp_m is None:
            return measured_m, ""
        return (F.with_checkpoint_accuracy(measured_m, cp_m),
                f"ASPRS 2023: measured {measured_m:.4f} m combined with the check points' own {cp_m:.4f} m ({src}), "
                "as the compliance section")

    def quantity_suffix(self, measured_m: float | None, key: str) -> str:
        """" (with the check points' own accuracy, ASPRS 2023)" when ``figure`` combines them."""
        combined = measured_m is not None and self._accuracy(key)[0] is not None
        return " (with the check points' own accuracy, ASPRS 2023)" if combined else ""


@dataclass(frozen=True)
class DomPointsJudged:
    """What the verdict table's DOM rows judge of a check at surveyed points (``ortho check --points``): the points
    the adjustment did not use as control (``aerotri.qa.compliance.dom_independent_points``, the compliance row's
    figure), as ``displacement`` (the check's ``Displacement`` with their count, RMS, 95th percentile and largest);
    ``control_ids``: the points left out, ``total``: every point the check measured. The DOM stands on orientations
    fitted to the control points, so their displacement is no check of it (trial audit F1: 4 control points at 0 m
    beside 6 others at 0.600 m read 0.4648 m, "pass" against 0.50 m)."""

    displacement: object  # ortho.check.Displacement of the independent points (count 0: none left)
    control_ids: tuple[str, ...]
    total: int

    def left_out_note(self) -> str:
        """"4 of the 10 surveyed points left out, the adjustment's control (RC00322, ...): not independent check
        points" ("" when none was)."""
        if not self.control_ids:
            return ""
        more = ", ..." if len(self.control_ids) > 3 else ""
        return (f"{len(self.control_ids)} of the {self.total} surveyed points left out, the adjustment's control "
                f"({', '.join(self.control_ids[:3])}{more}): not independent check points")


def _dom_points(dom_check, project: Project) -> DomPointsJudged | None:
    """None for a DOM check against a reference orthophoto (ground patches); for one at surveyed points the figures
    of those the adjustment did not use as control (``DomPointsJudged``)."""
    if dom_check is None or dom_check.method != "surveyed_points":
        return None
    from aerotri.qa.compliance import _json, dom_independent_points, dom_points_used_as_control

    dom = dom_check.displacement
    dom_all = _json(project.dom_report_path)
    control = dom_points_used_as_control(dom_all, _json(project.adjustment_report_path))
    if not control:
        return DomPointsJudged(dom, (), dom.count or 0)
    ind = dom_independent_points(dom_all, control)
    gsd = (lambda m: m / dom.gsd_m if m is not None and dom.gsd_m else None)
    judged = dataclasses.replace(dom, count=ind.n, rms_xy_m=ind.rmse_xy_m, rms_e_m=ind.rmse_e_m, rms_n_m=ind.rmse_n_m,
                                 rms_xy_gsd=gsd(ind.rmse_xy_m), p95_xy_m=ind.p95_xy_m, max_xy_m=ind.max_xy_m,
                                 max_xy_gsd=gsd(ind.max_xy_m), mean_e_m=None, mean_n_m=None, median_xy_m=None,
                                 distribution_gsd=None)
    return DomPointsJudged(judged, tuple(control), dom.count or 0)


def _dom_crs_note(dom_check, project: Project) -> str:
    """(the DOM rows) the DOM's CRS when it is not the project's (a contract's grid), and the operation the reference
    was read through, a ballpark one named as such: the figure then holds the datum shift it ignored."""
    note = ""
    crs = dom_check.dom_crs
    if crs and project.info.crs:
        from aerotri.core.errors import CrsError
        from aerotri.geom.crs.definition import same_horizontal

        try:
            other = not same_horizontal(crs, project.crs)
        except CrsError:  # a CRS the report cannot compare is named, not judged
            other = True
        if other:
            note += f"; DOM in {crs}"
    if dom_check.reference_operation:
        note += f"; reference through {dom_check.reference_operation}"
        if dom_check.reference_ballpark:
            from ortho.check import reference_ballpark_words

            note += f" ({reference_ballpark_words(dom_check)})"
    return note


def verdict_counts(passed: int, failed: int, not_judged=()) -> str:
    """The verdict table's counts as the console, the page and the PDF say them ("8 passed, 1 failed, 1 with a limit
    not judged"; the PDF left the last out: trial s100 rc2 L3)."""
    n = len(not_judged or ())
    if passed == failed == n == 0:
        # (a LiDAR-only report whose compliance rows pass read "0 passed, 0 failed" under a density "pass": docs
        # trial s101 F8)
        return "no row of the verdict table judged"
    return f"{passed} passed, {failed} failed" + (f", {n} with a limit not judged" if n else "")


def _dom_cell_words(d) -> str:
    """What the DOM rows' "GSD" is: the DOM's cell (trial s100 rc F13: read as the frames' 0.36 m image GSD)."""
    return f" (of the DOM's {d.gsd_m:g} m cell)" if getattr(d, "gsd_m", None) else ""


HEIGHTS_UNCHECKED = "heights_unchecked"


def heights_unchecked_words(gnss_given: bool, height_shares: dict | None = None) -> str:
    """Why a block without control points, surface control or check points with heights is not testable (trial s99
    atmut H1: a GNSS-only block with its camera held, the focal length 1 % / 5 % off or the GNSS heights 40 m off,
    read "Solution Successful" and QA pass with the ground 2.7 / 14.3 / 40.2 m off in height)."""
    held = ("the GNSS heights and the camera's focal length alone (a focal length 1 % off moves them by 1 % of the "
            "flying height, GNSS heights of another height system by the geoid)" if gnss_given else
            "nothing measured: no GNSS either")
    shares = height_shares or {}
    if gnss_given and shares.get("priors", 0.0) > max(shares.get("gnss", 0.0), shares.get("image", 0.0)):
        # a consumer receiver's one offset for the flight, unobserved: its a-priori value holds the block's height
        # (trial s100 rc2 M3: Brighton, "rest on the GNSS heights" beside a GNSS share of 0.00)
        held = ("the a-priori value of the GNSS's offset for the flight (a consumer receiver's common error of metres, "
                "which nothing observes) and the camera's focal length alone")
    # (said of a verdict that would pass: a failing row still fails the report, trial s100 rc F5)
    return (f"no control point, DEM (surface control or --check-dem) or check point with a height: the block's heights "
            f"rest on {held}, and nothing in the block can see an error there, so the report cannot pass: not "
            "testable where every row passes. Give check points, control or the LiDAR DEM ([adjust] dem)")


def _holes_row(section: str, m) -> QaCheck:
    """The DOM's cells inside the block that no frame sees (``m``: ortho/mosaic.json, ``MosaicSummary``): nodata in
    the delivered mosaic (a true ortho's ground occluded in every frame, or DEM nodata). Shown, not judged: no table
    has a limit."""
    from ortho.mosaic import on_objects_words

    share = None if m.share_seen_by_no_frame is None else round(100.0 * m.share_seen_by_no_frame, 3)
    return _check("dom_seen_by_no_frame_pct", section, "DOM cells seen by no frame (nodata inside the block)", share,
                  None, "%", note=f"{m.cells_seen_by_no_frame:,} cells, {_area_m2(m.area_seen_by_no_frame_m2)}; occluded "
                  "in every frame (true ortho) or over DEM nodata"
                  + on_objects_words(m.cells_on_objects, m.cells_seen_by_no_frame)
                  + (f"; {len(m.excluded)} frame(s) left out of the mosaic ([mosaic] exclude): "
                     f"{', '.join(m.excluded[:8])}{' ...' if len(m.excluded) > 8 else ''}" if m.excluded else "")
                  + "; hatched in ortho/seamlines_preview.png; not judged")


def _without_heights_row(section: str, m, tol: dict) -> QaCheck | None:
    """Of the DOM's cells no frame sees, those where the DEM (or a true ortho's DSM) the frames were rectified on has
    no heights (``m``: ortho/mosaic.json, ``ortho.unseen.unseen_without_heights``), as a share of the block, judged
    against the table's ``dom_without_heights_max_pct``: a DOM empty where its surface is (Brighton on its cloud's
    DEM: 44.7 % of the mosaic empty and "pass", 18 frame warnings alone said so). None for a mosaic.json before it
    was kept."""
    if m.share_without_heights is None:
        return None
    key = "dom_without_heights_max_pct"
    share = round(100.0 * m.share_without_heights, 3)
    note = (f"{m.cells_without_heights:,} cells of the {m.cells_seen_by_no_frame:,} seen by no frame: the surface the "
            f"frames were rectified on (DEM, a true ortho's DSM) has no heights there, beyond its extent or on its "
            f"nodata")
    if share > 0:
        note += "; a surface that covers the block (or the frames cut to it with --frames) fills them"
    return _check("dom_without_heights_pct", section, "DOM cells without surface heights (nodata inside the block)",
                  share, tol.get(key), "%", note=note, key=key if tol.get(key) is not None else None, digits=3)


def _area_m2(a: float) -> str:
    """An area in m2 as a reader takes it: whole square metres from 10 up, two significant digits below ("403 cells,
    0 m2" of a 5 cm DOM, new-user trial s51)."""
    return f"{a:,.0f} m2" if a >= 10 else f"{a:.2g} m2"


def _seam_crossings_row(section: str, m) -> QaCheck | None:
    """Where a mosaic of edited seamlines cuts buildings and trees that its automatic seams did not (``m``:
    ortho/mosaic.json, its "seam_crossings", ``ortho.seam_crossings``): the new crossings' length, m. Shown, not
    judged (the operator decides; roofs and crowns tear there). None for a mosaic of automatic seams."""
    c = m.seam_crossings
    if c is None:
        return None
    name = "edited seams: new crossings of buildings and trees"
    if not c.checked:
        return _check("dom_edited_seam_crossings_m", section, name, None, None, "m", note=f"{c.why}; not judged")
    kinds = (f"buildings {c.building_m:.1f} m, trees {c.tree_m:.1f} m (automatic seams {c.automatic_building_m:.1f} / "
             f"{c.automatic_tree_m:.1f} m)") if c.with_chm else (
        f"raised objects {c.building_m:.1f} m (automatic seams {c.automatic_building_m:.1f} m)")
    return _check("dom_edited_seam_crossings_m", section, name, round(c.new_m, 1), None, "m",
                  note=f"{c.new_crossings} new crossing(s) on {c.pairs_with_new_crossings} seam(s); all crossings: "
                       f"{kinds}; ortho/seam_crossings.gpkg; not judged")


def _sigma_basis(at) -> str | None:
    """What the adjustment's reported sigmas contain, for the reader who trusts them: with surface control, whether
    the surface's systematic error (the LiDAR's strip offsets) is in them or they are formal."""
    sy = at.surface_systematic
    if sy is None:
        return None
    if sy.get("considered"):
        return (f"formal, plus the surface control's systematic error ({sy.get('sigma_xy_m')} m plan, "
                f"{sy.get('sigma_z_m')} m height per LiDAR strip cell)")
    return ("formal only: the surface control's points taken as independent (no systematic error stated); the "
            "sigmas are too small by the DEM's systematic error")


def _notes(*parts: str) -> str:
    return "; ".join(p for p in parts if p)


def _too_few_note(n: int, compliance) -> str:
    """Said on a DEM row judged on fewer check points than the standard asks for its NVA (the compliance section's
    count; trial-qa: a DEM passed on 10 of ASPRS's 30 with no word in the verdict table, "not testable" below)."""
    need = max((c.n_required or 0 for c in compliance.checks if c.product == "LiDAR DEM"
                and c.quantity.startswith("NVA")), default=0)
    if not need or n >= need:
        return ""
    return f"{n} check points, {need:g} required by {compliance.name}: indicative only"


def _sigma0_limit_px(tol: dict, ks: KeyStatistics, s0_px: float) -> float | None:
    """The self-check limit of sigma naught in the camera's pixels: ``sigma0_max_px`` (digital cameras: a
    fraction of a pixel, whatever its size), or a contract's ``sigma0_max_um`` on the image over the pixel
    size (``key_statistics`` pixel_um, or sigma0_um / sigma0_px of older reports)."""
    pixel_um = ks.pixel_um
    if pixel_um is None and ks.sigma0_um and s0_px:
        pixel_um = ks.sigma0_um / s0_px
    return sigma0_limit_px(tol, pixel_um)




def _terrain_rows(project: Project, terrain: str | None, given: bool = False) -> list[QaCheck]:
    """The terrain class of the block's DEM (``aerotri.qa.terrain_class``) beside the table's (a Chinese table's
    limits are per terrain class): failed when the table's class is looser than the DEM's slope gives (a flat block
    held to the mountainous limits), said otherwise. None without a DEM or a terrain class."""
    from aerotri.exchange.layers import footprint_dem
    from aerotri.qa.terrain_class import TERRAIN_ORDER, dem_terrain

    # the LiDAR stages' DEM, else the one the orthos or the adjustment used (s95: an NGI block of 630 m relief held
    # to the flat limits, its DEM given by `adjust --dem` and `rectify --dem`, no word)
    dem, _why = footprint_dem(project)
    if terrain not in TERRAIN_ORDER or dem is None:
        return []
    got = dem_terrain(dem)
    if got is None:
        return []
    sec, name = "Tolerance table", "terrain class of the DEM"
    if got.mostly_extrapolated:
        return [_check("terrain_class_dem", sec, name, None, None, "", note=(
            f"not measured: {got.extrapolated_pct:.0f} % of {got.path.name} is a flat continuation beyond its tie "
            f"points, so its median slope ({got.median_slope_deg:.1f} deg) is the filling's, not the terrain's; "
            "not judged"))]
    if TERRAIN_ORDER[terrain] > TERRAIN_ORDER[got.terrain]:
        return [_failed("terrain_class_dem", sec, name, f"{got.text()}; the limits are the {terrain} class's, looser "
                                                         "than the terrain's: "
                                                         + (f"--terrain {got.terrain}" if given else
                                                            f"set [qa] terrain = \"{got.terrain}\""))]
    if terrain != got.terrain:
        # trial-relief F4: a block with 420 m of relief (median slope 23 deg) held to the flat limits, no word
        log.warning(f"{dem}: {got.text()}, the tolerance table's is {terrain}: the limits are tighter "
                    f"than the terrain's class; [qa] terrain in project.toml, or --terrain")
    note = got.text() + ("" if terrain == got.terrain else f"; the table's class is {terrain} (tighter limits)")
    return [_check("terrain_class_dem", sec, name, got.terrain, None, "", note=note + "; not judged")]


def _footprint_terrain(project: Project):
    """The terrain the flight acceptance puts the footprints on when the adjustment did not: the DEM the
    frame orthos were made on (``at/dem.tif`` of a block without LiDAR) or the adjustment's surface-control
    DEM, as the exported footprints; None leaves it to ``lidar_out/dem.tif`` / ``[flight]``."""
    from aerotri.adjust.flight_acceptance import Terrain
    from aerotri.exchange.layers import footprint_dem

    dem, _why = footprint_dem(project)
    if dem is None or dem == project.dem_path:
        return None
    source = str(dem.relative_to(project.root)) if dem.is_relative_to(project.root) else str(dem)
    return Terrain.from_dem(dem, planned_terrain_height(project), source=source)


def flight_rows(fa: dict, tol: dict) -> list[QaCheck]:
    """The flight acceptance checks as verdict rows; the limits are those of this report's table (a
    section computed by the adjustment with another table is judged again)."""
    rows = []
    for c in fa["checks"]:
        kind = LIMIT_KEYS[c["key"]][2]
        limit = tol.get(c["key"], c["limit"])
        value = c["value"]
        if value is None:
            verdict = None
        elif limit is None:
            verdict = None
        else:
            verdict = "pass" if (value <= limit if kind == "max" else value >= limit) else "fail"
        n_fail = c["n_fail"] if limit == c["limit"] else None
        note = (f"worst at {c['where']}" + (f"; {n_fail} of {c['n']} beyond the limit" if n_fail else "")
                + ("" if kind == "max" else "; a lower limit: the value must reach it"))
        if value is not None and limit is None:
            note = f"{note}; not judged: no flight limit applies to this block"
        rows.append(QaCheck(c["key"], "Flight acceptance", c["quantity"], value, limit, c["unit"],
                            note if value is not None else "not measured", verdict, c["key"]))
    return rows


def _outside_note(ids, groups, which: str, why: str) -> str:
    """The verdict table's note on the surveyed points without a dz (they are not in the RMSE): a row of
    non-vegetated points (``which``, ``judged_dz``) names those not of a vegetated group, those of unknown land
    cover marked so."""
    from aerotri.qa.compliance import OUTSIDE_IDS_SHOWN, outside_text, vegetated

    veg = [vegetated(g) for g in groups] if len(groups) == len(ids) else [None] * len(ids)
    keep = [(i, v) for i, v in zip(ids, veg) if not (which and v is True)]
    # (land cover matters only to a row of non-vegetated points: the others count every point)
    return outside_text([i for i, _ in keep], why, [i for i, v in keep if v is None] if which else (),
                        noun="surveyed point", shown=OUTSIDE_IDS_SHOWN)


def judged_dz(dz_m, groups, nva: bool) -> tuple[list[float], str]:
    """The dz the DEM height RMSE limit is judged on, and the word for them. ``nva`` (the table's dem_rmse_m is an
    NVA limit, ``Provenance.nva``: ASPRS 2023, the USGS LBS) with land-cover groups (check-heights --groups): only
    the non-vegetated points ("non-vegetated "), as the compliance section's NVA (``compliance.vegetated``;
    vegetated points and points without a group left out; vegetated points have their own limit (LBS VVA p95) or
    none (ASPRS 2023)). Otherwise every point (""): the map-scale tables and a user's own table limit the height
    RMS "of the LiDAR ground against surveyed points", forest points included."""
    from aerotri.qa.compliance import OUTSIDE_IDS_SHOWN, outside_text, vegetated

    veg = [vegetated(g) for g in groups] if nva and len(groups) == len(dz_m) else []
    if not any(v is not None for v in veg):
        return list(dz_m), ""
    return [d for d, v in zip(dz_m, veg) if v is False], "non-vegetated "


def vegetated_dz(dz_m, groups) -> list[float]:
    """The dz of the points of a vegetated land-cover group (``compliance.vegetated``)."""
    from aerotri.qa.compliance import vegetated

    return [d for d, g in zip(dz_m, groups) if vegetated(g)] if len(groups) == len(dz_m) else []


def strip_rows(project: Project, tol: dict) -> tuple[list[QaCheck], list | None]:
    """(the strip-consistency row, the pairs for the details) from lidar_out/strips/: the check, or after a
    strip adjustment its check after (the note gives the value before).

    The value is the RMS of the height differences of all pairs on smooth single-return surfaces (planar
    cells without vegetation, edges or steps): the RMSDz of the LiDAR specifications (``strip_rmsdz_m``;
    USGS Lidar Base Specification v1.3 table 2, swath overlap difference, QL1/QL2 0.08 m: see the
    tolerance tables for the source and its verification status).
    The RMS, not the NMAD: the systematic part (a strip too high, tilted by a roll error) is what
    the check is there to find, and the NMAD, spread about each pair's median, does not see a constant
    offset between two strips; blunders are kept out by the choice of cells, not by the statistic."""
    from lidarctl.strips.adjust import read_strip_adjustment
    from lidarctl.strips.check import nothing_compared, read_strip_check

    adjusted = project.strips_adjust_path.is_file()
    path = project.strips_check_used_path
    if not path.is_file():
        return [], None
    sec = "LiDAR strip consistency"
    name = "strip-to-strip height differences on smooth surfaces, RMS over all pairs"
    chk = read_strip_check(path)
    if chk is None:
        return [_check("strip_rmsdz_m", sec, name, None, None, "m",
                       note=f"not checked: {nothing_compared(path)}")], None
    a = chk.all_pairs
    pairs = [dict(a=p.a, b=p.b, n_cells=p.diff.n_cells, mean_m=p.diff.mean_m, rms_m=p.diff.rms_m, nmad_m=p.diff.nmad_m)
             for p in chk.pairs]
    worst = max(chk.pairs, key=lambda p: p.diff.rms_m)
    note = (f"{len(pairs)} pairs, {a.n_cells} cells of {chk.cell_m:g} m; NMAD {a.nmad_m:.3f} m; worst pair "
            f"{worst.b} - {worst.a}: mean {worst.diff.mean_m:+.3f} m, RMS {worst.diff.rms_m:.3f} m")
    from lidarctl.strips.check import rigid_fit_warning

    # the strip check's warning of a pair a rigid shift does not model (a boresight or scan-angle error) reaches the
    # accuracy report too (trial s100 rc2 L4: AHN3's pair warned on the strips' page, "pass QL0" here without a word)
    tilted = [f"{p.b} - {p.a}" for p in chk.pairs if rigid_fit_warning(p.offset_3d_b_minus_a) is not None]
    if tilted:
        note += (f"; {len(tilted)} pair(s) a rigid shift does not model ({', '.join(tilted[:4])}"
                 f"{', ...' if len(tilted) > 4 else ''}): a boresight or scan-angle error tilts the strips "
                 "(lidar_out/strips/index.html; lidarctl strips adjust --trajectory)")
    if adjusted:
        before = read_strip_adjustment(project.strips_adjust_path).check_before
        if before.rms_m is not None:
            note = f"after the strip adjustment (before: RMS {before.rms_m:.3f} m); " + note
    return [_check("strip_rmsdz_m", sec, name, a.rms_m, tol.get("strip_rmsdz_m"), "m", note=note,
                   key="strip_rmsdz_m", digits=4)], pairs


def line_map_rows(project: Project, tol: dict, asprs: Asprs2023Figures | None = None) -> list[QaCheck]:
    """The "Line map (DLG) plan accuracy" row from a check-vectors result: the chain's (lidar_out/
    vectors_check.json, ``[vectors] enabled``), else ``[vectors] check_json`` of project.toml; none without.

    The value is the plan RMS of the building corners (well-defined points) to their matched reference
    corners, judged against this report's tolerance for well-defined map features (``feature_rms_xy_m``
    of the map scale and terrain class), not the one the check was made with; under an ASPRS 2023 limit with the
    survey's own accuracy combined (``asprs``), as the compliance section."""
    path = project.vectors_check_path
    if not path.is_file():
        path = project.settings(VectorsSettings).check_json  # relative names anchored at the project
        if path is None:
            return []
        if not path.is_file():
            raise InputError(f"{project.config_path} [vectors] check_json: {path} not found")
    chk = read_vector_check(path)
    sec, name, cid = "Line map (DLG)", "Line map (DLG) plan accuracy: building corners, plan RMS", "line_map_rms_xy_m"
    b = chk.buildings
    if not b:
        return [_failed(cid, sec, name, f"{path.name}: no buildings layer checked")]
    if not b.n_matched_corners:
        return [_failed(cid, sec, name, f"{path.name}: no building corner matched a reference corner")]
    note = (f"{b.n_matched_corners} corners within {chk.match_m:g} m of a reference corner; to the nearest "
            f"reference outline {b.rms_xy_to_line_m:.3f} m RMS; buildings complete {b.completeness_pct:.1f} %, "
            f"correct {b.correctness_pct:.1f} %; reference {Path(chk.reference).name}")
    asprs = asprs or Asprs2023Figures(frozenset())
    figure, combined = asprs.figure(b.rms_xy_corner_m, "feature_rms_xy_m")
    return [_check(cid, sec, name + asprs.quantity_suffix(b.rms_xy_corner_m, "feature_rms_xy_m"), figure,
                   tol.get("feature_rms_xy_m"), "m", note=_notes(combined, note), key="feature_rms_xy_m", digits=4)]


def stage_results(project: Project) -> list:
    """What the stages leave for the report (the strip check too: a LiDAR delivery's swaths and density are judged
    without surveyed points; AHN3's strips and DEM read "nothing to report yet ... run the adjustment first")."""
    return [project.adjustment_report_path, project.control_transfer_path, project.dom_report_path,
            project.height_check_path, project.classification_eval_path, project.strips_check_path,
            project.strips_check_after_path]


def _with_stamp_inputs(project: Project, at):
    """``at`` (the adjustment's record) with the inputs the chain's adjust_final stamp hashed, when the report records
    none (written before it did) and the stamp is this report's (its at/report.json hash is the file's): an upgraded
    project's unchanged inputs were judged by time, 4-161 ms newer than the report, "adjust again" while the chain
    said adjust_final up to date (trial-upgrade). The stamp's hashes are sha1 of the bytes; ``inputs_changed`` then
    compares by content. Else ``at`` as it is (by time)."""
    import hashlib

    from aerotri.adjust.report_record import adjustment_input_paths

    if at.inputs is not None:
        return at
    try:
        stamp = json.loads((project.stages_dir / "adjust_final.json").read_text())
        made = hashlib.sha1(project.adjustment_report_path.read_bytes()).hexdigest()
    except (OSError, ValueError):
        return at
    if not isinstance(stamp, dict) or (stamp.get("outputs") or {}).get("at/report.json") != made:
        return at
    recorded = stamp.get("inputs") or {}
    inputs = {}
    for path in adjustment_input_paths(project):
        rel = path.relative_to(project.root).as_posix()
        sha1 = recorded.get(rel)
        if isinstance(sha1, str) and path.is_file():
            data = path.read_bytes()
            # in the record's form (size and sha256): the file's own where the bytes are the stamp's, else a size no
            # file has (changed, whatever its time)
            same = hashlib.sha1(data).hexdigest() == sha1
            inputs[rel] = {"size": len(data) if same else -1, "sha256": hashlib.sha256(data).hexdigest()}
    return dataclasses.replace(at, inputs=inputs) if inputs else at


def build_qa_report(root, *, tolerance_file=None, terrain: str | None = None, scale: str | None = None,
                    standard: str | None = None, horizontal_class_cm: float | None = None,
                    vertical_class_cm: float | None = None, accuracy_class: str | None = None) -> QaReport:
    """The report of a project folder (``StageOrderError`` when no stage has left results yet). The
    tolerance table: the arguments (the command line), else ``[qa]`` of project.toml, else chosen by the
    block's GSD and platform (``aerotri.core.tolerances.choose_table``); the report names it and why."""
    from lidarctl.checks.classes import read_filter_test
    from ortho.check import read_dom_check

    project = Project.open(root)  # a project folder: project.toml with [project] crs
    root = project.root
    if not any(p.is_file() for p in stage_results(project)):
        raise StageOrderError(
            f"{root}: nothing to report yet, no stage has left its results "
            f"({', '.join(str(p.relative_to(root)) for p in stage_results(project))}); "
            f"run the adjustment first (aerotri match {root}, then aerotri adjust {root}) or the whole chain "
            f"(aerotri run {root})"
            + (f"; a LiDAR delivery alone: lidarctl strips check STRIPS... {project.strips_dir}, and against surveyed "
               f"points lidarctl check-heights [CLOUD...] POINTS.csv --dem DEM.tif --json {project.height_check_path}"
               if lidar_only_project(project) else ""))
    cfg = read_qa_config(root)
    if terrain and terrain not in TERRAINS and not (tolerance_file or cfg.tolerances):
        raise InputError(f"terrain class {terrain!r}: expected one of {', '.join(TERRAINS)}")
    block = project_block_scale(project)
    class_text = accuracy_class or project.qa.accuracy_class
    if (standard or cfg.standard) in ("asprs2023", "asprs2014") and class_text:
        hv = asprs_class_cm(class_text)
        if hv is None or min(hv) <= 0:  # (it was blamed on project.toml's classes, the text given not named)
            expected = "expected ASPRS classes as 'H<cm> V<cm>' with both above 0, e.g. 'H10 V10'"
            if accuracy_class:
                raise OptionError(f"--class {class_text!r}: {expected}", param="--class")
            raise ConfigError(f"project.toml [qa] accuracy_class {class_text!r}: {expected}")
    if (standard or cfg.standard) == "asprs2023" and (hv := asprs_class_cm(class_text)):
        # the class of the compliance section is the class of the verdict table too
        horizontal_class_cm, vertical_class_cm = horizontal_class_cm or hv[0], vertical_class_cm or hv[1]
    lidar_only = lidar_only_project(project)
    table = choose_table(cfg, block, scale=scale, standard=standard, terrain=terrain, tolerance_file=tolerance_file,
                         horizontal_class_cm=horizontal_class_cm, vertical_class_cm=vertical_class_cm,
                         lidar_only=lidar_only, accuracy_class=accuracy_class)
    compliance = project_compliance(project, table, block, standard, accuracy_class, terrain, lidar_only, scale)
    asprs2023_provenance = dict(table.provenance) if table.path == TOLERANCE_DIR / ASPRS_FILE else {}
    if compliance.key == "usgs-lbs":
        table = with_lbs_lidar_limits(table, compliance.class_tested, lidar_only=lidar_only)
    elif compliance.key == "asprs2014":
        table = with_asprs2014_limits(table, compliance.class_tested)
    elif compliance.key == "cn-at" and compliance.requested:  # the standard asked for sets the AT and DOM limits
        table = with_cn_at_limits(table, compliance.class_tested)
    elif compliance.key == "cn-at":
        table = with_cn_at_lidar_limits(table, compliance.class_tested)
    if lidar_only:
        table = lidar_limits(table)
    terrain_given = terrain is not None  # (--terrain: the terrain row's advice names the option, not project.toml)
    terrain, tol, tol_path = table.terrain, table.limits, table.path
    # the limits still ASPRS 2023's (the USGS LBS, Edition 1 or cn-at replaced some for the compliance standard)
    asprs = Asprs2023Figures.of_project(
        project, frozenset(k for k, p in asprs2023_provenance.items() if table.provenance.get(k) is p))
    tol_file = None if table.path.parent == TOLERANCE_DIR else table.path  # a user's own table
    at = (read_adjustment_report(project.adjustment_report_path)
          if project.adjustment_report_path.is_file() else None)
    ctl = (read_control_transfer(project.control_transfer_path)
           if project.control_transfer_path.is_file() else None)
    dom_check = read_dom_check(project.dom_report_path) if project.dom_report_path.exists() else None
    dom_check_stale = dom_check is not None and dom_check.stale_for(project.mosaic_path, project.dom_report_path)
    other_dom = dom_check.dom if dom_check_stale and dom_check.of_project_mosaic is False else None
    if dom_check_stale:  # its figures are of a mosaic that no longer exists (or of another DOM): not the DOM's
        dom_check = None
    dom = dom_check.displacement if dom_check else None
    hc = read_height_check(project.height_check_path) if project.height_check_path.is_file() else None
    ce = read_filter_test(project.classification_eval_path) if project.classification_eval_path.exists() else None
    rows, strips = strip_rows(project, tol)
    rows += _terrain_rows(project, terrain, given=terrain_given)
    # an NVA limit (ASPRS 2023, the USGS LBS) judges the open ground only; a map-scale or user's table every point
    nva = bool(getattr(table.provenance.get("dem_rmse_m"), "nva", False))

    # LiDAR
    sec = "LiDAR classification"
    if ce:
        # against a truth holding class 1 (a production classification) the total error is no measure: reported, not
        # judged (trial s100 rc2 M1: Autzen and lidR Topography failed at 54.7 / 18.8 %, type I 0.34 / 0.04 %)
        from lidarctl.checks.classes import truth_holds_unclassified

        coarse = truth_holds_unclassified(project.classification_eval_path)
        rows.append(_check("filter_total_error_pct", sec, "ground filter total error against the reference classes",
                           ce.total_error_pct, None if coarse else tol.get("filter_total_error_pct"), "%",
                           key="filter_total_error_pct", digits=3, note=(
                               "not judged: the reference's class 1 (unclassified) counts as object, and where it "
                               "holds ground (a production classification) the total and type II errors overstate; "
                               f"the type I error, {ce.type_i_error_pct:.3f} %, is the measure" if coarse else "")))
        rows.append(_check("filter_type_i_error_pct", sec, "type I error (ground rejected)",
                           round(ce.type_i_error_pct, 3), None, "%"))
        rows.append(_check("filter_type_ii_error_pct", sec, "type II error (objects accepted as ground)",
                           round(ce.type_ii_error_pct, 3), None, "%"))
        rows.append(_check("filter_kappa_pct", sec, "Cohen's kappa", round(ce.kappa_pct, 2), None, "%"))
    sec = "LiDAR height check"
    if hc is not None and hc.n_checked == 0:
        rows.append(_failed("dem_rmse_m", sec, "ground height check", "no surveyed point has ground points within the "
                                                                      "search radius (points in another CRS, or x and "
                                                                      "y swapped?)"))
    elif hc is not None and hc.n_checked:
        dz, which = judged_dz(hc.dz_m, hc.dz_groups, nva)
        rmse = (hc.rmse_m if not which else math.sqrt(sum(d * d for d in dz) / len(dz)) if dz else None)
        figure, combined = asprs.figure(rmse, "dem_rmse_m")
        rows.append(_check("dem_rmse_m", sec, f"ground height RMSE at {len(dz) if which else hc.n_checked} "
                           f"{which}surveyed points{asprs.quantity_suffix(rmse, 'dem_rmse_m')}", figure,
                           tol.get("dem_rmse_m"), "m", key="dem_rmse_m", digits=4,
                           note=_notes(combined,
                                       _outside_note(hc.outside_ids, hc.outside_groups, which,
                                                     f"with no ground point within {hc.radius_m:g} m" if hc.radius_m
                                                     else "with no ground point near"),
                                       _too_few_note(len(dz) if which else hc.n_checked, compliance))))
        if dz and tol.get("dem_rmse_m"):
            lim = 3.0 * tol["dem_rmse_m"]
            pct = 100.0 * sum(abs(d) > lim for d in dz) / len(dz)
            rows.append(_check("height_check_outlier_pct", sec,
                               f"{which}surveyed points with |dz| > {lim:.2f} m (3 x the RMSE limit)", pct,
                               tol.get("height_check_max_outlier_pct"), "%", key="height_check_max_outlier_pct",
                               digits=2))
            if which and (veg := vegetated_dz(hc.dz_m, hc.dz_groups)):
                # the NVA limit does not judge them (their own limit, if any, is in the compliance section)
                pct = 100.0 * sum(abs(d) > lim for d in veg) / len(veg)
                rows.append(_check("height_check_vegetated_outlier_pct", sec,
                                   f"vegetated surveyed points with |dz| > {lim:.2f} m", round(pct, 2), None, "%",
                                   note=f"{len(veg)} points; not judged: the limit is a non-vegetated (NVA) one"))
    if hc is not None and hc.dem_n_checked == 0:
        rows.append(_failed("dem_raster_rmse_m", sec, "DEM height check", "no surveyed point lies on valid cells of "
                                                                         f"{hc.dem_path} (points in another CRS?)"))
    elif hc is not None and hc.dem_n_checked:
        # the DEM raster is the product a contract judges (check-heights --dem; without a cloud the only figure)
        name = Path(hc.dem_path).name if hc.dem_path else "the DEM"
        dz, which = judged_dz(hc.dem_dz_m, hc.dem_dz_groups, nva)
        rmse = (hc.dem_rmse_m if not which else math.sqrt(sum(d * d for d in dz) / len(dz)) if dz else None)
        figure, combined = asprs.figure(rmse, "dem_rmse_m")
        rows.append(_check("dem_raster_rmse_m", sec, f"DEM ({name}) height RMSE at "
                           f"{len(dz) if which else hc.dem_n_checked} {which}surveyed points"
                           f"{asprs.quantity_suffix(rmse, 'dem_rmse_m')}",
                           figure, tol.get("dem_rmse_m"), "m", key="dem_rmse_m", digits=4,
                           note=_notes(combined, _outside_note(hc.dem_outside_ids, hc.dem_outside_groups, which,
                                                     f"with no valid cell of the DEM {name} under them"),
                                       _too_few_note(len(dz) if which else hc.dem_n_checked, compliance),
                                       hc.dem_z_unit_note)))

    rows += line_map_rows(project, tol, asprs)

    # Control and adjustment
    sec = "Control points"
    if ctl and ctl.summary:
        rows.append(_check("control_accepted", sec, "LiDAR corners accepted as control / check points",
                           f"{ctl.control_full} full + {ctl.control_height} height / {ctl.check_points} check",
                           None, ""))
        if ctl.layout_targets:
            empty = [t for t in ctl.layout_targets if t.corner is None]
            fb = sum(t.tier not in (None, "usable") for t in ctl.layout_targets)
            # the layout may put two targets at one place: named once, with their number
            texts = [empty_target_text(dataclasses.asdict(t)) for t in empty]
            note = "; ".join(text if texts.count(text) == 1 else
                             f"{texts.count(text)} {text.replace(' target ', ' targets ', 1)}"
                             for text in dict.fromkeys(texts))
            if fb:
                note = f"{fb} filled by fallbacks" + (f"; {note}" if note else "")
            rows.append(_check("layout_targets_filled", sec, "layout targets with a control point",
                               f"{len(ctl.layout_targets) - len(empty)} of {len(ctl.layout_targets)}", None, "",
                               note=note))
    if at and at.counts.get("control_points") == 0:
        used = sum(c.used or 0 for c in at.surface_control)
        if used:  # the DEM (roof planes) held the tie points: the block's height and tilts are the surface's (s95)
            note = (f"no LiDAR control points; surface control: {used} tie points on the DEM hold the block's "
                    f"heights{' with the GNSS' if at.gnss_given else ''}")
        else:
            note = "no LiDAR control: " + ("the datum comes from GNSS alone" if at.gnss_given else
                                           "no datum from control")
        rows.append(_check("control_points_used", sec, "control points in the adjustment", 0, None, "", note=note))
        chk_z = at.check_rms_m[2] if at.check_rms_m and len(at.check_rms_m) > 2 else None
        if not used and chk_z is None and not (at.check_dem and at.check_dem.median_m is not None):
            rows.append(_check(HEIGHTS_UNCHECKED, sec, "block heights checked (control, DEM or check points)", "no",
                               None, "", note=heights_unchecked_words(at.gnss_given, at.height_shares)))
    ctrl = at.control_rms_m if at else None
    # plan and height each when there is one: plan-only control (the kite block's targets) has no height RMS
    if ctrl and None not in ctrl[:2]:
        rows.append(_check("control_rms_xy_m", sec, "control residuals, plan RMS", math.hypot(ctrl[0], ctrl[1]),
                           tol.get("rms_xy_m"), "m", key="rms_xy_m", digits=4))
    if ctrl and len(ctrl) > 2 and ctrl[2] is not None:
        rows.append(_check("control_rms_z_m", sec, "control residuals, height RMS", ctrl[2], tol.get("rms_z_m"), "m",
                           key="rms_z_m", digits=4))
    if at:
        rows.append(_check("control_rejected", sec, "control points rejected by the adjustment",
                           len(at.rejected_control), None, "", note=", ".join(at.rejected_control)))
    sec = "Aerotriangulation"
    ks = at.key_statistics if at else None
    if ks:
        # the adjustment's verdict, not only "products written": a weak solution (geometry held by GNSS and priors
        # alone, a calibration group fixed, frames left out) is not "Solution Successful" here either
        rows.append(_check("solution_successful", sec, "solution successful", ks.successful, True, "", note=ks.message))
        s0_px = at.sigma0_in_px
        if s0_px is not None and math.isfinite(s0_px):
            rows.append(_check("sigma0_px", sec, "sigma naught", s0_px, _sigma0_limit_px(tol, ks, s0_px),
                               "px", digits=3, note=f"{ks.sigma0_um:.2f} um" if ks.sigma0_um is not None else "",
                               key="sigma0_max_px" if tol.get("sigma0_max_px") is not None else "sigma0_max_um"))
    if at and at.frames_left_out:
        # trial-relief F2: half a block left out (a split block, frames over the sea) stood only in the solution's
        # note; the DOM's "seen by no frame" share is of the oriented frames' extent and missed it
        left = at.frames_left_out
        n_all = int(at.counts.get("images") or 0) + len(left)
        why = "; ".join(dict.fromkeys(r for _, r in left))
        rows.append(_check("frames_not_oriented", sec, "frames the adjustment left out", len(left), 0, "",
                           note=f"{', '.join(k for k, _ in left[:10])}{' ...' if len(left) > 10 else ''} "
                                f"({len(left)} of {n_all}): {why}; no orientation, ortho or DOM cover for them"))
    # by content against the inputs at/report.json records (a copy of the project, new file times, is the same
    # adjustment: trial-gis F9); a report written before that record: by time
    changed, by_content = inputs_changed(project, _with_stamp_inputs(project, at)) if at else ([], False)
    if changed:
        # trial-kite: control re-imported (a target moved 3 m), or an adjustment that failed after it: the report
        # gave the old check RMS, exit 0; aerotri run adjusts again, aerotri report alone cannot
        log.warning(f"{project.adjustment_report_path}: {', '.join(changed)} changed after this adjustment: its "
                    f"figures are of the inputs before; adjust again (aerotri adjust {root})")
        rows.append(_check("adjustment_current", sec, "adjustment made from the current inputs", False, True, "",
                           note=f"{', '.join(changed)} "
                                + ("changed since the adjustment (not the content at/report.json records)"
                                   if by_content else "written after at/report.json") + ": adjust again"))
    failed = project.work_dir / "adjust_failed" / "report.json"
    if at and failed.is_file() and failed.stat().st_mtime > project.adjustment_report_path.stat().st_mtime:
        # kite trial: an adjustment with other check points failed after this one, and the report gave the earlier
        # one's check points and figures without a word
        why = ""
        try:
            message = str(read_json(failed, "failed adjustment report").get("key_statistics", {}).get("message", ""))
            why = message.split(". ")[0].rstrip(".")  # its first sentence: "Solution failed: ..."
        except (InputError, AttributeError):
            pass
        log.warning(f"{failed}: a later adjustment failed ({why or 'its report there'}); this report's adjustment "
                    f"figures are of the one before it ({project.adjustment_report_path})")
        rows.append(_check("adjustment_latest", sec, "the latest adjustment is the one reported", False, True, "",
                           note=f"a later one failed ({failed.parent}/report.txt"
                                + (f": {why}" if why else "") + "); these figures are of the one before"))
    if at and not at.heights_measured:
        # trial-kite: the consolidated report said nothing of heights nobody measured (at/report.txt's DATUM did)
        rows.append(_check("heights_measured", sec, "heights measured", "no", None, "",
                           note="plan-only control, no GNSS or DEM: every height (EO, DEM, points, exports) is "
                                "relative, 0 at the control points' median ground; at/report.txt DATUM"))
    if at and at.control_to_tie_ratio is not None:
        # the PATB-table rule of thumb (docs/reports.md): not a contract limit, so reported, not judged
        ratio = at.control_to_tie_ratio
        rows.append(_check("control_to_tie_residual_ratio", sec, "control / tie image residuals, RMS ratio",
                           round(ratio, 2), None, "", note=("above 10: a systematic error (camera, GNSS, datum or "
                                                            "control coordinates) is worth compensating" if ratio > 10.0
                                                            else "about 4 is normal, around 10 points at a systematic "
                                                            "error") + "; not judged"))
    if at:
        rows += leave_one_out_rows(project, sec)
    chk = at.check_rms_m if at else None
    if chk and None not in chk[:2]:  # chk[2] None: plan-only check points (heights not surveyed), no height row
        # the points with a residual: a check point seen in fewer than two frames is not intersected (no residual,
        # not in the RMS) and does not count towards a standard's minimum (trial-qa: "8 points" over 5 residuals)
        n = sum(math.isfinite(a) and math.isfinite(b) for a, b, _ in at.check_residuals_m)
        npts = f"{n} points" + (f" ({'all' if at.check_points_from_lidar >= n else at.check_points_from_lidar} LiDAR "
                                "roof corners, not surveyed)" if at.check_points_from_lidar else "")
        if at.check_points > n:
            npts += (f"; {at.check_points - n} more of the {at.check_points} check points not intersected (seen in "
                     "fewer than 2 frames: no residual, at/report.txt)")
        need = tol.get("check_points_min")
        if need:
            short = f"{need:g} required by {table.name.split(':')[0]}"
            npts += f" ({short}: not testable as the standard asks)" if n < need else f" ({short})"
            rows.append(_check("check_points_count", sec, "check points for the accuracy assessment", n, None, "",
                               note=f"at least {need:g} required" + (": too few, the RMS rows below are indicative only"
                                                                if n < need else ""), key="check_points_min"))
        figure, combined = asprs.figure(math.hypot(chk[0], chk[1]), "rms_xy_m")
        rows.append(_check("check_rms_xy_m", sec, "check points, plan RMS"
                           f"{asprs.quantity_suffix(math.hypot(chk[0], chk[1]), 'rms_xy_m')}", figure,
                           tol.get("rms_xy_m"), "m", note=_notes(npts, combined), key="rms_xy_m", digits=4))
        if chk[2] is not None:
            nz = sum(math.isfinite(a) and math.isfinite(b) and math.isfinite(c) for a, b, c in at.check_residuals_m)
            figure, combined = asprs.figure(chk[2], "rms_z_m")
            rows.append(_check("check_rms_z_m", sec, "check points, height RMS"
                               f"{asprs.quantity_suffix(chk[2], 'rms_z_m')}", figure, tol.get("rms_z_m"), "m",
                               note=_notes(npts if nz == n else f"{nz} with a surveyed height of {npts}", combined),
                               key="rms_z_m", digits=4))
        d = at.check_residuals_m
        # Gross errors: single residuals beyond the residual limit (2 x the RMS limit); a few percent
        # of them is tolerated (their share is limited, not their existence).
        for k, (name, lim) in enumerate((("plan", tol.get("residual_xy_m")), ("height", tol.get("residual_z_m")))):
            e = [math.hypot(a, b) if k == 0 else abs(c) for a, b, c in d]
            e = [x for x in e if math.isfinite(x)]  # heights not surveyed are no residuals
            if e and lim:
                big = sum(x > lim for x in e)
                rows.append(_check(f"check_gross_{'xy' if k == 0 else 'z'}_pct", sec,
                                   f"check points with a {name} residual beyond {lim:g} m",
                                   100.0 * big / len(e), tol.get("gross_error_max_pct"), "%",
                                   note=f"{big} of {len(e)}", key="gross_error_max_pct", digits=2))

    cd = at.check_dem if at else None
    if cd is not None and cd.median_m is not None:
        # the block's heights against a DEM given only to check them (trial s100 rc F4: 7.9 m below it, "passed" in
        # the adjustment's 3-sigma test, and nowhere in this report, which said the heights were not checked)
        rows.append(_check("check_dem_offset_m", "Aerotriangulation", "tie points against the check DEM, |median| "
                           "height offset", abs(cd.median_m), tol.get("rms_z_m"), "m",
                           note=f"median {cd.median_m:+.3f} m (tie point - DEM) over {cd.n} tie points on the ground; "
                           f"{cd.dem} (--check-dem: compared, not held)", key="rms_z_m", digits=4))

    # DOM
    sec = "DOM"
    lost = dom_check.unmatched if dom_check else None  # textured patches without a match (None: an older report)
    if dom and dom.count == 0:
        rows.append(_failed("dom_rms_xy_m", sec, "displacement of the DOM",
                            f"the check found no usable patch: {lost.note()}" if lost and lost.patches else
                            "the check found no usable patch or point (no texture, no ground under --max-ndsm-m, or "
                            "the reference misses the DOM)"))
    at_points = _dom_points(dom_check, project) if dom and dom.rms_xy_m is not None else None
    if at_points is not None and at_points.displacement.count == 0:
        # every point the adjustment's control: nothing independent to judge, so no figure (never a pass)
        rows.append(QaCheck("dom_rms_xy_m", sec, "displacement at surveyed points, plan RMS", None,
                            tol.get("feature_rms_xy_m"), "m",
                            f"not testable: {at_points.left_out_note()}, none other; measure the DOM at check points "
                            f"the adjustment did not use{_dom_crs_note(dom_check, project)}", None, "feature_rms_xy_m"))
    elif dom and dom.rms_xy_m is not None:
        # at surveyed points: those the adjustment did not use (the compliance row's figure), the others said
        judged = at_points.displacement if at_points is not None else dom
        gsd = judged.rms_xy_gsd if judged.rms_xy_gsd is not None else float("nan")
        what = "on ground patches" if at_points is None else "at surveyed points"
        left_out = f"; {at_points.left_out_note()}" if at_points is not None and at_points.control_ids else ""
        figure, combined = asprs.figure(judged.rms_xy_m, "feature_rms_xy_m")
        rows.append(_check("dom_rms_xy_m", sec, f"displacement {what}, plan RMS"
                           f"{asprs.quantity_suffix(judged.rms_xy_m, 'feature_rms_xy_m')}", figure,
                           tol.get("feature_rms_xy_m"), "m", digits=4,
                           note=f"{judged.count} {'points' if at_points is not None else 'patches'}, {gsd:.2f} GSD"
                           f"{_dom_cell_words(judged)}{left_out}{_dom_crs_note(dom_check, project)}"
                           + (f"; {combined}" if combined else ""),
                           key="feature_rms_xy_m"))
        if lost is not None and lost.fails():
            # the RMS is of the patches matched: a DOM (or a frame's region) off by more than the search lost its
            # patches there, and the rest passed (``ortho.check.UnmatchedPatches``). A fail only where the search
            # reaches the limit (a patch beyond it is then beyond the limit), and only against a limit (review 34)
            gsd_m = dom.rms_xy_m / dom.rms_xy_gsd if dom.rms_xy_gsd else None
            judged_lost = lost.judged_against(tol.get("feature_rms_xy_m"), gsd_m)
            why = f"; {judged_lost.why}" if judged_lost.why else ""
            if lost.too_few_matched():
                # most of the DOM matched nothing: the few patches that did (false matches, as likely as not) are no
                # measure of it, so no figure (trial audit F6: 2 of 633 gave "2.370 m" for a DOM 5 m off)
                rows[-1] = dataclasses.replace(
                    rows[-1], value=None, verdict=judged_lost.verdict,
                    note=f"{'failed because the patches did not match: ' if judged_lost.verdict else ''}{lost.note()}"
                         f"{judged_lost.reach}{why}; the {dom.count} that matched are too few to measure the DOM "
                         "(no figure)")
                judged = dataclasses.replace(judged, p95_xy_m=None)  # nor a 95th percentile of them
            else:
                rows[-1] = dataclasses.replace(rows[-1], verdict=judged_lost.verdict,
                                               note=f"{lost.note()}{judged_lost.reach}{why}; {rows[-1].note}")
        elif lost is not None and lost.unusual():  # (trial-ortho2: a DOM half mirrored, 38 % lost, passed unsaid)
            rows[-1] = dataclasses.replace(rows[-1], note=f"warning: {lost.unusual_note()}; {rows[-1].note}")
        elif lost is not None and lost.patches:
            rows[-1] = dataclasses.replace(rows[-1], note=f"{rows[-1].note}; {lost.patches} of {lost.textured} "
                                                          "textured patches without a match")
        if judged.p95_xy_m is not None and tol.get("feature_rms_xy_m") and tol.get("gross_error_max_pct") == 5.0:
            # 95th percentile within 2 x the RMS limit <=> at most 5 % gross errors.
            largest = judged.max_xy_m if judged.max_xy_m is not None else float("nan")
            # under an ASPRS table the row says what it is in its name: ASPRS 2023 states RMSE only, and Edition 1's
            # 95 % figure (1.7308 x RMSE_r) is another limit (trial-qa read this one as ASPRS's)
            under_asprs = compliance.key.startswith("asprs") or table.key.upper().startswith("ASPRS")
            rows.append(_check("dom_p95_xy_m", sec, "95th percentile of the "
                               f"{'point' if at_points is not None else 'patch'} displacements"
                               + (" (the gross-error rule, not an ASPRS measure)" if under_asprs else ""),
                               judged.p95_xy_m, 2 * tol["feature_rms_xy_m"], "m", digits=4,
                               note=f"largest {largest:.3f} m; " "limit 2 x the RMS limit (at most 5 % gross errors)",
                               key="feature_rms_xy_m"))
    if dom_check_stale and other_dom:
        rows.append(_failed("dom_check_stale", sec, "DOM check of another DOM",
                            f"the DOM was not checked: {project.dom_report_path} measured {other_dom} (ortho check "
                            f"--dom), not {project.mosaic_path}; re-run ortho check {root} --reference REF.tif (a "
                            "check of another DOM now goes beside that DOM)"))
    elif dom_check_stale:
        rows.append(_failed("dom_check_stale", sec, "DOM check of an earlier mosaic",
                            f"the DOM was not checked: {project.dom_report_path} measured an earlier "
                            f"{project.mosaic_path} (the mosaic was made again since, e.g. by aerotri run without "
                            f"--reference, which does not check it); re-run ortho check {root} --reference REF.tif (or "
                            "aerotri run --reference)"))
    elif not dom_check and project.mosaic_path.is_file():  # said, not judged: no reference was given
        rows.append(QaCheck("dom_not_checked", sec, "DOM not checked", None, None, "",
                            f"no DOM check ({project.dom_report_path.name}): no reference orthophoto was given; "
                            f"ortho check {root} --reference REF.tif (or aerotri run --reference REF.tif)", None))
    if dom_check and dom_check.roofs is not None:
        rows.append(_roofs_row(sec, dom_check, project))
    if project.frames_index_path.is_file() and (dom_check or project.mosaic_path.is_file()):
        from ortho.block import read_index, say_surfaces_changed, stale_frames, surfaces_changed

        index = read_index(root)
        why = stale_frames(root, index, say_surfaces=False)  # (the surfaces once, below: a changed one is hashed)
        if why:
            rows.append(_failed("dom_stale", sec, "DOM from an older adjustment",
                                f"{why}; re-run ortho rectify, ortho mosaic and ortho check"))
        # said, not judged (the DOM and its check are of the surface it was made on; the chain rectifies again): a
        # DOM on the DSM before `lidarctl rasters` was run again read "true ortho on the DSM" and passed, only the
        # console said so (trial-upgrade F4)
        changed = surfaces_changed(root, index)
        if not why:
            say_surfaces_changed(project.frames_index_path, changed)
        if changed:
            rows.append(QaCheck("dom_surface_changed", sec, "DOM made on an earlier surface", None, None, "",
                                "; ".join(f"{f} ({what}) changed since the frames were rectified on it"
                                          for what, f in changed)
                                + f": re-run ortho rectify, ortho mosaic and ortho check (or aerotri run {root})",
                                None))
    if project.mosaic_summary_path.is_file():
        from ortho.mosaic import mosaic_older_than_frames

        older = mosaic_older_than_frames(root)
        if older:  # the mosaic's figures (and a check of it) are of frames that were replaced
            rows.append(_failed("mosaic_stale", sec, "DOM older than its frames",
                                f"{older}; re-run ortho mosaic {root} (and ortho check), or aerotri run {root}"))
        from ortho.mosaic import read_mosaic_summary

        m = read_mosaic_summary(project.mosaic_summary_path)  # (once for its three rows)
        rows.append(_holes_row(sec, m))
        rows += [r for r in (_without_heights_row(sec, m, tol), _seam_crossings_row(sec, m)) if r is not None]
    if dom_check:
        rows += _seam_rows(sec, dom_check, tol)

    # Flight acceptance: from the adjustment's report when it has the section, else computed here (before
    # the adjustment: GNSS positions with the nominal attitude)
    fa = at.flight_acceptance if at else None
    if fa and at.frames_left_out and not {k for k, _ in at.frames_left_out} <= {f.get("image_id") for f in
                                                                                fa.get("frames") or ()}:
        fa = None  # written before the left-out frames were in it (trial-relief F1): computed here, with them
    if fa is None and (project.eo_path.is_file() or project.gnss_path.is_file()) and project.camera_path.is_file():
        got = project_flight_acceptance(root, tol, terrain=_footprint_terrain(project))
        fa = dataclasses.asdict(got) if got is not None else None
    if fa:
        # judged by this report's table (its platform), whatever the adjustment's section was held to
        fa = {**fa, "spec": tol.get("flight_spec") or fa.get("spec"),
              "limits": {k: tol.get(k) for k in LIMIT_KEYS}}
        rows += flight_rows(fa, tol)
    elif project.eo_path.is_file() or project.gnss_path.is_file():
        missing = (f"no {project.camera_path.name}" if not project.camera_path.is_file() else
                   f"no DEM ({project.dem_path.relative_to(project.root)}, the frame orthos' or the adjustment's) "
                   "and no [flight] mean_terrain_height_m in project.toml to put the footprints on")
        rows.append(_check("flight_acceptance", "Flight acceptance", "flight acceptance", None, None, "",
                           note=f"not measured: {missing}"))

    verdicts = [r.verdict for r in rows if r.verdict]
    overall = overall_verdict(verdicts, dataclasses.asdict(compliance))
    if overall == "pass" and any(r.id == HEIGHTS_UNCHECKED for r in rows):
        overall = NOT_TESTABLE  # (every row passes, but nothing measured the block's heights: not "pass")
    ks_info = dict(sigma0_um=ks.sigma0_um, iterations=ks.iterations) if ks else dict(sigma0_um=None, iterations=None)
    info = dict(
        adjustment=dict(**ks_info, counts=at.counts or None,
                        check_normalised_rms=list(at.check_normalised_rms) if at.check_normalised_rms else None,
                        sigmas=_sigma_basis(at), check_points_from_lidar=at.check_points_from_lidar or None)
        if at else None,
        control_transfer=(ctl.summary or None) if ctl else None,
        lidar_strips=strips,
        lidar_height_bins=hc.bins if hc else None,
        lidar_height_groups=(hc.groups or None) if hc else None,
        lidar_classification=dataclasses.asdict(ce) if ce else None,
        dom=to_record(dom, drop_none=True) if dom else None,
    )
    # where each limit comes from; an unconfirmed one is marked
    prov = [table.provenance.get(r.limit_key or "") for r in rows]
    rows = tuple(dataclasses.replace(r, limit_source=p.source if p is not None else None,
                                     limit_confirmed=p.confirmed if p is not None else None)
                 for r, p in zip(rows, prov))
    return QaReport(project=(at.project if at and at.project else root.name),
                    map_scale=tol_path.stem if tol_file else split_key(table.key)[0],
                    tolerance_table=str(tol_path.name), terrain=terrain, tolerances=tol,
                    table=_table_record(table, lidar_only),
                    block=dataclasses.asdict(block), checks=rows,
                    overall=overall,
                    passed=verdicts.count("pass"), failed=verdicts.count("fail"), details=info,
                    flight_acceptance=fa, compliance=dataclasses.asdict(compliance),
                    not_judged=tuple(r.id for r in rows if r.verdict is None and r.limit is not None))


def _cell(v) -> str:
    """A value as verdict-table text (the template escapes it): None empty, true/false as yes/no (as the
    adjustment report's tables have them), floats to 4 significant digits."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _value_cell(value, limit) -> str:
    """A judged value as verdict-table text: ``_cell``, with the digits that keep it on its side of ``limit``."""
    if isinstance(value, float) and isinstance(limit, (int, float)) and not isinstance(limit, bool):
        return text_on_its_side(value, limit)
    return _cell(value)


def _label(key: str) -> str:
    """A JSON key as a column or row label: words, with the unit in brackets (``rms_xy_m`` -> rms xy (m))."""
    units = {"m": "m", "pct": "%", "um": "um", "px": "px", "gsd": "GSD", "deg": "deg", "s": "s", "km": "km"}
    parts = key.split("_")
    if len(parts) > 1 and parts[-1] in units:
        return " ".join(parts[:-1]) + f" ({units[parts[-1]]})"
    return key.replace("_", " ")


@dataclasses.dataclass(frozen=True)
class DetailBlock:
    """One piece of the report's "Details": a table, a heading (``level`` 4-6) or a paragraph (``text``)."""

    table: RF.Table | None = None
    level: int = 0
    text: str = ""


def detail_blocks(value, depth: int = 0) -> list[DetailBlock]:
    """A stage's numbers as tables: scalars as name/value rows, lists of records as tables, nested
    objects as their own small tables under a heading (no JSON)."""
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        cols = list(dict.fromkeys(k for v in value for k in v))
        # floats unrounded into the table's 3 decimals: rounded to 4 first, 0.04749 became 0.0475 and then 0.048
        return [DetailBlock(RF.table([_label(c) for c in cols],
                                     [[x if isinstance(x := v.get(c), float) else _scalar(x) for c in cols]
                                      for v in value], 3, num_from=0))]
    if isinstance(value, dict):
        flat = [[_label(k), _scalar(v)] for k, v in value.items() if not isinstance(v, (dict, list)) or
                (isinstance(v, list) and all(not isinstance(x, (dict, list)) for x in v))]
        out = [DetailBlock(RF.table(["quantity", "value"], flat, 4))] if flat else []
        for k, v in value.items():
            if isinstance(v, dict) or (isinstance(v, list) and v and any(isinstance(x, (dict, list)) for x in v)):
                out += [DetailBlock(level=min(4 + depth, 6), text=_label(k)), *detail_blocks(v, depth + 1)]
        return out
    return [DetailBlock(text=str(_scalar(value)))]


def _scalar(v):
    if isinstance(v, list):
        return ", ".join(_cell(x) for x in v)
    if isinstance(v, float):
        return round(v, 4)
    return v


def report_figures(rep: QaReport, project: Project) -> list:
    """The adjustment's figures (drawn from at/report.json, as in at/report.html) and the flight map."""
    if project.adjustment_report_path.is_file():
        from aerotri.adjust.report import report_figures as at_figures

        # the figures draw from the whole report, not only the fields the record types
        at = read_record(project.adjustment_report_path, ADJUSTMENT_REPORT, SCHEMA_VERSION)
        at = {**at, "flight_acceptance": rep.flight_acceptance or at.get("flight_acceptance")}
        return at_figures(at)
    fig = RF.flight_map(rep.flight_acceptance or {})
    return [fig] if fig is not None else []


STAGE_LINKS = (("../at/report.html", "adjustment (ISAT layout)"), ("../at/report.txt", "report.txt"),
               ("../control/review/review.html", "control transfer review"), ("../ortho/dom_report.json", "DOM check"),
               ("../lidar_out/height_check.json", "LiDAR height check"),
               ("../lidar_out/strips/index.html", "LiDAR strip differences"))
STAGE_IMAGES = (("../ortho/dom_report.png", "DOM displacement against the reference"),
                ("../at/connectivity.png", "Tie-point connectivity"))


def _tolerance_section(rep: dict) -> dict | None:
    """The tolerance table that judged the block: name, file, why it was chosen, the flight specification,
    and each limit with its source (unconfirmed ones marked)."""
    t = rep.get("table") or {}
    if not t:
        return None
    prov = t.get("provenance") or {}
    rows = [[k, _scalar(v), "yes" if prov.get(k, {}).get("confirmed") else ("no" if k in prov else ""),
             prov.get(k, {}).get("source", "")]
            for k, v in (rep.get("tolerances") or {}).items() if k not in ("flight_spec", "flight_limits_apply")]
    return dict(name=t.get("name", ""), file=t.get("file", ""), reason=t.get("reason", ""),
                flight_spec=str(t.get("flight_spec") or ""),
                limits=RF.table(["limit", "value", "confirmed in the source", "source"], rows, 4))


VERDICT_COLOURS = {"pass": "#ccffcc", "fail": "#ffcccc", "not testable": "#eeeeee", "reported": "#ddeeff"}
COMPLIANCE_HEADER = ["product", "quantity", "class", "measured", "figure", "limit", "check points (or what was counted)",
                     "accurate", "verdict", "finest class met"]


def _num(v, star: bool = False) -> str:
    return "" if v is None else f"{v:.4g}" + ("*" if star else "")


def _row_outside_cell(c: dict) -> str:
    """A compliance check's points without a dz, for its table cell and console line (``outside_text``)."""
    from aerotri.qa.compliance import OUTSIDE_IDS_SHOWN, outside_text

    return outside_text(c.get("outside_ids") or (), c.get("outside_why") or "", c.get("outside_unknown_ids") or (),
                        shown=OUTSIDE_IDS_SHOWN)


def checkpoints_accuracy_text(c: dict, words=("yes", "no")) -> str:
    """Whether a compliance check's check points are accurate enough: ``words`` for True / False; None is "unknown"
    when their accuracy is not stated (the note says "not stated"), else "not judged": the standard sets no rule
    for them (the thesis tables, cn-at's LiDAR and AT height rows), whatever survey accuracy project.toml gives (it
    read "accuracy unknown" beside [qa] survey_sigma_z_m = 0.01)."""
    if c["checkpoints_accurate"] is not None:
        return words[0] if c["checkpoints_accurate"] else words[1]
    return "unknown" if "not stated" in (c.get("checkpoints_note") or "") else "not judged"


def compliance_row(c: dict) -> list:
    """A compliance check as table cells: figure and limit in the check's unit, the limit marked * when its
    number is not confirmed in the standard's text."""
    counted = c.get("counted") or "check points"  # (a summary.json of before it was recorded: check points)
    need = (f"{c['n_points']}" + ("" if counted == "check points" else f" {counted}")
            + (f" ({c['n_required']} check points required)" if c["n_required"] else "")
            + (f"; {_row_outside_cell(c)}" if c.get("n_outside") else "")
            if c["n_points"] is not None else "")
    # (no point: no accuracy to judge)
    acc = checkpoints_accuracy_text(c) if c["n_points"] else ""
    verdict = c["verdict"] + (f": {c['why']}" if c["why"] else "")
    return [c["product"], c["quantity"], c["class_tested"], _num(c["measured"]),
            _value_cell(c["figure"], c["limit"]),
            _num(c["limit"], c["limit_confirmed"] is False) + (f" {c['unit']}" if c["limit"] is not None else "")
            + (f" (verdict table: {c['verdict_table_m']:g} m)" if c.get("verdict_table_m") is not None else ""),
            need, acc, verdict, c["finest_class"] or ""]


def verdict_class(verdict: str) -> str:
    """The page's CSS class of a verdict: "not testable" -> "not-testable" (its first word, "not", styled nothing)."""
    return verdict.split(" (")[0].split(":")[0].strip().replace(" ", "-")


def compliance_verdict(comp: dict | None) -> str:
    """The verdict of ``compliance_headline``: fail, not testable or pass ("" without a standard)."""
    if not comp or not comp.get("products"):
        return ""
    verdicts = [p["verdict"] for p in comp["products"] if p["verdict"] != "reported"]  # (regulated by none)
    return ("fail" if "fail" in verdicts else
            "not testable" if not verdicts or any(v.startswith("not testable") for v in verdicts) else "pass")


def _compliance_section(comp: dict | None) -> dict | None:
    """The compliance section: standard, class and why; per product the verdict and the finest class met; every
    check with its figure, limit (source in the title, * unconfirmed), check points and verdict."""
    if not comp:
        return None
    checks = [dict(cells=[str(x) for x in compliance_row(c)], limit_source=c["limit_source"] or "",
                   note=c["checkpoints_note"] or "", verdict_class=verdict_class(c["verdict"])) for c in comp["checks"]]
    products = [{**p, "verdict_class": verdict_class(p["verdict"])} for p in comp["products"]]
    return dict(name=comp["name"], class_tested=comp["class_tested"], reason=comp["reason"], products=products,
                header=COMPLIANCE_HEADER, checks=checks, unconfirmed="; ".join(comp["unconfirmed"]),
                statements=comp.get("statements") or [], statements_note=STATEMENTS_NOTE,
                nothing=NOTHING_JUDGED if standard_judges_nothing(comp) else "")


def standard_fails_report(comp: dict | None) -> bool:
    """Whether the compliance section fails the report's overall verdict: a standard asked for (--standard, project.toml
    [qa] standard) with a product that fails ("not testable" does not fail it). A LiDAR-only folder under --standard
    usgs-lbs read "Overall verdict: pass (3 passed, 0 failed)" beside "compliance ... QL2: fail (LiDAR DEM, LiDAR
    density)"; a standard the tolerance table chose is stated beside the verdict, as before."""
    return bool(comp and comp.get("requested") and any(p["verdict"] == "fail" for p in comp.get("products") or ()))


def standard_judges_nothing(comp: dict | None) -> bool:
    """Whether a standard was asked for and the project holds nothing it judges (no product with a measured figure
    or a check of it). Trial s94: a LiDAR-only folder with the classification's evaluation alone, `aerotri report P
    --standard usgs-lbs`, read "pass (1 passed, 0 failed; USGS Lidar Base Specification, QL2)", the compliance
    section empty: the pass was the project's own ground-filter limit."""
    return bool(comp and comp.get("requested") and not comp.get("products"))


NOTHING_JUDGED = ("nothing it judges was found: aerotriangulation (at/report.json), the DOM check, the line-map "
                  "check, the LiDAR DEM's height check (lidar_out/height_check.json: lidarctl check-heights ... "
                  "--json), the strip check (lidar_out/strips/) or the density (lidar_out/dem.tif with the "
                  "classified cloud)")


def standard_untestable(comp: dict | None) -> list[str]:
    """The products of a standard asked for that it cannot test (too few check points, check points not accurate
    enough, nothing measured), none failing: a delivery that cannot be accepted under the contract's standard."""
    if not comp or not comp.get("requested") or standard_fails_report(comp):
        return []
    return [p["product"] for p in comp.get("products") or () if p["verdict"].startswith(NOT_TESTABLE)]


def overall_verdict(verdicts: list, comp: dict | None) -> str | None:
    """The report's overall verdict: "fail" when a row of the verdict table fails or a product of the standard asked
    for fails (``standard_fails_report``); else "not testable" when a product of the standard asked for is
    (``standard_untestable``; trial-qa: 10 of the 30 check points ASPRS asks for read "pass"); "pass" when the table's
    rows pass, None when no row has a verdict."""
    if "fail" in verdicts or standard_fails_report(comp):
        return "fail"
    if standard_untestable(comp) or standard_judges_nothing(comp):
        return NOT_TESTABLE
    return "pass" if verdicts else None


def standard_fails_note(comp: dict | None) -> str:
    """Said after the compliance headline when the standard fails the overall verdict (``standard_fails_report``) or
    makes it not testable (``standard_untestable``)."""
    if standard_fails_report(comp):
        return "the standard asked for: the overall verdict fails with it"
    if standard_untestable(comp):
        return "the standard asked for cannot test it: the overall verdict is not testable"
    if standard_judges_nothing(comp):
        return "the standard asked for judges nothing here: the overall verdict is not testable"
    return ""


def compliance_headline(comp: dict | None) -> str:
    """The compliance section's verdict in one phrase, for beside the verdict table's overall verdict (the two
    judge different things: a LiDAR-only report under usgs-lbs read "Overall verdict: pass" at its top while the
    standard's VVA and density failed below): "" without a standard; the products that fail (else are not
    testable) named."""
    if standard_judges_nothing(comp):
        return f"compliance with {comp['name']}, class {comp['class_tested']}: not testable (nothing it judges found)"
    if not comp or not comp.get("products"):
        return ""
    fails = [p["product"] for p in comp["products"] if p["verdict"] == "fail"]
    untested = [p["product"] for p in comp["products"] if p["verdict"].startswith("not testable")]
    verdict = compliance_verdict(comp)
    named = fails or untested
    return (f"compliance with {comp['name']}, class {comp['class_tested']}: {verdict}"
            + (f" ({', '.join(named)})" if named else ""))


def compliance_lines(comp: dict | None) -> list[str]:
    """The console lines of the compliance section."""
    if not comp:
        return []
    lines = [f"compliance: {comp['name']}, class {comp['class_tested']} ({comp['reason']})"]
    if standard_judges_nothing(comp):
        lines.append(f"  not testable: {NOTHING_JUDGED}")
    for p in comp["products"]:
        met = "" if p["finest_class"].startswith("not established") else "met "
        lines.append(f"  {p['verdict']:<12} {p['product']}: finest class {met}{p['finest_class']}")
    for st in comp.get("statements") or ():
        both = f"{st['text']} ({st['why']})" if st['text'] and st['why'] else st['text'] or st['why']
        lines.append(f"  statement, {st['product']}: {both}")
    for c in comp["checks"]:
        star = "*" if c["limit_confirmed"] is False else ""
        acc = checkpoints_accuracy_text(c, ("accurate enough", "not accurate enough"))
        acc = acc if c["checkpoints_accurate"] is not None else f"accuracy {acc}"
        pts = f"{c['n_points']} {c.get('counted') or 'check points'}" + \
            (f", {c['n_required']} check points required" if c["n_required"] else "") + (f", {acc}" if c["n_points"] else "") + \
            (f", {_row_outside_cell(c)}" if c.get("n_outside") else "") \
            if c["n_points"] is not None else ""
        unit = f" {c['unit']}" if c.get("unit") else ""
        figure = f"{_value_cell(c['figure'], c['limit'])}{unit}" if c["figure"] is not None else "not measured"
        limit = f"limit {_num(c['limit'])}{unit}{star}" if c["limit"] is not None else "no limit"
        lines.append(f"    {c['verdict']:<12} {c['product']}: {c['quantity']} = {figure} "
                     f"({'; '.join(x for x in (limit, pts) if x)})" + (f"; {c['why']}" if c["why"] else ""))
    return lines


def format_html(rep: dict, figures: list | None = None, stage_images=STAGE_IMAGES, stage_links=STAGE_LINKS) -> str:
    """index.html: the verdict table, links to the stage reports, the stage plots present, the figures
    (``report_figures``), the flight acceptance tables and the stages' numbers as tables; the page is
    ``aerotri/templates/qa_report.html.j2``."""
    from aerotri.core.pages import render

    verdicts, section = [], None
    for r in rep["checks"]:
        unconfirmed = None  # a limit whose source is not confirmed: '*' with the source as its title
        if r.get("limit") is not None and r.get("limit_confirmed") is False:
            unconfirmed = r.get("limit_source") or ""
        verdicts.append(dict(section=r["section"] if r["section"] != section else None, quantity=_cell(r["quantity"]),
                             value=_value_cell(r["value"], r["limit"]), limit=_cell(r["limit"]), unconfirmed=unconfirmed,
                             unit=_cell(r["unit"]), verdict=r["verdict"] or "", note=_cell(r["note"])))
        section = r["section"]
    fa = rep.get("flight_acceptance")
    return render("qa_report.html.j2", project=rep["project"],
                  table_name=(rep.get("table") or {}).get("name") or str(rep["map_scale"]),
                  # (an ASPRS table has one set of limits for every terrain: no class beside it, trial s100 rc2 L1)
                  tolerance_table=rep["tolerance_table"],
                  terrain=rep["terrain"] if (rep.get("table") or {}).get("terrain_classes", True) else None,
                  reason=(rep.get("table") or {}).get("reason") or "given", overall=rep["overall"] or "",
                  overall_class=verdict_class(rep["overall"] or ""),
                  compliance_headline=compliance_headline(rep.get("compliance")),
                  standard_fails=standard_fails_note(rep.get("compliance")),
                  compliance_verdict=verdict_class(compliance_verdict(rep.get("compliance"))),
                  counts=verdict_counts(rep["passed"], rep["failed"], rep.get("not_judged")),
                  generated=f"{rep.get('generated_utc') or ''} (aerotri {rep.get('aerotri_version') or '?'})",
                  verdicts=verdicts,
                  compliance=_compliance_section(rep.get("compliance")), stage_links=list(stage_links),
                  stage_images=list(stage_images), figures=list(figures or []),
                  flight_tables=RF.flight_tables(fa) if fa else None, flight_spec=str((fa or {}).get("spec") or ""),
                  tolerance=_tolerance_section(rep),
                  details=[(k.replace("_", " "), detail_blocks(v)) for k, v in rep["details"].items() if v])


def _text(v) -> str:
    """A table cell for the PDF (plain text: no HTML escapes)."""
    if v is None:
        return ""
    return f"{v:.4g}" if isinstance(v, float) else str(v)


PDF_PAGE_IN = (11.69, 8.27)  # A4 landscape
PDF_TABLE_AXES = (0.03, 0.03, 0.94, 0.88)  # the table's axes on the page (figure fractions)
PDF_TABLE_PT = 7.5  # the tables' font size
PDF_ROWS_PER_PAGE = 34  # one-line rows a page holds (a row: matplotlib's 10 pt row height x 1.2 x 1.25)
_CELL_PAD = 0.1  # matplotlib.table.Cell.PAD: a left-aligned text stands this fraction of the cell's width in


@functools.lru_cache(maxsize=65536)
def _text_width_pt(text: str, size_pt: float) -> float:
    """The width of ``text`` in points as the PDF draws it (matplotlib's default font at ``size_pt``).

    Cached: a report measures the same headers and the growing prefixes of its cells again and again."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    return TextToPath().get_text_width_height_descent(text, FontProperties(size=size_pt), ismath=False)[0]


def _longest_prefix_within(text: str, width_pt: float, size_pt: float) -> int:
    """The most leading characters of ``text`` (at least 1) no wider than ``width_pt``; ``text`` itself is wider.

    By bisection: a prefix one character longer is wider (each glyph advances more than any kerning takes back)."""
    lo, hi = 0, len(text)  # text[:lo] fits (or lo = 0), text[:hi] does not
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _text_width_pt(text[:mid], size_pt) <= width_pt:
            lo = mid
        else:
            hi = mid
    return max(lo, 1)


def wrap_cell(text: str, width_pt: float, size_pt: float = PDF_TABLE_PT) -> str:
    """``text`` broken into lines no wider than ``width_pt`` points (measured, not counted in characters): at spaces,
    a word wider than the cell at the character that would cross it (ids, paths)."""
    out = []
    for para in str(text).split("\n"):
        line = ""
        for word in para.split(" "):
            trial = f"{line} {word}" if line else word
            if _text_width_pt(trial, size_pt) <= width_pt:
                line = trial
                continue
            if line:
                out.append(line)
            line = word
            while len(line) > 1 and _text_width_pt(line, size_pt) > width_pt:
                k = _longest_prefix_within(line, width_pt, size_pt)
                out.append(line[:k])
                line = line[k:]
        out.append(line)
    return "\n".join(out)


def _wrapped_rows(rows: list, widths: list) -> tuple[list, list]:
    """(the rows' cells wrapped to their columns' widths on the page, each row's height in one-line rows)."""
    # the text starts PAD x the width in from the cell's left edge; 2 pt kept free at its right edge
    col_pt = [w * PDF_TABLE_AXES[2] * PDF_PAGE_IN[0] * 72.0 * (1.0 - _CELL_PAD) - 2.0 for w in widths]
    cells = [[wrap_cell(_text(v), col_pt[j]) for j, v in enumerate(r)] for r in rows]
    # a one-line row is 1.25 x 1.2 x 10 pt high; each further line adds 1.2 x 7.5 pt (0.6 of a row)
    heights = [1.0 + 0.6 * (max(c.count("\n") for c in r) if r else 0) for r in cells]
    return cells, heights


def _pdf_table(pdf, plt, title: str, *, header: list, rows: list, widths: list, colours=None) -> None:
    """One A4-landscape page (or more) with a table; every cell wrapped to its column (long cells spilled past the
    page's edge), the rows paged by their heights (``PDF_ROWS_PER_PAGE`` one-line rows a page)."""
    head, (head_h,) = _wrapped_rows([header], widths)[0][0], _wrapped_rows([header], widths)[1]
    cells, heights = _wrapped_rows(rows, widths)
    pages, start, used = [], 0, head_h
    for i, h in enumerate(heights):
        if used + h > PDF_ROWS_PER_PAGE and i > start:
            pages.append((start, i))
            start, used = i, head_h
        used += h
    pages.append((start, len(rows)))
    for n, (a, b) in enumerate(pages):
        fig = plt.figure(figsize=PDF_PAGE_IN)
        # a long title (a standard's full name) on two lines, not cut off at the page's edge
        lines = textwrap.wrap(title + (" (continued)" if n else ""), 95)
        fig.text(0.04, 0.975, "\n".join(lines), fontsize=14 if len(lines) == 1 else 12, weight="bold", va="top")
        ax = fig.add_axes(list(PDF_TABLE_AXES))
        ax.axis("off")
        if b > a:
            t = ax.table(cellText=cells[a:b], colLabels=head, colWidths=widths, loc="upper left", cellLoc="left",
                         cellColours=colours[a:b] if colours else None)
            t.auto_set_font_size(False)
            t.set_fontsize(PDF_TABLE_PT)
            t.scale(1, 1.25)
            for (r, _), cell in t.get_celld().items():
                cell.set_height(cell.get_height() * (head_h if r == 0 else heights[a + r - 1]))
        pdf.savefig(fig)
        plt.close(fig)


def _dom_check_stale(rep: dict) -> bool:
    """Whether the report's DOM check measured an earlier mosaic (its row ``dom_check_stale``)."""
    return any(r["id"] == "dom_check_stale" for r in rep["checks"])


def write_pdf(path: Path, rep: dict, project: Project, figures: list | None = None) -> None:
    """The verdict table on the first page, the flight acceptance tables, the report's figures (each with
    its caption and scale key), then the plots the stages wrote (A4 landscape)."""
    from matplotlib.backends.backend_pdf import PdfPages

    plt = pyplot()

    with atomic_path(path) as tmp, PdfPages(tmp, metadata={"Title": f"Accuracy report {rep['project']}",
                                                           "CreationDate": None}) as pdf:
        fig = plt.figure(figsize=(11.69, 8.27))
        fig.text(0.04, 0.957, f"Accuracy report: {rep['project']}", fontsize=16, weight="bold")
        t = rep.get("table") or {}
        head = (f"tolerances: {t.get('name') or rep['map_scale']} ({rep['tolerance_table']}), terrain {rep['terrain']}; "
                f"chosen because {t.get('reason', 'given')}")
        fig.text(0.04, 0.898, "\n".join(textwrap.wrap(head, 190)[:3]), fontsize=6.5, va="bottom")
        headline = "; ".join(x for x in (compliance_headline(rep.get("compliance")),
                                         standard_fails_note(rep.get("compliance"))) if x)
        fig.text(0.04, 0.885, f"limits marked * are not confirmed in their source; overall verdict: {rep['overall'] or 'none'} "
                             f"({verdict_counts(rep['passed'], rep['failed'], rep.get('not_judged'))})", fontsize=10,
                 va="top")
        # the compliance verdict on its own lines, wrapped: one line cut it off after a long standard's name (cn-at)
        lines = textwrap.wrap(headline[:1].upper() + headline[1:], 125) if headline else []
        if lines:
            fig.text(0.04, 0.862, "\n".join(lines), fontsize=9, weight="bold", va="top", linespacing=1.3)
        top = 0.875 - (0.012 + 0.0215 * len(lines) if lines else 0.0)
        cells, colours = [], []
        for r in rep["checks"]:
            star = "*" if r.get("limit_confirmed") is False and r["limit"] is not None else ""
            # the note as the page's: what was not counted, why a row is not judged (the PDF had no note column:
            # "1 surveyed point with no valid cell of the DEM under it, not counted: X0" was on the page only)
            cells.append([r["section"], r["quantity"], _value_cell(r["value"], r["limit"]), _cell(r["limit"]) + star, r["unit"],
                          r["verdict"] or "", r.get("note") or ""])
            c = {"pass": "#ccffcc", "fail": "#ffcccc"}.get(r["verdict"], "white")
            colours.append(["white"] * 5 + [c, "white"])
        ax = fig.add_axes([0.03, 0.03, 0.94, top - 0.03])
        ax.axis("off")
        header = ["section", "quantity", "value", "limit", "unit", "verdict", "note"]
        widths = [0.11, 0.33, 0.07, 0.06, 0.04, 0.06, 0.29]
        # every cell wrapped to its column as the other tables' (the quantity was cut at 70 characters); the rows the
        # page holds under the headline by their heights (a one-line row at scale 1.1 takes 0.0225 of the page's
        # height, measured on the demo's page, the header one; each further line 1.2 x 7.5 pt of its 1.1 x 1.2 x 10
        # pt): the rest on the next pages, not cut off at the page's foot
        wrapped, _ = _wrapped_rows(cells, widths)
        line = 1.2 * PDF_TABLE_PT / (1.1 * 1.2 * 10.0)
        heights = [1.0 + line * max(c.count("\n") for c in r) for r in wrapped]
        room, fit = (top - 0.04) / 0.0225 - 1.0, 0
        while fit < len(cells) and (fit == 0 or sum(heights[:fit + 1]) <= room):
            fit += 1
        if cells:
            t = ax.table(cellText=wrapped[:fit], cellColours=colours[:fit], colLabels=header, colWidths=widths,
                         loc="upper left", cellLoc="left")
            t.auto_set_font_size(False)
            t.set_fontsize(PDF_TABLE_PT)
            t.scale(1, 1.1)
            for (i, _), cell in t.get_celld().items():
                if i > 0:
                    cell.set_height(cell.get_height() * heights[i - 1])
        pdf.savefig(fig)
        plt.close(fig)
        if len(cells) > fit:
            _pdf_table(pdf, plt, "Verdict table (continued)", header=header, rows=cells[fit:], widths=widths,
                       colours=colours[fit:])
        comp = rep.get("compliance")
        if comp:
            rows = [compliance_row(c) for c in comp["checks"]]
            colours = [["white"] * 8 + [VERDICT_COLOURS.get(c["verdict"], "white"), "white"] for c in comp["checks"]]
            _pdf_table(pdf, plt, f"Compliance: {comp['name']}, class {comp['class_tested']}",
                       header=COMPLIANCE_HEADER, rows=rows,
                       widths=[0.095, 0.19, 0.06, 0.06, 0.05, 0.06, 0.135, 0.055, 0.21, 0.075], colours=colours)
            _pdf_table(pdf, plt, "Compliance per product",
                       header=["product", "verdict", "finest class met"],
                       rows=[[p["product"], p["verdict"], p["finest_class"]] for p in comp["products"]]
                       + [["", "", ""], [f"Chosen because: {comp['reason']}", "", ""]], widths=[0.7, 0.1, 0.15])
        fa = rep.get("flight_acceptance")
        if fa:
            ops = {"max": "<=", "min": ">="}
            rows = [[c["quantity"], c["value"], (f"{ops[LIMIT_KEYS[c['key']][2]]} {c['limit']:g}"
                                                 if c["limit"] is not None else ""), c["unit"], c["where"],
                     f"{c['n_fail']} of {c['n']}", c["verdict"] or ""] for c in fa["checks"]]
            colours = [["white"] * 6 + [{"pass": "#ccffcc", "fail": "#ffcccc"}.get(r[-1], "white")] for r in rows]
            _pdf_table(pdf, plt, f"Flight acceptance ({fa['source']}; footprints on {Path(str(fa['terrain'])).name}; "
                                 f"limits: {fa.get('spec') or 'none'})",
                       header=["check", "worst", "limit", "unit", "at", "failing", "verdict"], rows=rows,
                       widths=[0.36, 0.08, 0.08, 0.05, 0.14, 0.08, 0.07], colours=colours)
            _pdf_table(pdf, plt, "Flight acceptance per strip",
                       header=["strip", "frames", "first", "last", "curvature %", "height range m", "forward min %",
                        "side median %", "max tilt deg", "max kappa deg", "failing"],
                       rows=[[RF.strip_label(s), s["frames"], s["first"], s["last"], s["curvature_pct"], s["height_range_m"],
                         s["forward_overlap_min_pct"], s["side_overlap_median_pct"], s["max_tilt_deg"],
                         s["max_kappa_deviation_deg"], ", ".join(LIMIT_KEYS[k][0] for k in RF.strip_fails(fa, s))]
                        for s in fa["strips"]], widths=[0.05, 0.05, 0.1, 0.1, 0.08, 0.08, 0.08, 0.08, 0.08, 0.08, 0.2])
        for f in figures or []:
            fig = plt.figure(figsize=(11.69, 8.27))
            fig.text(0.03, 0.96, f.title, fontsize=14, weight="bold")
            fig.text(0.03, 0.025, f"{f.caption}  Scale: {f.key}", fontsize=8, wrap=True)
            ax = fig.add_axes([0.02, 0.07, 0.96, 0.86])
            ax.imshow(plt.imread(io.BytesIO(f.png()), format="png"))
            ax.axis("off")
            pdf.savefig(fig)
            plt.close(fig)
        stale = _dom_check_stale(rep)
        for title, png in (("DOM displacement against the reference", project.dom_report_plot_path),
                           ("Tie-point connectivity", project.connectivity_plot_path)):
            if png.is_file() and not (stale and png == project.dom_report_plot_path):
                fig = plt.figure(figsize=(11.69, 8.27))
                fig.suptitle(title)
                ax = fig.add_axes([0.02, 0.02, 0.96, 0.9])
                ax.imshow(plt.imread(png))
                ax.axis("off")
                pdf.savefig(fig)
                plt.close(fig)


def write_qa_report(root, *, tolerance_file=None, terrain: str | None = None, scale: str | None = None,
                    pdf: bool | None = None, standard: str | None = None, horizontal_class_cm: float | None = None,
                    vertical_class_cm: float | None = None, accuracy_class: str | None = None) -> QaReport:
    """``build_qa_report``, written: reports/summary.json (the report's record), reports/index.html and, with ``pdf``
    (else ``[qa] pdf``), reports/report.pdf."""
    project = Project.open(root)
    rep = build_qa_report(project.root, tolerance_file=tolerance_file, terrain=terrain, scale=scale, standard=standard,
                          horizontal_class_cm=horizontal_class_cm, vertical_class_cm=vertical_class_cm,
                          accuracy_class=accuracy_class)
    summary = to_record(rep, exclude=("html",))
    # when and by what it was made (trial s96 M1: the morning's reader could not tell a report of last night from
    # one of last week; neither file said)
    import aerotri

    summary["generated_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    summary["aerotri_version"] = aerotri.__version__
    write_text_atomic(project.report_summary_path, json.dumps(summary, indent=1) + "\n")
    figures = report_figures(rep, project)
    # a DOM check of an earlier mosaic: neither its plot nor its page (the row says the DOM was not checked)
    stale = ("../ortho/dom_report.png", "../ortho/dom_report.json") if _dom_check_stale(summary) else ()
    # embedded, as the report's own figures are: reports/ copied for a client keeps them (s95: two figures were
    # links to ../ortho and ../at, lost in the copy)
    present = [(_png_data_uri((project.reports_dir / src).resolve()), alt) for src, alt in STAGE_IMAGES
               if (project.reports_dir / src).resolve().is_file() and src not in stale]
    # only the stage pages this project has: a block without LiDAR has no height check or strip page
    links = [(src, text) for src, text in STAGE_LINKS
             if (project.reports_dir / src).resolve().is_file() and src not in stale]
    write_text_atomic(project.report_index_path, format_html(summary, figures, present, links))
    if pdf if pdf is not None else read_qa_config(root).pdf:
        write_pdf(project.report_pdf_path, summary, project, figures)
    return dataclasses.replace(rep, html=str(project.report_index_path))


def _png_data_uri(path: Path) -> str:
    """A PNG file as an ``<img src>`` data URI."""
    import base64

    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def console_summary(report: QaReport) -> str:
    """The lines ``aerotri report`` prints: the table and why it was chosen, every judged row, the verdict."""
    t = report.table
    lines = [f"tolerances: {t['name']} ({t['file']}); chosen because {t['reason']}"]
    if t["unconfirmed"]:
        lines.append(f"  limits not confirmed in their source (marked *): {', '.join(t['unconfirmed'])}")
    for r in report.checks:
        if r.verdict:
            star = "*" if r.limit_confirmed is False and r.limit is not None else ""
            if r.value is not None:
                lines.append(f"  {r.verdict:<5} {r.section}: {r.quantity} = {r.value} {r.unit} (limit {r.limit}{star})")
            else:  # a verdict without a figure: its note is the reason (trial s96 F8: "no value ... (limit None)")
                lines.append(f"  {r.verdict:<5} {r.section}: {r.quantity}: {r.note or 'no value'}"
                             + (f" (limit {r.limit}{star})" if r.limit is not None else ""))
    lines += compliance_lines(report.compliance)
    verdict = report.overall or "no verdict (no quantity with a tolerance yet)"
    judged_by = t["name"] if t.get("lidar_only") else f"{report.map_scale} {report.terrain}"
    if t.get("limits_from"):
        judged_by += f" with the {t['limits_from']}"
    headline = "; ".join(x for x in (compliance_headline(report.compliance), standard_fails_note(report.compliance))
                         if x)
    lines.append(f"{report.html}: {verdict} ({verdict_counts(report.passed, report.failed, report.not_judged)}; "
                 f"{judged_by})"
                 + (f"; {headline}" if headline else ""))
    return "\n".join(lines)


_STOPPED_BEGIN, _STOPPED_END = "<!-- aerotri:run-stopped -->", "<!-- /aerotri:run-stopped -->"
# a run under way (``mark_report_stale(..., running=True)``): what a run killed by SIGKILL leaves (trial s96 M1)
_RUNNING_BEGIN, _RUNNING_END = "<!-- aerotri:run-running -->", "<!-- /aerotri:run-running -->"


def _without_banners(text: str, banners=((_STOPPED_BEGIN, _STOPPED_END), (_RUNNING_BEGIN, _RUNNING_END))) -> str:
    """``text`` without the banners (begin, end markers) ``banners`` (default: both kinds)."""
    import re as _re

    for a, b in banners:
        text = _re.sub(_re.escape(a) + ".*?" + _re.escape(b), "", text, flags=_re.S)
    return text


def clear_running_mark(root) -> None:
    """Take a run's own "running" mark (``mark_report_stale(..., running=True)``) out of the report again, before its
    report stage decides whether it is up to date: index.html as the report stage wrote it (its stamp's hash), and
    summary.json's verdict back. Nothing else is touched."""
    project = Project.open(root)
    index, summary_path = project.report_index_path, project.report_summary_path
    if index.is_file():
        text = index.read_text()
        if _RUNNING_BEGIN in text:
            write_text_atomic(index, _without_banners(text, ((_RUNNING_BEGIN, _RUNNING_END),)))
    if summary_path.is_file():
        try:
            summary = json.loads(summary_path.read_text())
        except ValueError:
            return
        if isinstance(summary, dict) and summary.get("running"):
            summary.pop("running")
            summary.pop("stale", None)
            summary["overall"] = summary.pop("overall_of_that_run", summary.get("overall"))
            write_text_atomic(summary_path, json.dumps(summary, indent=1) + "\n")


def mark_report_stale(root, note: str, running: bool = False) -> tuple[list[Path], list[str]]:
    """Say in the report of an earlier run that a later ``aerotri run`` stopped before making its own (``note``:
    when it started, the stage that stopped and why): a banner at the top of reports/index.html (an earlier banner
    replaced) and ``"stale": note`` in reports/summary.json, each written atomically; reports/report.pdf is left (the
    banner names it). Trial-overnight: after a failed night run the QA reader found the last good run's report and
    nothing saying so. The banner changes index.html, so the next run's report stage runs again (its output changed
    since it wrote it) and a finished run's report has none. Returns the files marked and, for each that could not
    be (a disk still full), ``"<file>: <why>"``. ``running``: the mark a run sets when it starts (``note``: "a run
    started at ... has not ended"), taken out again before its report stage (``clear_running_mark``): a run killed
    (SIGKILL, out of memory) leaves it."""
    import html as _html

    project = Project.open(root)
    marked, failed = [], []
    index = project.report_index_path
    begin, end = (_RUNNING_BEGIN, _RUNNING_END) if running else (_STOPPED_BEGIN, _STOPPED_END)
    if index.is_file():
        try:
            text = _without_banners(index.read_text())
            pdf = " and reports/report.pdf are" if project.report_pdf_path.is_file() else " is"
            banner = (f'{begin}<p style="background:#fdd;border:2px solid #a00;padding:6px;font-weight:bold">'
                      f"Stale: {_html.escape(note)}. This report{pdf} of the run before it; the next run that "
                      f"reaches its report stage writes them again.</p>{end}")
            at = text.find("<body>")
            text = text[:at + 6] + banner + text[at + 6:] if at >= 0 else banner + text
            write_text_atomic(index, text)
            marked.append(index)
        except OSError as e:
            failed.append(f"{index}: {e.strerror or e}")
            # summary.json is no output of the report stage: marked alone, its mark would outlive the next run that
            # finds index.html as it wrote it (review 51)
            return marked, failed
    summary_path = project.report_summary_path
    if summary_path.is_file():
        try:
            summary = json.loads(summary_path.read_text())
            if isinstance(summary, dict):
                summary["stale"] = note
                # a script reading "overall" alone read "pass" beside "stale" (trial s96 M1): the verdict of that run
                # is kept under its own key
                if summary.get("overall") != "stale":
                    summary["overall_of_that_run"] = summary.get("overall")
                summary["overall"] = "stale"
                if running:
                    summary["running"] = True
                else:
                    summary.pop("running", None)
                write_text_atomic(summary_path, json.dumps(summary, indent=1) + "\n")
                marked.append(summary_path)
        except (OSError, ValueError) as e:
            failed.append(f"{summary_path}: {getattr(e, 'strerror', None) or e}")
    return marked, failed
