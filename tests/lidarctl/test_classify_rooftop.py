"""Rooftop objects (lidarctl.classify.pipeline.rooftop_objects): units standing on a roof are cut from it by
their step; pitched roofs, ridges and the roof itself stay building. The one-plane fit of a
segment (segment_plane_rms) that lets narrow sheds count as planar."""

import numpy as np
from lidarctl.classify import pipeline as classify


def _scan(rng, w, h, density_per_m2=10.0):
    n = int(w * h * density_per_m2)
    return rng.uniform(0, w, n), rng.uniform(0, h, n)


def test_unit_on_a_flat_roof_is_an_object_the_roof_is_not():
    rng = np.random.default_rng(1)
    x, y = _scan(rng, 20.0, 20.0)
    z = 10.0 + rng.normal(0, 0.03, len(x))
    unit = (np.abs(x - 8.0) < 1.0) & (np.abs(y - 12.0) < 1.5)      # 2 x 3 m, 1.2 m high
    z[unit] += 1.2
    hall = (x > 14.0) & (y > 14.0)                                  # a 36 m2 raised part: too large
    z[hall] += 3.0
    spacing = classify.grid.mean_spacing_m(x, y)
    obj = classify.rooftop_objects(x, y, z, np.ones(len(x), bool), spacing, 0.03, max_area_m2=20.0)
    assert obj[unit].mean() > 0.95
    assert not obj[~unit].any()
    # off below its own area
    assert not classify.rooftop_objects(x, y, z, np.ones(len(x), bool), spacing, 0.03, max_area_m2=5.0).any()


def test_gable_roof_ridge_and_eaves_are_not_objects():
    rng = np.random.default_rng(2)
    x, y = _scan(rng, 16.0, 10.0)
    pitch = np.tan(np.radians(45.0))
    z = 8.0 + pitch * (5.0 - np.abs(y - 5.0)) + rng.normal(0, 0.03, len(x))
    obj = classify.rooftop_objects(x, y, z, np.ones(len(x), bool), classify.grid.mean_spacing_m(x, y), 0.03,
                                   max_area_m2=20.0)
    assert not obj.any()


def test_classify_points_keeps_the_roof_around_a_rooftop_unit():
    rng = np.random.default_rng(3)
    x, y = _scan(rng, 40.0, 40.0)
    z = 100.0 + rng.normal(0, 0.03, len(x))
    roof = (x > 10) & (x < 30) & (y > 10) & (y < 30)
    z[roof] += 8.0
    unit = roof & (np.abs(x - 18.0) < 2.0) & (np.abs(y - 20.0) < 2.0)      # 16 m2, 1.5 m high
    z[unit] += 1.5
    ones = np.ones(len(x), np.uint8)
    cls = classify.classify_points(x, y, z, ones, ones)
    assert np.mean(cls[roof & ~unit] == classify.BUILDING) > 0.97
    assert np.mean(cls[unit] == classify.BUILDING) < 0.05


def test_segment_plane_rms_tells_a_narrow_planar_roof_from_a_crown():
    rng = np.random.default_rng(4)
    cell_m = 0.5
    rows, cols = np.mgrid[0:40, 0:40]
    surface = 100.0 + 0.3 * cols * cell_m + 0.1 * rows * cell_m      # a tilted plane
    labels = np.zeros((40, 40), int)
    labels[5:8, 5:30] = 1                                             # a shed 1.5 m wide: no 3x3 roof interior
    labels[20:30, 20:30] = 2                                          # a crown: the same plane, bumpy
    surface[20:30, 20:30] += rng.uniform(0.0, 1.0, (10, 10))
    labels[35, 35] = 3                                                # too few cells for a plane
    rms = classify.segment_plane_rms(surface, labels, 3, cell_m)
    assert rms[0] < 1e-6
    assert 0.2 < rms[1] < 0.4                                         # uniform(0, 1): sigma 0.29
    assert np.isnan(rms[2])
