"""Building rule of lidarctl.classify.pipeline: penetration evidence keeps tree crowns out of the roofs."""

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from lidarctl.classify import pipeline as classify


def _sloped_ground(rng, width_m: float, depth_m: float, density_per_m2: float, base_m: float, slope: float):
    """Returns uniformly over a ``width_m`` x ``depth_m`` plot rising ``slope`` along u from ``base_m`` (3 cm range
    noise): u, v, ground z, and z and truth class (2) to build the scene's objects on."""
    n = int(width_m * depth_m * density_per_m2)
    u, v = rng.uniform(0, width_m, n), rng.uniform(0, depth_m, n)
    ground_z = base_m + slope * u + rng.normal(0, 0.03, n)
    return u, v, ground_z, ground_z.copy(), np.full(n, 2, np.uint8)


def _roof_and_crown(seed: int, density_per_m2: float = 10.0, canopy_gap: float = 0.35):
    """A flat 18 x 16 m roof 8 m high and, 6 m beside it, a dome-shaped crown (radius 8 m, base
    6 m, top 10 m above the ground; first returns at the simulator's depth into the crown) that
    passes ``canopy_gap`` of its pulses to the ground as a second return. Returns x, y, z,
    return number, number of returns, truth class (2 ground, 5 high vegetation, 6 building)."""
    rng = np.random.default_rng(seed)
    u, v, ground_z, z, truth = _sloped_ground(rng, 60.0, 40.0, density_per_m2, 100.0, 0.02)
    n = len(u)
    roof = (u > 6) & (u < 24) & (v > 10) & (v < 26)
    z[roof] = 108.0 + rng.normal(0, 0.03, roof.sum())
    truth[roof] = 6
    d2 = ((u - 40.0) ** 2 + (v - 18.0) ** 2) / 8.0 ** 2
    crown = d2 < 1.0
    z[crown] = ground_z[crown] + 6.0 + 4.0 * np.sqrt(1.0 - d2[crown]) * rng.uniform(0.6, 1.0, crown.sum())
    truth[crown] = 5
    through = crown & (rng.random(n) < canopy_gap)
    k = int(through.sum())
    returns = np.where(through, 2, 1).astype(np.uint8)
    return (np.r_[u, u[through]] + 500000.0, np.r_[v, v[through]] + 5400000.0, np.r_[z, ground_z[through]],
            np.r_[np.ones(n, np.uint8), np.full(k, 2, np.uint8)], np.r_[returns, np.full(k, 2, np.uint8)],
            np.r_[truth, np.full(k, 2, np.uint8)])


def test_multi_return_crown_beside_a_roof_stays_vegetation():
    # With the roof knobs chosen on AHN3 (plane RMS 0.25 m, 10 m2), a cell-by-cell multi-return
    # test let this crown's cells without a multi-return point (18 % of 4-return cells at a 35 %
    # gap) make up a roof: the whole crown became building.
    x, y, z, rn, nr, truth = _roof_and_crown(seed=0)
    cls = classify.classify_points(x, y, z, rn, nr, np.full(len(x), 300, np.uint16))
    assert np.mean(cls[truth == 6] == classify.BUILDING) > 0.99
    assert np.mean(cls[truth == 5] == classify.BUILDING) < 0.01
    # the rest is 1: smooth cells without a multi-return point (the vegetation rule, unchanged)
    assert np.mean(cls[truth == 5] == classify.HIGH_VEG) > 0.8


def _wilson_upper(k, n, z=1.645):
    f = k / n
    return (f + z * z / (2 * n) + z * np.sqrt(f * (1 - f) / n + z * z / (4 * n * n))) / (1 + z * z / n)


def test_fewer_multi_returns_is_the_wilson_bound_below_the_fraction():
    for n in (4, 7, 12, 36, 100):
        k = np.arange(0, n + 1)
        shown = classify.fewer_multi_returns(k, np.full(n + 1, n), 0.3)
        assert np.array_equal(shown, _wilson_upper(k, n) <= 0.3)
    # a roof window of 36 returns without a multi-return point shows it; a crown's 35 % does not,
    # nor does one cell of 4 returns without any, nor an empty window
    assert classify.fewer_multi_returns(np.array([0, 13]), np.array([36, 36]), 0.3).tolist() == [True, False]
    assert not classify.fewer_multi_returns(np.array([0]), np.array([4]), 0.3)[0]
    assert not classify.fewer_multi_returns(np.array([0]), np.array([0]), 0.3)[0]


