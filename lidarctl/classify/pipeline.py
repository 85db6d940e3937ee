"""Full classification into ASPRS classes: noise, ground, buildings, vegetation, water.

Pipeline (``classify_points``):
1. Noise (lidarctl.classify.noise): low outliers -> 7, high outliers -> 18; isolated points -> 7 when below
   the ground DEM, else 18.
2. Ground (lidarctl.classify.ground) -> 2; ground points more than ``deep_m`` below the mean ground of
   their 15 m neighbourhood (a deep patch of low noise that slipped through) become low noise
   and the ground is filtered again. Ground refinement (``lifted_ground``): a ground point that
   stands more than ``ground_lift_sigma`` range-noise sigmas above the least-squares plane of its
   neighbouring ground points (sigma measured on the cloud's own ground set) is the last return of
   low vegetation when its pulse also returned from above (multi-return), not bare earth; a single
   return is judged too (``ground_lift_single``) when it also stands that many times its
   neighbours' robust spread above the plane (a strip offset widens the spread, a low object among
   bare earth does not); it becomes low vegetation but stays in the DEM. Its mirror (``sunken_ground``,
   before it; off by default): a ground point more than ``ground_sink_sigma`` sigmas (and its neighbours'
   spread) and ``ground_sink_min_depth_m`` below that plane, a single return (``ground_sink_single``), with at
   most 2 of its 12 neighbours as low or clearly below the plane (a ditch, a pit, a bank is a surface bending
   down; a return from below the ground stands alone), is low noise and leaves the DEM (a multipath return
   1-3 m down would pit it). Height above ground (HAG)
   from a DEM of the ground points; non-ground points more than ``deep_m`` below that DEM are low
   noise too.
3. Buildings from planar roof segments: on a ``cell_m`` grid of the highest non-ground point (object
   DSM), a least-squares plane is fitted in every 3x3 window; cells with plane RMS below
   ``roof_rms_m``, HAG above ``building_min_height_m`` and few multi-return points (laser
   penetrates trees, not roofs: the returns of the fit's 3x3 window show a multi-return fraction
   below ``max_multi_return_fraction`` at 95 % one-sided confidence, ``fewer_multi_returns``) are
   roof cells;
   8-connected roof segments of at least ``building_min_area_m2`` are buildings (-> 6, points
   within ``roof_depth_m`` below the DSM).
   Small segments (sheds, garages: at least ``small_building_min_area_m2``) count by their whole
   area when their median plane RMS is below ``rough_rms_m`` and they are mostly single-return
   (the 3x3 fit eats a cell on every side of a small roof; a segment too narrow for any 3x3 window
   on its roof shows its planarity by one plane through all its cells, ``segment_plane_rms``
   below ``small_plane_rms_m``). A small roof next to a hedge or under a crown edge joins their
   segment, which then fails these tests as a whole: ``planar_cores`` fits a plane to each
   4+-cell group of roof cells of a rejected segment, grows it over the segment's cells on that
   plane and judges the grown piece alone by the small-building tests. A shed under a crown has the crown
   on the DSM: ``crown_covered_roofs`` finds its roof on the surface of the last returns (the lowest
   non-ground last return per cell, where no pulse reaches the ground), by the same planar cores and
   small-building tests, with the share of its returns whose pulse went on below it as the
   multi-return share (``covered_roofs``). Wall points: single returns in the
   ring of cells around a building. Roof-edge completion (``roof_edge_completion``): region
   growing of building points over eaves and low roof parts by local-plane continuity (kNN
   least-squares plane of the neighbouring building points, ``edge_tolerance_m``). Rooftop objects
   (``rooftop_objects``): parts of a building cut from its roof by a height step (more than 3 sigma
   of the range noise plus the rise of a ``roof_max_pitch_deg`` roof between neighbouring returns),
   smaller than ``rooftop_object_max_area_m2`` and higher than the surfaces around them (rooftop
   units, cables, crowns over a roof) leave the building class.
4. Vegetation by HAG: low (3) <= ``low_veg_max_m`` < medium (4) <= ``medium_veg_max_m`` < high (5).
   Where the cloud has multiple returns, a non-ground point above ``low_veg_max_m`` counts as
   vegetation only in cells with multi-return or rough (non-planar) structure; smooth single-return
   objects that are too small for a building (cars, walls) stay unclassified (1).
5. Water (9), *pulse-dropout water detection* (``detect_water``): water absorbs or mirrors away
   the near-infrared pulse, so an airborne scan over water shows a gap in the return pattern
   holding only a few returns, all at one level, with low intensity. On a ``water_cell_m`` grid
   the 3x3-window return count below ``water_density_ratio`` of the cloud's median marks dropout
   cells; each 8-connected dropout region of at least ``water_min_area_m2`` is a water body when
   its candidate returns (ground, unclassified, low vegetation; noise stays noise)
   (a) have a common level: the lowest well-populated height band (``water_level``; boats and
   quays stand above the water) holds at least ``water_flat_fraction`` of them within
   ``water_level_tol_m`` and at least ``water_min_points`` (b) that is horizontal (LSQ plane
   slope <= ``water_max_slope``) and not above the ground on its banks (the bed test: the median
   ground height of the rim cells, the DEM just across the gap, is not more than
   ``water_level_tol_m`` below the level). A river is not at one level: a gap failing (a) is judged
   against its sloping surface when ``water_sloping_surface`` (``water_surface``: reaches of
   ``water_level_tol_m / water_max_slope`` each at its own level, bilinear between them, a step between
   reaches a bank), each return and bank cell against the level beside it (Autzen's Willamette, 1.3 m of fall
   across the crop, bench/results/water_autzen.json); a sloping surface must also lie in a bed (at least half
   of the rim's ground cells more than ``water_level_tol_m`` above the level beside them: a draining car park
   or road does not) and fall one way along its course (``falls_along_course``: an undulating field does not);
   (c) are dark: the lower quartile of their intensity is below ``water_intensity_ratio`` of the
   cloud's median ground intensity (skipped when the cloud carries no intensity; specular
   returns near nadir are bright, hence the quartile); and (d) the gap is not an occlusion
   shadow: at most ``water_shadow_fraction`` of its rim cells hold building points (a shadow is
   bounded by the building that casts it); (e) open water has nothing above it: a return with any
   return more than ``low_veg_max_m`` above the level within one water cell horizontally is forest
   floor seen through a crown (drop-out under canopy), never water. Returns within 3 sigma (their robust spread, clipped
   to [1/4, 1] ``water_level_tol_m``) of the level become water; so do returns within
   ``water_shore_m`` of the gap at that level that are as dark as the body (on clouds without
   intensity: in a dropout cell), which the 3x3 window misses along the shore.
   *Level water* (``level_water``): a calm lake that returned the pulse shows no dropout; it is a
   surface level to ``level_water_tol_m`` over at least ``level_water_min_area_m2``, in a bed (the
   ground on its rim stands above the level), under open sky, of single returns; its shore is
   where the returns leave the level. A lake that mirrored the pulse away over its middle returns it
   only in patches along its shores; level patches at one level (within ``level_water_tol_m``) that
   border the same dropout gap (cells without any return) are one body
   (``level_water_across_dropouts``; the lidR Topography lakes, bench/results/water.json).
   *Tiles* (``lidarctl.tiles``): a tile takes the whole cloud's water cell, grid origin and returns per cell
   (``WaterGrid``), its cells cut by the buffer's edge are neither dropouts nor banks, a gap that one level holds is
   judged first on its sloping surface when that holds most of the returns the level leaves off, and a sloping
   surface's banks are the rim of the gap with its holes filled: a river seen in a tile's window is judged as the
   whole cloud judges it (bench/results/water_tiles.json).
6. Bridge decks (17, ``bridge_decks``): ground between two open-water-sized dropout gaps (not
   occlusion shadows) at most ``bridge_max_width_m`` apart along a grid direction within 30 degrees
   of a gap's long axis (a watercourse runs on under the deck), two gaps (the reaches upstream and
   downstream) or one gap it crosses for at least ``BRIDGE_MIN_CROSSING_M`` (reaches joined elsewhere; ground
   between the teeth of a ragged gap edge, such as the survey's coverage, has one gap on both sides only as
   deep as the teeth: the demo's 190 false deck returns), standing more than
   ``bridge_min_clearance_m`` above the lower of the two gaps' banks (median ground of their rims),
   on spans (the connected cells between the two gaps) of at least ``bridge_min_deck_m2`` whose ground
   stands that clear almost everywhere (``bridge_min_clear_share``: a level deck, not a sloping shore).
   On the AHN3 Delft crop this finds 755 of the 1,365 civil-structure (26) points (two bridges over
   the canals) and takes 205 true ground points of an approach ramp (bench/results/lidar_ahn3_errors.json).
   A deck the ground filter left out (high over a river whose surface gave returns far below it) meets
   the roof rules instead; ``spanning_decks`` takes it back from the buildings: a long, narrow building
   segment (``BRIDGE_MIN_ASPECT``, at most ``bridge_max_width_m`` wide) with open-water dropout gaps on
   both sides along most of its length (``BRIDGE_MIN_OVER_WATER``) that runs on into the terrain at an
   end (the ground beyond it less than ``building_min_height_m`` below the deck; a roof ends in walls).
   The Autzen footbridge (1,303 returns) was a building for want of this rule.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import ClassVar

import numba
import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from aerotri.core.errors import ConfigError
from aerotri.core.settings import setting
from lidarctl import grid
from lidarctl.classify import ground as ground_mod
from lidarctl.classify import noise as noise_mod
from lidarctl.knn import QUERY_CHUNK, BucketGrid
from lidarctl.raster_ops import fill_nodata, plane_rms, reduce_grid, rimmed_dropouts, sample_bilinear, slope_tan

log = logging.getLogger(__name__)
# the classified cloud's units (``lidarctl.units.LengthUnits``), for the places and heights log lines name: set by
# the classify command (``tiles._classify``); metres when unset (trial s96 F5: a feet cloud's water note named a
# place in metres, which is no position in its CRS)
_place_units = None


def set_place_units(units) -> None:
    global _place_units
    _place_units = units


def _place(x_m: float, y_m: float) -> str:
    u = _place_units
    if u is None or not u.known or not (math.isfinite(x_m) and math.isfinite(y_m)):
        return f"x {x_m:.1f} y {y_m:.1f} m"
    return f"x {float(u.xy_from_m(x_m)):.1f} y {float(u.xy_from_m(y_m)):.1f} {u.xy_name}"


def _height(z_m: float) -> str:
    u = _place_units
    if u is None or not u.known or u.z_m == 1.0:
        return f"{z_m:.2f} m"
    return f"{float(u.z_from_m(z_m)):.2f} {u.z_name} ({z_m:.2f} m)"

# A candidate water body at least this large (m2) that is judged no water is said in the log, with the test it
# failed and its numbers against the limit (a river or lake lost silently was trial-us's finding 2).
WATER_REJECT_LOG_M2 = 2500.0

UNCLASSIFIED, GROUND, LOW_VEG, MED_VEG, HIGH_VEG, BUILDING, LOW_NOISE, WATER, HIGH_NOISE = 1, 2, 3, 4, 5, 6, 7, 9, 18
BRIDGE_DECK = 17
CLASS_NAMES = {1: "unclassified", 2: "ground", 3: "low veg", 4: "medium veg", 5: "high veg",
               6: "building", 7: "low noise", 9: "water", 11: "road", 17: "bridge deck", 18: "high noise"}


# A roof's ridge, dormer or eave breaks the 3 x 3 plane fit of the roof cells within this many cells of a roof cell (a
# window across a break spans 3 cells): the growth tests spare that band (foliage_beyond_roof_reach).
ROOF_FIT_REACH_CELLS = 2


@dataclasses.dataclass(frozen=True)
class ClassifySettings:
    """Options of the classification stage (``lidarctl classify``, ``[classify]`` in project.toml).

    ``ground_method`` and ``preset`` name a filter of the ground-filter registry
    (``lidarctl.classify.ground.GROUND_FILTERS``) and one of its presets; the field choices list the filters
    registered when this module is imported, ``__post_init__`` checks against the registry as it is.
    """

    SECTION: ClassVar[str] = "classify"

    ground_method: str = setting("morph", choices=tuple(ground_mod.GROUND_FILTERS), help="Ground filter: " + ", ".join(
        f"{name} ({f.help})" if f.help else name for name, f in ground_mod.GROUND_FILTERS.items()) + ".")
    preset: str | None = setting(None, choices=ground_mod.preset_names(), help="Ground filter parameters for "
                                 "the terrain type (default: the single all-round set).")
    ground_params: dict = setting(default_factory=dict, help="Ground-filter parameters that replace the "
                                  "preset's (name -> value; lidarctl.classify.ground.GroundSettings / MorphSettings fields).")
    keep_classes: bool = setting(False, help="Keep the classes the LiDAR was delivered with (vendor-classified) "
                                             "after checking that ground and building classes are present and "
                                             "plausible (lidarctl.classify.delivered_classes); no classification is run.")
    cell_m: float = setting(0.0, min=0.0, help="Cell of the surface grids (DSM, local planes) in metres; 0: max(0.5 m, "
                                               "2 x the mean point spacing).")
    building_min_height_m: float = setting(2.0, min=0.0, help="Objects standing higher than this above the DEM may be "
                                                              "buildings (m).")
    # roof_rms_m and building_min_area_m2: the best of bench/eval_ahn3_holdout.py's grid on the shared
    # AHN3 crop, scored on a second crop (bench/eval_ahn3_unseen.py). That grid point also had a
    # multi-return fraction of 0.45, which with the other two made a synthetic tree a building.
    # max_multi_return_fraction: the share of multi-return points a roof's plane-fit window must be
    # shown to stay below (95 % confidence, see classify_points), not one cell's observed share.
    building_min_area_m2: float = setting(10.0, min=0.0, help="Smallest roof segment (m2) classified as a building.")
    # A roof is planes; a closed canopy fits a local plane here and there by chance (BC Timber Sales' forest tiles of
    # lasR's data: 43 scattered roof cells, at most 3 together, made a 6,650 m2 crown segment a building). The
    # smallest building's area (small_building_min_area_m2) is the least a plane of a roof shows.
    roof_min_patch_m2: float = setting(6.0, min=0.0, help="Roof cells count toward a segment's roof area only in "
                                       "connected planar patches at least this large (m2); 0: every roof cell.")
    roof_rms_m: float = setting(0.25, min=0.0, min_open=True, help="Largest RMS (m) of a roof cell's local plane (3 x 3 "
                                                                   "cells of the DSM).")
    roof_depth_m: float = setting(100.0, min=0.0, help="Building points lie at most this far below the DSM (m).")
    wall_min_height_m: float = setting(0.5, min=0.0, help="Building points (roofs, walls) stand at least this high above "
                                                          "the ground (m).")
    max_multi_return_fraction: float = setting(0.3, min=0.0, max=1.0, help="A roof's plane-fit window must be shown "
                                               "(95 % confidence) to hold fewer multi-return points than this share.")
    grow_multi_return_fraction: float = setting(0.7, min=0.0, max=1.0, help="Cells with at most this share of "
                                                "multi-return points may join a building segment.")
    low_veg_max_m: float = setting(2.0, min=0.0, help="Vegetation up to this height above the ground is low (class 3) "
                                                      "(m).")
    medium_veg_max_m: float = setting(5.0, min=0.0, help="Vegetation up to this height above the ground is medium "
                                                         "(class 4), higher is high (class 5) (m).")
    rough_rms_m: float = setting(0.3, min=0.0, min_open=True, help="Local plane RMS (m) from which a surface is rough "
                                                                   "(vegetation), not a roof.")
    water_cell_m: float = setting(0.0, min=0.0, help="Cell of the water detection (m); 0: max(1 m, 2 x the mean point "
                                                     "spacing).")
    water_density_ratio: float = setting(0.3, min=0.0, max=1.0, help="A cell with fewer returns than this share of "
                                                                     "the median cell is a dropout (water absorbs).")
    water_min_area_m2: float = setting(20.0, min=0.0, help="Smallest water body (m2).")
    water_level_tol_m: float = setting(0.2, min=0.0, min_open=True, help="Returns within this of a water body's level "
                                                                         "lie on it (m).")
    water_flat_fraction: float = setting(0.6, min=0.0, max=1.0, help="Share of a candidate's ground returns that must "
                                                                     "lie on its level.")
    water_min_points: int = setting(5, min=1, help="Fewest returns on a water body's level.")
    water_max_slope: float = setting(0.01, min=0.0, help="Steepest water surface (gradient of its fitted plane, "
                                                         "dimensionless).")
    water_sloping_surface: bool = setting(True, help="A dropout gap whose returns are not at one level may be a river "
                                                     "falling along its course: reaches of water_level_tol_m / "
                                                     "water_max_slope each at their own level, joined without steps.")
    water_intensity_ratio: float = setting(0.5, min=0.0, help="Water returns are darker than this share of the "
                                                              "ground's median intensity.")
    water_shadow_fraction: float = setting(0.2, min=0.0, max=1.0, help="A dropout whose rim is more than this share "
                                                                       "building is a roof's shadow, not water.")
    water_shore_m: float = setting(4.0, min=0.0, help="Width of the shore examined around a dropout (m).")
    # Level water (``level_water``): calm water that returned the pulse. 5 cm: a few sigma of the
    # range noise of airborne scanners (1-3 cm); terrain that drains slopes by more over a few cells.
    level_water_tol_m: float = setting(0.05, min=0.0, min_open=True, help="Level water: returns within this of the "
                                                                          "level lie on it (m).")
    level_water_min_area_m2: float = setting(200.0, min=0.0, help="Level water: smallest body (m2); 0: off.")
    level_water_across_dropouts: bool = setting(True, help="Level water: level patches around one pulse-dropout "
                                                "gap at the same level are one body (water returns pulses only "
                                                "along its shores).")
    level_water_bank_fraction: float = setting(0.8, min=0.0, max=1.0, help="Level water: share of the ground cells on "
                                                                           "its rim standing above the level (a bed).")
    # Beyond the survey's coverage the water grid is as empty as a lake that mirrors every pulse. Where emptiness is
    # the only evidence (level patches joined across a gap, a deck between gaps) it counts only inside the coverage
    # (issue 44, i44-edge); the dropout rule judges a gap by its returns (dark, level, in a bed) and keeps it all: a
    # river running off a crop's edge (Autzen's, 20 m without a return) is by occupancy a band beyond a strip.
    # Physics, no fitted value (the 10 m cells are those of the mean spacing; the one-cell closing keeps canals).
    water_survey_coverage: bool = setting(True, help="Empty water cells beyond the survey's coverage (its occupied "
                                          "10 m cells, closed by one cell, with their holes filled; the empty cells of "
                                          "its ragged edge joined to the outside) are no gap that level water is "
                                          "joined across or a bridge deck spans.")
    # The whole cloud's level water bodies for the level regions a tile's window cuts (i44-edge): a lake larger than a
    # tile and its buffer judged whole. Off from review 15 (the parent held every occupied water cell: ~150-200 bytes
    # each, tens of GB for a 300 M-point block) until level-wire: the tiles spool their water cells by level tile on
    # the run's scratch and the bodies are found tile by tile over windows of a tile and its neighbours
    # (``level_tiles.whole_level_bodies_spooled``): the parent holds the tiles' borders and per-region tables.
    water_whole_level_bodies: bool = setting(True, help="Level water in tiles: the level regions a tile's window "
                                             "cuts judged by the whole cloud's level bodies (a lake larger than a "
                                             "tile), found tile by tile over the water cells the tiles write to the "
                                             "run's scratch (60-150 bytes per occupied water cell on disk; the "
                                             "parent holds a few tiles' windows, the regions crossing tile "
                                             "borders and a table per region: 13-63 bytes per water cell measured, "
                                             "against 150-200 with every cell).")
    # A deck is at most this long along the watercourse it spans (the road's width, not the span
    # across the water): a two-lane road with pavements is ~15 m. 0 disables the bridge rule.
    bridge_max_width_m: float = setting(20.0, min=0.0, help="A bridge deck is at most this long along the water it "
                                                            "spans (m); 0: no bridge rule.")
    # A deck clears the water and has depth: it stands at least this much above the lower quay.
    bridge_min_clearance_m: float = setting(0.5, min=0.0, help="A deck stands at least this high above the lower quay "
                                                               "(m).")
    # A deck carries at least one traffic lane (3.5 m) over at least ~3 m of water: a span (the cells
    # between the two gaps) smaller than this is no deck. And a level deck stands clear almost
    # everywhere (only its ends may ramp down): at least ``bridge_min_clear_share`` of the span's
    # ground clears the quay, where a strip of land between two arms of a lake, sloping into the
    # water, clears it only along its crest. Seen on: AHN3's two bridges (spans of 97 and 25 m2,
    # shares 0.96 and 1.0) and three spans on lidr_topography's lake shore (26-78 m2, 0.20-0.31).
    bridge_min_deck_m2: float = setting(10.0, min=0.0, help="Smallest deck (m2).")
    bridge_min_clear_share: float = setting(0.9, min=0.0, max=1.0, help="Share of a span's ground that must clear the "
                                                                        "quay for a deck.")
    # Lift test (multi-return last returns only): 4 sigma of the measured range noise. On AHN3 the
    # false ground stands 0.13 m (median) above the true ground, whose own scatter is ~0.02 m.
    ground_lift_sigma: float = setting(4.0, min=0.0, help="Ground returns more than this many range-noise sigmas above "
                                                          "their local ground plane, under something that split the "
                                                          "pulse, are no ground (0: no lift test).")
    # Single returns judged too: they must also stand ground_lift_sigma times their neighbours'
    # robust spread (1.4826 MAD) about the plane above it.
    ground_lift_single: bool = setting(True, help="Judge single returns by the lift test too (against their neighbours' "
                                                  "spread).")
    # Sink test (issue 44, sunken-ground): the lift test's mirror, for returns from below the ground (multipath)
    # that the gap tests let through. Off by default (sunken-ground2, bench/results/ground_sink.json): with the floor
    # and single returns below (fixed before scoring) it spares AHN3's real dips (0 points change) and still clears
    # Autzen's injected returns 1-8 m down (no DEM pit over 0.5 m), but ISPRS (7 samples, all single returns) loses
    # 32 returns 0.2-3.9 m below their neighbours, 29 of them truth ground: 3.144 -> 3.157 %, over the 0.005 point
    # limit set before the run. 6 sigma (1eeb769e's value; 4, the lift test's, took AHN3 SE ground PA 0.21 point
    # down) was chosen on AHN3 and ISPRS in-sample.
    ground_sink_sigma: float = setting(0.0, min=0.0, help="Ground returns more than this many range-noise sigmas (and "
                                       "their neighbours' spread) below their local ground plane, alone at that depth "
                                       "(at most 2 of 12 neighbours), are low noise (0: no sink test; 6 was tried).")
    # Fixed before scoring (sunken-ground2), by what the test is for, not fitted: a return less than half a metre
    # below its neighbours cannot pit the DEM by more than the 0.5 m a DEM's pits are judged by (a cell's mean is
    # never below its lowest return), and half the low-outlier test's own gap (gap_m 1 m); drains, gutters and kerbs
    # (AHN3: 0.04-0.63 m, median 0.17 m, below their neighbours) are terrain.
    ground_sink_min_depth_m: float = setting(0.5, min=0.0, help="...and more than this below that plane (m): shallower "
                                             "dips (drains, gutters) are terrain.")
    # Multipath off glass or water comes back as the pulse's only return; the last of several returns is the
    # ground under low vegetation or an edge, whose neighbours may stand a little high.
    ground_sink_single: bool = setting(True, help="Judge single returns only by the sink test (the last of several "
                                                  "returns stays ground).")
    deep_cell_m: float = setting(5.0, min=0.0, min_open=True, help="Cell of the search for ground returns far below "
                                                                   "the mean ground (m).")
    deep_m: float = setting(5.0, min=0.0, min_open=True, help="Returns more than this (plus the local relief) below the "
                                                              "ground are low noise (m).")
    small_building_min_area_m2: float = setting(6.0, min=0.0, help="Smallest building segment below "
                                                                   "building_min_area_m2 (m2), with the rules below.")
    small_building_max_multi_fraction: float = setting(0.2, min=0.0, max=1.0, help="A small building's cells hold at "
                                                       "most this share of multi-return points on average.")
    # Small segments may also show their planarity by one plane fitted to all their DSM cells (RMS
    # below small_plane_rms_m; 0.2 and 0.3 m let hedges and vans in, bench/eval_ahn3_bldg_rules.py).
    small_building_plane_fit: bool = setting(True, help="A small segment may show its planarity by one plane through "
                                                        "all its DSM cells.")
    small_plane_rms_m: float = setting(0.1, min=0.0, min_open=True, help="Largest RMS of that plane (m).")
    # Planar cores: the sheds and garden buildings the BGT maps and this classifier missed on AHN3 Delft
    # (9 of 106 footprints in the NE quarter, all 5-21 m2) were planar and single-return but joined one
    # candidate segment with the hedges and crowns beside them (bench/eval_buildings_bgt.py --errors).
    # The rule re-uses the small-building thresholds above; it adds no fitted parameter.
    # Roof reach (off by default): 2 cells would be the band a 3x3 plane fit cannot take at a ridge or an
    # edge. Tried on AHN3 Delft against the BGT (bench/eval_buildings_bgt.py --rules): it moves area from
    # false to missed in equal measure (NE: -37 m2 false, -36 m2 found) and lowers the per-point building
    # PA against AHN3's classes from 95.4 to 93.2 %, so it is not a default.
    roof_reach_cells: int = setting(0, min=0, help="Cells of a building segment further than this from its roof "
                                    "cells join only when at most small_building_max_multi_fraction of their returns "
                                    "are multiple (0: no limit).")
    # Low split-pulse growth (off, 0): on AHN3 Delft 77 % of the false building area against the BGT
    # stands 1.5-4 m above the ground (back gardens: hedges and low crowns joined to sheds and extensions,
    # bench/eval_buildings_bgt_false.py); a roof stops the pulse, a hedge splits it. Below this height a
    # grown cell (not a roof cell) joins only when its 3x3 window passes the roof cells' own multi-return
    # test (max_multi_return_fraction at 95 % confidence). It takes about as much of the BGT's own low
    # buildings (the same kind of object) as false area (3.5 m, north-east: 53 / 45 m2).
    # Pierced growth: a roof stops every pulse above the ground, a hedge or crown lets a share through to
    # it. A grown cell whose 3x3 window shows (95 %) more than this share of its pulses (first returns above
    # the ground) ending on the ground (last returns of split pulses at most wall_min_height_m above it)
    # leaves the building, unless its surface passes the roof cells' planarity and penetration tests (a
    # glass roof). On AHN3 NE it removes about two m2 of false area per m2 of found (bench/eval_buildings_bgt_false.py).
    # Low growth is off by default (0); pierced growth at 0.1 with the edge-completion stop below is the rule set
    # issue 44's criterion ("area and objects", fixed before it was run) picks on all four AHN3 footprint parts
    # against the BGT (docs/classification-generalisation.md, "Shipped since stop 104").
    low_growth_max_height_m: float = setting(0.0, min=0.0, help="Building cells (not roof cells) standing lower than "
                                             "this above the DEM must stop the pulses like a roof (0: no test).")
    pierced_growth_max_fraction: float = setting(0.1, min=0.0, max=1.0, help="Building cells (not roof cells) whose "
                                                 "3x3 window shows (95 % confidence) more than this share of its "
                                                 "pulses reaching the ground leave the building (0: no test).")
    # Pierced growth spares a grown surface that is planar with its returns at its top: a glass roof passes
    # pulses too. A pergola, a slatted or translucent canopy does the same and is no closed roof (BAG: a pand
    # has "a closed roof construction"; the BGT maps a canopy by its posts only).
    pierced_glass_roofs: bool = setting(True, help="Pierced growth keeps planar surfaces that let pulses through (a "
                                        "glass roof); false: only roofs that stop the pulses stay.")
    # Roof edge completion grows a roof's plane point by point: over a pergola or a slatted canopy level with an
    # extension roof beside it, it took the slats' returns whose pulses went on to the ground (AHN3 Delft,
    # south-west footprint part). An eave splits the pulses along a line, such a surface over its whole area.
    pierced_edge_completion: bool = setting(True, help="Roof edge completion does not grow into cells (not roof "
                                            "cells) that the pierced-growth test finds letting pulses through to the "
                                            "ground (with pierced_growth_max_fraction > 0).")
    # Pieces cut off by the growth tests: a crown that touches a roof joins its segment, and so do crowns touching that
    # crown. The growth tests take the cells the pulses pass, which can leave a crown cut off from every roof with
    # the segment's building verdict (IGN LiDAR HD Montpellier: street and courtyard crowns, 51,935 of 97,148 high
    # vegetation returns building). A building is one connected structure, so each piece left is judged again with
    # the segment's own tests; nothing new is fitted.
    cut_pieces_judged: bool = setting(True, help="After the growth tests, each connected piece of a building segment "
                                      "stays only when its roof patches cover building_min_area_m2 or its cells "
                                      "hold at most small_building_max_multi_fraction multi-return points (mean): a "
                                      "crown cut off from the roof leaves. Skipped where 3 x 3 cells exceed "
                                      "building_min_area_m2 (sparse clouds).")
    # Rims of dropout roofs: a glass, wet or black roof returns few or no pulses over its middle (AHN3 Delft: two
    # 22 m2 BGT buildings, 35-41 returns on their rims), so its rim cells' 3x3 windows hold few returns, the
    # pulses its edges split and the empty middle; the growth tests, made to judge a hedge by its window, cannot
    # show that such a rim stops the pulses and take it. The rim is a roof's when it rims a region that returned
    # no pulse (lidarctl.raster_ops.rimmed_dropouts, the vectors' roof dropouts): mostly building cells around it.
    dropout_roof_rims: bool = setting(False, help="Low growth, pierced growth and the pierced edge-completion stop "
                                      "spare the building cells rimming a region that returned no pulse and is "
                                      "rimmed mostly by building cells (a roof seen by its rim).")
    # Roofs under crowns: on AHN3 Delft two BGT sheds (8 and 21 m2) stood under garden crowns, flat at 2.2 m,
    # every pulse ending on them (single returns and last returns of pulses split by the crown above). The
    # rule re-uses the small-building thresholds and building_min_height_m; it adds no fitted parameter.
    crown_covered_roofs: bool = setting(True, help="Small roofs under a crown are found on the surface of the last "
                                        "returns (cells no pulse passes to the ground), by the planar-core tests.")
    # Foliage beyond a roof's reach (IGN LiDAR HD Isère: leaf-on broadleaf crowns against houses, 34,255 of 60,410
    # high-vegetation returns building): such a crown joins the roof's segment by growth and passes few pulses to the
    # ground, so pierced growth does not take it, but it spreads them through its depth. A roof's ridge, dormer or
    # eave breaks the 3 x 3 fit within 2 cells of a roof cell; the growth beyond that, each connected region of it
    # judged as a whole, is foliage when its returns split more pulses than a roof's (max_multi_return_fraction, 95 %),
    # its surface is rough (median plane RMS of rough_rms_m or more) and its returns lie deeper below its top than a
    # roof's (median depth beyond roof_rms_m): such a region leaves the building. No value is fitted.
    foliage_beyond_roof_reach: bool = setting(True, help="Each connected region of building cells more than 2 cells "
                                              "from a roof cell leaves the building when its returns split more than "
                                              "max_multi_return_fraction of the pulses (95 %), its median plane RMS is "
                                              "at least rough_rms_m and its returns lie deeper than roof_rms_m below "
                                              "its top (median).")
    small_building_planar_cores: bool = setting(True, help="Small roofs inside a segment rejected as a whole (a shed "
                                                "beside a hedge) are judged alone: each group of roof cells grows "
                                                "over the cells on its plane.")
    edge_neighbours: int = setting(8, min=3, help="Roof edge completion: building points of the local plane a "
                                                  "candidate is tested against.")
    edge_radius_m: float = setting(1.0, min=0.0, min_open=True, help="Roof edge completion: those neighbours lie "
                                                                     "within this distance (m).")
    edge_tolerance_m: float = setting(0.1, min=0.0, min_open=True, help="Roof edge completion: a candidate within this "
                                                                        "of the plane, which fits its points as well, "
                                                                        "joins the roof (m).")
    edge_iterations: int = setting(8, min=0, help="Roof edge completion: region-growing passes.")
    edge_zone_m: float = setting(3.0, min=0.0, help="Roof edge completion: candidates within this of a building (m).")
    # Rooftop objects (``rooftop_objects``): step-separated parts of a building smaller than this
    # (m2, from point count x spacing^2) that stand above the roof around them are not building
    # (AHN3 labels rooftop units, cables and crowns over roofs unclassified). 0: off. 20 m2 and 65 deg:
    # scored per AHN3 quarter by bench/eval_ahn3_bldg_rules.py (10/40 m2, 45/55 deg too; larger areas
    # or flatter pitches take dormers and roof steps from the buildings); chosen on the other three
    # quarters it is taken when SE, NW or NE is held out, not when SW is.
    rooftop_object_max_area_m2: float = setting(20.0, min=0.0, help="Parts of a roof smaller than this (m2) standing "
                                                                    "above the roof around them are no building (0: off).")
    # A rooftop object rises above a roof (a surface of at least rooftop_object_max_area_m2); before
    # this, steps to any surface counted and a free-standing shed, higher than its own wall returns,
    # was cut as a rooftop object (AHN3 Delft: 1 of the 9 BGT sheds missed; the others by planar cores).
    rooftop_steps_to_roofs_only: bool = setting(True, help="Rooftop objects: only steps to a roof-sized surface count "
                                                "(false: steps to any building surface, e.g. a shed's walls).")
    # Steepest rise (deg) between neighbouring returns that still counts as one surface.
    roof_max_pitch_deg: float = setting(65.0, min=0.0, max=90.0, help="Steepest rise between neighbouring returns of "
                                                                      "one roof surface (deg).")
    # Walls: multi-return points in the ring around a roof that lie below its eave join too
    # (a facade splits pulses with the eave above it). False: single returns only.
    wall_multi_return: bool = setting(False, help="Walls: multi-return points below a roof's eave join the building "
                                                  "too (false: single returns only).")
    noise: noise_mod.NoiseSettings = dataclasses.field(default_factory=noise_mod.NoiseSettings)

    def __post_init__(self):
        ground_mod.check_method_preset(self.ground_method, self.preset)
        if self.medium_veg_max_m < self.low_veg_max_m:
            raise ValueError(f"medium_veg_max_m {self.medium_veg_max_m:g} is below low_veg_max_m {self.low_veg_max_m:g}")
        try:
            checked = ground_mod.checked_overrides(self.ground_method, self.ground_params or {},
                                                   f"ground_params of the {self.ground_method!r} filter")
        except ConfigError as exc:  # from_table (project.toml [classify]) adds the file and section
            raise ValueError(str(exc)) from None
        object.__setattr__(self, "ground_params", checked)  # frozen: the checked copy, set once


def fewer_multi_returns(n_multi: np.ndarray, n: np.ndarray, fraction: float, z: float = 1.645) -> np.ndarray:
    """True where ``n_multi`` multi-return points out of ``n`` show, at one-sided confidence ``z``
    (1.645: 95 %), a multi-return fraction below ``fraction``: the score test, i.e. the Wilson upper
    bound of the fraction is at most ``fraction``. False where ``n`` is 0 (no evidence); with fewer
    than z^2 (1 - fraction) / fraction returns (6.3 at 0.3) no count can show it."""
    n = np.asarray(n, float)
    return (n > 0) & (np.asarray(n_multi) <= fraction * n - z * np.sqrt(fraction * (1.0 - fraction) * n))


def more_than_fraction(k: np.ndarray, n: np.ndarray, fraction: float, z: float = 1.645) -> np.ndarray:
    """True where ``k`` of ``n`` show, at one-sided confidence ``z`` (1.645: 95 %), a share above
    ``fraction``: the mirror of ``fewer_multi_returns`` (the Wilson lower bound of the share is at least
    ``fraction``). False where ``n`` is 0."""
    n = np.asarray(n, float)
    return (n > 0) & (np.asarray(k) >= fraction * n + z * np.sqrt(fraction * (1.0 - fraction) * n))


def dilate_square(mask: np.ndarray, size: int) -> np.ndarray:
    """``ndimage.binary_dilation`` by a ``size`` x ``size`` square (odd size, outside False) as a
    separable maximum filter: the same cells, without testing every offset of the square."""
    return ndimage.maximum_filter(np.asarray(mask, bool).view(np.uint8), size=size, mode="constant",
                                  cval=0).view(bool)


def labelled_median(values: np.ndarray, labels: np.ndarray, nlab: int) -> np.ndarray:
    """``ndimage.median(values, labels, 1..nlab)`` (the mean of the two middle values for an even
    count) sorting only the labelled cells, not the whole grid."""
    sel = labels.ravel() > 0
    v, lab = values.ravel()[sel], labels.ravel()[sel]
    order = np.lexsort((v, lab))
    v = v[order]
    count = np.bincount(lab, minlength=nlab + 1)[1:]
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    lo, hi = first + (count - 1) // 2, first + count // 2
    return (v[lo] + v[hi]) / 2.0


def cut_pieces(building_cells: np.ndarray, keep: np.ndarray, roof: np.ndarray, multi_frac: np.ndarray, cell_m: float,
               p: "ClassifySettings") -> np.ndarray:
    """The building cells that stay when each 8-connected piece of ``building_cells`` (cells of ``keep`` aside: small
    buildings judged whole, rims of dropout roofs) is judged as a segment: its roof patches (``roof_patches``) cover
    ``building_min_area_m2``, or its cells' mean multi-return share is at most ``small_building_max_multi_fraction``."""
    pieces, n = ndimage.label(building_cells & ~keep, np.ones((3, 3), int))
    if n == 0:
        return building_cells
    ids = np.arange(1, n + 1)
    stays = ndimage.sum_labels(roof_patches(roof & (pieces > 0), cell_m, p.roof_min_patch_m2), pieces, ids) * \
        cell_m * cell_m >= p.building_min_area_m2
    # A shed's fragments (a small building's test needs that share too) stay; a crown's pulses split.
    stays |= ndimage.mean(multi_frac, pieces, ids) <= p.small_building_max_multi_fraction
    return building_cells & (np.concatenate([[False], stays])[pieces] | keep)


