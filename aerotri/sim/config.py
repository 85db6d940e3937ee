"""Simulator presets (TOML files in ``datasets/presets``; a wheel installs them into
``<prefix>/share/aerotri/presets``) and their validation.

A preset is a TOML file of tables ``[preset] [crs] [camera] [flight] [gnss] [lidar] [scene] [render] [truth]``,
optionally ``[observations]``, and ``[chain.<stage>]``: the stage options the simulated project's project.toml
gets. ``load_preset`` gives it as a ``Preset``, one frozen dataclass per table (read with
``aerotri.core.settings.from_table``: an unknown key or a wrong type names the file, the table and the key);
``--set section.key=value`` overrides single values (TOML syntax for the value) before it is typed. Every invalid
value is refused with an ``InputError`` that names the key and what was expected.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import tomllib
import typing
from pathlib import Path

from aerotri.core.errors import InputError
from aerotri.core.settings import from_table

def _preset_dir() -> Path:
    """``$AEROTRI_PRESETS``, else the source checkout's datasets/presets, else the installed copy."""
    if "AEROTRI_PRESETS" in os.environ:
        return Path(os.environ["AEROTRI_PRESETS"])
    checkout = Path(__file__).resolve().parents[2] / "datasets" / "presets"
    if checkout.is_dir():
        return checkout
    import sysconfig

    # an installed wheel: <prefix>/lib/pythonX.Y/site-packages/aerotri -> <prefix>/share/aerotri/presets
    for prefix in (Path(__file__).resolve().parents[5], Path(sysconfig.get_path("data"))):
        installed = prefix / "share" / "aerotri" / "presets"
        if installed.is_dir():
            return installed
    return checkout


PRESET_DIR = _preset_dir()


def available_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def load_preset(name_or_path: str, overrides: list[str] | tuple[str, ...] = ()) -> "Preset":
    """The preset by name (``tiny``, ``demo``, ``dmc``) or TOML path, with ``--set`` overrides, checked."""
    path = Path(name_or_path)
    if not (path.suffix == ".toml" and path.exists()):
        path = PRESET_DIR / f"{name_or_path}.toml"
        if not path.exists():
            raise InputError(f"unknown preset {name_or_path!r}; available: {', '.join(available_presets())} "
                             f"(or a path to a preset .toml file)")
    try:
        cfg = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    cfg = _apply_overrides(cfg, overrides)
    _validate(cfg, str(path))
    return _typed(cfg, str(path))


