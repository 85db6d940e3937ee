"""Classification into ASPRS classes: noise, ground, buildings, vegetation, water; fusion with the orthophoto."""

# The version of the classification rules: the tiled classification's resume key holds it (``lidarctl.tiles``), so
# tiles kept by a run before a rule changed are classified again, not reused (the toolkit's version, 0.1.0, never
# changed with them). Bump it with every change of what class a point gets at the same settings.
# 1: before i44-water; 2: i44-water (water from the whole cloud's water grid, sloping surfaces, filled banks);
# 3: i44-bridge (a deck separates two different gaps); 4: i44-bridge2 (or crosses one gap for at least 4 m: its
# reaches may be one gap); 5: i44-edge (a tile's level regions and darkness from the whole cloud's level bodies and
# land; emptiness beyond the survey's coverage is no gap for the level-water join or a deck); 6: s11-fixes (such a
# one-gap deck needs both ends on land across the water and sides that drop to it: jetties, breakwaters, earth
# causeways are ground); 7: i44-edge-fixes (a river up to 100 m wide crossing the survey is inside its footprint;
# the whole cloud's level bodies: regions at different levels side by side stay apart, roofs and walls are no
# bank); 8: s13-fixes (a one-gap deck's ends on land across up to 12 m of water, was 6: a dropout band over one
# bank); 9: the whole cloud's level bodies an option, off by default (review 15: memory by the cloud's bounding
# box; quays above 2.8 m); 10: level-bodies-sparse (with ``water_whole_level_bodies``: a rim cell above the steepest
# bank is a quay's wall, a bank, when no lower land lies within 50 m; default settings: classes unchanged); 11:
# s19-fixes (with ``water_whole_level_bodies``: land at or below the water's level is lower land too, the body's
# own cells and rim aside: a roof ring round a yard at street level is no bank); 12: level-wire (the whole cloud's level
# bodies found tile by tile inside the tiles' run, the same bodies; ``water_whole_level_bodies`` on by default: a
# lake larger than a tile judged whole; with it off, classes as in 9).
# 13: trial-us (small groups of returns standing more than 50 m above every other return of a 3 x 3 window are high
# noise: birds, clouds; a river's long profile compares each step with those two or more upstream; water returns beside
# a deck count as water for ``spanning_decks``; no class changed on ISPRS, AHN3 Delft, Topography, MixedConifer, Autzen).
# sunken-ground's sink test (``ground_sink_sigma``) is off by default: classes unchanged by it.
# 14: h1-tiling (a tile's window refines its ground on the surface the whole cloud chooses, a grid of means or a TIN,
# ``grid.CloudFrame.refine_dense``: a whole cloud's classes unchanged, a tiled cloud's as the whole cloud's where a
# window's density chose the other surface; the demo's strips in 12 tiles of 430 m: 974 -> 1 of 4.94 M points differ
# from 2 tiles).
# 15: rooftop-noise (the rooftop-object rule's range noise is the lifted-ground test's ``ground_noise_m``, which a tile
# takes from the whole cloud, not a per-window sample: AHN3 Delft in 80 / 150 m tiles 42 / 2 -> 34 / 0 returns differ
# from the whole cloud's; whole clouds: AHN3 12 of 640,510 returns moved (vegetation -> building), the 7 ISPRS samples,
# Topography, Autzen, MixedConifer, Nebraska and the demo's strips unchanged).
# 16: roof patches (a segment's roof area counts only its planar patches of ``roof_min_patch_m2``: lasR's BC Timber
# Sales forest tiles 52,485 / 246,848 / 239,821 / 175,047 building returns -> 0 / 45 / 214 / 48; the 7 ISPRS samples,
# AHN3 Delft, Topography, MixedConifer, Megaplot, Autzen, Nebraska and the demo's strips unchanged).
# 17: cut pieces (``cut_pieces_judged``: a piece of a building segment cut off by the growth tests stays only with a
# building's roof patches or a shed's single returns: IGN LiDAR HD Montpellier's high vegetation called building
# 51,935 -> 22,075 returns).
# 18: foliage beyond a roof's reach (``foliage_beyond_roof_reach``: a connected region of building cells more than 2
# cells from a roof cell that splits the pulses, is rough and deep leaves the building: IGN LiDAR HD Isère's high
# vegetation called building 34,255 -> 2,892 returns; the 7 ISPRS samples, Topography, MixedConifer, Autzen, Nebraska
# and the demo's strips unchanged; AHN3 Delft 3,528 returns; an option: off, the classes of 17).
RULES_VERSION = 18

# The versions whose changes decide classes only with a setting on (version -> the setting's name): a run with that
# setting off keeps the version before them (``rules_version``), so its kept tiles and its stage stay up to date
# (review 19: version 10 re-ran every project, the demo's classification 250 s, a big block hours, for the same
# classes).
OPTION_ONLY_VERSIONS = {10: "water_whole_level_bodies", 11: "water_whole_level_bodies", 12: "water_whole_level_bodies",
                        18: "foliage_beyond_roof_reach"}


def rules_version(settings) -> int:
    """The rules' version of a classification with ``settings`` (``pipeline.ClassifySettings``): ``RULES_VERSION``,
    less the latest versions whose changes decide classes only with a setting that is off here
    (``OPTION_ONLY_VERSIONS``)."""
    return max(v for v in range(1, RULES_VERSION + 1)
               if v not in OPTION_ONLY_VERSIONS or getattr(settings, OPTION_ONLY_VERSIONS[v]))
