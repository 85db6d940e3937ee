"""Tolerance tables by map scale and terrain class: the limits of the accuracy reports (a registry).

Each table is a TOML file (``tolerance_tables/cn_1to2000.toml``, ``cn_1to5000.toml``,
``cn_1to10000.toml``: the Chinese national specification for photogrammetric office work at these
scales) with sections ``flat``, ``hilly``, ``mountainous`` plus ``general`` for every class; a user
gives the table of a contract with ``tolerances = "FILE"`` in ``[qa]`` of project.toml or
``--tolerances FILE``. ``SCALE_TABLES`` is the registry of the built-in tables (the CLI's choices).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from aerotri.core.errors import ConfigError, InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_text

TOLERANCE_DIR = Path(__file__).with_name("tolerance_tables")
SCALE_TABLES = {"1:2000": "cn_1to2000.toml", "1:5000": "cn_1to5000.toml", "1:10000": "cn_1to10000.toml"}
TERRAINS = ("flat", "hilly", "mountainous")


def tolerance_path(scale: str | None = None, tolerance_file=None, source: str = "map scale") -> Path:
    """The tolerance table of ``scale`` (or ``tolerance_file``); ``source`` names where the scale came from."""
    if tolerance_file:
        p = Path(tolerance_file)
        if not p.is_file():
            raise InputError(f"{p}: tolerance table not found")
        return p
    scale = scale or "1:5000"
    if scale not in SCALE_TABLES:
        raise ConfigError(f"{source} {scale!r}: no built-in tolerance table (have {', '.join(SCALE_TABLES)}); "
                          f"give your own with --tolerances FILE")
    return TOLERANCE_DIR / SCALE_TABLES[scale]


def load_tolerances(scale: str | None = None, terrain: str = "flat", tolerance_file=None) -> dict:
    """Limits for one terrain class: the ``general`` section overlaid by the class's own."""
    path = tolerance_path(scale, tolerance_file)
    try:
        table = tomllib.loads(read_text(path, "tolerance table (TOML)"))
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: not a valid TOML tolerance table ({e})") from None
    if terrain not in table:
        have = [k for k, v in table.items() if isinstance(v, dict) and k != "general"]
        raise InputError(f"{path}: no [{terrain}] section (terrain classes here: {', '.join(have)})")
    return {**table.get("general", {}), **table[terrain]}


def qa_settings(root: Path) -> dict:
    """``[qa]`` of project.toml (map_scale, terrain, tolerances, pdf), with defaults; checked."""
    project = Project.open(root)
    qa = project.qa  # types checked when the project is opened
    src = f"{project.config_path} [qa]"
    out = dict(map_scale=qa.map_scale, terrain=qa.terrain, tolerances=qa.tolerances, pdf=qa.pdf)
    if not out["tolerances"] and out["map_scale"] not in SCALE_TABLES:
        raise ConfigError(f"{src} map_scale = {out['map_scale']!r}: no built-in tolerance table (have "
                          f"{', '.join(SCALE_TABLES)}); give your own with tolerances = \"FILE\"")
    if out["terrain"] not in TERRAINS and not out["tolerances"]:
        raise ConfigError(f"{src} terrain = {out['terrain']!r}: expected one of {', '.join(TERRAINS)}")
    if out["tolerances"]:
        out["tolerances"] = str((Path(root) / out["tolerances"]).resolve())
    return out
