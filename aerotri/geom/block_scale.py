"""The ground sample distance and platform of a photo block, from the project's own files: what chooses its
tolerance table (``aerotri.core.tolerances.choose_table``).

GSD = pixel size x height above ground / focal length (``Camera.gsd_m``), with the median height above
ground of the frames: projection centres from ``at/eo.txt`` (else ``gnss.txt``) minus the ground under them
from ``lidar_out/dem.tif``, else the median height of the adjusted tie points (the heights the caller gives, else
``at/object_points.csv``), else ``[flight] mean_terrain_height_m``. The planned terrain height comes last: it is
a planning figure (an EXIF import writes the take-off point's height there; Tuniu's 86.6 m made "GSD 11 cm at
100 m" of 10 cm at 92 m over its adjusted points' 94.2 m). A block flown lower than ``selection.toml``
[platform] low_altitude_height_max_m (150 m) is a low-altitude (UAS) block. Heights in the project CRS's
height unit are converted to metres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aerotri.core.tolerances import BlockScale, low_altitude_height_m


def _dem_heights(path: Path, x, y) -> np.ndarray:
    """DEM heights at map positions (nearest cell; NaN outside or on nodata)."""
    import rasterio

    with rasterio.open(path) as ds:
        z = np.array([v[0] for v in ds.sample(zip(x, y), masked=True)], dtype=object)
    return np.array([float("nan") if np.ma.is_masked(v) else float(v) for v in z])


def _object_point_heights(path: Path) -> np.ndarray:
    """The z column of ``at/object_points.csv`` (id,kind,x,y,z,...)."""
    from aerotri.core.textio import read_text

    rows = [r.split(",") for r in read_text(path, "object points (CSV)").splitlines()[1:] if r.strip()]
    try:
        return np.array([float(r[4]) for r in rows if len(r) > 4])
    except ValueError:
        return np.array([])


def planned_terrain_height(project) -> float | None:
    """``[flight] mean_terrain_height_m`` of project.toml in the project CRS's height unit (None: not given): metres
    by its name, while the frames' positions, DEMs and footprints are in the CRS's unit (US feet: 1,125 m above
    ground read for 1,000 when taken as it stands)."""
    mean_h = project.flight.mean_terrain_height_m
    if mean_h is None:
        return None
    from aerotri.geom.crs.definition import height_unit_m, project_crs

    return float(mean_h) / height_unit_m(project_crs(project))


def block_scale(camera, centre_z, ground_z, height_unit_m: float, how: str) -> BlockScale:
    """The median height above ground (m), its GSD and the platform of frames at heights ``centre_z`` over
    ground heights ``ground_z`` (arrays, or a scalar ground height; in the CRS's height unit)."""
    h = (np.asarray(centre_z, float) - np.asarray(ground_z, float)) * height_unit_m
    h = h[np.isfinite(h)]
    if not len(h):
        return BlockScale(None, None, None, f"{how}: no frame over the terrain")
    hm = float(np.median(h))
    if hm <= 0:
        return BlockScale(None, hm, None, f"{how}: frames {hm:.1f} m below the terrain (heights in another system?)")
    platform = "uas" if hm < low_altitude_height_m() else "manned"
    return BlockScale(camera.gsd_m(hm), hm, platform, how)


def project_block_scale(project, ground_heights=None, ground_source: str = "the adjusted tie points", *,
                        camera: tuple | None = None, positions: tuple | None = None) -> BlockScale:
    """The block's GSD and platform from the project folder (module docstring); ``ground_heights``: heights
    of the ground in the CRS's height unit (the adjustment's tie points; NaN ignored), taken when there is no
    lidar_out/dem.tif, before ``at/object_points.csv`` and ``[flight] mean_terrain_height_m``. The camera is the one the orientations belong to (``oriented_camera``: the
    adjustment's at/camera.toml, else the nominal camera.toml), or ``camera``, (camera, source), when given. The
    frames' positions are ``positions``, ((N, 3) map coordinates, source), when given (an adjustment writing its
    report before its eo.txt: a block without GNSS has neither file yet), else at/eo.txt's, else gnss.txt's. A
    ``BlockScale`` without GSD says what was missing."""
    from aerotri.geom.camera import oriented_camera
    from aerotri.geom.crs.definition import height_unit_m, project_crs
    from aerotri.geom.eo import read_eo, read_gnss

    if not project.camera_path.is_file():
        return BlockScale(None, None, None, "no camera.toml")
    camera, cam_src = camera if camera is not None else oriented_camera(project)
    cam = f"{Path(cam_src).name if 'self-calibrated' not in cam_src else 'self-calibrated camera'} " \
          f"(f {camera.focal_mm:g} mm, pixel {camera.pixel_um:g} um)"
    if positions is not None:
        pos, src = np.asarray(positions[0], dtype=float), positions[1]
    elif project.eo_path.is_file():
        pos, src = read_eo(project.eo_path).centre_m, "at/eo.txt"
    elif project.gnss_path.is_file():
        pos, src = read_gnss(project.gnss_path).position_m, "gnss.txt"
    else:
        return BlockScale(None, None, None, f"{cam}; no at/eo.txt or gnss.txt")
    unit = height_unit_m(project_crs(project))
    planned = planned_terrain_height(project)
    head = f"{cam}; {len(pos)} frames of {src}"
    if project.dem_path.is_file():
        return block_scale(camera, pos[:, 2], _dem_heights(project.dem_path, pos[:, 0], pos[:, 1]), unit,
                           f"{head} over lidar_out/dem.tif")
    # the adjusted tie points before the planned terrain height: they are the ground the frames were measured on
    if ground_heights is not None and np.isfinite(np.asarray(ground_heights, float)).any():
        g = float(np.nanmedian(np.asarray(ground_heights, float)))
        return block_scale(camera, pos[:, 2], g, unit, f"{head} over the median height of {ground_source} "
                                                       f"({_height_words(g, unit)})")
    if project.object_points_path.is_file():
        z = _object_point_heights(project.object_points_path)
        z = z[np.isfinite(z)]
        if len(z):
            g = float(np.median(z))
            return block_scale(camera, pos[:, 2], g, unit,
                               f"{head} over the median height of the adjusted points of at/object_points.csv "
                               f"({_height_words(g, unit)})")
    if planned is not None:
        return block_scale(camera, pos[:, 2], planned, unit, f"{head} over [flight] mean_terrain_height_m "
                           f"({project.flight.mean_terrain_height_m:g} m; no adjusted tie points)")
    return BlockScale(None, None, None, f"{head}; no terrain height (no lidar_out/dem.tif, no [flight] "
                                        f"mean_terrain_height_m, no adjusted tie points)")


def _height_words(height: float, unit_m: float) -> str:
    """A ground height with its unit, one decimal (+ 0.0: no "-0.0", trial s103: the kite's relative heights)."""
    from aerotri.geom.crs.definition import length_unit_name

    return f"{round(height, 1) + 0.0:.1f} {length_unit_name(unit_m)}"
