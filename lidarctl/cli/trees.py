"""``lidarctl trees``: tree-height model, forest stands and tree tops of a classified cloud (seed 004)."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.settings import click_option
from lidarctl.rasters.trees import TreeSettings


@click.command(cls=Command, name="trees")
@click.argument("classified", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
@click_option(TreeSettings, "res_m", "--res-m")
@click_option(TreeSettings, "max_edge_m", "--max-edge-m")
@click_option(TreeSettings, "min_height_m", "--min-height-m")
@click_option(TreeSettings, "min_stand_area_m2", "--min-stand-area-m2")
@click_option(TreeSettings, "top_radius_m", "--top-radius-m")
@click_option(TreeSettings, "top_radius_per_m", "--top-radius-per-m")
@click_option(TreeSettings, "smooth_px", "--smooth-px")
@click_option(TreeSettings, "veg_classes", "--classes", metavar="C1,C2,...")
@click_option(TreeSettings, "pit_free", "--pit-free/--no-pit-free")
@click.option("--crs", default=None, help="CRS (EPSG:code) of files without one, or with an unreadable one.")
def trees(*, classified, outdir, res_m, max_edge_m, min_height_m, min_stand_area_m2, top_radius_m, top_radius_per_m,
          smooth_px, veg_classes, pit_free, crs):
    """Tree heights of CLASSIFIED LAS/LAZ file(s) (one or more strips in one CRS) into OUTDIR.

    Writes chm.tif (canopy height model, COG, heights in the CRS's vertical unit, NODATA where no trees: a
    TIN of the vegetation first returns above the ground DEM with an edge-length limit), trees.gpkg (layer
    stands: connected canopy of at least --min-stand-area-m2 with area and mean, p50, p90, p95, max height in
    metres; layer tree_tops: local maxima within a window of radius --top-radius-m + --top-radius-per-m x
    height, with their heights), trees.png (preview with a colour key) and trees.json (summary). The four
    files appear together or not at all. Lengths in metres, also for clouds in feet.
    """
    from lidarctl.rasters.trees import trees_from_files

    settings = TreeSettings(res_m=res_m, max_edge_m=max_edge_m, min_height_m=min_height_m,
                            min_stand_area_m2=min_stand_area_m2, top_radius_m=top_radius_m,
                            top_radius_per_m=top_radius_per_m, smooth_px=smooth_px, veg_classes=tuple(veg_classes),
                            pit_free=pit_free)
    r = trees_from_files(classified, outdir, settings, crs=crs)
    fh = r.forest_heights
    heights = (f"heights mean {fh.mean_height_m:.1f} m, p95 {fh.p95_height_m:.1f} m, max {fh.max_height_m:.1f} m"
               if fh else "no stand")
    click.echo(f"{outdir}: {r.stands} stands, forest {r.forest_area_m2 / 1e4:.3f} ha of "
               f"{r.canopy_area_m2 / 1e4:.3f} ha canopy; {heights}; {r.tree_tops} tree tops")

