"""``lidarctl corners``: roof corners of a classified cloud as LiDAR ground control candidates."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.errors import InputError
from aerotri.core.settings import click_option, resolve
from lidarctl.corners.roof_corners import CornerSettings, corner_control


@click.command(cls=Command, name="corners")
@click.argument("classified", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
@click_option(CornerSettings, "min_edge_m", "--min-edge-m")
@click_option(CornerSettings, "roof", "--roof")
@click_option(CornerSettings, "sigma_strip_xy_m", "--sigma-strip-xy-m")
@click_option(CornerSettings, "sigma_strip_z_m", "--sigma-strip-z-m")
@click.option("--crs", default=None, help="CRS (EPSG:code) of files without one, or with an unreadable one.")
@click_option(CornerSettings, "figure", "--figure/--no-figure")
@click_option(CornerSettings, "tile_m", "--tile-m")
@click_option(CornerSettings, "buffer_m", "--buffer-m")
def corners(*, classified, outdir, min_edge_m, roof, sigma_strip_xy_m, sigma_strip_z_m, crs, figure, tile_m, buffer_m):
    """Roof corners of CLASSIFIED LAS/LAZ file(s) (one or more strips in one CRS, building class 6)
    into OUTDIR.

    Writes corners.csv (id,x,y,z,sx_m,sy_m,sz_m,roof,building_id,edge1_deg,edge2_deg,angle_deg,
    support_pts,score,usable; x, y, z in the files' CRS and units, sigmas in metres),
    corners.geojson (corners and regularised roof outlines), roof_planes.geojson (one polygon per
    roof face, shrunk 1 m or 2 point spacings inside its edges, with its plane z = a (x - x0) +
    b (y - y0) + c and the plane's covariance: surface control for aerotri adjust --planes),
    roof_outlines.gpkg (the roof outlines for QGIS, and building footprints for ortho rectify
    --true-ortho --footprints where no cadastre is at hand) and corners.json (summary, with the
    units). Every length option is in metres, also for clouds in feet. When no corner is usable as
    control it stops with exit code 2 and writes nothing. The files are read by tiles (--tile-m with a
    --buffer-m border larger than the largest roof), never merged: memory is set by the tile size.
    """
    settings = resolve(CornerSettings, None, click.get_current_context())  # the options, with their sources
    res = corner_control(classified, outdir, settings, crs=crs)
    if res.no_usable:
        hint = "try --roof any or a smaller --min-edge-m" if roof == "flat" else "try a smaller --min-edge-m"
        raise InputError(f"{res.no_usable}; {hint}")
    st = res.stats
    click.echo(
        f"{st.n_corners} corners ({st.n_usable} usable) on {st.n_outlines} roofs "
        f"({100 * st.outlined_share:.0f} % of the building points on an outlined roof), "
        f"point spacing {st.point_spacing_m:.2f} m, edges >= {st.min_edge_m:.2f} m; "
        f"{res.units_text} -> {outdir / 'corners.csv'}"
    )
