"""``lidarctl`` command line: thin click subcommands over library functions.

Every length option is in metres (``_m`` in its name), whatever the CRS of the cloud: clouds in
feet are scaled to metres as they are read (``lidarctl.io``) and outputs are written back in the
cloud's CRS and units, which the outputs name (raster tags, JSON keys, printed labels).
"""

from __future__ import annotations

import click

from aerotri.core.atomic import refuse_input_as_output
from aerotri.core.commands import FiniteFloatRange, Group, at_least, fraction, positive, scheduler_options
from aerotri.core.settings import click_option, resolve
from lidarctl.classify.pipeline import ClassifySettings
from lidarctl.checks.heights import GROUPINGS, DensityGroups
from lidarctl.checks.map_accuracy import MapEvalSettings
from lidarctl.vectors.layers import MapVectorSettings
from lidarctl.checks.plan import PlanCheckSettings
from lidarctl.checks.vectors import VectorCheckSettings
from lidarctl.terrain.hydro import HydroSettings
from lidarctl.rasters.products import DEFAULT_BUFFER_PX, DEFAULT_TILE_PX, DEFAULT_TIN_FILL_RADIUS_PX, RasterSettings


@click.group(cls=Group)
@click.version_option(package_name="aerotri")
def main():
    """Airborne LiDAR: noise removal, ground filtering, classification, rasters, roof-corner control."""


from lidarctl.cli.corners import corners  # noqa: E402
from lidarctl.cli.merge import merge  # noqa: E402
from lidarctl.cli.strips import strips  # noqa: E402
from lidarctl.cli.trees import trees  # noqa: E402

main.add_command(corners)
main.add_command(merge)
main.add_command(strips)
main.add_command(trees)


_DENSITY = DensityGroups()


def _parse_map(text: str | None, option: str) -> dict:
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        try:
            a, b = item.split(":")
            a, b = int(a), int(b)
        except ValueError:
            raise click.BadParameter(f"{item!r}: expected FROM:TO class pairs, e.g. 3:1,4:1", param_hint=option) from None
        if not (0 <= a <= 255 and 0 <= b <= 255):  # ASPRS codes are bytes (TO 255: leave out)
            raise click.BadParameter(f"{item!r}: class codes are 0-255", param_hint=option)
        if a in out:
            raise click.BadParameter(f"{item!r}: class {a} mapped twice", param_hint=option)
        out[a] = b
    return out


def ground_filter_options(f):
    """``--ground-params FILE`` and one option per parameter of every registered ground filter
    (``--morph-cell-m``, ``--ptd-seed-cell-m``, ...), listed in ``--help`` under one heading per filter."""
    import dataclasses

    from aerotri.core.commands import GroupedOption
    from aerotri.core.settings import click_type, constraints
    from lidarctl.classify import ground

    for method, flt in reversed(list(ground.GROUND_FILTERS.items())):
        defaults = flt.params()
        for fld in reversed(dataclasses.fields(flt.params)):
            f = click.option(ground.option_name(method, fld.name), f"gp__{method}__{fld.name}", cls=GroupedOption,
                             group=f"Ground filter {method!r}, {flt.help} (--method {method}; [default] without --preset)",
                             type=click_type(flt.params, fld.name), default=None,
                             help=f"{constraints(fld).help} [{getattr(defaults, fld.name):g}]")(f)
    return click.option("--ground-params", "ground_params_file", type=click.Path(dir_okay=False), default=None,
                        help="TOML file of ground-filter parameters: optional method and preset keys and a table "
                             "per filter, e.g. [ptd] seed_cell_m = 20.0; the options below override it.")(f)


