"""The truth simulator: a DMC-like frame block and LiDAR strips over a synthetic town, with known truth.

``simulate(cfg, outdir)`` writes a complete project folder (see the architecture doc) plus ``truth/``.
Nothing in the library imports this package.
"""

__all__ = ["Preset", "SimTruth", "available_presets", "lidar_plan", "load_preset", "simulate"]

_HOME = {"Preset": "aerotri.sim.config", "SimTruth": "aerotri.sim.project", "available_presets": "aerotri.sim.config",
         "load_preset": "aerotri.sim.config", "simulate": "aerotri.sim.project",
         "lidar_plan": "aerotri.sim.project"}


def __getattr__(name):
    # Lazy: the command line (``aerotri sim --help``) need not compile the ray caster (numba).
    if name in _HOME:
        import importlib

        return getattr(importlib.import_module(_HOME[name]), name)
    raise AttributeError(f"module 'aerotri.sim' has no attribute {name!r}")
