"""``lidarctl strips check``: how overlapping strips disagree in height on smooth single-return surfaces.

Per pair (A, B) the differences dz = z_B - z_A of the common planar cells (``overlap``) with their mean,
RMS, standard deviation and NMAD (1.4826 x the median absolute deviation from the median: the spread
without the blunders); per strip the same over the differences of its pairs, signed as "this strip
minus the other" (a strip that is too high has a positive mean), and over all pairs; the NMAD of a strip
and of all pairs is about each pair's own median (``NMAD_DEFINITION``, strips.json "nmad_definition"). Against the across-track position
of strip A: the differences binned by A's scan angle, and a line dz = c + s u + q u^2 fitted over the
across-track position u (m): s (m/m) is the relative roll of the two strips (a roll error tilts a strip
across its track), q (1/m) its torsion-like bending; s is also given in degrees.

Outputs (OUTDIR, written as a whole or not at all): ``diff_<A>_<B>.tif`` (COG, dz in the CRS's height
unit, nodata outside the common smooth cells), ``diff_<A>_<B>.png`` (map with a diverging colour key in
metres, and dz against A's scan angle), ``strips.json`` (every number; lengths in metres) and
``index.html``. ``read_strip_check`` reads strips.json back into a ``StripCheckResult``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import Mapping

import numpy as np
import pyproj

from aerotri.core.atomic import atomic_dir, refuse_foreign_contents, refuse_input_as_output
from aerotri.core.errors import OptionError
from aerotri.core.records import to_record
from aerotri.core.textio import read_record, record_error
from aerotri.core.figures import pyplot, save_png
from lidarctl.strips.overlap import PairDiff, StripSet, SurfaceSettings, overlapping_pairs_or_error, read_strip_planes
from lidarctl.units import LengthUnits

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

NMAD_K = 1.4826
SCAN_BIN_DEG = 2.0
FILES = ("strips.json", "index.html")
NMAD_DEFINITION = ("1.4826 x the median of |dz - the median dz of the cell's own pair|: per pair over its cells, per "
                   "strip over its pairs' cells, for all pairs over every pair's cells (a scan-angle bin: about its "
                   "own median)")  # strips.json "nmad_definition", adjust.json too


SCHEMA_VERSION = 1  # strips.json: the layout of ``StripCheckResult.to_json``
STRIP_CHECK_VERSION = 2  # the chain's strips stage stamp: bump when strips.json changes at the same strips and options
STRIP_CHECK = "strip check (strips.json)"  # the record's name in messages


@dataclasses.dataclass(frozen=True)
class DiffStats:
    """Statistics of height differences (metres): n, mean, RMS, standard deviation, median, NMAD and the
    95th percentile of |dz|; only ``n_cells`` (0) when there are none. strips.json holds
    ``to_record(d, drop_none=True)`` (``{"n_cells": 0}`` without differences)."""

    n_cells: int
    mean_m: float | None = None
    rms_m: float | None = None
    std_m: float | None = None
    median_m: float | None = None
    nmad_m: float | None = None
    p95_abs_m: float | None = None

    @classmethod
    def of_record(cls, d: dict) -> "DiffStats":
        """From its record (or a record holding its keys, as a pair's in strips.json)."""
        return cls(**{f.name: d[f.name] for f in dataclasses.fields(cls) if f.name in d})


@dataclasses.dataclass(frozen=True)
class ScanBin:
    """dz in one bin of strip A's scan angle (degrees; metres)."""

    scan_angle_deg: float
    n: int
    mean_m: float
    nmad_m: float


@dataclasses.dataclass(frozen=True)
class RollFit:
    """The robust fit dz = c + s u + q u^2 over the across-track position u (m) about ``u_ref_m``."""

    u_ref_m: float
    offset_m: float
    slope_m_per_m: float
    relative_roll_deg: float
    curvature_per_m: float
    slope_m_per_scan_deg: float
    u_span_m: float


@dataclasses.dataclass(frozen=True)
class ScanProfile:
    """dz against strip A's scan angle: the bins and the fit (None: fewer than 5 cells or no spread)."""

    bins: tuple[ScanBin, ...]
    fit: RollFit | None


@dataclasses.dataclass(frozen=True)
class Offset3d:
    """The 3D offset of strip B against strip A (B - A, metres) with its sigmas, from ``cells`` planar cells
    (``sloped_cells`` steeper than 10 deg) up to ``max_slope_deg``."""

    dx_m: float
    dy_m: float
    dz_m: float
    sigma_dx_m: float
    sigma_dy_m: float
    sigma_dz_m: float
    cells: int
    sloped_cells: int
    max_slope_deg: float
    # does a rigid shift model the pair? sigma0: the residuals (normal distance after the shift) against their
    # expected noise (1: as the planes' scatter predicts); residual_trend_m: their change across the overlap (a
    # robust line against A's across-track position, over its span) with its sigma; a boresight error tilts and
    # turns the strips, which no shift takes up, and the shift's sigmas then understate its error
    sigma0: float | None = None
    residual_trend_m: float | None = None
    sigma_residual_trend_m: float | None = None


@dataclasses.dataclass(frozen=True)
class PairCheck:
    """One overlapping pair: dz = z_b - z_a on the common smooth cells, against a's scan angle, the 3D
    offset (None: fewer than 10 shared planar cells), the files written for it (names in OUTDIR) and the
    common smooth cells left out as two different surfaces (``SurfaceSettings.max_dz_m``)."""

    a: str
    b: str
    common_planar_cells: int
    diff: DiffStats
    area_m2: float
    vs_scan_angle_a: ScanProfile
    offset_3d_b_minus_a: Offset3d | None
    raster: str | None = None
    png: str | None = None
    different_surface_cells: int = 0


@dataclasses.dataclass(frozen=True)
class StripCheck:
    """One strip: its source, points, planar cells, pairs, and the differences "this strip minus the others"."""

    name: str
    file: str
    point_source_id: int | None
    points: int
    planar_cells: int
    pairs: int
    minus_others: DiffStats


@dataclasses.dataclass(frozen=True)
class StripCheckResult:
    """What ``lidarctl strips check`` found (strips.json; ``read_strip_check`` reads it back): the pairs, the
    strips and all pairs together (metres), the cell size and surface settings, the CRS and its units."""

    convention: str
    cell_m: float
    crs: str | None
    units: LengthUnits
    points: int
    strips: tuple[StripCheck, ...]
    pairs: tuple[PairCheck, ...]
    skipped_pairs: Mapping[str, str]  # "a-b" -> why the pair was left out
    all_pairs: DiffStats
    surface: SurfaceSettings
    map_colour_limit_m: float | None = None
    overview_png: str | None = None
    seconds: float | None = None
    points_per_s: float | None = None
    schema_version: int = SCHEMA_VERSION
    # what the NMADs are (``NMAD_DEFINITION``); None: a strips.json written before it was said (its strips' NMAD
    # pooled about one median, its all pairs' too before trial-quick)
    nmad_definition: str | None = NMAD_DEFINITION

    def to_json(self) -> str:
        """strips.json's text."""
        return json.dumps(_check_record(self), indent=2) + "\n"


def _pair_record(p: PairCheck) -> dict:
    fit = p.vs_scan_angle_a.fit
    out = {"a": p.a, "b": p.b, "common_planar_cells": p.common_planar_cells,
           "different_surface_cells": p.different_surface_cells, **to_record(p.diff, drop_none=True),
           "area_m2": p.area_m2,
           "vs_scan_angle_a": {"bins": [dataclasses.asdict(b) for b in p.vs_scan_angle_a.bins],
                               "fit": dataclasses.asdict(fit) if fit is not None else {}},
           "offset_3d_b_minus_a": dataclasses.asdict(p.offset_3d_b_minus_a) if p.offset_3d_b_minus_a else {}}
    if (why := rigid_fit_warning(p.offset_3d_b_minus_a)) is not None:
        out["offset_3d_warning"] = why
    for k in ("raster", "png"):
        if getattr(p, k) is not None:
            out[k] = getattr(p, k)
    return out


def _check_record(r: StripCheckResult) -> dict:
    out = {"schema_version": r.schema_version, "convention": r.convention,
           **({"nmad_definition": r.nmad_definition} if r.nmad_definition is not None else {}),
           "cell_m": r.cell_m, "crs": r.crs,
           **r.units.as_dict(), "points": r.points,
           "strips": [{**{f.name: getattr(t, f.name) for f in dataclasses.fields(t)},
                       "minus_others": to_record(t.minus_others, drop_none=True)} for t in r.strips],
           "pairs": [_pair_record(p) for p in r.pairs], "skipped_pairs": dict(r.skipped_pairs),
           "all_pairs": to_record(r.all_pairs, drop_none=True), "surface": dataclasses.asdict(r.surface)}
    for k in ("map_colour_limit_m", "overview_png"):
        if getattr(r, k) is not None:
            out[k] = getattr(r, k)
    if r.seconds is not None:
        out.update(seconds=r.seconds, points_per_s=r.points_per_s)
    return out


def _pair_of(d: dict) -> PairCheck:
    v = d["vs_scan_angle_a"]
    o = d["offset_3d_b_minus_a"]
    return PairCheck(d["a"], d["b"], d["common_planar_cells"], DiffStats.of_record(d), d["area_m2"],
                     ScanProfile(tuple(ScanBin(**b) for b in v["bins"]), RollFit(**v["fit"]) if v["fit"] else None),
                     Offset3d(**o) if o else None, d.get("raster"), d.get("png"), d.get("different_surface_cells", 0))


def _check_of(d: dict) -> StripCheckResult:
    """The ``StripCheckResult`` of a strips.json record (``read_strip_check``)."""
    strips = tuple(StripCheck(**{**t, "minus_others": DiffStats.of_record(t["minus_others"])}) for t in d["strips"])
    units = LengthUnits(d["xy_unit_m"], d["z_unit_m"], known=d["xy_unit"] != "file units")
    return StripCheckResult(d["convention"], d["cell_m"], d["crs"], units, d["points"], strips,
                            tuple(_pair_of(p) for p in d["pairs"]), d["skipped_pairs"], DiffStats.of_record(d["all_pairs"]),
                            SurfaceSettings(**d["surface"]), d.get("map_colour_limit_m"), d.get("overview_png"),
                            d.get("seconds"), d.get("points_per_s"), d.get("schema_version", SCHEMA_VERSION),
                            d.get("nmad_definition"))


def read_strip_check(path) -> StripCheckResult | None:
    """strips.json as written by ``check_strips`` (or the check before/after of ``adjust_strips``); None when it
    records that there was nothing to compare (``nothing_compared``). InputError naming the file when it is
    not one."""
    path = Path(path)
    d = read_record(path, STRIP_CHECK, SCHEMA_VERSION)
    if "why" in d:
        return None
    try:
        return _check_of(d)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, STRIP_CHECK, exc) from None


