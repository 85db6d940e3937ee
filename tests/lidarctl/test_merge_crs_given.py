"""``lidarctl merge`` of strips without a CRS record (trial s99 lidmut M5, L1): ``--crs`` naming a CRS whose area of
use the strips' coordinates lie far outside (UTM 33N metres merged as Oregon Lambert feet) is warned of, as every other
command warns; without ``--crs`` the merged file without a CRS is said."""

from __future__ import annotations

import logging

import laspy
import numpy as np
from click.testing import CliRunner

from lidarctl.cli.main import main


def _untagged(path, seed: int):
    rng = np.random.default_rng(seed)
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = [0.01] * 3, [500_000.0, 5_000_000.0, 0.0]
    data = laspy.LasData(h)
    n = 500
    data.x, data.y = 500_000 + rng.uniform(0, 100, n), 5_000_000 + rng.uniform(0, 100, n)
    data.z = rng.uniform(0, 10, n)
    data.write(path)
    return path


def test_merge_says_what_it_cannot_know_of_the_crs(tmp_path, caplog):
    caplog.set_level(logging.WARNING)
    a, b = _untagged(tmp_path / "a.las", 1), _untagged(tmp_path / "b.las", 2)
    r = CliRunner().invoke(main, ["merge", str(a), str(b), str(tmp_path / "m.las"), "--crs", "EPSG:2992"])
    assert r.exit_code == 0, r.output
    said = caplog.text + r.output
    assert "outside the area of use" in said and "used all the same" in said
    caplog.clear()
    r = CliRunner().invoke(main, ["merge", str(a), str(b), str(tmp_path / "m2.las"), "--crs", "EPSG:32633"])
    assert r.exit_code == 0, r.output
    assert "outside the area of use" not in caplog.text + r.output
    caplog.clear()
    r = CliRunner().invoke(main, ["merge", str(a), str(b), str(tmp_path / "m3.las")])
    assert r.exit_code == 0, r.output
    assert "none of the 2 strips has a CRS record" in caplog.text + r.output
