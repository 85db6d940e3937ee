"""``aerotri crs``: fit datum/grid parameters and height anomaly surfaces, transform point files."""

from __future__ import annotations

import logging

import time
from pathlib import Path

import click

from aerotri.core.atomic import refuse_input_as_output, write_text_atomic
from aerotri.core.commands import Group, at_least, positive
import numpy as np

from aerotri.geom.crs.definition import crs_label, parse_crs
from aerotri.geom.crs.files import assign_las, fit_common_points, read_height_points, transform_points_file
from aerotri.geom.crs.datum import HEIGHT_MODELS, MODELS, PARAMETER_NAMES, load_height_model, load_transformation
from aerotri.geom.crs.heights import fit_height_anomaly
from aerotri.geom.crs.raster import KINDS, warp_raster
from aerotri.geom.crs.raster_warp import RESAMPLING
from aerotri.core.errors import InputError

log = logging.getLogger(__name__)


@click.group(cls=Group)
def crs():
    """Datums, projections and heights: fit parameters from common points, transform files."""


def format_fit_report(result, path) -> str:
    t = result.transformation
    lines = [f"Transformation {t.model}: {t.from_crs} -> {t.to_crs}  ({len(result.ids)} common points from {path})", ""]
    lines.append(f"{'parameter':<18}{'value':>22}{'std dev':>16}")
    for n in PARAMETER_NAMES[t.model]:
        sd = None if t.std_devs is None else t.std_devs.get(n)
        dec = 4 if "_" in n else 10  # unitless affine coefficients need more digits
        lines.append(f"{n:<18}{t.parameters[n]:>22.{dec}f}{'' if sd is None else f'{sd:16.{dec}f}'}")
    lines += t.convention_lines()
    s0 = "n/a (no redundancy)" if not np.isfinite(result.sigma0_m) else f"{result.sigma0_m:.4f} m"
    lines += ["", f"Sigma0: {s0}   Degrees of freedom: {result.redundancy}", ""]
    v = result.residuals_m
    head = f"{'id':<12}{'dE m':>10}{'dN m':>10}" + (f"{'dU m':>10}" if v.shape[1] == 3 else "") + f"{'r_i':>7}"
    lines.append(head)
    for pid, r, ri in zip(result.ids, v, result.redundancy_numbers):
        lines.append(f"{pid:<12}" + "".join(f"{c:10.4f}" for c in r) + f"{ri:7.2f}")
    rms = result.rms_m
    lines.append(f"{'RMS':<12}{rms.e_m:10.4f}{rms.n_m:10.4f}" + (f"{rms.u_m:10.4f}" if rms.u_m is not None else "")
                 + f"   horizontal {rms.horizontal_m:.4f} m")
    if result.heights is not None:
        lines.append(f"Heights: {result.heights}")
    for w in result.warnings:
        lines.append(f"Warning: {w}")
    return "\n".join(lines)


def _default_output(input_param: str):
    """The output of ``crs fit``/``fit-heights``: -o, else <input>.<model>.json (as the commands make it)."""
    return lambda p: [p["output"] or Path(p[input_param]).with_suffix(f".{p['model']}.json")]


@crs.command("fit", outputs=_default_output("common_points"))
@click.argument("common_points", type=click.Path(dir_okay=False))
@click.option("--model", type=click.Choice(MODELS), required=True, help="transformation model")
@click.option("--from", "from_epsg", required=True,
              help="CRS of the source coordinates (x_from, y_from): EPSG code, WKT, PROJ string, or a .wkt/.prj file")
@click.option("--to", "to_epsg", required=True,
              help="CRS of the target coordinates (x_to, y_to): EPSG code, WKT, PROJ string, or a .wkt/.prj file")
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="parameter file (JSON); default <input>.<model>.json")
def fit_cmd(common_points, model, from_epsg, to_epsg, output):
    """Least-squares transformation parameters from points known in both systems."""
    out = Path(output) if output else Path(common_points).with_suffix(f".{model}.json")
    refuse_input_as_output(out, [common_points], "-o")
    result = fit_common_points(common_points, model, from_epsg, to_epsg)
    write_text_atomic(out, result.to_json())
    click.echo(format_fit_report(result, common_points))
    click.echo(f"Parameters written to {out}")


@crs.command("fit-heights", outputs=_default_output("points"))
@click.argument("points", type=click.Path(dir_okay=False))
@click.option("--model", type=click.Choice(HEIGHT_MODELS), default="plane", show_default=True)
@click.option("--epsg", "epsg", help="EPSG code of the points' x, y (a metre grid; a grid in feet is refused: the model "
              "file holds metres); recorded in the model file. Without it, 'crs transform' evaluates the model on the "
              "output coordinates")
@click.option("--h-crs", "h_crs", help="geographic CRS (datum) of the points' ellipsoidal heights h, e.g. EPSG:4326 for "
              "GNSS heights on WGS 84, EPSG:4490 on CGCS2000; recorded in the model file, which is then applied on h "
              "of that datum; required with --epsg (a levelling table's grid often differs from its heights' datum)")
