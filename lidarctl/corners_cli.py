"""``lidarctl corners``: roof corners of a classified cloud as LiDAR ground control candidates."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from aerotri.core.atomic import refuse_input_as_output
from aerotri.core.commands import Command
from aerotri.core.errors import InputError
from lidarctl.corners import (
    find_roof_corners,
    plot_corners,
    read_strips,
    simple_ndsm,
    to_crs_units,
    write_corner_files,
)


@click.command(cls=Command, name="corners")
@click.argument("classified", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--min-edge-m", default=5.0, show_default=True, type=click.FloatRange(min=0.5),
              help="Report corners whose two edges are at least this long (m).")
@click.option("--roof", type=click.Choice(["flat", "any"]), default="flat", show_default=True,
              help="Roofs whose corners may be marked usable as control.")
@click.option("--sigma-strip-xy-m", default=0.03, show_default=True, type=click.FloatRange(min=0.0),
              help="Horizontal georeferencing error of a strip, added to every corner's sx_m, sy_m (m).")
@click.option("--sigma-strip-z-m", default=0.03, show_default=True, type=click.FloatRange(min=0.0),
              help="Vertical georeferencing error of a strip, added to every corner's sz_m (m).")
@click.option("--crs", default=None, help="CRS (EPSG:code) of files that have none; never guessed.")
@click.option("--figure/--no-figure", default=True, show_default=True,
              help="Also write corners.png (outlines and corners over the nDSM).")
def corners(classified, outdir, min_edge_m, roof, sigma_strip_xy_m, sigma_strip_z_m, crs, figure):
    """Roof corners of CLASSIFIED LAS/LAZ file(s) (one or more strips in one CRS, building class 6)
    into OUTDIR.

    Writes corners.csv (id,x,y,z,sx_m,sy_m,sz_m,roof,building_id,edge1_deg,edge2_deg,angle_deg,
    support_pts,score,usable; x, y, z in the files' CRS and units, sigmas in metres),
    corners.geojson (corners and regularised roof outlines) and corners.json (summary, with the
    units). Every length option is in metres, also for clouds in feet. Nothing is written when no
    usable corner is found.
    """
    for name in ("corners.csv", "corners.geojson", "corners.json", "corners.png"):
        refuse_input_as_output(Path(outdir) / name, classified, "OUTDIR")
    cat = read_strips(classified, crs=crs)
    units = cat["units"]
    names = ", ".join(str(p) for p in classified)
    try:
        result = find_roof_corners(cat["x"], cat["y"], cat["z"], cat["classification"], cat["point_source_id"],
                                   min_edge_m=min_edge_m, roof=roof, sigma_strip_xy_m=sigma_strip_xy_m,
                                   sigma_strip_z_m=sigma_strip_z_m, progress=True)
    except InputError as exc:
        raise type(exc)(f"{names}: {exc}", param=exc.param) from None
    st = result["stats"]
    if st["n_usable"] == 0:
        raise InputError(
            f"{names}: no usable roof corner ({st['n_corners']} corners on {st['n_outlines']} roof outlines, none "
            f"with score >= {st['usable_score']} and edges >= {min_edge_m} m"
            f"{' on a flat roof' if roof == 'flat' else ''}); "
            "try --roof any or a smaller --min-edge-m"
        )
    if figure:
        # Before any file is written: the figure's grid is checked against the machine's memory.
        xyz = np.column_stack([cat["x"], cat["y"], cat["z"]])
        try:
            ndsm, extent_m = simple_ndsm(xyz, cat["classification"], cell_m=max(0.5, st["point_spacing_m"]))
        except InputError as exc:
            raise type(exc)(f"{names}: {exc}", param=exc.param) from None
    out = to_crs_units(result, units)
    paths = write_corner_files(outdir, out, crs=cat["crs"], source=names, inputs=classified)
    if figure:
        extent = tuple(float(units.xy_from_m(v)) for v in extent_m)
        plot_corners(Path(outdir) / "corners.png", ndsm, extent, out["outlines"], out["corners"],
                     title=f"roof corners: {st['n_usable']} usable of {st['n_corners']}", xy_unit=units.xy_name)
    click.echo(
        f"{st['n_corners']} corners ({st['n_usable']} usable) on {st['n_outlines']} roofs, "
        f"point spacing {st['point_spacing_m']:.2f} m; coordinates in {units.describe()} -> {paths['csv']}"
    )