def owned_by_strips(entry: Path) -> bool:
    """Whether ``entry`` in an OUTDIR of ``strips check`` / ``strips adjust`` (the chain's lidar_out/strips/ holds
    either) is what one of them writes there: the folder is replaced as a whole, anything else is refused
    (``aerotri.core.atomic.refuse_foreign_contents``)."""
    name = entry.name
    if entry.is_dir():
        return name in ("check_before", "check_after")
    return (name in ("index.html", "overview.png", "strips.json", "adjust.json")
            or (name.startswith("diff_") and entry.suffix in (".tif", ".png"))
            or entry.suffix.lower() in (".las", ".laz"))  # adjust's corrected strips


def refuse_replacing(outdir: Path, paths, option: str | None = "OUTDIR") -> None:
    """OptionError when OUTDIR, which is replaced as a whole, holds an input strip or a file neither strips
    command writes (``lidarctl strips check lidar/*.las lidar`` deleted the strips it had read). ``option``: what
    the message names (None: the folder only, the chain's lidar_out/strips/)."""
    for q in map(Path, paths):
        if outdir.resolve() == q.resolve() or outdir.resolve() in q.resolve().parents:
            raise OptionError(f"{q}: the input lies in the output folder {outdir}, which is replaced as a whole; "
                              "choose another output folder", param=option)
    if has_strips_record(outdir):
        refuse_foreign_contents(outdir, owned_by_strips, "lidarctl strips", option)
    else:  # not a previous output, whatever its names (every strips output holds its record): only clutter passes
        refuse_foreign_contents(outdir, lambda e: False, "lidarctl strips (the folder holds no strips.json or "
                                "adjust.json of it)", option)


