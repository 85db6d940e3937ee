"""``lidarctl check-heights``, ``check-plan`` and ``check-vectors``: products against surveyed points and maps."""

from __future__ import annotations

import click

from aerotri.core.atomic import refuse_input_as_output
from aerotri.core.commands import Command, fraction, positive
from aerotri.core.settings import click_option, resolve
from lidarctl.checks.heights import GROUPINGS, DensityGroups
from lidarctl.checks.plan import PlanCheckSettings
from lidarctl.checks.vectors import VectorCheckSettings

_DENSITY = DensityGroups()


@click.command("check-heights", cls=Command)
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


@click.command("check-plan", cls=Command)
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


@click.command("check-vectors", cls=Command)
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

    resolved = resolve(VectorCheckSettings, None, click.get_current_context())
    result = vc.check_files(product_path, reference_path, resolved.settings, json_path, png_path)
    # the scale nobody gave is said as the default (trial s96 F9: "NOT within tolerance 0.5 m" of a 1:10000 table)
    click.echo(vc.format_report(result, scale_given=resolved.sources.get("scale", "default") != "default"))