def roof_patches(roof: np.ndarray, cell_m: float, min_area_m2: float) -> np.ndarray:
    """The roof cells in 8-connected patches of at least ``min_area_m2`` (all of them for 0): a roof's planes, not the
    scattered cells where a canopy fits a local plane by chance."""
    if min_area_m2 <= 0 or not roof.any():
        return roof
    lab, n = ndimage.label(roof, np.ones((3, 3), int))
    size_m2 = np.bincount(lab.ravel(), minlength=n + 1) * cell_m * cell_m
    keep = size_m2 >= min_area_m2
    keep[0] = False
    return keep[lab]


def planar_cores(surface: np.ndarray, seeds: np.ndarray, allowed: np.ndarray, multi_frac: np.ndarray,
                 cell_m: float, *, min_area_m2: float, max_multi_fraction: float, plane_rms_m: float,
                 reach_m: float) -> np.ndarray:
    """Cells of small planar roofs found inside larger non-building segments (bool grid).

    Each 8-connected group of ``seeds`` (roof cells) of at least 4 cells gets the least-squares plane
    of its ``surface`` heights (m), the seed farthest off it dropped and the plane refitted while one
    lies off it (a 3x3 fit straddling the roof's edge made it a roof cell); the plane grows over the
    ``allowed`` cells within ``reach_m`` (m) of the group's bounding box whose height lies within
    ``plane_rms_m`` plus half a cell diagonal of the plane's rise (the cell's highest return may stand
    that far up a pitched roof) of it. A grown piece is a roof when it covers at least ``min_area_m2``,
    its cells' mean multi-return share is at most ``max_multi_fraction`` and one plane fits all its
    cells to ``plane_rms_m`` RMS: a crown or a hedge beside it breaks that plane, so stays out of it.
    """
    out = np.zeros(seeds.shape, bool)
    lab, n = ndimage.label(seeds & allowed, np.ones((3, 3), int))
    if n == 0:
        return out
    pad = max(1, int(np.ceil(reach_m / cell_m)))
    eight = np.ones((3, 3), bool)
    for i, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        rows, cols = np.nonzero(lab[sl] == i)
        rows, cols = rows + sl[0].start, cols + sl[1].start
        while len(rows) >= 4:
            a, b, u0, v0, h0, _ = _segment_planes(surface, rows, cols, np.ones(len(rows), np.int64), 1, cell_m)
            a, b, u0, v0, h0 = a[1], b[1], u0[1], v0[1], h0[1]
            if not (np.isfinite(a) and np.isfinite(b)):
                break
            tol = plane_rms_m + 0.5 * np.sqrt(2.0) * cell_m * np.hypot(a, b)
            res = np.abs(surface[rows, cols] - (h0 + a * (cols * cell_m - u0) + b * (rows * cell_m - v0)))
            if res.max() <= tol:
                break
            keep = np.ones(len(rows), bool)
            keep[np.argmax(res)] = False
            rows, cols = rows[keep], cols[keep]
        if len(rows) < 4 or not (np.isfinite(a) and np.isfinite(b)) or res.max() > tol:
            continue
        r0, r1 = max(0, sl[0].start - pad), min(seeds.shape[0], sl[0].stop + pad)
        c0, c1 = max(0, sl[1].start - pad), min(seeds.shape[1], sl[1].stop + pad)
        rr, cc = np.mgrid[r0:r1, c0:c1]
        plane = h0 + a * (cc * cell_m - u0) + b * (rr * cell_m - v0)
        seed = np.zeros((r1 - r0, c1 - c0), bool)
        seed[rows - r0, cols - c0] = True
        on_plane = allowed[r0:r1, c0:c1] & (np.abs(surface[r0:r1, c0:c1] - plane) <= tol)
        piece = ndimage.binary_propagation(seed, structure=eight, mask=on_plane)
        if piece.sum() * cell_m * cell_m < min_area_m2 or multi_frac[r0:r1, c0:c1][piece].mean() > max_multi_fraction:
            continue
        if not segment_plane_rms(surface[r0:r1, c0:c1], piece.astype(np.int32), 1, cell_m)[0] < plane_rms_m:
            continue
        out[r0:r1, c0:c1] |= piece
    return out


def covered_roofs(z, flat, candidate, *, last, reaches_ground, dem, cell_m: float, shape,
                  p: "ClassifySettings") -> np.ndarray:
    """Returns (bool per point) of small roofs under crowns. ``flat``: each point's cell on the grid ``shape``
    (``cell_m``, the ``dem`` grid); ``candidate``: the non-ground, non-building returns; ``last``: last (or
    single) returns; ``reaches_ground``: returns at the ground's level.

    A roof stops every pulse: where a crown stands above it, the pulses it split end on the roof. The surface
    of the last returns (the lowest candidate last return per cell) over the cells standing above
    ``building_min_height_m`` holds the roof; its 3x3 planar cells (plane RMS below ``small_plane_rms_m``)
    where no return reaches the ground seed ``planar_cores`` on it (the edge cells, straddling the walls,
    may join), with the share of a cell's returns on that
    surface whose pulse went on below it (not a last return) in place of the multi-return share (a hedge's
    top lets pulses on, a roof none). A core's returns on its surface (within ``small_plane_rms_m`` plus the
    rise of the core's plane across half a cell diagonal) are the roof's; the crown above stays vegetation."""
    n_cells = shape[0] * shape[1]
    sel = candidate & last
    lsm = np.full(n_cells, np.inf)
    np.minimum.at(lsm, flat[sel], z[sel])
    lsm = lsm.reshape(shape)
    has = np.isfinite(lsm)
    surface = np.where(has, lsm, dem)
    grounded = np.bincount(flat[reaches_ground], minlength=n_cells).reshape(shape) > 0
    # the roof's edge cells straddle its walls (ground returns beside them): they may join a core, not seed it
    allowed = has & (surface - dem > p.building_min_height_m)
    if not (allowed & ~grounded).any():
        return np.zeros(len(z), bool)
    # the share of the returns at the surface (within small_plane_rms_m of the cell's lowest: a ratio, so a
    # pitched roof's returns further up the cell only thin the sample) whose pulse went on below it
    near = candidate & (np.abs(z - surface.ravel()[flat]) <= p.small_plane_rms_m)
    tot = np.bincount(flat[near], minlength=n_cells).reshape(shape)
    went_on = np.bincount(flat[near & ~last], minlength=n_cells).reshape(shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        went_on_frac = np.where(tot > 0, went_on / np.maximum(tot, 1), 0.0)
    seeds = allowed & ~grounded & (plane_rms(surface, cell_m) < p.small_plane_rms_m)
    cores = planar_cores(surface, seeds, allowed, went_on_frac, cell_m, min_area_m2=p.small_building_min_area_m2,
                         max_multi_fraction=p.small_building_max_multi_fraction, plane_rms_m=p.small_plane_rms_m,
                         reach_m=p.edge_zone_m)
    lab, nlab = ndimage.label(cores, np.ones((3, 3), int))
    if nlab == 0:
        return np.zeros(len(z), bool)
    # a core's returns: within small_plane_rms_m plus its plane's rise across half a cell diagonal of the cell's
    # lowest (the crown above, and the foliage's single returns, lie higher)
    rows, cols = np.nonzero(lab)
    a, b = _segment_planes(surface, rows, cols, lab[rows, cols], nlab, cell_m)[:2]
    rise = np.zeros(shape)
    rise[rows, cols] = 0.5 * np.sqrt(2.0) * cell_m * np.hypot(a, b)[lab[rows, cols]]
    tol = p.small_plane_rms_m + rise.ravel()[flat]
    return candidate & (lab.ravel()[flat] > 0) & (np.abs(z - surface.ravel()[flat]) <= tol)


def _segment_planes(surface, rows, cols, lab, nlab: int, cell_m: float):
    """Least-squares plane h = h0 + a (u - u0) + b (v - v0) of each label's cells (u = col x cell_m,
    v = row x cell_m): arrays a, b, u0, v0, h0, rms indexed by label 0..nlab (NaN where singular)."""
    h = surface[rows, cols].astype(float)
    cnt = np.bincount(lab, minlength=nlab + 1).astype(float)
    n = np.maximum(cnt, 1)
    u = cols * cell_m
    v = rows * cell_m
    u0, v0, h0 = (np.bincount(lab, w, nlab + 1) / n for w in (u, v, h))
    u, v, hc = u - u0[lab], v - v0[lab], h - h0[lab]
    suu, svv, suv = (np.bincount(lab, w, nlab + 1) for w in (u * u, v * v, u * v))
    suh, svh, shh = (np.bincount(lab, w, nlab + 1) for w in (u * hc, v * hc, hc * hc))
    det = suu * svv - suv * suv
    with np.errstate(invalid="ignore", divide="ignore"):
        a = (suh * svv - svh * suv) / det
        b = (svh * suu - suh * suv) / det
        rms = np.sqrt(np.maximum(shh - a * suh - b * svh, 0.0) / n)
    return a, b, u0, v0, h0, rms


def segment_plane_rms(surface: np.ndarray, labels: np.ndarray, nlab: int, cell_m: float) -> np.ndarray:
    """RMS residual (m) of the least-squares plane through each labelled segment's cells of
    ``surface`` (labels 1..nlab; NaN for segments of fewer than 4 cells)."""
    rows, cols = np.nonzero(labels)
    lab = labels[rows, cols]
    cnt = np.bincount(lab, minlength=nlab + 1)
    out = _segment_planes(surface, rows, cols, lab, nlab, cell_m)[5]
    out[(cnt < 4) | ~np.isfinite(out)] = np.nan
    return out[1:]


@numba.njit(cache=True)
def _others(dist, nb, points):
    """The neighbours but the first (the query point itself), as contiguous arrays: dist[:, 1:] and
    points[nb[:, 1:]] (nb: indices into ``points``; len(points) where missing, mapped to its last point:
    the kernels skip them by their infinite distance)."""
    m, k = nb.shape
    last = len(points) - 1
    d = np.empty((m, k - 1))
    i = np.empty((m, k - 1), np.int64)
    for r in range(m):
        for c in range(1, k):
            d[r, c - 1] = dist[r, c]
            i[r, c - 1] = points[min(nb[r, c], last)]
    return d, i


def _ground_plane_chunks(x, y, z, gi, spacing_m: float, k: int):
    """Per chunk ``a:b`` of the ground points ``gi``: ``(a, b, dist, nb, dz, spread)``, their ``k`` nearest other
    ground points (within 6 mean point spacings, at least 1 m; ``dist`` inf where none), each point's height (m)
    above the robust plane through them and the neighbours' robust spread about it (``_plane_offsets``)."""
    radius_m = max(1.0, 6.0 * spacing_m)
    gx, gy = x[gi] - x[gi].min(), y[gi] - y[gi].min()
    # cKDTree's neighbours from a bucket grid (lidarctl.knn), a fraction of its CPU; in chunks of
    # queries, so the neighbour arrays (k x 16 bytes a point) stay bounded on large tiles.
    nbrs = BucketGrid(gx, gy, k + 1)
    xf, yf, zf = np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)
    for a in range(0, len(gi), QUERY_CHUNK):
        b = min(a + QUERY_CHUNK, len(gi))
        dist, nb, _ = nbrs.query(gx[a:b], gy[a:b], k + 1, radius_m)
        dist, nb = _others(dist, nb, gi)
        yield (a, b, dist, nb, *_plane_offsets(xf, yf, zf, gi[a:b], nb, dist, min_points=5, robust=True))


