"""``lidarctl vectors``: the map layers of a classified cloud."""

from __future__ import annotations

import click

from aerotri.core.commands import Command
from aerotri.core.settings import click_option, resolve
from lidarctl.vectors.layers import MapVectorSettings


@click.command(cls=Command, outputs=lambda params: params["paths"][-1:])  # OUT: the last argument
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
