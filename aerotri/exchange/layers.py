"""Map layers of an adjusted block: GeoPackage (``aerotri export --format gpkg``, project CRS) and KML
(``--format kml``, WGS84 longitude/latitude and ellipsoidal height), written by ``aerotri.core.vector_files``.
KML takes an absolute altitude above sea level (EGM96), not above the ellipsoid; no ``altitudeMode`` is written, so
viewers clamp the placemarks to their terrain (KML's default, ``clampToGround``) and the heights, N (tens of metres)
above EGM96 ones, are for readers that take them as ellipsoidal (trial s100 exchange F4: this said "as KML requires").

Layers (the same in both files):

- ``control_points``: the control and check points of the adjustment report (``at/report.json``) at their
  given coordinates, attributes ``point_id``, ``kind`` (full, horizontal, height, check), ``used`` (1: in the
  adjustment as control), ``rays`` and the ground residuals ``dx_m``, ``dy_m``, ``dz_m`` = adjusted - given
  (project CRS axes, metres; a coordinate the point does not control has no residual: NULL); plan-only
  (horizontal) control has no given height: its point stands at its adjusted height, never at 0;
- ``footprints``: each frame's outline on the ground (``image_id``, ``omega_deg``, ``phi_deg``, ``kappa_deg``):
  ``EDGE_POINTS`` points along each image edge (pixel-area corners included), their rays through the adjusted
  camera and orientation (``at/eo.txt``) intersected with the project's DEM (``footprint_dem``: the LiDAR
  stages' ``lidar_out/dem.tif``, else the DEM the frame orthos were rectified on, else the adjustment's
  surface-control DEM), else with the mean height of the adjusted points (a frame whose edge rays miss the
  ground has none);
- ``projection_centres``: the frames' adjusted centres (``image_id``, ``omega_deg``, ``phi_deg``, ``kappa_deg``).

In the KML every placemark also has a ``Name`` (its point or image id), which KML viewers show.
"""

from __future__ import annotations

import contextlib
import logging
import math
import tempfile
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_json
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.geom.local_frame import FramesOnEarth

log = logging.getLogger(__name__)

EDGE_POINTS = 8  # per image edge, corners included once
DEM_ITERATIONS = 20


def _edge_pixels(width: int, height: int, n: int = EDGE_POINTS) -> np.ndarray:
    """(4n, 2) pixel coordinates around the frame's outer edge (the pixel-area corners), clockwise from the
    top-left corner."""
    x0, y0, x1, y1 = -0.5, -0.5, width - 0.5, height - 0.5
    t = np.arange(n) / n
    top = np.column_stack([x0 + t * (x1 - x0), np.full(n, y0)])
    right = np.column_stack([np.full(n, x1), y0 + t * (y1 - y0)])
    bottom = np.column_stack([x1 - t * (x1 - x0), np.full(n, y1)])
    left = np.column_stack([np.full(n, x0), y1 - t * (y1 - y0)])
    return np.vstack([top, right, bottom, left])


def _dem_sampler(ds):
    """Heights of an open DEM at map points (NaN outside or on nodata), read point by point (a block's DEM may
    be larger than memory)."""

    def sample(x, y):
        vals = np.array([v[0] for v in ds.sample(zip(x, y), masked=True)], dtype=object)
        return np.array([np.nan if v is np.ma.masked else float(v) for v in vals])

    return sample


def footprint_dem(project: Project) -> tuple[Path | None, str]:
    """The DEM the footprints are draped on and where it came from: ``lidar_out/dem.tif``, else the DEM of the
    frame orthos (``ortho/frames/index.json``: the footprints then outline the orthos), else the adjustment's
    surface-control DEM (``at/report.json``); (None, why) when none of them is a file now."""
    if project.dem_path.is_file():
        return project.dem_path, "the LiDAR stages' DEM"
    index = project.frames_index_path
    if index.is_file():
        f = ((read_json(index, "frame ortho index").get("inputs") or {}).get("dem") or {}).get("file")
        if isinstance(f, str) and (project.root / f).is_file():  # relative to the project, or absolute
            return project.root / f, f"the DEM of the frame orthos ({index})"
    if project.adjustment_report_path.is_file():
        f = (read_json(project.adjustment_report_path, "adjustment report").get("surface_control") or {}).get("dem")
        if isinstance(f, str) and Path(f).is_absolute() and Path(f).is_file():
            return Path(f), f"the adjustment's surface control ({project.adjustment_report_path})"
    return None, "no DEM: no lidar_out/dem.tif, no frame orthos, no surface control"