@main.command()
@click.argument("in_paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.argument("out_path", type=click.Path())
@click_option(ClassifySettings, "preset", "--preset")
@click.option("--crs", default=None, help="CRS (EPSG:code) when the file has none; never guessed.")
@click_option(ClassifySettings, "ground_method", "--method")
@click.option("--tile-size-m", "tile_size_m", type=positive(), default=None,
              help="Tile size in metres, also for clouds in feet (default: about 4 M points per tile with its "
                   "buffer at the file's density).")
@click.option("--buffer-m", "buffer_m", type=positive(), default=None,
              help="Overlap buffer around each tile in metres (default: the ground filter's reach, 60 m).")
@click.option("--work-dir", type=click.Path(file_okay=False), default=None,
              help="Folder for the temporary tile files (default: next to the output; removed afterwards).")
@click_option(ClassifySettings, "keep_classes", "--keep-classes")
@click.option("--format", "out_format", type=click.Choice(["las", "laz"]), default=None,
              help="Format of the classified strips in an output folder (default: each strip's own).")
@click.option("--image", "image_path", type=click.Path(dir_okay=False), default=None,
              help="Orthophoto (GeoTIFF, R G B [NIR], the cloud's CRS) to fuse with: grass and trees split by "
                   "greenness at 1 m, road surface (11) from intensity, smoothness and shape, green 'buildings' "
                   "made trees (lidarctl.classify.fusion).")
@click.option("--nir", default=None,
              help="--image: the near-infrared band number of the orthophoto (e.g. 4) or a one-band file on its "
                   "grid; greenness is then NDVI, else excess green.")
@click.option("--resume/--no-resume", default=True, show_default=True,
              help="Keep each finished tile in OUT.resume/ next to the output until the output is written, and take "
                   "back the tiles a killed or interrupted run of the same inputs and settings kept there (the folder "
                   "goes when the run ends or fails); --no-resume: start over (what an interrupted run kept is removed "
                   "first; this run's tiles are kept as usual).")
@scheduler_options
@ground_filter_options
def classify(*, in_paths, out_path, crs, tile_size_m, buffer_m, work_dir, out_format, image_path, nir, scheduler,
             workers, ground_params_file, resume, **options):
    """Noise, ground, buildings, vegetation and water as ASPRS classes (LAS/LAZ in, LAS/LAZ out).

    One file: IN_PATH OUT_PATH (a .las/.laz file). Strips of a block: STRIP... OUT_DIR; they are
    classified together without a merged file (a tile takes its points from every strip) and each
    strip gets its classified copy OUT_DIR/<strip name> (the folder is replaced as a whole, all files
    or none). The strips must share one point format and CRS (--crs: the CRS of strips without one).

    Large clouds are cut into tiles with overlap buffers, classified as parallel tasks and written
    back in file order (memory bounded by the tile size, not the file or block size; lidarctl.tiles).
    A cloud in feet is classified in metres; the output is the input with new classes (same CRS and
    units). A run after a kill, Ctrl-C or SIGTERM classifies only the tiles the interrupted run did not
    finish (--resume).
    """
    from aerotri.core.settings import option_given
    from lidarctl.tiles import classify_command

    ctx = click.get_current_context()
    ground = {tuple(k.split("__")[1:]): v for k, v in options.items() if k.startswith("gp__")}
    click.echo(classify_command(
        in_paths, out_path, options["keep_classes"], options["ground_method"], options["preset"], crs=crs,
        tile_size_m=tile_size_m,
        buffer_m=buffer_m, work_dir=work_dir, out_format=out_format, image_path=image_path, nir=nir,
        ground_params_file=ground_params_file, ground_options=ground, method_given=option_given(ctx, "ground_method"),
        preset_given=option_given(ctx, "preset"), scheduler=scheduler, workers=workers, resume=resume))


@main.command()
@click.argument("in_paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.argument("outdir", type=click.Path(file_okay=False))
@click_option(RasterSettings, "res_m", "--res-m", required=True, default=None, show_default=False,
              help="Cell size in metres, also for clouds in feet (1 m = 3.2808 ft in the GeoTIFF) ([rasters] res_m of "
                   "aerotri run).")
@click.option("--crs", default=None, help="CRS (EPSG:code) of files without one, or with an unreadable one.")
@click.option("--tile-px", type=click.IntRange(min=1), default=DEFAULT_TILE_PX, show_default=True,
              help="Tile size in raster cells (memory: about 160 bytes per cell of a tile with its buffer, two tiles at "
                   "a time).")
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
    resume_dir = beside(outdir)
    if not resume:
        discard_kept(resume_dir)
    for p in rs.write_rasters(list(in_paths), outdir, res_m, crs=crs, tile_px=tile_px, buffer_px=buffer_px,
                              dem_fill_radius_px=dem_fill_radius_px, resume_dir=resume_dir):
        click.echo(str(p))


@main.command()
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


@main.command()
@click.argument("pred_paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--truth", "truth_path", type=click.Path(dir_okay=False), default=None,
              help="Truth cloud with the same points in the same order (point-by-point filter test).")
@click.option("--reference", "reference_path", type=click.Path(dir_okay=False), default=None,
              help="Reference map: class GeoTIFF (ASPRS codes) or class polygons (.gpkg/.geojson); PRED is then a "
                   "classified cloud or a class GeoTIFF, scored per cell and per building.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None, help="Write the numbers as JSON.")
@click.option("--map-pred", default=None,
              help="Class mapping for the prediction, e.g. 3:1,4:1,5:1 (TO 255: leave out); --truth: replaces the "
                   "mapping onto a coarser truth's class 1.")
@click.option("--map-truth", default=None, help="Class mapping for the truth or reference, e.g. 0:1.")
@click.option("--res-m", "res_m", type=positive(), default=None,
              help="--reference: cell size in metres [0.5; with a raster: the raster's cells, or a raster sampled at "
                   "the centres of cells of this size, e.g. to match a sparse cloud].")
@click.option("--class-field", default=MapEvalSettings.class_field, show_default=True,
              help="--reference polygons: the attribute holding the class (ASPRS code or name: building, tree, "
                   "grass, road, bare ground, water).")
@click.option("--reference-class", default=None,
              help="--reference polygons: one class for every polygon (e.g. building for footprints).")
@click.option("--min-overlap", type=fraction(open_low=True, open_high=False), default=MapEvalSettings.min_overlap,
              show_default=True, help="--reference: share of a building's area that must overlap to count it as "
                                      "found (reference) or correct (detected).")
@click.option("--min-building-m2", type=at_least(0), default=MapEvalSettings.min_building_m2,
              show_default=True, help="--reference: buildings smaller than this (m2) are not counted per building.")
@click.option("--within", default=None,
              help="--reference: score only inside the polygons of this file, or 'hull': inside the convex hulls "
                   "of the reference polygons' blocks (a reference that maps only part of the area).")
@click.option("--crs", default=None, help="--reference only: CRS (EPSG:code) of inputs that have none.")
def evaluate(*, pred_paths, truth_path, reference_path, json_path, map_pred, map_truth, res_m, class_field,
             reference_class, min_overlap, min_building_m2, within, crs):
    """Accuracy of the classification PRED_PATHS (one file; --reference: also classified strips).

    --truth: a cloud against its truth cloud point by point: type I/II/total error and kappa (ground =
    classes 2, 9) and the confusion matrix; against a truth with class 1 and no vegetation class (AHN3: 1 2 6 9 26)
    our classes 3 4 5 7 17 18 count as its 1 (said, with the figures before the mapping).

    --reference: a classified cloud (the class of each cell's highest point, noise left out; medium
    vegetation counts as tree) or a class raster against a reference map, as the seeds report it:
    pixel confusion matrix over building, tree, grass, road, bare ground, water with producer's,
    user's and overall accuracy and kappa; buildings per area (type I/II, overall) and per building
    (completeness and correctness by count).
    """
    from aerotri.core.atomic import write_text_atomic

    _check_evaluate_paths(pred_paths, truth_path, reference_path, json_path, within)
    if crs is not None and reference_path is None:
        from aerotri.core.errors import OptionError

        # s27: it was ignored without a word; the truth is compared point by point, by record
        raise OptionError("applies to --reference only: --truth compares the two clouds point by point (record by "
                          "record), not by their coordinates; leave --crs out", param="--crs")
    maps = _parse_map(map_pred, "--map-pred"), _parse_map(map_truth, "--map-truth")
    if reference_path is not None:
        text, json_text = _evaluate_map(pred_paths, reference_path, MapEvalSettings(
            res_m=res_m, min_overlap=min_overlap, min_building_m2=min_building_m2, class_field=class_field,
            reference_class=reference_class, map_pred=maps[0], map_ref=maps[1], crs=crs, within=within))
    else:
        text, json_text = _evaluate_truth(pred_paths, truth_path, *maps)
    click.echo(text)
    if json_path:
        write_text_atomic(json_path, json_text)


def _check_evaluate_paths(pred_paths, truth_path, reference_path, json_path, within) -> None:
    """One of --truth and --reference; --json replaces no input."""
    from aerotri.core.errors import OptionError

    if (truth_path is None) == (reference_path is None):
        raise OptionError("give either --truth (a truth cloud) or --reference (a reference map)",
                          param="--truth" if truth_path is None else "--reference")
    if json_path:
        refuse_input_as_output(json_path, [*pred_paths, truth_path, reference_path,
                                           None if within in (None, "hull") else within], "--json")


def _evaluate_map(pred_paths, reference_path, settings) -> tuple[str, str]:
    """``lidarctl evaluate --reference``: (the report, the --json file's text)."""
    from lidarctl.checks import map_accuracy as ma

    result = ma.evaluate_map(pred_paths, reference_path, settings)
    return ma.format_map_report(result), result.to_json()


def _evaluate_truth(pred_paths, truth_path, map_pred: dict, map_truth: dict) -> tuple[str, str]:
    """``lidarctl evaluate --truth``: (the report, the --json file's text)."""
    from aerotri.core.errors import OptionError
    from lidarctl.checks import classes as ev

    if len(pred_paths) != 1:
        raise OptionError(f"--truth: one classified file, not {len(pred_paths)}", param="--truth")
    result = ev.evaluate_files(pred_paths[0], truth_path, map_pred, map_truth)
    text = "\n".join([ev.format_filter_table({"ground": result.filter_test}), "",
                      ev.format_confusion(result.confusion), *ev.format_class_map(result)]
                     + _truth_notes(result.confusion, result.class_map))
    return text, result.to_json()


def _truth_notes(conf, class_map: dict | None = None) -> list[str]:
    """What the numbers against a truth cloud do not say: its class 1 may hold ground (a production classification:
    Autzen, lidR's topography), and a truth of ground and one other class makes the matrix compare classes it has
    no label for (the ISPRS filter test's 0 / 2). ``class_map``: the mapping already applied to the prediction
    (a truth in a coarser scheme), which the --map-pred offered must repeat (it replaces it)."""
    truth = [c for c, row in zip(conf.classes, conf.matrix) if sum(row) > 0]
    pred = [c for c, col in zip(conf.classes, zip(*conf.matrix)) if sum(col) > 0]
    notes = []
    if 1 in truth:
        notes.append("note: the truth's class 1 (unclassified) counts as object: where it also holds ground (a "
                     "production classification), type II and total overstate the errors; type I does not")
    other = [c for c in truth if c not in (2, 9)]
    if len(other) == 1 and len(set(pred) - {2, 9, other[0]}) > 0:
        mapping = {**{int(a): b for a, b in (class_map or {}).items()},
                   **{c: other[0] for c in sorted(set(pred) - {2, 9, other[0]})}}
        notes.append(f"note: the truth labels ground and class {other[0]} only: the overall accuracy and kappa above "
                     f"count every other predicted class as wrong; --map-pred "
                     + ",".join(f"{a}:{b}" for a, b in sorted(mapping.items())) + " gives the two-class matrix")
    return notes


@main.command("check-heights")
@click.argument("paths", nargs=-1, required=True, type=click.Path(dir_okay=False), metavar="[CLOUD]... POINTS_CSV")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False), default=None,
              help="Also check this DEM GeoTIFF (bilinear height at each point); with no CLOUD, the DEM alone.")
@click.option("--radius-m", "radius_m", type=positive(), default=5.0, show_default=True,
              help="Search radius (m, also for clouds in feet).")
@click.option("--exclude-m", "exclude_m", type=positive(), default=1.0, show_default=True,
              help="Statistics again without points with |dz| beyond this (m).")
@click.option("--groups", "grouping", type=click.Choice(GROUPINGS), default="auto", show_default=True,
              help="Group the statistics by the CSV's group column, by the vegetation density around each point "
                   "(from the cloud's first returns), or not at all; auto: the column when there is one.")
@click.option("--cover-radius-m", "cover_radius_m", type=positive(), default=_DENSITY.radius_m, show_default=True,
              help="Density: radius (m) of the first returns counted around a point.")
@click.option("--canopy-height-m", "canopy_height_m", type=positive(), default=_DENSITY.canopy_height_m,
              show_default=True, help="Density: a first return this high above the ground (m) is canopy.")
@click.option("--open-below", type=fraction(), default=_DENSITY.open_below, show_default=True,
              help="Density: canopy cover below this fraction is open.")
@click.option("--dense-above", type=fraction(open_high=False), default=_DENSITY.dense_above, show_default=True,
              help="Density: canopy cover above this fraction is dense (between: sparse).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Write the numbers as JSON (dz and statistics in metres, _m keys; per-point coordinates "
                   "in the cloud's units, named by xy_unit and z_unit).")
@click.option("--dem-z-unit", "dem_z_unit", type=click.Choice(("m", "ft", "us-ft")), default=None,
              help="The DEM's height unit when the file declares none (no vertical CRS, no VERTICAL_UNITS tag); "
                   "without it they are taken in its CRS's horizontal unit, with a warning.")
@click.option("--crs", default=None, help="CRS (EPSG:code) when the file has none.")
def check_heights(*, paths, dem_path, radius_m, exclude_m, grouping, cover_radius_m, canopy_height_m, open_below,
                  dense_above, json_path, crs, dem_z_unit):
    """Height check against surveyed points (CSV id,x,y,z[,group] in the CRS and units of the cloud, or of the
    DEM): of the cloud's ground (class 2; one file or classified strips) and/or of the DEM raster (--dem);
    dz in metres, error bins, mean |dz| and RMSE overall and per group (seed 004 Tab. 1: by vegetation
    density with --groups density)."""
    from lidarctl.checks import heights as hc
    from aerotri.core.atomic import write_text_atomic

    *cloud_paths, points_csv = paths
    if json_path:
        refuse_input_as_output(json_path, [*cloud_paths, points_csv, dem_path], "--json")
    density = hc.DensityGroups(radius_m=cover_radius_m, canopy_height_m=canopy_height_m, open_below=open_below,
                               dense_above=dense_above)
    result = hc.check_heights_file(cloud_paths, points_csv, radius_m=radius_m, exclude_m=exclude_m, crs=crs,
                                   dem_path=dem_path, grouping=grouping, density=density, dem_z_unit=dem_z_unit)
    click.echo(hc.format_report(result))
    if json_path:
        write_text_atomic(json_path, result.to_json())


@main.command("check-plan")
@click.argument("paths", nargs=-1, required=True, type=click.Path(dir_okay=False), metavar="CLOUD... POINTS_CSV")
@click_option(PlanCheckSettings, "radius_m", "--radius-m")
@click_option(PlanCheckSettings, "min_edge_m", "--min-edge-m")
@click_option(PlanCheckSettings, "scale", "--scale")
@click_option(PlanCheckSettings, "terrain", "--terrain")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Write the numbers as JSON (offsets in metres, _m keys; per-point coordinates in the cloud's "
                   "units).")
@click.option("--png", "png_path", type=click.Path(dir_okay=False), default=None,
              help="Offset vectors over the surveyed points and the histogram of the plan offsets.")
@click.option("--crs", default=None, help="CRS (EPSG:code) of clouds that have none.")
@click.option("--points-crs", default=None, help="CRS of POINTS_CSV, checked against the cloud's (never transformed).")
def check_plan(paths, json_path, png_path, crs, points_crs, **_settings):
    """Plan check of classified CLOUD(s) (building class 6; strips in one CRS) against surveyed roof / building
    corners (POINTS_CSV id,x,y[,z] in the cloud's CRS and units): each point's nearest LiDAR roof corner (the
    eave corners of lidarctl corners) within --radius-m; dx, dy, plan offset (LiDAR - surveyed), RMS x / y /
    plan, mean (bias), max, found / not found, dz when the CSV has z; pass / fail against the map scale's
    plan RMS of well-defined features. Wall corners (cadastre footprints) include the roof overhang."""
    from lidarctl.checks import plan as pc

    *cloud_paths, points_csv = paths
    params = resolve(PlanCheckSettings, None, click.get_current_context()).settings
    result = pc.check_plan_files(cloud_paths, points_csv, params, crs=crs, points_crs=points_crs,
                                 json_path=json_path, png_path=png_path)
    click.echo(pc.format_report(result))


@main.command()
@click.argument("dem_path", type=click.Path(dir_okay=False))
@click.argument("out_path", type=click.Path(dir_okay=False))
@click.option("--order", type=click.Choice(["4", "2"]), default="4", show_default=True,
              help="4: keeps planes and the breaklines between them (crests, toes, embankments); 2 (Perona-Malik): "
                   "keeps steps (walls, cliffs) but rounds creases.")
@click.option("--edge-m", "edge_m", type=positive(), default=None,
              help="What counts as a breakline rather than noise (m, also for DEMs in feet): order 4, the "
                   "4-neighbour Laplacian [1.0]; order 2, the height difference between neighbouring cells [0.5].")
@click.option("--iterations", type=click.IntRange(min=1, max=100000), default=None,
              help="Diffusion steps [order 4: 100; order 2: 20].")
@click.option("--step", type=FiniteFloatRange(min=0, max=0.25, min_open=True), default=None,
              help="Diffusion time step [order 4: 0.03, at most 1/32; order 2: 0.2, at most 0.25].")
@click.option("--window-px", type=click.IntRange(min=16), default=2048, show_default=True,
              help="Processing window in cells (memory about 40 bytes per cell of a window with its halo).")
def smooth(*, dem_path, out_path, order, edge_m, iterations, step, window_px):
    """Edge-preserving smoothing of DEM_PATH (GeoTIFF) into OUT_PATH (COG): anisotropic diffusion, by
    windows (the same result as in one piece); nodata respected, CRS and units kept."""
    from lidarctl.terrain.smooth import DiffusionSettings, smooth_dem

    order = int(order)
    params = DiffusionSettings(order=order, edge_m=edge_m or (1.0 if order == 4 else 0.5),
                               iterations=iterations or (100 if order == 4 else 20), step=step)
    r = smooth_dem(dem_path, out_path, params, window_px)
    click.echo(f"{r.path}: {r.valid_cells:,} of {r.cells:,} cells smoothed ({r.windows} window(s)); "
               f"changes RMS {r.rms_change_m:.3f} m, max {r.max_change_m:.3f} m")


@main.command("hydro-flatten")
@click.argument("dem_path", type=click.Path(dir_okay=False))
@click.argument("out_path", type=click.Path(dir_okay=False))
@click.option("--water", "water_path", type=click.Path(dir_okay=False), required=True,
              help="Water polygons in the DEM's CRS: lidarctl vectors' map (its layer water, with water_z and "
                   "water_z_range_m) or a file of polygons (levels then from their shores).")
@click.option("--water-layer", default=None,
              help="The layer of --water holding the water polygons [water; a file's only layer when it has a "
                   "water_z field].")
@click_option(HydroSettings, "max_range_m", "--max-range-m")
@click_option(HydroSettings, "shore_cells", "--shore-cells")
@click_option(HydroSettings, "shore_percentile", "--shore-percentile")
def hydro_flatten(*, dem_path, out_path, water_path, water_layer, **_settings):
    """Hydro-flatten DEM_PATH (GeoTIFF) into OUT_PATH (COG): each standing water body of --water at one level, at
    or below its shore (USGS Lidar Base Specification); flowing water (water returns spanning more than
    --max-range-m) is left as it is and listed. Nothing else changes."""
    from lidarctl.terrain.hydro import format_result, hydro_flatten as flatten

    params = resolve(HydroSettings, None, click.get_current_context()).settings
    click.echo(format_result(flatten(dem_path, water_path, out_path, params, water_layer)))


@main.command()
@click.argument("dem_path", type=click.Path(dir_okay=False))
@click.argument("out_path", type=click.Path(dir_okay=False))
@click.option("--interval-m", type=positive(), required=True,
              help="Contour interval (m), traced in the DEM's height unit: 0.3048 gives 1 ft on a DEM in feet "
                   "(international or US survey: an interval within 10 ppm of a whole number of feet is that "
                   "number); levels at its whole multiples.")
@click.option("--index", "index_every", type=click.IntRange(min=0), default=5, show_default=True,
              help="Every N-th level is an index contour (0: none).")
@click.option("--smooth", "smoothing", type=click.Choice(["none", "bspline", "tension"]), default="none",
              show_default=True, help="Fit the traced lines: an approximating cubic B-spline, or a spline under "
                                      "tension through the vertices; lines that would cross keep their traced form.")
@click.option("--tolerance-px", type=positive(), default=0.5, show_default=True,
              help="B-spline: RMS distance (cells) the fitted line may keep from the traced one.")
@click.option("--tension", type=at_least(0), default=1.0, show_default=True,
              help="Tension spline: 0 is a cubic spline, larger values tend to the traced polyline.")
@click.option("--png/--no-png", default=True, show_default=True, help="A preview PNG beside OUT (over the hillshade).")
def contours(*, dem_path, out_path, interval_m, index_every, smoothing, tolerance_px, tension, png):
    """Contour lines of DEM_PATH (GeoTIFF) into OUT_PATH (.gpkg or .geojson, layer 'contours': elevation in the
    DEM's unit, elevation_m, index, closed), traced on the cell centres and cut at nodata. An interval that
    would put adjacent levels less than a cell apart on average is refused (exit 2)."""
    from lidarctl.terrain.contours import contours_from_file

    s = contours_from_file(dem_path, out_path, interval_m=interval_m, index_every=index_every, smoothing=smoothing,
                           tolerance_px=tolerance_px, tension=tension, png=png)
    # + 0.0: a level of -0.0 (a multiple of the interval reached from below) is written 0, not -0
    span = f" from {s.lowest_level + 0.0:g} to {s.highest_level + 0.0:g} {s.unit}" if s.levels else ""
    click.echo(f"{out_path}: {s.contours} contours on {s.levels} levels every {s.interval:g} {s.unit} "
               f"(the DEM's height unit){span} ({s.closed} closed, "
               f"{s.index_contours} index), smoothing {s.smoothing} ({s.fell_back_to_traced} kept traced "
               f"to avoid crossings), {s.crossings} crossings")


@main.command()
@click.argument("dem_path", type=click.Path(dir_okay=False))
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--min-area-m2", type=positive(), default=None,
              help="Stream threshold: the upstream area (m2, also for DEMs in feet) from which a cell is a stream. "
                   "Default: from the DEM, 2 x the longer side of its valid data in cells x the cell area (more than "
                   "a sheet of flow down a plane collects: converging flow); the value used is printed.")