def lifted_ground(x, y, z, is_ground, spacing_m: float, lift_sigma: float, *, intercepted=None,
                  k: int = 12, judge_single: bool = True, sigma_m: float | None = None,
                  offsets: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Ground points standing clear of the local ground surface under something that intercepted
    part of their pulse (mask over all points).

    For every ground point the least-squares plane through its ``k`` nearest other ground points
    (within 6 mean point spacings, at least 1 m) gives its height above the local surface; the
    range noise sigma is the robust spread (1.4826 MAD) of those heights over the whole ground
    set, so the threshold ``lift_sigma`` sigma scales with the sensor and the terrain's
    roughness, not a fixed height. Flagged: points of ``intercepted`` (the last returns of
    multi-return pulses: leaves or an edge above took part of the pulse, so the last return may
    be the low vegetation under them) more than ``lift_sigma`` sigma above their plane. A single
    return (``judge_single``) must also stand ``lift_sigma`` times its neighbours' robust spread
    (1.4826 MAD) about the plane above it: in the overlap of two strips with a height offset half
    the points stand above the plane through both, with nothing over them (judged against sigma alone, the simulator's unadjusted
    strips, 4-9 cm apart, lost 0.3 % of their ground that way), and that plane's residuals hold
    the offset. ``intercepted`` None: no point is judged. ``sigma_m``: the range noise (m) of a larger cloud these
    points are part of (a tile's window: the whole cloud's, ``tiles.cloud_noise``; None: of these points).
    ``offsets``: ``ground_plane_offsets(x, y, z, flatnonzero(is_ground), spacing_m, k)`` when already computed
    (``tiles.cloud_noise`` keeps them). 0 or a negative ``lift_sigma`` disables the test.
    """
    out = np.zeros(len(x), bool)
    gi = np.flatnonzero(is_ground)
    if lift_sigma <= 0 or intercepted is None or not (judge_single or np.any(intercepted[gi])):
        return out
    sigma_m, offsets = _ground_range_noise(x, y, z, is_ground, spacing_m, offsets, k, sigma_m=sigma_m)
    if sigma_m is None:
        return out
    dz, spread = offsets
    ok = np.isfinite(dz)
    dz = np.nan_to_num(dz, nan=0.0)
    lifted = intercepted[gi] & (dz > lift_sigma * sigma_m)
    if judge_single:
        # A single return is judged against the robust scatter of its own neighbours about their
        # plane as well: where two strips overlap with a height offset that scatter holds half the
        # offset, so the upper strip's points do not stand out; a low object whose neighbours are
        # mostly bare earth does (a median, so the object's own points among them do not count).
        lifted |= ~intercepted[gi] & (dz > lift_sigma * np.maximum(sigma_m, np.nan_to_num(spread, nan=np.inf)))
    out[gi[ok & lifted]] = True
    return out


def ground_plane_offsets(x, y, z, gi, spacing_m: float, k: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Each ground point's (``gi``) height (m) above the robust plane through its ``k`` nearest other ground points
    and their robust spread about it (``_ground_plane_chunks``; NaN: too few neighbours)."""
    dz, spread = np.empty(len(gi)), np.empty(len(gi))
    for a, b, _, _, dz_ab, spread_ab in _ground_plane_chunks(x, y, z, gi, spacing_m, k):
        dz[a:b], spread[a:b] = dz_ab, spread_ab
    return dz, spread


def _ground_range_noise(x, y, z, is_ground, spacing_m: float, offsets=None, k: int = 12, sigma_m=None):
    """(the range noise sigma (m) of the ground points ``is_ground``: ``sigma_m`` when given (a tile's whole cloud's),
    else their ``ground_noise_m``; ``offsets``: their ``ground_plane_offsets`` with ``k`` neighbours, computed here when
    None). Sigma is None when the ground has under 4 ``k`` points with a plane. The one definition of the figure the
    lifted-ground test and the rooftop-object rule share."""
    gi = np.flatnonzero(is_ground)
    if len(gi) < 4 * k:
        return None, offsets
    if offsets is None:
        offsets = ground_plane_offsets(x, y, z, gi, spacing_m, k)
    if np.isfinite(offsets[0]).sum() < 4 * k:
        return None, offsets
    return (ground_noise_m(offsets[0]) if sigma_m is None else sigma_m), offsets


def ground_noise_needed(p: "ClassifySettings") -> bool:
    """Whether a classification with ``p`` takes the ground's range noise (``_ground_range_noise``): the lifted-ground
    test's or the rooftop-object rule's (``tiles.cloud_noise`` finds the whole cloud's figure then)."""
    return p.ground_lift_sigma > 0 or p.rooftop_object_max_area_m2 > 0


def ground_noise_m(plane_offsets_m: np.ndarray) -> float:
    """The range noise sigma (m) of a ground set: 1.4826 x the median absolute height of its points above their
    local planes (``ground_plane_offsets``; NaN left out)."""
    dz = np.asarray(plane_offsets_m, float)
    return 1.4826 * float(np.median(np.abs(dz[np.isfinite(dz)])))


def sunken_ground(x, y, z, is_ground, spacing_m: float, sink_sigma: float, *, min_depth_m: float = 0.0,
                  judged=None, k: int = 12, max_at_depth: int = 2) -> np.ndarray:
    """Ground points sunk clear below the local ground surface, alone at their depth: returns from
    below the ground (multipath off glass, water, wet roofs) that the gap tests let through (mask
    over all points).

    The mirror of ``lifted_ground``: for every ground point the least-squares plane through its ``k``
    nearest other ground points (within 6 mean point spacings, at least 1 m) gives its height above
    the local surface; sigma is the robust spread (1.4826 MAD) of those heights over the whole ground
    set. Flagged: points more than ``sink_sigma`` times the larger of sigma and their neighbours' own
    robust spread about the plane below it (a rough or broken surface, a kerb or a bank, widens that
    spread), with at most ``max_at_depth`` of those neighbours as low as it (within 2 sigma) and at most ``max_at_depth``
    more than 2 sigma (or twice their spread) below the plane.
    A real depression (a ditch, a pit, a stream bank, the foot of a stair) is a surface: it holds
    returns at its depth and bends down into it, so neighbours lie below the plane too; a return from
    below the ground stands alone. Only points more than ``min_depth_m`` (metres) below the plane, and
    only points of ``judged`` (None: all; the pipeline passes the single returns), are flagged; the
    others still serve as neighbours. 0 or a negative ``sink_sigma`` disables the test.
    """
    out = np.zeros(len(x), bool)
    gi = np.flatnonzero(is_ground)
    if sink_sigma <= 0 or len(gi) < 4 * k:
        return out
    xf, yf, zf = np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)
    dz, spread = np.empty(len(gi)), np.empty(len(gi))
    cand_pos, cand_nb = [], []
    for a, b, dist, nb, dz_ab, spread_ab in _ground_plane_chunks(x, y, z, gi, spacing_m, k):
        dz[a:b], spread[a:b] = dz_ab, spread_ab
        # Keep the neighbours of the points sunk by more than the spread alone allows (few): the
        # global sigma is known only after the last chunk.
        low = np.flatnonzero(np.nan_to_num(dz[a:b], nan=0.0) < -sink_sigma * np.nan_to_num(spread[a:b], nan=np.inf))
        cand_pos.append(a + low)
        cand_nb.append(np.where(np.isfinite(dist[low]), nb[low], -1))
    ok = np.isfinite(dz)
    if ok.sum() < 4 * k:
        return out
    sigma_m = 1.4826 * float(np.median(np.abs(dz[ok])))
    pos, nb = np.concatenate(cand_pos), np.concatenate(cand_nb)
    deep = dz[pos] < -max(sink_sigma * max(sigma_m, 0.0), min_depth_m)
    if judged is not None:
        deep &= np.asarray(judged, bool)[gi[pos]]
    pos, nb = pos[deep], nb[deep]
    for p_i, row in zip(pos, nb):
        q = row[row >= 0]
        p = gi[p_i]
        u, v = xf[q] - xf[p], yf[q] - yf[p]
        design = np.column_stack([u, v, np.ones(len(q))])
        coef = np.linalg.lstsq(design, zf[q] - zf[p], rcond=None)[0]
        depth = -coef[2]                       # the point's height above the plane (negative)
        residual = zf[q] - zf[p] - design @ coef
        # Neighbours clearly below the plane too (2 sigma, or 2 x their spread where the plane is tilted or the
        # surface rough: 1 in 40 by noise alone): the surface bends down there (a depression's floor, the foot
        # of a bank or a stair), the point is not alone.
        if (np.count_nonzero(zf[q] <= zf[p] + 2.0 * sigma_m) <= max_at_depth
                and np.count_nonzero(residual < -2.0 * max(sigma_m, spread[p_i])) <= max_at_depth):
            out[p] = True
    return out


def ground_dem(x, y, z, ground, cell_m, *, x0, y0, nrows, ncols) -> np.ndarray:
    """Filled DEM (mean height of ground points per cell), rows growing with y."""
    dem = reduce_grid(x[ground], y[ground], z[ground], cell_m=cell_m, x0=x0, y0=y0, nrows=nrows, ncols=ncols,
                      how="mean")
    return fill_nodata(dem, grid.lattice_offset(x0, y0, cell_m))


def deep_ground_outliers(x, y, z, ground, cell_m: float = 5.0, deep_m: float = 5.0) -> np.ndarray:
    """Ground-labelled points far below the mean ground of their 3x3 cell neighbourhood.

    Catches patches of low noise at mixed depths that support each other in the gap tests and
    slipped into the ground set: a point is flagged when it lies more than ``deep_m`` plus the
    local relief (slope of the mean-ground grid times the window radius) below the windowed mean.
    """
    out = np.zeros(len(x), bool)
    gi = np.flatnonzero(ground)
    if len(gi) < 10:
        return out
    cid, nrows, ncols, x0, y0 = grid.cell_ids(x[gi], y[gi], cell_m)
    s = np.bincount(cid, z[gi], minlength=nrows * ncols).reshape(nrows, ncols)
    c = np.bincount(cid, minlength=nrows * ncols).reshape(nrows, ncols).astype(float)
    k = np.ones((3, 3))
    ss = ndimage.correlate(s, k, mode="constant")
    cc = ndimage.correlate(c, k, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cc > 0, ss / np.maximum(cc, 1), np.nan)
    filled = fill_nodata(mean, grid.lattice_offset(x0, y0, cell_m))
    relief = slope_tan(filled, cell_m) * 1.5 * cell_m
    ref = (filled - relief).ravel()[cid]
    out[gi[z[gi] < ref - deep_m]] = True
    return out


def _plane_offsets(x, y, z, query, nb, dist, *, min_points: int, robust: bool = False):
    """``_plane_offsets_kernel`` with its arguments in one set of types (contiguous arrays, ``robust``
    given): numba compiles a function once per set of argument types, and this one (parallel,
    ``np.linalg.solve``, ``np.median``) takes about 10 CPU-s each time on a fresh clone; sliced
    neighbour arrays and an omitted ``robust`` had made two."""
    c = np.ascontiguousarray
    return _plane_offsets_kernel((c(x, np.float64), c(y, np.float64), c(z, np.float64)), c(query, np.int64),
                                 c(nb, np.int64), c(dist, np.float64), int(min_points), bool(robust))


@numba.njit(cache=True, parallel=True)
def _plane_offsets_kernel(points, query, nb, dist, min_points, robust):
    """Per query point (an index into ``points`` (x, y, z)): height above the LSQ plane z = a dx + b dy + c
    through its valid neighbours ``nb`` (point indices, at ``dist``; dx, dy relative to the query point, so c is
    the plane height there), and the neighbours' spread about the plane: their RMS residual, or with ``robust``
    1.4826 x their median absolute residual. NaN with fewer than ``min_points`` neighbours."""
    x, y, z = points
    n, k = nb.shape
    dz = np.full(n, np.nan)
    spread = np.full(n, np.nan)
    for i in numba.prange(n):
        q = query[i]
        s_uu = s_uv = s_u = s_vv = s_v = s_1 = s_uh = s_vh = s_h = 0.0
        m = 0
        for t in range(k):
            if not np.isfinite(dist[i, t]):
                continue
            r = nb[i, t]
            u, v, h = x[r] - x[q], y[r] - y[q], z[r] - z[q]
            s_uu += u * u; s_uv += u * v; s_u += u; s_vv += v * v; s_v += v; s_1 += 1.0
            s_uh += u * h; s_vh += v * h; s_h += h
            m += 1
        if m < min_points:
            continue
        a = np.array([[s_uu, s_uv, s_u], [s_uv, s_vv, s_v], [s_u, s_v, s_1]]) + 1e-9 * np.eye(3)
        coef = _solve3(a, np.array([s_uh, s_vh, s_h]))
        res = np.empty(m)
        ss = 0.0
        j = 0
        for t in range(k):
            if not np.isfinite(dist[i, t]):
                continue
            r = nb[i, t]
            e = z[r] - z[q] - (coef[0] * (x[r] - x[q]) + coef[1] * (y[r] - y[q]) + coef[2])
            ss += e * e
            res[j] = abs(e)
            j += 1
        spread[i] = 1.4826 * _median_small(res) if robust else np.sqrt(ss / m)
        dz[i] = -coef[2]
    return dz, spread


# np.linalg.solve and np.median in the kernel above took about 10 of its 13 CPU-s of compilation (parallel) on a
# fresh clone (numba's LAPACK binding and quickselect); these two compile in a fraction of a second.
@numba.njit(cache=True)
def _solve3(a, b):
    """x of a x = b for a 3 x 3 ``a`` (both overwritten): LU with partial pivoting (the first largest pivot of
    a column, rows scaled by its reciprocal, as LAPACK's dgetf2), then unit-lower and upper substitution."""
    for j in range(3):
        p = j
        for i in range(j + 1, 3):
            if abs(a[i, j]) > abs(a[p, j]):
                p = i
        if p != j:
            for c in range(3):
                a[j, c], a[p, c] = a[p, c], a[j, c]
            b[j], b[p] = b[p], b[j]
        r = 1.0 / a[j, j]
        for i in range(j + 1, 3):
            a[i, j] *= r
            for c in range(j + 1, 3):
                a[i, c] -= a[i, j] * a[j, c]
    for i in range(1, 3):
        for c in range(i):
            b[i] -= a[i, c] * b[c]
    for i in range(2, -1, -1):
        for c in range(i + 1, 3):
            b[i] -= a[i, c] * b[c]
        b[i] /= a[i, i]
    return b


@numba.njit(cache=True)
def _median_small(v):
    """np.median of a short finite array (sorted in place by insertion): the middle value, or the mean of the
    two middle values."""
    n = len(v)
    for i in range(1, n):
        t = v[i]
        j = i - 1
        while j >= 0 and v[j] > t:
            v[j + 1] = v[j]
            j -= 1
        v[j + 1] = t
    h = n >> 1
    return (v[h - 1] + v[h]) / 2 if n & 1 == 0 else v[h]


class _GrowingNeighbours:
    """k nearest neighbours (horizontal) in a point set that grows: a KD-tree of the initial set,
    built once, and one of the points added since, merged per query."""

    def __init__(self, x, y, ref, radius_m: float):
        self.x, self.y, self.r = x, y, radius_m
        self.x0, self.y0 = float(np.min(x[ref])), float(np.min(y[ref]))
        self.base = np.asarray(ref, np.int64)
        self.base_tree = cKDTree(np.column_stack([x[ref] - self.x0, y[ref] - self.y0]))
        self.added = np.zeros(0, np.int64)

    def add(self, idx):
        self.added = np.concatenate([self.added, idx])

    def query(self, idx, k: int):
        q = np.column_stack([self.x[idx] - self.x0, self.y[idx] - self.y0])
        d, n = self.base_tree.query(q, k=k, distance_upper_bound=self.r)
        d, n = d.reshape(len(idx), k), n.reshape(len(idx), k)
        n = self.base[np.minimum(n, len(self.base) - 1)]
        if len(self.added):
            ka = min(k, len(self.added))
            tree = cKDTree(np.column_stack([self.x[self.added] - self.x0, self.y[self.added] - self.y0]))
            da, na = tree.query(q, k=ka, distance_upper_bound=self.r)
            da, na = da.reshape(len(idx), ka), na.reshape(len(idx), ka)
            d = np.concatenate([d, da], axis=1)
            n = np.concatenate([n, self.added[np.minimum(na, len(self.added) - 1)]], axis=1)
            first = np.argsort(d, axis=1, kind="stable")[:, :k]
            d, n = np.take_along_axis(d, first, 1), np.take_along_axis(n, first, 1)
        return d, n


def local_plane_offsets(x, y, z, ref, query, *, k: int = 8, radius_m: float = 1.0, neighbours=None):
    """Height of each query point above the least-squares plane through its k nearest reference
    points (horizontal distance, within ``radius_m``), and that plane's RMS residual (m).

    Returns (dz, rms, ok); ``ok`` is False where fewer than 5 reference points are near.
    """
    n = len(query)
    if len(ref) < 5 or n == 0:
        return np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, bool)
    nbrs = neighbours or _GrowingNeighbours(x, y, ref, radius_m)
    dist, nb = nbrs.query(np.asarray(query, np.int64), min(k, len(ref)))
    dz, rms = _plane_offsets(np.asarray(x, float), np.asarray(y, float), np.asarray(z, float),
                             np.asarray(query, np.int64), nb, dist, min_points=5)
    return dz, rms, np.isfinite(dz)


def _near_mask(xa, ya, xb, yb, cell_m: float) -> np.ndarray:
    """Mask over points a lying in the 3x3 ``cell_m`` cells around any point b (so every a within
    ``cell_m`` of some b is included)."""
    if len(xb) == 0 or len(xa) == 0:
        return np.zeros(len(xa), bool)
    x0, y0 = float(min(np.min(xa), np.min(xb))) - cell_m, float(min(np.min(ya), np.min(yb))) - cell_m
    ncols = int(np.floor((max(np.max(xa), np.max(xb)) - x0) / cell_m)) + 3
    ia = np.floor((ya - y0) / cell_m).astype(np.int64) * ncols + np.floor((xa - x0) / cell_m).astype(np.int64)
    ib = np.floor((yb - y0) / cell_m).astype(np.int64) * ncols + np.floor((xb - x0) / cell_m).astype(np.int64)
    ib = np.unique(ib)
    keys = np.unique((ib[:, None] + (np.array([-1, 0, 1])[:, None] * ncols + np.array([-1, 0, 1])).ravel()).ravel())
    return np.isin(ia, keys)


def roof_edge_completion(x, y, z, is_building, candidates, p: ClassifySettings) -> None:
    """Grow building points (in place) over roof edges and low roof parts the cell rules missed.

    Edge cells of a roof hold pulses split between the eave and the wall or ground below, so they
    fail the multi-return and 3x3-plane tests; a lean-to roof sloping down to 1.5 m above the
    ground falls below the building height threshold. A candidate point joins the building when it
    lies within ``edge_tolerance_m`` of the local plane through its ``edge_neighbours`` nearest
    building points (within ``edge_radius_m``) and that plane fits them to the same tolerance (a
    planar roof continues; tree crowns beside the eave do not). Region growing: up to
    ``edge_iterations`` passes, each testing only the candidates next to the points added before.
    """
    cand = np.flatnonzero(candidates & ~is_building)
    ref = np.flatnonzero(is_building)
    if len(cand) == 0 or len(ref) < 5:
        return
    r = p.edge_radius_m
    # Only building points near a candidate can be its neighbours; the growth adds to them.
    ref = ref[_near_mask(x[ref], y[ref], x[cand], y[cand], r)]
    if len(ref) < 5:
        return
    neighbours = _GrowingNeighbours(x, y, ref, r)
    query = cand
    for _ in range(p.edge_iterations):
        if len(query) == 0:
            return
        dz, rms, ok = local_plane_offsets(x, y, z, ref, query, k=p.edge_neighbours, radius_m=r, neighbours=neighbours)
        add = ok & (np.abs(np.nan_to_num(dz, nan=np.inf)) < p.edge_tolerance_m)
        add &= np.nan_to_num(rms, nan=np.inf) < p.edge_tolerance_m
        if not add.any():
            return
        new = query[add]
        is_building[new] = True
        neighbours.add(new)
        cand = cand[~is_building[cand]]
        query = cand[_near_mask(x[cand], y[cand], x[new], y[new], r)]


def range_noise_m(x, y, z, surface, k: int = 8, sample: int = 20000) -> float:
    """Range noise (m): the robust spread (1.4826 MAD) of the heights of ``surface`` points (mask;
    the ground) above the LSQ plane of their ``k`` nearest ``surface`` neighbours, on a seeded
    sample of at most ``sample`` points. 0.05 m when the surface has too few points. The rooftop-object rule's
    fallback where the ground is too small for ``ground_noise_m`` (a sample of a tile's window would make its classes
    depend on the tiling)."""
    b = np.flatnonzero(surface)
    if len(b) < 4 * k:
        return 0.05
    q = np.random.default_rng(0).choice(b, min(sample, len(b)), replace=False) if len(b) > sample else b
    # cKDTree itself, not a BucketGrid: among 20,000 queries one or more tie (1 on a quarter of the demo), and a
    # BucketGrid answers those by building this same tree, so it only added its own cost (demo 1.84 -> 2.11 CPU-s).
    nbrs = _GrowingNeighbours(x, y, b, np.inf)
    dist, nb = nbrs.query(q, k + 1)
    dz = _plane_offsets(np.asarray(x, float), np.asarray(y, float), np.asarray(z, float), q, nb[:, 1:],
                        dist[:, 1:], min_points=5)[0]
    dz = dz[np.isfinite(dz)]
    return 1.4826 * float(np.median(np.abs(dz))) if len(dz) else 0.05


