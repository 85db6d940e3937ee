"""Options of the tie-point stage: ``MatchSettings`` (``aerotri match``, ``[match]`` in project.toml) with
the feature extraction (``FeatureSettings``, sparse and dense) and pair matching (``PairMatchSettings``) it uses.

Each dataclass is the one place of its options, defaults and allowed values (``aerotri.core.settings``);
``FeatureSettings.key()`` and ``PairMatchSettings.key()`` name the cache files, so that changed options never
reuse results of other ones.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import ClassVar

from aerotri.core.settings import setting


FEATURES_VERSION = 3  # 2: keypoints on the image content (SIFT precise upscale, pyramid levels without offset);
# 3: frames read by windows, deep (12/16-bit) samples scaled by their significant bits; tile_px (detection by
# tiles) joins the key through the settings
MATCH_VERSION = 1  # pair matching and its verification (``aerotri.match.matching``): the pair's resume key and the
# matches' cache name hold it (through ``aerotri.match.pipeline._pair_key``), as does the chain's match stamp. Bump it
# when the matches of a pair change at the same settings. 1: resume-keys (the matching as of main 195def90)


def _key(params, version: int | None = None) -> str:
    """12 hex digits naming a parameter set (its cache files); ``version`` of the code, when given."""
    d = dataclasses.asdict(params) | ({} if version is None else {"version": version})
    return hashlib.sha1(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


@dataclasses.dataclass(frozen=True)
class FeatureSettings:
    """Feature extraction of one kind (``name``: the cache files' tag); the key of the cache."""

    budget: int = setting(6000, min=100, help="Keypoints per frame (spatially spread).")
    grid: tuple[int, int] = setting((12, 8), min=1, help="Cells across the image width and height; each keeps its "
                                                         "share of the budget.")
    max_dim_px: int = setting(3000, min=64, help="Detect on the pyramid level whose larger side is at most this many "
                                                 "pixels.")
    contrast_threshold: float = setting(0.01, min=0.0, min_open=True, help="SIFT contrast threshold.")
    tile_px: int = setting(1792, min=256, help="Detect in tiles of about this many pixels a side of the detection level "
                                               "(plus a 128 px margin), one after the other: SIFT holds about 230 bytes "
                                               "a pixel of what it detects on, so memory follows the tile, not the "
                                               "frame. A level up to this size plus the margins is detected whole.")
    name: str = setting("sparse", help="Tag of the cache files.")

    def key(self) -> str:
        # the extraction's version joins the key: features (and the matches indexing them) cached by an
        # older version, with keypoints off the image content, are not reused
        return _key(self, FEATURES_VERSION)


@dataclasses.dataclass(frozen=True)
class PairMatchSettings:
    """Matching of one frame pair; the key of the cache."""

    ratio: float = setting(0.8, min=0.0, max=1.0, min_open=True, help="Lowe ratio test threshold.")
    ransac_px: float = setting(1.0, min=0.0, min_open=True, help="RANSAC inlier threshold on the epipolar distance "
                                                                 "(full-resolution px).")
    min_inliers: int = setting(15, min=1, help="Fewest verified matches of a pair (fewer: no ties).")
    seed: int = setting(0, help="Seed of the RANSAC (repeatable results).")
    local_px: float = setting(1.5, min=0.0, min_open=True, help="Local parallax consistency tolerance (px of the "
                                                                "detection level).")
    local_k: int = setting(10, min=1, help="Neighbours of the local parallax consistency check.")
    guide_margin: float = setting(0.1, min=0.0, help="Guided matching with GNSS: compare only keypoints predicted "
                                                     "inside the other frame's footprint grown by this share of "
                                                     "its size (covers attitude, crab and relief).")

    def key(self) -> str:
        return _key(self)


def _dense_features() -> FeatureSettings:
    return FeatureSettings(budget=10000, grid=(20, 12), max_dim_px=4500, contrast_threshold=0.004, name="dense")


@dataclasses.dataclass(frozen=True)
class MatchSettings:
    """Options of the tie-point stage (``aerotri match``, ``[match]`` in project.toml)."""

    SECTION: ClassVar[str] = "match"
    sparse: FeatureSettings = dataclasses.field(default_factory=FeatureSettings)
    dense: FeatureSettings = dataclasses.field(default_factory=_dense_features)
    match: PairMatchSettings = dataclasses.field(default_factory=PairMatchSettings)
    dense_ratio: float = setting(0.9, min=0.0, max=1.0, min_open=True,
                                 help="Lowe ratio test threshold of the densification.")
    min_overlap: float = setting(0.15, min=0.0, max=1.0, max_open=True,
                                 help="Minimum predicted footprint overlap of a candidate pair (fraction of the "
                                      "smaller footprint).")
    terrain_height_m: float | None = setting(None, help="Mean terrain height (m) for the footprints; default: "
                                                        "project.toml [flight] or lidar_out/dem.tif.")
    image_top_deg: float | None = setting(None, help="Direction of the image top relative to the flight direction "
                                                    "(degrees, 0 = forward); default: from the sensor's shape, "
                                                    "0 for a landscape frame (the long side across track, as the "
                                                    "DMC's), 90 for a portrait one.")
    densify: bool = setting(True, help="Densify weak models (dense features where a stereo model or a strip pair "
                                       "has too few ties).")
    complete_px: float = setting(0.5, min=0.0, help="Track completion: a track missed by the matching of a verified "
                                                    "pair takes the free keypoint within this many px (of the "
                                                    "detection level) of its place predicted from the pair's "
                                                    "matches, when their descriptors are as close as the pair's "
                                                    "matches' (0: off).")
    min_per_region: int = setting(3, min=0, help="A stereo model is weak with fewer ties in a von Gruber region.")
    min_strip_ties: int = setting(20, min=0, help="Two adjacent strips are weakly tied with fewer common tracks.")
    retrieval_min_matches: int = setting(25, min=1, help="Without GNSS: thumbnails with this many matches make a "
                                                         "pair.")