@click.option("--fill/--breach", "fill", default=True, show_default=True,
              help="Depressions: priority-flood fill with a float64 epsilon gradient, or breaching (the outflow path "
                   "carved down to the pit).")
@click.option("--simplify-px", type=at_least(0), default=0.5, show_default=True,
              help="Douglas-Peucker tolerance of the stream lines in cells (0: the D8 path through the cell centres).")
@click.option("--png/--no-png", default=True, show_default=True, help="drainage.png: streams over the hillshade.")
def drainage(dem_path, outdir, min_area_m2, fill, simplify_px, png):
    """Drainage network of DEM_PATH (GeoTIFF) into OUTDIR (replaced as a whole; all files or none):
    conditioned.tif, flowdir.tif (D8, ESRI codes 1 E 2 SE 4 S 8 SW 16 W 32 NW 64 N 128 NE), accum_cells.tif,
    accum_m2.tif, strahler.tif (COGs in the DEM's CRS, nodata kept), drainage.gpkg (layers streams with
    strahler_order, length_m, upstream_area_m2; watersheds per segment; basins per outlet), drainage.png and
    drainage.json. Global: the whole DEM is held in memory, about 100 bytes per cell at the peak (1 GB for
    10 M cells).
    """
    from lidarctl.terrain.drainage import drainage as run

    r = run(dem_path, outdir, min_area_m2, "fill" if fill else "breach", simplify_px, png)
    click.echo(f"{r.outdir}: {r.valid_cells:,} of {r.cells:,} cells; {r.method}: {r.cells_changed:,} cells changed "
               f"(raised up to {r.raised_max_m:.3f} m, cut up to {r.lowered_max_m:.3f} m); stream threshold "
               f"{r.min_area_m2:,.1f} m2 ({r.min_area_rule}); {r.segments} stream segments up to Strahler order "
               f"{r.max_order}, {r.basins} basins")
    if r.no_streams:
        click.echo(r.no_streams)