def _closed_conifer_canopy(seed: int, density_per_m2: float = 10.0, canopy_gap: float = 0.15):
    """A gable house (10 x 12 m, 30 deg facets, eaves 6 m up) and a flat garage (5 x 5 m, 3 m) in the open, and beside
    them a closed conifer stand on a jittered 3 m grid (cones of 2.2-3 m radius rising 2.5 m per m to 12-18 m, 0.3 m
    of branch roughness; ``canopy_gap`` of the pulses split to the ground), on a 5 % slope. Returns x, y, z, return
    number, number of returns, truth class (2 ground, 5 crown, 6 building)."""
    rng = np.random.default_rng(seed)
    u, v, ground_z, z, truth = _sloped_ground(rng, 120.0, 80.0, density_per_m2, 300.0, 0.05)
    n = len(u)
    cu, cv = (a.ravel() for a in np.meshgrid(np.arange(41.5, 120.0, 3.0), np.arange(1.5, 80.0, 3.0)))
    cu, cv = cu + rng.uniform(-0.6, 0.6, cu.size), cv + rng.uniform(-0.6, 0.6, cv.size)
    radius, top = rng.uniform(2.2, 3.0, cu.size), rng.uniform(12.0, 18.0, cu.size)
    dist, near = cKDTree(np.column_stack([cu, cv])).query(np.column_stack([u, v]), k=4)
    surface = np.where(dist < radius[near], top[near] - 2.5 * dist, -np.inf).max(axis=1) + rng.normal(0, 0.3, n)
    crown = np.isfinite(surface)
    z[crown] = ground_z[crown] + surface[crown]
    truth[crown] = 5
    house = (u > 8) & (u < 20) & (v > 20) & (v < 30)
    z[house] = ground_z[house] + 6.0 + np.tan(np.radians(30.0)) * (5.0 - np.abs(v[house] - 25.0))
    garage = (u > 25) & (u < 30) & (v > 50) & (v < 55)
    z[garage] = ground_z[garage] + 3.0 + rng.normal(0, 0.02, garage.sum())
    truth[house | garage] = 6
    through = crown & (rng.random(n) < canopy_gap)
    k = int(through.sum())
    return (np.r_[u, u[through]] + 885000.0, np.r_[v, v[through]] + 629000.0, np.r_[z, ground_z[through]],
            np.r_[np.ones(n, np.uint8), np.full(k, 2, np.uint8)],
            np.r_[np.where(through, 2, 1).astype(np.uint8), np.full(k, 2, np.uint8)],
            np.r_[truth, np.full(k, 2, np.uint8)])


def test_a_closed_conifer_canopy_is_no_building_by_its_chance_plane_fits():
    # lasR's BC Timber Sales forest tiles (classes 1/2, no building): a closed stand's crown surface fits a local plane
    # in scattered cells, whose sum over the whole stand's segment passed building_min_area_m2 (bcts_2: 246,848 of
    # 823,945 returns called building). Roof area counts only in planar patches of roof_min_patch_m2.
    x, y, z, rn, nr, truth = _closed_conifer_canopy(seed=0)
    intensity = np.full(len(x), 300, np.uint16)
    cls = classify.classify_points(x, y, z, rn, nr, intensity)
    assert np.mean(cls[truth == 5] == classify.BUILDING) < 0.01
    assert np.mean(cls[truth == 6] == classify.BUILDING) > 0.99
    every_cell = dataclasses.replace(classify.ClassifySettings(), roof_min_patch_m2=0.0)
    before = classify.classify_points(x, y, z, rn, nr, intensity, params=every_cell)
    assert np.mean(before[truth == 5] == classify.BUILDING) > 0.5


def test_roof_patches_keep_the_connected_planes_of_at_least_the_area():
    roof = np.zeros((12, 12), bool)
    roof[1:6, 1:6] = True          # 25 cells: 6.25 m2 at 0.5 m
    roof[8, 8] = roof[9, 9] = True  # two cells touching at a corner: 0.5 m2
    roof[8, 1:4] = True             # 0.75 m2
    kept = classify.roof_patches(roof, 0.5, 6.0)
    assert kept.sum() == 25 and kept[1:6, 1:6].all()
    assert classify.roof_patches(roof, 0.5, 0.5).sum() == 25 + 2 + 3
    assert classify.roof_patches(roof, 0.5, 0.6).sum() == 25 + 3
    assert np.array_equal(classify.roof_patches(roof, 0.5, 0.0), roof)


