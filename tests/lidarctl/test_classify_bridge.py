"""Bridge decks (lidarctl.classify.pipeline.bridge_decks): ground between two water gaps along a watercourse,
standing clear above the quays, leaves the ground class (-> 17, bridge deck).

The scene (200 x 100 m, 3 returns/m2, 2 cm range noise, quays and streets at 0 m): canal A along u
(v 40-55 m, no returns: calm water gives none) crossed by a 10 m wide road whose deck stands 1.2 m
above the quays, ramping down over 15 m on both sides; canal C parallel to A (v 70-80 m, u < 60 m),
the raised strip between them (v 55-70 m, 1 m high) lies across both canals' axes: not a bridge.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarctl.classify import pipeline as classify

X0, Y0 = 85000.0, 447000.0


def bridge_scene():
    rng = np.random.default_rng(5)
    n = 200 * 100 * 3
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    canal_a = (v > 40) & (v < 55)
    canal_c = (v > 70) & (v < 80) & (u < 60)
    road = (u > 90) & (u < 100)
    deck = road & canal_a
    keep = ~((canal_a & ~road) | canal_c)
    z = rng.normal(0, 0.02, n)
    ramp = np.clip(1.0 - np.maximum(25.0 - v, v - 70.0) / 15.0, 0.0, 1.0)   # 1 on 25 < v < 70
    z += np.where(road, 1.2 * np.where(canal_a, 1.0, np.where((v > 25) & (v < 70), ramp, 0.0)), 0.0)
    strip = (v > 55) & (v < 70) & (u < 60)
    z += 1.0 * strip
    u, v, z, deck, strip = u[keep], v[keep], z[keep], deck[keep], strip[keep]
    return u + X0, v + Y0, z, deck, strip


def test_deck_between_two_gaps_along_the_canal_is_a_bridge_the_strip_between_canals_is_not():
    x, y, z, deck, strip = bridge_scene()
    ground = np.ones(len(x), bool)
    spacing = 1 / np.sqrt(3.0)
    p = classify.ClassifySettings()
    found = classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), spacing, p=p)
    assert found[deck].mean() > 0.9
    # nothing else: not the ramps, not the quays along the canals, not the raised strip between
    # the two parallel canals (water on both sides, 15 m apart, but across their axes)
    assert not found[~deck].any()
    # only ground points are judged; 0 disables the rule
    half = np.arange(len(x)) % 2 == 0
    assert not classify.bridge_decks(x, y, z, half, np.zeros(len(x), bool), spacing, p=p)[~half].any()
    off = classify.ClassifySettings(bridge_max_width_m=0.0)
    assert not classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), spacing, p=off).any()
    # a deck at quay level (a dam between two basins) is not a bridge
    flat = np.where(deck, z - 1.2, z)
    assert not classify.bridge_decks(x, y, flat, ground, np.zeros(len(x), bool), spacing, p=p)[deck].any()
    # a ridge of land across the water (an isthmus: its crest 1.2 m up, its sides sloping into the water
    # on both sides) clears the quays only along its crest: not a level deck
    crest = np.where(deck, z - 1.2 + 1.2 * np.clip(1.0 - np.abs(x - X0 - 95.0) / 5.0, 0.0, 1.0), z)
    assert not classify.bridge_decks(x, y, crest, ground, np.zeros(len(x), bool), spacing, p=p).any()


def test_classification_labels_the_deck_17_and_keeps_the_quays_ground():
    x, y, z, deck, strip = bridge_scene()
    cls = classify.classify_points(x, y, z)
    assert np.mean(cls[deck] == classify.BRIDGE_DECK) > 0.9
    assert np.mean(cls[~deck & ~strip] == classify.GROUND) > 0.98
    assert not np.any(cls[~deck] == classify.BRIDGE_DECK)


def test_a_cloud_narrower_than_the_deck_search_is_classified():
    """The deck search looks for water up to ``bridge_max_width_m`` (18 water cells here) along each direction; a
    cloud fewer cells across than that raised ValueError (a helper's 18 m crop of a river, stop 118): the canal
    scene cut 2 m beyond the canal's banks (17 cells across), and a 15 x 30 m field with a 7 m dropout gap, through
    ``classify_points``."""
    x, y, z, deck, _ = bridge_scene()
    band = (y - Y0 > 38) & (y - Y0 < 57)
    ground = np.ones(int(band.sum()), bool)
    found = classify.bridge_decks(x[band], y[band], z[band], ground, ~ground, 1 / np.sqrt(3.0),
                                  p=classify.ClassifySettings())
    assert not found[~deck[band]].any()
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, 15, 3600), rng.uniform(0, 30, 3600)
    out = (np.abs(u - 7.5) < 3.5) & (np.abs(v - 15) < 3.5)
    u, v = u[~out] + X0, v[~out] + Y0
    cls = classify.classify_points(u, v, rng.normal(0, 0.02, len(u)), np.ones(len(u), int), np.ones(len(u), int),
                                   np.full(len(u), 100))
    assert np.all(cls == classify.GROUND)


def footbridge_scene(seed=3):
    """A footbridge the ground filter leaves out (Autzen's case): a river along u (v 40-70 m) 5 m below the
    banks, its surface giving a few returns (5 % of the land's density), the banks sloping into it; a 5 m wide
    deck across it along v, arching from 0.3 m at the banks to 3 m mid-span, with sparse railing returns 1 m
    above its edges. Beside it, what must stay building: a house (20 x 10 m, roof 6 m), a long shed on the
    south bank along the river (4 x 25 m, roof 3 m: water on one side only) and a narrow building between
    two ponds (16 x 4 m, roof 4 m: water on both sides, but it ends in walls)."""
    rng = np.random.default_rng(seed)
    n = 200 * 120 * 4
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 120, n)
    z = rng.normal(0, 0.02, n)
    river = (v > 40) & (v < 70)
    deck = (np.abs(u - 100) < 2.5) & (v > 35) & (v < 75)
    house = (u > 20) & (u < 40) & (v > 10) & (v < 20)
    shed = (u > 130) & (u < 155) & (v > 33) & (v < 37)
    ponds = (u > 60) & (u < 80) & (((v > 85) & (v < 95)) | ((v > 99) & (v < 109)))
    between = (u > 62) & (u < 78) & (v >= 95) & (v <= 99)
    d_bank = np.minimum(np.abs(v - 40), np.abs(v - 70))
    z = np.where(river, -5.0 + rng.normal(0, 0.03, n), z - np.where(d_bank < 5, 5.0 * (1 - d_bank / 5), 0.0))
    water = river & (rng.uniform(size=n) < 0.05)
    z = np.where(deck, 0.3 + 2.7 * np.sin(np.pi * np.clip((v - 35) / 40, 0, 1)) + rng.normal(0, 0.02, n), z)
    for m, h in ((house, 6.0), (shed, 3.0), (between, 4.0)):
        z = np.where(m, h + rng.normal(0, 0.02, n), z)
    z += np.where(deck & (np.abs(u - 100) > 2.3) & (np.arange(n) % 4 == 0), 1.0, 0.0)
    keep = ~((river & ~deck & ~water) | (ponds & ~between))
    lab = np.select([deck, house, shed, between], [1, 2, 3, 4], 0)[keep]
    return u[keep] + X0, v[keep] + Y0, z[keep], lab


def test_footbridge_left_out_by_the_ground_filter_is_a_deck_not_a_building():
    x, y, z, lab = footbridge_scene()
    cls = classify.classify_points(x, y, z)
    deck = lab == 1
    high = deck & (z > 1.5)   # where the deck stands a building's height above the water's banks
    assert not np.any(cls[deck] == classify.BUILDING)
    assert np.mean(cls[high] == classify.BRIDGE_DECK) > 0.9
    for k in (2, 3, 4):   # the house, the shed along the bank, the building between the ponds
        assert np.mean(cls[lab == k] == classify.BUILDING) > 0.95, k
    # the rule alone: without it the deck is a building (the roof rules take it), with it the others stay
    p = classify.ClassifySettings()
    spacing = classify.grid.mean_spacing_m(x, y)
    as_built = np.where(cls == classify.BRIDGE_DECK, classify.BUILDING, cls)
    g = classify.dropout_grid(x, y, as_built == classify.BUILDING, spacing, p)
    found = classify.spanning_decks(x, y, z, as_built == classify.BUILDING, as_built == classify.GROUND, g, p=p)
    assert found[high].mean() > 0.9 and not found[lab > 1].any()
    off = classify.ClassifySettings(bridge_max_width_m=0.0)
    assert not classify.spanning_decks(x, y, z, as_built == classify.BUILDING, as_built == classify.GROUND, g,
                                       p=off).any()


def test_a_deck_beside_water_that_returned_the_pulse_is_a_deck():
    """Trial-us (A): the footbridge scene's river, upstream of the deck calm and returning 60 % of the pulses (its
    returns level water, class 9), downstream 5 % (a dropout gap). The deck spans water on both sides: water that
    returned the pulse counts beside it as a dropout gap does (was: gap on one side only, under half the deck over
    water: all of it building; Autzen in UTM 10N lost its footbridge so)."""
    rng = np.random.default_rng(3)
    n = 200 * 120 * 4
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 120, n)
    z = rng.normal(0, 0.02, n)
    river = (v > 40) & (v < 70)
    deck = (np.abs(u - 100) < 2.5) & (v > 35) & (v < 75)
    d_bank = np.minimum(np.abs(v - 40), np.abs(v - 70))
    z = np.where(river, -5.0 + rng.normal(0, 0.01, n), z - np.where(d_bank < 5, 5.0 * (1 - d_bank / 5), 0.0))
    water = river & ~deck & (rng.uniform(size=n) < np.where(u > 102.5, 0.6, 0.05))
    z = np.where(deck, 0.3 + 2.7 * np.sin(np.pi * np.clip((v - 35) / 40, 0, 1)) + rng.normal(0, 0.02, n), z)
    z += np.where(deck & (np.abs(u - 100) > 2.3) & (np.arange(n) % 4 == 0), 1.0, 0.0)
    keep = ~(river & ~deck & ~water)
    x, y, z, deck, water = u[keep] + X0, v[keep] + Y0, z[keep], deck[keep], water[keep]
    cls = classify.classify_points(x, y, z)
    assert np.mean(cls[water] == classify.WATER) > 0.95
    high = deck & (z > 1.5)
    assert np.mean(cls[high] == classify.BRIDGE_DECK) > 0.9 and not np.any(cls[deck] == classify.BUILDING)


@pytest.mark.realdata
def test_autzen_footbridge_is_not_a_building(shared_data):
    """The footbridge over the Willamette in the Autzen crop (feet; seen on its 1 ft orthophoto running NNE
    from the path's loop across the river): its 1,303 deck returns were a building; now bridge deck, and
    the crop holds no building left (it has none)."""
    from lidarctl import io

    r = io.read_cloud(shared_data / "autzen" / "autzen_trim.laz")
    cls = classify.classify_points(r.x, r.y, r.z, r.return_number, r.number_of_returns, r.intensity)
    ft = 0.3048
    # the deck's axis on the orthophoto: (636440, 849240) ft to (636525, 849445) ft
    p0, p1 = np.array([636440.0, 849240.0]) * ft, np.array([636525.0, 849445.0]) * ft
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    d = np.column_stack([r.x, r.y]) - p0
    along, across = d @ u, d @ np.array([-u[1], u[0]])
    corridor = (np.abs(across) < 4.0) & (along > 0) & (along < np.linalg.norm(p1 - p0))
    assert np.sum(cls == classify.BUILDING) == 0
    assert np.sum(cls[corridor] == classify.BRIDGE_DECK) > 1000


def ragged_edge_scene(seed=7):
    """The demo's false decks (190 ground returns, i44-bridge): the ragged edge of a survey's coverage. A field
    (200 x 100 m, 3 returns/m2) rising 2 m per 100 m along u, covered for v < 80 m and, by a cross strip, for
    u > 170 m; the corner beyond (u < 170, v > 80: no returns, a long dropout gap along u) reaches into the
    last covered metres in teeth (2.5 m wide, every 12 m, down to v = 77.5 m). The ground between two teeth has
    the same gap on both sides along u, less than ``bridge_max_width_m`` apart, and stands above the gap's
    bank (the median of its rim): the old rule took it for decks."""
    rng = np.random.default_rng(seed)
    n = 200 * 100 * 3
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    z = 0.02 * u + rng.normal(0, 0.02, n)
    tooth = (v > 77.5) & (np.mod(u, 12.0) < 2.5)
    keep = (u > 170) | ((v < 80) & ~tooth)
    edge = (v > 77.5) & (u < 170)
    return u[keep] + X0, v[keep] + Y0, z[keep], edge[keep]


def test_ground_between_teeth_of_one_gap_at_the_coverage_edge_is_no_deck():
    x, y, z, edge = ragged_edge_scene()
    ground = np.ones(len(x), bool)
    spacing = 1 / np.sqrt(3.0)
    found = classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), spacing, p=classify.ClassifySettings())
    assert edge.sum() > 500   # the ground between the teeth is there to be judged
    assert not found.any()


def joined_reaches_scene(case, seed=5):
    """Reviewer 10's cases (i44-bridge2): the canal scene's deck (canal A, v 40-55 m, the 10 m road at u 90-100
    m), its reaches upstream and downstream joined into one dropout gap elsewhere: ``ring`` a moat (a loop back
    round, v 10-20 m and two connectors, the road on the island side only), ``band`` a dropout band 4 m wide
    (a strip gap) along the far bank, across the road (v 52-56 m), ``edge`` the survey's coverage ending 3 m
    beyond the far bank (no returns v > 58 m for u < 180 m; a cross strip covers u > 180 m), ``edge_short`` 3 m
    short of it (v > 52 m: reviewer 10's case; the canal's water and the band beyond the survey are one
    emptiness, i44-edge). Returns x, y, z and the deck's returns (mask)."""
    rng = np.random.default_rng(seed)
    n = 200 * 100 * 3
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    canal = (v > 40) & (v < 55)
    road = (u > 90) & (u < 100)
    if case == "ring":
        canal |= (((v > 10) & (v < 20) & (u > 30) & (u < 170)) | ((u > 30) & (u < 45) & (v > 10) & (v < 55))
                  | ((u > 155) & (u < 170) & (v > 10) & (v < 55)))
        road &= v > 25
    deck = road & canal
    water = canal & ~road
    if case == "band":
        water |= (v > 52) & (v < 56)
    if case == "edge":
        water |= (v > 58) & (u < 180)
    if case == "edge_short":
        water |= (v > 52) & (u < 180)
    deck &= ~water
    z = rng.normal(0, 0.02, n)
    ramp = np.clip(1.0 - np.maximum(25.0 - v, v - 70.0) / 15.0, 0.0, 1.0)
    z += np.where(road, 1.2 * np.where(canal, 1.0, np.where((v > 25) & (v < 70), ramp, 0.0)), 0.0)
    keep = ~water
    return u[keep] + X0, v[keep] + Y0, z[keep], deck[keep]


@pytest.mark.parametrize("case", ["ring", "band", "edge"])
def test_deck_is_found_when_the_reaches_on_its_two_sides_join_elsewhere(case):
    # i44-bridge's test (two different gap labels ahead and behind) found none of these decks: the gap labels
    # are connected over the whole cloud. The deck crosses the water all the same.
    x, y, z, deck = joined_reaches_scene(case)
    ground = np.ones(len(x), bool)
    found = classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), 1 / np.sqrt(3.0),
                                  p=classify.ClassifySettings())
    assert deck.sum() > 300
    assert found[deck].mean() > 0.9
    assert not found[~deck].any()


def test_deck_into_the_band_beyond_the_survey_is_no_deck():
    # The coverage ending 3 m short of the far bank (i44-bridge2 found the deck): the canal's empty water on both
    # sides of the road runs into the band beyond the survey without land between, so by the returns the road is a
    # pier into the unsurveyed (i44-edge: emptiness beyond the survey's coverage is no gap); with the survey's
    # coverage mask off it is a deck again.
    x, y, z, deck = joined_reaches_scene("edge_short")
    ground = np.ones(len(x), bool)
    found = classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), 1 / np.sqrt(3.0),
                                  p=classify.ClassifySettings())
    assert not found.any()
    off = classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), 1 / np.sqrt(3.0),
                                p=classify.ClassifySettings(water_survey_coverage=False))
    assert off[deck].mean() > 0.9 and not off[~deck].any()