@main.command(outputs=lambda params: params["paths"][-1:])  # OUT: the last argument
@click.argument("paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--image", type=click.Path(dir_okay=False), default=None,
              help="Orthophoto (GeoTIFF): OUT.png shows the layers over it.")
@click.option("--dem", type=click.Path(dir_okay=False), default=None,
              help="DEM GeoTIFF: its contours (--contour-interval-m) become the 'contours' layer.")
@click.option("--contours", "contours_path", type=click.Path(dir_okay=False), default=None,
              help="Contour layer (.gpkg/.geojson, lidarctl contours) copied into OUT as 'contours'.")
@click_option(MapVectorSettings, "contour_interval_m", "--contour-interval-m")
@click_option(MapVectorSettings, "cell_m", "--cell-m")
@click_option(MapVectorSettings, "min_area_m2", "--min-area-m2")
@click_option(MapVectorSettings, "simplify_m", "--simplify-m")
@click_option(MapVectorSettings, "spot_spacing_m", "--spot-spacing-m")
@click.option("--crs", default=None, help="CRS (EPSG:code) when the files have none; never guessed.")
def vectors(paths, image, dem, contours_path, crs, **_settings):
    """Line-map (DLG) layers of the classified clouds PATHS... into OUT (the last argument, .gpkg): buildings
    (regularised outlines, eave/ridge heights, area), roads (polygons of class 11) and road_centrelines
    (width), water (class 9), spot_heights, and contours (--contours or --dem)."""
    from aerotri.core.errors import OptionError
    from lidarctl.vectors.layers import vectors_to_file

    if len(paths) < 2:
        raise OptionError("give the classified cloud(s) and then OUT.gpkg", param="PATHS")
    *clouds, out_path = paths
    if dem and contours_path:
        raise OptionError("give --dem or --contours, not both", param="--contours")
    params = resolve(MapVectorSettings, None, click.get_current_context()).settings
    s = vectors_to_file(clouds, out_path, params=params, crs=crs, dem=dem, contours=contours_path, image=image)
    c = s.counts
    counts = ", ".join(f"{k} {getattr(c, k)}" for k in ("buildings", "roads", "road_centrelines", "water",
                                                        "spot_heights", "contours") if getattr(c, k) is not None)
    click.echo(f"{out_path}: {counts} ({s.units.xy_name})")
    if c.road_points == 0:
        # the chain's classification has no orthophoto yet: a user expecting roads from --image got 0 unexplained
        click.echo("roads: the clouds hold no road returns (class 11); roads come from a classification fused with "
                   "an orthophoto (lidarctl classify ... --image DOM.tif); --image here only draws OUT.png")