def has_strips_record(outdir: Path) -> bool:
    """Whether ``outdir`` holds the record one of the strips commands writes (strips.json / adjust.json: a JSON
    object with our ``schema_version``, or, written before 2026-11-28 without one, with our keys: ``convention``,
    ``cell_m`` and ``pairs``, adjust.json's ``model``, ``cell_m`` and ``parameters``, or a lone ``why``): the folder is then a previous output (provenance, not names: a user's
    folder of .las files is not ours because its names are); every output of either command holds one (a run that
    compares nothing too, ``record_nothing_compared``), and the folder is written whole (``atomic_dir``)."""
    for name in ("strips.json", "adjust.json"):
        try:
            d = json.loads((Path(outdir) / name).read_text())
        except (OSError, ValueError):
            continue
        if isinstance(d, dict) and ("schema_version" in d or {"convention", "cell_m", "pairs"} <= d.keys()
                                    or {"model", "cell_m", "parameters"} <= d.keys() or d.keys() == {"why"}):
            return True
    return False


def record_nothing_compared(folder: Path, why: str) -> None:
    """strips.json saying why there is no check (the chain goes on without one; ``nothing_compared``)."""
    (Path(folder) / "strips.json").write_text(json.dumps({"schema_version": SCHEMA_VERSION, "why": why}, indent=2) + "\n")


def nothing_compared(path) -> str | None:
    """Why the strip check at ``path`` (strips.json) compared nothing, None when it did or there is none."""
    path = Path(path)
    if not path.is_file():
        return None
    return read_record(path, STRIP_CHECK, SCHEMA_VERSION).get("why")