def footprints(project: Project, block: AdjustedBlock) -> tuple[list[str], list[np.ndarray], np.ndarray, str]:
    """(image ids, (M, 3) outline per frame in the project CRS, omega-phi-kappa (N, 3), surface used)."""
    from aerotri.geom.camera import oriented_camera
    from aerotri.geom.eo import read_eo

    cam, _ = oriented_camera(project)
    eo = read_eo(project.eo_path)
    xy = _edge_pixels(cam.width, cam.height)
    mean_h = float(np.mean(block.frame.to_map(block.points_local)[:, 2])) if len(block.points_local) else 0.0
    surface = f"mean height of the adjusted points ({mean_h:.2f})"
    with contextlib.ExitStack() as stack:
        sampler = None
        dem_path, dem_source = footprint_dem(project)
        if dem_path is not None:
            from aerotri.geom.crs.definition import parse_crs, same_horizontal
            from aerotri.geom.crs.raster_warp import open_north_up

            # checked as every DEM reader checks it (a CRS, 2 x 2 cells, one band of finite heights)
            ds = stack.enter_context(open_north_up(dem_path, "DEM", heights=True))
            if same_horizontal(parse_crs(ds.crs, str(dem_path)), parse_crs(block.crs)):
                sampler = _dem_sampler(ds)
                surface = f"DEM {dem_path}, {dem_source}"
            elif dem_path == project.dem_path:
                raise InputError(f"{dem_path}: DEM in {ds.crs.to_string()}, the project in {block.crs}; "
                                 f"footprints need the DEM in the project CRS")
            else:  # a DEM from elsewhere (the orthos warp it): the export goes on as it did before it was used
                surface += f" ({dem_path}, {dem_source}, is in {ds.crs.to_string()}, not the project CRS)"
                log.warning(f"{dem_path}: DEM in {ds.crs.to_string()}, the project in {block.crs}; footprints on "
                            f"the mean height of the adjusted points")
        ids, outlines, opk = [], [], []
        # the frames over the earth, in the adjustment's own ENU frame (a Cartesian CRS: the map coordinates)
        frames = FramesOnEarth(project.crs, eo.centre_m, eo.rotations(), frame=block.frame)
        for i in range(len(eo)):
            d = frames.rays_local(cam, i, xy[:, 0], xy[:, 1])
            if not np.all(d[:, 2] < -1e-9):
                log.warning(f"{eo.image_id[i]}: rays at the frame's edge do not reach the ground (an oblique frame "
                            f"seeing the horizon); no footprint")
                continue
            z = np.full(len(xy), mean_h)
            for _ in range(DEM_ITERATIONS if sampler else 0):
                p = frames.at_height(i, d, z)
                zs = sampler(p[:, 0], p[:, 1])
                z_new = np.where(np.isfinite(zs), zs, z)
                done = np.max(np.abs(z_new - z)) < 1e-3
                z = z_new
                if done:
                    break
            outlines.append(frames.at_height(i, d, z))
            ids.append(eo.image_id[i])
            opk.append(eo.opk_deg[i])
    return ids, outlines, np.array(opk).reshape(-1, 3), surface


def _control_rows(project: Project) -> list[dict]:
    report = read_json(project.adjustment_report_path, "adjustment report")
    rows = []
    for c in report.get("control_points", []):
        given, adjusted = c.get("given_m"), c.get("adjusted_m")
        if given is None:
            raise InputError(f"{project.adjustment_report_path}: control point {c.get('id')!r} has no given_m")
        res = c.get("residual_m") or ([a - g for a, g in zip(adjusted, given)] if adjusted else [None] * 3)
        xyz = list(given)
        if c.get("kind") == "horizontal":  # plan-only: no given height (its stored 0 is none), the adjusted one
            xyz[2] = adjusted[2] if adjusted else float("nan")
        rows.append({"id": str(c["id"]), "kind": str(c.get("kind", "full")), "used": int(bool(c.get("used", True))),
                     "rays": int(c.get("rays", 0)), "xyz": xyz, "d": res})
    for c in report.get("check_points", []):
        rows.append({"id": str(c["id"]), "kind": "check", "used": 0, "rays": int(c.get("rays", 0)),
                     "xyz": c["measured_m"], "d": c.get("d_m") or [None] * 3})
    return rows


