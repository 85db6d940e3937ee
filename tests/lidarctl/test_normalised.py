"""A height-normalised cloud (heights above the ground) given where elevations are expected is said
(``lidarctl.normalised``; new-user trial s94: lidR's MixedConifer made a DEM of 0-1.2 m, contours and streams
without a word)."""

from __future__ import annotations

import dataclasses
import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.geom import las
from lidarctl import synthetic
from lidarctl.cli.main import main
from lidarctl.normalised import normalised_heights_note
from lidarctl.units import METRE

NOTE = "heights look normalised"


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """The synthetic scene (terrain 93-110 m), the same normalised by its true terrain (ground at 0, with the
    scene's low outliers below it), and the same lowered so that its ground lies 0.1-17 m around 0 (a real
    terrain that crosses its datum's zero)."""
    d = tmp_path_factory.mktemp("normalised")
    cloud, truth = synthetic.synthetic_scene(width_m=150.0, density_per_m2=2.0, seed=5)
    ground_z = synthetic.terrain_height(cloud.x - 500000.0, cloud.y - 5400000.0)
    normalised = dataclasses.replace(cloud, z=cloud.z - ground_z)
    lowered = dataclasses.replace(cloud, z=cloud.z - float(np.median(ground_z)))
    for name, c in (("elev", cloud), ("norm", normalised), ("low", lowered)):
        synthetic.write_las(d / f"{name}.las", c, classification=truth, crs="EPSG:32632")
    return d


def _note(path):
    return normalised_heights_note(path, las.read_header(path), METRE)


def test_a_normalised_cloud_is_said_and_elevations_are_not(clouds):
    note = _note(clouds / "norm.las")
    assert note is not None and NOTE in note and "norm.las" in note
    assert _note(clouds / "elev.las") is None
    # terrain whose heights cross 0 (relief of metres) is not ground at 0 everywhere
    assert _note(clouds / "low.las") is None


def test_classify_and_rasters_warn_of_a_normalised_cloud(clouds, tmp_path):
    runner = CliRunner()
    r = runner.invoke(main, ["rasters", str(clouds / "norm.las"), str(tmp_path / "r"), "--res-m", "2"])
    assert r.exit_code == 0, r.output
    assert r.output.count(NOTE) == 1
    r = runner.invoke(main, ["classify", str(clouds / "norm.las"), str(tmp_path / "c.las")])
    assert r.exit_code == 0, r.output
    assert r.output.count(NOTE) == 1
    r = runner.invoke(main, ["rasters", str(clouds / "elev.las"), str(tmp_path / "r2"), "--res-m", "2"])
    assert r.exit_code == 0 and NOTE not in r.output, r.output


def test_mixedconifer_is_said_and_the_other_real_clouds_are_not(shared_data):
    """lidR's MixedConifer (normalised by lidR) is; AHN3 Delft (polder ground -0.6 to +1 m NAP) and lidR Topography
    are not."""
    assert NOTE in _note(shared_data / "lidr_mixedconifer" / "MixedConifer.laz")
    assert _note(shared_data / "ahn3_delft" / "ahn3_cropped_1.laz") is None
    assert _note(shared_data / "lidr_topography" / "Topography.laz") is None
