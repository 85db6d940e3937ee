"""Simulator presets (TOML files in ``datasets/presets``; a wheel installs them into
``<prefix>/share/aerotri/presets``) and their validation.

A preset is a nested table: ``[preset] [crs] [camera] [flight] [gnss] [lidar] [scene] [render]
[truth]``, optionally ``[observations]`` (``OPTIONAL``), and ``[chain.<stage>]``: the stage options the simulated project's project.toml gets. ``--set section.key=value`` overrides single values (TOML syntax for the value).
Every invalid value is refused with an ``InputError`` that names the key and what was expected.
"""

from __future__ import annotations

import copy
import json
import math
import os
import tomllib
from pathlib import Path

from aerotri.core.errors import InputError

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


def load_preset(name_or_path: str, overrides: list[str] | tuple[str, ...] = ()) -> dict:
    """Load a preset by name (``tiny``, ``demo``, ``dmc``) or TOML path, apply overrides, validate."""
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
    cfg = apply_overrides(cfg, overrides)
    validate(cfg, str(path))
    return cfg


# Parameters a preset may leave out (their defaults: 8-bit RGB frames written whole by OpenCV, deflate truth
# rasters, texture down to the GSD, counts as given; the observations of ``aerotri sim --observations-only``):
# ``--set`` may still set them.
OPTIONAL = {"render": {"bits": 8, "bands": "rgb", "tile_px": 0, "compress": "none", "texture_fine_m": 0.0},
            "truth": {"compress": "deflate"}, "scene": {"counts_for_m": [1.0, 1.0]},
            "observations": {"tie_sigma_px": 0.3, "tie_points_per_frame": 130}}


def optional(cfg: dict, section: str, key: str):
    """A parameter of ``OPTIONAL``: the preset's value, else its default."""
    return cfg.get(section, {}).get(key, OPTIONAL[section][key])


def apply_overrides(cfg: dict, overrides) -> dict:
    cfg = copy.deepcopy(cfg)
    for item in overrides:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise InputError(f"--set {item!r}: expected section.key=value, e.g. flight.side_overlap=0.3")
        key, value = item.split("=", 1)
        section, name = key.strip().split(".", 1)
        if section not in cfg and section in OPTIONAL:
            cfg[section] = {}
        if section not in cfg or (name not in cfg[section] and name not in OPTIONAL.get(section, {})):
            raise InputError(f"--set {item!r}: unknown parameter {key!r}")
        try:
            parsed = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            parsed = value.strip()
        old = cfg[section].get(name, OPTIONAL.get(section, {}).get(name))
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


def validate(cfg: dict, source: str = "preset") -> None:
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
    lo, hi = cfg["scene"]["building_height_m"]
    if not (0 < lo <= hi):
        raise InputError(f"{source}: scene.building_height_m must be [min, max] with 0 < min <= max")
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