@click.option("--smoothing", type=at_least(0.0), default=0.0, show_default=True,
              help="tps smoothing, >= 0 (0 interpolates)")
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="model file (JSON); default <input>.<model>.json")
def fit_heights_cmd(points, model, epsg, h_crs, smoothing, output):
    """Height anomaly surface zeta = h - H from points with ellipsoidal and normal heights."""
    out = Path(output) if output else Path(points).with_suffix(f".{model}.json")
    refuse_input_as_output(out, [points], "-o")
    h_geo = _h_crs(h_crs, epsg)
    ids, x, y, h, H = read_height_points(points, epsg)
    # an EPSG code as its label, any other CRS (a site grid's PROJ string or .wkt) as its WKT: a label is no CRS the
    # model's readers can parse (trial-site: "unknown CRS 'Transverse Mercator (...)'" at crs transform / warp)
    grid = parse_crs(epsg, "--epsg") if epsg else None
    label = None if grid is None else (crs_label(grid) if crs_label(grid).startswith("EPSG:") else grid.to_wkt())
    h_label = None if h_geo is None else (crs_label(h_geo) if crs_label(h_geo).startswith("EPSG:") else h_geo.to_wkt())
    try:
        res = fit_height_anomaly(ids, x, y, h, H, model=model, smoothing=smoothing, crs=label, h_crs=h_label)
    except InputError as exc:
        raise InputError(f"{points}: {exc}") from None
    write_text_atomic(out, res.to_json())
    click.echo(_height_fit_table(model, points, ids, res))
    if h_geo is not None:
        click.echo(f"h taken as ellipsoidal heights on {h_geo.datum.name} ({crs_label(h_geo)}): the model is "
                   "applied on h of that datum")
    else:
        click.echo("the datum of h is not recorded (no --h-crs): the model is applied on the h a "
                   "transformation ends with (docs/datums.md)")
    click.echo(f"Model written to {out}")


def _h_crs(h_crs, epsg):
    """The geographic CRS of the levelling points' h: --h-crs; None without it and --epsg (nothing recorded).

    Never taken from --epsg: GNSS levelling tables give x, y in the local grid (Xian 1980) and h on the GNSS
    datum (WGS 84 / CGCS2000), and a model taken on the grid's ellipsoid is about 119 m off near Yichang."""
    if h_crs is None and epsg is None:
        return None
    if h_crs is None:
        raise InputError(f"--h-crs is required with --epsg {epsg}: the geographic CRS of the points' ellipsoidal "
                         "heights h (e.g. EPSG:4326 for GNSS heights on WGS 84, EPSG:4490 on CGCS2000, the grid's "
                         "own datum such as EPSG:4610 for Xian 1980 only when h were computed on its ellipsoid)")
    c = parse_crs(h_crs, "--h-crs")
    if c.is_geocentric:
        return c
    if c.geodetic_crs is None:
        raise InputError(f"--h-crs {crs_label(c)}: not a CRS with a geodetic datum (expected e.g. EPSG:4326)")
    return c.geodetic_crs


def _height_fit_table(model, points, ids, res) -> str:
    lines = [f"Height anomaly model {model} from {len(ids)} points ({points}); H = h - zeta; residuals are the "
             "model's zeta minus the point's (loo: the model of the other points)",
             f"{'id':<12}{'zeta m':>10}{'resid m':>10}{'loo m':>10}"]
    lines += [f"{pid:<12}{z:10.4f}{r:10.4f}" + (f"{lr:10.4f}" if np.isfinite(lr) else f"{'-':>10}")
              for pid, z, r, lr in zip(ids, res.zeta_m, res.residuals_m, res.loo_residuals_m)]
    loo = res.loo_rms_m
    lines.append(f"RMS {res.rms_m:.4f} m   leave-one-out RMS "
                 + (f"{loo:.4f} m" if np.isfinite(loo) else "not available (no point can be left out)"))
    lines += [f"Warning: {w}" for w in res.warnings]
    return "\n".join(lines)