def stats(dz: np.ndarray) -> DiffStats:
    """n, mean, RMS, standard deviation, median, NMAD and 95th percentile of |dz| (metres)."""
    dz = np.asarray(dz, float)
    if len(dz) == 0:
        return DiffStats(0)
    med = float(np.median(dz))
    return DiffStats(int(len(dz)), mean_m=float(dz.mean()), rms_m=float(np.sqrt(np.mean(dz ** 2))),
                     std_m=float(dz.std(ddof=1)) if len(dz) > 1 else 0.0, median_m=med,
                     nmad_m=float(NMAD_K * np.median(np.abs(dz - med))),
                     p95_abs_m=float(np.percentile(np.abs(dz), 95)))


def pairs_stats(dz_per_pair: list[np.ndarray]) -> DiffStats:
    """``stats`` of the pairs' dz together, but the NMAD about each pair's own median (``NMAD_DEFINITION``): the
    statistics of all pairs and of a strip against the others. Which strip of a pair is a is arbitrary, so pooled
    signed differences of pairs offset in opposite directions (the demo's +0.047 and -0.043 m) made a bimodal spread
    whose NMAD (0.061 m) exceeded the RMS and every pair's NMAD (0.018 m); a strip high against one neighbour and
    low against another made the same of its "minus others"."""
    dz_per_pair = [np.asarray(d, float) for d in dz_per_pair]
    pooled = stats(np.concatenate(dz_per_pair) if dz_per_pair else np.zeros(0))
    if pooled.n_cells == 0:
        return pooled
    within = np.concatenate([d - np.median(d) for d in dz_per_pair if len(d)])
    return dataclasses.replace(pooled, nmad_m=float(NMAD_K * np.median(np.abs(within))))


def scan_profile(dz: np.ndarray, angle_deg: np.ndarray, u_m: np.ndarray, bin_deg: float = SCAN_BIN_DEG) -> ScanProfile:
    """dz binned by scan angle (mean, NMAD, n per bin) and the robust fit dz = c + s u + q u^2 over the
    across-track position (Huber-weighted; u in metres)."""
    edges = np.arange(np.floor(angle_deg.min() / bin_deg) * bin_deg, angle_deg.max() + bin_deg, bin_deg)
    k = np.clip(np.digitize(angle_deg, edges) - 1, 0, max(len(edges) - 2, 0))
    bins = []
    for b in np.unique(k):
        d = dz[k == b]
        bins.append(ScanBin(float(edges[b] + bin_deg / 2), int(len(d)), float(d.mean()),
                            float(NMAD_K * np.median(np.abs(d - np.median(d))))))
    fit = None
    if len(dz) >= 5 and np.ptp(u_m) > 0:
        u0 = float(np.mean(u_m))
        uu = u_m - u0
        G = np.column_stack([np.ones_like(uu), uu, uu ** 2])
        x = _huber_lsq(G, dz)
        s_deg = np.polyfit(angle_deg, dz, 1)[0] if np.ptp(angle_deg) > 0 else np.nan
        fit = RollFit(u_ref_m=u0, offset_m=float(x[0]), slope_m_per_m=float(x[1]),
                      relative_roll_deg=float(np.degrees(np.arctan(x[1]))), curvature_per_m=float(x[2]),
                      slope_m_per_scan_deg=float(s_deg), u_span_m=float(np.ptp(u_m)))
    return ScanProfile(tuple(bins), fit)


def _huber_lsq(G: np.ndarray, y: np.ndarray, k: float = 1.5, iterations: int = 10, return_weights: bool = False):
    """Least squares with Huber weights (threshold ``k`` robust sigmas, the NMAD of the residuals)."""
    w = np.ones(len(y))
    x = np.zeros(G.shape[1])
    for _ in range(iterations):
        sw = np.sqrt(w)
        x = np.linalg.lstsq(G * sw[:, None], y * sw, rcond=None)[0]
        r = y - G @ x
        s = max(NMAD_K * np.median(np.abs(r - np.median(r))), 1e-6)
        a = np.abs(r) / (k * s)
        w = np.where(a <= 1, 1.0, 1.0 / np.maximum(a, 1e-12))
    return (x, w) if return_weights else x


