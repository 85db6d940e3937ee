"""Settings of the ortho stages (``[rectify]``, ``[mosaic]`` and ``[dom_check]`` in project.toml, and the options
of ``ortho rectify``, ``ortho mosaic`` and ``ortho check``): the one declaration of each option's type, default,
range and help; the library functions (``rectify_block``, ``mosaic_block``, ``run_check``) take these
dataclasses. The allowed values come from the stages' registries.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import ClassVar

from aerotri.core.settings import setting
from ortho.patches import MIN_PATCH_PX
from ortho.rectify import INTERPOLATION

SEAM_METHODS = ("least-cost", "voronoi")

# per-frame ortho compression: intermediates for the mosaic, so write speed matters as much as size.
# Measured on a 120 MP DMC frame (band interleaved; bench/ortho.py, bench/results/ortho_bench.json, 2 cores):
# zstd 102 MB, zstd-fast 172 MB, none 374 MB; the stage takes 3.1, 3.1 and 1.8 CPU-s (1.7, 1.7 and 1.1 s):
# zstd-fast saves no CPU, none saves 40 % of it for 3.7 times the disk. zstd stays the default: on a
# shared 2-core machine none does not bring the one-frame command to 100 MP/s either (interpreter,
# imports and numba's set-up are about 0.7 s of it). The other GDAL codecs, writing alone (bench/ortho.py
# write_profiles): DEFLATE 1 and PackBits cost as much CPU as ZSTD 1 for larger files, LZW and LERC
# twice as much, JPEG (lossy, IJG libjpeg 9 in the wheel) nearly twice as much.
FRAME_COMPRESSION = {
    "zstd": dict(compress="zstd", zstd_level=1, predictor=2),
    "zstd-fast": dict(compress="zstd", zstd_level=1),
    "none": {},
}


@dataclasses.dataclass(frozen=True)
class RectifySettings:
    """``ortho rectify``: DEM, pixel size, output CRS, interpolation, true ortho, compression."""

    SECTION: ClassVar[str] = "rectify"
    dem: Path | None = setting(None, path=True, help="DEM GeoTIFF (default: lidar_out/dem.tif of the LiDAR stages).")
    res_m: float | None = setting(None, min=0.0, min_open=True,
                                  help="Output pixel size in metres (default: the median nadir GSD, rounded).")
    crs: str | None = setting(None, crs=True,
                              help="Output CRS: an EPSG code (e.g. EPSG:4546), WKT, PROJ text or a .wkt/.prj file (in "
                                   "project.toml: in the project folder), or gk3:cgcs2000 / gk3:xian1980 for the "
                                   "3-degree Gauss-Krueger zone nearest the block centre (default: the target CRS of "
                                   "the datum parameters, else the project CRS).")
    interpolation: str = setting("bilinear", choices=tuple(INTERPOLATION), help="Resampling of the frames.")
    true_ortho: bool = setting(False, help="Rectify on the DSM and mask pixels occluded by it.")
    dsm: Path | None = setting(None, path=True, help="DSM GeoTIFF of the true ortho (the heights it is rectified on).")
    occlusion_dsm: Path | None = setting(
        None, path=True,
        help="DSM GeoTIFF of the true ortho's occlusion test, when not the DSM itself; footprints and crown bases on "
             "its grid (aerotri run on the LiDAR stages' DSM: lidar_out/dsm_crowns.tif, the first return nearest "
             "each cell centre with the trees' fitted crowns, with [rectify] crowns = lidar_out/crowns.gpkg; "
             "lidar_out/dsm_nearest.tif the same without the crowns; lidar_out/dsm.tif: the DSM itself).")
    footprints: Path | None = setting(
        None, path=True,
        help="Building footprints (GeoPackage of wall-line polygons in the project CRS, e.g. a cadastre) for the true "
             "ortho's occlusion test: inside them the DSM is solid; a roof overhang outside them (within 1.5 m, 2 m "
             "above the DEM) hides only down to 0.3 m below its building's eave line and only within the roof outline "
             "(the footprint grown by the eave width the DSM gives, at most 1 m), so ground seen beneath and beside "
             "eaves is kept (docs/true-ortho.md). aerotri run on the LiDAR stages' DSM without it: the roof outlines "
             "the corners stage traced (lidar_out/roof_outlines.gpkg).")
    crown_base: Path | None = setting(
        None, path=True,
        help="Tree crown bases (GeoTIFF on the DSM's grid: per cell the height of the lowest vegetation return, nodata "
             "where none) for the true ortho's occlusion test: a tree cell near no footprint hides only between its "
             "crown base and its top, so ground seen beneath a crown is kept (docs/true-ortho.md).")
    crowns: Path | None = setting(
        None, path=True,
        help="Tree crowns fitted to their LiDAR returns (lidarctl rasters' lidar_out/crowns.gpkg: a disk, top and crown "
             "base per tree) for the true ortho's occlusion test, on the occlusion DSM lidar_out/dsm_crowns.tif: a tree "
             "cell hides only within the disks and from the tree's crown base up (docs/true-ortho.md).")
    max_view_angle_deg: float = setting(
        90.0, min=0.0, min_open=True, max=90.0,
        help="Largest angle between a cell's ray to the projection centre and the vertical (deg); cells seen more "
             "obliquely are nodata in the frame's ortho. 90: no limit; 50-60 trims the grazing far field of oblique "
             "drone frames (a nadir DMC frame reaches about 41 deg at its corners with 3 deg of tilt).")
    compression: str = setting("zstd", choices=tuple(FRAME_COMPRESSION),
                               help="Per-frame GeoTIFFs: zstd (level 1 + predictor), zstd-fast (no predictor, ~1.7x "
                                    "larger, no less CPU), none (~40 % less CPU per frame, ~3.7x larger).")
    # Off by default: on a full-size DMC frame ortho (8484 x 14308 px, 16 bit) they cost 3.7 CPU-s, 0.70 of the
    # frame's rectification (5.2 CPU-s per frame in the 2 x 4 DMC block's true-ortho run), and 34 % more disk (demo
    # frames: 0.075 CPU-s, 0.09 of it, 38 % more disk); the mosaic, the product, has its own
    # (bench/frame_overviews.py, bench/results/frame_overviews.json)
    overviews: bool = setting(False, help="Internal overviews (2x, 4x ... averaged, with the mask's) in each frame ortho, "
                                          "so a GIS opens one at full extent quickly; the full-resolution samples are "
                                          "unchanged. On a full-size DMC frame about 0.7 x the CPU of its "
                                          "rectification and 34 % more disk.")


@dataclasses.dataclass(frozen=True)
class MosaicSettings:
    """``ortho mosaic``: seamlines, nDSM, feathering, balancing, tile size."""

    SECTION: ClassVar[str] = "mosaic"
    seams: str = setting("least-cost", choices=SEAM_METHODS,
                         help="Seamlines: least-cost paths around buildings and trees, or Voronoi cells of the nadir "
                              "points.")
    ndsm: Path | None = setting(None, path=True,
                                help="nDSM for seam costs (buildings, trees) (default: lidar_out/ndsm.tif if present).")
    feather_m: float | None = setting(None, min=0.0,
                                      help="Feather width across seams in metres, 0: one pixel (default: 8 GSD).")
    balance: bool = setting(True, help="Gain balancing between frames.")
    offsets: bool = setting(False, help="With the gains, an offset per frame and band (haze, a black level) by the "
                                        "same least squares (default: gains only; needs balance).")
    tile_px: int = setting(1024, min=16, help="Mosaic processing tile size (px).")
    exclude: tuple[str, ...] = setting(
        (), help="Frames left out of the mosaic (image ids): no seams, balancing or blending from them; their orthos "
                 "stay in ortho/frames (a re-flown strip's frames, a cloud, a bad exposure).")
    output_bits: int | None = setting(
        None, choices=(8,),
        help="8: write the DOM with 8-bit samples, the balanced samples mapped linearly to 0 .. 255 by one mapping for "
             "the block (output_range; by default from the frames' white level: 0 .. 4095 for 12-bit DMC data in 16-bit "
             "TIFF), recorded in the DOM's tags and mosaic.json with what it clips; nodata stays in the mask (default: "
             "the frames' own type, 16-bit in, 16-bit out).")
    output_range: str = setting(
        "white-level", choices=("white-level", "percentiles"),
        help="With output_bits: the frames' data range mapped to 0 .. 255: white-level (0 .. the frames' white level: "
             "nothing clipped but what the frames saturate) or percentiles (the balanced samples' pooled 0.1 and 99.9 "
             "percentiles, all bands and frames: a contrast stretch that clips about 0.1 % at each end, counted in "
             "mosaic.json).")


@dataclasses.dataclass(frozen=True)
class CheckSettings:
    """``ortho check``: which patches of the DOM count and how they are matched with the reference."""

    SECTION: ClassVar[str] = "dom_check"
    ndsm: Path | None = setting(None, path=True, help="nDSM: only ground patches (nDSM <= max_ndsm_m) count (default: "
                                                      "lidar_out/ndsm.tif if present).")
    max_ndsm_m: float = setting(0.5, help="Highest nDSM value (m) of a ground patch (with an nDSM).")
    patch_px: int = setting(48, min=MIN_PATCH_PX, help="Patch size (px).")
    search_px: int = setting(6, min=1, help="Search radius around each patch (px).")
    roof_corners: Path | None = setting(None, path=True,
                                        help="CSV with x,y columns: roof corners where the roofs are measured against a "
                                             "true-ortho reference (default: with the simulator's truth/ortho.tif "
                                             "as the reference the truth/roof_corners.csv beside it, else the outline "
                                             "corners of the nDSM's buildings).")
