"""Hydro-flattening: each standing water body of a DEM at one level (USGS Lidar Base Specification, whose DEMs
are hydro-flattened: a lake flat and level, its surface at or below the terrain immediately around it).

A DEM from the ground and water returns is neither: a lake returns few pulses (water mirrors them away), so its
cells are means of scattered returns and, between them, the TIN from the shores; lidR Topography's western lake
spans 2 m in lidarctl rasters' dem.tif, and 1 m contours cross it.

Method, per polygon of the water layer (``lidarctl vectors``' ``water``: ``water_z``, the median height of its
water returns, and ``water_z_range_m``, their 5th to 95th percentile range):

* its shore: the DEM cells within ``shore_cells`` cells outside it that lie in no water polygon;
* its level: the lower of ``water_z`` and the shore's 5th percentile (the water lies at or below the terrain
  around it; a few low shore cells, a ditch or an outlet, do not pull the lake down); a polygon without
  ``water_z`` (hand-digitised) takes the shore's alone;
* a polygon without ``water_z_range_m`` (hand-digitised) is judged by its shore instead: the low heights of the
  shore's thirds along the body's long axis differing by more than ``max_range_m`` are flowing water (``shore_fall``);
* every DEM cell whose centre lies inside it takes the level; nothing else changes.

A body whose water returns span more than ``max_range_m`` is flowing water (a river falling along its course): one
level would dam it, so it is left as it is and listed; a river is flattened bank to bank along its course from 3D
breaklines, which this command does not make. Heights are in the DEM's unit; ``max_range_m`` in metres.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.core.settings import setting

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


@dataclasses.dataclass(frozen=True)
class HydroSettings:
    """``lidarctl hydro-flatten``: which water bodies are flattened and how their level is found."""

    max_range_m: float = setting(0.5, min=0.0, min_open=True,
                                 help="A body whose water returns span more than this (5th to 95th percentile, m) "
                                      "is flowing water and is left as it is.")
    shore_cells: int = setting(2, min=1, help="Width of the shore ring around a body (cells).")
    shore_percentile: float = setting(5.0, min=0.0, max=50.0,
                                      help="The level is at most this percentile of the shore's heights.")


@dataclasses.dataclass(frozen=True)
class WaterBody:
    """One polygon of the water layer and what became of it (heights in the DEM's unit; ``level`` None: left)."""

    index: int
    area_m2: float
    water_z: float | None
    range_m: float | None
    shore_level: float | None
    level: float | None
    cells: int
    reason: str = ""
    empty_cells: int = 0   # cells inside it without data (outside the survey), left empty


@dataclasses.dataclass(frozen=True)
class HydroResult:
    path: Path
    bodies: tuple[WaterBody, ...]
    height_unit: str = "m"   # of the DEM's heights (levels, water_z)

    @property
    def flattened(self) -> tuple[WaterBody, ...]:
        return tuple(b for b in self.bodies if b.level is not None)

    @property
    def left(self) -> tuple[WaterBody, ...]:
        return tuple(b for b in self.bodies if b.level is None)


def read_water(path, dem_crs, water_layer: str | None = None):
    """Polygons, water_z and water_z_range_m (None where the file has no such field) of a water layer
    (the layer ``water`` of a GeoPackage, else its only layer); CrsError when its CRS is not the DEM's
    (``dem_crs``: pyproj)."""
    import pyogrio
    import shapely
    from pyogrio.errors import DataLayerError, DataSourceError
    from pyogrio.raw import read

    from aerotri.geom.crs.definition import crs_label, same_horizontal

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file; expected the water polygons (lidarctl vectors' .gpkg, layer water)")
    try:
        names = [str(n) for n, _ in pyogrio.list_layers(path)]
        layer = water_layer or ("water" if "water" in names else (names[0] if len(names) == 1 else None))
        if layer is None or layer not in names:
            raise InputError(f"{path}: no layer {layer or 'water'!r} (layers: {', '.join(names)}); expected lidarctl "
                             "vectors' map or a file of water polygons (--water-layer names its layer)")
        meta, _, wkb, fields = read(path, layer=layer)
        # a file's only layer is taken for water when it says so (its name or a water_z field) or when named: the
        # building footprints given by mistake were "138 of 160 water bodies flattened"
        if layer != "water" and water_layer is None and "water_z" not in meta["fields"]:
            raise InputError(f"{path}: its layer {layer!r} is not named water and has no water_z field; if it holds "
                             f"water polygons, say so: --water-layer {layer}")
    except (DataSourceError, DataLayerError, OSError) as exc:
        raise InputError(f"{path}: not a readable vector file ({exc})") from None
    import pyproj

    crs = pyproj.CRS.from_user_input(meta["crs"]) if meta.get("crs") else None
    if crs is None:
        raise InputError(f"{path}: no CRS; expected water polygons in the DEM's CRS ({crs_label(dem_crs)}), in a "
                         "format that records it (GeoPackage, GeoJSON, a shapefile with its .prj)")
    if not same_horizontal(crs, dem_crs):
        raise CrsError(f"{path} is in {crs_label(crs)} but the DEM in {crs_label(dem_crs)}; give both in one CRS "
                       "(aerotri crs transform)")
    cols = dict(zip(meta["fields"], fields))
    geoms = [shapely.from_wkb(b) if b is not None else None for b in wkb]
    keep = [i for i, g in enumerate(geoms) if g is not None and not g.is_empty and "Polygon" in g.geom_type]
    if not keep:
        raise InputError(f"{path}: layer {layer!r} holds no polygons; expected water polygons")

    def column(name):
        if name not in cols:
            return [None] * len(keep)
        v = np.asarray(cols[name], dtype=float)
        return [None if not np.isfinite(v[i]) else float(v[i]) for i in keep]

    return [geoms[i] for i in keep], column("water_z"), column("water_z_range_m")


def shore_ring(z: np.ndarray, body: np.ndarray, other_water: np.ndarray, params: HydroSettings) -> np.ndarray:
    """The body's shore cells with data: within ``shore_cells`` of it, in no water polygon."""
    from scipy import ndimage

    return ndimage.binary_dilation(body, iterations=params.shore_cells) & ~body & ~other_water & np.isfinite(z)


def shore_fall(z: np.ndarray, body: np.ndarray, ring: np.ndarray, percentile: float) -> float | None:
    """How far the shore's low heights (``percentile`` of each third of the shore along the body's long axis) differ,
    in the DEM's unit: a lake's water line lies at one level all round, a river's falls along its course. None
    for a body too small to tell (fewer than 3 shore cells a third)."""
    br, bc = np.nonzero(body)
    rr, cc = np.nonzero(ring)
    if len(br) < 3 or len(rr) < 9:
        return None
    _, vectors = np.linalg.eigh(np.cov(np.vstack([bc, br]).astype(float)))
    along = (cc - bc.mean()) * vectors[0, -1] + (rr - br.mean()) * vectors[1, -1]
    a, b = np.linspace(along.min(), along.max(), 4)[1:3]
    heights = z[rr, cc]
    lows = [float(np.percentile(heights[m], percentile)) for m in (along <= a, (along > a) & (along <= b), along > b)
            if m.sum() >= 3]
    return max(lows) - min(lows) if len(lows) >= 2 else None


def flatten_window(z: np.ndarray, body: np.ndarray, ring: np.ndarray, water_z: float | None,
                   params: HydroSettings) -> tuple[float | None, float | None]:
    """(shore level, level) of one body on a window of DEM heights ``z`` (NaN: nodata): ``body`` its cells, ``ring``
    its shore (``shore_ring``); the body's valid cells of ``z`` are set to the level in place."""
    shore = float(np.percentile(z[ring], params.shore_percentile)) if ring.any() else None
    candidates = [v for v in (water_z, shore) if v is not None]
    if not candidates:
        return shore, None
    level = min(candidates)
    cells = body & np.isfinite(z)
    z[cells] = level
    return shore, level


def hydro_flatten(dem_path, water_path, out_path, params: HydroSettings = HydroSettings(),
                  water_layer: str | None = None) -> HydroResult:
    """Hydro-flatten the DEM GeoTIFF ``dem_path`` with the water polygons of ``water_path`` into ``out_path`` (a
    float32 COG; CRS, nodata, band unit and tags kept; atomic). Memory: one body's window at a time."""
    import pyproj
    import rasterio
    import shapely
    from rasterio import features
    from rasterio.shutil import copy as rio_copy
    from rasterio.windows import Window, bounds, from_bounds

    from aerotri.core.atomic import refuse_input_as_output, temporary_dir
    from aerotri.geom.crs.definition import length_unit_name, linear_unit_m
    from lidarctl.terrain.dem_io import HYDRO_TAG, open_dem, write_dem_cog

    if not (math.isfinite(params.max_range_m) and params.max_range_m > 0):
        raise OptionError(f"must be a positive number of metres, got {params.max_range_m}", param="--max-range-m")
    dem_path, water_path, out_path = Path(dem_path), Path(water_path), Path(out_path)
    refuse_input_as_output(out_path, [dem_path, water_path], option="OUT")
    src, z_m = open_dem(dem_path, out_path, say_unit=True)
    with src:
        dem_crs = pyproj.CRS.from_user_input(src.crs.to_wkt())
        xy_m = linear_unit_m(dem_crs)
        polys, water_z, ranges = read_water(water_path, dem_crs, water_layer)
        polys_tree = shapely.STRtree(polys)
        nodata = src.nodata if src.nodata is not None else -9999.0
        tmpdir = temporary_dir(out_path.parent if out_path.parent != Path("") else Path("."), out_path.name)
        bodies = []
        try:
            work = tmpdir / "flattened.tif"
            rio_copy(src, work, driver="GTiff", tiled=True, blockxsize=512, blockysize=512, compress="DEFLATE",
                     predictor=3, zlevel=1, bigtiff="IF_SAFER")
            with rasterio.open(work, "r+") as dst:
                full = Window(0, 0, dst.width, dst.height)
                pad = params.shore_cells + 1
                for k, poly in enumerate(polys):
                    area_m2 = poly.area * xy_m ** 2
                    if ranges[k] is not None and ranges[k] > params.max_range_m:
                        bodies.append(WaterBody(k, area_m2, water_z[k], ranges[k], None, None, 0,
                                                f"water returns span {ranges[k]:.2f} m (> {params.max_range_m:g} m): "
                                                "flowing water, left as it is"))
                        continue
                    win = from_bounds(*poly.bounds, transform=dst.transform)
                    win = Window(math.floor(win.col_off) - pad, math.floor(win.row_off) - pad,
                                 math.ceil(win.width) + 2 * pad + 1, math.ceil(win.height) + 2 * pad + 1)
                    try:
                        win = win.intersection(full)
                    except Exception:   # rasterio.errors.WindowError: the polygon lies off the DEM
                        bodies.append(WaterBody(k, area_m2, water_z[k], ranges[k], None, None, 0,
                                                "outside the DEM"))
                        continue
                    a = dst.read(1, window=win, masked=True)
                    z = a.filled(np.nan).astype(np.float64)
                    tr = dst.window_transform(win)
                    body = features.rasterize([poly], out_shape=z.shape, transform=tr, dtype="uint8").astype(bool)
                    near = polys_tree.query(shapely.box(*bounds(win, dst.transform)))
                    water = features.rasterize([polys[i] for i in near], out_shape=z.shape, transform=tr,
                                               dtype="uint8").astype(bool)
                    if not (body & np.isfinite(z)).any():
                        bodies.append(WaterBody(k, area_m2, water_z[k], ranges[k], None, None, 0,
                                                "no DEM cell with data has its centre inside it"))
                        continue
                    ring = shore_ring(z, body, water | body, params)
                    if ranges[k] is None:
                        # no water returns to tell a lake from a river (a hand-digitised outline): the shore tells it
                        # (trial-hydro: Autzen's river flattened at its lowest shore, the channel cut up to 3.1 m)
                        fall = shore_fall(z, body, ring, params.shore_percentile)
                        if fall is not None and fall * z_m > params.max_range_m:
                            bodies.append(WaterBody(k, area_m2, water_z[k], None, None, None, 0,
                                                    f"no water_z_range_m, and its shore's low heights fall "
                                                    f"{fall * z_m:.2f} m along it (> {params.max_range_m:g} m): flowing "
                                                    "water, left as it is (give water_z_range_m to judge it by its "
                                                    "water returns)"))
                            continue
                    shore, level = flatten_window(z, body, ring, water_z[k], params)
                    if level is None:
                        bodies.append(WaterBody(k, area_m2, None, ranges[k], None, None, 0,
                                                "no water_z and no shore cell with data"))
                        continue
                    cells = int((body & np.isfinite(z)).sum())
                    dst.write(np.where(np.isfinite(z), z, nodata).astype(np.float32), 1, window=win)
                    bodies.append(WaterBody(k, area_m2, water_z[k], ranges[k], shore, level, cells,
                                            empty_cells=int((body & ~np.isfinite(z)).sum())))
                # said to lidarctl smooth, which would move the flat surfaces again (trial-hydro)
                flat = sum(b.level is not None for b in bodies)
                dst.update_tags(**{HYDRO_TAG: f"{flat} water bodies at one level each (lidarctl hydro-flatten)"})
            write_dem_cog(work, out_path)
        finally:
            import shutil

            shutil.rmtree(tmpdir, ignore_errors=True)
    result = HydroResult(out_path, tuple(bodies), length_unit_name(z_m))
    log.debug(f"{dem_path} -> {out_path}: {len(result.flattened)} of {len(bodies)} water bodies flattened")
    return result


def format_result(result: HydroResult) -> str:
    unit = result.height_unit
    lines = [f"{result.path}: {len(result.flattened)} of {len(result.bodies)} water bodies flattened"]
    for b in result.bodies:
        head = f"  water {b.index + 1}: {b.area_m2:,.0f} m2"
        if b.level is None:
            lines.append(f"{head}, left: {b.reason}")
            continue
        parts = []
        if b.water_z is not None:
            parts.append(f"water returns {b.water_z:.2f}")
        if b.shore_level is not None:
            parts.append(f"shore {b.shore_level:.2f}")
        empty = f", {b.empty_cells:,} without data left empty" if b.empty_cells else ""
        lines.append(f"{head} at {b.level:.2f} {unit} ({', '.join(parts)}; {b.cells:,} cells{empty})")
    return "\n".join(lines)