def pair_offset_3d(A, B, max_slope_deg: float = 60.0) -> Offset3d | None:
    """The 3D offset t of strip B against strip A (B - A, metres) from every planar cell they share up to
    ``max_slope_deg``: n . (c_B - c_A) = n . t (n the mean normal, c the centroids), Huber-weighted least
    squares with sigmas (sigma0 a posteriori). Horizontal components come from sloped surfaces (roofs,
    embankments): their sigmas say how well the overlap determines them. None: fewer than 10 such cells."""
    common, ka, kb = np.intersect1d(A.ids, B.ids, assume_unique=True, return_indices=True)
    ok = (A.slope_deg[ka] <= max_slope_deg) & (B.slope_deg[kb] <= max_slope_deg)
    ka, kb = ka[ok], kb[ok]
    if len(ka) < 10:
        return None
    n = A.normals()[ka] + B.normals()[kb]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    y = np.einsum("ij,ij->i", n, B.centroid[kb] - A.centroid[ka])
    sig = np.sqrt(A.rms_m[ka] ** 2 / A.n[ka] + B.rms_m[kb] ** 2 / B.n[kb] + 0.003 ** 2)
    t, w = _huber_lsq(n / sig[:, None], y / sig, return_weights=True)
    N = (n / sig[:, None] * w[:, None]).T @ (n / sig[:, None])
    r = (y - n @ t) / sig
    s0 = float(np.sqrt(np.sum(w * r ** 2) / max(len(y) - 3, 1)))
    try:
        sd = s0 * np.sqrt(np.diag(np.linalg.inv(N)))
    except np.linalg.LinAlgError:
        sd = np.full(3, np.inf)
    sloped = int(np.sum(np.maximum(A.slope_deg[ka], B.slope_deg[kb]) > 10.0))
    trend, sd_trend = _residual_trend(y - n @ t, A.u_m[ka])
    return Offset3d(float(t[0]), float(t[1]), float(t[2]), float(sd[0]), float(sd[1]), float(sd[2]), int(len(y)),
                    sloped, max_slope_deg, sigma0=s0, residual_trend_m=trend, sigma_residual_trend_m=sd_trend)


@dataclasses.dataclass(frozen=True)
class RigidFitRule:
    """When a pair's rigid 3D shift is said not to model it (``rigid_fit_warning``): its residuals' sigma0 above
    ``max_sigma0``, or their trend across the overlap beyond ``max_trend_sigmas`` of its sigma and
    ``min_trend_m``. Chosen on the simulator (bench/eval_strips_rigid_fit.py)."""

    max_sigma0: float = 3.0
    max_trend_sigmas: float = 5.0
    min_trend_m: float = 0.02


RIGID_FIT = RigidFitRule()


def rigid_fit_warning(o: Offset3d | None, rule: RigidFitRule = RIGID_FIT) -> str | None:
    """Why a rigid shift does not model the pair (its sigmas then understate the shift's error), None when it
    does (or the fit diagnostics are missing: a strips.json of before they were recorded)."""
    if o is None or o.sigma0 is None:
        return None
    why = []
    if o.sigma0 > rule.max_sigma0:
        why.append(f"the residuals are {o.sigma0:.1f} x their expected noise")
    t, st = o.residual_trend_m, o.sigma_residual_trend_m
    if t is not None and st and abs(t) > rule.max_trend_sigmas * st and abs(t) > rule.min_trend_m:
        why.append(f"they change by {t:+.3f} +- {sigma_text(st)} m across the overlap (with the scan angle)")
    if not why:
        return None
    return ("a rigid shift does not model this pair (" + "; ".join(why) + "): a boresight or scan-angle error tilts "
            "and turns the strips; the shift and its sigmas are not to be trusted, adjust the strips with their "
            "trajectories (lidarctl strips adjust --trajectory). " + FORMAL_SIGMAS)


# said with every warning and on the page: the sigmas take the cells as independent, and the trend's floor (2 cm)
# binds before its 5 sigma (about 0.5 mm on AHN3), so a smaller boresight error goes unwarned
FORMAL_SIGMAS = ("No warning does not make the plan sigmas trustworthy: they are formal (the cells taken as "
                 "independent), and a boresight error leaving a trend under 2 cm is not warned about while the plan "
                 "offsets can be many sigmas off (simulator, 1/20 of the boresight of bench/eval_strips_rigid_fit.py: "
                 "10 of 12 pairs 3.6-24 sigmas off in plan, none warned; bench/results/strips_rigid_fit_small.json).")


def sigma_text(v_m: float) -> str:
    """A sigma in metres: 3 decimals, below 1 mm its first digit (0.0001), never "0.000"."""
    return f"{v_m:.3f}" if v_m >= 0.001 else f"{v_m:.1g}"


def offset_3d_text(o: Offset3d) -> str:
    """"(+0.056 +- 0.002, -0.029 +- 0.003, +0.048 +- 0.0001) m": the 3D offset with its sigmas."""
    return (f"({o.dx_m:+.3f} +- {sigma_text(o.sigma_dx_m)}, {o.dy_m:+.3f} +- {sigma_text(o.sigma_dy_m)}, "
            f"{o.dz_m:+.3f} +- {sigma_text(o.sigma_dz_m)}) m")


