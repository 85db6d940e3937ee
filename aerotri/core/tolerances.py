"""Tolerance tables (the limits of the accuracy reports) and how a block's table is chosen.

Tables are TOML files in ``tolerance_tables/`` (docs/tolerances.md lists them with their sources):

- ``cn_1to2000.toml``, ``cn_1to5000.toml``, ``cn_1to10000.toml``: Chinese map-scale tables for manned
  aerial photography, sections ``flat``, ``hilly``, ``mountainous`` plus ``general``;
- ``asprs2023.toml``: ASPRS Positional Accuracy Standards, Edition 2 (2023), limits as multiples of a
  horizontal class H and a vertical class V (cm), classes by GSD in ``[[gsd_classes]]``;
- ``flight_cn_aerial.toml``: the flight acceptance limits of manned aerial photography;
- ``selection.toml``: the rules that choose a table from a block's GSD and platform.

Every number carries a ``[provenance.KEY]`` (or ``[limits.KEY]``) ``source`` and ``confirmed``; an
unconfirmed limit is shown as such in the reports. A user's own file (``[qa] tolerances = "FILE"`` or
``--tolerances FILE``) in the map-scale layout replaces the built-in tables.

A table is named by a key (``map_scale`` in the settings, kept as a string so the stages pass it through):
``"1:5000"``, ``"ASPRS2023 H7.1cm V10cm"``, with `` UAS`` appended for a low-altitude block (no manned
flight specification applies to it). ``choose_table`` makes the key from project.toml ``[qa]`` or, when
``[qa]`` names no table, from the block's GSD and platform (a ``BlockScale``).
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from pathlib import Path

from aerotri.core.errors import ConfigError, InputError
from aerotri.core.project import Project, QaSettings
from aerotri.core.textio import read_text

TOLERANCE_DIR = Path(__file__).with_name("tolerance_tables")
SCALE_TABLES = {"1:2000": "cn_1to2000.toml", "1:5000": "cn_1to5000.toml", "1:10000": "cn_1to10000.toml"}
ASPRS_FILE = "asprs2023.toml"
FLIGHT_FILE = "flight_cn_aerial.toml"
SELECTION_FILE = "selection.toml"
TERRAINS = ("flat", "hilly", "mountainous")
STANDARDS = ("asprs2023", "cn")
PLATFORMS = ("uas", "manned")
DEFAULT_SCALE = "1:5000"  # when nothing tells the block's GSD (no camera or no terrain height)
UAS_SUFFIX = " UAS"
NO_FLIGHT_SPEC = ("none applies: a low-altitude (UAS) block is not held to the manned aerial photography "
                  "flight limits, and no UAS flight specification is shipped; values reported, not judged")
_ASPRS_KEY = re.compile(r"^ASPRS2023 H(?P<h>[0-9.]+)cm V(?P<v>[0-9.]+)cm$")


@dataclasses.dataclass(frozen=True)
class Provenance:
    """Where a limit comes from; ``confirmed`` False: not checked against the document's own text; ``nva`` True:
    a height limit on non-vegetated (open) ground only (an NVA limit: ASPRS 2023, the USGS LBS), so the height
    check judges it on the non-vegetated points; False: on every surveyed point (the map-scale tables)."""

    source: str
    confirmed: bool
    nva: bool = False
    # a limit that is a multiple of an accuracy class: the class ("horizontal" H or "vertical" V) and the factor
    of_class: str = ""
    factor: float | None = None


@dataclasses.dataclass(frozen=True)
class BlockScale:
    """What decides a block's table: the median GSD (m) and height above ground (m) of its frames, the
    platform ("uas" for a low-altitude block, "manned", None unknown) and how each was found."""

    gsd_m: float | None
    height_above_ground_m: float | None
    platform: str | None
    how: str  # e.g. "camera.toml (3.61 mm, 1.55 um); 18 frames of gnss.txt 41.0 m above lidar_out/dem.tif"


@dataclasses.dataclass(frozen=True)
class ToleranceTable:
    """A resolved table: ``limits`` is what the checks read (key -> number; plus ``flight_spec`` and, for a
    UAS block, ``flight_limits_apply`` False), ``provenance`` the source of each limit, ``reason`` why this
    table judges the block, ``limits_from``: the standard and class whose limits replaced some of the table's ("" for
    none; said beside the verdict, which named the table's scale alone: trial s96 F8)."""

    key: str
    name: str
    path: Path
    terrain: str
    limits: dict
    provenance: dict  # limit key -> Provenance
    reason: str
    platform: str | None
    limits_from: str = ""

    @property
    def terrain_classes(self) -> bool:
        """Whether the table's limits differ by terrain class: the map-scale tables' do, an ASPRS table has one set for
        every terrain (asprs2023.toml: terrain_classes = false)."""
        return not self.key.upper().startswith("ASPRS")

    @property
    def unconfirmed(self) -> list[str]:
        return [k for k, p in self.provenance.items() if not p.confirmed and k in self.limits]


