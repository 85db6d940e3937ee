"""Real reference data: ISPRS filter test (7 samples) and the AHN3 Delft crop."""

from pathlib import Path

import numpy as np
import pytest
import shapely
from scipy import ndimage
from scipy.spatial import cKDTree

from lidarctl import io, tiles
from lidarctl.classify import class_grid as cg
from lidarctl.classify import pipeline as classify
from lidarctl.checks import classes as evaluate
from lidarctl.classify import noise
from lidarctl.classify import ground

SAMPLES = ("samp11", "samp21", "samp31", "samp41", "samp51", "samp61", "samp71")


@pytest.mark.realdata
def test_isprs_mean_total_error_one_parameter_set(shared_data):
    totals = []
    for s in SAMPLES:
        c = io.read_cloud(shared_data / "isprs_filtertest" / f"{s}-utm.laz")
        code = noise.detect_noise(c.x, c.y, c.z)
        keep = code == 0
        g = np.zeros(len(c), bool)
        g[keep] = ground.ground_filter(c.x[keep], c.y[keep], c.z[keep])
        e = evaluate.filter_errors(g, c.classification == 2)
        # No true bare-earth point may be thrown away as noise.
        assert not np.any((code > 0) & (c.classification == 2)), s
        totals.append(e.total_error_pct)
    # 3.23 % with the local-surface test and the TIN angle criterion (issue 21; 3.82 % before;
    # bench/results/lidar_isprs_loo.json: 3.52 % leave-one-sample-out)
    assert np.mean(totals) <= 3.3, totals


@pytest.mark.realdata
def test_ahn3_has_no_crs_and_ground_is_found_and_buildings_cover_the_bgt_footprints(shared_data, bgt_footprints,
                                                                                     tmp_path):
    """Issue 44's measure: the building class rasterised at 0.5 m (highest return per cell) against the BGT
    footprints (an independent survey), cells within 0.5 m of an outline ignored, inside the footprints' block
    hulls, per quarter of the crop (split at the median x and y of its returns; bench/eval_buildings_bgt.py)."""
    path = shared_data / "ahn3_delft" / "ahn3_cropped_1.laz"
    with pytest.raises(io.InputError, match="no CRS"):
        io.read_cloud(path)
    out = tmp_path / "classified.laz"
    tiles.classify_file(path, out, crs="EPSG:28992")
    c = io.read_cloud(out)
    assert c.crs.to_epsg() == 28992
    ref_cls = io.read_cloud(path, crs="EPSG:28992").classification
    cls = np.asarray(c.classification)
    conf = evaluate.confusion(np.where(np.isin(cls, (2, 6)), cls, 1), ref_cls, classes=[1, 2, 6, 9, 26])
    # Ground against AHN3's classes (issue 3's target, kept): measured 98.2 / 97.4 %.
    assert conf.producers_accuracy_pct["2"] >= 95.0, conf
    assert conf.users_accuracy_pct["2"] >= 95.0, conf
    # Buildings per point against AHN3 are a reported figure since issue 44 (AHN3 calls building the see-through
    # garden structures the BGT does not map, and the pierced-growth test takes them): 92.45 / 97.25 % measured
    # (93.05 / 96.64 % before stop 117's foliage beyond a roof's reach, whose returns mostly lie outside every BGT
    # footprint; 93.2 / 96.3 % before stop 108's cut pieces; 95.5 / 95.3 % without the pierced-growth test).
    assert conf.producers_accuracy_pct["6"] >= 92.0, conf
    assert conf.users_accuracy_pct["6"] >= 97.0, conf

    polys = bgt_footprints
    grid, _ = cg.cloud_grid(out, 0.5, "EPSG:28992")
    footprints = cg.ClassPolygons(polys, np.full(len(polys), classify.BUILDING, np.uint8), None, Path("bgt"))
    ref, _ = cg.rasterize_polygons(footprints, grid)
    band = cg.rasterize_mask([shapely.union_all([p.boundary for p in polys]).buffer(0.5)], grid)
    in_blocks = cg.rasterize_mask(cg.block_hulls(footprints), grid)
    top = cg.cloud_classes(out, grid)
    empty = top == cg.IGNORE
    top = top[tuple(ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True))]
    building, footprint = top == classify.BUILDING, ref == classify.BUILDING
    xc, yc = grid.centres()
    quarter = (xc[None, :] >= np.median(c.x)).astype(int) + 2 * (yc[:, None] >= np.median(c.y)).astype(int)
    scored_quarters = 0
    for k in range(4):
        scored = in_blocks & ~band & (quarter == k)
        tp, fn, fp = (np.sum(a & b & scored) for a, b in ((building, footprint), (~building, footprint),
                                                          (building, ~footprint)))
        if tp + fn == 0:
            continue   # the south-west quarter holds no footprint
        scored_quarters += 1
        # measured (SE, NW, NE): completeness 96.6 / 95.8 / 97.1 %, correctness 97.7 / 96.3 / 95.9 %
        assert 100.0 * tp / (tp + fn) >= 95.0, (k, tp, fn, fp)
        assert 100.0 * tp / (tp + fp) >= 95.0, (k, tp, fn, fp)
    assert scored_quarters == 3


@pytest.mark.realdata
def test_single_return_crowns_are_not_roofs(shared_data):
    """laspy's Nebraska tile (single returns only, ~117 points/m2): without multi-return evidence the
    crowns' smooth top surface looked like roofs (9,394 of 10,956 high-vegetation points became
    building); the spread of a cell's returns below its highest one tells foliage from a roof."""
    c = io.read_cloud(shared_data / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las")
    assert np.all(c.number_of_returns == 1)
    cls = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
    veg = np.isin(c.classification, (3, 4, 5))
    building = cls == classify.BUILDING
    assert np.mean(building[veg]) < 0.02
    assert np.mean(c.classification[building] == 6) >= 0.95


@pytest.mark.realdata
def test_no_water_under_canopy_on_forested_hills(shared_data):
    """lidR's forested Topography: no truth-ground point with a crown return more than 2 m above it
    within 2 m becomes water (drop-out under canopy is not open water)."""
    c = io.read_cloud(shared_data / "lidr_topography" / "Topography.laz")
    cls = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
    idx = np.flatnonzero((c.classification == 2) & (cls == classify.WATER))
    near = cKDTree(np.column_stack([c.x, c.y])).query_ball_point(np.column_stack([c.x[idx], c.y[idx]]), 2.0)
    assert not any(np.max(c.z[nb]) - c.z[i] > 2.0 for nb, i in zip(near, idx))
    # The lakes' own returns are still found.
    assert np.sum((c.classification == 9) & (cls == classify.WATER)) > 100
    # Issue 44: the lakes return the pulse (no dropout); found as level water, PA and UA >= 90 %
    # (measured 95.8 / 95.2 % with level patches joined across dropout gaps, 91.7 / 95.9 % without;
    # bench/results/water.json; 5.6 / 61.5 % by the dropout rule alone).
    water, found = c.classification == 9, cls == classify.WATER
    assert np.mean(found[water]) >= 0.90
    assert np.mean(water[found]) >= 0.90