def _residual_trend(r_m: np.ndarray, u_m: np.ndarray) -> tuple[float | None, float | None]:
    """(change of the residuals ``r_m`` across the span of ``u_m`` from a Huber line, its sigma); (None, None)
    without a span. The sigma comes from the residuals' NMAD about the line (cells taken as independent)."""
    if len(r_m) < 10 or not np.ptp(u_m) > 0:
        return None, None
    uu = u_m - u_m.mean()
    G = np.column_stack([np.ones_like(uu), uu])
    x, w = _huber_lsq(G, r_m, return_weights=True)
    e = r_m - G @ x
    s = max(NMAD_K * float(np.median(np.abs(e - np.median(e)))), 1e-6)
    try:
        sd_slope = s * float(np.sqrt(np.linalg.inv((G * w[:, None]).T @ G)[1, 1]))
    except np.linalg.LinAlgError:
        return None, None
    span = float(np.ptp(u_m))
    return float(x[1]) * span, sd_slope * span


@dataclasses.dataclass
class CheckResult:
    """The numbers of a check (``summary``: what strips.json holds; ``write_outputs`` adds the files) and the
    pair differences."""

    summary: StripCheckResult
    pairs: list[PairDiff]
    strip_set: StripSet


def analyse(ss: StripSet, params: SurfaceSettings, paths, min_cells: int = 20) -> CheckResult:
    """Statistics of every overlapping pair and every strip (InputError: one strip, no overlap, no smooth
    surface)."""
    pairs, skipped = overlapping_pairs_or_error(ss, params, paths, min_cells)
    per_strip: dict[str, list[np.ndarray]] = {s.name: [] for s in ss.strips}
    pair_out = []
    by_name = {s.name: s for s in ss.strips}
    for p in pairs:
        per_strip[p.a].append(-p.dz_m)
        per_strip[p.b].append(p.dz_m)
        pair_out.append(PairCheck(p.a, p.b, p.common_cells, stats(p.dz_m), float(len(p.dz_m) * ss.grid.cell_m ** 2),
                                  scan_profile(p.dz_m, p.scan_angle_a_deg, p.u_a_m),
                                  pair_offset_3d(by_name[p.a], by_name[p.b]), different_surface_cells=p.apart_cells))
    strip_out = []
    for s in ss.strips:
        strip_out.append(StripCheck(s.name, str(s.source.path), s.source.point_source_id, s.n_points,
                                    int(len(s.ids)), sum(1 for p in pairs if s.name in (p.a, p.b)),
                                    pairs_stats(per_strip[s.name])))
    summary = StripCheckResult(
        "dz = z_b - z_a per pair at the cell centres (metres); per strip: this strip minus the others; NMAD about "
        "each pair's own median",
        ss.grid.cell_m, ss.crs.to_string() if ss.crs is not None else None, ss.units, ss.n_points, tuple(strip_out),
        tuple(pair_out), skipped, pairs_stats([p.dz_m for p in pairs]),
        dataclasses.replace(params, cell_m=ss.grid.cell_m))
    return CheckResult(summary, pairs, ss)


def check_strips(paths, outdir, params: SurfaceSettings = SurfaceSettings(), *, crs=None,
                 title: str = "Strip differences", vmax_m: float | None = None, png: bool = True,
                 option: str | None = "OUTDIR") -> StripCheckResult:
    """The stage: read the strips, analyse the overlaps and write OUTDIR (see the module docstring). Returns
    what strips.json holds (with ``seconds`` and ``points_per_s``). ``option``: what a refusal names (None: the
    folder only, the chain's)."""
    t0 = time.perf_counter()
    paths = [Path(p) for p in paths]
    outdir = Path(outdir)
    refuse_input_as_output(outdir, paths, option)
    refuse_replacing(outdir, paths, option)
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(paths)  # a strip given twice would count every point twice
    ss = read_strip_planes(paths, params, crs)
    res = analyse(ss, params, paths)
    limit = strip_rmsdz_limit_m()
    for p in res.summary.pairs:
        if (why := rigid_fit_warning(p.offset_3d_b_minus_a)) is not None:
            o = p.offset_3d_b_minus_a
            log.warning(f"{p.b} - {p.a}: 3D offset {offset_3d_text(o)}: {why}")
        if (why := pair_beyond_words(p, limit)) is not None:
            log.warning(why)
    with atomic_dir(outdir) as tmp:
        write_outputs(res, tmp, title, vmax_m, png)
        dt = time.perf_counter() - t0
        summary = dataclasses.replace(res.summary, seconds=dt, points_per_s=res.summary.points / dt if dt > 0 else None)
        (tmp / "strips.json").write_text(summary.to_json())
    return summary


def strip_rmsdz_limit_m() -> float:
    """The interswath RMSDz a pair is warned beyond: the project's tolerance tables' ``strip_rmsdz_m`` (0.08 m, USGS
    LBS QL1/QL2 as the tables hold it; the QA report judges the strips by it)."""
    from aerotri.core.tolerances import load_table

    return float(load_table("1:5000", "flat").limits["strip_rmsdz_m"])