def sigma0_limit_px(limits: dict, pixel_um: float | None) -> float | None:
    """The self-check limit of sigma naught in the camera's pixels: ``sigma0_max_px`` (digital cameras: a fraction
    of a pixel, whatever its size), or a contract's ``sigma0_max_um`` on the image over the pixel size (um)."""
    if limits.get("sigma0_max_px") is not None:
        return float(limits["sigma0_max_px"])
    if limits.get("sigma0_max_um") is not None and pixel_um:
        return round(float(limits["sigma0_max_um"]) / float(pixel_um), 3)
    return None


def _toml(path: Path, what: str = "tolerance table (TOML)") -> dict:
    try:
        return tomllib.loads(read_text(path, what))
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: not a valid TOML tolerance table ({e})") from None


def _provenance(d: dict, path: Path | None = None) -> dict:
    """Limit key -> ``Provenance`` of the table's ``[provenance.<key>]`` sections; ``confirmed`` and ``nva`` are TOML
    booleans (a text "false" is true to Python and would judge a DEM limit on the open ground only: refused)."""
    out = {}
    for k, v in (d.get("provenance") or {}).items():
        if not isinstance(v, dict):
            continue
        for flag in ("confirmed", "nva"):
            if flag in v and not isinstance(v[flag], bool):
                raise ConfigError(f"{path or 'tolerance table'}: [provenance.{k}] {flag} = {v[flag]!r}: expected true "
                                  f"or false (a TOML boolean, without quotes)")
        out[k] = Provenance(str(v.get("source", "")), v.get("confirmed", False), v.get("nva", False))
    return out


def split_key(key: str) -> tuple[str, bool]:
    """(table key, low-altitude block) of a settings key such as ``"1:5000"`` or ``"ASPRS2023 H7.1cm V10cm UAS"``."""
    key = str(key).strip()
    if key.endswith(UAS_SUFFIX):
        return key[: -len(UAS_SUFFIX)].strip(), True
    return key, False


def asprs_key(h_cm: float, v_cm: float, uas: bool = False) -> str:
    return f"ASPRS2023 H{h_cm:g}cm V{v_cm:g}cm" + (UAS_SUFFIX if uas else "")


OWN_TABLE = "--tolerances FILE"  # how the commands that read a tolerance table take a user's own


def _known(source: str, key: str, own_table: str | None = OWN_TABLE) -> str:
    """``own_table``: how the command printing this takes a user's own table (None: it takes none, so the advice
    names the built-in keys only: lidarctl check-vectors and check-plan have no --tolerances)."""
    advice = f"give your own with {own_table}" if own_table else "give one of these"
    return (f"{source} {key!r}: no built-in tolerance table (have {', '.join(SCALE_TABLES)} and "
            f"'ASPRS2023 H<cm>cm V<cm>cm'); {advice}")


