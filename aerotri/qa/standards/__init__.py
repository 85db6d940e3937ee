"""The accuracy standards a delivery is judged against, as data: one TOML file per standard in this folder
(``asprs2023.toml``, ``usgs_lbs.toml``, ``cn_at.toml``), every limit with its source and whether its number
was confirmed in the document (docs/standards.md lists them). The "thesis" standard is the project's
map-scale tolerance tables (aerotri/core/tolerance_tables/cn_1to*.toml), read through aerotri.core.tolerances.
"""

from __future__ import annotations

import tomllib
from functools import lru_cache
from pathlib import Path

STANDARDS_DIR = Path(__file__).parent
STANDARD_FILES = {"asprs2023": "asprs2023.toml", "usgs-lbs": "usgs_lbs.toml", "cn-at": "cn_at.toml"}
STANDARD_KEYS = ("asprs2023", "usgs-lbs", "cn-at", "thesis")


@lru_cache(maxsize=None)
def load_standard(key: str) -> dict:
    """The table of a standard (``STANDARD_FILES``), as parsed TOML (shipped with the package: a broken file
    is a bug, not bad input)."""
    return tomllib.loads((STANDARDS_DIR / STANDARD_FILES[key]).read_text(encoding="utf-8"))
