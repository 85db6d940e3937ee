"""The accuracy standards a delivery is judged against, as data: one TOML file per standard in this folder
(``asprs2023.toml``, ``asprs2014.toml``, ``usgs_lbs.toml``, ``cn_at.toml``), every limit with its source and whether its number
was confirmed in the document (docs/standards.md lists them). The "thesis" standard is the project's
map-scale tolerance tables (aerotri/core/tolerance_tables/cn_1to*.toml), read through aerotri.core.tolerances.

Each file is read into its own frozen dataclass (the three standards state their limits in three shapes: ASPRS
by class multiples and counts, the LBS by quality level, the Chinese specifications in map millimetres by scale
and terrain, but for the features at 1:5000 / 1:10000 in the design table's metres): ``asprs2023()``, ``usgs_lbs()``, ``cn_at()``. The TOML keys are the field names
(``aerotri.core.settings.from_table`` reads them; the files ship with the package, so a key of another name is a
bug, not bad input).
"""

from __future__ import annotations

import dataclasses
import tomllib
from functools import lru_cache
from pathlib import Path

from aerotri.core.settings import from_table

STANDARDS_DIR = Path(__file__).parent
STANDARD_FILES = {"asprs2023": "asprs2023.toml", "asprs2014": "asprs2014.toml", "usgs-lbs": "usgs_lbs.toml",
                  "cn-at": "cn_at.toml"}
STANDARD_KEYS = ("asprs2023", "asprs2014", "usgs-lbs", "cn-at", "thesis")


@dataclasses.dataclass(frozen=True)
class StandardInfo:
    """A standard's ``[standard]`` table: its key, the name reports give it, the document and the edition read."""

    key: str
    name: str
    document: str
    edition: str


# -- ASPRS Positional Accuracy Standards, Edition 2 (2023) ---------------------------------------------
@dataclasses.dataclass(frozen=True)
class AsprsLimit:
    """One rule of the ASPRS standard: its number (None for a rule without one) in ``unit``, or no pass/fail
    at all (``pass_fail`` False: reported only); where it stands and how far it was confirmed."""

    unit: str
    clause: str
    evidence: str
    confirmed: bool
    value: float | None = None
    pass_fail: bool = True
    formula_confirmed: bool | None = None  # for a rule with a formula: whether the formula was read


@dataclasses.dataclass(frozen=True)
class AsprsLimits:
    check_points_min: AsprsLimit
    check_points_max: AsprsLimit
    vertical_vva: AsprsLimit  # vegetated vertical accuracy: reported, no pass/fail
    checkpoint_accuracy_included: AsprsLimit  # the check points' own accuracy in the product's RMSE
    checkpoint_accuracy_factor: AsprsLimit  # check points this many times as accurate as the class tested


@dataclasses.dataclass(frozen=True)
class AsprsLadders:
    """The classes (cm) "the finest class met" is named from, horizontal and vertical, ascending."""

    horizontal_cm: tuple[float, ...]
    vertical_cm: tuple[float, ...]
    evidence: str
    confirmed: bool


@dataclasses.dataclass(frozen=True)
class Asprs2023:
    standard: StandardInfo
    limits: AsprsLimits
    ladders: AsprsLadders


# -- ASPRS Positional Accuracy Standards, Edition 1 (2014) ---------------------------------------------
@dataclasses.dataclass(frozen=True)
class Asprs2014Limits:
    """Edition 1's rules a compliance report uses (``asprs2014.toml``): the check points required (NVA, VVA), how
    much more accurate than the class they must be, and the multiples of the per-axis class X."""

    check_points_min: AsprsLimit
    vva_check_points_min: AsprsLimit
    checkpoint_accuracy_factor: AsprsLimit
    horizontal_radial_factor: AsprsLimit  # RMSE_r <= this x X (X per axis)
    nva_95_factor: AsprsLimit  # NVA at 95 % = this x RMSE_z
    vva_p95_factor: AsprsLimit  # VVA: 95th percentile of |dz| <= this x X
    swath_rmsdz_factor: AsprsLimit
    at_plan_factor: AsprsLimit  # AT RMSE_x, RMSE_y <= this x the product's
    at_height_factor: AsprsLimit  # AT RMSE_z <= this x the product's RMSE_x (orthoimagery)


@dataclasses.dataclass(frozen=True)
class Asprs2014:
    standard: StandardInfo
    limits: Asprs2014Limits


# -- USGS Lidar Base Specification -----------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class QualityLevel:
    """One quality level's limits: non-vegetated RMSEz, vegetated 95th percentile of |dz|, swath overlap
    RMSDz and largest difference, within-swath precision (m), the aggregate nominal pulse density (first
    returns per m2, a lower limit) and spacing (m); ``confirmed`` names the limits read in a source."""

    name: str
    nva_rmse_m: float
    vva_p95_m: float
    interswath_rmsdz_m: float
    interswath_max_m: float
    within_swath_m: float
    anpd_min: float
    anps_max_m: float
    confirmed: tuple[str, ...]
    evidence: str


@dataclasses.dataclass(frozen=True)
class LidarBaseSpecification:
    standard: StandardInfo
    default_level: str  # the level tested when no class is given
    default_level_reason: str
    nva_min_points: int  # non-vegetated check points required
    nva_min_evidence: str
    nva_min_confirmed: bool
    levels: tuple[QualityLevel, ...]  # QL0 (finest) .. QL3

    def level(self, name: str) -> QualityLevel:
        """The quality level ``name`` (KeyError naming the levels)."""
        for lv in self.levels:
            if lv.name == name:
                return lv
        raise KeyError(f"no quality level {name!r} (have {', '.join(lv.name for lv in self.levels)})")


