"""The adjustment's later reads re-grid the overlap points kept in memory (overlap.regrid) instead of reading
the files again: the same planes as a read of the files with that correction, at every cell two strips share."""

from __future__ import annotations

import numpy as np
import pytest

from lidarctl.strips import adjust as adj
from lidarctl.strips import overlap as ov
from lidarctl.strips import trajectory as tj

PARAMS = ov.SurfaceSettings(max_slope_deg=60.0)


def _shared(ss: ov.StripSet) -> dict:
    """{(a, b): (common cell ids, the planes' arrays of a and b there)} of every pair of strips."""
    out = {}
    for ia, a in enumerate(ss.strips):
        for b in ss.strips[ia + 1:]:
            ids, ka, kb = np.intersect1d(a.ids, b.ids, assume_unique=True, return_indices=True)
            out[a.name, b.name] = (ids, [(s.n[k], s.centroid[k], s.grad[k], s.rms_m[k],
                                          None if s.extra is None else s.extra[k]) for s, k in ((a, ka), (b, kb))])
    return out


def _assert_same_shared_planes(got: ov.StripSet, want: ov.StripSet):
    g, w = _shared(got), _shared(want)
    assert g.keys() == w.keys()
    assert sum(len(ids) > 100 for ids, _ in w.values()) == 2  # strips 1-2 and 2-3 overlap, 1-3 do not
    for pair, (ids, planes) in w.items():
        assert np.array_equal(g[pair][0], ids), pair
        for pg, pw in zip(g[pair][1], planes):
            for x, y in zip(pg, pw):
                assert (x is None) == (y is None)
                if y is not None:
                    np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("sensor_model", [False, True], ids=["strip_model", "boresight_model"])
def test_regrid_of_kept_points_gives_the_planes_of_a_reread(shifted_block, sensor_model):
    paths = shifted_block.paths
    extra, chosen = None, {}
    if sensor_model:
        extra, chosen = adj.boresight_extra(tj.read_trajectories(shifted_block.trajectories))
    ss = ov.read_strip_planes(paths, PARAMS, extra=extra)
    if sensor_model:
        model = adj.boresight_model(ss, chosen, 0.05)
        theta = np.zeros(len(model.names))
        theta[:5] = [np.radians(0.05), np.radians(-0.03), np.radians(0.04), 0.05, 3e-3]
        theta[5:] = [0.0, -12.0, 0.1, 0.0, 0.0, 0.0, 1.0, 12.0, -0.1]  # p - e: strips 1 and 3 towards 2
    else:
        model = adj.strip_model(ss, "strip_2")
        assert [n.split(".")[0] for n in model.names[::6]] == ["strip_1", "strip_3"]  # strip 2 held fixed
        angles = [np.radians(0.05), np.radians(-0.03), np.radians(0.1)]
        theta = np.array([1.0, -12.0, 0.1, *angles, -1.0, 12.0, -0.1, *angles])  # p - e: 1 and 3 towards 2
    reach = adj._reach_m(model, theta)
    assert reach > 12.0  # metres: the overlaps grow by several cells (3.5 m)
    keep = adj.keep_region(ss, reach + adj.REACH_MARGIN_M, times=sensor_model)
    first = ov.read_strip_planes(paths, PARAMS, extra=extra, correct=model.correction(theta), grid=ss.grid, keep=keep,
                                 z_ref=ss.z_ref)
    # a later correction that moves the points by up to the margin more
    theta2 = theta * 1.05
    assert adj._reach_m(model, theta2) <= reach + adj.REACH_MARGIN_M
    want = ov.read_strip_planes(paths, PARAMS, extra=extra, correct=model.correction(theta2), grid=ss.grid,
                                z_ref=ss.z_ref)
    got = ov.regrid(first, PARAMS, extra=extra, correct=model.correction(theta2), chunk_points=7000)
    _assert_same_shared_planes(got, want)


def test_keep_region_leaves_out_what_no_overlap_can_reach(shifted_block):
    ss = ov.read_strip_planes(shifted_block.paths, PARAMS)
    keep = adj.keep_region(ss, 0.5)
    first = ov.read_strip_planes(shifted_block.paths, PARAMS, grid=ss.grid, keep=keep, z_ref=ss.z_ref)
    kept = {name: len(k.single) for name, k in first.kept.items()}
    # strips 1 and 3 (45 m either side of 2, swaths of 88 m) keep their half next to strip 2 and the margin
    # (5 cells of 3.5 m, rounded up to whole blocks of 5 cells: 17.5 to 35 m)
    assert 0.5 < kept["strip_1"] / first.strips[0].n_points < 0.9
    assert 0.5 < kept["strip_3"] / first.strips[2].n_points < 0.9
    assert kept["strip_2"] == first.strips[1].n_points


def test_dense_and_sparse_cell_sums_agree(shifted_block, monkeypatch):
    dense = ov.read_strip_planes(shifted_block.paths, PARAMS)
    monkeypatch.setattr(ov, "DENSE_CELLS_PER_POINT", -1e9)  # every chunk through np.unique and bincount
    sparse = ov.read_strip_planes(shifted_block.paths, PARAMS)
    for a, b in zip(dense.strips, sparse.strips):
        assert np.array_equal(a.ids, b.ids) and np.array_equal(a.occupied, b.occupied)
        for f in ("n", "centroid", "grad", "rms_m", "scan_angle_deg", "u_m"):
            np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-9, atol=1e-9)
