"""The truth simulator: a DMC-like frame block and LiDAR strips over a synthetic town, with known truth.

``simulate(cfg, outdir)`` writes a complete project folder (see the architecture doc) plus ``truth/``.
Nothing in the library imports this package.
"""

from aerotri.sim.config import available_presets, load_preset

__all__ = ["available_presets", "load_preset", "simulate"]


def __getattr__(name):
    # Lazy: the command line imports this package for the presets without the renderer and scanner.
    if name == "simulate":
        from aerotri.sim.project import simulate

        return simulate
    raise AttributeError(f"module 'aerotri.sim' has no attribute {name!r}")
