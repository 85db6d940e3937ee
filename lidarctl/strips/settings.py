"""Options of the strip stage of the chain (``[strips]`` in project.toml): the check of the overlaps
before classification, and the adjustment when asked for::

    [strips]
    adjust = true                 # default false: the check only reads the strips
    [strips.surface]              # what counts as a smooth surface (SurfaceSettings)
    cell_m = 2.0
    [strips.adjustment]           # the least squares (StripAdjustSettings)
    shift_sigma_m = 0.05
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from aerotri.core.settings import setting
from lidarctl.strips.adjust import StripAdjustSettings
from lidarctl.strips.overlap import SurfaceSettings


@dataclasses.dataclass(frozen=True)
class StripsSettings:
    """The strip stage: check the overlaps (always), adjust the strips and classify the corrected ones
    (``adjust``); with ``use_trajectory`` and the project's trajectory/*.txt the sensor model (boresight,
    range offset, a shift per strip), else a shift and rotation per strip."""

    SECTION: ClassVar[str] = "strips"

    adjust: bool = setting(False, help="Adjust the strips and classify the corrected ones (default: check only).")
    use_trajectory: bool = setting(True, help="Adjust with the sensor model when the project has trajectory/*.txt.")
    maps: bool = setting(True, help="Colour maps (PNG) of the differences next to their rasters.")
    surface: SurfaceSettings = dataclasses.field(default_factory=SurfaceSettings)
    adjustment: StripAdjustSettings = dataclasses.field(default_factory=StripAdjustSettings)