def pair_beyond_words(p: "PairCheck", limit_m: float) -> str | None:
    """A warning for a pair whose RMS dz exceeds ``limit_m`` (trial s99 lidmut L5: a strip 1 m high printed its
    means, +0.993 / -1.023 m, with no warning); None within it or without cells."""
    d = p.diff
    if not d.n_cells or d.rms_m is None or d.rms_m <= limit_m:
        return None
    offset = d.median_m is not None and abs(d.median_m) > limit_m
    return (f"{p.b} - {p.a}: RMS {d.rms_m:.3f} m over {d.n_cells} smooth cells, beyond the {limit_m:g} m interswath "
            "RMSDz of the tolerance tables (strip_rmsdz_m; USGS LBS QL1/QL2): "
            + (f"the strips stand {d.median_m:+.3f} m apart (median): a strip's height offset (its trajectory, a "
               "geoid or datum applied to one strip only); lidarctl strips adjust estimates it" if offset else
               f"a scatter about a median of {d.median_m:+.3f} m (NMAD {d.nmad_m:.3f} m): a misalignment in plan or "
               "attitude, or cells of two surfaces"))


def colour_limit_m(pairs: list[PairDiff]) -> float:
    """Symmetric colour range of the maps: the 98th percentile of |dz| over all pairs, 2 cm to 1 m."""
    d = np.abs(np.concatenate([p.dz_m for p in pairs]))
    return float(np.clip(np.percentile(d, 98), 0.02, 1.0))


def pair_raster(p: PairDiff, ss: StripSet):
    """(north-up dz array in metres with NaN outside the cells, transform in metres) over the pair's cells."""
    from rasterio.transform import from_origin

    g = ss.grid
    i, j = np.divmod(p.ids, g.ncols)
    i0, i1, j0, j1 = i.min(), i.max(), j.min(), j.max()
    a = np.full((i1 - i0 + 1, j1 - j0 + 1), np.nan)
    a[i1 - i, j - j0] = p.dz_m
    return a, from_origin(g.x0 + j0 * g.cell_m, g.y0 + (i1 + 1) * g.cell_m, g.cell_m, g.cell_m)


def write_outputs(res: CheckResult, folder: Path, title: str, vmax_m: float | None, png: bool = True) -> None:
    """Rasters, PNGs and the HTML page of a check into ``folder`` (strips.json is written by the caller);
    ``res.summary`` gets the colour limit and the files' names."""
    from lidarctl.rasters.products import _transform_in_units, write_cog
    from aerotri.geom.crs.definition import length_unit_name

    ss = res.strip_set
    units = ss.units
    vmax = vmax_m or colour_limit_m(res.pairs)
    rows = []
    for p, ps in zip(res.pairs, res.summary.pairs):
        stem = f"diff_{p.a}_{p.b}"
        a, transform = pair_raster(p, ss)
        write_cog(folder / f"{stem}.tif", units.z_from_m(a), _transform_in_units(transform, units), ss.crs,
                  unit=length_unit_name(units.z_m, long=True),
                  description=f"dz = z({p.b}) - z({p.a}) on smooth single-return surfaces",
                  tags={"LINEAR_UNITS": units.xy_name, "VERTICAL_UNITS": units.z_name, "CELL_SIZE_M": ss.grid.cell_m})
        ps = dataclasses.replace(ps, raster=f"{stem}.tif")
        if png:
            _pair_png(folder / f"{stem}.png", p, ps=ps, a=a, transform=transform, vmax=vmax, title=title,
                      xy_m=units.xy_m, xy_unit=units.xy_name)
            ps = dataclasses.replace(ps, png=f"{stem}.png")
        rows.append(ps)
    res.summary = dataclasses.replace(res.summary, pairs=tuple(rows), map_colour_limit_m=vmax)
    if png:
        _overview_png(folder / "overview.png", res, vmax, title)
        res.summary = dataclasses.replace(res.summary, overview_png="overview.png")
    _html(folder / "index.html", res.summary, title)