@main.command("check-vectors")
@click.argument("product_path", type=click.Path(dir_okay=False))
@click.option("--reference", "reference_path", type=click.Path(dir_okay=False), required=True,
              help="Reference vectors (.gpkg) with layers of the same names (buildings, roads, ...).")
@click_option(VectorCheckSettings, "layers", "--layer", multiple=True, show_default=False,
              help="Check only this layer (repeatable) [every shared layer].")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None, help="Write the numbers as JSON.")
@click.option("--png", "png_path", type=click.Path(dir_okay=False), default=None,
              help="Plot of the building outlines and corner offset vectors.")
@click_option(VectorCheckSettings, "match_m", "--match-m")
@click_option(VectorCheckSettings, "buffer_m", "--buffer-m")
@click_option(VectorCheckSettings, "scale", "--scale")
@click_option(VectorCheckSettings, "terrain", "--terrain")
@click_option(VectorCheckSettings, "within", "--within")
def check_vectors(product_path, reference_path, json_path, png_path, **_settings):
    """Line-map accuracy of PRODUCT_PATH (lidarctl vectors) against --reference: plan RMS of the building corners
    (to the nearest reference outline and to the matched reference corner), completeness and correctness of
    each layer by area (polygons) or buffer (lines), with the map scale's tolerance for well-defined features.
    A reference that maps only part of the area (--within hull, or a polygon file) is said when many produced
    features lie outside it."""
    from lidarctl.checks import vectors as vc

    params = resolve(VectorCheckSettings, None, click.get_current_context()).settings
    result = vc.check_files(product_path, reference_path, params, json_path, png_path)
    click.echo(vc.format_report(result))