def tolerance_path(scale: str | None = None, tolerance_file=None, source: str = "map scale",
                   own_table: str | None = OWN_TABLE) -> Path:
    """The file of the table ``scale`` (a table key) or ``tolerance_file``; ``source`` names where the key came from,
    ``own_table`` how the command takes a user's own table (None: it does not; see ``_known``)."""
    if tolerance_file:
        p = Path(tolerance_file)
        if not p.is_file():
            raise InputError(f"{p}: tolerance table not found")
        return p
    table, _ = split_key(scale or DEFAULT_SCALE)
    if table in SCALE_TABLES:
        return TOLERANCE_DIR / SCALE_TABLES[table]
    if _ASPRS_KEY.match(table):
        return TOLERANCE_DIR / ASPRS_FILE
    raise ConfigError(_known(source, table, own_table))


def _flight_limits(uas: bool, own: dict) -> tuple[dict, dict]:
    """The flight acceptance limits of the platform: none for a low-altitude block, else the manned aerial
    specification (``flight_cn_aerial.toml``) under the table's own flight keys."""
    if uas:
        return {"flight_limits_apply": False, "flight_spec": NO_FLIGHT_SPEC}, {}
    d = _toml(TOLERANCE_DIR / FLIGHT_FILE)
    limits = {**d["general"], **{k: v for k, v in own.items() if k.startswith("flight_")}}
    own_keys = [k for k in own if k.startswith("flight_")]
    spec = d["table"]["name"] + (f" (with the table's own {', '.join(own_keys)})" if own_keys else "")
    prov = {k: p for k, p in _provenance(d).items() if k not in own_keys}
    return {**limits, "flight_spec": spec}, prov


@dataclasses.dataclass(frozen=True)
class FlightLimits:
    """The limits a flight is accepted by (``aerotri.adjust.flight_acceptance``), named by their tolerance-table keys
    (a table's own ``flight_*`` keys replace the specification's); None: not judged (a UAS block: none)."""

    flight_tilt_max_deg: float | None = None  # tilt of the camera axis from the vertical
    flight_kappa_max_deg: float | None = None  # kappa deviation from the base direction
    flight_curvature_max_pct: float | None = None  # strip curvature, % of the strip's length
    flight_height_step_max_m: float | None = None  # flying-height change between adjacent frames
    flight_height_range_max_m: float | None = None  # highest minus lowest flying height of a strip
    flight_forward_overlap_min_pct: float | None = None
    flight_side_overlap_min_pct: float | None = None


def manned_flight_limits() -> FlightLimits:
    """The flight acceptance limits of manned aerial photography (``flight_cn_aerial.toml`` [general], shipped
    with the package: a key of another name is a bug, not bad input)."""
    return FlightLimits(**_toml(TOLERANCE_DIR / FLIGHT_FILE)["general"])


def asprs_table(h_cm: float, v_cm: float) -> tuple[dict, dict, dict]:
    """(limits, provenance, table metadata) of the ASPRS 2023 classes H (horizontal, cm) and V (vertical, cm)."""
    d = _toml(TOLERANCE_DIR / ASPRS_FILE)
    limits, prov = {}, {}
    for k, e in d["limits"].items():
        if "value" in e:
            limits[k] = e["value"]
        else:
            cls = {"horizontal": h_cm, "vertical": v_cm}[e["of"]]
            limits[k] = round(e["factor"] * cls / 100.0, 4)
        prov[k] = Provenance(e["source"], bool(e["confirmed"]), bool(e.get("nva", False)), of_class=e.get("of", ""),
                             factor=e.get("factor"))
    return limits, prov, d["table"]


def _cm_text(v_cm: float) -> str:
    """Two significant figures, but whole centimetres from 100 cm on (581, not 5.8e+02)."""
    return f"{v_cm:.0f}" if abs(v_cm) >= 100 else f"{v_cm:.2g}"