def into_the_lake_scene(kind, seed=5):
    """Reviewer 11's scenes: ground into one lake (160 x 50 m, v 30-80 m, no returns; the shore at 0.2 m), one
    dropout gap round it, so only the one-gap crossing rule could call it a deck. ``jetty``: 6 m wide, 35 m into
    the lake, 1.2 m above the water (vertical sides); ``breakwater``: 12 m crest at 2 m, 30 m long; ``causeway``:
    an earth embankment (crest 12 m wide at 1.5 m, side slopes 1:1.5 with returns down to the water) to an island
    (u 80-120, v 60-72 m). Returns x, y, z and the ground over the lake (mask)."""
    rng = np.random.default_rng(seed)
    n = 200 * 100 * 3
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    lake = (u > 20) & (u < 180) & (v > 30) & (v < 80)
    z = 0.2 + rng.normal(0, 0.02, n)
    if kind == "causeway":
        off = np.abs(u - 100.0)
        crest = np.where(off < 6.0, 1.5, 1.5 - (off - 6.0) / 1.5)   # 1:1.5 slopes down to the water (0.2 m)
        island = (u > 80) & (u < 120) & (v > 60) & (v < 72)
        obj = ((off < 7.95) & (v > 25) & (v < 60)) | island
        z = np.where(island, 1.5, np.where(obj, crest, 0.2)) + rng.normal(0, 0.02, n)
    else:
        obj = (u > 95) & (u < 101) & (v > 25) & (v < 65) if kind == "jetty" else (u > 90) & (u < 102) & (v > 25) & (v < 60)
        z = np.where(obj, 1.2 if kind == "jetty" else 2.0, 0.2) + rng.normal(0, 0.02, n)
    keep = ~(lake & ~obj)
    return u[keep] + X0, v[keep] + Y0, z[keep], (obj & lake)[keep]