# -- Chinese specifications for digital aerial triangulation -------------------------------------------
@dataclasses.dataclass(frozen=True)
class PlanLimit:
    """A plan RMS limit by terrain class, for the map ``scales`` it applies to; where it stands and how far it was
    confirmed. Its unit is its subclass's."""

    what: str
    scales: tuple[str, ...]
    flat: float
    hilly: float
    mountainous: float
    high_mountain: float
    clause: str
    evidence: str
    confirmed: bool

    def by_terrain(self, terrain: str) -> float:
        """The number of a terrain class (``CnAt.terrains``), in the subclass's unit."""
        return {"flat": self.flat, "hilly": self.hilly, "mountainous": self.mountainous,
                "high_mountain": self.high_mountain}[terrain]


@dataclasses.dataclass(frozen=True)
class MapPlanLimit(PlanLimit):
    """A plan RMS limit in millimetres on the map."""

    def mm(self, terrain: str) -> float:
        """The limit (mm on the map) of a terrain class."""
        return self.by_terrain(terrain)

    def ground_m(self, terrain: str, scale: str) -> float:
        """The limit (m on the ground) of a terrain class at a map scale."""
        from aerotri.qa.standards.formulas import map_mm_to_ground_m

        return map_mm_to_ground_m(self.mm(terrain), scale)


@dataclasses.dataclass(frozen=True)
class SpotHeightLimit:
    """A height RMS limit (m; spot heights, AT check points) by terrain class and map scale; terrain classes without
    a limit: None."""

    what: str
    scales: tuple[str, ...]
    clause: str
    evidence: str
    confirmed: bool
    flat: dict[str, float] | None = None  # map scale -> limit (m)
    hilly: dict[str, float] | None = None
    mountainous: dict[str, float] | None = None
    high_mountain: dict[str, float] | None = None

    def height_m(self, terrain: str, scale: str) -> float | None:
        """The limit (m) of a terrain class (``CnAt.terrains``) at a map scale, None where none is given."""
        by_scale = {"flat": self.flat, "hilly": self.hilly, "mountainous": self.mountainous,
                    "high_mountain": self.high_mountain}[terrain]
        return None if by_scale is None else by_scale.get(scale)


@dataclasses.dataclass(frozen=True)
class CnAtLimits:
    check_plan_mm: MapPlanLimit  # AT check points
    control_plan_mm: MapPlanLimit  # AT basic orientation (control) points
    tie_plan_mm: MapPlanLimit  # common points between adjacent blocks
    feature_plan_mm: MapPlanLimit  # well-defined map features, 1:500-1:2000
    feature_plan_mm_small: MapPlanLimit  # the same, 1:5000 and 1:10000 (the design table's numbers as map mm)
    check_height_m_small: SpotHeightLimit  # AT check points' heights, 1:5000 and 1:10000 (the design table's)
    spot_height_m: SpotHeightLimit


@dataclasses.dataclass(frozen=True)
class CheckPointAccuracy:
    """How accurate control and check points must be: plan within a fraction of the feature plan limit,
    height within a fraction of the basic contour interval."""

    plan_fraction_of_feature: float
    height_fraction_of_contour: float
    clause: str
    evidence: str
    confirmed: bool


@dataclasses.dataclass(frozen=True)
class GrossError:
    factor_of_rms: float  # a single error beyond this many times the RMS limit is a gross error
    evidence: str
    confirmed: bool


@dataclasses.dataclass(frozen=True)
class CnAtInfo(StandardInfo):
    scales: tuple[str, ...] = ()  # map scales, largest first
    terrains: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class CnAt:
    standard: CnAtInfo
    limits: CnAtLimits
    check_point_accuracy: CheckPointAccuracy
    gross_error: GrossError


def _read(key: str) -> dict:
    return tomllib.loads((STANDARDS_DIR / STANDARD_FILES[key]).read_text(encoding="utf-8"))


@lru_cache(maxsize=None)
def asprs2023() -> Asprs2023:
    """The ASPRS 2023 table (``asprs2023.toml``)."""
    return from_table(Asprs2023, _read("asprs2023"), STANDARD_FILES["asprs2023"])


@lru_cache(maxsize=None)
def asprs2014() -> Asprs2014:
    """The ASPRS 2014 (Edition 1) table (``asprs2014.toml``)."""
    return from_table(Asprs2014, _read("asprs2014"), STANDARD_FILES["asprs2014"])


@lru_cache(maxsize=None)
def usgs_lbs() -> LidarBaseSpecification:
    """The USGS Lidar Base Specification's table (``usgs_lbs.toml``), its levels in file order."""
    doc = _read("usgs-lbs")
    head, cp = dict(doc["standard"]), doc["check_points"]
    level, reason = head.pop("default_class"), head.pop("default_class_reason")
    levels = tuple(from_table(QualityLevel, {"name": name, **{k: v for k, v in lv.items() if k != "provenance"},
                                             **lv["provenance"]}, f"{STANDARD_FILES['usgs-lbs']} [levels.{name}]")
                   for name, lv in doc["levels"].items())
    return LidarBaseSpecification(from_table(StandardInfo, head, STANDARD_FILES["usgs-lbs"]), level, reason,
                                  int(cp["nva_min"]), cp["nva_min_evidence"], cp["nva_min_confirmed"], levels)


@lru_cache(maxsize=None)
def cn_at() -> CnAt:
    """The Chinese AT specifications' table (``cn_at.toml``)."""
    return from_table(CnAt, _read("cn-at"), STANDARD_FILES["cn-at"])