def rooftop_objects(x, y, z, is_building, spacing_m: float, noise_m: float, *, max_area_m2: float,
                    max_pitch_deg: float = 55.0, steps_to_roofs_only: bool = True) -> np.ndarray:
    """Building points that belong to objects standing on a roof (mask over all points).

    Building points within 2 point spacings are one surface when their height difference is at
    most 3 sigma of the range noise (``noise_m``, ``ground_noise_m`` of the ground) plus the rise of
    a roof pitched at ``max_pitch_deg`` over their horizontal distance; a rooftop unit, a cable or a crown over the
    roof is cut from the roof by its step. A surface component is an object when its area (point
    count x mean spacing^2) is below ``max_area_m2`` and it stands above the roof next to it: on at
    least 80 % of the neighbour pairs that cross to a component of at least ``max_area_m2`` it is the
    higher (steps to smaller components, such as a shed's wall returns, do not count;
    ``steps_to_roofs_only`` False: steps to any component count, the rule before issue 44's sheds).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    out = np.zeros(len(x), bool)
    b = np.flatnonzero(is_building)
    if len(b) < 10:
        return out
    xb, yb, zb = x[b] - x[b].min(), y[b] - y[b].min(), z[b]
    pairs = cKDTree(np.column_stack([xb, yb])).query_pairs(2.0 * spacing_m, output_type="ndarray")
    if len(pairs) == 0:
        return out
    i, j = pairs[:, 0], pairs[:, 1]
    dh = np.hypot(xb[i] - xb[j], yb[i] - yb[j])
    dz = zb[i] - zb[j]
    same = np.abs(dz) <= 3.0 * noise_m + dh * np.tan(np.radians(max_pitch_deg))
    graph = coo_matrix((np.ones(int(same.sum())), (i[same], j[same])), shape=(len(b), len(b)))
    ncomp, lab = connected_components(graph, directed=False)
    area_m2 = np.bincount(lab, minlength=ncomp) * spacing_m ** 2
    li, lj = lab[i[~same]], lab[j[~same]]
    up = dz[~same] > 0
    # Only steps to a roof-sized surface count: an object on a roof rises above the roof, while a
    # shed's roof rises above the few facade returns of its own walls (a small component too).
    roof_i, roof_j = area_m2[li] >= max_area_m2, area_m2[lj] >= max_area_m2
    if not steps_to_roofs_only:
        roof_i, roof_j = np.ones_like(roof_i), np.ones_like(roof_j)
    higher = np.bincount(li, up & roof_j, ncomp) + np.bincount(lj, ~up & roof_i, ncomp)
    crossing = np.bincount(li, roof_j, ncomp) + np.bincount(lj, roof_i, ncomp)
    obj = (area_m2 < max_area_m2) & (crossing > 0) & (higher >= 0.8 * np.maximum(crossing, 1))
    out[b[obj[lab]]] = True
    return out


def water_level(z, tol_m: float) -> tuple[float, float]:
    """Level (m) of the lowest well-populated height band of width ``tol_m / 2`` among the heights
    ``z`` of a gap's returns, and the robust spread (m, 1.4826 MAD) of the returns about it.

    Water is the lowest coherent surface in its gap (boats, pontoons and quays stand above it,
    low noise is already removed): the lowest band holding at least half as many returns as the
    densest band, refined twice by the median of the returns within ``tol_m / 2``.
    """
    zs = np.sort(np.asarray(z, float))
    width = 0.5 * tol_m
    count = np.searchsorted(zs, zs + width, side="right") - np.arange(len(zs))
    k = int(np.flatnonzero(count >= 0.5 * count.max())[0])
    level = float(np.median(zs[k:k + count[k]]))
    for _ in range(2):
        near = zs[np.abs(zs - level) <= width]
        level = float(np.median(near))
    sigma_m = 1.4826 * float(np.median(np.abs(near - level)))
    return level, sigma_m


def water_surface(x, y, z, tol_m: float, max_slope: float, min_points: int):
    """Level (m) of a water surface that slopes along its course, at every return (``x``, ``y``, ``z``: a gap's
    returns, metres), or None when the returns give no surface.

    A river is not at one level: it falls along its course (cm per 100 m in a pool, up to the steepest
    water surface ``max_slope`` over a riffle), so one level holds only a reach. The returns are cut into
    reaches of ``L = tol_m / max_slope`` (the length over which the steepest water surface falls by the
    level tolerance: within a reach one level holds to ``tol_m``); each reach with at least ``min_points``
    returns gets its ``water_level``. Where a reach's level differs from a neighbour's (4-connected) by more
    than the steepest surface's fall between them plus ``tol_m``, the step is a bank or a quay, not water:
    of the two, the reach further from the median reach level is dropped, its returns' levels NaN. The level
    at a return is the bilinear interpolation of the reach levels at the reach centres (missing reaches take
    the nearest reach's level), so a surface sloping at ``max_slope`` leaves no step at the reach borders.
    """
    reach_m = tol_m / max_slope if max_slope > 0 else np.inf
    n = len(z)
    if not np.isfinite(reach_m) or max(np.ptp(x), np.ptp(y)) <= reach_m:
        return None
    x0, y0 = float(x.min()), float(y.min())
    ix = ((x - x0) // reach_m).astype(np.int64)
    iy = ((y - y0) // reach_m).astype(np.int64)
    nr, nc = int(iy.max()) + 1, int(ix.max()) + 1
    cell = iy * nc + ix
    order = np.argsort(cell, kind="stable")
    starts = np.flatnonzero(np.r_[True, cell[order][1:] != cell[order][:-1]])
    lev = np.full(nr * nc, np.nan)
    for s, e in zip(starts, np.r_[starts[1:], n]):
        members = order[s:e]
        if len(members) >= min_points:
            lev[cell[members[0]]] = water_level(z[members], tol_m)[0]
    lev = lev.reshape(nr, nc)
    ok = np.isfinite(lev)
    if ok.sum() < 2:
        return None
    # A step between two neighbouring reaches is a bank or a quay: the reach further from the gap's median
    # level is dropped.
    step = max_slope * reach_m + tol_m
    far = np.abs(lev - np.median(lev[ok]))
    bank = np.zeros_like(ok)
    for a, b in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                 ((slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
        jump = ok[a] & ok[b] & (np.abs(lev[a] - lev[b]) > step)
        bank[a] |= jump & (far[a] >= far[b])
        bank[b] |= jump & (far[b] > far[a])
    ok &= ~bank
    if ok.sum() < 1:
        return None
    # A river falls along its course: a surface that rises and falls (an undulating field) is no river.
    if not falls_along_course(lev, ok, np.bincount(cell, minlength=nr * nc).reshape(nr, nc) > 0, tol_m):
        return None
    filled = lev[tuple(ndimage.distance_transform_edt(~ok, return_distances=False, return_indices=True))]
    # bilinear between the reach centres (rows run with y from the lowest y: sample_bilinear's grid with y0 at row 0)
    level = sample_bilinear(filled, x, y, cell_m=reach_m, x0=x0, y0=y0)
    level[~ok[iy, ix]] = np.nan
    return level


def falls_along_course(lev: np.ndarray, ok: np.ndarray, occupied: np.ndarray, tol_m: float) -> bool:
    """Whether the water surface of the reach levels ``lev`` (m; a grid of reaches, used where ``ok``) never
    rises by more than ``tol_m`` going one way along its course.

    Course coordinate of a reach (in reaches): its path length through the reaches holding returns
    (``occupied``, 8-connected) from the reaches at one end of the principal axis (within one reach of its
    lowest projection), so a bend is followed round; when some levelled reach is not connected to that end through
    returns, its projection on the principal axis. A river's cross-section is level, its long profile falls: the
    profile is the median level of the reaches in each one-reach step of the course, and it must be
    non-increasing to ``tol_m`` one way (no step stands more than ``tol_m`` above a step two or more upstream of it:
    a reach's place on the course is known to one reach, so neighbouring steps' medians at a riffle depend on where
    the grid cuts it; trial-us: Autzen's river turned to UTM rose 0.2045 m between two neighbouring steps).
    A surface that rises and falls (an undulating field) fails; so does a meander folded back on its
    principal axis far enough that both its ends lie at the low end (a missed river, not a false one)."""
    rr, cc = np.nonzero(ok)
    if len(rr) < 3:
        return True
    pts = np.column_stack([cc, rr]).astype(float)
    centred = pts - pts.mean(axis=0)
    t = centred @ np.linalg.svd(centred, full_matrices=False)[2][0]
    orr, occ = np.nonzero(occupied | ok)
    index = np.full(ok.shape, -1, np.int64)
    index[orr, occ] = np.arange(len(orr))
    rows, cols, wts = [], [], []
    h, w = ok.shape
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = orr + dr, occ + dc
        inside = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        j = np.full(len(orr), -1, np.int64)
        j[inside] = index[r2[inside], c2[inside]]
        has = j >= 0
        rows.append(np.flatnonzero(has))
        cols.append(j[has])
        wts.append(np.full(int(has.sum()), float(np.hypot(dr, dc))))
    graph = sparse.coo_matrix((np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(len(orr), len(orr))).tocsr()
    mine = index[rr, cc]
    along = csgraph.dijkstra(graph, directed=False, indices=mine[t - t.min() < 1.0], min_only=True)[mine]
    if np.all(np.isfinite(along)):
        t = along
    step = np.floor(t - t.min()).astype(np.int64)
    profile = np.array([np.median(lev[rr, cc][step == k]) for k in np.unique(step)])
    if len(profile) < 3:
        return True
    # A step is compared with the steps at least two upstream of it: neighbouring steps' reaches may lie at
    # nearly the same place on the course (the course coordinate of a reach is known to one reach), so their
    # medians differ with where the reach grid cuts a riffle, not with the river's fall.
    rise_down = float(np.max(profile[2:] - np.minimum.accumulate(profile)[:-2]))
    rise_up = float(np.max(np.maximum.accumulate(profile)[:-2] - profile[2:]))
    return min(rise_down, rise_up) <= tol_m


class _NearestLevel:
    """The level (m) of a sloping water surface at any place: that of the nearest water return."""

    def __init__(self, x, y, level):
        self._tree = cKDTree(np.column_stack([x, y]))
        self._level = np.asarray(level, float)

    def __call__(self, x, y) -> np.ndarray:
        if len(x) == 0:
            return np.zeros(0)
        return self._level[self._tree.query(np.column_stack([x, y]))[1]]


@dataclasses.dataclass(frozen=True)
class WaterGrid:
    """The whole cloud's water grid, for a tile classified apart from the rest of its cloud (``lidarctl.tiles``,
    issue 44): the cell (m: ``water_cell_m`` or 2 mean point spacings of the whole cloud), the origin of the
    whole cloud's grid (its lowest x, y, m) and the reference returns per cell (the median over the whole
    cloud's occupied cells). A tile's water cells are then the whole cloud's cells, judged against the whole
    cloud's density: a window that a river fills (most of its occupied cells holding the water's few returns)
    no longer lowers the dropout threshold below the water. ``window_m``: the tile's buffered box (xmin, ymin,
    xmax, ymax; infinite at the cloud's own edges); a cell whose 3 x 3 window is not wholly inside it (the
    buffer's edge cuts it, so it holds part of its returns) is no dropout."""

    cell_m: float
    x0_m: float
    y0_m: float
    median_count: float
    window_m: tuple = (-np.inf, -np.inf, np.inf, np.inf)
    # The survey's footprint: the whole cloud's 10 m cells (``COVERAGE_CELL_M`` from x0_m, y0_m) holding returns,
    # holes filled (``survey_footprint``); None: the tile's own points decide (as a whole cloud's do).
    footprint_10m: np.ndarray | None = dataclasses.field(default=None, compare=False)
    # The whole cloud's level water bodies (``whole_level_bodies``), for the level regions a tile's window cuts.
    level_bodies: LevelBodies | None = dataclasses.field(default=None, compare=False)   # or SpooledLevelBodies
    # The median intensity of the lowest return of the whole cloud's water cells (the land's reflectance, for a
    # window that open water fills; NaN: none).
    land_intensity: float = float("nan")
    # The whole cloud's mean point spacing (m, ``grid.mean_spacing_m``), from which ``cell_m`` (NaN: not given).
    spacing_m: float = float("nan")

    def cell_ids(self, x, y):
        """``grid.cell_ids`` of the points on this grid, its origin moved to the cell holding their lowest x, y."""
        c = self.cell_m
        x0 = self.x0_m + np.floor((float(np.min(x)) - self.x0_m) / c) * c
        y0 = self.y0_m + np.floor((float(np.min(y)) - self.y0_m) / c) * c
        return grid.cell_ids(x, y, c, x0, y0)

    def inside(self, nrows: int, ncols: int, x0: float, y0: float) -> np.ndarray:
        """Cells (nrows x ncols from x0, y0) whose 3 x 3 window lies inside ``window_m``."""
        c = self.cell_m
        xmin, ymin, xmax, ymax = self.window_m
        jx = x0 + np.arange(ncols) * c
        iy = y0 + np.arange(nrows) * c
        ok_x = (jx - c >= xmin) & (jx + 2 * c <= xmax)
        ok_y = (iy - c >= ymin) & (iy + 2 * c <= ymax)
        return ok_y[:, None] & ok_x[None, :]


@dataclasses.dataclass(frozen=True)
class LevelBodies:
    """Water cells of the whole cloud's level water bodies (``whole_level_bodies``): row and column on the whole
    cloud's water grid (``WaterGrid``: its cell and origin), flat keys ``row * ncols + col`` (sorted) and the
    level of each cell's body (m)."""

    ncols: int
    keys: np.ndarray
    level_m: np.ndarray

    @property
    def empty(self) -> bool:
        return not len(self.keys)

    def level_at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The body's level (m) at whole-grid cells ``rows``, ``cols`` (NaN: in no body)."""
        out = np.full(len(rows), np.nan)
        if not len(self.keys) or not len(rows):
            return out
        key = rows.astype(np.int64) * self.ncols + cols
        ok = (rows >= 0) & (cols >= 0) & (cols < self.ncols)
        pos = np.clip(np.searchsorted(self.keys, key), 0, len(self.keys) - 1)
        hit = ok & (self.keys[pos] == key)
        out[hit] = self.level_m[pos[hit]]
        return out


# The steepest bank (rise over run): dry earth rests at up to 35-40 degrees, riprap at about 34; a rim cell standing
# higher above the water than this over the rim's two cells is a wall, a roof or a crown (``whole_level_bodies``).
BANK_MAX_SLOPE = 1.0
# A rim cell standing higher than the steepest bank is a quay's wall when it is the land: it stands no higher above the
# lowest return within this reach (m; the water body's own cells and its rim aside, any other return however low:
# a street at the level of a yard among roofs is lower land, review 19) than the steepest bank rises across the rim;
# else it is an object on lower land (a roof, a crown) and no bank. The reach is the diameter of the
# ground filter's largest opening (2 x ``ground.MorphSettings.max_window_m``, 25 m): an object it leaves out of the
# ground, the tile's own pass (``level_water``, whose banks are ground cells) does not bank on either
# (level-bodies-sparse; chosen on that, not fitted).
WALL_BEHIND_M = 50.0


def whole_level_bodies_dense(cells: np.ndarray, heights: np.ndarray, wg: WaterGrid,
                             p: ClassifySettings) -> LevelBodies:
    """``whole_level_bodies`` on grids over the cells' bounding box (i44-edge-fixes; 69 bytes a cell of the box, review
    15): the reference its sparse version is tested and measured against. The level water bodies of a whole cloud
    from its water cells alone (the tiles' pass, ``tiles.water_grid``):
    ``cells`` (k, 2) row and column on the whole grid of ``wg`` (each cell once), ``heights`` (k, 3) each cell's
    lowest, median and highest return (m). ``level_water``'s rules on grid arrays, each cell as three returns at
    its centre: every return a candidate (a cell whose returns span at most 2 ``level_water_tol_m`` is level: over
    open water all are candidates; a crown in a cell spans more), the median the ground (the banks: a shore cell's
    mean ground lies above the water, its lowest return on it), the highest the open-sky test's (a return within
    one cell of a centre: the cell and its four neighbours); no split-pulse test (the tile applies it). Where every
    return is a candidate, roofs are level cells too: a region cut to its level is relabelled within itself (not
    joined to a neighbouring region at another level), and a rim cell standing above the steepest bank
    (``BANK_MAX_SLOPE``) banks on its lowest return or not at all (i44-edge-fixes, a courtyard among roofs). A body
    whose area or bed lies partly beyond a tile's window is then judged as a whole (issue 44, i44-edge). Grid
    arrays over the cells' bounding box, no per-return work (i44-edge-fixes: the cost of a grid pass, where three
    pseudo-returns a cell through ``level_water`` took 7 CPU-s and 1.2 GB per million cells)."""
    empty = LevelBodies(1, np.zeros(0, np.int64), np.zeros(0))
    tol = p.level_water_tol_m
    if not len(cells) or p.level_water_min_area_m2 <= 0:
        return empty
    c = wg.cell_m
    r_min, c_min = (int(v) for v in cells.min(axis=0))
    ncols_whole = int(cells[:, 1].max()) + 1
    nrows, ncols = int(cells[:, 0].max()) + 1 - r_min, ncols_whole - c_min
    rr, cc = cells[:, 0] - r_min, cells[:, 1] - c_min
    z = []   # lowest, median, highest return per cell (NaN: no returns)
    for k in range(3):
        a = np.full((nrows, ncols), np.nan)
        a[rr, cc] = heights[:, k]
        z.append(a)
    del rr, cc
    lo, ground, hi = z
    occupied = np.isfinite(ground)
    med = np.where(hi - lo <= 2.0 * tol, ground, np.nan)   # the level cells' median return
    ok = np.isfinite(med)
    if ok.sum() * c * c < p.level_water_min_area_m2:
        return empty
    lab = _level_regions(med, tol)
    shore_cells = max(1, int(np.ceil(p.water_shore_m / c)))
    water_bits = np.zeros((nrows, ncols), np.uint8)   # bit k: return k (lowest, median, highest) is water

    def bodies(lab: np.ndarray, joined: bool) -> None:
        """Marks in ``water_bits`` the level regions ``lab`` (region id per cell) that are water bodies."""
        size = np.bincount(lab.ravel())
        big = size * c * c >= p.level_water_min_area_m2
        big[0] = False
        if not big.any():
            return
        # Cut each large region to its level and relabel (a region may have crept along gentle slopes).
        level_of = np.full(len(size), np.nan)
        in_big = big[lab]
        ids = np.flatnonzero(big)
        level_of[ids] = ndimage.median(med[in_big], lab[in_big], ids)
        at_level = in_big & (np.abs(med - level_of[lab]) <= tol)
        del in_big
        if joined:
            # A body joined across a gap is one body even where its level cells do not touch.
            present = np.unique(lab[at_level])
            relabel = np.zeros(len(size), np.int32)
            relabel[present] = np.arange(1, len(present) + 1)
            labels = np.where(at_level, relabel[lab], 0)
            nlab = len(present)
        else:
            # Each region's cells at its level, 8-connected within the region only: two regions at different levels
            # side by side (a roof ring's level cells beside a courtyard's, every return a candidate here) are no
            # one region (``level_water`` joins them; there a roof is no candidate, reviewer 12d).
            labels = _level_regions(np.where(at_level, lab, np.nan).astype(float), 0.5)
            nlab = int(labels.max())
        del at_level
        if nlab == 0:
            return
        area = np.bincount(labels.ravel(), minlength=nlab + 1) * c * c
        boxes = ndimage.find_objects(labels)
        for k in np.flatnonzero(area[1:] >= p.level_water_min_area_m2) + 1:
            pad = shore_cells + 2
            r0, c0 = max(boxes[k - 1][0].start - pad, 0), max(boxes[k - 1][1].start - pad, 0)
            win = (slice(r0, boxes[k - 1][0].stop + pad), slice(c0, boxes[k - 1][1].stop + pad))
            region = labels[win] == k
            level = float(np.median(med[win][region]))
            rim = ndimage.binary_dilation(region, np.ones((3, 3), bool), 2) & ~region
            # A bank is ground rising from the water, not a wall: a rim cell's median standing higher than the
            # steepest bank reaches across the rim (``BANK_MAX_SLOPE`` over its two cells) is a roof or a crown; its
            # lowest return is the bank when that is within (ground through foliage), else the cell is no bank
            # (a roof ring round a level courtyard, reviewer 12d: as the ground filter leaves roofs out).
            steepest = level + BANK_MAX_SLOPE * 2.0 * c
            bank = ground[win][rim]
            bank = np.where(bank <= steepest, bank, np.where(lo[win][rim] <= steepest, lo[win][rim], np.nan))
            high = np.isnan(bank) & np.isfinite(ground[win][rim])
            if high.any():   # a quay's wall (the land) or an object on lower land (``WALL_BEHIND_M``)
                reach = int(np.ceil(WALL_BEHIND_M / c))
                ri, ci = np.nonzero(rim)
                ri, ci = ri[high] + r0, ci[high] + c0
                e0, f0 = max(int(ri.min()) - reach, 0), max(int(ci.min()) - reach, 0)
                ext = (slice(e0, int(ri.max()) + reach + 1), slice(f0, int(ci.max()) + reach + 1))
                # the land: any return but the body's own and its rim's (the water's cells beside a wall, whose
                # lowest return is on the water, are rim cells; a street at the water's level beyond a roof is land)
                own = labels[ext] == k
                wr, wc = np.nonzero(rim)
                wr, wc = wr + r0 - e0, wc + c0 - f0
                inside = (wr >= 0) & (wc >= 0) & (wr < own.shape[0]) & (wc < own.shape[1])
                own[wr[inside], wc[inside]] = True
                land = np.where(np.isfinite(lo[ext]) & ~own, lo[ext], np.inf)
                del own
                behind = ndimage.minimum_filter(land, size=2 * reach + 1, mode="constant",
                                                cval=np.inf)[ri - e0, ci - f0]
                top = lo[ri, ci]
                wall = top - behind <= BANK_MAX_SLOPE * 2.0 * c
                bank[np.flatnonzero(high)[wall]] = top[wall]
            bank = bank[np.isfinite(bank)]
            if len(bank) == 0 or np.mean(bank > level + tol) < p.level_water_bank_fraction:
                continue
            # Shore: the returns near the body at its level; open sky over them: no return well above the level
            # within a cell (a crown; the highest return of the cell and of its four neighbours).
            shore = ndimage.binary_dilation(region, np.ones((3, 3), bool), shore_cells)
            on = [shore & (np.abs(a[win] - level) <= tol) for a in z]
            sky = ndimage.maximum_filter(np.nan_to_num(hi[win], nan=-np.inf),
                                         footprint=ndimage.generate_binary_structure(2, 1), mode="constant",
                                         cval=-np.inf)
            covered = sky > level + p.low_veg_max_m
            members = sum((o & region).astype(np.int64) for o in on)
            if members.sum() and (members * covered).sum() / members.sum() > 0.05:
                continue   # a level floor under crowns is forest floor
            for bit, o in enumerate(on):
                water_bits[win] |= ((o & ~covered).astype(np.uint8) << bit)

    bodies(lab, False)
    if p.level_water_across_dropouts:
        # Level patches too small to be a body alone, joined across the gaps they border (``level_water``).
        small = np.bincount(lab.ravel()) * c * c < p.level_water_min_area_m2
        small[0] = False
        patches = np.where(small[lab], lab, 0).ravel()
        void = ~occupied
        if p.water_survey_coverage:   # beyond the survey is no gap a lake's shores border
            x0, y0 = wg.x0_m + c_min * c, wg.y0_m + r_min * c
            if wg.footprint_10m is not None:
                fp, fx0, fy0 = wg.footprint_10m, wg.x0_m, wg.y0_m
            else:   # the footprint of the cells' centres, as ``survey_beyond`` takes it from the returns
                i, j = np.nonzero(occupied)
                xc, yc = x0 + (j + 0.5) * c, y0 + (i + 0.5) * c
                fx0, fy0 = float(xc.min()), float(yc.min())
                fp = survey_footprint(occupied_10m(xc, yc, fx0, fy0))
                del i, j, xc, yc
            void &= ~beyond_coverage(occupied, c, x0, y0, fp, fx0, fy0)
        joined = _join_across_dropouts(patches, med, void.ravel(), tol)
        del void
        if joined is not patches:
            # Only the bodies made of two or more patches: the others were judged above.
            part = patches > 0
            pairs = np.unique(np.column_stack([joined[part], patches[part]]), axis=0)
            parts = np.bincount(pairs[:, 0], minlength=int(joined.max()) + 1)
            joined = np.where(parts[joined] >= 2, joined, 0)
            if joined.any():
                bodies(joined.reshape(nrows, ncols), True)
    water = water_bits > 0
    if not water.any():
        return empty
    blab, nlab = ndimage.label(water, np.ones((3, 3), int))
    # each body's level: the median of its water returns
    vals = [z[bit][(water_bits & (1 << bit)) > 0] for bit in range(3)]
    labs = [blab[(water_bits & (1 << bit)) > 0] for bit in range(3)]
    body_level = np.atleast_1d(ndimage.median(np.concatenate(vals), np.concatenate(labs), np.arange(1, nlab + 1)))
    i, j = np.nonzero(water)
    key = (i.astype(np.int64) + r_min) * ncols_whole + (j + c_min)
    return LevelBodies(ncols_whole, key, np.asarray(body_level, float)[blab[i, j] - 1])


def _level_regions(med: np.ndarray, tol: float) -> np.ndarray:
    """Level regions of a grid: cells with a finite ``med`` (m) joined to their 8 neighbours whose ``med`` differs by
    at most ``tol``; region id per cell (1..n, 0: not level). The joins along rows and columns are cells of a grid
    of twice the resolution (a cell, the join to its right, the join below) labelled 4-connected; the diagonal
    joins then merge those labels (a graph of labels, not of cells: memory of a few bytes per cell)."""
    nrows, ncols = med.shape
    g = np.zeros((2 * nrows - 1, 2 * ncols - 1), bool)
    g[::2, ::2] = np.isfinite(med)
    with np.errstate(invalid="ignore"):
        g[::2, 1::2] = np.abs(med[:, 1:] - med[:, :-1]) <= tol
        g[1::2, ::2] = np.abs(med[1:, :] - med[:-1, :]) <= tol
    lab2, n = ndimage.label(g)
    del g
    lab = lab2[::2, ::2].copy()
    del lab2
    pairs = []
    with np.errstate(invalid="ignore"):
        for a, b in (((slice(0, -1), slice(0, -1)), (slice(1, None), slice(1, None))),
                     ((slice(0, -1), slice(1, None)), (slice(1, None), slice(0, -1)))):
            e = np.abs(med[a] - med[b]) <= tol
            la, lb = lab[a][e], lab[b][e]
            differ = la != lb
            pairs.append(np.column_stack([la[differ], lb[differ]]))
    pairs = np.unique(np.concatenate(pairs), axis=0)
    if not len(pairs):
        return lab
    m = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n + 1,) * 2)
    _, comp = csgraph.connected_components(m, directed=False)
    ids = np.unique(comp[1:], return_inverse=True)[1] + 1
    return np.r_[0, ids].astype(lab.dtype)[lab]


