"""The adjustment report ``at/report.json`` read back as a typed record: what the stages after the
adjustment (the accuracy report, the chain) take from it.

The adjustment stage owns the file (``aerotri.adjust.report`` writes it); this module owns its reader. Only
the fields other stages use are typed here; the figures of ``at/report.html`` draw from the whole file.
The file's ground figures are in the project CRS's unit (feet in a feet CRS); the record's ``_m`` fields are
metres (``map_unit_m``). Image quantities in micrometres (``_um``) or pixels (``_px``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

from aerotri.core.errors import CrsError, InputError
from aerotri.core.textio import read_record, record_error
from aerotri.core.digest import file_sha256

log = logging.getLogger(__name__)

ADJUSTMENT_REPORT = "bundle adjustment report (at/report.json)"
SCHEMA_VERSION = 1


def _xyz(v, unit_m=(1.0, 1.0, 1.0)) -> tuple[float | None, ...] | None:
    """A list of numbers (or nulls) as a tuple, None when absent; ``unit_m``: metres per unit of x, y, z."""
    if v is None:
        return None
    return tuple(None if x is None else float(x) * u for x, u in zip(v, unit_m))


def _number(v) -> float | None:
    return None if v is None else float(v)


def map_unit_m(crs, source: str = "CRS") -> tuple[float, float, float]:
    """Metres per unit of the report's ground coordinates and residuals (x, y, z): the project CRS's horizontal
    unit and the height unit of its horizontal part (the adjustment's map heights, ``LocalFrame``). A feet CRS:
    0.3048 (its "_m" keys are feet, the tolerances metres).

    ``CrsError`` naming ``source`` (the file and key) when PROJ cannot read the CRS or its map axes have no length
    unit (geographic, geocentric: ``map_axes_unit_m``): the adjustment's CRS is projected or local
    (``check_block_crs``), and a unit taken as metres would scale every ground figure (a feet report judged 3.3
    times too loose). No CRS at all (None or "": the adjustment always writes one, so a hand-made report or a test's
    block): metres, said in a warning."""
    if not crs:
        log.warning(f"{source}: no CRS; its ground coordinates and residuals are read as metres")
        return (1.0, 1.0, 1.0)
    from aerotri.geom.crs.definition import map_axes_unit_m

    return map_axes_unit_m(crs, source)


@dataclass(frozen=True)
class KeyStatistics:
    """The ISAT "key statistics" of the solution: sigma naught, iterations and the verdict."""

    success: bool
    verdict: str  # "successful", "weak" or "failed"
    message: str
    iterations: int | None
    sigma0_um: float | None
    sigma0_px: float | None  # None in reports written before sigma0_px: see ``sigma0_in_px``
    sigma0: float | None  # unit-free: sigma naught over the a-priori image sigma
    pixel_um: float | None
    degrees_of_freedom: int | None = None

    @property
    def successful(self) -> bool:
        """"Solution Successful": products written and nothing weak."""
        return self.success and self.verdict == "successful"


@dataclass(frozen=True)
class SurfaceControlClass:
    """Surface control over one class of ground (or the whole DEM, named "DEM"): tie points used and rejected,
    RMS of point height minus surface (m)."""

    name: str
    used: int | None
    rejected: int | None
    rms_m: float | None


@dataclass(frozen=True)
class CheckDemRecord:
    """The adjusted tie points against a DEM given only to check them (``--check-dem``; report.json dem_checks, role
    "check"): the DEM, the tie points compared and their median height - DEM (m; None: too few to test)."""

    dem: str
    n: int
    median_m: float | None


@dataclass(frozen=True)
class AdjustmentRecord:
    """What ``at/report.json`` tells the stages after the adjustment."""

    path: Path
    project: str | None
    counts: dict  # images, strips, tie_points, control_points, check_points, ... (numbers only)
    gnss_given: bool  # GNSS camera positions observed ("given EO GPS" in the ISAT options)
    image_sigma_px: float | None  # a-priori sigma of an image coordinate
    key_statistics: KeyStatistics | None
    control_rms_m: tuple[float | None, ...] | None  # X, Y, Z RMS of the control residuals on the ground (metres)
    rejected_control: tuple[str, ...]  # ids of control points the adjustment rejected
    check_rms_m: tuple[float | None, ...] | None  # X, Y, Z RMS at the check points (metres)
    check_residuals_m: tuple[tuple[float, float, float], ...]  # dX, dY, dZ per check point (metres; NaN: not surveyed)
    check_points: int  # check points in the report (with or without residuals)
    check_normalised_rms: tuple[float | None, ...] | None
    flight_acceptance: dict | None  # the flight acceptance section as written (a ``FlightAcceptance``, asdict)
    control_to_tie_ratio: float | None = None  # RMS image residual of control over that of the ties
    datum_notes: tuple[str, ...] = ()  # what the datum rests on when GNSS does not carry it
    heights_measured: bool = True  # False: relative heights, 0 at the control's median ground (report.json)
    surface_control: tuple[SurfaceControlClass, ...] = ()  # per class of ground, or the DEM as one; () without
    # the surface's systematic error (LiDAR strip offsets) as the sigmas carry it: report.json
    # surface_control.systematic ("considered" false: the orientations' and points' sigmas are formal); None without
    surface_systematic: dict | None = None
    check_points_from_lidar: int = 0  # check points that are corners of the surface control's LiDAR
    # the adjustment's input files as it read them (report.json "inputs", ``record_inputs``): path relative to the
    # project -> {"size", "sha256"}, None where the file was absent; None: a report written before it was recorded
    inputs: dict | None = None
    # (image id, why) of the images the adjustment left out (report.json components.left_out): no orientation
    frames_left_out: tuple[tuple[str, str], ...] = ()
    check_dem: CheckDemRecord | None = None  # the check DEM's comparison (``--check-dem``), None without one
    # the block height mode's shares of its determination (report.json geometry_modes: group -> share); None without
    height_shares: dict | None = None

    @property
    def sigma0_in_px(self) -> float | None:
        """Sigma naught in pixels (from the unit-free sigma naught in reports written before ``sigma0_px``)."""
        ks = self.key_statistics
        if ks is None:
            return None
        if ks.sigma0_px is not None:
            return ks.sigma0_px
        if ks.sigma0 is not None:
            return ks.sigma0 * (self.image_sigma_px if self.image_sigma_px is not None else math.nan)
        return None


def _key_statistics(ks: dict) -> KeyStatistics | None:
    if not ks:
        return None
    f = {k: (None if ks.get(k) is None else float(ks[k])) for k in ("sigma0_um", "sigma0_px", "sigma0", "pixel_um")}
    return KeyStatistics(success=bool(ks.get("success")), verdict=str(ks.get("verdict", "successful")),
                         message=str(ks.get("message", "")),
                         iterations=None if ks.get("iterations") is None else int(ks["iterations"]),
                         degrees_of_freedom=(None if ks.get("degrees_of_freedom") is None
                                             else int(ks["degrees_of_freedom"])),
                         **f)


def _surface_control(sc: dict | None) -> tuple[SurfaceControlClass, ...]:
    if not sc:
        return ()
    return tuple(SurfaceControlClass(name=str(name), used=c.get("used"), rejected=c.get("rejected"),
                                     rms_m=_number(c.get("rms_m")))
                 for name, c in (sc.get("classes") or {"DEM": sc}).items())


def adjustment_record(d: dict, path="at/report.json") -> AdjustmentRecord:
    """The record of an adjustment report as a dict (what ``write_outputs`` writes; ``path``: where
    it was read from); KeyError, TypeError or ValueError when a field is not what the adjustment writes."""
    options = d.get("options") or {}
    rejected = tuple(str(r.get("id", r) if isinstance(r, dict) else r) for r in d.get("rejected_control") or [])
    checks = d.get("check_points") or []
    # a plan-only check point has dZ None (its height was not surveyed): NaN here, left out of height figures
    # the report's ground figures are in the project CRS's unit (feet in a feet CRS): metres here, as the
    # tolerance tables and the stages after the adjustment read them
    unit = map_unit_m(d.get("crs"), f"{path}: crs")
    residuals = tuple(tuple(math.nan if x is None else float(x) * u for x, u in zip(c["d_m"], unit)) for c in checks
                      if c.get("d_m") and any(x is not None for x in c["d_m"]))
    sigma = options.get("image_sigma_px")
    return AdjustmentRecord(
        path=Path(path), project=d.get("project"), counts=dict(d.get("counts") or {}),
        gnss_given=options.get("given_eo_gps") == "Enabled", image_sigma_px=None if sigma is None else float(sigma),
        key_statistics=_key_statistics(d.get("key_statistics") or {}),
        control_rms_m=_xyz(d.get("rms_control_ground_m"), unit), rejected_control=rejected,
        check_rms_m=_xyz(d.get("check_rms_m"), unit), check_residuals_m=residuals, check_points=len(checks),
        check_normalised_rms=_xyz(d.get("check_normalised_rms")), flight_acceptance=d.get("flight_acceptance") or None,
        control_to_tie_ratio=_number((d.get("image_residuals") or {}).get("control_to_tie_ratio")),
        datum_notes=tuple(str(n) for n in d.get("datum") or ()),
        heights_measured=d.get("heights_measured", True) is not False,
        surface_control=_surface_control(d.get("surface_control")),
        surface_systematic=(d.get("surface_control") or {}).get("systematic"),
        check_points_from_lidar=int(d.get("check_points_from_lidar") or 0),
        inputs=_inputs(d.get("inputs")),
        frames_left_out=tuple((str(k), str(lo.get("reason", ""))) for lo in (d.get("components") or {}).get("left_out")
                              or () for k in lo.get("images", ())),
        check_dem=next((CheckDemRecord(dem=str(c.get("dem", "")), n=int(c.get("n") or 0),
                                       median_m=_number(c.get("median_m")) if c.get("limit_m") is not None else None)
                        for c in d.get("dem_checks") or () if c.get("role") == "check"), None),
        height_shares=next((dict(g.get("shares") or {}) for g in d.get("geometry_modes") or ()
                            if g.get("mode") == "height"), None))


def _inputs(v) -> dict | None:
    """report.json "inputs" (path -> {"size", "sha256"} or None); None without the key. A ValueError when it is not
    that (named by ``read_adjustment_report``)."""
    if v is None:
        return None
    if not isinstance(v, dict) or not all(
            r is None or (isinstance(r, dict) and isinstance(r.get("sha256"), str) and isinstance(r.get("size"), int))
            for r in v.values()):
        raise ValueError("inputs: expected file -> {size, sha256} or null")
    return {str(k): (None if r is None else {"size": int(r["size"]), "sha256": str(r["sha256"])})
            for k, r in v.items()}


def adjustment_input_paths(project) -> tuple[Path, ...]:
    """The files the adjustment reads whose later change makes its figures those of other inputs: the control
    points and their image measurements, gnss.txt and the tie points (``aerotri.core.project.Project`` paths)."""
    return (project.control_points_path, project.control_image_points_path, project.gnss_path,
            project.tiepoints_path)


def _relative(path: Path, root: Path) -> str:
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return str(path)


def record_inputs(project) -> dict:
    """report.json "inputs": each of ``adjustment_input_paths`` relative to the project, with its size and sha256
    (None: absent). ``inputs_changed`` compares the files with it: a copy of the project (``cp -r``, unzip, a
    download: new modification times in copy order) is the same adjustment."""
    out = {}
    for p in adjustment_input_paths(project):
        try:
            out[_relative(p, project.root)] = {"size": p.stat().st_size, "sha256": file_sha256(p)} if p.is_file() else None
        except FileNotFoundError:  # (removed meanwhile)
            out[_relative(p, project.root)] = None
    return out


def inputs_changed(project, record: AdjustmentRecord) -> tuple[list[str], bool]:
    """The adjustment's inputs (``adjustment_input_paths``) that changed since ``record`` (at/report.json) was made,
    as paths relative to the project, and whether all of them were judged by content.

    By content when the report records its inputs (``record_inputs``): a file absent then, or of another size or
    sha256 now. A file not modified after the report (its time not later) and of the recorded size is taken as the
    same without hashing it; a later time alone (a copy, an unzip, the same content written again) is no change.
    A report written before the inputs were recorded (or a file its record does not name): by time, a file
    modified after the report (the same content written again counts too). A file removed since is not counted
    (a delivery may leave the tie points out)."""
    made = project.adjustment_report_path.stat().st_mtime_ns
    changed, by_time = [], False
    for p in adjustment_input_paths(project):
        try:
            st = p.stat()
        except FileNotFoundError:
            continue
        if not p.is_file():
            continue
        rel = _relative(p, project.root)
        if record.inputs is None or rel not in record.inputs:  # not recorded: by time
            if st.st_mtime_ns > made:
                changed.append(rel)
                by_time = True
            continue
        was = record.inputs[rel]
        if was is None or st.st_size != was["size"] or (st.st_mtime_ns > made and file_sha256(p) != was["sha256"]):
            changed.append(rel)
    return changed, not by_time


def read_adjustment_report(path) -> AdjustmentRecord:
    """``at/report.json`` as the adjustment wrote it; InputError naming the file when it is not one."""
    path = Path(path)
    d = read_record(path, ADJUSTMENT_REPORT, SCHEMA_VERSION)
    try:
        return adjustment_record(d, path)
    except InputError:  # already names the file and key (a CRS whose unit cannot be read)
        raise
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, ADJUSTMENT_REPORT, exc) from None