@crs.command("warp")
@click.argument("input_path", metavar="IN", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("output_path", metavar="OUT", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--to", "to_epsg", required=True, help="target CRS (EPSG code, WKT, PROJ string, or a .wkt/.prj file)")
@click.option("--from", "from_epsg", help="CRS of IN when its own is wrong or missing [the raster's CRS]")
@click.option("--params", type=click.Path(dir_okay=False), help="parameter file from 'crs fit' (a datum change)")
@click.option("--heights", type=click.Path(dir_okay=False), help="height anomaly model from 'crs fit-heights' "
                                                                 "(ellipsoidal -> normal heights)")
@click.option("--allow-ballpark", is_flag=True, help="accept PROJ's ballpark operation that ignores a datum shift")
@click.option("--res-m", type=positive(),
              help="target cell size (m) of a projected target, also for grids in feet (0.3048 m: 1 ft cells) "
                   "[the source cell size]")
@click.option("--res-deg", type=positive(), help="target cell size (degrees) of a geographic target")
@click.option("--kind", type=click.Choice(KINDS), default="auto", show_default=True,
              help="height: cell values are heights and change with the datum (DEM, DSM); image: an orthophoto; "
                   "auto: one floating-point band is a height raster")
@click.option("--resampling", type=click.Choice(list(RESAMPLING)), default="bilinear", show_default=True)
def warp_cmd(*, input_path, output_path, to_epsg, from_epsg, params, heights, allow_ballpark, res_m, res_deg, kind,
             resampling):
    """Reproject a GeoTIFF (DEM, DSM, DOM) across datums and projections into a COG, nodata kept."""
    t0 = time.perf_counter()
    r = warp_raster(input_path, output_path, to_epsg, from_crs=from_epsg,
                    params=load_transformation(params) if params else None,
                    heights=load_height_model(heights) if heights else None, allow_ballpark=allow_ballpark,
                    res_m=res_m, res_deg=res_deg, kind=kind, resampling=resampling)
    click.echo(f"{r.width} x {r.height} cells of {r.res:g} {_grid_unit(output_path)} in {r.crs} ({r.kind} raster, "
               f"{100 * r.valid_fraction:.1f} % valid) {r.operation['description']}: {output_path} "
               f"({time.perf_counter() - t0:.1f} s)")


def _grid_unit(path) -> str:
    """The unit of the cells of the raster written at ``path``, by its CRS, for the summary line ("cells of 1 in
    EPSG:3740" named none)."""
    import math

    import pyproj
    import rasterio

    from aerotri.geom.crs.definition import length_unit_name, linear_unit_m

    with rasterio.open(path) as ds:
        unit_m = linear_unit_m(pyproj.CRS.from_wkt(ds.crs.to_wkt()))
    return "deg" if math.isnan(unit_m) else length_unit_name(unit_m)


@crs.command("transform")
@click.argument("input_path", metavar="IN", type=click.Path(dir_okay=False))
@click.argument("output_path", metavar="OUT", type=click.Path(dir_okay=False))
@click.option("--from", "from_epsg", help="CRS of IN (EPSG code, WKT, PROJ string, or a .wkt/.prj file; LAS/LAZ: "
              "default the file's CRS record)")
@click.option("--to", "to_epsg", required=True, help="CRS of OUT (EPSG code, WKT, PROJ string, or a .wkt/.prj file)")
@click.option("--params", type=click.Path(dir_okay=False), help="parameter file from 'crs fit'")
@click.option("--heights", type=click.Path(dir_okay=False), help="height anomaly model from 'crs fit-heights': "
              "ellipsoidal heights h in IN become normal heights H = h - zeta in OUT (the other way with "
              "--normal-to-ellipsoidal)")
@click.option("--normal-to-ellipsoidal", is_flag=True,
              help="IN's heights are normal heights H (levelled, above the quasigeoid): OUT gets ellipsoidal heights "
                   "h = H + zeta of the --heights model (required), on the datum the model records, carried on to "
                   "OUT's")
@click.option("--allow-ballpark", is_flag=True, help="accept PROJ's ballpark operation that ignores a datum shift")
@click.option("--chunk-points", "chunk_size", type=at_least(1, int), default=1_000_000, show_default=True,
              help="LAS/LAZ points per chunk")
def transform_cmd(*, input_path, output_path, from_epsg, to_epsg, params, heights, normal_to_ellipsoidal,
                  allow_ballpark, chunk_size):
    """Transform a CSV/TXT point list or a LAS/LAZ file (chunked, all point dimensions kept)."""
    t0 = time.perf_counter()
    n, t = transform_points_file(input_path, output_path, from_crs=from_epsg, to_crs=to_epsg, params=params,
                                 heights=heights, allow_ballpark=allow_ballpark, chunk_size=chunk_size,
                                 normal_to_ellipsoidal=normal_to_ellipsoidal)
    dt = time.perf_counter() - t0
    for w in t.warnings:
        log.warning(w)
    click.echo(f"{n} points {t.description}: {output_path} ({dt:.2f} s)")


@crs.command("assign")
@click.argument("input_path", metavar="IN", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("output_path", metavar="OUT", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--crs", "crs_text", required=True, help="the CRS IN's coordinates are in (EPSG code, WKT or PROJ string)")
@click.option("--chunk-points", "chunk_size", type=at_least(1, int), default=1_000_000, show_default=True,
              help="LAS/LAZ points per chunk")
def assign_cmd(*, input_path, output_path, crs_text, chunk_size):
    """Re-tag a LAS/LAZ file whose CRS record is wrong or missing: OUT is IN with the CRS record of --crs, no point
    moved (as PDAL's override_srs, gdal_edit -a_srs). Refused when IN's header bounds cannot be --crs coordinates
    (degrees out of range, another Gauss-Krueger zone, beyond the projection, or more than 10 degrees from its area of
    use); a warning when they lie outside its area of use by less. To move the points into another CRS use 'crs
    transform'."""
    t0 = time.perf_counter()
    r = assign_las(input_path, output_path, crs_text, chunk_size=chunk_size)
    for w in r.warnings:
        log.warning(w)
    click.echo(f"{r.n_points} points re-tagged {r.old or 'no CRS record'} -> {r.new}, coordinates unchanged: "
               f"{output_path} ({time.perf_counter() - t0:.2f} s)")