def _layers(block: AdjustedBlock, project: Project) -> tuple[list, str]:
    """[(layer name, geometry type, shapely geometries (project CRS), {field: values})], surface note."""
    import shapely

    rows = _control_rows(project)
    ids, outlines, opk, surface = footprints(project, block)
    nan = float("nan")

    from aerotri.geom.crs.definition import map_axes_unit_m, project_crs

    # the report's residuals are in the project CRS's unit (feet in a feet project); the fields say metres (they
    # carried feet before trial-exchange)
    unit_m = map_axes_unit_m(project_crs(project), "[project] crs")

    def col(k):
        return np.array([nan if r["d"][k] is None or not math.isfinite(r["d"][k]) else float(r["d"][k]) * unit_m[k]
                         for r in rows])

    control = ("control_points", "Point Z", [shapely.Point(*r["xyz"]) for r in rows],
               {"point_id": np.array([r["id"] for r in rows], object), "kind": np.array([r["kind"] for r in rows], object),
                "used": np.array([r["used"] for r in rows], np.int32), "rays": np.array([r["rays"] for r in rows], np.int32),
                "dx_m": col(0), "dy_m": col(1), "dz_m": col(2)})
    foot = ("footprints", "Polygon Z", [shapely.Polygon(o) for o in outlines],
            {"image_id": np.array(ids, object), "omega_deg": opk[:, 0].copy(), "phi_deg": opk[:, 1].copy(),
             "kappa_deg": opk[:, 2].copy()})
    from aerotri.geom.eo import read_eo

    eo = read_eo(project.eo_path)
    # the attitude beside the centre (trial s96 L6: image_id alone, the angles on the footprints only)
    centres = ("projection_centres", "Point Z", [shapely.Point(*c) for c in eo.centre_m],
               {"image_id": np.array(eo.image_id, object), "omega_deg": eo.opk_deg[:, 0].astype(float),
                "phi_deg": eo.opk_deg[:, 1].astype(float), "kappa_deg": eo.opk_deg[:, 2].astype(float)})
    return [control, foot, centres], surface


def _to_wgs84(geoms, block: AdjustedBlock, project: Project):
    import shapely

    from aerotri.geom.crs.definition import parse_crs, project_heights, with_heights
    from aerotri.geom.crs.transform import CrsTransformer

    t = CrsTransformer(with_heights(parse_crs(block.crs), project_heights(project)), parse_crs("EPSG:4979"))

    def f(xyz):
        lon, lat, h = t.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        return np.column_stack([lon, lat, h])

    return [shapely.transform(g, f, include_z=True) for g in geoms]


def _write(path: Path, layers, crs: str) -> None:
    from aerotri.core.vector_files import VectorLayer, write_layers

    write_layers(path, [VectorLayer(name, gtype, geoms, fields) for name, gtype, geoms, fields in layers], crs=crs)


def files(block: AdjustedBlock, project: Project, fmt: str) -> list[ExportFile]:
    """``layers/block.gpkg`` (``fmt`` gpkg, bytes) or ``layers/block.kml`` (kml, text)."""
    layers, surface = _layers(block, project)
    log.info(f"footprints on the {surface}")
    with tempfile.TemporaryDirectory() as tmp:
        if fmt == "gpkg":
            from aerotri.geom.crs.definition import crs_label, horizontal_crs, parse_crs

            path = Path(tmp) / "block.gpkg"
            crs = parse_crs(block.crs)
            label = crs_label(horizontal_crs(crs))
            _write(path, layers, label if label.startswith("EPSG:") else horizontal_crs(crs).to_wkt())
            return [ExportFile("layers/block.gpkg", path.read_bytes())]
        path = Path(tmp) / "block.kml"
        # KML shows a placemark's "Name": the point's or frame's id
        wgs = [(n, g, _to_wgs84(geoms, block, project), {"Name": f.get("point_id", f.get("image_id"))} | f)
               for n, g, geoms, f in layers]
        _write(path, wgs, "EPSG:4326")
        return [ExportFile("layers/block.kml", path.read_text())]
