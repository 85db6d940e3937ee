"""The NGI real-DMC reference set for bench scripts: ``tests/realdata_ngi.py`` loaded as a module.

The tests keep the one reader of the NGI frames, orientations and camera; pytest imports it with
``--import-mode=importlib``, so bench scripts load it from its file rather than by package name.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def load_ngi():
    """The ``realdata_ngi`` test module (registered in ``sys.modules``: its dataclasses look it up)."""
    if "realdata_ngi" in sys.modules:
        return sys.modules["realdata_ngi"]
    spec = importlib.util.spec_from_file_location("realdata_ngi", REPO / "tests" / "realdata_ngi.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["realdata_ngi"] = mod
    spec.loader.exec_module(mod)
    return mod
