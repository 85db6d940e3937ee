"""``lidarctl rasters`` and ``lidarctl crowns``: the raster products of a classified cloud."""

from __future__ import annotations

import click

from aerotri.core.commands import Command, at_least, positive
from aerotri.core.settings import click_option
from lidarctl.rasters.products import (DEFAULT_BUFFER_PX, DEFAULT_TILE_PX, DEFAULT_TIN_FILL_RADIUS_PX, MIN_AUTO_TILE_PX,
                                      RasterSettings)


@click.command(cls=Command)
@click.argument("in_paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.argument("outdir", type=click.Path(file_okay=False))
@click_option(RasterSettings, "res_m", "--res-m", required=True, default=None, show_default=False,
              help="Cell size in metres, also for clouds in feet (1 m = 3.2808 ft in the GeoTIFF) ([rasters] res_m of "
                   "aerotri run).")
@click.option("--crs", default=None, help="CRS (EPSG:code) of files without one, or with an unreadable one.")
@click.option("--tile-px", type=click.IntRange(min=1), default=None,
              help=f"Tile size in raster cells (memory: about 160 bytes per cell of a tile with its buffer, two tiles "
                   f"at a time; default {DEFAULT_TILE_PX}, halved down to {MIN_AUTO_TILE_PX} while the tiles would not "
                   f"fit in the memory the process may use, e.g. a container's limit).")
@click.option("--buffer-px", type=click.IntRange(min=0), default=DEFAULT_BUFFER_PX, show_default=True,
              help="Overlap buffer around each tile in cells: gaps up to about this size are filled as in one piece.")
@click.option("--dem-fill-radius-px", type=at_least(0), default=DEFAULT_TIN_FILL_RADIUS_PX,
              show_default=True,
              help="DEM cells without ground are interpolated in the TIN of the ground around them where the "
                   "triangle's circumradius is at most this many cells (buildings, sparse ground under canopy); "
                   "wider gaps get a smooth pyramid fill. 0: pyramid fill only.")
@click.option("--resume/--no-resume", default=True, show_default=True,
              help="Keep each finished tile's grids in OUTDIR.resume/ next to OUTDIR until the rasters are written "
                   "(28 bytes a cell, uncompressed), and take back the tiles a killed or interrupted run of the same "
                   "inputs and settings kept there (the folder goes when the run ends or fails); --no-resume: start "
                   "over (what an interrupted run kept is removed first; this run's tiles are kept as usual).")
def rasters(*, in_paths, outdir, res_m, crs, tile_px, buffer_px, dem_fill_radius_px, resume):
    """dem/dsm/ndsm/chm/intensity/dsm_nearest COGs and hillshade.png from classified LAS/LAZ file(s) (one or more
    strips in one CRS) into OUTDIR, by tiles read straight from the files (no merged cloud).

    The rasters are in the files' CRS; heights in its vertical unit (band unit type and tags say
    which). A run after a kill, Ctrl-C or SIGTERM computes only the tiles the interrupted run did not finish
    (--resume).
    """
    import logging

    from aerotri.core.resume import beside, discard_kept
    from aerotri.geom import las
    from lidarctl import io
    from lidarctl.rasters import products as rs

    _, units = io.resolve_crs_units(in_paths[0], las.read_header(in_paths[0]), crs)
    if not units.is_metric:
        logging.getLogger(__name__).info(
            "%s: %s; cells of %g m = %.6g %s, heights in %s", in_paths[0], units.describe(), res_m,
            res_m / units.xy_m, units.xy_name, units.z_name)
    from lidarctl.normalised import warn_if_normalised

    warn_if_normalised(in_paths, crs)
    resume_dir = beside(outdir)
    if not resume:
        discard_kept(resume_dir)
    for p in rs.write_rasters(list(in_paths), outdir, res_m, crs=crs, tile_px=tile_px, buffer_px=buffer_px,
                              dem_fill_radius_px=dem_fill_radius_px, resume_dir=resume_dir):
        click.echo(str(p))


@click.command(cls=Command)
@click.argument("in_paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--dsm-nearest", "nearest_path", type=click.Path(dir_okay=False), default=None,
              help="The nearest-return DSM the crowns are cut into [OUTDIR/dsm_nearest.tif, of lidarctl rasters].")
@click.option("--tile-m", "tile_m", type=positive(), default=500.0, show_default=True,
              help="Tile side (m): the returns of a tile and its halo (about 40 m) are held in memory at a time; "
                   "the outputs do not depend on it.")
def crowns(*, in_paths, outdir, nearest_path, tile_m):
    """Tree crowns fitted to their returns for the true ortho's occlusion test: crowns.gpkg (a disk, top and crown
    base per tree) and dsm_crowns.tif (the nearest-return DSM with them) into OUTDIR, from classified LAS/LAZ
    file(s) (strips in one CRS, by tiles; docs/true-ortho.md, "Tree crowns fitted to their returns"). The
    chain's rasters stage writes them after the rasters; ortho rectify --occlusion-dsm dsm_crowns.tif --crowns
    crowns.gpkg reads them."""
    from pathlib import Path

    from aerotri.core.errors import InputError
    from lidarctl.rasters.crown_model import write_crown_model

    nearest = Path(nearest_path) if nearest_path else Path(outdir) / "dsm_nearest.tif"
    if not nearest.is_file():
        raise InputError(f"{nearest}: nearest-return DSM not found; expected dsm_nearest.tif of lidarctl rasters "
                         "(--dsm-nearest)")
    for p in write_crown_model(list(in_paths), nearest, outdir, tile_m=tile_m):
        click.echo(str(p))
