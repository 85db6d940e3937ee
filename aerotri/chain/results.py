"""What each stage of the chain hands back: a frozen record per stage, its key numbers for the summary row and
the stamp (``work/stages/<stage>.json`` "result", ``summary.json``).

``StageResult.record`` is the JSON form: the stage's fields in their order, then ``why`` (a stage that found
out by running that it had nothing to do) and ``notes``. A field declared with a default of None is left out
while it is None (a figure the stage did not measure is no column); a field without a default is always
written, None included (the report's verdict when nothing was judged).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

_LAST = ("why", "notes")


@dataclasses.dataclass(frozen=True, kw_only=True)
class StageResult:
    """A stage's result: why it did nothing (None: it did its work) and notes for the summary."""

    why: str | None = None
    notes: tuple[str, ...] = ()
    _HIDDEN: ClassVar[tuple[str, ...]] = ()  # fields the record never holds

    def _written_when_none(self) -> tuple[str, ...]:
        """Fields with a default of None that the record holds even while None."""
        return ()

    def record(self) -> dict:
        """The key numbers as the stamp and the summary row hold them (module doc)."""
        out = {}
        keep = self._written_when_none()
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in _LAST or f.name in self._HIDDEN or (v is None and f.default is None and f.name not in keep):
                continue
            out[f.name] = v
        if self.why is not None:
            out["why"] = self.why
        if self.notes:
            out["notes"] = list(self.notes)
        return out


@dataclasses.dataclass(frozen=True, kw_only=True)
class StripsResult(StageResult):
    """The strip stage: the adjustment (model, RMS of all pairs before and after in metres, sigma naught) or the
    check (pairs compared, RMS and NMAD of all pairs in metres)."""

    model: str | None = None
    rms_before_m: float | None = None
    rms_after_m: float | None = None
    sigma0: float | None = None
    pairs: int | None = None
    rms_m: float | None = None
    nmad_m: float | None = None


@dataclasses.dataclass(frozen=True, kw_only=True)
class ClassifyResult(StageResult):
    points: int
    strips: int
    tiles: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class RastersResult(StageResult):
    res_m: float


@dataclasses.dataclass(frozen=True, kw_only=True)
class CornersResult(StageResult):
    corners: int
    usable: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class VectorsResult(StageResult):
    """The line map's feature counts and, when it was checked (``checked``, not in the record), the plan RMS of its
    building corners to the reference (metres) and their count (None: no building corner matched)."""

    buildings: int | None = None
    roads: int | None = None
    water: int | None = None
    spot_heights: int | None = None
    checked: bool = False
    corner_rms_xy_m: float | None = None
    corners: int | None = None
    _HIDDEN: ClassVar[tuple[str, ...]] = ("checked",)

    def _written_when_none(self) -> tuple[str, ...]:
        return ("corner_rms_xy_m", "corners") if self.checked else ()


@dataclasses.dataclass(frozen=True, kw_only=True)
class MatchResult(StageResult):
    tracks: int
    observations: int
    components: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class AdjustResult(StageResult):
    """Key numbers of an adjustment: sigma naught (um on the image), control points, check-point RMS (plan and
    height, metres) and, with the leave-one-out check, its plan RMS and the control scatter (metres)."""

    sigma0_um: float | None = None
    control_points: int | None = None
    rms_check_xy_m: float | None = None
    rms_check_z_m: float | None = None
    loo_rms_xy_m: float | None = None
    control_scatter_xy_m: float | None = None


@dataclasses.dataclass(frozen=True, kw_only=True)
class ControlResult(StageResult):
    corners_accepted: int
    control_full: int
    control_height: int
    check_points: int
    layout_targets: int
    layout_targets_unfilled: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class TiePointDemResult(StageResult):
    res_m: float
    points: int
    cells_measured: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class RectifyResult(StageResult):
    frames: int
    res_m: float
    ortho: str  # "true (DSM)" or "conventional (DEM)"


@dataclasses.dataclass(frozen=True, kw_only=True)
class MosaicResult(StageResult):
    width_px: int
    height_px: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class DomCheckResult(StageResult):
    """The DOM check: plan RMS of the patch displacements (metres, GSD) and the patches measured, on open ground
    and, when measured, on roofs."""

    rms_xy_m: float | None = None
    rms_xy_gsd: float | None = None
    count: int | None = None
    roofs_rms_xy_m: float | None = None  # the roofs row, when the check measured roofs
    roofs_rms_xy_gsd: float | None = None
    roofs_count: int | None = None


@dataclasses.dataclass(frozen=True, kw_only=True)
class HeightCheckResult(StageResult):
    """The LiDAR height check at surveyed points: RMSE and mean |dz| (metres) and the points compared."""

    rmse_m: float | None = None
    mean_abs_dz_m: float | None = None
    n: int | None = None


@dataclasses.dataclass(frozen=True, kw_only=True)
class LidarEvalResult(StageResult):
    """The classification against the true classes: type I and II errors and Cohen's kappa (percent)."""

    type_i_error_pct: float | None = None
    type_ii_error_pct: float | None = None
    kappa_pct: float | None = None


@dataclasses.dataclass(frozen=True, kw_only=True)
class ReportResult(StageResult):
    """The accuracy report: overall verdict ("pass", "fail", "not testable": a standard asked for cannot test a
    product; None: no quantity judged) and the rows counted."""

    verdict: str | None
    passed: int
    failed: int