# The cells of the survey's footprint (m): those of ``grid.mean_spacing_m`` (and of the tiles' first water-grid pass).
COVERAGE_CELL_M = 10.0


def occupied_10m(x, y, x0: float, y0: float) -> np.ndarray:
    """The ``COVERAGE_CELL_M`` cells from x0, y0 (rows along y) holding a return (bool, up to the points' largest
    cell)."""
    j = np.floor((np.asarray(x, float) - x0) / COVERAGE_CELL_M).astype(np.int64)
    i = np.floor((np.asarray(y, float) - y0) / COVERAGE_CELL_M).astype(np.int64)
    occ = np.zeros((int(i.max()) + 1, int(j.max()) + 1), bool)
    occ[i, j] = True
    return occ


# A channel of the survey's outline (10 m cells): an empty band with coverage on both sides -- a river or canal
# crossing the survey whose water returned no pulse -- up to 2 x this radius wide (100 m) lies inside the footprint
# (its bridges are decks over a gap, reviewer 12d: a 30-40 m river's decks were lost); within this many cells of the
# cloud's bounding box only the one-cell closing (there a closing this wide would fill the band beyond a strip's end
# in the corner it makes with another strip: the ragged-edge terraces).
FOOTPRINT_CHANNEL_CELLS = 5


def survey_footprint(occupied: np.ndarray) -> np.ndarray:
    """The survey's footprint on the 10 m cells: the cells holding returns, closed by one cell (3 x 3; the cloud's
    edge counts as empty), with their holes filled. A lake that mirrored every pulse lies inside, enclosed by its
    shores; so does a channel one 10 m cell wide that runs off the cloud's edge (a canal 10-20 m wide whose calm
    water returned nothing: its banks reach the edge on both sides); the band beyond a strip's end or side is open
    to the cloud's edge along its length and stays outside. More than ``FOOTPRINT_CHANNEL_CELLS`` cells from the
    cloud's bounding box, the footprint closed by a disk of that radius (the outside beyond the box open) is
    inside too: a river up to 100 m wide crossing the survey without returns is a channel between its banks, not
    the world beyond (a disk of that radius fits in the band beyond a strip's end, not in the river)."""
    closed = ndimage.binary_closing(np.pad(occupied, 2), np.ones((3, 3), bool))[2:-2, 2:-2]
    footprint = ndimage.binary_fill_holes(closed | occupied)
    r = FOOTPRINT_CHANNEL_CELLS
    if min(occupied.shape) <= 2 * r:
        return footprint
    i, j = np.mgrid[-r:r + 1, -r:r + 1]
    pad = 2 * r + 2
    wide = ndimage.binary_closing(np.pad(occupied, pad), np.hypot(i, j) <= r)[pad:-pad, pad:-pad]
    wide = ndimage.binary_fill_holes(wide | occupied)
    inner = np.zeros(occupied.shape, bool)
    inner[r:-r, r:-r] = True
    return footprint | (wide & inner)


def beyond_coverage(count: np.ndarray, c: float, x0: float, y0: float, footprint: np.ndarray,
                    fx0: float, fy0: float) -> np.ndarray:
    """Cells of a water grid (returns per cell ``count``, cells of ``c`` m from ``x0``, ``y0``) beyond the survey's
    coverage: the empty cells whose centre lies in a 10 m cell outside ``footprint`` (cells from ``fx0``,
    ``fy0``; beyond its extent is outside), and the empty cells joined to those (8-connected) within one 10 m cell
    of them -- the coverage's ragged edge, where the last scan lines end between the 10 m cells' centres."""
    nrows, ncols = count.shape
    outside = np.pad(~footprint, 1, constant_values=True)
    fringe = ndimage.binary_dilation(outside, np.ones((3, 3), bool))
    i = np.clip(np.floor((y0 + (np.arange(nrows) + 0.5) * c - fy0) / COVERAGE_CELL_M).astype(np.int64) + 1,
                0, outside.shape[0] - 1)
    j = np.clip(np.floor((x0 + (np.arange(ncols) + 0.5) * c - fx0) / COVERAGE_CELL_M).astype(np.int64) + 1,
                0, outside.shape[1] - 1)
    empty = count == 0
    near = empty & fringe[np.ix_(i, j)]
    lab, nlab = ndimage.label(near, np.ones((3, 3), int))
    if nlab == 0:
        return near
    seeded = np.zeros(nlab + 1, bool)
    seeded[lab[near & outside[np.ix_(i, j)]]] = True
    seeded[0] = False
    return seeded[lab]


def survey_beyond(x, y, count: np.ndarray, c: float, x0: float, y0: float,
                  water_grid: WaterGrid | None = None) -> np.ndarray:
    """``beyond_coverage`` of a water grid of the points ``x``, ``y``: the footprint of the whole cloud's 10 m cells
    (``water_grid``, a tile) or of these points (from their lowest x, y)."""
    if water_grid is not None and water_grid.footprint_10m is not None:
        return beyond_coverage(count, c, x0, y0, water_grid.footprint_10m, water_grid.x0_m, water_grid.y0_m)
    fx0, fy0 = float(np.min(x)), float(np.min(y))
    return beyond_coverage(count, c, x0, y0, survey_footprint(occupied_10m(x, y, fx0, fy0)), fx0, fy0)


# The side of a block of the sparse water grid (cells; ``whole_level_bodies``): only blocks holding a water cell (and,
# for the survey's coverage, those holding a cell of its footprint) are stored. 16 cells: a block of 1.4 m cells is
# 23 m, so a corridor 140 m wide stores 1.4 cells per occupied one (32 cells: 1.8; bench/level_bodies_sparse.py), and
# the block grid of a 50 km diagonal is 2.4 M entries.
LEVEL_BODIES_BLOCK_CELLS = 16


