"""Bridge decks (lidarctl.classify.bridge_decks): ground between two water gaps along a watercourse,
standing clear above the quays, leaves the ground class (-> 17, bridge deck).

The scene (200 x 100 m, 3 returns/m2, 2 cm range noise, quays and streets at 0 m): canal A along u
(v 40-55 m, no returns: calm water gives none) crossed by a 10 m wide road whose deck stands 1.2 m
above the quays, ramping down over 15 m on both sides; canal C parallel to A (v 70-80 m, u < 60 m),
the raised strip between them (v 55-70 m, 1 m high) lies across both canals' axes: not a bridge.
"""

from __future__ import annotations

import numpy as np

from lidarctl import classify

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
    found = classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), spacing, p)
    assert found[deck].mean() > 0.9
    # nothing else: not the ramps, not the quays along the canals, not the raised strip between
    # the two parallel canals (water on both sides, 15 m apart, but across their axes)
    assert not found[~deck].any()
    # only ground points are judged; 0 disables the rule
    half = np.arange(len(x)) % 2 == 0
    assert not classify.bridge_decks(x, y, z, half, np.zeros(len(x), bool), spacing, p)[~half].any()
    off = classify.ClassifySettings(bridge_max_width_m=0.0)
    assert not classify.bridge_decks(x, y, z, ground, np.zeros(len(x), bool), spacing, off).any()
    # a deck at quay level (a dam between two basins) is not a bridge
    flat = np.where(deck, z - 1.2, z)
    assert not classify.bridge_decks(x, y, flat, ground, np.zeros(len(x), bool), spacing, p)[deck].any()
    # a ridge of land across the water (an isthmus: its crest 1.2 m up, its sides sloping into the water
    # on both sides) clears the quays only along its crest: not a level deck
    crest = np.where(deck, z - 1.2 + 1.2 * np.clip(1.0 - np.abs(x - X0 - 95.0) / 5.0, 0.0, 1.0), z)
    assert not classify.bridge_decks(x, y, crest, ground, np.zeros(len(x), bool), spacing, p).any()


def test_classification_labels_the_deck_17_and_keeps_the_quays_ground():
    x, y, z, deck, strip = bridge_scene()
    cls = classify.classify_points(x, y, z)
    assert np.mean(cls[deck] == classify.BRIDGE_DECK) > 0.9
    assert np.mean(cls[~deck & ~strip] == classify.GROUND) > 0.98
    assert not np.any(cls[~deck] == classify.BRIDGE_DECK)
