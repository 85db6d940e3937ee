"""``ortho`` command line: thin click subcommands over library functions."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Group, scheduler_options
from aerotri.core.executor import executor_for
from aerotri.core.settings import click_option
from ortho.settings import CheckSettings, MosaicSettings, RectifySettings


@click.group(cls=Group)
@click.version_option(package_name="aerotri")
def main():
    """Orthorectification on the LiDAR DEM, seamlines, mosaics and DOM accuracy checks."""


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click_option(RectifySettings, "dem", "--dem")
@click_option(RectifySettings, "res_m", "--res")
@click_option(RectifySettings, "crs", "--crs")
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
@click_option(RectifySettings, "interpolation", "--interpolation")
@click_option(RectifySettings, "true_ortho", "--true-ortho")
@click_option(RectifySettings, "dsm", "--dsm")
@click.option("--frames", help="comma-separated image ids (default: all images)")
@click_option(RectifySettings, "compression", "--frame-compress")
@scheduler_options
def rectify(project, dem, res_m, crs, params_path, heights_path, allow_ballpark, eo_path, camera_path,
            interpolation, true_ortho, dsm, frames, compression, scheduler, workers):
    """One orthoimage per frame (ortho/frames/<image_id>.tif with a validity mask), one Dask task per frame."""
    from ortho.block import rectify_block

    settings = RectifySettings(dem=dem, res_m=res_m, crs=crs, interpolation=interpolation, true_ortho=true_ortho,
                               dsm=dsm, compression=compression)
    with executor_for(scheduler, workers) as executor:
        index = rectify_block(project, eo_path=eo_path, camera_path=camera_path,
                              frames=frames.split(",") if frames else None, executor=executor, params=params_path,
                              heights=heights_path, allow_ballpark=allow_ballpark, **settings.kwargs())
    from aerotri.geom.crs import crs_label, parse_crs

    op = index.get("coordinate_operation")
    click.echo(f"rectified {len(index['frames'])} frames at {index['res_m']} m in {crs_label(parse_crs(index['crs']))}"
               f"{' (' + op['description'] + ')' if op else ''} -> {Path(project) / 'ortho' / 'frames'}")


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--res", "res_m", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="cell size (m) [about 4 tie points per cell]")
@click.option("--min-rays", type=click.IntRange(min=2), default=3, show_default=True,
              help="tie points seen in at least this many frames")
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), help="output GeoTIFF [at/dem.tif]")
def dem(project, res_m, min_rays, out):
    """A DEM (COG, project CRS) from the adjusted tie points (at/object_points.csv), over the frames' footprints:
    for blocks without a DEM from elsewhere (ortho rectify --dem at/dem.tif)."""
    from ortho.points_dem import write_points_dem

    s = write_points_dem(project, out, res_m, min_rays)
    click.echo(f"DEM {s['width']} x {s['height']} cells at {s['res_m']} m from {s['points']} tie points "
               f"({s['outliers']} outliers out; cells measured {s['cells_measured']}, interpolated "
               f"{s['cells_interpolated']}, extended {s['cells_extrapolated']}), heights {s['height_range_m'][0]:.2f} to "
               f"{s['height_range_m'][1]:.2f} -> {s['file']}")


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click_option(MosaicSettings, "seams", "--seams")
@click_option(MosaicSettings, "ndsm", "--ndsm")
@click_option(MosaicSettings, "feather_m", "--feather-m")
@click_option(MosaicSettings, "balance", "--balance/--no-balance")
@click_option(MosaicSettings, "tile_px", "--tile-px")
@click.option("--crs", "crs", help="the product CRS the frames must be in (as given to ortho rectify); the mosaic never "
                                    "resamples twice, so frames in another CRS are refused [the frames' CRS]")
@scheduler_options
def mosaic(project, seams, ndsm, feather_m, balance, tile_px, crs, scheduler, workers):
    """Seamlines, blending and radiometric balancing into ortho/mosaic.tif (COG) and ortho/seamlines.geojson;
    one Dask task per output tile."""
    from ortho.mosaic import mosaic_block

    if crs is not None:
        from ortho.block import require_frames_crs

        require_frames_crs(project, crs)
    settings = MosaicSettings(seams=seams, ndsm=ndsm, feather_m=feather_m, balance=balance, tile_px=tile_px)
    with executor_for(scheduler, workers) as executor:
        info = mosaic_block(project, executor=executor, **settings.kwargs())
    click.echo(f"mosaic {info['width']} x {info['height']} px of {info['frames']} frames -> {info['path']}")


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--reference", "reference_path", type=click.Path(path_type=Path), help="reference orthophoto GeoTIFF")
@click.option("--points", "points_path", type=click.Path(path_type=Path),
              help="CSV id,x,y,x_dom,y_dom: surveyed points and their positions measured in the DOM")
@click.option("--dom", "dom_path", type=click.Path(path_type=Path), help="DOM to check [ortho/mosaic.tif]")
@click.option("--ndsm", "ndsm_path", type=click.Path(path_type=Path), help="keep only ground patches (nDSM <= --max-ndsm-m)")
@click_option(CheckSettings, "max_ndsm_m", "--max-ndsm-m")
@click_option(CheckSettings, "patch_px", "--patch-px")
@click_option(CheckSettings, "search_px", "--search-px")
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
    settings = CheckSettings(max_ndsm_m=max_ndsm_m, patch_px=patch_px, search_px=search_px)
    report = run_check(project, reference_path=reference_path, points_path=points_path, dom_path=dom_path,
                       ndsm_path=ndsm_path, out_stem=out_stem, params=params_path, allow_ballpark=allow_ballpark,
                       **settings.kwargs())
    s = report["displacement"]
    if s.get("count"):
        click.echo(f"{s['count']} {'patches' if reference_path else 'points'}: RMS {s['rms_xy_m']:.3f} m "
                   f"({s['rms_xy_gsd']:.2f} GSD), max {s['max_xy_m']:.3f} m -> {report['json']}")
    else:
        click.echo(f"no usable {'patches' if reference_path else 'points'} -> {report['json']}")