# ----------------------------------------------------------------------------------------------
# The preset's tables, one frozen dataclass each (lengths in metres, angles in degrees). A key the
# preset may leave out has a default (8-bit RGB frames written whole by OpenCV, deflate truth rasters,
# texture down to the GSD, the scene's counts as given, no injected LiDAR error).
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetHeader:
    """``[preset]``: its name, a line saying what it is, the seed of every random stream."""

    name: str
    description: str = ""
    seed: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetCrs:
    """``[crs]``: the project CRS (EPSG code) and the scene's lower-left corner in it (ellipsoidal height)."""

    epsg: int
    origin_e_m: float
    origin_n_m: float
    base_height_m: float


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetCamera:
    """``[camera]``: the true camera the frames are rendered through (camera.toml gets only its focal length and
    format); principal point offset in mm (x right, y up), Brown coefficients."""

    focal_mm: float
    sensor_width_mm: float
    sensor_height_mm: float
    width: int
    height: int
    ppx_mm: float
    ppy_mm: float
    k1: float
    k2: float
    k3: float
    p1: float
    p2: float


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetFlight:
    """``[flight]``: the photo flight (overlaps as fractions, tilt and kappa deviations drawn within the limits)."""

    height_above_ground_m: float
    forward_overlap: float
    side_overlap: float
    strips: int
    frames_per_strip: int
    speed_mps: float
    max_tilt_deg: float
    max_kappa_dev_deg: float


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetGnss:
    """``[gnss]``: the antenna positions' errors (white noise, per-strip shift and drift), the lever arm in the
    camera frame (x right, y up, z up) and the sigmas written into gnss.txt and project.toml."""

    sigma_m: float
    strip_shift_sigma_m: float = 0.0
    drift_sigma_m_per_s: float = 0.0
    lever_arm_m: tuple[float, float, float]
    sigma_xy_m: float
    sigma_z_m: float


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetLidar:
    """``[lidar]``: the LiDAR flight and scanner (zig-zag, full field of view ``fov_deg``), its noise and outliers,
    the injected system errors (boresight roll, pitch, heading; range offset; scan angle scale) and the format."""

    height_above_ground_m: float
    pulse_rate_hz: float
    scan_frequency_hz: float
    fov_deg: float
    speed_mps: float
    side_overlap: float
    range_noise_m: float
    strip_offset_sigma_m: float
    boresight_error_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    range_offset_m: float = 0.0
    scan_angle_scale_error: float = 0.0
    attitude_noise_deg: float
    low_outlier_rate: float
    high_outlier_rate: float
    water_return_fraction: float
    canopy_first_return_prob: float
    canopy_interior_return_prob: float
    canopy_ground_return_prob: float
    format: str


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetScene:
    """``[scene]``: the town, the valley side and the targets (ranges as [min, max]); the counts are those of a
    scene of ``counts_for_m`` = [width, height] metres (None: of any size), see ``scene.scene_counts``."""

    counts_for_m: tuple[float, float] | None = None
    margin_m: float
    terrain_res_m: float
    hill_amplitude_m: float
    hill_scale_m: float
    steep_start_frac: float
    steep_band_m: float
    steep_slope_deg: float
    mountain_relief_m: float
    urban_margin_m: float
    road_angle_deg: float
    road_spacing_m: float
    road_width_m: tuple[float, float]
    ponds: int
    pond_size_m: tuple[float, float]
    buildings: int
    shape_weights: tuple[float, float, float]
    building_length_m: tuple[float, float]
    building_width_m: tuple[float, float]
    building_height_m: tuple[float, float]
    building_angle_jitter_deg: float
    building_gap_m: float
    pitched_fraction: float
    eave_m: tuple[float, float]
    single_trees: int
    tree_clusters: int
    slope_trees: int
    bushes: int
    crown_radius_m: tuple[float, float]
    tree_height_m: tuple[float, float]
    check_targets: int
    target_radius_m: float


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetRender:
    """``[render]``: rays per pixel per axis, sensor noise and exposure, the frames' bits, bands, tiling (0: one
    strip image written by OpenCV) and compression, the finest texture (0: the GSD)."""

    samples: int
    noise_dn: float
    exposure_sigma: float
    vignetting: float
    bits: int = 8
    bands: str = "rgb"
    tile_px: int = 0
    compress: str = "none"
    texture_fine_m: float = 0.0


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetTruth:
    """``[truth]``: the cell sizes of the truth rasters and orthophoto, their compression."""

    raster_res_m: float
    ortho_res_m: float
    compress: str = "deflate"


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetObservations:
    """``[observations]`` (``aerotri sim --observations-only``): image noise of the tie and control measurements,
    tie points per frame on average."""

    tie_sigma_px: float = 0.3
    tie_points_per_frame: int = 130


@dataclasses.dataclass(frozen=True, kw_only=True)
class Preset:
    """A simulator preset, one field per TOML table; ``chain`` holds the ``[chain.<stage>]`` tables as TOML gives
    them (the stage options project.toml gets, checked by ``aerotri run`` when it reads them)."""

    preset: PresetHeader
    crs: PresetCrs
    camera: PresetCamera
    flight: PresetFlight
    gnss: PresetGnss
    lidar: PresetLidar
    scene: PresetScene
    render: PresetRender
    truth: PresetTruth
    observations: PresetObservations = PresetObservations()
    chain: typing.Mapping = dataclasses.field(default_factory=dict)


def _table_classes() -> dict:
    hints = typing.get_type_hints(Preset)
    return {f.name: hints[f.name] for f in dataclasses.fields(Preset) if f.name != "chain"}


def _typed(cfg: dict, source: str) -> Preset:
    """The checked TOML document as a ``Preset`` (an unknown table or key, a wrong type: ``ConfigError``)."""
    classes = _table_classes()
    unknown = [k for k in cfg if k not in classes and k != "chain"]
    if unknown:
        raise InputError(f"{source}: unknown table [{unknown[0]}] (known: {', '.join([*classes, 'chain'])})")
    tables = {name: from_table(cls, cfg.get(name, {}), f"{source} [{name}]") for name, cls in classes.items()}
    return Preset(**tables, chain=copy.deepcopy(cfg.get("chain", {})))


def _field_default(section: str, name: str):
    """The default of ``section.name`` (None: required, or no such field)."""
    cls = _table_classes().get(section)
    f = next((f for f in dataclasses.fields(cls) if f.name == name), None) if cls is not None else None
    return None if f is None or f.default is dataclasses.MISSING else f.default


def _is_field(section: str, name: str) -> bool:
    cls = _table_classes().get(section)
    return cls is not None and any(f.name == name for f in dataclasses.fields(cls))