def _ground_and_roof(rng, width_m: float, density_per_m2: float):
    """``_sloped_ground`` of ``width_m`` x 40 m (1 % slope) with a flat 18 x 16 m roof 8 m above it (u 6-24 m, v 12-28
    m): u, v, ground z, z, truth class and the roof's mask."""
    u, v, ground_z, z, truth = _sloped_ground(rng, width_m, 40.0, density_per_m2, 50.0, 0.01)
    roof = (u > 6) & (u < 24) & (v > 12) & (v < 28)
    z[roof] = ground_z[roof] + 8.0 + rng.normal(0, 0.03, roof.sum())
    truth[roof] = 6
    return u, v, ground_z, z, truth, roof


def _roof_hedge_crown(seed: int, density_per_m2: float = 10.0):
    """A flat 18 x 16 m roof 8 m high; along its east eave a 3 m wide hedge 6 m high that passes 40 % of its pulses to
    the ground; beyond it a dense broadleaf crown (dome of radius 7 m, base 5 m, top 11 m, rough) whose split pulses
    (40 %) end inside the crown, none on the ground. Returns x, y, z, return number, number of returns, truth class
    (2 ground, 5 crown or hedge, 6 building)."""
    rng = np.random.default_rng(seed)
    u, v, ground_z, z, truth, roof = _ground_and_roof(rng, 70.0, density_per_m2)
    n = len(u)
    hedge = (u >= 24) & (u < 27) & (v > 16) & (v < 24)
    z[hedge] = ground_z[hedge] + 6.0 - rng.uniform(0.0, 1.0, hedge.sum())
    d2 = ((u - 33.5) ** 2 + (v - 20.0) ** 2) / 7.0 ** 2
    crown = (d2 < 1.0) & ~roof & ~hedge
    z[crown] = ground_z[crown] + 5.0 + 6.0 * np.sqrt(1.0 - d2[crown]) * rng.uniform(0.8, 1.0, crown.sum())
    truth[hedge | crown] = 5
    split = (hedge | crown) & (rng.random(n) < 0.4)
    k = int(split.sum())
    # a hedge's split pulse ends on the ground; a dense crown's on a lower layer of leaves
    second = np.where(hedge[split], ground_z[split], z[split] - rng.uniform(1.0, 3.0, k))
    return (np.r_[u, u[split]] + 770000.0, np.r_[v, v[split]] + 6277000.0, np.r_[z, second],
            np.r_[np.ones(n, np.uint8), np.full(k, 2, np.uint8)],
            np.r_[np.where(split, 2, 1).astype(np.uint8), np.full(k, 2, np.uint8)],
            np.r_[truth, np.where(hedge[split], 2, 5).astype(np.uint8)])


def _building_shares(scene, part, **without):
    """The shares of the returns ``part`` and of the roof (truth 6) of ``scene`` (x, y, z, return number, number of
    returns, truth) called building with the shipped settings, then with the settings ``without`` a rule."""
    x, y, z, rn, nr, truth = scene
    intensity = np.full(len(x), 300, np.uint16)
    out = []
    for p in (classify.ClassifySettings(), dataclasses.replace(classify.ClassifySettings(), **without)):
        cls = classify.classify_points(x, y, z, rn, nr, intensity, params=p)
        out.append((np.mean(cls[part] == classify.BUILDING), np.mean(cls[truth == 6] == classify.BUILDING)))
    return out


def test_a_crown_cut_off_from_the_roof_by_pierced_growth_leaves_the_building():
    # IGN LiDAR HD Montpellier (leaf-on street and courtyard crowns): a crown touching a roof through a hedge joins the
    # roof's segment; pierced growth takes the hedge (its pulses reach the ground) but left the dense crown beyond it,
    # cut off from every roof, with the segment's building verdict. Each piece left is judged again.
    scene = _roof_hedge_crown(seed=0)
    x, y, truth = scene[0], scene[1], scene[5]
    crown = (truth == 5) & (np.hypot(x - 770033.5, y - 6277020.0) < 6.0) & (x > 770028.0)
    (crown_with, roof_with), (crown_without, roof_without) = _building_shares(scene, crown, cut_pieces_judged=False)
    assert crown_with < 0.01 and roof_with > 0.99
    assert crown_without > 0.5 and roof_without > 0.99