def asprs_classes_for_gsd(gsd_m: float) -> tuple[float, float, str]:
    """(H cm, V cm, row text) of the ASPRS 2023 classes for a GSD (``[[gsd_classes]]``: the first row not exceeded)."""
    rows = _toml(TOLERANCE_DIR / ASPRS_FILE)["gsd_classes"]
    gsd_cm = 100.0 * gsd_m
    row = next((r for r in rows if gsd_cm <= r["gsd_max_cm"]), rows[-1])
    beyond = gsd_cm > row["gsd_max_cm"]
    text = (f"GSD {_cm_text(gsd_cm)} cm {'>' if beyond else '<='} {row['gsd_max_cm']:g} cm: H {row['horizontal_class_cm']:g} cm, "
            f"V {row['vertical_class_cm']:g} cm (asprs2023.toml [[gsd_classes]], unconfirmed)")
    return float(row["horizontal_class_cm"]), float(row["vertical_class_cm"]), text


def scale_for_gsd(gsd_m: float) -> tuple[str, str]:
    """(map scale, row text) of the Chinese table for a manned block's GSD (``selection.toml`` [[cn_scale]])."""
    rows = _toml(TOLERANCE_DIR / SELECTION_FILE)["cn_scale"]
    row = next((r for r in rows if gsd_m <= r["gsd_max_m"]), rows[-1])
    beyond = gsd_m > row["gsd_max_m"]
    return row["scale"], (f"GSD {100 * gsd_m:.3g} cm {'>' if beyond else '<='} {100 * row['gsd_max_m']:g} cm: "
                          f"{row['scale']} (selection.toml [[cn_scale]], unconfirmed)"
                          + ("; coarser than every shipped table" if beyond else ""))


def low_altitude_height_m() -> float:
    """Median height above ground below which a block is a low-altitude (UAS) block (``selection.toml``)."""
    return float(_toml(TOLERANCE_DIR / SELECTION_FILE)["platform"]["low_altitude_height_max_m"])


def asprs_gsd_max_m() -> float:
    return float(_toml(TOLERANCE_DIR / SELECTION_FILE)["asprs"]["gsd_max_m"])


# GB/T 7931-2008 6.1 sets the well-defined map features' plan limit for 1:500-1:2000 in millimetres on the map (0.6 mm
# flat / hilly, 0.8 mm mountainous): 1:500 and 1:1000 are the 1:2000 table's metres scaled by the denominator.
FEATURE_MAP_MM_SCALES = {"1:500": 500, "1:1000": 1000}
_FEATURE_KEY = "feature_rms_xy_m"


@dataclasses.dataclass(frozen=True)
class FeatureLimit:
    """The plan RMS limit (m on the ground) of well-defined map features at a map scale and terrain class: the line
    map's and DOM's tolerance; whether it was checked against the specification's text, and its source."""

    scale: str
    terrain: str
    limit_m: float | None
    confirmed: bool
    source: str
    note: str = ""  # what a reader of a verdict by this limit should know (an unconfirmed limit's caveat)


def feature_limit(scale: str, terrain: str = "flat", *, source: str = "--scale") -> FeatureLimit:
    """``FeatureLimit`` of a map scale (1:500-1:10000) or ASPRS key; errors name ``source``. At 1:5000 and 1:10000
    the design table's metres (0.50 / 0.75 m, unconfirmed) are tighter than 1:2000's GB/T 7931 limit (1.2 / 1.6 m):
    the note says so, since a map can then pass at 1:2000 and fail at 1:10000."""
    key = str(scale).strip()
    if key in FEATURE_MAP_MM_SCALES:
        base = load_table("1:2000", terrain, source=source, own_table=None)
        d = FEATURE_MAP_MM_SCALES[key]
        lim = base.limits[_FEATURE_KEY] * d / 2000.0
        prov = base.provenance.get(_FEATURE_KEY, Provenance("", False))
        return FeatureLimit(key, terrain, lim, prov.confirmed,
                            f"GB/T 7931-2008 6.1: {lim * 1000.0 / d:g} mm on the map at 1:{d} (1:2000's {terrain} "
                            f"{base.limits[_FEATURE_KEY]:g} m scaled)")
    if key not in SCALE_TABLES and not _ASPRS_KEY.match(key):
        raise ConfigError(f"{source} {key!r}: no built-in limit for map features (have "
                          f"{', '.join([*FEATURE_MAP_MM_SCALES, *SCALE_TABLES])} and 'ASPRS2023 H<cm>cm V<cm>cm')")
    table = load_table(key, terrain, source=source, own_table=None)
    lim = table.limits.get(_FEATURE_KEY)
    prov = table.provenance.get(_FEATURE_KEY, Provenance("not stated", False))
    note = ""
    if lim is not None and key in SCALE_TABLES and key != "1:2000":
        base = load_table("1:2000", terrain, source=source, own_table=None).limits[_FEATURE_KEY]
        if lim < base:
            note = (f"the {key} limit {lim:g} m is the design table's figure in metres (unconfirmed), tighter than "
                    f"1:2000's {base:g} m (GB/T 7931: {base / 2:g} mm on the map); read as {lim:g} mm on the map it would be "
                    f"{lim * float(key.split(':')[1]) / 1000.0:g} m: check your contract's limit")
    return FeatureLimit(key, terrain, lim, prov.confirmed, prov.source, note)