def _apply_overrides(cfg: dict, overrides) -> dict:
    """``--set section.key=value`` items (TOML syntax for the value) on the preset's TOML document: the key must
    be a field of that table; a number where the preset (or the field's default) has a number."""
    cfg = copy.deepcopy(cfg)
    for item in overrides:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise InputError(f"--set {item!r}: expected section.key=value, e.g. flight.side_overlap=0.3")
        key, value = item.split("=", 1)
        section, name = key.strip().split(".", 1)
        if not _is_field(section, name):
            raise InputError(f"--set {item!r}: unknown parameter {key!r}")
        cfg.setdefault(section, {})
        try:
            parsed = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            parsed = value.strip()
        old = cfg[section].get(name, _field_default(section, name))
        if isinstance(old, (int, float)) and not isinstance(old, bool) and not isinstance(parsed, (int, float)):
            raise InputError(f"--set {item!r}: {key} must be a number")
        cfg[section][name] = float(parsed) if isinstance(old, float) and isinstance(parsed, int) else parsed
    return cfg


def _need(cfg, source, section, key, *, lo=None, hi=None, lo_open=False, integer=False):
    try:
        v = cfg[section][key]
    except KeyError:
        raise InputError(f"{source}: missing parameter {section}.{key}") from None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{source}: {section}.{key} must be a finite number, got {v!r}")
    if integer and int(v) != v:
        raise InputError(f"{source}: {section}.{key} must be a whole number, got {v!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise InputError(f"{source}: {section}.{key} = {v} is out of range (must be {'>' if lo_open else '>='} {lo})")
    if hi is not None and v > hi:
        raise InputError(f"{source}: {section}.{key} = {v} is out of range (must be <= {hi})")
    return v


def _validate(cfg: dict, source: str = "preset") -> None:
    """The ranges and the checks across tables, on the TOML document (the typing follows in ``_typed``)."""
    for section in ("preset", "crs", "camera", "flight", "gnss", "lidar", "scene", "render", "truth"):
        if section not in cfg:
            raise InputError(f"{source}: missing section [{section}]")
    # [chain.<stage>] (the stage options the project gets) is checked by aerotri run when it reads
    # project.toml; tests/aerotri/sim/test_config.py checks the shipped presets' sections.
    _need(cfg, source, "crs", "epsg", lo=1, integer=True)
    _need(cfg, source, "camera", "focal_mm", lo=1.0, hi=1000.0, lo_open=True)
    _need(cfg, source, "camera", "sensor_width_mm", lo=1.0, hi=1000.0)
    _need(cfg, source, "camera", "sensor_height_mm", lo=1.0, hi=1000.0)
    _need(cfg, source, "camera", "width", lo=16, hi=30000, integer=True)
    _need(cfg, source, "camera", "height", lo=16, hi=30000, integer=True)
    for side in ("forward_overlap", "side_overlap"):
        _need(cfg, source, "flight", side, lo=0.0, hi=0.95)
    _need(cfg, source, "lidar", "side_overlap", lo=0.0, hi=0.9)
    _need(cfg, source, "flight", "strips", lo=1, hi=200, integer=True)
    _need(cfg, source, "flight", "frames_per_strip", lo=2, hi=2000, integer=True)
    _need(cfg, source, "flight", "speed_mps", lo=1.0, hi=500.0)
    _need(cfg, source, "flight", "max_tilt_deg", lo=0.0, hi=10.0)
    _need(cfg, source, "flight", "max_kappa_dev_deg", lo=0.0, hi=30.0)
    _need(cfg, source, "gnss", "sigma_m", lo=0.0, hi=10.0)
    _need(cfg, source, "lidar", "pulse_rate_hz", lo=100.0, hi=2e6)
    _need(cfg, source, "lidar", "scan_frequency_hz", lo=1.0, hi=500.0)
    _need(cfg, source, "lidar", "fov_deg", lo=1.0, hi=75.0)
    _need(cfg, source, "lidar", "range_noise_m", lo=0.0, hi=5.0)
    for key in ("low_outlier_rate", "high_outlier_rate", "water_return_fraction"):
        _need(cfg, source, "lidar", key, lo=0.0, hi=1.0)
    bore = cfg["lidar"].get("boresight_error_deg", [0.0, 0.0, 0.0])
    if not (isinstance(bore, (list, tuple)) and len(bore) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) <= 5.0 for v in bore)):
        raise InputError(f"{source}: lidar.boresight_error_deg must be [roll, pitch, heading] in degrees (each within "
                         f"+-5), got {bore!r}")
    if "range_offset_m" in cfg["lidar"]:
        _need(cfg, source, "lidar", "range_offset_m", lo=-10.0, hi=10.0)
    if "scan_angle_scale_error" in cfg["lidar"]:
        _need(cfg, source, "lidar", "scan_angle_scale_error", lo=-0.01, hi=0.01)
    if cfg["lidar"].get("format") not in ("las", "laz"):
        raise InputError(f"{source}: lidar.format must be 'las' or 'laz', got {cfg['lidar'].get('format')!r}")
    _need(cfg, source, "scene", "terrain_res_m", lo=0.1, hi=10.0)
    _need(cfg, source, "scene", "steep_slope_deg", lo=0.0, hi=60.0)
    _need(cfg, source, "render", "samples", lo=1, hi=8, integer=True)
    _need(cfg, source, "truth", "raster_res_m", lo=0.05, hi=50.0)
    _need(cfg, source, "truth", "ortho_res_m", lo=0.02, hi=50.0)
    ref = cfg["scene"].get("counts_for_m")
    if ref is not None and not (isinstance(ref, (list, tuple)) and len(ref) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0 for v in ref)):
        raise InputError(f"{source}: scene.counts_for_m must be [width, height] in metres (both > 0), got {ref!r}")
    r = cfg["render"]
    if r.get("bands", "rgb") not in ("rgb", "pan"):
        raise InputError(f"{source}: render.bands must be 'rgb' or 'pan', got {r.get('bands')!r}")
    if r.get("bits", 8) not in (8, 12):
        raise InputError(f"{source}: render.bits must be 8 or 12, got {r.get('bits')!r}")
    if "tile_px" in r:
        t = _need(cfg, source, "render", "tile_px", lo=0, hi=4096, integer=True)
        if t % 32:
            raise InputError(f"{source}: render.tile_px must be a multiple of 32 (or 0: untiled), got {t}")
    for section in ("render", "truth"):
        if cfg[section].get("compress", "deflate") not in ("none", "deflate", "lzw", "zstd"):
            raise InputError(f"{source}: {section}.compress must be one of none, deflate, lzw, zstd, got "
                             f"{cfg[section].get('compress')!r}")
    if "texture_fine_m" in cfg["render"]:
        _need(cfg, source, "render", "texture_fine_m", lo=0.01, hi=10.0)
    if "tie_sigma_px" in cfg.get("observations", {}):
        _need(cfg, source, "observations", "tie_sigma_px", lo=0.0, hi=10.0)
    if "tie_points_per_frame" in cfg.get("observations", {}):
        _need(cfg, source, "observations", "tie_points_per_frame", lo=1, hi=10000, integer=True)
    heights = cfg["scene"].get("building_height_m")
    if not (isinstance(heights, (list, tuple)) and len(heights) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in heights) and 0 < heights[0] <= heights[1]):
        raise InputError(f"{source}: scene.building_height_m must be [min, max] with 0 < min <= max, got {heights!r}")
    lo, hi = heights
    # Flying heights must clear the whole scene, the valley side and the tallest building with room
    # to spare, and the frames must see the ground.
    top_m = (cfg["scene"]["steep_band_m"] * math.tan(math.radians(cfg["scene"]["steep_slope_deg"]))
             + 3 * cfg["scene"]["mountain_relief_m"] + 3 * cfg["scene"]["hill_amplitude_m"])
    for section in ("flight", "lidar"):
        h = _need(cfg, source, section, "height_above_ground_m")
        if h <= 0:
            raise InputError(f"{source}: {section}.height_above_ground_m = {h}: the flying height is below the terrain")
        if h < top_m + hi + 50.0:
            raise InputError(
                f"{source}: {section}.height_above_ground_m = {h} m does not clear the terrain: the valley side "
                f"rises about {top_m:.0f} m above the town and buildings reach {hi} m (need at least "
                f"{top_m + hi + 50.0:.0f} m)")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string for what presets hold
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise InputError(f"preset [chain]: cannot write {v!r} into project.toml")


def stage_sections_toml(chain: dict, prefix: str = "") -> str:
    """The preset's ``[chain.<stage>]`` tables as project.toml sections (``[<stage>]``, sub-tables nested)."""
    out = []
    for section, table in chain.items():
        name = f"{prefix}{section}"
        plain = {k: v for k, v in table.items() if not isinstance(v, dict)}
        out.append(f"\n[{name}]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in plain.items()))
        sub = {k: v for k, v in table.items() if isinstance(v, dict)}
        if sub:
            out.append(stage_sections_toml(sub, f"{name}."))
    return "".join(out)
