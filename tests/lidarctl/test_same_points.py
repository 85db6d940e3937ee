"""A strip given twice under other bytes (re-exported as LAZ with another point source id): trial s99 lidmut H5, merged
with 84,890 points twice and checked against its original at RMS 0.000 m, exit 0. Refused by every command that takes
several strips, naming both files; strips with the same count and extent but other points are not."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import CRS

from lidarctl.cli.main import main


def _strip(path, seed: int, *, source_id: int | None = None, dz_m: float = 0.0, shuffle_z: bool = False):
    """2,000 points of format 6 on 100 x 100 m (UTM 33N), GPS times; the same ``seed`` gives the same points."""
    rng = np.random.default_rng(seed)
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = [0.001] * 3, [500_000.0, 5_000_000.0, 0.0]
    h.add_crs(CRS.from_epsg(32633))
    data = laspy.LasData(h)
    n = 2000
    data.x, data.y = 500_000 + rng.uniform(0, 100, n), 5_000_000 + rng.uniform(0, 100, n)
    z = rng.uniform(0, 10, n) + dz_m
    if shuffle_z:  # other points inside the same extent
        z = z[::-1].copy()
    data.z = z
    data.gps_time = 1000.0 + np.arange(n) * 1e-4
    data.classification = np.full(n, 2, np.uint8)
    data.return_number, data.number_of_returns = np.ones(n, np.uint8), np.ones(n, np.uint8)
    data.point_source_id = np.full(n, seed if source_id is None else source_id, np.uint16)
    data.write(path)
    return path


@pytest.mark.parametrize("command", ["merge", "strips check"])
def test_a_strip_re_exported_under_another_name_is_refused(tmp_path, command):
    a = _strip(tmp_path / "strip_01.las", 1)
    b = _strip(tmp_path / "strip_02.las", 2)
    copy = _strip(tmp_path / "strip_01_reexport.laz", 1, source_id=99)
    out = tmp_path / ("m.las" if command == "merge" else "check")
    r = CliRunner().invoke(main, [*command.split(), str(a), str(b), str(copy), str(out)])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"{copy}: holds the same points as {a} (2,000 points, the same extent" in r.output, r.output
    assert not out.exists()


def test_strips_of_the_same_count_and_extent_but_other_points_are_merged(tmp_path):
    a = _strip(tmp_path / "a.las", 1)
    other = _strip(tmp_path / "b.las", 1, source_id=7, shuffle_z=True)
    r = CliRunner().invoke(main, ["merge", str(a), str(other), str(tmp_path / "m.las")])
    assert r.exit_code == 0, r.output
    assert len(laspy.read(tmp_path / "m.las").points) == 4000