def load_table(scale: str | None = None, terrain: str = "flat", tolerance_file=None, reason: str = "", *,
               source: str = "map scale", own_table: str | None = OWN_TABLE) -> ToleranceTable:
    """The resolved table of a key (``scale``) or a user's file: limits for one terrain class (a map-scale
    table's ``general`` section overlaid by the class's own; ASPRS classes have none), the flight limits of
    the platform, and where each limit comes from. ``source`` / ``own_table``: what an unknown key's error
    names as its origin and how to give one's own table (``tolerance_path``)."""
    key = scale or DEFAULT_SCALE
    table, uas = split_key(key)
    path = tolerance_path(key, tolerance_file, source, own_table)
    m = None if tolerance_file else _ASPRS_KEY.match(table)
    if m:
        h_cm, v_cm = float(m["h"]), float(m["v"])
        limits, prov, meta = asprs_table(h_cm, v_cm)
        name = f"{meta['name']}: {h_cm:g}-cm horizontal / {v_cm:g}-cm vertical accuracy class"
        own = {}
    else:
        d = _toml(path)
        if terrain not in d:
            have = [k for k, v in d.items() if isinstance(v, dict) and k in TERRAINS]
            raise InputError(f"{path}: no [{terrain}] section (terrain classes here: {', '.join(have) or 'none'})")
        own = {**d.get("general", {}), **d[terrain]}
        for k, v in own.items():  # a limit of inf, nan or text passes or fails everything: refused by name
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{path}: [{terrain}]/[general] {k} = {v!r}: expected a finite limit >= 0")
        limits, prov = dict(own), _provenance(d, path)
        name = (d.get("table") or {}).get("name") or f"{path.name} (user table)"
        name = f"{name}, {terrain}"
    flight, fprov = _flight_limits(uas, own)
    limits = {**{k: v for k, v in limits.items() if not k.startswith("flight_")}, **flight}
    return ToleranceTable(key=key, name=name, path=path, terrain=terrain, limits=limits, provenance={**prov, **fprov},
                          reason=reason, platform="uas" if uas else None)


QA_SECTION = "project.toml [qa]"  # where a choice came from, as reports name it (the same for a copy elsewhere)


def read_qa_config(root) -> QaSettings:
    """``[qa]`` of the project at ``root`` (types and ranges checked when the project is opened; here the
    table names and the combinations: ConfigError naming the key), ``tolerances`` as an absolute path."""
    project = Project.open(root)
    qa = project.qa
    src = f"{project.config_path} [qa]"
    if qa.map_scale is not None and qa.map_scale not in SCALE_TABLES:
        raise ConfigError(f"{src} map_scale = {qa.map_scale!r}: no built-in tolerance table (have "
                          f"{', '.join(SCALE_TABLES)}); give your own with tolerances = \"FILE\"")
    if qa.terrain is not None and qa.terrain not in TERRAINS and not qa.tolerances:
        raise ConfigError(f"{src} terrain = {qa.terrain!r}: expected one of {', '.join(TERRAINS)}")
    if qa.standard == "asprs2023" and qa.map_scale is not None:
        raise ConfigError(f"{src}: standard = \"asprs2023\" and map_scale = {qa.map_scale!r} contradict each other "
                          f"(a map scale names a Chinese table); give one of them")
    tol = qa.tolerances
    return dataclasses.replace(qa, tolerances=(Path(project.root) / tol).resolve() if tol else None)


