"""``lidarctl merge`` of LAS 1.4 strips whose CRS is held in an extended VLR (EVLR) alone: the merged file had no
CRS (laspy's writer writes no EVLRs unless asked; merge_las copied the VLRs only). Now the first strip's EVLRs
are kept (a CRS among them), strips whose EVLR CRSs differ are refused as with VLRs, and ``--crs`` states the
project CRS instead of theirs. Files made with laspy."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from laspy.vlrs.known import WktCoordinateSystemVlr
from laspy.vlrs.vlrlist import VLRList
from pyproj import CRS

from lidarctl.cli.main import main


def _strip(path, epsg: int, x0_m: float, seed: int, extra: bool = False):
    """1,000 points of format 6 (LAS 1.4) on 100 x 100 m, the CRS (WKT) in an EVLR alone."""
    rng = np.random.default_rng(seed)
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = [0.01] * 3, [x0_m, 5_000_000.0, 0.0]
    data = laspy.LasData(h)
    n = 1000
    data.x, data.y = x0_m + rng.uniform(0, 100, n), 5_000_000 + rng.uniform(0, 100, n)
    data.z = rng.uniform(0, 10, n)
    data.point_source_id = np.full(n, seed, np.uint16)
    evlrs = [WktCoordinateSystemVlr(CRS.from_epsg(epsg).to_wkt())]
    if extra:
        evlrs.append(laspy.VLR("ProducerX", 7, "a producer's own record", b"\x01\x02\x03"))
    data.evlrs = VLRList(evlrs)
    data.write(path)
    return path


def _merge(*args):
    return CliRunner().invoke(main, ["merge", *map(str, args)])


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_a_crs_held_in_an_evlr_alone_is_kept_by_merge(tmp_path, suffix):
    a = _strip(tmp_path / "a.las", 32633, 500_000.0, 1, extra=True)
    b = _strip(tmp_path / "b.las", 32633, 500_100.0, 2)
    assert not laspy.read(a).header.vlrs and laspy.read(a).header.parse_crs().to_epsg() == 32633
    out = tmp_path / f"m{suffix}"
    r = _merge(a, b, out)
    assert r.exit_code == 0, r.output
    m = laspy.read(out)
    assert len(m.points) == 2000 and set(np.unique(m.point_source_id)) == {1, 2}
    assert m.header.parse_crs().to_epsg() == 32633
    assert [(v.user_id, v.record_id) for v in m.header.evlrs] == [("LASF_Projection", 2112), ("ProducerX", 7)]
    assert m.header.evlrs[1].record_data == b"\x01\x02\x03"


def test_strips_whose_evlr_crss_differ_are_refused_and_crs_replaces_theirs(tmp_path):
    a = _strip(tmp_path / "a.las", 32633, 500_000.0, 1)
    c = _strip(tmp_path / "c.las", 32632, 500_100.0, 3)
    r = _merge(a, c, tmp_path / "m.las")
    assert r.exit_code == 2 and "c.las" in r.output and "EPSG:32632" in r.output and "EPSG:32633" in r.output, r.output
    assert not (tmp_path / "m.las").exists()
    # --crs: the project CRS stated once (a VLR), no EVLR CRS beside it
    r = _merge(a, _strip(tmp_path / "b.las", 32633, 500_100.0, 2), tmp_path / "p.las", "--crs", "EPSG:32633")
    assert r.exit_code == 0, r.output
    m = laspy.read(tmp_path / "p.las")
    assert m.header.parse_crs().to_epsg() == 32633 and not [v for v in m.header.evlrs if v.user_id == "LASF_Projection"]