class _Blocks:
    """The cells of the active blocks (bool ``active``: blocks of ``side`` x ``side`` cells) of a grid of ``nrows`` x
    ``ncols`` cells, numbered block by block (index ``slot * side**2 + row_in_block * side + col_in_block``): a grid
    stored only where it is occupied. ``locate`` gives -1 for a cell beyond the grid, -2 for one in a block not
    stored."""

    def __init__(self, active: np.ndarray, nrows: int, ncols: int, side: int):
        self.side, self.nrows, self.ncols = side, nrows, ncols
        self.block_row, self.block_col = np.nonzero(active)
        self.slot = np.full(active.shape, -1, np.int64)
        self.slot[self.block_row, self.block_col] = np.arange(len(self.block_row))
        self.n = len(self.block_row) * side * side

    def rc(self, u: np.ndarray):
        """Row and column on the grid of cells ``u``."""
        s, rem = np.divmod(u, self.side * self.side)
        rem = rem.astype(np.int32)
        r = self.block_row[s].astype(np.int32) * self.side + rem // self.side
        c = self.block_col[s].astype(np.int32) * self.side + rem % self.side
        return r, c

    def locate(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        """The cells at rows ``r``, columns ``c`` (-1: beyond the grid; -2: in a block not stored)."""
        side = self.side
        s = self.slot[np.clip(r // side, 0, self.slot.shape[0] - 1), np.clip(c // side, 0, self.slot.shape[1] - 1)]
        out = s * (side * side) + (r % side) * side + c % side
        out[s < 0] = -2
        out[(r < 0) | (r >= self.nrows) | (c < 0) | (c >= self.ncols)] = -1
        return out

    def neighbour(self, u: np.ndarray, dr: int, dc: int) -> np.ndarray:
        r, c = self.rc(u)
        return self.locate(r + dr, c + dc)

    def block_rows(self) -> np.ndarray:
        """(stored blocks, side): the grid rows of each stored block's rows."""
        return self.block_row[:, None] * self.side + np.arange(self.side)

    def block_cols(self) -> np.ndarray:
        return self.block_col[:, None] * self.side + np.arange(self.side)

    def exists(self) -> np.ndarray:
        """The stored cells that lie on the grid (a block at its far edges is partly beyond)."""
        return ((self.block_rows() < self.nrows)[:, :, None] & (self.block_cols() < self.ncols)[:, None, :]).ravel()


def _components(g: _Blocks, member: np.ndarray, joins=None) -> np.ndarray:
    """Labels 1..n of the 8-connected components of the cells ``member`` of ``g`` (neighbours join when
    ``joins(u, v)`` holds, always without it); 0 elsewhere."""
    u = np.flatnonzero(member)
    out = np.zeros(g.n, np.int32)
    if not len(u):
        return out
    r, c = g.rc(u)
    parent = np.arange(len(u), dtype=np.int32)   # union-find over the members (positions in u)
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        v = g.locate(r + dr, c + dc)
        k = np.flatnonzero(v >= 0)
        k = k[member[v[k]]]
        if joins is not None:
            k = k[joins(u[k], v[k])]
        _union(parent, k.astype(np.int32), np.searchsorted(u, v[k]).astype(np.int32))
        del v, k
    del r, c
    out[u] = _root_labels(parent)
    return out


@numba.njit(cache=True)
def _union(parent, a, b):
    """Joins the sets of ``a[k]`` and ``b[k]`` (union-find ``parent``, in place; the root of a set is its lowest
    member, found by ``lidarctl.grid._find``: the edges come a direction at a time, not as ``grid._components``'
    whole graph, to keep one direction's arrays in memory)."""
    for k in range(len(a)):
        x, y = grid._find(parent, a[k]), grid._find(parent, b[k])
        if x != y:
            if x < y:
                parent[y] = x
            else:
                parent[x] = y


@numba.njit(cache=True)
def _root_labels(parent):
    """Labels 1..n of the sets of union-find ``parent`` (in order of their first member)."""
    out = np.zeros(len(parent), np.int32)
    n = 0
    for x in range(len(parent)):
        root = grid._find(parent, x)
        if root == x:
            n += 1
            out[x] = n
        else:
            out[x] = out[root]
    return out


def _group_median(values: np.ndarray, groups: np.ndarray, n: int) -> np.ndarray:
    """``np.median`` of ``values`` per group 0..n-1 (the mean of the two middle values; NaN: an empty group)."""
    order = np.lexsort((values, groups))
    v = values[order]
    count = np.bincount(groups, minlength=n)
    start = np.r_[0, np.cumsum(count)[:-1]]
    out = np.full(n, np.nan)
    has = count > 0
    out[has] = (v[(start + (count - 1) // 2)[has]] + v[(start + count // 2)[has]]) / 2
    return out


def _pairs_near(g: _Blocks, labels: np.ndarray, keep: np.ndarray, reach: int, occupied: np.ndarray):
    """(cell, label) pairs: the ``occupied`` cells within ``reach`` cells (Chebyshev, as a 3 x 3 dilation repeated)
    of a cell whose label is kept (``keep[label]``), outside that label; unique, sorted by cell. Only the region's
    edge cells (an 8-neighbour outside it) are sources: the straight path from any of its cells to a cell outside
    within reach leaves it at an edge cell within reach too."""
    src = np.flatnonzero(keep[labels])
    r, c = g.rc(src)
    src_lab = labels[src]
    edge = np.zeros(len(src), bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                v = g.locate(r + dr, c + dc)
                edge |= (v < 0) | (labels[np.maximum(v, 0)] != src_lab)
    src, r, c, src_lab = src[edge], r[edge], c[edge], src_lab[edge]
    del edge
    stride = np.int64(labels.max()) + 1
    found = np.zeros(0, np.int64)   # cell * stride + label
    for dr in range(-reach, reach + 1):
        keys = [found]
        for dc in range(-reach, reach + 1):
            if dr == dc == 0:
                continue
            v = g.locate(r + dr, c + dc)
            ok = np.flatnonzero(v >= 0)
            ok = ok[occupied[v[ok]] & (labels[v[ok]] != src_lab[ok])]
            keys.append(v[ok] * stride + src_lab[ok])
        found = np.unique(np.concatenate(keys))
    return found // stride, found % stride


# The cells ``_lowest_land_near`` takes at a time (the rows about each: ~75 keys a cell at 1.41 m cells): its memory
# is bounded by this, not by the rim cells above the steepest bank (a city of yards among roofs: 493 bytes a cell of
# the whole call, 70 % here, review 19).
LOWEST_LAND_CHUNK_CELLS = 4096


def _lowest_land_near(g: _Blocks, u: np.ndarray, body: np.ndarray, reach: int, lo: np.ndarray, labels: np.ndarray,
                      rim: np.ndarray, stride: np.int64) -> np.ndarray:
    """The lowest of ``lo`` (m) within ``reach`` cells (Chebyshev) of each cell ``u`` (inf: none), the cells of its
    body ``body`` (per cell of ``u``; ``labels`` per cell) and of that body's rim (``rim``: sorted keys
    ``cell * stride + body``) aside: the lowest along each row first (at the cells ``reach`` rows about ``u``, per
    body), then along the column; ``LOWEST_LAND_CHUNK_CELLS`` cells at a time, in order of body, row, column."""
    r, c = g.rc(u)
    order = np.lexsort((c, r, body))
    out = np.full(len(u), np.inf)
    span = np.arange(-reach, reach + 1)
    ncols = np.int64(g.ncols)
    for k in range(0, len(u), LOWEST_LAND_CHUNK_CELLS):
        sel = order[k:k + LOWEST_LAND_CHUNK_CELLS]
        rs, cs = r[sel], c[sel]
        ids, f = np.unique(body[sel], return_inverse=True)
        nf = np.int64(len(ids))

        def key(rows, cols, fs):
            return ((rows.astype(np.int64) + reach) * ncols + cols) * nf + fs

        keys = np.unique(key((rs[:, None] + span).ravel(), np.repeat(cs, len(span)), np.repeat(f, len(span))))
        fs = keys % nf
        rows = (keys // nf) // ncols - reach
        cols = (keys // nf) % ncols
        along_row = np.full(len(keys), np.inf)
        for dc in span:
            w = g.locate(rows, cols + dc)
            ok = np.flatnonzero(w >= 0)
            w = w[ok]
            z = lo[w]
            with np.errstate(invalid="ignore"):
                take = z < along_row[ok]   # only a lower return changes the minimum (NaN: no return)
            ok, w, z = ok[take], w[take], z[take]
            b = ids[fs[ok]]
            take = labels[w] != b
            ok, w, z, b = ok[take], w[take], z[take], b[take]
            pair = w * stride + b
            take = rim[np.minimum(np.searchsorted(rim, pair), len(rim) - 1)] != pair
            along_row[ok[take]] = z[take]
        for dr in span:
            out[sel] = np.minimum(out[sel], along_row[np.searchsorted(keys, key(rs + dr, cs, f))])
    return out


def _active_blocks_near_footprint(nbr: int, nbc: int, side: int, nrows: int, ncols: int, c: float, x0: float,
                                  y0: float, footprint: np.ndarray, fx0: float, fy0: float) -> np.ndarray:
    """Blocks (``nbr`` x ``nbc`` of ``side`` cells) holding a cell whose 10 m cell (as ``beyond_coverage`` finds it)
    lies in ``footprint``: every cell of another block without returns is outside it, beyond the coverage. Each
    block's rows of 10 m cells, then its columns, reduced by ``any`` (bool arrays of block rows by 10 m columns, not
    sums over the footprint's box: int64 running sums were 314 of 366 MB on a 50 km corridor, review 19)."""
    near = np.pad(footprint, 1, constant_values=False)
    if not near.any():
        return np.zeros((nbr, nbc), bool)

    def index(first, last, origin, start, n):
        f = lambda k: np.clip(np.floor((origin + (k + 0.5) * c - start) / COVERAGE_CELL_M).astype(np.int64) + 1,
                              0, n - 1)
        return f(first.astype(float)), f(last.astype(float))

    def any_between(a: np.ndarray, i0: np.ndarray, i1: np.ndarray) -> np.ndarray:
        """``a[i0[b]:i1[b] + 1].any(axis=0)`` for each b (rows of a, i0 <= i1)."""
        out = a[i0]
        for t in range(1, int((i1 - i0).max()) + 1):
            out |= a[np.minimum(i0 + t, i1)]
        return out

    b = np.arange(nbr)
    i0, i1 = index(b * side, np.minimum((b + 1) * side, nrows) - 1, y0, fy0, near.shape[0])
    b = np.arange(nbc)
    j0, j1 = index(b * side, np.minimum((b + 1) * side, ncols) - 1, x0, fx0, near.shape[1])
    rows = any_between(near, i0, i1)   # (block rows, 10 m columns)
    del near
    return any_between(rows.T, j0, j1).T


def whole_level_bodies(cells: np.ndarray, heights: np.ndarray, wg: WaterGrid, p: ClassifySettings) -> LevelBodies:
    """The level water bodies of a whole cloud from its water cells alone (the tiles' pass, ``tiles.water_grid``):
    ``cells`` (k, 2) row and column on the whole grid of ``wg`` (each cell once), ``heights`` (k, 3) each cell's
    lowest, median and highest return (m). The bodies of ``whole_level_bodies_dense`` (the same cells and levels,
    its rules), on the cells of the occupied blocks of ``LEVEL_BODIES_BLOCK_CELLS`` only (and, for the survey's
    coverage, of the blocks near its footprint): memory by the occupied cells, not by the cloud's bounding box (a
    diagonal corridor's box is mostly empty; level-bodies-sparse, review 15). Regions, gaps and bodies are
    components joined across the blocks (a graph of the cells); the dilations (rim, shore) are pairs of a cell and
    the region it lies near; a block not stored is beyond the coverage (``water_survey_coverage``) or one empty
    gap (without it)."""
    empty = LevelBodies(1, np.zeros(0, np.int64), np.zeros(0))
    tol = p.level_water_tol_m
    if not len(cells) or p.level_water_min_area_m2 <= 0:
        return empty
    c = wg.cell_m
    r_min, c_min = (int(v) for v in cells.min(axis=0))
    ncols_whole = int(cells[:, 1].max()) + 1
    nrows, ncols = int(cells[:, 0].max()) + 1 - r_min, ncols_whole - c_min
    rr, cc = cells[:, 0] - r_min, cells[:, 1] - c_min
    side = LEVEL_BODIES_BLOCK_CELLS
    nbr, nbc = -(-nrows // side), -(-ncols // side)
    active = np.zeros((nbr, nbc), bool)
    active[rr // side, cc // side] = True
    coverage = p.level_water_across_dropouts and p.water_survey_coverage
    x0, y0 = wg.x0_m + c_min * c, wg.y0_m + r_min * c
    if coverage:
        if wg.footprint_10m is not None:
            fp, fx0, fy0 = wg.footprint_10m, wg.x0_m, wg.y0_m
        else:   # the footprint of the cells' centres, as ``survey_beyond`` takes it from the returns
            xc, yc = x0 + (cc + 0.5) * c, y0 + (rr + 0.5) * c
            fx0, fy0 = float(xc.min()), float(yc.min())
            fp = survey_footprint(occupied_10m(xc, yc, fx0, fy0))
            del xc, yc
        active |= _active_blocks_near_footprint(nbr, nbc, side, nrows, ncols, c, x0, y0, fp, fx0, fy0)
    g = _Blocks(active, nrows, ncols, side)
    u = g.locate(rr, cc)
    del rr, cc
    z = []   # lowest, median, highest return per cell (NaN: no returns)
    for k in range(3):
        a = np.full(g.n, np.nan)
        a[u] = heights[:, k]
        z.append(a)
    del u
    lo, ground, hi = z
    occupied = np.isfinite(ground)
    med = np.where(hi - lo <= 2.0 * tol, ground, np.nan)   # the level cells' median return
    ok = np.isfinite(med)
    if ok.sum() * c * c < p.level_water_min_area_m2:
        return empty
    with np.errstate(invalid="ignore"):
        lab = _components(g, ok, lambda a, b: np.abs(med[a] - med[b]) <= tol)
    shore_cells = max(1, int(np.ceil(p.water_shore_m / c)))
    water_bits = np.zeros(g.n, np.uint8)   # bit k: return k (lowest, median, highest) is water

    def bodies(lab: np.ndarray, joined: bool) -> None:
        """Marks in ``water_bits`` the level regions ``lab`` (region id per cell) that are water bodies."""
        size = np.bincount(lab)
        big = size * c * c >= p.level_water_min_area_m2
        big[0] = False
        if not big.any():
            return
        level_of = np.full(len(size), np.nan)
        in_big = big[lab]
        ids = np.flatnonzero(big)
        level_of[ids] = ndimage.median(med[in_big], lab[in_big], ids)
        at_level = np.zeros(g.n, bool)
        k = np.flatnonzero(in_big)
        at_level[k] = np.abs(med[k] - level_of[lab[k]]) <= tol
        del in_big, k
        if joined:
            present = np.unique(lab[at_level])
            relabel = np.zeros(len(size), np.int32)
            relabel[present] = np.arange(1, len(present) + 1)
            labels = np.where(at_level, relabel[lab], 0)
        else:   # each region's cells at its level, 8-connected within the region only (``whole_level_bodies_dense``)
            labels = _components(g, at_level, lambda a, b: lab[a] == lab[b])
        del at_level
        nlab = int(labels.max())
        if nlab == 0:
            return
        area = np.bincount(labels, minlength=nlab + 1) * c * c
        good = area >= p.level_water_min_area_m2
        good[0] = False
        if not good.any():
            return
        in_good = good[labels]
        level = _group_median(med[in_good], labels[in_good], nlab + 1)
        del in_good
        # The bed: the rim (two cells beyond the region) banks as in ``whole_level_bodies_dense``.
        v, lv = _pairs_near(g, labels, good, 2, occupied)   # sorted by cell, then label
        steepest = level[lv] + BANK_MAX_SLOPE * 2.0 * c
        bank = np.where(ground[v] <= steepest, ground[v], np.where(lo[v] <= steepest, lo[v], np.nan))
        high = np.flatnonzero(np.isnan(bank))
        if len(high):   # a quay's wall (the land) or an object on lower land (``WALL_BEHIND_M``)
            stride = np.int64(nlab) + 1
            behind = _lowest_land_near(g, v[high], lv[high], int(np.ceil(WALL_BEHIND_M / c)), lo, labels,
                                       v * stride + lv, stride)
            wall = lo[v[high]] - behind <= BANK_MAX_SLOPE * 2.0 * c
            bank[high[wall]] = lo[v[high[wall]]]
        fin = np.isfinite(bank)
        n_bank = np.bincount(lv[fin], minlength=nlab + 1)
        n_above = np.bincount(lv[fin & (bank > level[lv] + tol)], minlength=nlab + 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            good &= (n_bank > 0) & ~(n_above / n_bank < p.level_water_bank_fraction)
        del v, lv, bank, fin
        if not good.any():
            return
        # Shore and open sky (the highest return of the cell and of its four neighbours).
        v, lv = _pairs_near(g, labels, good, shore_cells, occupied)
        own = np.flatnonzero(good[labels])
        v, lv = np.r_[own, v], np.r_[labels[own], lv]
        del own
        sky = np.where(occupied[v], hi[v], -np.inf)
        for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            w = g.neighbour(v, dr, dc)
            h = np.full(len(v), -np.inf)
            h[w >= 0] = np.nan_to_num(hi[w[w >= 0]], nan=-np.inf)
            sky = np.maximum(sky, h)
        covered = sky > level[lv] + p.low_veg_max_m
        with np.errstate(invalid="ignore"):
            on = [np.abs(a[v] - level[lv]) <= tol for a in z]
        region = labels[v] == lv
        members = sum((o & region).astype(np.int64) for o in on)
        n_members = np.bincount(lv, weights=members, minlength=nlab + 1)
        n_covered = np.bincount(lv, weights=members * covered, minlength=nlab + 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            good &= ~((n_members > 0) & (n_covered / n_members > 0.05))   # a level floor under crowns
        take = good[lv]
        for bit, o in enumerate(on):
            m = take & o & ~covered
            water_bits[v[m]] |= np.uint8(1 << bit)

    bodies(lab, False)
    if p.level_water_across_dropouts:
        # Level patches too small to be a body alone, joined across the gaps they border (``level_water``).
        small = np.bincount(lab) * c * c < p.level_water_min_area_m2
        small[0] = False
        patches = np.where(small[lab], lab, 0)
        exists = g.exists()
        void = exists & ~occupied
        if coverage:   # beyond the survey is no gap a lake's shores border (``beyond_coverage`` on the blocks)
            outside = np.pad(~fp, 1, constant_values=True)
            fringe = ndimage.binary_dilation(outside, np.ones((3, 3), bool))
            i = np.clip(np.floor((y0 + (g.block_rows().astype(float) + 0.5) * c - fy0) / COVERAGE_CELL_M)
                        .astype(np.int64) + 1, 0, outside.shape[0] - 1)[:, :, None]
            j = np.clip(np.floor((x0 + (g.block_cols().astype(float) + 0.5) * c - fx0) / COVERAGE_CELL_M)
                        .astype(np.int64) + 1, 0, outside.shape[1] - 1)[:, None, :]
            near = void & fringe[i, j].ravel()
            seed = near & outside[i, j].ravel()
            del i, j
            # a block not stored lies outside the footprint, its cells beyond: so are the near cells beside it
            e = np.flatnonzero(near)
            r, cl = g.rc(e)
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    if dr or dc:
                        seed[e[g.locate(r + dr, cl + dc) == -2]] = True
            del e, r, cl
            nlab_near = _components(g, near)
            seeded = np.zeros(int(nlab_near.max()) + 1, bool)
            seeded[nlab_near[seed]] = True
            seeded[0] = False
            void &= ~seeded[nlab_near]
            del near, seed, nlab_near, seeded
        joined = _join_across_dropouts_blocks(g, patches, med, void, tol, unstored_void=not coverage)
        del void
        if joined is not None:
            part = patches > 0
            pairs = np.unique(np.column_stack([joined[part], patches[part]]), axis=0)
            parts = np.bincount(pairs[:, 0], minlength=int(joined.max()) + 1)
            joined = np.where(parts[joined] >= 2, joined, 0)
            if joined.any():
                bodies(joined, True)
    water = water_bits > 0
    if not water.any():
        return empty
    blab = _components(g, water)
    nlab = int(blab.max())
    vals = [z[bit][(water_bits & (1 << bit)) > 0] for bit in range(3)]
    labs = [blab[(water_bits & (1 << bit)) > 0] for bit in range(3)]
    body_level = np.atleast_1d(ndimage.median(np.concatenate(vals), np.concatenate(labs), np.arange(1, nlab + 1)))
    u = np.flatnonzero(water)
    r, cl = g.rc(u)
    # int64: the whole grid's flat keys pass 2**31 beyond 46,341 cells square (46 km at 1 m cells, review 19)
    key = (r.astype(np.int64) + r_min) * ncols_whole + (cl.astype(np.int64) + c_min)
    order = np.argsort(key)
    return LevelBodies(ncols_whole, key[order], np.asarray(body_level, float)[blab[u[order]] - 1])


def _join_across_dropouts_blocks(g: _Blocks, lab: np.ndarray, med: np.ndarray, void: np.ndarray, tol: float,
                                 unstored_void: bool):
    """``_join_across_dropouts`` on the cells of ``g``: the joined region id per cell, or None when nothing
    joins. ``unstored_void``: the blocks not stored are empty gaps (the survey's coverage off), each group of them
    (8-connected) one gap with the stored empty cells beside it."""
    nreg = int(lab.max())
    unstored = np.zeros(g.slot.shape, bool)
    if unstored_void:
        unstored = g.slot < 0
    if nreg < 2 or not (void.any() or unstored.any()):
        return None
    vlab = _components(g, void)
    nv = int(vlab.max())
    blab, nb = ndimage.label(unstored, np.ones((3, 3), int))
    eight = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]

    def gap_of(u):
        """The gap (1..nv: stored cells; nv+1..: groups of blocks not stored; 0: none) beside cells ``u``, per
        neighbour direction."""
        r, c = g.rc(u)
        for dr, dc in eight:
            w = g.locate(r + dr, c + dc)
            gap = np.zeros(len(u), np.int64)
            s = w >= 0
            gap[s] = vlab[w[s]]
            if nb:
                s = w == -2
                gap[s] = nv + blab[(r[s] + dr) // g.side, (c[s] + dc) // g.side]
            yield gap

    if nb:   # the stored gaps beside blocks not stored are one gap with them
        vs = np.flatnonzero(void)
        a, b = [], []
        for gap in gap_of(vs):
            k = gap > nv
            a.append(vlab[vs[k]])
            b.append(gap[k])
        a, b = np.concatenate(a), np.concatenate(b)
        m = sparse.coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(nv + nb + 1,) * 2)
        _, comp = csgraph.connected_components(m, directed=False)
        gap_id = comp
    else:
        gap_id = np.arange(nv + 1)
    src = np.flatnonzero(lab > 0)
    pairs = []
    for gap in gap_of(src):
        k = gap > 0
        pairs.append(np.column_stack([gap_id[gap[k]], lab[src[k]]]))
    pairs = np.unique(np.concatenate(pairs), axis=0)
    if len(pairs) < 2:
        return None
    level = np.zeros(nreg + 1)
    present = np.unique(lab[src])
    level[present] = ndimage.median(med[src], lab[src], present)
    order = np.lexsort((level[pairs[:, 1]], pairs[:, 0]))
    v, r = pairs[order, 0], pairs[order, 1]
    link = (v[1:] == v[:-1]) & (np.abs(level[r[1:]] - level[r[:-1]]) <= tol)
    if not link.any():
        return None
    m = sparse.coo_matrix((np.ones(int(link.sum())), (r[:-1][link], r[1:][link])), shape=(nreg + 1,) * 2)
    _, comp = csgraph.connected_components(m, directed=False)
    ids = np.unique(comp[1:], return_inverse=True)[1] + 1
    return np.r_[0, ids].astype(np.int32)[lab]


def water_cell_size_m(spacing_m: float, p: ClassifySettings) -> float:
    """The water grid's cell (m): ``water_cell_m``, or 2 mean point spacings of the cloud and at least 1 m."""
    return p.water_cell_m or max(1.0, 2.0 * spacing_m)


def water_cells(x, y, spacing_m: float, p: ClassifySettings, water_grid: WaterGrid | None = None):
    """The water grid's cell (m, ``water_cell_size_m``) and ``grid.cell_ids`` of the points on it from the cloud's
    lowest x, y; with ``water_grid`` (a tile) the whole cloud's cell and origin."""
    if water_grid is None:
        c = water_cell_size_m(spacing_m, p)
        return c, grid.cell_ids(x, y, c)
    return water_grid.cell_m, water_grid.cell_ids(x, y)


@dataclasses.dataclass
class DropoutGrid:
    """The water grid of step 5 (cells of ``c`` m): the cell id of every point, the returns per
    cell, the 8-connected pulse-dropout regions (3x3-window return count below
    ``water_density_ratio`` of the median occupied cell, so single empty cells in a sparse scan do
    not count; labels 1..nlab, 0 elsewhere) with their areas (m2), the cells holding building
    points (for the occlusion-shadow test at a region's rim) and the cells whose returns are all known
    (``known``: all but those at a tile's buffer edge, ``WaterGrid.inside``; no rim or bank there)."""

    c: float
    flat: np.ndarray
    nrows: int
    ncols: int
    x0: float
    y0: float
    count: np.ndarray
    median_count: float
    labels: np.ndarray
    nlab: int
    area_m2: np.ndarray
    building_cell: np.ndarray
    known: np.ndarray | None = None
    # cells beyond the survey's coverage (``survey_beyond``; None: not asked): no gap a deck spans
    beyond: np.ndarray | None = None

    def rim(self, win, region) -> np.ndarray:
        """The rim (two cells wide) of ``region`` (a mask over the window ``win`` of the grid), known cells only."""
        rim = ndimage.binary_dilation(region, np.ones((3, 3), bool), 2) & ~region
        return rim if self.known is None else rim & self.known[win]

    def ground_cell_z(self, x, y, z, is_ground) -> np.ndarray:
        """Mean height (m) of the ``is_ground`` points per cell (NaN without)."""
        return reduce_grid(x[is_ground], y[is_ground], z[is_ground], cell_m=self.c, x0=self.x0, y0=self.y0,
                           nrows=self.nrows, ncols=self.ncols, how="mean")


def dropout_grid(x, y, is_building, spacing_m: float, p: ClassifySettings,
                 water_grid: WaterGrid | None = None) -> DropoutGrid:
    """The ``DropoutGrid`` of the cloud (cell ``water_cell_m``, default max(1 m, 2 point spacings)); with
    ``water_grid`` (a tile of a larger cloud) its cell, origin and reference count."""
    c, (flat, nrows, ncols, x0, y0) = water_cells(x, y, spacing_m, p, water_grid)
    count = np.bincount(flat, minlength=nrows * ncols).reshape(nrows, ncols).astype(float)
    occupied = count > 0
    if water_grid is None:
        median_count = float(np.median(count[occupied])) if occupied.any() else 0.0
    else:
        median_count = water_grid.median_count
    dropout = ndimage.uniform_filter(count, 3, mode="nearest") < p.water_density_ratio * median_count
    beyond = survey_beyond(x, y, count, c, x0, y0, water_grid) if p.water_survey_coverage else None
    known = None
    if water_grid is not None:
        known = water_grid.inside(nrows, ncols, x0, y0)
        dropout &= known
    labels, nlab = ndimage.label(dropout, np.ones((3, 3), int))
    area_m2 = np.bincount(labels.ravel(), minlength=nlab + 1) * c * c
    building_cell = np.bincount(flat[is_building], minlength=nrows * ncols).reshape(nrows, ncols) > 0
    return DropoutGrid(c, flat, nrows, ncols, x0, y0, count, median_count, labels, nlab, area_m2, building_cell,
                       known, beyond)


def detect_water(x, y, z, intensity, candidate, is_building, *, is_ground, spacing_m: float,
                 p: ClassifySettings, solid=None, dropout: DropoutGrid | None = None,
                 land_intensity: float | None = None) -> np.ndarray:
    """Water returns (mask) by pulse-dropout water detection; see the module docstring, step 5.

    ``candidate``: points that may be water returns (ground, unclassified, low vegetation);
    ``is_building`` / ``is_ground``: class masks for the occlusion-shadow and bank tests;
    ``solid``: the points that are not noise (default all), for the canopy test; ``dropout``: the
    cloud's ``dropout_grid`` when the caller has it; ``land_intensity``: a tile's whole cloud's reference
    (``WaterGrid.land_intensity``), taken when most of the window's ground lies in open-water-sized gaps.
    Heights in metres; intensity in the sensor's units (only ratios to the cloud's median are used).
    """
    n = len(x)
    water = np.zeros(n, bool)
    g = dropout if dropout is not None else dropout_grid(x, y, is_building, spacing_m, p)
    if g.nlab == 0:
        return water
    c, flat, ncols, count, median_count = g.c, g.flat, g.ncols, g.count, g.median_count
    labels, area_m2, building_cell = g.labels, g.area_m2, g.building_cell
    # Canopy: the returns within one water cell (m) horizontally of a point. A pulse that reached the
    # level below a crown is ground seen through foliage, not open water. The KD-tree is built only
    # when a gap gets this far (most tiles have none), over the returns that can stand more than
    # ``low_veg_max_m`` above any level (levels are heights of candidate returns).
    canopy = {}

    def open_sky(idx, level):
        """Mask over ``idx``: no return more than ``low_veg_max_m`` above ``level`` (m, one or one per
        point of ``idx``) within ``c``."""
        if len(idx) == 0:
            return np.zeros(0, bool)
        if not canopy:
            tall = np.ones(n, bool) if solid is None else np.asarray(solid, bool).copy()
            tall &= z > np.min(z[candidate]) + p.low_veg_max_m
            canopy["idx"] = np.flatnonzero(tall)
            canopy["tree"] = cKDTree(np.column_stack([x[canopy["idx"]], y[canopy["idx"]]]))
        near = canopy["tree"].query_ball_point(np.column_stack([x[idx], y[idx]]), c)
        lens = np.fromiter((len(v) for v in near), np.int64, len(near))
        if not lens.sum():
            return np.ones(len(idx), bool)
        nb = canopy["idx"][np.concatenate([np.asarray(v, np.int64) for v in near])]
        high = np.zeros(len(idx), bool)
        owner = np.repeat(np.arange(len(idx)), lens)
        above = np.broadcast_to(np.asarray(level, float), (len(idx),))[owner] + p.low_veg_max_m
        np.logical_or.at(high, owner, z[nb] > above)
        return ~high

    ground_cell_z = g.ground_cell_z(x, y, z, is_ground)
    lab_pt = labels.ravel()[flat]
    # Clouds without intensity (a constant field) skip the reflectance test.
    use_intensity = intensity is not None and is_ground.any() and np.ptp(np.asarray(intensity)[is_ground]) > 0
    if use_intensity:
        inten = np.asarray(intensity, float)
        ground_intensity = float(np.median(inten[is_ground]))
        if land_intensity is not None and np.isfinite(land_intensity):
            # A tile's window that open water fills (most of its ground returns in open-water-sized gaps) has no
            # land to measure the darkness against: the whole cloud's (issue 44, a lake larger than a tile).
            gap_ground = is_ground & (lab_pt > 0) & (area_m2[lab_pt] >= p.water_min_area_m2)
            if gap_ground.sum() > 0.5 * is_ground.sum():
                ground_intensity = float(land_intensity)
    cand = np.flatnonzero(candidate & (lab_pt > 0) & (area_m2[lab_pt] >= p.water_min_area_m2))
    if len(cand) == 0:
        return water
    shore_cand = np.flatnonzero(candidate & (lab_pt == 0))
    shore_row, shore_col = np.divmod(flat[shore_cand], ncols)
    shore_cells = max(1, int(np.ceil(p.water_shore_m / c)))
    boxes = ndimage.find_objects(labels)
    cand = cand[np.argsort(lab_pt[cand], kind="stable")]
    lab_c = lab_pt[cand]
    starts = np.flatnonzero(np.r_[True, lab_c[1:] != lab_c[:-1]])
    tol = p.water_level_tol_m
    why = {}   # gap -> why it is no water (``WATER_REJECT_LOG_M2``)

    def judge(members, k, level, sigma_m, surface):
        """The water returns of gap ``k`` (its ``members``) at one ``level`` (``surface`` None) or on the sloping
        ``surface`` (m at each member; ``level`` the gap's one level), or None when the gap is not water."""
        zg = z[members]
        level_of = None   # the level at a point (m) where the surface slopes along a river's course
        if surface is not None:
            res = zg - surface
            near_res = np.abs(res[np.abs(res) <= 0.5 * tol])
            sigma_m = 1.4826 * float(np.median(near_res)) if len(near_res) else tol
            level_z = surface
            on_surface = np.isfinite(surface)
            level_of = _NearestLevel(x[members][on_surface], y[members][on_surface], surface[on_surface])
        else:
            level_z = np.full(len(zg), level)
        # The water returns' own spread (sensor noise, waves) sets how far from the level they lie.
        on_tol = np.clip(3.0 * sigma_m, 0.25 * tol, tol)
        on = np.abs(zg - level_z) <= on_tol
        on_level = members[on]
        # Open water has nothing above it: returns under a crown (any return more than
        # ``low_veg_max_m`` above the level within one cell) are not water.
        on_level = on_level[open_sky(on_level, level_z[on] if level_of is not None else level)]
        if len(on_level) < p.water_min_points:
            why[k] = f"{len(on_level)} returns on its level under open sky, {p.water_min_points} needed"
            return None
        # Horizontal: least-squares plane through the level returns.
        a = np.column_stack([x[on_level] - x[on_level].mean(), y[on_level] - y[on_level].mean(),
                             np.ones(len(on_level))])
        coef = np.linalg.lstsq(a, z[on_level], rcond=None)[0]
        slope = np.hypot(coef[0], coef[1])
        if slope > p.water_max_slope:
            why[k] = f"its level returns slope {slope:.4f}, at most {p.water_max_slope} allowed"
            return None
        if use_intensity:
            quartile = np.percentile(inten[on_level], 25)
            if quartile >= p.water_intensity_ratio * ground_intensity:
                why[k] = (f"its returns are not dark (quartile intensity {quartile:.0f}, below "
                          f"{p.water_intensity_ratio * ground_intensity:.0f} needed)")
                return None
        # The region's bounding box, padded for the rim and the shore (whole-grid work per region
        # would cost O(regions x cells)).
        pad = shore_cells + 1
        r0, c0 = max(boxes[k - 1][0].start - pad, 0), max(boxes[k - 1][1].start - pad, 0)
        win = (slice(r0, boxes[k - 1][0].stop + pad), slice(c0, boxes[k - 1][1].stop + pad))
        region = labels[win] == k
        rim = g.rim(win, region)
        shadow = building_cell[win][rim].mean() if rim.any() else 0.0
        if shadow > p.water_shadow_fraction:
            why[k] = f"{shadow:.0%} of its rim is building (a shadow), at most {p.water_shadow_fraction:.0%} allowed"
            return None
        # Water lies in its bed: the ground on the banks is not below the water level.
        bank_z = ground_cell_z[win][rim]
        if level_of is not None:
            # Each bank cell against the river's level beside it. The banks are the rim of the gap with its holes
            # filled: cells inside it that hold returns (foam on a riffle, a patch that returned the pulse) are
            # the river, not its bank (as many of them as a tile's window holds, issue 44).
            rim = g.rim(win, ndimage.binary_fill_holes(region))
            rr, cc = np.nonzero(rim & np.isfinite(ground_cell_z[win]))
            bank_z = ground_cell_z[win][rr, cc] - level_of(g.x0 + (cc + c0 + 0.5) * c,
                                                           g.y0 + (rr + r0 + 0.5) * c) + level
        bank_z = bank_z[np.isfinite(bank_z)]
        if len(bank_z) and np.median(bank_z) < level - tol:
            why[k] = f"its banks lie {level - np.median(bank_z):.2f} m below its level (median)"
            return None
        # A sloping surface is a river only in a bed: most of its banks stand more than the tolerance above the
        # level beside them (a car park or road draining at 1 % lies level with, or above, its surroundings).
        if level_of is not None and (not len(bank_z) or np.mean(bank_z > level + tol) < 0.5):
            why[k] = (f"on its sloping surface {np.mean(bank_z > level + tol) if len(bank_z) else 0:.0%} of its "
                      f"banks stand above the level beside them, 50 % needed")
            return None
        # Shore: the 3x3 dropout window misses the water returns next to the banks; returns within
        # ``water_shore_m`` of the body at its level join when they are dark too.
        shore = ndimage.binary_dilation(region, np.ones((3, 3), bool), shore_cells)
        i, j = shore_row - r0, shore_col - c0
        inside = (i >= 0) & (i < shore.shape[0]) & (j >= 0) & (j < shore.shape[1])
        inside[inside] = shore[i[inside], j[inside]]
        if level_of is None:
            near = shore_cand[inside & (np.abs(z[shore_cand] - level) <= on_tol)]
            near = near[open_sky(near, level)]
        else:
            near = shore_cand[inside]
            near_level = level_of(x[near], y[near])
            keep = np.abs(z[near] - near_level) <= on_tol
            near, near_level = near[keep], near_level[keep]
            near = near[open_sky(near, near_level)]
        if use_intensity:
            # As dark as the body's own returns (dark asphalt beside a pond is not water).
            dark = min(p.water_intensity_ratio * ground_intensity,
                       2.0 * np.median(inten[on_level]))
            near = near[inten[near] < dark]
        else:
            near = near[count.ravel()[flat[near]] < p.water_density_ratio * median_count]
        return on_level, near

    for members in np.split(cand, starts[1:]):
        k = int(lab_pt[members[0]])
        zg = z[members]
        if len(zg) < p.water_min_points:
            continue
        level, sigma_m = water_level(zg, tol)
        n_level = int(np.sum(np.abs(zg - level) <= tol))
        one_level = n_level >= p.water_min_points and n_level >= p.water_flat_fraction * len(zg)
        tries = [None] if one_level else []
        if p.water_sloping_surface and (not one_level or len(zg) - n_level >= p.water_min_points):
            # Not all at one level: a river falls along its course (``water_surface``). It is judged on its
            # sloping surface when that holds the flat share of the returns and, where one level holds the
            # gap too, more than half of the returns that level leaves off (a piece of a river short enough
            # for one level still falls: a tile that sees a shorter piece of it than the whole cloud must
            # not see less water, issue 44); that failing, the one level's verdict.
            surface = water_surface(x[members], y[members], zg, tol, p.water_max_slope, p.water_min_points)
            if surface is not None:
                n_surface = int(np.sum(np.abs(zg - surface) <= tol))
                if n_surface >= p.water_min_points and n_surface >= p.water_flat_fraction * len(zg) and \
                        (not one_level or n_surface - n_level > 0.5 * (len(zg) - n_level)):
                    tries.insert(0, surface)
        if not tries:
            why[k] = (f"one level holds {n_level / len(zg):.1%} of its {len(zg):,} returns ({p.water_flat_fraction:.0%} "
                      "needed) and no sloping water surface fits them")
        for surface in tries:
            found = judge(members, k, level, sigma_m, surface)
            if found is not None:
                water[found[0]] = True
                water[found[1]] = True
                break
        else:
            if area_m2[k] >= WATER_REJECT_LOG_M2:
                log.info("a candidate water body of %.0f m2 (a dropout gap, level %.2f m) is no water: %s", area_m2[k],
                         level, why.get(k, "no test passed"))
    return water


# Level water (``level_water``): a calm lake that returns the pulse is a surface level to centimetres
# over a large area; terrain is not (it drains, so it slopes), and a level floor (a car park, a
# square) ends at a curb or a street below it, where water stands in a bed whose banks rise above it.
def level_water(x, y, z, candidate, is_ground, spacing_m: float, *, p: ClassifySettings, solid=None,
                number_of_returns=None, water_grid: WaterGrid | None = None) -> np.ndarray:
    """Water returns (mask) of calm water bodies that returned the pulse (no dropout needed).

    On the water grid (``water_cell_m``, default max(1 m, 2 point spacings)) a cell is level when its
    ``candidate`` returns span at most 2 ``level_water_tol_m``. Level cells whose medians differ by at
    most ``level_water_tol_m`` are joined (8-connected); each region is cut to the cells within
    ``level_water_tol_m`` of its level (median of the cell medians) and relabelled. A region is a water
    body when (a) its area is at least ``level_water_min_area_m2``; (b) it lies in a bed: at least
    ``level_water_bank_fraction`` of the ground cells on its rim (two cells wide) stand more than
    ``level_water_tol_m`` above the level (a floor's rim is a curb down or more floor at its level);
    (c) open sky: no return more than ``low_veg_max_m`` above the level within one cell (ground seen
    through crowns is never water); (d) where the cloud records returns per pulse, at most 5 % of its
    returns are from split pulses (nothing beneath a water surface). Shore: candidate returns within
    ``water_shore_m`` of the body at its level (within ``level_water_tol_m``) are water, those above
    it are the bank -- the level decides, not the distance. ``water_grid``: the whole cloud's cell and origin
    for a tile of it (``WaterGrid``).
    """
    n = len(x)
    water = np.zeros(n, bool)
    tol = p.level_water_tol_m
    if p.level_water_min_area_m2 <= 0 or not candidate.any():
        return water
    c, (flat, nrows, ncols, x0, y0) = water_cells(x, y, spacing_m, p, water_grid)
    ci = np.flatnonzero(candidate)
    order = ci[np.lexsort((z[ci], flat[ci]))]
    cell = flat[order]
    start = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
    cnt = np.diff(np.r_[start, len(cell)])
    zs = z[order]
    zmin, zmax = zs[start], zs[start + cnt - 1]
    zmed = 0.5 * (zs[start + (cnt - 1) // 2] + zs[start + cnt // 2])
    med = np.full(nrows * ncols, np.nan)
    level_cell = (zmax - zmin) <= 2.0 * tol
    med[cell[start[level_cell]]] = zmed[level_cell]
    med = med.reshape(nrows, ncols)
    ok = np.isfinite(med)
    if ok.sum() * c * c < p.level_water_min_area_m2:
        return water
    # 8-connected joins of level cells at the same height: union-find over the grid edges.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    idx = np.arange(nrows * ncols).reshape(nrows, ncols)
    rows, cols = [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = (slice(0, nrows - dr), slice(max(0, -dc), ncols - max(0, dc)))
        b = (slice(dr, nrows), slice(max(0, dc), ncols - max(0, -dc)))
        e = ok[a] & ok[b] & (np.abs(med[a] - med[b]) <= tol)
        rows.append(idx[a][e])
        cols.append(idx[b][e])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    m = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(nrows * ncols,) * 2)
    _, lab = connected_components(m, directed=False)
    lab = np.where(ok.ravel(), lab + 1, 0)
    ground_cell_z = reduce_grid(x[is_ground], y[is_ground], z[is_ground], cell_m=c, x0=x0, y0=y0, nrows=nrows,
                                ncols=ncols, how="mean")
    tall = np.ones(n, bool) if solid is None else np.asarray(solid, bool).copy()
    tall_idx = np.flatnonzero(tall)
    tree = []
    multi = None if number_of_returns is None else np.asarray(number_of_returns) > 1
    if multi is not None and not multi.any():
        multi = None
    shore_cells = max(1, int(np.ceil(p.water_shore_m / c)))
    # A tile of a larger cloud: the level of the whole cloud's level water body at each cell (NaN: none), and the
    # cells near the window's cut edge (a region reaching them has area and banks beyond the window).
    outer, cut = None, None
    if water_grid is not None and water_grid.level_bodies is not None and not water_grid.level_bodies.empty:
        cut = ~water_grid.inside(nrows, ncols, x0, y0)
        if cut.any():
            rr, cc = np.divmod(np.arange(nrows * ncols), ncols)
            r_off = int(round((y0 - water_grid.y0_m) / c))
            c_off = int(round((x0 - water_grid.x0_m) / c))
            outer = water_grid.level_bodies.level_at(rr + r_off, cc + c_off).reshape(nrows, ncols)
            if not np.isfinite(outer).any():
                outer = None
            cut = ndimage.binary_dilation(cut, np.ones((3, 3), bool), shore_cells + 2)

    def bodies(lab, joined: bool) -> np.ndarray:
        """Water returns of the level regions ``lab`` (region id per cell) that are water bodies."""
        water = np.zeros(n, bool)
        size = np.bincount(lab)
        big = size * c * c >= p.level_water_min_area_m2
        big[0] = False
        if not big.any():
            return water
        # Cut each large region to its level and relabel (a region may have crept along gentle slopes).
        level_of = np.full(len(size), np.nan)
        keep = big[lab]
        for k in np.flatnonzero(big):
            level_of[k] = np.median(med.ravel()[lab == k])
        at_level = keep & (np.abs(med.ravel() - np.nan_to_num(level_of[lab], nan=np.inf)) <= tol)
        if joined:
            # A body joined across a gap is one body even where its level cells do not touch.
            ids, inv = np.unique(np.where(at_level, lab, 0), return_inverse=True)
            labels = (inv.reshape(nrows, ncols) if ids[0] == 0 else inv.reshape(nrows, ncols) + 1).astype(np.int64)
            nlab = int(labels.max())
        else:
            labels, nlab = ndimage.label(at_level.reshape(nrows, ncols), np.ones((3, 3), int))
        if nlab == 0:
            return water
        area = np.bincount(labels.ravel(), minlength=nlab + 1) * c * c
        boxes = ndimage.find_objects(labels)
        lab_pt = labels.ravel()[flat]
        judged = area >= p.level_water_min_area_m2
        in_whole = np.zeros(nlab + 1, bool)
        if outer is not None:
            # Regions the window cuts that lie in a whole-cloud body (most of their cells): their area and bed
            # are the whole body's (issue 44: a lake larger than a tile and its buffer).
            ids = np.arange(1, nlab + 1)
            in_whole[1:] = (ndimage.maximum(cut, labels, ids) > 0) & \
                (ndimage.mean(np.isfinite(outer), labels, ids) > 0.5)
            judged |= in_whole
        judged[0] = False
        for k in np.flatnonzero(judged):
            pad = shore_cells + 2
            r0, c0 = max(boxes[k - 1][0].start - pad, 0), max(boxes[k - 1][1].start - pad, 0)
            win = (slice(r0, boxes[k - 1][0].stop + pad), slice(c0, boxes[k - 1][1].stop + pad))
            region = labels[win] == k
            level = float(np.median(med[win][region]))
            whole_body = in_whole[k] and abs(float(np.nanmedian(outer[win][region])) - level) <= tol
            if not whole_body:
                if area[k] < p.level_water_min_area_m2:
                    continue
                rim = ndimage.binary_dilation(region, np.ones((3, 3), bool), 2) & ~region
                bank = ground_cell_z[win][rim]
                bank = bank[np.isfinite(bank)]
                if len(bank) == 0 or np.mean(bank > level + tol) < p.level_water_bank_fraction:
                    if area[k] >= WATER_REJECT_LOG_M2:
                        at = lab_pt == k  # where it lies (s95: the note named no place to look at)
                        log.info("a level candidate water body of %.0f m2 (level %s) about %s is no "
                                 "water: %.0f %% of the ground on its rim stands above its level, %.0f %% needed",
                                 area[k], _height(level), _place(float(np.mean(x[at])) if at.any() else math.nan,
                                                                 float(np.mean(y[at])) if at.any() else math.nan),
                                 100.0 * np.mean(bank > level + tol) if len(bank) else 0.0,
                                 100.0 * p.level_water_bank_fraction)
                    continue
            members = np.flatnonzero(candidate & (lab_pt == k))
            members = members[np.abs(z[members] - level) <= tol]
            if multi is not None and np.mean(multi[members]) > 0.05:
                continue
            if not tree:
                tree.append(cKDTree(np.column_stack([x[tall_idx], y[tall_idx]])))
            # Shore: candidates near the body at its level.
            shore = ndimage.binary_dilation(region, np.ones((3, 3), bool), shore_cells)
            rr, cc = np.divmod(flat[candidate], ncols)
            ii, jj = rr - r0, cc - c0
            inside = (ii >= 0) & (ii < shore.shape[0]) & (jj >= 0) & (jj < shore.shape[1])
            inside[inside] = shore[ii[inside], jj[inside]]
            near = np.flatnonzero(candidate)[inside]
            near = near[np.abs(z[near] - level) <= tol]
            # Open sky over the body: a return well above the level within a cell is a crown.
            hits = tree[0].query_ball_point(np.column_stack([x[near], y[near]]), c)
            covered = np.fromiter((bool(len(h)) and float(np.max(z[tall_idx[h]])) > level + p.low_veg_max_m
                                   for h in hits), bool, len(near))
            if np.mean(covered[np.isin(near, members)]) > 0.05:
                continue   # a level floor under crowns is forest floor
            water[near[~covered]] = True
        return water

    water = bodies(lab, False)
    if p.level_water_across_dropouts:
        # Level patches joined across the gaps they border: bodies the patches alone are too small to
        # be (a joined body that fails a test leaves its parts' own verdicts standing). Only patches
        # too small to be a body alone join: a level floor of a body's size (quays along a canal whose
        # calm water returned nothing) is judged as itself, never merged across the canal.
        small = np.bincount(lab) * c * c < p.level_water_min_area_m2
        small[0] = False
        patches = np.where(small[lab], lab, 0)
        cnt = np.bincount(flat, minlength=nrows * ncols)
        void = cnt == 0
        if p.water_survey_coverage:   # beyond the survey is no gap a lake's shores border
            void &= ~survey_beyond(x, y, cnt.reshape(nrows, ncols), c, x0, y0, water_grid).ravel()
        joined = _join_across_dropouts(patches, med, void, tol)
        if joined is not patches:
            # Only the bodies made of two or more patches: the others were judged above.
            pairs = np.unique(np.column_stack([joined, patches])[patches > 0], axis=0)
            parts = np.bincount(pairs[:, 0], minlength=int(joined.max()) + 1)
            joined = np.where(parts[joined] >= 2, joined, 0)
            if joined.any():
                water |= bodies(joined, True)
    return water


def _join_across_dropouts(lab: np.ndarray, med: np.ndarray, void: np.ndarray, tol: float) -> np.ndarray:
    """Level regions (``lab``: region id per cell of the grid ``med``, 0: not level) joined across the
    pulse-dropout gaps of a water body: two regions that border the same 8-connected group of empty
    cells (``void``: no return at all) and whose levels (median of their cells' ``med``) differ by at most
    ``tol`` are one body. Water that returned the pulse only along its shores, around a gap where
    it mirrored the pulse away, is a ring of level patches, each smaller than a body; joined
    through the gap they are one surface at one level. Returns the joined region id per cell."""
    nrows, ncols = med.shape
    void = void.reshape(nrows, ncols)
    nreg = int(lab.max())
    if nreg < 2 or not void.any():
        return lab
    vlab, nv = ndimage.label(void, np.ones((3, 3), int))
    lab2 = lab.reshape(nrows, ncols)
    pairs = []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == dc == 0:
                continue
            a = (slice(max(0, -dr), nrows - max(0, dr)), slice(max(0, -dc), ncols - max(0, dc)))
            b = (slice(max(0, dr), nrows - max(0, -dr)), slice(max(0, dc), ncols - max(0, -dc)))
            e = (lab2[a] > 0) & (vlab[b] > 0)
            pairs.append(np.column_stack([vlab[b][e], lab2[a][e]]))
    pairs = np.unique(np.concatenate(pairs), axis=0)
    if len(pairs) < 2:
        return lab
    ok = lab > 0
    level = np.zeros(nreg + 1)
    level[1:] = ndimage.median(med.ravel()[ok], lab[ok], np.arange(1, nreg + 1))
    # Per gap, its bordering regions in order of level; neighbours in that order within tol join.
    order = np.lexsort((level[pairs[:, 1]], pairs[:, 0]))
    v, r = pairs[order, 0], pairs[order, 1]
    link = (v[1:] == v[:-1]) & (np.abs(level[r[1:]] - level[r[:-1]]) <= tol)
    if not link.any():
        return lab
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    g = coo_matrix((np.ones(int(link.sum())), (r[:-1][link], r[1:][link])), shape=(nreg + 1,) * 2)
    _, comp = connected_components(g, directed=False)
    # Relabel 1..k with 0 kept for the cells that are not level.
    ids = np.unique(comp[1:], return_inverse=True)[1] + 1
    return np.where(ok, np.r_[0, ids][lab], 0)


def dropout_gaps(x, y, z, is_ground, g: DropoutGrid, p: ClassifySettings):
    """Open-water-sized pulse-dropout gaps of ``g`` (step 5's dropout regions of at least
    ``water_min_area_m2`` that are not occlusion shadows, i.e. at most ``water_shadow_fraction`` of
    their rim cells hold building points).

    Returns (labels, bank, axis, flat, c): the gap label of every cell (0: no gap); per label the
    bank level (m: the median mean-ground height of its rim cells, the quays; NaN without ground
    on the rim) and the unit vector (row, col) of its long axis when it is a watercourse (principal
    axes at least 3:1), else (0, 0); the cell id of every point; the cell size (m). Gaps need no
    returns in them: a canal whose calm surface returned nothing counts.
    """
    c, flat, labels, nlab, area_m2, building_cell = g.c, g.flat, g.labels, g.nlab, g.area_m2, g.building_cell
    bank = np.full(nlab + 1, np.nan)
    axis = np.zeros((nlab + 1, 2))
    if nlab == 0:
        return labels, bank, axis, flat, c
    ground_z = g.ground_cell_z(x, y, z, is_ground)
    keep = np.zeros(nlab + 1, bool)
    boxes = ndimage.find_objects(labels)
    for k in np.flatnonzero(area_m2[1:] >= p.water_min_area_m2) + 1:
        win = tuple(slice(max(b.start - 2, 0), b.stop + 2) for b in boxes[k - 1])
        region = labels[win] == k
        rim = g.rim(win, region)
        keep[k] = not rim.any() or building_cell[win][rim].mean() <= p.water_shadow_fraction
        bz = ground_z[win][rim]
        if np.isfinite(bz).any():
            bank[k] = np.nanmedian(bz)
        evals, evecs = np.linalg.eigh(np.cov(np.argwhere(region).T.astype(float)))
        if evals[1] >= 9.0 * max(evals[0], 1e-9):   # axes 3:1
            axis[k] = evecs[:, 1]
    labels = np.where(keep[labels], labels, 0)
    if g.beyond is not None:
        # Emptiness beyond the survey's coverage is no water a deck crosses (issue 44, i44-edge: the demo's ragged
        # northern edge): only the gaps' cells inside the coverage.
        labels = np.where(g.beyond, 0, labels)
    return labels, bank, axis, flat, c


# A deck with one dropout gap on both sides (its reaches join elsewhere) crosses at least this much of it (m,
# across the watercourse, and at least two grid cells); ground between the teeth of a ragged dropout edge
# (2.5 m deep in the tests' scene, one 1.23 m cell in the demo) spans less. Chosen on the demo and the
# ragged-edge test scene (2.5-10 m reject their false decks and keep reviewer 10's joined-reach decks).
BRIDGE_MIN_CROSSING_M = 4.0


def bridge_decks(x, y, z, is_ground, is_building, spacing_m: float, *, p: ClassifySettings,
                 dropout: DropoutGrid | None = None) -> np.ndarray:
    """Ground points on bridge decks (mask): ground between two water gaps at most
    ``bridge_max_width_m`` apart along one of the four grid directions, running along a
    watercourse (within 30 degrees of the long axis of a gap on at least one side), two distinct gaps
    (labels) or one gap it crosses for at least ``BRIDGE_MIN_CROSSING_M`` across that direction (the
    reaches join elsewhere: a moat, a dropout band along a bank, the survey's edge beyond the deck), and
    standing more than ``bridge_min_clearance_m`` above the lower bank of the two gaps.

    A bridge carries a road across a watercourse, so along the watercourse the deck has open water
    (a dropout gap, ``dropout_gaps``) on both sides, only as far apart as the road is wide, and it
    stands clear of the water, above the quays it joins. A quay has water on one side; the land
    between two canals meeting at an angle lies across the canals' axes, not along one. The ground
    filter takes a deck for terrain (it ramps smoothly into the approaches); a bare-earth DEM
    passes under it, and AHN3 labels it a civil structure (26), not ground. ``dropout``: the
    cloud's ``dropout_grid`` when the caller has it.
    """
    out = np.zeros(len(x), bool)
    if p.bridge_max_width_m <= 0 or not np.any(is_ground):
        return out
    g = dropout if dropout is not None else dropout_grid(x, y, is_building, spacing_m, p)
    labels, bank, axis, flat, c = dropout_gaps(x, y, z, is_ground, g, p)
    if not labels.any():
        return out
    gap = labels > 0
    nrows, ncols = gap.shape
    ground_z = g.ground_cell_z(x, y, z, is_ground)
    need = np.full(gap.shape, np.inf)   # the height (m) a deck point must exceed
    cos_tol = np.cos(np.radians(30.0))
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        step_m = c * np.hypot(dr, dc)
        reach = int(p.bridge_max_width_m // step_m) + 1
        dist = {1: np.full(gap.shape, np.inf), -1: np.full(gap.shape, np.inf)}
        hit_label = {1: np.zeros(gap.shape, np.int64), -1: np.zeros(gap.shape, np.int64)}
        for s in range(reach, 0, -1):   # the nearest gap cell ahead (1) and behind (-1), in cells
            for sign in (1, -1):
                r, q = sign * s * dr, sign * s * dc
                if abs(r) >= nrows or abs(q) >= ncols:   # a grid narrower than the reach: no gap that far
                    continue
                dst = (slice(max(-r, 0), nrows - max(r, 0)), slice(max(-q, 0), ncols - max(q, 0)))
                src = (slice(max(r, 0), nrows + min(r, 0)), slice(max(q, 0), ncols + min(q, 0)))
                lab = np.zeros_like(labels)
                lab[dst] = labels[src]
                dist[sign][lab > 0] = s
                hit_label[sign][lab > 0] = lab[lab > 0]
        spans = ~gap & ((dist[1] + dist[-1] - 1) * step_m <= p.bridge_max_width_m)
        unit = np.array([dr, dc]) / np.hypot(dr, dc)
        along = np.abs(axis @ unit) >= cos_tol   # per label: this direction runs along its axis
        spans &= along[hit_label[1]] | along[hit_label[-1]]
        # A deck cuts the watercourse: the water on its two sides is two gaps (upstream, downstream), or, where
        # the reaches join elsewhere (a moat, a dropout band along a bank, the survey's edge beyond the deck),
        # one gap that the deck crosses for at least BRIDGE_MIN_CROSSING_M (across this direction, gap on
        # both sides all along). Ground between the teeth of a ragged gap edge (the survey's coverage: the
        # demo's 190 false deck returns) has one gap on both sides only as deep as the teeth reach.
        # At least two cells: on a coarse grid (ISPRS samp71's 4.7 m cells) one cell is as deep as a tooth.
        n_cross = max(2, int(np.ceil(BRIDGE_MIN_CROSSING_M / step_m - 1e-9)))
        if dr and dc:   # perpendicular to (1, 1): (1, -1), the anti-diagonal; to (1, -1): (1, 1)
            across = np.eye(n_cross, dtype=bool)[:, ::-1] if dc == 1 else np.eye(n_cross, dtype=bool)
        else:
            across = np.ones((n_cross, 1) if dc else (1, n_cross), bool)
        two = spans & (hit_label[1] != hit_label[-1])
        top = np.fmin(bank[hit_label[1]], bank[hit_label[-1]])
        one = ndimage.binary_opening(spans, structure=across) & ~two
        if one.any():   # a jetty, breakwater or causeway has one gap round it too: a deck must show it is one
            one = _deck_evidence(one, gap, ground_z, top, (dr, dc), step_m)
        spans = two | one
        need = np.where(spans & np.isfinite(top), np.fmin(need, top), need)
    gi = np.flatnonzero(is_ground)
    out[gi] = z[gi] > need.ravel()[flat[gi]] + p.bridge_min_clearance_m
    if not out.any():
        return out
    # Whole decks: the 8-connected spans between two gaps, each large enough and standing clear as a whole.
    span_lab, n_span = ndimage.label(np.isfinite(need), np.ones((3, 3), int))
    lab = span_lab.ravel()
    area_m2 = np.bincount(lab, minlength=n_span + 1) * c * c
    clear = np.bincount(lab[flat[out]], minlength=n_span + 1)
    share = clear / np.maximum(np.bincount(lab[flat[gi]], minlength=n_span + 1), 1)
    whole = (area_m2 >= p.bridge_min_deck_m2) & (share >= p.bridge_min_clear_share)
    whole[0] = False
    out &= whole[lab[flat]]
    return out


# A one-gap deck's evidence (``_deck_evidence``): each end of the deck reaches land across the water within this
# (m), or no land before the data's end (the survey's edge). A dropout band along a bank leaves up to its width empty
# along the deck: reviewer 10's 4 m, reviewer 13's 8-10 m (6 m dropped those bridges whole, 330/340 -> 0/340); a
# jetty's or breakwater's tip has open water beyond it: 15 m (jetty) and 20 m (breakwater) to the far shore in
# reviewer 11's scenes (tests/lidarctl/test_classify_bridge.py), where the jetty is found again from 14 m. 12 m:
# the widest band seen plus 2 m, 3 m short of the nearest open water beyond a tip. Chosen on those synthetic scenes;
# the real sets' classes are unchanged from 6 m (bench/results/bridge_decks.json, label s13-fixes).
BRIDGE_END_WATER_M = 12.0
# ... and its sides drop to the water within a cell: the ground of its cells next to the gap stands at least this
# share of the deck's height above the bank (a deck's edge is the deck; an embankment's fill has returns down its
# slopes, its edge cells near the water's level).
BRIDGE_MIN_EDGE_RISE = 0.6


def _deck_evidence(one: np.ndarray, gap: np.ndarray, ground_z: np.ndarray, bank_z: np.ndarray, d, step_m: float
                   ) -> np.ndarray:
    """The components (8-connected) of ``one`` (cells spanning one gap along grid direction ``d`` (row, col)) that
    show a deck's physical evidence: both ends, along the perpendicular of ``d``, on land across the water (the
    first cell beyond the component that is no gap within ``BRIDGE_END_WATER_M``, or no land at all before the
    grid's end: a survey's or tile's edge) for most of the component's lines, and sides that drop from the deck to the water (the median
    ground height of its cells beside a gap along ``d`` at least ``BRIDGE_MIN_EDGE_RISE`` of the deck's median
    height above ``bank_z``). ``ground_z``: mean ground height per cell (NaN without); ``step_m``: one step along
    ``d`` (the perpendicular's step is the same length)."""
    lab, n = ndimage.label(one, np.ones((3, 3), int))
    if n == 0:
        return one
    nrows, ncols = one.shape
    rr, cc = np.nonzero(one)
    comp = lab[rr, cc]
    w = np.array([d[1], -d[0]])   # perpendicular of d in (row, col) steps
    max_water = int(np.floor(BRIDGE_END_WATER_M / step_m + 1e-9))
    ends_ok = np.ones(len(rr), bool)
    for sign in (1, -1):
        r, q = rr.copy(), cc.copy()
        state = np.zeros(len(rr), np.int8)   # 0: in the component, 1: in water beyond it, 2: land / edge, 3: water
        water = np.zeros(len(rr), np.int64)
        for _ in range(nrows + ncols):
            go = state < 2
            if not go.any():
                break
            r[go] += sign * w[0]
            q[go] += sign * w[1]
            out = go & ((r < 0) | (r >= nrows) | (q < 0) | (q >= ncols))
            state[out] = 2   # the grid's end: no data beyond (the survey's or the tile's edge)
            go &= ~out
            here_lab = lab[r[go], q[go]]
            here_gap = gap[r[go], q[go]]
            idx = np.flatnonzero(go)
            leaving = (state[idx] == 0) & (here_lab != comp[idx])
            in_water = here_gap & ((state[idx] == 1) | leaving)
            landed = ~here_gap & ((state[idx] == 1) | leaving)
            # land across at most max_water cells of water: the far bank; beyond more: open water (a jetty's tip)
            state[idx[landed]] = np.where(water[idx[landed]] > max_water, 3, 2)
            state[idx[in_water]] = 1
            water[idx[in_water]] += 1
        ends_ok &= state == 2
    share = np.bincount(comp, ends_ok, minlength=n + 1) / np.maximum(np.bincount(comp, minlength=n + 1), 1)
    # the sides: cells with a gap next to them along d
    side = np.zeros(len(rr), bool)
    for sign in (1, -1):
        r2, q2 = rr + sign * d[0], cc + sign * d[1]
        ok = (r2 >= 0) & (r2 < nrows) & (q2 >= 0) & (q2 < ncols)
        side[ok] |= gap[r2[ok], q2[ok]]
    gz, bz = ground_z[rr, cc], bank_z[rr, cc]
    keep = np.zeros(n + 1, bool)
    for k in np.flatnonzero(share[1:] >= 0.5) + 1:
        m = comp == k
        deck_z, bank = np.nanmedian(gz[m]) if np.isfinite(gz[m]).any() else np.nan, np.nanmedian(bz[m])
        edge = gz[m & side]
        if not np.isfinite(edge).any() or not np.isfinite(deck_z) or not np.isfinite(bank) or deck_z <= bank:
            continue
        keep[k] = (np.nanmedian(edge) - bank) >= BRIDGE_MIN_EDGE_RISE * (deck_z - bank)
    return keep[lab] & one


# A deck is long and narrow (a roadway or path across the water, not a floor plan): its length at least
# this many times its mean width.
BRIDGE_MIN_ASPECT = 3.0
# And it stands over water: at least this share of its cells has an open-water-sized dropout gap on both
# sides across its axis (the approaches over land make up the rest).
BRIDGE_MIN_OVER_WATER = 0.5


def _walk_hits(mask: np.ndarray, rows: np.ndarray, cols: np.ndarray, step_rc: np.ndarray, n_steps: int) -> np.ndarray:
    """Per start cell (rows, cols): True when ``mask`` is hit within ``n_steps`` half-cell steps along
    ``step_rc`` (row, col per step, in cells)."""
    hit = np.zeros(len(rows), bool)
    for k in range(1, n_steps + 1):
        r = np.floor(rows + 0.5 + k * step_rc[0]).astype(np.int64)
        q = np.floor(cols + 0.5 + k * step_rc[1]).astype(np.int64)
        ok = (r >= 0) & (r < mask.shape[0]) & (q >= 0) & (q < mask.shape[1])
        hit[ok] |= mask[r[ok], q[ok]]
    return hit


def spanning_decks(x, y, z, is_building, is_ground, g: DropoutGrid, *, p: ClassifySettings,
                   is_water=None) -> np.ndarray:
    """Building points that are a bridge deck over water (mask): decks the ground filter left out (a deck
    high over a river is no terrain), which then meet the roof rules (planar, high, single returns).

    A roof and a deck both stand planar above the bare-earth DEM; what tells them apart is what lies
    around them. A segment of building cells (8-connected, on the dropout grid ``g``) is a deck when
    (a) it is long and narrow: mean width (area / length along its principal axis) at most
    ``bridge_max_width_m`` and length at least ``BRIDGE_MIN_ASPECT`` times the width, and at least
    ``bridge_min_deck_m2``; (b) it spans water: at least ``BRIDGE_MIN_OVER_WATER`` of its cells have an
    open-water-sized dropout gap (``dropout_gaps``; the candidates' own cells do not make a gap an
    occlusion shadow) or water returns (``is_water``: water that returned the pulse) on both sides across its
    axis, within its width plus three cells; and (c) it joins
    the terrain at an end: the ground within three cells beyond one end of its axis stands less than
    ``building_min_height_m`` below the deck's end (a bridge runs on into its approach; a roof ends in
    walls at least that high). ``bridge_max_width_m`` 0 disables the rule, as it does ``bridge_decks``.
    """
    out = np.zeros(len(x), bool)
    if p.bridge_max_width_m <= 0 or not np.any(is_building) or not np.any(is_ground) or g.nlab == 0:
        return out
    c = g.c
    bcell = np.bincount(g.flat[is_building], minlength=g.nrows * g.ncols).reshape(g.nrows, g.ncols) > 0
    seg, nseg = ndimage.label(bcell, np.ones((3, 3), int))
    cands = []
    for k, box in enumerate(ndimage.find_objects(seg), 1):
        rr, cc = np.nonzero(seg[box] == k)
        rr, cc = rr + box[0].start, cc + box[1].start
        area = len(rr) * c * c
        if area < p.bridge_min_deck_m2 or len(rr) < 3:
            continue
        rc = np.column_stack([rr, cc]).astype(float)
        centre = rc.mean(axis=0)
        evals, evecs = np.linalg.eigh(np.cov((rc - centre).T))
        u, w = evecs[:, 1], evecs[:, 0]   # long and short axis, (row, col) unit vectors
        s = (rc - centre) @ u
        length = (np.ptp(s) + 1.0) * c
        width = area / length
        if width > p.bridge_max_width_m or length < BRIDGE_MIN_ASPECT * width:
            continue
        cands.append((k, rr, cc, centre, u, w, s, width))
    if not cands:
        return out
    # Water-sized gaps; a gap beside a candidate is not its occlusion shadow for being next to it.
    others = g.building_cell & ~np.isin(seg, [cd[0] for cd in cands])
    labels = dropout_gaps(x, y, z, is_ground, dataclasses.replace(g, building_cell=others), p)[0]
    gap = labels > 0
    if is_water is not None and np.any(is_water):
        # water that returned the pulse is water beside the deck as much as a dropout gap is
        gap |= np.bincount(g.flat[is_water], minlength=g.nrows * g.ncols).reshape(g.nrows, g.ncols) > 0
    ground_z = g.ground_cell_z(x, y, z, is_ground)
    b_idx = np.flatnonzero(is_building)
    deck_cells = np.zeros(g.nrows * g.ncols, bool)
    for k, rr, cc, centre, u, w, s, width in cands:
        n_steps = int(np.ceil(2.0 * (width / c + 3.0)))
        both = (_walk_hits(gap, rr, cc, 0.5 * w, n_steps) & _walk_hits(gap, rr, cc, -0.5 * w, n_steps))
        if both.mean() < BRIDGE_MIN_OVER_WATER:
            continue
        joins = False
        for sign, end in ((1.0, s.max()), (-1.0, s.min())):
            at_end = np.abs(s - end) <= 1.0
            # the deck's height at this end: the median building return of its end cells (railings above
            # and walls below do not move it)
            deck_z = np.median(z[b_idx[np.isin(g.flat[b_idx], rr[at_end] * g.ncols + cc[at_end])]])
            # the ground just beyond this end, across the deck's width
            beyond = []
            for j in range(2, 7):   # 1 to 3 cells beyond, in half cells
                for t in np.linspace(-0.5, 0.5, 5) * width / c:
                    pos = centre + (end + sign * 0.5 * j) * u + t * w
                    r, q = int(np.floor(pos[0] + 0.5)), int(np.floor(pos[1] + 0.5))
                    if 0 <= r < g.nrows and 0 <= q < g.ncols and seg[r, q] != k:
                        beyond.append(ground_z[r, q])
            beyond = np.asarray(beyond, float)
            if np.isfinite(beyond).any() and deck_z - np.nanmedian(beyond) < p.building_min_height_m:
                joins = True
        if joins:
            deck_cells[rr * g.ncols + cc] = True
    out[is_building] = deck_cells[g.flat[is_building]]
    return out


def classify_points(x, y, z, return_number=None, number_of_returns=None, intensity=None,
                    *, params: ClassifySettings | None = None, fusion=None,
                    water_grid: WaterGrid | None = None, frame: grid.CloudFrame | None = None,
                    bare_earth: tuple | None = None) -> np.ndarray:
    """ASPRS class per point (uint8). Arrays are per point; heights in metres. ``fusion``
    (``lidarctl.classify.fusion.Fusion``): the orthophoto's rules applied last (roads, grass/tree, building check).
    ``water_grid``: for a tile of a larger cloud, the whole cloud's water grid (``WaterGrid``; None: this cloud's).
    ``frame``: for a tile of a larger cloud, the whole cloud's grid origin, mean point spacing and noise figures
    (``grid.CloudFrame``; None: this cloud's): every grid is then on the whole cloud's cells, every cell size from
    its spacing and the ground tolerances from its noise, so that the classes do not depend on the tiling.
    ``bare_earth``: (noise code, ground mask) per point as ``bare_earth`` found them with the same settings and
    frame (a tile: ``tiles.cloud_noise``; None: found here), optionally with the ground points' plane offsets and
    spreads (``ground_plane_offsets`` of that ground mask at the frame's spacing: the lifted-ground test takes them
    instead of computing them again)."""
    if len(x) < 10:
        raise ValueError("classification needs at least 10 points")
    frame = frame or grid.CloudFrame.of_points(x, y)
    with grid.whole_cloud(frame):
        return _classify_points(x, y, z, return_number, number_of_returns, intensity, p=params or ClassifySettings(),
                                fusion=fusion, water_grid=water_grid, ground_noise=frame.ground_noise_m,
                                found=bare_earth)


def bare_earth(x, y, z, return_number=None, number_of_returns=None, *, params: ClassifySettings | None = None,
               frame: grid.CloudFrame | None = None, refine_residuals: list | None = None):
    """The first steps of ``classify_points`` (noise, ground filter, sunken returns): (noise code per point,
    ground mask before the lifted-ground test, last-return mask, the mean point spacing used, m).
    ``refine_residuals``: a list that gets the ground filter's residuals from its refined surface (the
    morphological filter's; its last run), as (point indices, residuals in m, ``ground.RefineCells`` with point
    indices)."""
    with grid.whole_cloud(frame or grid.CloudFrame.of_points(x, y)):
        return _bare_earth(x, y, z, return_number, number_of_returns, params or ClassifySettings(), refine_residuals)


def _bare_earth(x, y, z, return_number, number_of_returns, p: ClassifySettings, refine_residuals=None):
    """``bare_earth`` within ``grid.whole_cloud``: (code, is_ground, last, spacing_m)."""
    n = len(x)
    # noise
    code = noise_mod.detect_noise(x, y, z, p.noise)
    clean = code == 0
    last = _last_returns(n, return_number, number_of_returns)
    idx = np.flatnonzero(clean & last)

    # ground
    is_ground = np.zeros(n, bool)
    for _ in range(2):
        residuals = None if refine_residuals is None else []
        g = ground_mod.ground_filter(x[idx], y[idx], z[idx], method=p.ground_method, preset=p.preset,
                                     refine_residuals=residuals, **p.ground_params)
        if residuals:
            refine_residuals[:] = [(idx[k], r, cells._replace(ground=idx[cells.ground])) for k, r, cells in residuals]
        is_ground[:] = False
        is_ground[idx[g]] = True
        deep = deep_ground_outliers(x, y, z, is_ground, p.deep_cell_m, p.deep_m)
        if not deep.any():
            break
        # Deep noise in the ground set bent the surface: flag it and filter the ground again.
        code[deep] = noise_mod.LOW
        is_ground &= ~deep
        idx = idx[code[idx] == 0]

    spacing = grid.cloud_spacing_m(x, y)
    # Returns from below the ground that the gap tests passed (a neighbour within gap_m + slope x d above
    # them) and the filter kept: alone below the ground plane, they would pit the DEM.
    single = None
    if p.ground_sink_single and number_of_returns is not None:
        single = np.asarray(number_of_returns) <= 1
    sunken = sunken_ground(x, y, z, is_ground, spacing, p.ground_sink_sigma, min_depth_m=p.ground_sink_min_depth_m,
                           judged=single)
    code[sunken] = noise_mod.LOW
    is_ground &= ~sunken
    return code, is_ground, last, spacing


def _last_returns(n: int, return_number, number_of_returns) -> np.ndarray:
    """Only a last (or single) return can be bare earth: the pulse went on below the others (all, without return
    numbers)."""
    if return_number is None or number_of_returns is None:
        return np.ones(n, bool)
    return np.asarray(return_number) >= np.asarray(number_of_returns)


def _classify_points(x, y, z, return_number, number_of_returns, intensity, *, p: ClassifySettings, fusion,
                     water_grid: WaterGrid | None, ground_noise: float | None, found=None) -> np.ndarray:
    """``classify_points`` within ``grid.whole_cloud`` (``found``: its ``bare_earth``)."""
    n = len(x)
    cls = np.full(n, UNCLASSIFIED, np.uint8)
    offsets = None
    if found is None:
        code, is_ground, last, spacing = _bare_earth(x, y, z, return_number, number_of_returns, p)
    else:
        code, is_ground = (np.array(a) for a in found[:2])
        offsets = found[2] if len(found) > 2 else None
        last, spacing = _last_returns(n, return_number, number_of_returns), grid.cloud_spacing_m(x, y)
    # Ground refinement: last returns of low objects that the filter took for bare earth. They
    # leave the ground class but stay in the DEM (they lie a decimetre or two above it; without
    # them the DEM sags under hedges, the hedges reach building height and roof segments grow
    # into them) and out of the object grids (their single returns would dilute the crowns'
    # multi-return share): they end as low vegetation.
    intercepted = None
    if return_number is not None and number_of_returns is not None:
        intercepted = np.asarray(number_of_returns) > 1
    noise_ground = None
    if ground_noise is None and p.rooftop_object_max_area_m2 > 0:
        # The ground's range noise of the lifted-ground test serves the rooftop-object rule too: one figure, which a
        # tile takes from the whole cloud (``tiles.cloud_noise``), so a roof's objects do not depend on the tiling.
        if intercepted is not None and p.ground_lift_sigma > 0:   # the test computes the plane offsets anyway
            ground_noise, offsets = _ground_range_noise(x, y, z, is_ground, spacing, offsets)
        else:   # taken on this ground when a roof needs it (single-return AHN3: 1.56 -> 1.78 CPU-s computed here)
            noise_ground = is_ground.copy()
    lifted = lifted_ground(x, y, z, is_ground, spacing, p.ground_lift_sigma, intercepted=intercepted,
                           judge_single=p.ground_lift_single, sigma_m=ground_noise, offsets=offsets)
    c = p.cell_m or max(0.5, 2.0 * spacing)
    x0, y0 = grid.origin(x, y, c)
    ncols = int(np.floor((x.max() - x0) / c)) + 1
    nrows = int(np.floor((y.max() - y0) / c)) + 1
    dem = ground_dem(x, y, z, is_ground, c, x0=x0, y0=y0, nrows=nrows, ncols=ncols)
    hag = z - sample_bilinear(dem, x, y, cell_m=c, x0=x0, y0=y0)

    # Points far below the bare-earth DEM cannot be objects: low noise the gap tests missed.
    code[(code == 0) & ~is_ground & (hag < -p.deep_m)] = noise_mod.LOW
    clean = code == 0
    cls[code == noise_mod.LOW] = LOW_NOISE
    cls[code == noise_mod.HIGH] = HIGH_NOISE
    iso = code == noise_mod.ISOLATED
    cls[iso] = np.where(hag[iso] < 0.0, LOW_NOISE, HIGH_NOISE)
    # buildings
    obj = clean & ~is_ground & ~lifted
    is_ground &= ~lifted
    cls[is_ground] = GROUND
    flat = grid.cell_ids(x, y, c, x0, y0)[0]
    dsm = reduce_grid(x[obj], y[obj], z[obj], cell_m=c, x0=x0, y0=y0, nrows=nrows, ncols=ncols, how="max")
    has_obj = np.isfinite(dsm)
    dsm_f = np.where(has_obj, dsm, dem)
    rms = plane_rms(dsm_f, c)
    multi = np.zeros(n, bool)
    has_multi = False
    if return_number is not None and number_of_returns is not None:
        multi = np.asarray(number_of_returns) > 1
        has_multi = bool(multi.any())
    cnt = np.bincount(flat[obj], minlength=nrows * ncols).reshape(nrows, ncols)
    cnt_multi = np.bincount(flat[obj & multi], minlength=nrows * ncols).reshape(nrows, ncols)
    with np.errstate(invalid="ignore", divide="ignore"):
        multi_frac = np.where(cnt > 0, cnt_multi / np.maximum(cnt, 1), 0.0)
    high_obj = has_obj & (dsm_f - dem > p.building_min_height_m)
    # Penetration: a roof stops every pulse at its surface, so a cell's returns lie within the
    # roof's slope across the cell of its highest one; foliage spreads them through the crown.
    # On single-return clouds this is the evidence the multi-return fraction gives elsewhere.
    sum_obj = np.bincount(flat[obj], z[obj], minlength=nrows * ncols).reshape(nrows, ncols)
    depth = np.where(cnt >= 3, dsm_f - sum_obj / np.maximum(cnt, 1), 0.0)
    reach = 0.5 * c * slope_tan(dsm_f, c)
    roof = high_obj & (rms < p.roof_rms_m) & (depth <= p.roof_rms_m + reach)
    if has_multi:
        # A roof stops the pulses, foliage lets a share through. One cell's 3-4 returns cannot tell
        # a crown's share from a roof's 0 (a crown passing 35 % of its pulses leaves 18 % of its
        # 4-return cells without a multi-return point), so the share is judged over the plane fit's
        # own 3x3 window (~36 returns): it must be below the roof's limit at 95 % confidence. At
        # roof_rms_m 0.25 m the per-cell test made scattered crown cells of the simulator's trees
        # roof cells, 10-24 m2 per crown cluster (42,000 high-vegetation points became building).
        k3 = np.ones((3, 3), np.int64)
        n3 = ndimage.correlate(cnt, k3, mode="constant")
        m3 = ndimage.correlate(cnt_multi, k3, mode="constant")
        roof &= fewer_multi_returns(m3, n3, p.max_multi_return_fraction)
        candidate = high_obj & (multi_frac <= p.grow_multi_return_fraction)
    else:
        candidate = high_obj & (rms < p.rough_rms_m) & (depth <= p.rough_rms_m + reach)
    # Roof segments grow into connected object cells that are not tree-like (ridges, dormers and
    # roof edges break the 3x3 plane fit); a segment is a building when its planar part is large.
    candidate = ndimage.binary_closing(candidate, np.ones((3, 3), bool)) & high_obj | roof
    labels, nlab = ndimage.label(candidate, np.ones((3, 3), int))
    see_through = None
    if nlab:
        ids = np.arange(1, nlab + 1)
        roof_area = ndimage.sum_labels(roof_patches(roof, c, p.roof_min_patch_m2), labels, ids) * c * c
        big = roof_area >= p.building_min_area_m2
        # Sheds and garages: the planar interior of a small roof loses a cell on every side to the
        # 3x3 fit, so a small segment counts by its whole area when it is planar and single-return.
        small = ~big & (ndimage.sum_labels(candidate, labels, ids) * c * c >= p.small_building_min_area_m2)
        if small.any():
            planar = labelled_median(rms, labels, nlab) < p.rough_rms_m
            if p.small_building_plane_fit:
                # A narrow shed (under 3 cells wide) has no 3x3 window on its roof alone; one
                # plane through the whole segment's DSM tells a planar roof from a crown.
                planar |= segment_plane_rms(dsm_f, labels, nlab, c) < p.small_plane_rms_m
            small &= planar
            small &= ndimage.mean(multi_frac, labels, ids) <= p.small_building_max_multi_fraction
        building_cells = np.concatenate([[False], big | small])[labels]
        small_cells = np.concatenate([[False], small])[labels]   # small buildings, judged whole
        if p.roof_reach_cells > 0:
            # A big segment's growth beyond its roof cells is for the cells the 3x3 fit cannot take
            # (ridges, edges, dormers: a window across a break spans 3 cells, so they lie within 2 cells
            # of a roof cell). Further out a cell joins only when it too stops the pulses, like a small
            # roof: a crown or hedge touching an eave splits them.
            near_roof = dilate_square(roof, 2 * p.roof_reach_cells + 1)
            building_cells &= near_roof | (multi_frac <= p.small_building_max_multi_fraction) | small_cells
        rims = np.zeros_like(roof)
        if p.dropout_roof_rims and has_multi and (p.low_growth_max_height_m > 0 or p.pierced_growth_max_fraction > 0):
            occupied = np.bincount(flat, minlength=nrows * ncols).reshape(nrows, ncols) > 0
            rims = building_cells & dilate_square(rimmed_dropouts(occupied, building_cells), 3)
        if p.low_growth_max_height_m > 0 and has_multi:
            # A hedge or a low crown grown into from a roof splits the pulses; the roof cells and the
            # grown cells that stop the pulses (3x3 window, as a roof cell) stay.
            stops = fewer_multi_returns(m3, n3, p.max_multi_return_fraction)
            building_cells &= roof | rims | stops | (dsm_f - dem >= p.low_growth_max_height_m)
        if p.pierced_growth_max_fraction > 0 and has_multi:
            # A roof stops every pulse above the ground; a hedge or a crown grown into from a roof lets a
            # share through to it (the last return of a split pulse on the ground). A grown cell (not a
            # roof cell, not a small building judged as a whole) whose 3x3 window shows, at 95 %
            # confidence, more than this share of its pulses reaching the ground leaves the building.
            level = is_ground | lifted | (hag <= p.wall_min_height_m)
            through = np.bincount(flat[clean & multi & last & level], minlength=nrows * ncols)
            above = np.bincount(flat[clean & (np.asarray(return_number) == 1) & ~level], minlength=nrows * ncols)
            through3 = ndimage.correlate(through.reshape(nrows, ncols), k3, mode="constant")
            above3 = ndimage.correlate(above.reshape(nrows, ncols), k3, mode="constant")
            pierced = more_than_fraction(through3, above3, p.pierced_growth_max_fraction)
            if p.pierced_edge_completion:
                see_through = pierced & ~roof & ~rims
            # A glass roof passes pulses too, but its surface is a roof's: planar, its returns at its top.
            roof_surface = (rms < p.roof_rms_m) & (cnt >= 3) & (depth <= p.roof_rms_m + reach) & p.pierced_glass_roofs
            building_cells &= roof | rims | ~pierced | roof_surface | small_cells
        if p.foliage_beyond_roof_reach and has_multi:
            beyond = building_cells & ~dilate_square(roof, 2 * ROOF_FIT_REACH_CELLS + 1) & ~rims & ~small_cells
            grown, n_grown = ndimage.label(beyond, np.ones((3, 3), int))
            if n_grown:
                ids = np.arange(1, n_grown + 1)
                foliage = more_than_fraction(ndimage.sum_labels(cnt_multi, grown, ids),
                                             ndimage.sum_labels(cnt, grown, ids), p.max_multi_return_fraction)
                foliage &= labelled_median(rms, grown, n_grown) >= p.rough_rms_m
                foliage &= labelled_median(depth - reach, grown, n_grown) > p.roof_rms_m
                building_cells &= ~np.concatenate([[False], foliage])[grown]
        if p.cut_pieces_judged and 9 * c * c <= p.building_min_area_m2:
            # A piece's roof patches are evidence only where a 3x3 window fits the smallest building: at a sparse
            # cloud's cells (IGN's tile decimated to 0.3 returns per m2: 3.7 m) a roof shows almost no roof cell.
            # small buildings were judged whole, a dropout roof's rims by their own rule
            judged_whole = small_cells | rims
            building_cells = cut_pieces(building_cells, judged_whole, roof, multi_frac, c, p)
        if p.small_building_planar_cores:
            building_cells |= planar_cores(dsm_f, roof & ~building_cells, candidate & ~building_cells, multi_frac, c,
                                           min_area_m2=p.small_building_min_area_m2,
                                           max_multi_fraction=p.small_building_max_multi_fraction,
                                           plane_rms_m=p.small_plane_rms_m, reach_m=p.edge_zone_m)
    else:
        building_cells = np.zeros_like(roof)
    # Wall points fall in the ring of cells just outside the roof outline.
    ring = dilate_square(building_cells, 3) & ~building_cells
    wall_ok = ~multi
    if p.wall_multi_return:
        # The eave: the highest roof top among the building cells next to a ring cell. A facade
        # return lies below it (a crown overhanging the eave stands above it).
        eave = ndimage.maximum_filter(np.where(building_cells, dsm_f, -np.inf), size=3, mode="constant",
                                      cval=-np.inf)
        wall_ok = wall_ok | (z <= eave.ravel()[flat])
    in_bld = (building_cells.ravel()[flat]) | (ring.ravel()[flat] & wall_ok)
    is_building = obj & in_bld & (hag > p.wall_min_height_m) & (z >= dsm_f.ravel()[flat] - p.roof_depth_m)
    zone = max(1, int(round(p.edge_zone_m / c)))
    near = dilate_square(building_cells, 2 * zone + 1).ravel()[flat]
    if see_through is not None:   # a surface the pulses pass is no roof edge
        near &= ~see_through.ravel()[flat]
    roof_edge_completion(x, y, z, is_building, obj & near & (hag > p.wall_min_height_m), p)
    if p.rooftop_object_max_area_m2 > 0:
        # The range noise of the sensor, measured on the bare earth (roof plane fits cross ridges
        # and eaves).
        noise_m = ground_noise
        if noise_m is None and noise_ground is not None and is_building.any():
            noise_m = _ground_range_noise(x, y, z, noise_ground, spacing, offsets)[0]
        if noise_m is None or not np.isfinite(noise_m):
            noise_m = range_noise_m(x, y, z, is_ground)
        is_building &= ~rooftop_objects(x, y, z, is_building, spacing, noise_m,
                                        max_area_m2=p.rooftop_object_max_area_m2, max_pitch_deg=p.roof_max_pitch_deg,
                                        steps_to_roofs_only=p.rooftop_steps_to_roofs_only)
    if p.crown_covered_roofs and has_multi:
        # a shed under a crown: the crown is on the DSM, the roof on the surface where the pulses end
        level = is_ground | lifted | (hag <= p.wall_min_height_m)
        is_building |= covered_roofs(z, flat, obj & ~is_building & ~level, last=last, reaches_ground=clean & level,
                                     dem=dem, cell_m=c, shape=(nrows, ncols), p=p)
    cls[is_building] = BUILDING

    # vegetation
    veg = obj & ~is_building
    low = veg & (hag <= p.low_veg_max_m)
    med = veg & (hag > p.low_veg_max_m) & (hag <= p.medium_veg_max_m)
    high = veg & (hag > p.medium_veg_max_m)
    if has_multi:
        structured = ((multi_frac > 0) | (rms >= p.rough_rms_m)).ravel()[flat]
        med &= structured
        high &= structured
    cls[low | (lifted & clean)] = LOW_VEG
    cls[med] = MED_VEG
    cls[high] = HIGH_VEG

    # water
    gaps = dropout_grid(x, y, is_building, spacing, p, water_grid)
    water = detect_water(x, y, z, intensity, is_ground | (cls == UNCLASSIFIED) | (cls == LOW_VEG),
                         is_building, is_ground=is_ground, spacing_m=spacing, p=p, solid=clean, dropout=gaps,
                         land_intensity=None if water_grid is None else water_grid.land_intensity)
    cls[water] = WATER
    cls[level_water(x, y, z, is_ground | (cls == UNCLASSIFIED) | (cls == LOW_VEG), is_ground, spacing, p=p,
                    solid=clean, number_of_returns=number_of_returns, water_grid=water_grid)] = WATER
    cls[bridge_decks(x, y, z, cls == GROUND, is_building, spacing, p=p, dropout=gaps)] = BRIDGE_DECK
    cls[spanning_decks(x, y, z, cls == BUILDING, cls == GROUND, gaps, p=p, is_water=cls == WATER)] = BRIDGE_DECK
    if fusion is not None:
        from lidarctl.classify import fusion as fusion_mod

        cls = fusion_mod.fuse(x, y, z, hag, cls, intensity, img=fusion.image, p=fusion.params,
                              return_number=return_number, number_of_returns=number_of_returns,
                              water_level_tol_m=p.water_level_tol_m)
    return cls
