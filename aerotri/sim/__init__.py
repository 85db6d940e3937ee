"""The truth simulator: a DMC-like frame block and LiDAR strips over a synthetic town, with known truth.

``simulate(cfg, outdir)`` writes a complete project folder (see the architecture doc) plus ``truth/``.
Nothing in the library imports this package.
"""

from aerotri.sim.config import available_presets, load_preset
from aerotri.sim.project import simulate

__all__ = ["available_presets", "load_preset", "simulate"]