def _pair_png(path, p: PairDiff, *, ps: PairCheck, a, transform, vmax: float, title: str, xy_m: float = 1.0,
              xy_unit: str = "m") -> None:
    """The pair's dz map, axes in the file's coordinates (``transform`` is in metres: divided by ``xy_m``, metres
    per file unit; a file in feet showed metre-scaled numbers that are no CRS's coordinates), and dz by scan angle."""
    plt = pyplot()

    ny, nx = a.shape
    extent = tuple(v / xy_m for v in (transform.c, transform.c + nx * transform.a, transform.f - ny * transform.a,
                                      transform.f))
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5.2), gridspec_kw={"width_ratios": [1.25, 1]})
    im = ax.imshow(a, cmap="RdBu_r", vmin=-vmax, vmax=vmax, extent=extent, interpolation="nearest")
    ax.set_facecolor("#d9d9d9")
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    ax.set_xlabel(f"easting [{xy_unit}]")
    ax.set_ylabel(f"northing [{xy_unit}]")
    cb = fig.colorbar(im, ax=ax, shrink=0.85)
    cb.set_label(f"dz = z({p.b}) - z({p.a})  [m]")
    d = ps.diff
    ax.set_title(f"{p.b} - {p.a}\nmean {d.mean_m:+.3f} m, RMS {d.rms_m:.3f} m, NMAD {d.nmad_m:.3f} m "
                 f"({d.n_cells} cells)", fontsize=9)
    ax2.scatter(p.scan_angle_a_deg, p.dz_m, s=2, color="0.6", alpha=0.5, rasterized=True)
    bins = ps.vs_scan_angle_a.bins
    ax2.errorbar([b.scan_angle_deg for b in bins], [b.mean_m for b in bins],
                 yerr=[b.nmad_m for b in bins], fmt="o-", color="C3", ms=4, label="bin mean +- NMAD")
    fit = ps.vs_scan_angle_a.fit
    if fit:
        ax2.set_title(f"relative roll {fit.relative_roll_deg * 1000:+.1f} mdeg "
                      f"({fit.slope_m_per_scan_deg * 1000:+.2f} mm per scan degree)", fontsize=9)
    ax2.axhline(0, color="k", lw=0.6)
    ax2.set_ylim(-1.5 * vmax, 1.5 * vmax)
    ax2.set_xlabel(f"scan angle of {p.a} [deg]")
    ax2.set_ylabel("dz [m]")
    ax2.legend(fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=100)


def _overview_png(path, res: CheckResult, vmax: float, title: str) -> None:
    plt = pyplot()

    ss = res.strip_set
    g = ss.grid
    fig, ax = plt.subplots(figsize=(9, 8))
    # the strips' planar cells in greys (a hue beside the red-blue dz ramp reads as a difference), each strip named
    f = 1.0 / ss.units.xy_m  # the file's coordinates (the grid is in metres)
    for k, s in enumerate(ss.strips):
        xc, yc = g.centres(s.ids)
        xc, yc = xc * f, yc * f
        ax.scatter(xc, yc, s=1, color=("0.82", "0.68")[k % 2], label="planar cells of a strip" if k == 0 else None,
                   rasterized=True)
        if len(xc):
            ax.text(float(np.median(xc)), float(np.median(yc)), s.name, fontsize=7, ha="center", va="center",
                    bbox=dict(facecolor="white", edgecolor="none", alpha=0.7, pad=1))
    im = None
    for p in res.pairs:
        xc, yc = g.centres(p.ids)
        xc, yc = xc * f, yc * f
        im = ax.scatter(xc, yc, c=p.dz_m, s=4, marker="s", cmap="RdBu_r", vmin=-vmax, vmax=vmax, rasterized=True)
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    ax.set_xlabel(f"easting [{ss.units.xy_name}]")
    ax.set_ylabel(f"northing [{ss.units.xy_name}]")
    if im is not None:
        fig.colorbar(im, ax=ax, shrink=0.8).set_label("dz of each pair (z_b - z_a) [m]")
    ax.legend(fontsize=7, markerscale=8, loc="upper right")
    ax.set_title(f"{title}: all pairs, RMS {res.summary.all_pairs.rms_m:.3f} m", fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=100)


def _not_compared(r: StripCheckResult) -> dict[str, str]:
    """Strip name -> why no cell of it was compared (its points and planar cells, and the strips it overlaps too
    little or none), for each strip without differences."""
    out = {}
    for t in r.strips:
        if t.minus_others.n_cells:
            continue
        others = [k[len(t.name) + 1:] if k.startswith(t.name + "-") else k[:-len(t.name) - 1]
                  for k in r.skipped_pairs if k.startswith(t.name + "-") or k.endswith("-" + t.name)]
        why = (f"too few common smooth cells with {', '.join(others)}" if others else "overlaps no other strip")
        out[t.name] = f"{t.points} points, {t.planar_cells} planar cells: {why}"
    return out


def _html(path: Path, summary: StripCheckResult, title: str) -> None:
    from aerotri.core.pages import render

    # the page shows strips.json's numbers, under its names
    path.write_text(render("strips_check.html.j2", package="lidarctl", s=_check_record(summary),
                           not_compared=_not_compared(summary), title=title, crs_name=_crs_name(summary.crs),
                           formal_sigmas=FORMAL_SIGMAS))


def _crs_name(crs: str | None) -> str:
    """The page's name of strips.json's CRS: EPSG:code, else the CRS's name (the JSON keeps the whole WKT; the page
    showed it, 1,500 characters for a LAS file in feet whose CRS has no EPSG code)."""
    if crs is None:
        return "none"
    from aerotri.geom.crs.definition import crs_label

    try:
        return crs_label(pyproj.CRS.from_user_input(crs))
    except pyproj.exceptions.CRSError:
        return crs
