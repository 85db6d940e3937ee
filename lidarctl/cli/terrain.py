"""``lidarctl smooth``, ``hydro-flatten``, ``contours`` and ``drainage``: products of a DEM."""

from __future__ import annotations

import click

from aerotri.core.commands import Command, FiniteFloatRange, at_least, positive
from aerotri.core.log import counted
from aerotri.core.settings import click_option, resolve
from lidarctl.terrain.hydro import HydroSettings


@click.command(cls=Command)
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
    click.echo(f"{r.path}: {r.valid_cells:,} of {r.cells:,} cells smoothed ({counted(r.windows, 'window')}); "
               f"changes RMS {r.rms_change_m:.3f} m, max {r.max_change_m:.3f} m")


@click.command("hydro-flatten", cls=Command)
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


@click.command(cls=Command)
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
@click.option("--water", "water_path", type=click.Path(dir_okay=False), default=None,
              help="Water polygons (lidarctl vectors' .gpkg, layer water) the contours are cut at: a map's contours "
                   "stop at the shore, also of a river left unflattened as flowing water.")
@click.option("--water-layer", default=None, help="The layer of --water holding the water polygons [water].")
@click.option("--min-ring-cells", type=at_least(0), default=None,
              help="Closed contours enclosing fewer DEM cells than this are left out: hills and pits the DEM does not "
                   "resolve (a return's noise, a post, a bush); 0 keeps every ring [4].")
def contours(*, dem_path, out_path, interval_m, index_every, smoothing, tolerance_px, tension, png, water_path,
             water_layer, min_ring_cells):
    """Contour lines of DEM_PATH (GeoTIFF) into OUT_PATH (.gpkg or .geojson, layer 'contours': elevation in the
    DEM's unit, elevation_m, index, closed), traced on the cell centres and cut at nodata. An interval that
    would put adjacent levels less than a cell apart on average is refused (exit 2)."""
    from lidarctl.terrain.contours import MIN_RING_CELLS, contours_from_file

    min_ring_cells = MIN_RING_CELLS if min_ring_cells is None else min_ring_cells
    s = contours_from_file(dem_path, out_path, interval_m=interval_m, index_every=index_every, smoothing=smoothing,
                           tolerance_px=tolerance_px, tension=tension, png=png, water_path=water_path,
                           water_layer=water_layer, min_ring_cells=min_ring_cells)
    # + 0.0: a level of -0.0 (a multiple of the interval reached from below) is written 0, not -0
    span = f" from {s.lowest_level + 0.0:g} to {s.highest_level + 0.0:g} {s.unit}" if s.levels else ""
    click.echo(f"{out_path}: {s.contours} contours on {s.levels} levels every {s.interval:g} {s.unit} "
               f"(the DEM's height unit){span} ({s.closed} closed, "
               f"{s.index_contours} index), smoothing {s.smoothing} ({s.fell_back_to_traced} kept traced "
               f"to avoid crossings or a collapse), {s.crossings} crossings"
               + (f"; {s.under_a_tenth_of_a_cell} contours under a tenth of a cell across left out (a level grazing "
                  f"one cell's height)" if s.under_a_tenth_of_a_cell else "")
               + (f"; {s.small_rings} closed contours enclosing fewer than {s.min_ring_cells:g} cells left out "
                  f"(--min-ring-cells)" if s.small_rings else "")
               + (f"; {s.cut_at_water} cut at the water's outlines (--water)" if water_path is not None else ""))


@click.command(cls=Command)
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
@click.option("--water", "water_path", type=click.Path(dir_okay=False), default=None,
              help="Water polygons in the DEM's CRS (lidarctl vectors' map, its layer water): the streams end at their "
                   "shores; their courses through the water (the fill's flat surface) go to a layer through_water.")
@click.option("--water-layer", default=None, help="The layer of --water holding the water polygons [water].")
def drainage(dem_path, outdir, min_area_m2, fill, simplify_px, png, water_path, water_layer):
    """Drainage network of DEM_PATH (GeoTIFF) into OUTDIR (replaced as a whole; all files or none):
    conditioned.tif, flowdir.tif (D8, ESRI codes 1 E 2 SE 4 S 8 SW 16 W 32 NW 64 N 128 NE), accum_cells.tif,
    accum_m2.tif, strahler.tif (COGs in the DEM's CRS, nodata kept), drainage.gpkg (layers streams with
    strahler_order, length_m, upstream_area_m2; watersheds per segment; basins per outlet), drainage.png and
    drainage.json. Global: the whole DEM is held in memory, about 100 bytes per cell at the peak (1 GB for
    10 M cells).
    """
    from lidarctl.terrain.drainage import drainage as run

    r = run(dem_path, outdir, min_area_m2, "fill" if fill else "breach", simplify_px, png, water_path=water_path,
            water_layer=water_layer)
    click.echo(f"{r.outdir}: {r.valid_cells:,} of {r.cells:,} cells; {r.method}: {r.cells_changed:,} cells changed "
               f"(raised up to {r.raised_max_m:.3f} m, cut up to {r.lowered_max_m:.3f} m); stream threshold "
               f"{r.min_area_m2:,.1f} m2 ({r.min_area_rule}); {r.segments} stream segments up to Strahler order "
               f"{r.max_order}, {r.basins} basins"
               + (f"; {r.segments_through_water} segments cut at the water's shores ({r.length_through_water_m:,.0f} m "
                  "through water: layer through_water)" if r.segments_through_water is not None else ""))
    if r.no_streams:
        click.echo(r.no_streams)
