"""Surface control with a fifth of the tie points on trees and moving cars (aerotri.sim.clutter): the DEM
still fixes the heights as with ground points alone; the trees and cars are kept off it."""

from __future__ import annotations

import numpy as np
import pytest

from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.sim.clutter import write_clutter_projects
from aerotri.sim.observations import geometric_block

SIGMA_PX = 0.3


@pytest.fixture(scope="module")
def cluttered(tmp_path_factory):
    # GNSS heights shifted per strip (0.5 m sigma), plan unbiased, no control points: the DEM carries the heights
    block = geometric_block(3, 6, seed=5, gnss_shift_sigma_m=0.5, gnss_drift_sigma_m_per_km=0.0)
    block.gnss_local[:, :2] -= block.gnss_shift_m[block.strip, :2]
    block.gnss_shift_m[:, :2] = 0.0
    ties, clean, dirty = write_clutter_projects(block, tmp_path_factory.mktemp("clutter"), points_per_image=120,
                                                n_check=20, sigma_px=SIGMA_PX, seed=8)
    return ties, clean, dirty


def _adjust(root, ndsm=False):
    return adjust_project(root, AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, point_covariances=False,
                                               dem=root / "dem.tif", ndsm=root / "ndsm.tif" if ndsm else None))


def _check_dz(ba) -> np.ndarray:
    return np.array([c["adjusted_m"][2] - c["measured_m"][2] for c in ba.check.values()])


def _classes(ba, ties):
    """Per tie point: its class, surface use (0/1/2), active rays; per observation: removed by data snooping."""
    b, r = ba.block, ba.result
    cls = np.array([ties.point_class[p] for p in b.point_id])
    rays = np.bincount(b.obs_point[r.obs_active], minlength=b.n_points)
    snooped = np.zeros(len(b.obs_point), dtype=bool)
    snooped[[x.obs for x in r.removed]] = True
    return cls, r.surface_use, rays, snooped


def test_trees_and_moving_cars_do_not_bias_the_heights(cluttered):
    ties, clean_root, dirty_root = cluttered
    counts = ties.counts()
    n = counts.points
    assert 0.08 < counts.vegetation.points / n < 0.12 and 0.08 < counts.moving.points / n < 0.12, counts
    clean = _check_dz(_adjust(clean_root))
    bound = np.sqrt(np.mean(clean**2) / len(clean))  # the clean run's check heights know their mean to this
    for ndsm in (False, True):  # the DEM alone (the gate and Huber do all the work), and with the crowns' nDSM
        ba = _adjust(dirty_root, ndsm)
        dz = _check_dz(ba)
        assert abs(dz.mean() - clean.mean()) < bound, (ndsm, dz.mean(), clean.mean(), bound)
        assert np.sqrt(np.mean(dz**2)) < 1.1 * np.sqrt(np.mean(clean**2)) + 0.01, ndsm
        cls, use, rays, snooped = _classes(ba, ties)
        held = (use == 1) & (rays >= 2)  # a surface observation on a point in the solution
        veg, car, ground = cls == "vegetation", cls == "moving", cls == "ground"
        assert held[veg].mean() < 0.05, (ndsm, held[veg].mean())
        assert held[ground].mean() > (0.85 if ndsm else 0.95), (ndsm, held[ground].mean())
        # the cars' rays do not meet: snooping removes them (a point left with one ray drops out) or the gate
        # keeps the DEM off what is left
        car_obs = cls[ba.block.obs_point] == "moving"
        assert snooped[car_obs].mean() > 0.4 and ((rays[car] < 2) | (use[car] != 1)).mean() > 0.9, ndsm
        assert held[car].mean() < 0.05
