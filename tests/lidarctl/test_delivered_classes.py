"""Vendor-classified LiDAR: the delivered classes are kept when they are a plausible classification, and
refused with a message naming the file and the fault when they are not."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from lidarctl import synthetic
from lidarctl.cli.main import main

CRS = "EPSG:32632"


@pytest.fixture(scope="module")
def scene():
    return synthetic.synthetic_scene(width_m=240.0, density_per_m2=3.0, seed=4)


def _write(path, cloud, classes):
    synthetic.write_las(path, cloud, classification=classes, crs=CRS)
    return path


def test_delivered_classes_are_kept(scene, tmp_path):
    cloud, truth = scene
    src = _write(tmp_path / "vendor.las", cloud, truth)
    res = CliRunner().invoke(main, ["classify", str(src), str(tmp_path / "out.las"), "--keep-classes"])
    assert res.exit_code == 0, res.output
    with laspy.open(src) as a, laspy.open(tmp_path / "out.las") as b:
        pa, pb = a.read(), b.read()
    assert np.array_equal(np.asarray(pa.classification), np.asarray(pb.classification))
    assert np.array_equal(np.asarray(pa.X), np.asarray(pb.X))
    assert "delivered classes kept" in res.output


@pytest.mark.parametrize("fault, message", [
    ("unclassified", "not classified"),
    ("no_ground", "ground class (2) holds"),
    ("ground_is_roofs", "not the lowest surface"),
    ("buildings_on_ground", "building class (6) stands"),
])
def test_implausible_classes_are_refused(scene, tmp_path, fault, message):
    cloud, truth = scene
    cls = truth.copy()
    if fault == "unclassified":
        cls[:] = 1
    elif fault == "no_ground":
        cls[cls == 2] = 1
    elif fault == "ground_is_roofs":  # in the western half the 'ground' is on the roofs and trees, the ground is 1
        west = cloud.x < np.median(cloud.x)
        cls[west & (truth == 2)] = 1
        cls[west & np.isin(truth, [3, 4, 5, 6])] = 2
    elif fault == "buildings_on_ground":  # class 6 put on a third of the ground points
        g = np.flatnonzero(truth == 2)
        cls[truth == 6] = 1
        cls[g[::3]] = 6
    src = _write(tmp_path / "vendor.las", cloud, cls)
    out = tmp_path / "out.las"
    res = CliRunner().invoke(main, ["classify", str(src), str(out), "--keep-classes"])
    assert res.exit_code == 2, res.output
    assert str(src) in res.output and message in res.output and "Traceback" not in res.output
    assert not out.exists()
