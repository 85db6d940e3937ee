"""Options of the ortho stages as settings dataclasses (``[rectify]`` and ``[mosaic]`` in project.toml).

The defaults are those of the library functions (``rectify_block``, ``mosaic_block``), read from their
signatures, so the two cannot drift apart; the allowed values come from the stages' registries.
"""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

from aerotri.core.settings import setting
from ortho.block import FRAME_COMPRESSION, rectify_block
from ortho.mosaic import mosaic_block
from ortho.rectify import INTERPOLATION

SEAM_METHODS = ("least-cost", "voronoi")

_R = inspect.signature(rectify_block).parameters
_M = inspect.signature(mosaic_block).parameters


@dataclasses.dataclass(frozen=True)
class RectifySettings:
    """``ortho rectify`` options: DEM, pixel size, output CRS, interpolation, true ortho, compression."""

    dem: Path | None = setting(_R["dem_path"].default, path=True,
                               help="DEM GeoTIFF (default: lidar_out/dem.tif of the LiDAR stages).")
    res_m: float | None = setting(_R["res_m"].default, min=0.0, min_open=True,
                                  help="Output pixel size in metres (default: the median nadir GSD, rounded).")
    crs: str | None = setting(_R["crs"].default, help="Output CRS (default: the project CRS).")
    interpolation: str = setting(_R["interpolation"].default, choices=tuple(INTERPOLATION))
    true_ortho: bool = setting(_R["true_ortho"].default, help="Rectify on the DSM and mask occluded pixels.")
    dsm: Path | None = setting(_R["dsm_path"].default, path=True, help="DSM GeoTIFF for true_ortho.")
    compression: str = setting(_R["compression"].default, choices=tuple(FRAME_COMPRESSION))

    def kwargs(self) -> dict:
        """Keyword arguments of ``rectify_block``."""
        return dict(dem_path=self.dem, res_m=self.res_m, crs=self.crs, interpolation=self.interpolation,
                    true_ortho=self.true_ortho, dsm_path=self.dsm, compression=self.compression)


@dataclasses.dataclass(frozen=True)
class MosaicSettings:
    """``ortho mosaic`` options: seamlines, nDSM, feathering, balancing, tile size."""

    seams: str = setting(_M["seams"].default, choices=SEAM_METHODS)
    ndsm: Path | None = setting(_M["ndsm_path"].default, path=True,
                                help="nDSM for seam costs (default: lidar_out/ndsm.tif if present).")
    feather_m: float | None = setting(_M["feather_m"].default, min=0.0, min_open=True,
                                      help="Feather width across seams in metres (default: 8 GSD).")
    balance: bool = setting(_M["balance"].default, help="Gain balancing between frames.")
    tile_px: int = setting(_M["tile_px"].default, min=1, help="Mosaic processing tile size (px).")

    def kwargs(self) -> dict:
        """Keyword arguments of ``mosaic_block``."""
        return dict(seams=self.seams, ndsm_path=self.ndsm, feather_m=self.feather_m, balance=self.balance,
                    tile_px=self.tile_px)
