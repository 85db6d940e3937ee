"""Issue 40: every length option names its unit (``--res-m``, ``--radius-m``, ``--image-sigma-px`` ...).

A scan of every click command of aerotri, ortho and lidarctl: a numeric option whose name holds a word of
a length, size, spread or angle must end in a unit suffix. New options are held to it as they are added.
"""

from __future__ import annotations

import click
import pytest

from aerotri.cli import main as aerotri_main
from lidarctl.cli.main import main as lidarctl_main
from ortho.cli import main as ortho_main

# words that make a number a length (or a spread of one, or an angle); matched as whole words of the option name
QUANTITY_WORDS = {"res", "resolution", "radius", "size", "buffer", "interval", "height", "spacing", "distance", "arm",
                  "sigma", "edge", "tile", "cell", "window", "width", "length", "dim", "shift", "offset", "depth",
                  "feather", "angle", "exclude", "tol", "tolerance", "gsd", "simplify", "match", "every"}
# the unit suffixes: SI lengths and areas, image units, angles and counts of the block's own units
UNITS = {"m", "m2", "cm", "mm", "um", "px", "deg", "baselines", "strips", "points"}
# numeric options with a quantity word that are not lengths, with the reason
NOT_LENGTHS = {
    "--morph-dense-points-per-cell": "a count of points per refinement cell",
    "--top-radius-per-m": "metres of radius per metre of height (ends in -m already: a ratio)",
}
# the names this change gave a unit: the old spellings must be gone (no aliases before 1.0)
RENAMED = {
    ("ortho", "rectify"): {"--res": "--res-m", "--max-view-angle": "--max-view-angle-deg"},
    ("ortho", "dem"): {"--res": "--res-m"},
    ("lidarctl", "rasters"): {"--res": "--res-m"},
    ("lidarctl", "evaluate"): {"--res": "--res-m"},
    ("lidarctl", "classify"): {"--tile-size": "--tile-size-m", "--buffer": "--buffer-m"},
    ("lidarctl", "check-heights"): {"--radius": "--radius-m", "--exclude": "--exclude-m",
                                    "--cover-radius": "--cover-radius-m", "--canopy-height": "--canopy-height-m"},
    ("lidarctl", "check-plan"): {"--radius": "--radius-m"},
    ("lidarctl", "contours"): {"--interval": "--interval-m"},
    ("lidarctl", "smooth"): {"--edge": "--edge-m"},
    ("aerotri", "crs", "warp"): {"--res": "--res-m"},
    ("aerotri", "crs", "transform"): {"--chunk-size": "--chunk-points"},
    ("aerotri", "match"): {"--terrain-height": "--terrain-height-m", "--max-dim": "--max-dim-px"},
    ("aerotri", "control"): {"--full-spacing": "--full-spacing-baselines", "--height-every": "--height-every-strips"},
    ("aerotri", "adjust"): {"--lever-arm": "--lever-arm-m", "--image-sigma": "--image-sigma-px"},
    ("aerotri", "import"): {"--sigma-xyz": "--sigma-xyz-m"},
}


def _commands(group: click.Group, path: tuple[str, ...]):
    for name, cmd in group.commands.items():
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, path + (name,))
        else:
            yield path + (name,), cmd


def _all_commands() -> dict:
    out = {}
    for name, group in (("aerotri", aerotri_main), ("ortho", ortho_main), ("lidarctl", lidarctl_main)):
        out.update(_commands(group, (name,)))
    return out


def _is_number(p: click.Parameter) -> bool:
    return isinstance(p.type, (click.types.FloatParamType, click.types.IntParamType))


def _needs_unit(name: str) -> bool:
    words = name[2:].split("-")
    return any(w in QUANTITY_WORDS for w in words)


def test_every_length_option_names_its_unit():
    commands = _all_commands()
    assert len(commands) >= 35  # the scan sees the three programs' commands, sub-groups included
    missing, seen = [], 0
    for path, cmd in commands.items():
        for p in cmd.params:
            if not isinstance(p, click.Option) or not _is_number(p):
                continue
            for name in (o for o in p.opts if o.startswith("--")):
                if not _needs_unit(name) or name in NOT_LENGTHS:
                    continue
                seen += 1
                if name[2:].split("-")[-1] not in UNITS:
                    missing.append(f"{' '.join(path)} {name}")
    assert seen > 60  # the words catch the length options there are (res, radius, sigma, tile ...)
    assert not missing, f"length options without their unit in the name: {missing}"


@pytest.mark.parametrize("path", sorted(RENAMED), ids=" ".join)
def test_the_old_spellings_are_gone(path):
    """No alias: the old name is no option of the command, the new one is (click refuses the old with exit 2)."""
    cmd = _all_commands()[path]
    names = {o for p in cmd.params for o in getattr(p, "opts", ())}
    for old, new in RENAMED[path].items():
        assert old not in names and new in names, (path, old, new)


def test_the_scan_catches_a_length_without_its_unit():
    """The words list flags the names this change fixed (so the scan would have failed before)."""
    old = [old for renames in RENAMED.values() for old in renames]
    assert all(_needs_unit(o) for o in old)
    assert not any(o.split("-")[-1] in UNITS for o in old)
