"""``ortho`` command line: thin click subcommands over library functions."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from aerotri.core.commands import FiniteFloatRange, Group, scheduler_options
from aerotri.core.console import console_script
from aerotri.core.executor import executor_for
from aerotri.core.settings import click_option
from ortho.settings import CheckSettings, MosaicSettings, RectifySettings

if TYPE_CHECKING:
    from ortho.check import DomCheck


@click.group(cls=Group)
@click.version_option(package_name="aerotri")
def main():
    """Orthorectification on the LiDAR DEM, seamlines, mosaics and DOM accuracy checks."""


def _settings(cls, project):
    """The settings of an ortho command over PROJECT: defaults < project.toml section < options given."""
    from aerotri.core.project import Project
    from aerotri.core.settings import resolve

    return resolve(cls, Project.open(project), click.get_current_context())


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click_option(RectifySettings, "dem", "--dem")
@click_option(RectifySettings, "res_m", "--res-m")
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
@click_option(RectifySettings, "occlusion_dsm", "--occlusion-dsm")
@click_option(RectifySettings, "footprints", "--footprints")
@click_option(RectifySettings, "crown_base", "--crown-base")
@click_option(RectifySettings, "crowns", "--crowns")
@click_option(RectifySettings, "max_view_angle_deg", "--max-view-angle-deg")
@click.option("--frames", help="comma-separated image ids (default: all images)")
@click_option(RectifySettings, "compression", "--frame-compress")
@click_option(RectifySettings, "overviews", "--frame-overviews")
@scheduler_options
def rectify(*, project, params_path, heights_path, allow_ballpark, eo_path, camera_path, frames, scheduler, workers,
            **_settings_given):
    """One orthoimage per frame (ortho/frames/<image_id>.tif with a validity mask), one Dask task per frame.

    Settings: the defaults, then project.toml [rectify], then the options given here (ortho/frames/index.json
    lists each with where it came from)."""
    from aerotri.geom.crs.definition import crs_label, parse_crs
    from ortho.block import rectify_block

    with executor_for(scheduler, workers) as executor:
        done = rectify_block(project, _settings(RectifySettings, project), eo_path=eo_path, camera_path=camera_path,
                              frames=frames.split(",") if frames else None, executor=executor, params=params_path,
                              heights=heights_path, allow_ballpark=allow_ballpark)
    given = len(set(frames.split(","))) if frames else len(done.image_ids)
    kept = len(done.image_ids) - given  # a subset re-run brings the earlier frames of the same grid along
    count = f"{given} frame{'s' if given != 1 else ''}" + (f" ({kept} earlier kept)" if kept > 0 else "")
    click.echo(f"rectified {count} at {done.res_m} m in {crs_label(parse_crs(done.crs_wkt))}"
               f"{' (' + done.operation + ')' if done.operation else ''} -> {Path(project) / 'ortho' / 'frames'}")


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--res-m", "res_m", type=FiniteFloatRange(min=0.0, min_open=True), default=None,
              help="cell size (m) [about 4 tie points per cell]")
@click.option("--min-rays", type=click.IntRange(min=2), default=3, show_default=True,
              help="tie points seen in at least this many frames")
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), help="output GeoTIFF [at/dem.tif]")
def dem(project, res_m, min_rays, out):
    """A DEM (COG, project CRS) from the adjusted tie points (at/object_points.csv), over the frames' footprints:
    for blocks without a DEM from elsewhere (ortho rectify --dem at/dem.tif)."""
    from ortho.points_dem import write_points_dem

    s = write_points_dem(project, out, res_m, min_rays)
    click.echo(f"DEM {s.width} x {s.height} cells at {s.res_m} m from {s.points} tie points "
               f"({s.outliers} outliers out, {100.0 * s.outliers / max(s.points + s.outliers, 1):.0f} %; cells "
               f"measured {s.cells_measured}, interpolated {s.cells_interpolated}, extended {s.cells_extrapolated}), "
               f"heights {s.height_range_m[0]:.2f} to {s.height_range_m[1]:.2f} -> {s.file}")
    if s.cells_extrapolated:
        click.echo(f"  {s.extension_words()}")


def _frame_ids(ctx, param, values):
    """--exclude given once per frame or as a comma-separated list (as rectify's --frames)."""
    return tuple(i.strip() for v in values for i in v.split(",") if i.strip())


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click_option(MosaicSettings, "seams", "--seams")
@click_option(MosaicSettings, "ndsm", "--ndsm")
@click_option(MosaicSettings, "feather_m", "--feather-m")
@click_option(MosaicSettings, "balance", "--balance/--no-balance")
@click_option(MosaicSettings, "offsets", "--offsets/--no-offsets")
@click_option(MosaicSettings, "tile_px", "--tile-px")
@click_option(MosaicSettings, "output_bits", "--output-bits")
@click_option(MosaicSettings, "output_range", "--output-range")
@click_option(MosaicSettings, "exclude", "--exclude", multiple=True, show_default=False, callback=_frame_ids,
              help="Leave this frame out of the mosaic (repeatable, or image ids separated by commas): no seams, "
                   "balancing or blending from it; its ortho stays in ortho/frames (project.toml [mosaic] exclude).")
@click.option("--seamlines", "seamlines", type=click.Path(path_type=Path),
              help="edited seamlines: a GeoPackage of one polygon per frame (field 'frame'), as ortho/seamlines.gpkg; "
                   "its polygons are the seams (checked for gaps, overlaps and frames that do not cover them; where "
                   "they cross buildings or trees the automatic seams do not: a warning, ortho/seam_crossings.gpkg)")
@click.option("--crs", "crs", help="the product CRS the frames must be in (as given to ortho rectify); the mosaic never "
                                    "resamples twice, so frames in another CRS are refused [the frames' CRS]")
@scheduler_options
def mosaic(project, crs, seamlines, scheduler, workers, **_settings_given):
    """Seamlines, blending and radiometric balancing into ortho/mosaic.tif (COG), ortho/seamlines.geojson,
    ortho/seamlines.gpkg (one polygon per frame, to edit and give back with --seamlines) and
    ortho/seamlines_preview.png (the seams over the DOM, nodata hatched); one Dask task per output tile.

    Settings: the defaults, then project.toml [mosaic], then the options given here (ortho/mosaic.json lists
    each with where it came from)."""
    from ortho.block import require_frames_crs
    from ortho.mosaic import mosaic_block

    if crs is not None:
        require_frames_crs(project, crs)
    with executor_for(scheduler, workers) as executor:
        done = mosaic_block(project, _settings(MosaicSettings, project), executor=executor, seamlines=seamlines)
    click.echo(f"mosaic {done.width_px} x {done.height_px} px of {done.frames} frames -> {done.path}")


@main.command()
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--reference", "reference_path", type=click.Path(path_type=Path), help="reference orthophoto GeoTIFF")
@click.option("--points", "points_path", type=click.Path(path_type=Path),
              help="CSV id,x,y,x_dom,y_dom: surveyed points and their positions measured in the DOM")
@click.option("--dom", "dom_path", type=click.Path(path_type=Path), help="DOM to check [ortho/mosaic.tif]")
@click_option(CheckSettings, "roof_corners", "--roof-corners")
@click_option(CheckSettings, "ndsm", "--ndsm")
@click_option(CheckSettings, "max_ndsm_m", "--max-ndsm-m")
@click_option(CheckSettings, "patch_px", "--patch-px")
@click_option(CheckSettings, "search_px", "--search-px")
@click.option("--out", "out_stem", type=click.Path(path_type=Path), help="report stem [ortho/dom_report]")
@click.option("--params", "params_path", type=click.Path(dir_okay=False, path_type=Path),
              help="datum parameter file ('aerotri crs fit') relating the reference's CRS and the DOM's")
@click.option("--allow-ballpark", is_flag=True, help="accept PROJ's ballpark operation between the two CRSs")
def check(*, project, reference_path, points_path, dom_path, out_stem, params_path, allow_ballpark, **_settings_given):
    """DOM accuracy against a reference orthophoto (NCC patches) or surveyed points; JSON and a plot.

    Settings: the defaults, then project.toml [dom_check] (a folder with one), then the options given here."""
    from aerotri.core.settings import resolve
    from ortho.check import run_check

    if (reference_path is None) == (points_path is None):
        raise click.UsageError("give exactly one of --reference or --points")
    has_project = (Path(project) / "project.toml").is_file()
    settings = _settings(CheckSettings, project) if has_project else resolve(CheckSettings, None, click.get_current_context())
    report = run_check(project, settings, reference_path=reference_path, points_path=points_path, dom_path=dom_path,
                       out_stem=out_stem, params=params_path, allow_ballpark=allow_ballpark)
    click.echo(_check_line(report, "patches" if reference_path else "points"))
    if report.reference_ballpark:  # the figures hold the datum shift: said beside them, not only in the JSON
        from ortho.check import reference_ballpark_words

        click.echo(f"reference through {report.reference_operation}: {reference_ballpark_words(report)}")
    if report.roofs is not None:
        click.echo(_roofs_line(report))
    if report.seams is not None:
        click.echo(_seams_line(report.seams))


def _seams_line(s) -> str:
    """The seam misalignment: block RMS, texture floor and patches left out, the worst seam (or "not measured"), the
    seams most of whose textured patches found no match."""
    floor = f" {s.min_texture_ratio:g}" if s.min_texture_ratio is not None else ""
    lost = s.unmatched_seams()
    lost_text = ""
    if lost:
        named = ", ".join(f"{p.image_a} / {p.image_b} {p.unmatched} of {p.textured}" for p in lost[:4])
        lost_text = (f"; {len(lost)} seams did not match ({named}{', ...' if len(lost) > 4 else ''}): frames off by "
                     "more than the search?")
    if not s.patches:
        if s.unsettled or s.unmatched:
            counts = (f"{s.one_direction} below the texture floor{floor}, {s.unmatched or 0} without a match, "
                      f"{s.unsettled} unsettled")
            return (f"seams: 0 of {s.examined} patches matched ({counts})" + lost_text if lost
                    else f"seams: not measured (0 of {s.examined} patches: {counts})")
        return f"seams: not measured (0 of {s.examined} patches above the texture floor{floor})"
    worst = s.worst()
    text = (f"seams: {s.patches} of {s.examined} patches (texture floor{floor}): RMS {s.rms_px:.3f} px; worst seam ")
    if worst is None:
        return text + f"not judged (no seam of {s.least_patches} patches)" + lost_text
    return text + (f"{worst.image_a} / {worst.image_b} {worst.rms_px:.3f} px ({worst.patches} patches; "
                   f"{len(s.judged())} of {len(s.per_seam)} seams of {s.least_patches}+ patches)") + lost_text


def _check_line(report: DomCheck, what: str) -> str:
    s, u = report.displacement, report.unmatched
    # the textured patches that found no match (``ortho.check.UnmatchedPatches``): failing, or counted
    lost = f" (FAILS: {u.note()})" if u is not None and u.fails() else (
        f" ({u.patches} of {u.textured} textured without a match)" if u is not None and u.patches else "")
    if not s.count:
        return f"no usable {what}{lost} -> {report.json_path}"
    return (f"{s.count} {what}: RMS {s.rms_xy_m:.3f} m ({s.rms_xy_gsd:.2f} GSD), max {s.max_xy_m:.3f} m{lost} "
            f"-> {report.json_path}")


def _roofs_line(report: DomCheck) -> str:
    r = report.roofs
    if not r.count:
        why = report.roofs_why or f"{report.roof_corners or 0} roof corners, none measurable"
        return f"roofs: none measured ({why})"
    from ortho.check import roofs_not_measured_words

    in_nodata = roofs_not_measured_words(report)
    # the median in GSD as _roofs_document divides
    return (f"roofs: {r.count} of {report.roof_corners} corners{in_nodata}: RMS {r.rms_xy_m:.3f} m "
            f"({r.rms_xy_gsd:.2f} GSD), median {r.median_xy_m:.3f} m ({r.median_xy_m / r.gsd_m:.2f} GSD)")


# the console script (pyproject.toml): ``main``, then the process ends without Python's finalization
# (``aerotri.core.console``: 0.2 CPU-s of a demo mosaic); tests run ``main`` itself through CliRunner
run = console_script(main)
