"""Rotations given against another CRS's axes turned onto the project grid (``poses.rotation_to_project``)."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from aerotri.core.project import Project
from aerotri.exchange.poses import rotation_to_project


@pytest.mark.parametrize("lon, lat", [(11.9, 65.0), (6.2, 70.0), (9.5, -33.7)])
def test_geographic_axes_turn_by_the_meridian_convergence(tmp_path, lon, lat):
    """East-north-up at a point of a geographic CRS (Metashape's usual EPSG:4326 reference) onto UTM 32N's grid: a
    turn about the vertical by the grid's meridian convergence, which pyproj states. The Jacobian's central
    difference took a step of 1 unit, one degree of a geographic CRS: 0.00008 deg off at 70 N (trial-exchange)."""
    (tmp_path / "project.toml").write_text('[project]\nname = "g"\ncrs = "EPSG:32632"\n')
    R = rotation_to_project("EPSG:4326", Project.open(tmp_path), np.array([[lon, lat, 300.0]]), "test")[0]
    gamma_deg = pyproj.Proj("EPSG:32632").get_factors(lon, lat).meridian_convergence  # deg
    assert np.degrees(np.arctan2(R[1, 0], R[0, 0])) == pytest.approx(gamma_deg, abs=1e-7)
    assert np.allclose(R[2], [0, 0, 1], atol=1e-9) and np.allclose(R[:, 2], [0, 0, 1], atol=1e-9)