def _block_text(block: BlockScale | None) -> str:
    if block is None or block.gsd_m is None:
        return f"GSD unknown ({block.how if block is not None else 'not estimated'})"
    return (f"GSD {_cm_text(100 * block.gsd_m)} cm at {block.height_above_ground_m:.0f} m above ground "
            f"({block.how})")


def choose_table(cfg: QaSettings, block: BlockScale | None = None, *, scale: str | None = None,
                 standard: str | None = None, terrain: str | None = None, tolerance_file=None,
                 horizontal_class_cm: float | None = None, vertical_class_cm: float | None = None,
                 lidar_only: bool = False, accuracy_class: str | None = None) -> ToleranceTable:
    """The table that judges a block, and why. The keyword arguments (the command line) override ``cfg``
    (project.toml [qa]); what neither names is chosen from ``block``: a low-altitude (UAS) block, or any block
    with a GSD under ``selection.toml`` [asprs] gsd_max_m, gets the ASPRS 2023 classes of its GSD; a coarser
    manned block the Chinese map-scale table of its GSD; a block of unknown GSD the 1:5000 table.
    ``lidar_only``: a project without frames (no platform to assume; the reason says so). Under a map-scale
    standard (cn-at, thesis) the class tested (``accuracy_class``, --class, else ``cfg.accuracy_class``) is a map
    scale: its table judges the block, as the compliance section judges it at that scale, before ``cfg.map_scale``."""
    platform = cfg.platform or (block.platform if block is not None else None)
    if cfg.platform:
        plat_why = f"platform {cfg.platform} from {QA_SECTION}"
    elif platform:
        plat_why = (f"platform {platform}: {block.height_above_ground_m:.0f} m above ground (a UAS block flies below "
                    f"{low_altitude_height_m():g} m)")
    elif lidar_only:
        plat_why = "a LiDAR-only project (no camera.toml, frames, GNSS or EO): only its LiDAR limits apply"
    else:
        plat_why = "platform unknown (manned assumed)"
    uas = platform == "uas"
    terrain = terrain or cfg.terrain or "flat"
    h_cm = horizontal_class_cm or cfg.horizontal_class_cm
    v_cm = vertical_class_cm or cfg.vertical_class_cm
    std = standard or (None if scale else cfg.standard)
    # the report's compliance standards (aerotri/qa/compliance.py) map onto the table families: the Chinese ones
    # onto the map-scale tables, the LiDAR specification onto none (chosen by the block)
    named = std
    std = {"cn-at": "cn", "thesis": "cn", "usgs-lbs": None, "asprs2014": None}.get(std, std)
    # a map-scale standard's class is a scale: the verdict table is that scale's, as the compliance section's
    # (aerotri.qa.compliance.choose: --class, [qa] accuracy_class, then [qa] map_scale); --standard cn-at --class
    # 1:2000 judged the compliance at 1:2000 and the verdict table at the GSD's 1:5000
    cls_text = accuracy_class or cfg.accuracy_class
    cls_scale = cls_text.strip().replace(" ", "") if std == "cn" and cls_text and not scale else None
    cls_src = "--class" if accuracy_class else f"{QA_SECTION} accuracy_class"
    no_table = ""
    if cls_scale is not None and cls_scale not in SCALE_TABLES:
        no_table = f"; class {cls_scale} from {cls_src} has no map-scale table ({', '.join(SCALE_TABLES)})"
        cls_scale = None
    given_scale = scale or cls_scale or (None if standard and std != "cn" else cfg.map_scale)
    file = tolerance_file or (None if (scale or standard) else cfg.tolerances)

    def cn(key, why):
        return load_table(key + (UAS_SUFFIX if uas else ""), terrain, None, f"{why}; {plat_why}")

    if file:
        src = "--tolerances" if tolerance_file else f"{QA_SECTION} tolerances"
        # the key stays a built-in scale: stages that only pass the key on judge by the built-in table
        return load_table(DEFAULT_SCALE + (UAS_SUFFIX if uas else ""), terrain, file, f"your table ({src}); {plat_why}")
    if given_scale:
        src = "--scale" if scale else cls_src if cls_scale else f"{QA_SECTION} map_scale"
        return cn(given_scale, f"map scale {given_scale} from {src}{no_table}")
    gsd = block.gsd_m if block is not None else None
    if std == "cn":
        # named as given (thesis, cn-at, or the old "cn": the thesis tables), with the tables it maps onto
        cn_why = (f"standard {named} from {'--standard' if standard else QA_SECTION}"
                  + ("" if named == "cn" else ": the map-scale tables") + no_table)
        if gsd is None:
            return cn(DEFAULT_SCALE, f"{cn_why}; "
                                     f"{_block_text(block)}: default {DEFAULT_SCALE}")
        s, row = scale_for_gsd(gsd)
        return cn(s, f"{cn_why}; {_block_text(block)}; {row}")
    if std == "asprs2023" or (std is None and gsd is not None and (uas or gsd < asprs_gsd_max_m())):
        why = (f"standard asprs2023 from {'--standard' if standard else QA_SECTION}" if std else
               f"{'a UAS block' if uas else f'GSD under {100 * asprs_gsd_max_m():g} cm'} (selection.toml)")
        if h_cm is None or v_cm is None:
            if gsd is None:
                raise ConfigError(f"{QA_SECTION}: standard asprs2023 needs the accuracy classes: give "
                                  f"horizontal_class_cm and vertical_class_cm, or a camera.toml and a terrain height "
                                  f"(lidar_out/dem.tif or [flight] mean_terrain_height_m) to choose them by GSD "
                                  f"({_block_text(block)})")
            gh, gv, row = asprs_classes_for_gsd(gsd)
            why += f"; {_block_text(block)}; {row}"
            h_cm, v_cm = h_cm or gh, v_cm or gv
        else:
            why += f"; classes from {QA_SECTION if not horizontal_class_cm else 'the command line'}"
        return load_table(asprs_key(h_cm, v_cm, uas), terrain, None, f"{why}; {plat_why}")
    if gsd is None and lidar_only:
        why = (f"the LBS has no table of its own: the default {DEFAULT_SCALE} table" if named == "usgs-lbs" else
               f"ASPRS Edition 1 has no table of its own: the default {DEFAULT_SCALE} table" if named == "asprs2014"
               else
               f"no standard named: the default {DEFAULT_SCALE} table (--standard usgs-lbs or asprs2023 --class, or "
               f"[qa] standard, judges by a LiDAR standard)")
        return cn(DEFAULT_SCALE, why)
    if gsd is None:
        return cn(DEFAULT_SCALE, f"{_block_text(block)}: the default {DEFAULT_SCALE} table (set [qa] map_scale or "
                                 f"standard to choose)")
    s, row = scale_for_gsd(gsd)
    return cn(s, f"manned block, {_block_text(block)}; {row}")


@dataclasses.dataclass(frozen=True)
class QaChoice:
    """The report settings of a project resolved (``[qa]``, else the block's GSD and platform): the chosen table's
    key and terrain class, a user's tolerance file (absolute path) or None, whether to write the PDF, and the
    ``ToleranceTable`` with why it was chosen."""

    map_scale: str
    terrain: str
    tolerances: str | None
    pdf: bool
    table: ToleranceTable


def qa_settings(root, block: BlockScale | None = None) -> QaChoice:
    """The report settings of a project; ``block``: the block's GSD and platform (``aerotri.geom.block_scale``)
    for the choice of table."""
    cfg = read_qa_config(root)
    t = choose_table(cfg, block)
    return QaChoice(map_scale=t.key, terrain=t.terrain, tolerances=str(cfg.tolerances) if cfg.tolerances else None,
                    pdf=cfg.pdf, table=t)
