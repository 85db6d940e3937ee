"""DEM cells interpolated across a void of ground returns are said (trial s99 lidmut M1: ground over a 200 x 200 m area
left in class 1 by the vendor was TIN-filled, RMS 0.26 m / max 0.72 m off the truth there, with no word)."""

from __future__ import annotations

import logging

import numpy as np
from click.testing import CliRunner

from lidarctl import synthetic
from lidarctl.cli.main import main


def test_a_void_in_the_ground_is_said_with_its_area(tmp_path, caplog):
    caplog.set_level(logging.INFO)
    cloud, truth = synthetic.synthetic_scene(width_m=220.0, density_per_m2=1.5, seed=5, n_buildings=2, n_trees=10)
    full = tmp_path / "full.las"
    synthetic.write_las(full, cloud, classification=truth, crs="EPSG:32632")
    r = CliRunner().invoke(main, ["rasters", str(full), str(tmp_path / "r_full"), "--res-m", "1"])
    assert r.exit_code == 0, r.output
    assert "interpolated across voids" not in caplog.text + r.output
    # the ground of a 120 x 120 m square in the middle left unclassified: cells more than 25 m inside it are the void
    x, y = cloud.x - cloud.x.min(), cloud.y - cloud.y.min()
    inside = (np.abs(x - 110.0) < 60.0) & (np.abs(y - 110.0) < 60.0) & (truth == 2)
    cls = np.where(inside, 1, truth).astype(np.uint8)
    holed = tmp_path / "holed.las"
    synthetic.write_las(holed, cloud, classification=cls, crs="EPSG:32632")
    caplog.clear()
    r = CliRunner().invoke(main, ["rasters", str(holed), str(tmp_path / "r_holed"), "--res-m", "1"])
    assert r.exit_code == 0, r.output
    said = caplog.text + r.output
    assert "lie more than 25 m from any ground return: interpolated across voids" in said, said
    # about (120 - 2 x 25)^2 = 4,900 cells of 1 m (the square's edge cells hold ground a cell beyond)
    n = int(said.split(" DEM cells (")[0].split()[-1].replace(",", ""))
    assert 4000 < n < 5300, n
