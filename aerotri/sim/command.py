"""What ``aerotri sim`` does, as one library call: the preset with its overrides, then the whole project, or
only the block's observations, or the project and observations from its truth geometry."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from aerotri.core.errors import InputError


def simulate_command(preset: str, outdir: Path, *, seed: int | None = None, overrides=(), force: bool = False,
                     observations: bool = False, observations_only: bool = False,
                     tie_points_per_frame: int | None = None, tie_sigma_px: float | None = None, n_control: int = 4,
                     blunder_fraction: float = 0.0, bad_control_shift_m: float = 0.0) -> str | None:
    """Simulate into ``outdir``; returns the line the command prints (None: the simulator printed its own)."""
    from aerotri.sim import load_preset, simulate

    cfg = load_preset(preset, [*overrides, *([f"preset.seed={int(seed)}"] if seed is not None else [])])
    if not 0.0 <= blunder_fraction < 1.0:
        raise InputError(f"--blunder-fraction {blunder_fraction}: must be in [0, 1)")
    if observations_only:
        from aerotri.sim.project import simulate_observations

        block = simulate_observations(cfg, outdir, force=force, tie_sigma_px=tie_sigma_px,
                                      tie_points_per_frame=tie_points_per_frame, n_control=n_control,
                                      blunder_fraction=blunder_fraction, bad_control_shift_m=bad_control_shift_m)
        return (f"{block.frames} frames, {block.tie_points} tie points, {block.tie_observations} tie observations, "
                f"{block.control_points} control and {block.check_points} check points; "
                f"DEM of the truth terrain: {block.dem_path} ({block.terrain_res_m:.2f} m)")
    simulate(cfg, outdir, force=force)
    if not observations:
        return None
    from aerotri.sim.observations import write_truth_observations

    sigma = cfg.observations.tie_sigma_px if tie_sigma_px is None else tie_sigma_px
    summary = write_truth_observations(outdir, tie_sigma_px=sigma, n_control=n_control,
                                       blunder_fraction=blunder_fraction, bad_control_shift_m=bad_control_shift_m,
                                       seed=cfg.preset.seed, tie_points_per_frame=tie_points_per_frame)
    counts = ((f.name, getattr(summary, f.name)) for f in dataclasses.fields(summary))
    return f"truth observations: {', '.join(f'{k} {v}' for k, v in counts if isinstance(v, (int, float)))}"
