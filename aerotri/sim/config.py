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
import math
import os
import tomllib
import typing
from pathlib import Path

from aerotri.core.errors import InputError
from aerotri.core.settings import default_settings, from_table, setting

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
    cfg, given = _apply_overrides(cfg, overrides)
    preset = _typed(cfg, str(path), given)
    _check_across_tables(preset, str(path), given)
    return preset


# ----------------------------------------------------------------------------------------------
# The preset's tables, one frozen dataclass each (lengths in metres, angles in degrees). A key the
# preset may leave out has a default (8-bit RGB frames written whole by OpenCV, deflate truth rasters,
# texture down to the GSD, the scene's counts as given, no injected LiDAR error).
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetHeader:
    """``[preset]``: its name, a line saying what it is, the seed of every random stream."""

    name: str = setting(help="the preset's name, written into the project")
    description: str = setting("", help="one line saying what the block is")
    seed: int = setting(help="the seed of every random stream (aerotri sim --seed overrides it)")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetCrs:
    """``[crs]``: the project CRS (EPSG code) and the scene's lower-left corner in it (ellipsoidal height)."""

    epsg: int = setting(min=1, help="the project CRS (a projected CRS in metres)")
    origin_e_m: float = setting(help="easting of the scene's lower-left corner")
    origin_n_m: float = setting(help="northing of the scene's lower-left corner")
    base_height_m: float = setting(help="ellipsoidal height of the flat town")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetCamera:
    """``[camera]``: the true camera the frames are rendered through (camera.toml gets only its focal length and
    format); principal point offset in mm (x right, y up), Brown coefficients."""

    focal_mm: float = setting(min=1.0, max=1000.0, min_open=True, help="focal length")
    sensor_width_mm: float = setting(min=1.0, max=1000.0, help="sensor size across track (image x)")
    sensor_height_mm: float = setting(min=1.0, max=1000.0, help="sensor size along track (image y)")
    width: int = setting(min=16, max=30000, help="frame width in pixels")
    height: int = setting(min=16, max=30000, help="frame height in pixels")
    ppx_mm: float = setting(help="principal point offset, x right (camera.toml has none)")
    ppy_mm: float = setting(help="principal point offset, y up")
    k1: float = setting(help="Brown radial coefficient (normalised image coordinates x / f, as camera.toml's)")
    k2: float = setting(help="Brown radial coefficient")
    k3: float = setting(help="Brown radial coefficient")
    p1: float = setting(help="Brown tangential coefficient")
    p2: float = setting(help="Brown tangential coefficient")

    def __post_init__(self):
        # the frames have square pixels of sensor_width_mm / width: a sensor height that does not match was ignored by
        # the camera and used by the flight plan (trial-cam F6)
        along_um = 1000.0 * self.sensor_height_mm / self.height
        across_um = 1000.0 * self.sensor_width_mm / self.width
        if abs(along_um - across_um) > 0.005 * across_um:
            raise ValueError(f"sensor_height_mm = {self.sensor_height_mm:g} over height = {self.height} px is "
                             f"{along_um:.4g} um a pixel, sensor_width_mm = {self.sensor_width_mm:g} over width = "
                             f"{self.width} px {across_um:.4g} um: expected square pixels (sensor_height_mm = "
                             f"{self.height * across_um / 1000.0:.6g})")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetFlight:
    """``[flight]``: the photo flight (overlaps as fractions, tilt and kappa deviations drawn within the limits)."""

    height_above_ground_m: float = setting(min=0.0, min_open=True,
                                           help="above the town; must clear the valley side and the tallest building")
    forward_overlap: float = setting(min=0.0, max=0.95, help="along-track overlap over the town (fraction)")
    side_overlap: float = setting(min=0.0, max=0.95, help="across-track overlap over the town (fraction)")
    strips: int = setting(min=1, max=200, help="flight lines (the scene grows with the flight)")
    frames_per_strip: int = setting(min=2, max=2000, help="frames per flight line")
    speed_mps: float = setting(min=1.0, max=500.0, help="ground speed (the GNSS times)")
    max_tilt_deg: float = setting(min=0.0, max=10.0, help="largest omega/phi deviation from nadir")
    max_kappa_dev_deg: float = setting(min=0.0, max=30.0, help="largest kappa deviation from the flight direction")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetGnss:
    """``[gnss]``: the antenna positions' errors (white noise, per-strip shift and drift), the lever arm in the
    camera frame (x right, y up, z up) and the sigmas written into gnss.txt and project.toml."""

    sigma_m: float = setting(min=0.0, max=10.0, help="white noise of each antenna position")
    strip_shift_sigma_m: float = setting(0.0, min=0.0, help="per-strip constant shift")
    drift_sigma_m_per_s: float = setting(0.0, min=0.0, help="per-strip linear drift")
    lever_arm_m: tuple[float, float, float] = setting(help="antenna in the camera frame (x right, y up, z up)")
    sigma_xy_m: float = setting(min=0.0, min_open=True, help="plan sigma written into gnss.txt and project.toml")
    sigma_z_m: float = setting(min=0.0, min_open=True, help="height sigma written into gnss.txt and project.toml")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetLidar:
    """``[lidar]``: the LiDAR flight and scanner (zig-zag, full field of view ``fov_deg``), its noise and outliers,
    the injected system errors (boresight roll, pitch, heading; range offset; scan angle scale) and the format."""

    height_above_ground_m: float = setting(min=0.0, min_open=True, help="above the town, as the photo flight's")
    pulse_rate_hz: float = setting(min=100.0, max=2e6, help="pulses per second")
    scan_frequency_hz: float = setting(min=1.0, max=500.0, help="mirror lines per second")
    fov_deg: float = setting(min=1.0, max=75.0, help="full field of view (zig-zag, oscillating mirror)")
    speed_mps: float = setting(min=1.0, max=500.0, help="ground speed")
    side_overlap: float = setting(min=0.0, max=0.9, help="overlap of neighbouring strips (fraction)")
    range_noise_m: float = setting(min=0.0, max=5.0, help="range noise (sigma)")
    strip_offset_sigma_m: float = setting(min=0.0, help="per-strip height offset (sigma)")
    boresight_error_deg: tuple[float, float, float] = setting(
        (0.0, 0.0, 0.0), min=-5.0, max=5.0, help="scanner roll, pitch, heading against the IMU (an injected error)")
    range_offset_m: float = setting(0.0, min=-10.0, max=10.0, help="added to every range (an injected error)")
    scan_angle_scale_error: float = setting(0.0, min=-0.01, max=0.01,
                                            help="the beam leaves at (1 + this) x the scan angle read (injected)")
    attitude_noise_deg: float = setting(min=0.0, help="IMU attitude noise (sigma)")
    low_outlier_rate: float = setting(min=0.0, max=1.0, help="share of returns far below the surface")
    high_outlier_rate: float = setting(min=0.0, max=1.0, help="share of returns in the air (birds, haze)")
    water_return_fraction: float = setting(min=0.0, max=1.0, help="share of pulses on water that return")
    canopy_first_return_prob: float = setting(min=0.0, max=1.0, help="chance a pulse into a crown returns from its top")
    canopy_interior_return_prob: float = setting(min=0.0, max=1.0, help="chance of a return from inside the crown")
    canopy_ground_return_prob: float = setting(min=0.0, max=1.0, help="chance of a return from the ground beneath")
    format: str = setting(choices=("las", "laz"), help="the strips' file format")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetScene:
    """``[scene]``: the town, the valley side and the targets (ranges as [min, max]); the counts are those of a
    scene of ``counts_for_m`` = [width, height] metres (None: of any size), see ``scene.scene_counts``."""

    counts_for_m: tuple[float, float] | None = setting(
        None, min=0.0, min_open=True, help="[width, height] of the scene the counts are for (another flight scales them)")
    margin_m: float = setting(min=0.0, help="terrain beyond the photo footprints")
    terrain_res_m: float = setting(min=0.1, max=10.0, help="cell of the truth terrain")
    hill_amplitude_m: float = setting(min=0.0, help="rolling hills' amplitude")
    hill_scale_m: float = setting(min=0.0, min_open=True, help="rolling hills' wavelength")
    steep_start_frac: float = setting(min=0.0, max=1.0, help="the valley side starts at this fraction of the height")
    steep_band_m: float = setting(min=0.0, help="width of the valley side")
    steep_slope_deg: float = setting(min=0.0, max=60.0, help="slope of the valley side")
    mountain_relief_m: float = setting(min=0.0, help="relief above the valley side")
    urban_margin_m: float = setting(min=0.0, help="kept free of buildings at the scene's edge")
    road_angle_deg: float = setting(help="direction of the road grid")
    road_spacing_m: float = setting(min=0.0, min_open=True, help="distance between roads")
    road_width_m: tuple[float, float] = setting(min=0.0, help="[min, max]")
    ponds: int = setting(min=0, help="ponds (water)")
    pond_size_m: tuple[float, float] = setting(min=0.0, help="[min, max]")
    buildings: int = setting(min=0, help="buildings in a scene of counts_for_m")
    shape_weights: tuple[float, float, float] = setting(min=0.0, help="rectangle, L, courtyard")
    building_length_m: tuple[float, float] = setting(min=0.0, help="[min, max]")
    building_width_m: tuple[float, float] = setting(min=0.0, help="[min, max]")
    building_height_m: tuple[float, float] = setting(min=0.0, min_open=True, help="[min, max], min <= max")
    building_angle_jitter_deg: float = setting(min=0.0, help="deviation from the road grid")
    building_gap_m: float = setting(min=0.0, help="least distance between buildings")
    pitched_fraction: float = setting(min=0.0, max=1.0, help="share of pitched roofs")
    eave_m: tuple[float, float] = setting(min=0.0, help="roof overhang beyond the walls, [min, max]")
    single_trees: int = setting(min=0, help="trees standing alone")
    tree_clusters: int = setting(min=0, help="groups of trees")
    slope_trees: int = setting(min=0, help="trees on the valley side")
    bushes: int = setting(min=0, help="low vegetation objects")
    crown_radius_m: tuple[float, float] = setting(min=0.0, help="[min, max]")
    tree_height_m: tuple[float, float] = setting(min=0.0, help="[min, max]")
    check_targets: int = setting(min=0, help="painted targets (surveyed check points)")
    target_radius_m: float = setting(min=0.0, min_open=True, help="radius of a target")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetRender:
    """``[render]``: rays per pixel per axis, sensor noise and exposure, the frames' bits, bands, tiling (0: one
    strip image written by OpenCV) and compression, the finest texture (0: the GSD)."""

    samples: int = setting(min=1, max=8, help="rays per pixel per axis (anti-aliasing)")
    noise_dn: float = setting(min=0.0, help="sensor noise (sigma, digital numbers of 8 bits)")
    exposure_sigma: float = setting(min=0.0, help="frame-to-frame exposure change (relative sigma)")
    vignetting: float = setting(min=0.0, max=1.0, help="relative fall-off at the image corner")
    bits: int = setting(8, choices=(8, 12), help="8-bit frames, or 12-bit data in 16-bit TIFF")
    bands: str = setting("rgb", choices=("rgb", "pan"), help="three colour bands or one panchromatic")
    tile_px: int = setting(0, min=0, max=4096, help="TIFF tile size, a multiple of 32 (0: one strip image)")
    compress: str = setting("none", choices=("none", "deflate", "lzw", "zstd"), help="the frames' compression")
    texture_fine_m: float = setting(0.0, min=0.0, max=10.0, help="the finest texture (0: the GSD)")

    def __post_init__(self):
        if self.tile_px % 32:
            raise ValueError(f"tile_px must be a multiple of 32 (or 0: untiled), got {self.tile_px}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetTruth:
    """``[truth]``: the cell sizes of the truth rasters and orthophoto, their compression."""

    raster_res_m: float = setting(min=0.05, max=50.0, help="cell of the truth DEM, DSM and class rasters")
    ortho_res_m: float = setting(min=0.02, max=50.0, help="cell of the true orthophoto")
    compress: str = setting("deflate", choices=("none", "deflate", "lzw", "zstd"), help="the rasters' compression")


@dataclasses.dataclass(frozen=True, kw_only=True)
class PresetObservations:
    """``[observations]`` (``aerotri sim --observations-only``): image noise of the tie and control measurements,
    tie points per frame on average."""

    tie_sigma_px: float = setting(0.3, min=0.0, max=10.0, help="image noise of the tie and control measurements")
    tie_points_per_frame: int = setting(130, min=1, max=10000, help="tie points per frame on average")


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


def _typed(cfg: dict, source: str, given: dict[tuple[str, str], str]) -> Preset:
    """The TOML document as a ``Preset``: every table's keys, types, ranges and choices checked by ``from_table``
    (a missing table or key, an unknown one, a wrong type or a value out of range: ``ConfigError``; one set
    with ``--set``, ``given``, is named as typed)."""
    classes = _table_classes()
    unknown = [k for k in cfg if k not in classes and k != "chain"]
    if unknown:
        raise InputError(f"{source}: unknown table [{unknown[0]}] (known: {', '.join([*classes, 'chain'])})")
    missing = [name for name, cls in classes.items() if name not in cfg and default_settings(cls) is None]
    if missing:
        raise InputError(f"{source}: missing table [{missing[0]}]")
    tables = {name: from_table(cls, cfg.get(name, {}), f"{source} [{name}]",
                               sources={k: v for (t, k), v in given.items() if t == name})
              for name, cls in classes.items()}
    return Preset(**tables, chain=copy.deepcopy(cfg.get("chain", {})))


def _field_default(section: str, name: str):
    """The default of ``section.name`` (None: required, or no such field)."""
    cls = _table_classes().get(section)
    f = next((f for f in dataclasses.fields(cls) if f.name == name), None) if cls is not None else None
    return None if f is None or f.default is dataclasses.MISSING else f.default


def _is_field(section: str, name: str) -> bool:
    cls = _table_classes().get(section)
    return cls is not None and any(f.name == name for f in dataclasses.fields(cls))


def _apply_overrides(cfg: dict, overrides) -> tuple[dict, dict[tuple[str, str], str]]:
    """``--set section.key=value`` items (TOML syntax for the value) on the preset's TOML document: the key must
    be a field of that table; a number where the preset (or the field's default) has a number. Returns the
    document and (section, key) -> the option as typed (``--set section.key=value``; the last of a key)."""
    cfg = copy.deepcopy(cfg)
    given = {}
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
        given[(section, name)] = f"--set {item}"
    return cfg, given


def checked_preset(preset: Preset, source: str = "preset") -> Preset:
    """A preset made or changed in code (``dataclasses.replace(preset.flight, side_overlap=1.5)``) put through
    ``load_preset``'s checks: ``ConfigError`` / ``InputError`` naming the table and key. Such a preset was simulated
    as it stood (trial-api F4: a strip spacing of -207.36 m)."""
    from aerotri.core.settings import checked_settings

    preset = checked_settings(preset, source)
    _check_across_tables(preset, source, {})
    return preset


def _check_across_tables(preset: Preset, source: str, given: dict[tuple[str, str], str]) -> None:
    """What no single field can check: the ranges' order, and flying heights that clear the scene (a value set
    with ``--set``, ``given``, named as typed)."""
    def refused(section: str, key: str, message: str) -> InputError:
        return InputError(f"{given[section, key]}: {message}" if (section, key) in given else message)

    lo, hi = preset.scene.building_height_m
    if lo > hi:
        raise refused("scene", "building_height_m",
                      f"{source} [scene] building_height_m = [{lo}, {hi}]: expected [min, max] with min <= max")
    # Flying heights must clear the whole scene, the valley side and the tallest building with room
    # to spare, and the frames must see the ground.
    sc = preset.scene
    top_m = sc.steep_band_m * math.tan(math.radians(sc.steep_slope_deg)) + 3 * sc.mountain_relief_m \
        + 3 * sc.hill_amplitude_m
    for section in ("flight", "lidar"):
        h = getattr(preset, section).height_above_ground_m
        if h < top_m + hi + 50.0:
            raise refused(section, "height_above_ground_m",
                          f"{source} [{section}] height_above_ground_m = {h}: does not clear the terrain: the valley "
                          f"side rises about {top_m:.0f} m above the town and buildings reach {hi} m (need at least "
                          f"{top_m + hi + 50.0:.0f} m)")


def preset_reference() -> str:
    """docs/presets.md: every table of a preset with its keys (type, unit, default, allowed range, meaning), from
    the dataclasses ``load_preset`` reads them with (``core.settings.markdown_reference``)."""
    from aerotri.core.settings import markdown_reference

    hints = typing.get_type_hints(Preset)
    sections = [(f.name, [hints[f.name]], "`aerotri sim`") for f in dataclasses.fields(Preset) if f.name != "chain"]
    head = ("# Simulator presets: every key\n\n"
            "Generated by `preset_reference()` in `aerotri/sim/config.py` from the preset's dataclasses;\n"
            "`tests/aerotri/sim/test_config.py` checks that this page is current. A preset is a TOML file\n"
            "(`datasets/presets/*.toml`, or a path) of the tables below, plus `[chain.<stage>]` tables: the stage\n"
            "options the simulated project's project.toml gets (checked by `aerotri run`, see docs/settings.md).\n"
            "`aerotri sim --set table.key=value` overrides one value (TOML syntax). A missing or unknown key, a value\n"
            "of the wrong type or out of range, and flying heights that do not clear the scene stop with the file,\n"
            "the table and the key. See docs/simulator.md for what the simulator makes.\n\n")
    return head + markdown_reference(sections, {})
