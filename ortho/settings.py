"""Options of the ortho stages as settings dataclasses (``[rectify]`` and ``[mosaic]`` in project.toml, and
the options of ``ortho rectify``, ``ortho mosaic`` and ``ortho check``).

The defaults are those of the library functions (``rectify_block``, ``mosaic_block``, ``run_check``), read
from their signatures, so the two cannot drift apart; the allowed values come from the stages' registries.
"""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

from aerotri.core.settings import setting
from ortho.block import FRAME_COMPRESSION, rectify_block
from ortho.check import run_check
from ortho.mosaic import mosaic_block
from ortho.patches import MIN_PATCH_PX
from ortho.rectify import INTERPOLATION

SEAM_METHODS = ("least-cost", "voronoi")

_R = inspect.signature(rectify_block).parameters
_M = inspect.signature(mosaic_block).parameters
_C = inspect.signature(run_check).parameters


@dataclasses.dataclass(frozen=True)
class RectifySettings:
    """``ortho rectify`` options: DEM, pixel size, output CRS, interpolation, true ortho, compression."""

    dem: Path | None = setting(_R["dem_path"].default, path=True,
                               help="DEM GeoTIFF (default: lidar_out/dem.tif of the LiDAR stages).")
    res_m: float | None = setting(_R["res_m"].default, min=0.0, min_open=True,
                                  help="Output pixel size in metres (default: the median nadir GSD, rounded).")
    crs: str | None = setting(_R["crs"].default,
                              help="Output CRS: an EPSG code (e.g. EPSG:4546), or gk3:cgcs2000 / gk3:xian1980 for the "
                                   "3-degree Gauss-Krueger zone nearest the block centre (default: the target CRS of "
                                   "the datum parameters, else the project CRS).")
    interpolation: str = setting(_R["interpolation"].default, choices=tuple(INTERPOLATION),
                                 help="Resampling of the frames.")
    true_ortho: bool = setting(_R["true_ortho"].default, help="Rectify on the DSM and mask pixels occluded by it.")
    dsm: Path | None = setting(_R["dsm_path"].default, path=True, help="DSM GeoTIFF of the true ortho.")
    compression: str = setting(_R["compression"].default, choices=tuple(FRAME_COMPRESSION),
                               help="Per-frame GeoTIFFs: zstd (level 1 + predictor), zstd-fast (no predictor, ~1.7x "
                                    "larger, no less CPU), none (~40 % less CPU per frame, ~3.7x larger).")

    def kwargs(self) -> dict:
        """Keyword arguments of ``rectify_block``."""
        return dict(dem_path=self.dem, res_m=self.res_m, crs=self.crs, interpolation=self.interpolation,
                    true_ortho=self.true_ortho, dsm_path=self.dsm, compression=self.compression)


@dataclasses.dataclass(frozen=True)
class MosaicSettings:
    """``ortho mosaic`` options: seamlines, nDSM, feathering, balancing, tile size."""

    seams: str = setting(_M["seams"].default, choices=SEAM_METHODS,
                         help="Seamlines: least-cost paths around buildings and trees, or Voronoi cells of the nadir "
                              "points.")
    ndsm: Path | None = setting(_M["ndsm_path"].default, path=True,
                                help="nDSM for seam costs (buildings, trees) (default: lidar_out/ndsm.tif if present).")
    feather_m: float | None = setting(_M["feather_m"].default, min=0.0,
                                      help="Feather width across seams in metres, 0: one pixel (default: 8 GSD).")
    balance: bool = setting(_M["balance"].default, help="Gain balancing between frames.")
    tile_px: int = setting(_M["tile_px"].default, min=16, help="Mosaic processing tile size (px).")

    def kwargs(self) -> dict:
        """Keyword arguments of ``mosaic_block``."""
        return dict(seams=self.seams, ndsm_path=self.ndsm, feather_m=self.feather_m, balance=self.balance,
                    tile_px=self.tile_px)


@dataclasses.dataclass(frozen=True)
class CheckSettings:
    """``ortho check`` options: which patches count and how they are matched."""

    max_ndsm_m: float = setting(_C["max_ndsm_m"].default, help="Highest nDSM value (m) of a ground patch (with an "
                                                               "nDSM).")
    patch_px: int = setting(_C["patch_px"].default, min=MIN_PATCH_PX, help="Patch size (px).")
    search_px: int = setting(_C["search_px"].default, min=1, help="Search radius around each patch (px).")

    def kwargs(self) -> dict:
        """Keyword arguments of ``run_check``."""
        return dict(max_ndsm_m=self.max_ndsm_m, patch_px=self.patch_px, search_px=self.search_px)
