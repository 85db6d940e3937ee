"""The slope-based ground filter against a scene whose ground is known: a sloped terrain with a building and
trees; its limits (terrain steeper than max_slope, a building wider than twice the radius) as documented."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from lidarctl.classify import ground
from lidarctl.cli.main import main as lidarctl_cli
from lidarctl.classify.slope_filter import SlopeSettings, slope_ground


def _scene(slope: float, building_m: float, seed: int = 3):
    """Ground points (2 / m2, 5 cm noise) on a plane rising ``slope`` to the east, a flat roof 8 m above the
    terrain at its centre (``building_m`` wide, the ground under it not measured) and 40 tree crowns."""
    rng = np.random.default_rng(seed)
    n = 2 * 160 * 160
    x, y = rng.uniform(0, 160, n), rng.uniform(0, 160, n)
    roof = (np.abs(x - 80) < building_m / 2) & (np.abs(y - 80) < building_m / 2)
    z = slope * x + rng.normal(0, 0.05, n)
    z[roof] = slope * 80 + 8.0
    tx, ty = rng.uniform(10, 150, (2, 40))
    keep = ~np.any(np.hypot(tx - 80, ty - 80) < building_m, axis=0)
    tx, ty = tx[keep], ty[keep]
    cx, cy = (np.repeat(tx, 60) + rng.normal(0, 1.5, 60 * len(tx)), np.repeat(ty, 60) + rng.normal(0, 1.5, 60 * len(ty)))
    cz = slope * cx + rng.uniform(3, 12, len(cx))
    is_ground = np.r_[~roof, np.zeros(len(cx), bool)]
    return np.r_[x, cx], np.r_[y, cy], np.r_[z, cz], is_ground


def test_ground_kept_objects_removed_on_moderate_slopes():
    x, y, z, truth = _scene(slope=0.15, building_m=30.0)
    g = slope_ground(x, y, z)
    assert g[truth].mean() > 0.99  # type I below 1 %
    assert (~g[~truth]).mean() > 0.99  # roof and crowns removed
    assert np.array_equal(g, ground.ground_filter(x, y, z, method="slope"))  # the registry runs it


def test_documented_limits():
    # terrain steeper than max_slope loses ground (its upper side), a wider radius keeps a wide roof off the ground
    x, y, z, truth = _scene(slope=0.6, building_m=30.0)
    assert slope_ground(x, y, z)[truth].mean() < 0.9
    assert slope_ground(x, y, z, SlopeSettings(max_slope=0.8))[truth].mean() > 0.99
    x, y, z, truth = _scene(slope=0.0, building_m=30.0)
    roof = ~truth & (z > 7.0)
    assert not slope_ground(x, y, z)[roof].any()
    assert slope_ground(x, y, z, SlopeSettings(radius_m=8.0))[roof].any()  # its centre: no ground within 8 m


def test_the_command_line_has_its_parameters():
    out = CliRunner().invoke(lidarctl_cli, ["classify", "--help"]).output
    assert "--method [morph|ptd|slope]" in out.replace("\n", " ") or "slope" in out
    for name in ("--slope-cell-m", "--slope-radius-m", "--slope-max-slope", "--slope-tolerance-m"):
        assert name in out
