"""``lidarctl classify``: noise, ground, buildings, vegetation and water as ASPRS classes."""

from __future__ import annotations

import click

from aerotri.core.commands import Command, positive, scheduler_options
from aerotri.core.settings import click_option
from lidarctl.classify.pipeline import ClassifySettings


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


@click.command(cls=Command)
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
