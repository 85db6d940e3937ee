"""The standards as data (aerotri/qa/standards/*.toml) and their formulas: every limit carries its source and
whether it was confirmed; the formulas reproduce the numbers the standards (or pages quoting them) state,
else hand-computed cases."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from aerotri.qa.standards import STANDARD_FILES, asprs2023, cn_at, usgs_lbs
from aerotri.qa.standards import formulas as F


@pytest.mark.parametrize("read", [asprs2023, usgs_lbs, cn_at])
def test_every_limit_names_its_source_and_confirmation(read):
    d = read()
    assert d.standard.name and d.standard.document and d.standard.edition and d.standard.key in STANDARD_FILES
    if read is usgs_lbs:
        assert [lv.name for lv in d.levels] == ["QL0", "QL1", "QL2", "QL3"] and d.level(d.default_level)
        for lv in d.levels:
            assert lv.evidence, lv.name
            assert set(lv.confirmed) <= {f.name for f in dataclasses.fields(lv)} - {"name", "confirmed", "evidence"}
        return
    for f in dataclasses.fields(d.limits):
        e = getattr(d.limits, f.name)
        assert isinstance(e.confirmed, bool), f.name
        assert e.evidence and e.clause, f.name


def test_the_strip_rmsdz_from_memory_is_marked_unconfirmed():
    """The 0.08 m swath overlap limit (QL1/QL2) is quoted only by secondary sources: unconfirmed."""
    lbs = usgs_lbs()
    for ql in ("QL1", "QL2"):
        assert lbs.level(ql).interswath_rmsdz_m == 0.08
        assert "interswath_rmsdz_m" not in lbs.level(ql).confirmed


def test_cn_limits_by_terrain_and_scale():
    """Map millimetres by terrain class (GB/T 7931-2008 6.1: features 0.6 mm flat, 0.8 mm mountainous); spot
    heights only for flat and hilly ground at 1:500-1:2000."""
    L = cn_at().limits
    assert (L.feature_plan_mm.mm("flat"), L.feature_plan_mm.mm("mountainous")) == (0.6, 0.8)
    assert L.feature_plan_mm.confirmed and "1:5000" in L.feature_plan_mm_small.scales
    assert [L.spot_height_m.height_m("flat", s) for s in ("1:500", "1:1000", "1:2000", "1:5000")] == [0.4, 0.5, 0.5, None]
    assert L.spot_height_m.height_m("mountainous", "1:500") is None
    with pytest.raises(KeyError):
        usgs_lbs().level("QL9")


def test_lbs_pulse_spacing_is_the_inverse_square_root_of_the_density():
    """The table's two density columns agree (ANPS = 1 / sqrt(ANPD), to the 2 decimals the LBS gives)."""
    for lv in usgs_lbs().levels:
        assert F.anps(lv.anpd_min) == pytest.approx(lv.anps_max_m, abs=0.005), lv.name


def test_nva_95_percent_of_the_10_cm_class():
    """LBS 2020 rev. A (as quoted in the QL1 delivery's metadata): NVA 0.196 m at 95 % = RMSEz x 1.9600 for
    the 10-cm class."""
    assert F.nssda_vertical_95(0.10) == pytest.approx(0.196, abs=1e-12)


def test_radial_rmse_and_checkpoint_accuracy_hand_cases():
    assert F.rmse_h(0.03, 0.04) == pytest.approx(0.05)
    assert F.rmse([0.1, -0.1, 0.1, -0.1]) == pytest.approx(0.1)
    assert F.rmse_h_of_points([0.3, -0.3], [0.4, -0.4]) == pytest.approx(0.5)
    # product RMSE_V 10 cm measured against check points of 2 cm: sqrt(10^2 + 2^2) = 10.198 cm
    assert F.with_checkpoint_accuracy(0.10, 0.02) == pytest.approx(math.sqrt(0.0104))
    assert F.with_checkpoint_accuracy(0.10, None) == 0.10
    assert F.checkpoint_rmse_h(0.01) == pytest.approx(0.014142, abs=1e-6)
    # check points twice as accurate as a 10-cm class: RMSE <= 5 cm
    assert F.checkpoints_accurate_enough(0.05, 0.10, 2.0) is True
    assert F.checkpoints_accurate_enough(0.051, 0.10, 2.0) is False
    assert F.checkpoints_accurate_enough(None, 0.10, 2.0) is None


def test_vva_percentile_and_map_limits_hand_cases():
    dz = np.concatenate([np.arange(1, 20) / 100.0, [-1.0]])  # 0.01 .. 0.19 m and one 1 m miss
    # 95th percentile of |dz| by linear interpolation: rank 0.95 * 19 = 18.05 between 0.19 and 1.0
    assert F.vva_p95(dz) == pytest.approx(0.19 + 0.05 * (1.0 - 0.19))
    assert F.map_mm_to_ground_m(0.35, "1:5000") == pytest.approx(1.75)
    assert F.map_mm_to_ground_m(0.6, "1:500") == pytest.approx(0.30)
    assert F.scale_denominator("1:10000") == 10000
    with pytest.raises(ValueError):
        F.scale_denominator("5000")
    assert F.finest_class(0.071, [0.05, 0.071, 0.10]) == 0.071
    assert F.finest_class(0.072, [0.05, 0.071, 0.10]) == 0.10
    assert F.finest_class(0.2, [0.05, 0.10]) is None
    assert F.anpd(8000, 1000.0) == 8.0
