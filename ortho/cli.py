"""``ortho`` command line: thin click subcommands over library functions."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Group, at_least, finite, positive, scheduler_options
from aerotri.core.executor import executor_for


@click.group(cls=Group)
@click.version_option(package_name="aerotri")
def main():
    """Orthorectification on the LiDAR DEM, seamlines, mosaics and DOM accuracy checks."""


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--dem", "dem_path", type=click.Path(path_type=Path), help="DEM GeoTIFF [lidar_out/dem.tif]")
@click.option("--res", "res_m", type=positive(), help="output pixel size in metres, > 0 [median nadir GSD, rounded]")
@click.option("--crs", "crs", help="output CRS: EPSG code (e.g. EPSG:4546), or gk3:cgcs2000 / gk3:xian1980 for the "
                                    "3-degree GK zone nearest the block centre [the --params target, else the "
                                    "project CRS]")
@click.option("--params", "params_path", type=click.Path(dir_okay=False, path_type=Path),
              help="datum parameter file from 'aerotri crs fit' (e.g. WGS 84 UTM -> Xian 1980 GK); needed when the "
                   "output CRS is on another datum")
@click.option("--heights", "heights_path", type=click.Path(dir_okay=False, path_type=Path),
              help="height anomaly model from 'aerotri crs fit-heights', for a DEM in normal heights")
@click.option("--allow-ballpark", is_flag=True,
              help="accept PROJ's ballpark operation that ignores a datum shift (errors of decimetres to "
                   "hundreds of metres)")
@click.option("--eo", "eo_path", type=click.Path(path_type=Path), help="EO file [at/eo.txt]")
@click.option("--camera", "camera_path", type=click.Path(path_type=Path), help="camera file [camera.toml]")
@click.option("--interpolation", type=click.Choice(["nearest", "bilinear", "cubic", "lanczos"]), default="bilinear",
              show_default=True)
@click.option("--true-ortho", is_flag=True, help="rectify on the DSM and mask pixels occluded by it")
@click.option("--dsm", "dsm_path", type=click.Path(path_type=Path), help="DSM GeoTIFF for --true-ortho")
@click.option("--frames", help="comma-separated image ids (default: all images)")
@click.option("--frame-compress", "compression", type=click.Choice(["zstd", "zstd-fast", "none"]), default="zstd",
              show_default=True, help="per-frame GeoTIFFs: zstd (level 1 + predictor), zstd-fast (no predictor, "
                                      "~1.7x larger), none (least CPU, ~3.7x larger)")
@scheduler_options
def rectify(project, dem_path, res_m, crs, params_path, heights_path, allow_ballpark, eo_path, camera_path,
            interpolation, true_ortho, dsm_path, frames, compression, scheduler, workers):
    """One orthoimage per frame (ortho/frames/<image_id>.tif with a validity mask), one Dask task per frame."""
    from ortho.block import rectify_block

    with executor_for(scheduler, workers) as executor:
        index = rectify_block(project, dem_path, res_m, crs, eo_path, camera_path, interpolation, true_ortho, dsm_path,
                              frames.split(",") if frames else None, executor=executor, compression=compression,
                              params=params_path, heights=heights_path, allow_ballpark=allow_ballpark)
    op = index.get("coordinate_operation")
    click.echo(f"rectified {len(index['frames'])} frames at {index['res_m']} m in {index['crs_name']}"
               f"{' (' + op['description'] + ')' if op else ''} -> {Path(project) / 'ortho' / 'frames'}")


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--seams", type=click.Choice(["least-cost", "voronoi"]), default="least-cost", show_default=True)
@click.option("--ndsm", "ndsm_path", type=click.Path(path_type=Path),
              help="nDSM for seam costs (buildings, trees) [lidar_out/ndsm.tif if present]")
@click.option("--feather-m", type=at_least(0.0), default=None,
              help="feather width across seams in metres, >= 0 (0: one pixel) [8 GSD]")
@click.option("--no-balance", is_flag=True, help="skip the gain balancing between frames")
@click.option("--tile-px", type=at_least(16, int), default=1024, show_default=True,
              help="mosaic processing tile size (px, >= 16)")
@click.option("--crs", "crs", help="the product CRS the frames must be in (as given to ortho rectify); the mosaic never "
                                    "resamples twice, so frames in another CRS are refused [the frames' CRS]")
@scheduler_options
def mosaic(project, seams, ndsm_path, feather_m, no_balance, tile_px, crs, scheduler, workers):
    """Seamlines, blending and radiometric balancing into ortho/mosaic.tif (COG) and ortho/seamlines.geojson;
    one Dask task per output tile."""
    from ortho.mosaic import mosaic_block

    if crs is not None:
        from ortho.block import require_frames_crs

        require_frames_crs(project, crs)
    with executor_for(scheduler, workers) as executor:
        info = mosaic_block(project, seams=seams, ndsm_path=ndsm_path, feather_m=feather_m, balance=not no_balance,
                            tile_px=tile_px, executor=executor)
    click.echo(f"mosaic {info['width']} x {info['height']} px of {info['frames']} frames -> {info['path']}")


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--reference", "reference_path", type=click.Path(path_type=Path), help="reference orthophoto GeoTIFF")
@click.option("--points", "points_path", type=click.Path(path_type=Path),
              help="CSV id,x,y,x_dom,y_dom: surveyed points and their positions measured in the DOM")
@click.option("--dom", "dom_path", type=click.Path(path_type=Path), help="DOM to check [ortho/mosaic.tif]")
@click.option("--ndsm", "ndsm_path", type=click.Path(path_type=Path), help="keep only ground patches (nDSM <= --max-ndsm-m)")
@click.option("--max-ndsm-m", type=finite(), default=0.5, show_default=True,
              help="highest nDSM value (m) of a ground patch")
@click.option("--patch-px", type=at_least(8, int), default=48, show_default=True, help="patch size (px, >= 8)")
@click.option("--search-px", type=at_least(1, int), default=6, show_default=True,
              help="search radius around each patch (px, >= 1)")
@click.option("--out", "out_stem", type=click.Path(path_type=Path), help="report stem [ortho/dom_report]")
@click.option("--params", "params_path", type=click.Path(dir_okay=False, path_type=Path),
              help="datum parameter file ('aerotri crs fit') relating the reference's CRS and the DOM's")
@click.option("--allow-ballpark", is_flag=True, help="accept PROJ's ballpark operation between the two CRSs")
def check(project, reference_path, points_path, dom_path, ndsm_path, max_ndsm_m, patch_px, search_px, out_stem,
          params_path, allow_ballpark):
    """DOM accuracy against a reference orthophoto (NCC patches) or surveyed points; JSON and a plot."""
    from ortho.check import run_check

    if (reference_path is None) == (points_path is None):
        raise click.UsageError("give exactly one of --reference or --points")
    report = run_check(project, reference_path=reference_path, points_path=points_path, dom_path=dom_path,
                       ndsm_path=ndsm_path, max_ndsm_m=max_ndsm_m, patch_px=patch_px, search_px=search_px,
                       out_stem=out_stem, params=params_path, allow_ballpark=allow_ballpark)
    s = report["displacement"]
    if s.get("count"):
        click.echo(f"{s['count']} {'patches' if reference_path else 'points'}: RMS {s['rms_xy_m']:.3f} m "
                   f"({s['rms_xy_gsd']:.2f} GSD), max {s['max_xy_m']:.3f} m -> {report['json']}")
    else:
        click.echo(f"no usable {'patches' if reference_path else 'points'} -> {report['json']}")