@pytest.mark.parametrize("kind", ["jetty", "breakwater", "causeway"])
def test_ground_into_a_lake_is_no_deck(kind):
    """A jetty or breakwater ends in the water (no land across it within BRIDGE_END_WATER_M); an earth causeway's
    fill has returns down its slopes (no drop from deck to water). i44-bridge2 called 618/623, 1082/1088 and
    1183/2872 of these returns bridge decks. (With vertical sides a causeway to an island is a moat's deck in
    everything the returns show: reviewer 11's scene, 1243/2796, stays one.)"""
    x, y, z, over = into_the_lake_scene(kind)
    found = classify.bridge_decks(x, y, z, np.ones(len(x), bool), np.zeros(len(x), bool), 1 / np.sqrt(3.0),
                                  p=classify.ClassifySettings())
    assert over.sum() > 500
    assert not found.any(), found[over].sum()


@pytest.mark.parametrize("band_m, far", [(8.0, True), (10.0, True), (8.0, False)])
def test_a_wide_dropout_band_over_one_bank_keeps_the_bridge(band_m, far):
    """Reviewer 13: a dropout band over one bank (3 m into the canal, ``band_m`` wide, across the road) left more than
    BRIDGE_END_WATER_M = 6 m empty along the deck, and the whole bridge was dropped (330/340 -> 0/340); at 12 m it is
    found, the jetty and breakwater of reviewer 11 still not (test_ground_into_a_lake_is_no_deck)."""
    rng = np.random.default_rng(5)
    n = 200 * 100 * 3
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    canal, road = (v > 40) & (v < 55), np.abs(u - 95) < 5
    water = (canal & ~road) | (((v > 52) & (v < 52 + band_m)) if far else ((v > 43 - band_m) & (v < 43)))
    deck = road & canal & ~water
    ramp = np.clip(1.0 - np.maximum(25.0 - v, v - 70.0) / 15.0, 0.0, 1.0)
    z = rng.normal(0, 0.02, n) + np.where(road, 1.2 * np.where(canal, 1.0, ramp), 0.0)
    keep = ~water
    x, y, z, deck = u[keep] + X0, v[keep] + Y0, z[keep], deck[keep]
    found = classify.bridge_decks(x, y, z, np.ones(len(x), bool), np.zeros(len(x), bool), 1 / np.sqrt(3.0),
                                  p=classify.ClassifySettings())
    assert deck.sum() > 300 and found[deck].mean() > 0.9 and not found[~deck].any()