def test_cut_pieces_keep_roofs_and_single_return_fragments():
    p = classify.ClassifySettings()   # building_min_area_m2 10, roof_min_patch_m2 6, small-building share 0.2
    cells = np.zeros((30, 40), bool)
    roof = np.zeros_like(cells)
    multi = np.zeros(cells.shape)
    cells[2:12, 2:12] = roof[3:11, 3:11] = True       # a roof: 64 roof cells, 16 m2 at 0.5 m
    cells[2:12, 15:25] = True                         # a crown cut off: no roof cell, half its returns split
    multi[2:12, 15:25] = 0.5
    roof[4:7, 16:19] = True                           # with a chance patch of 9 cells (2.25 m2)
    cells[15:18, 2:5] = True                          # a shed's fragment: single returns, no roof cell
    cells[15:25, 15:25] = roof[15:25, 15:25] = True   # a second roof, 25 m2, among split returns
    multi[15:25, 15:25] = 0.5
    cells[20:23, 30:33] = True                        # a small building judged whole (kept whatever its piece)
    multi[20:23, 30:33] = 0.5
    keep = np.zeros_like(cells)
    keep[20:23, 30:33] = True
    left = classify.cut_pieces(cells, keep, roof, multi, 0.5, p)
    assert not left[2:12, 15:25].any()
    expected = cells.copy()
    expected[2:12, 15:25] = False
    assert np.array_equal(left, expected)


def _roof_and_touching_crown(seed: int, density_per_m2: float = 40.0):
    """A flat 18 x 16 m roof 8 m high and a dense broadleaf crown against its east eave (a dome of radius 7 m, base
    5 m, top 11 m, rough by its leaf clusters) whose split pulses (40 %) end on lower leaves inside it, none on the
    ground; IGN LiDAR HD's density. Returns x, y, z, return number, number of returns, truth class (2 ground, 5 crown,
    6 building)."""
    rng = np.random.default_rng(seed)
    u, v, ground_z, z, truth, roof = _ground_and_roof(rng, 60.0, density_per_m2)
    n = len(u)
    d2 = ((u - 31.0) ** 2 + (v - 20.0) ** 2) / 7.0 ** 2
    crown = (d2 < 1.0) & ~roof
    # leaf clusters of about a metre: the crown's top is rough at that scale (+- 0.6 m), each return within its cluster
    clusters = rng.normal(0.0, 0.6, (41, 61))[v.astype(int), u.astype(int)]
    z[crown] = (ground_z[crown] + 5.0 + 6.0 * np.sqrt(1.0 - d2[crown]) + clusters[crown]
                - rng.uniform(0.0, 0.5, crown.sum()))
    truth[crown] = 5
    split = crown & (rng.random(n) < 0.4)
    k = int(split.sum())
    return (np.r_[u, u[split]] + 770000.0, np.r_[v, v[split]] + 6277000.0,
            np.r_[z, z[split] - rng.uniform(1.0, 3.0, k)], np.r_[np.ones(n, np.uint8), np.full(k, 2, np.uint8)],
            np.r_[np.where(split, 2, 1).astype(np.uint8), np.full(k, 2, np.uint8)],
            np.r_[truth, np.full(k, 5, np.uint8)])


def test_a_dense_crown_grown_into_from_a_roof_leaves_the_building_by_its_foliage():
    # IGN LiDAR HD Isère (leaf-on broadleaf crowns against houses): the crown joins the roof's segment by growth, and
    # its pulses end on its own leaves, not on the ground, so pierced growth does not take it. Beyond 2 cells of a
    # roof cell, a grown region that splits the pulses, is rough and holds its returns deep below its top is foliage.
    scene = _roof_and_touching_crown(seed=0)
    beyond_eave = (scene[5] == 5) & (scene[0] > 770025.5)   # more than 1.5 m (3 cells) from the eave
    (crown_with, roof_with), (crown_without, roof_without) = _building_shares(scene, beyond_eave,
                                                                              foliage_beyond_roof_reach=False)
    assert crown_with < 0.02 and roof_with > 0.99
    assert crown_without > 0.9 and roof_without > 0.99
