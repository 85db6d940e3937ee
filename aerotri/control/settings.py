"""Options of the control stage: ``ControlSettings`` (``aerotri control``, ``[control]`` in project.toml) with
how a corner is measured in a frame (``MeasureSettings``) and where control goes (``LayoutSettings``).

Each dataclass is the one place of its options, defaults and allowed values (``aerotri.core.settings``);
the command line and project.toml read them from here.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from aerotri.core.settings import setting


@dataclasses.dataclass(frozen=True)
class MeasureSettings:
    """How a corner is measured in one frame (the method: ``aerotri.control.measure``)."""

    eo_sigma_px: float = setting(1.0, min=0.0, help="Orientation uncertainty in the image (px), widens the search "
                                                    "window.")
    window_k: float = setting(3.0, min=0.0, min_open=True, help="Search radius = this many predicted standard "
                                                                "deviations.")
    min_radius_px: float = setting(4.0, min=0.0, help="Smallest search radius (px).")
    max_radius_px: float = setting(25.0, min=0.0, min_open=True, help="Largest search radius (px).")
    edge_len_px: float = setting(30.0, min=1.0, help="Longest edge piece used for the fit (px).")
    min_contrast: float = setting(4.0, min=0.0, help="Grey values per px across both edges (below: occluded or no "
                                                     "contrast).")
    ambiguity_ratio: float = setting(0.7, min=0.0, max=1.0, help="A rival junction scoring above this fraction of the "
                                                                 "best makes the corner ambiguous.")
    ambiguity_dist_px: float = setting(1.5, min=0.0, help="Rivals closer than this are the same corner (px).")
    max_fit_rms_px: float = setting(0.35, min=0.0, min_open=True, help="Largest rms of the edge points about the two "
                                                                       "fitted lines (px).")
    min_edge_points: int = setting(6, min=3, help="Fewest sub-pixel edge points per edge.")


@dataclasses.dataclass(frozen=True)
class LayoutSettings:
    """Where control goes (the rule: ``aerotri.control.layout``): spacings in baselines, the weights of the
    choice of a target's corner."""

    full_spacing_baselines: float = setting(5.0, min=0.5, help="Full (XYZ) control every this many baselines along "
                                                               "the strip edges.")
    height_every_strips: int = setting(3, min=0, help="Height points in the middle strip of every this many strips "
                                                      "(0: none).")
    min_frames: int = setting(3, min=2, help="A control point must be measured in at least this many frames "
                                             "(3: triple overlap).")
    search_radius_baselines: float = setting(1.25, min=0.0, min_open=True,
                                             help="A target takes the best corner within this many baselines.")
    score_weight: float = setting(0.5, min=0.0, help="Weight of the corner score in the choice of a target's corner.")
    residual_weight: float = setting(0.5, min=0.0, help="Weight of the largest multi-ray residual (relative to the "
                                                        "tolerance) in the choice of a target's corner.")
    fallback: bool = setting(True, help="A target without a usable corner in min_frames frames takes, in this "
                                         "order, a lower-scored flat-roof corner, a flat-roof corner in two frames "
                                         "(as height control) or a pitched-roof corner before it stays empty.")
    edge_inset: float = setting(0.12, min=0.0, max=0.5, help="Outer block edge targets lie this fraction of the "
                                                             "strip width inside.")


@dataclasses.dataclass(frozen=True)
class ControlSettings:
    """Options of the control stage (``aerotri control``, ``[control]`` in project.toml; the section's sigma keys
    are the control points' a-priori precision, ``aerotri.core.project.ControlPointSettings``)."""

    SECTION: ClassVar[str] = "control"
    measure: MeasureSettings = MeasureSettings()
    layout: LayoutSettings = LayoutSettings()
    tol_px: float = setting(0.7, min=0.05, help="Multi-ray reprojection residual tolerance (px).")
    image_sigma_px: float = setting(0.3, min=0.0, min_open=True,
                                    help="Image measurement precision used for the LiDAR comparison (px).")
    datum_sigma_m: float = setting(0.2, min=0.0, help="Datum error of the orientations before control, per "
                                                      "coordinate (m).")
    alpha: float = setting(1e-3, min=0.0, max=1.0, min_open=True, max_open=True,
                           help="Type I error of the comparison with the LiDAR corner.")
    usable_only: bool = setting(True, help="Measure only corners marked usable (plus manually measured ones).")
    chips: bool = setting(True, help="Write control/review/ (HTML + chips).")
    checks: bool = setting(True, help="Write accepted corners that are not control as check points.")
