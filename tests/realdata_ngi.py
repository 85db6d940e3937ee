"""The NGI real-data block (../shared/data/ngi_dmc, 4 Z/I DMC frames) as a project folder, and the measures
that compare an adjustment of it with the national aerial triangulation.

Used by ``tests/aerotri/adjust/test_ngi_realdata.py`` and ``bench/eval_ngi_surface.py`` (both load this
file by path). The data is never copied: the project's images and DEM are symbolic links.

Data (its README.md): frames 640 x 1152 px (portrait), pinhole camera f = 120 mm, sensor 92.16 x 165.888 mm
(144 um pixels), principal point at the centre; reference orientation ``camera_pos_ori.txt``
(``id X Y Z omega phi kappa``, m and degrees, the photogrammetric convention the toolkit uses); a 24 m
SUDEM (``dem.tif``) in "Lo25" (Transverse Mercator lon_0 = 25, WGS 84, no false origin) + EGM2008 height.
The reference heights are EGM2008 heights as well (flying height about 5250 m over 150-780 m terrain),
so the project says ``heights = "EPSG:3855"`` and the DEM's heights need no conversion.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import rasterio

FOCAL_MM = 120.0
SENSOR_MM = (92.16, 165.888)
WIDTH_PX, HEIGHT_PX = 640, 1152
PIXEL_UM = SENSOR_MM[0] * 1000.0 / WIDTH_PX  # 144 um
# The horizontal CRS of the data ("Lo25"), spelled as the README gives it.
LO25 = "+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs +type=crs"
HEIGHTS = "EPSG:3855"  # EGM2008 height, the DEM's vertical datum (EPSG datum 1027) and the reference's
GNSS_SIGMA_M = 0.05
# The portrait frames have their top 90 degrees from the flight direction (kappa near 180 flying west, near 0
# flying east): the footprints of the match stage's flight plan need it, or no cross-strip pair is found.
IMAGE_TOP_DEG = 90.0  # the portrait frames' top from the flight direction (found from the sensor)
REFERENCE_FILE = "camera_pos_ori.txt"
DEM_FILE = "dem.tif"


@dataclasses.dataclass
class Reference:
    """The national AT: projection centres (N, 3) m and omega, phi, kappa (N, 3) degrees, by image id."""

    image_id: list[str]
    centre_m: np.ndarray
    opk_deg: np.ndarray

    def rows(self, image_ids) -> np.ndarray:
        """Row of each of ``image_ids`` (KeyError naming an id the reference lacks)."""
        k = {iid: i for i, iid in enumerate(self.image_id)}
        return np.array([k[i] for i in image_ids], dtype=int)


def read_reference(data_dir) -> Reference:
    """``camera_pos_ori.txt``: ``id X Y Z omega phi kappa`` per line."""
    ids, rows = [], []
    for line in (Path(data_dir) / REFERENCE_FILE).read_text().splitlines():
        f = line.split()
        if len(f) == 7 and not line.lstrip().startswith("#"):
            ids.append(f[0])
            rows.append([float(v) for v in f[1:]])
    a = np.array(rows, dtype=float)
    return Reference(ids, a[:, :3], a[:, 3:])


def build_ngi_project(data_dir, out_dir, gnss_sigma_m: float = GNSS_SIGMA_M) -> Path:
    """Write a project folder at ``out_dir`` (created; must not exist or be empty) from the NGI data:
    project.toml (Lo25 + EGM2008 heights), camera.toml (pinhole), gnss.txt (the reference projection
    centres, ``gnss_sigma_m`` in each axis, no lever arm), images/ and lidar_out/dem.tif as symbolic links
    to the data. Returns ``out_dir``."""
    data_dir, root = Path(data_dir).resolve(), Path(out_dir)
    ref = read_reference(data_dir)
    if root.exists() and any(root.iterdir()):
        raise FileExistsError(f"{root}: not empty (the NGI project is built into a new folder)")
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "lidar_out").mkdir()
    (root / "project.toml").write_text(
        "# The NGI DMC block (4 frames of map sheet 3324C, 2015), built by tests/realdata_ngi.py\n"
        "[project]\n"
        'name = "ngi_dmc"\n'
        f'crs = "{LO25}"\n'
        f'heights = "{HEIGHTS}"\n'
        "[gnss]\n"
        f"sigma_xy_m = {gnss_sigma_m}\n"
        f"sigma_z_m = {gnss_sigma_m}\n"
    )
    (root / "camera.toml").write_text(
        "# Z/I DMC downsampled by 12 and turned to portrait (orthority's test frames)\n"
        'name = "ngi_dmc"\n'
        'model = "pinhole"\n'
        f"focal_mm = {FOCAL_MM}\n"
        f"pixel_um = {PIXEL_UM}\n"
        f"width = {WIDTH_PX}\n"
        f"height = {HEIGHT_PX}\n"
    )
    lines = ["# image_id X_m Y_m Z_m sX_m sY_m sZ_m: the national AT's projection centres (EGM2008 heights)"]
    for i, iid in enumerate(ref.image_id):
        x, y, z = ref.centre_m[i]
        lines.append(f"{iid} {x:.4f} {y:.4f} {z:.4f} {gnss_sigma_m} {gnss_sigma_m} {gnss_sigma_m}")
    (root / "gnss.txt").write_text("\n".join(lines) + "\n")
    for iid in ref.image_id:
        src = data_dir / f"{iid}.tif"
        if not src.is_file():
            raise FileNotFoundError(f"{src}: the frame of reference record {iid} is missing")
        (root / "images" / src.name).symlink_to(src)
    (root / "lidar_out" / "dem.tif").symlink_to(data_dir / DEM_FILE)
    return root


def match_settings(**changes):
    """The match settings of this block: the defaults (the portrait frames' top is found from the sensor's
    shape, ``IMAGE_TOP_DEG``), with ``changes`` (MatchSettings fields)."""
    from aerotri.match.settings import MatchSettings

    return MatchSettings(**changes)


# -- measures -----------------------------------------------------------------------------------------

def angle_diff_deg(a, b) -> np.ndarray:
    """a - b wrapped into (-180, 180] degrees."""
    return (np.asarray(a, float) - np.asarray(b, float) + 180.0) % 360.0 - 180.0


def opk_differences(eo_ids, eo_opk_deg, eo_centre_m, ref: Reference) -> dict:
    """Attitude and position differences of an orientation against the reference (same image ids)."""
    sel = ref.rows(eo_ids)
    d_opk = angle_diff_deg(eo_opk_deg, ref.opk_deg[sel])
    d_pos = np.asarray(eo_centre_m, float) - ref.centre_m[sel]
    return {
        "opk_rms_diff_deg": float(np.sqrt(np.mean(d_opk**2))),
        "opk_max_abs_diff_deg": float(np.abs(d_opk).max()),
        "omega_phi_kappa_rms_diff_deg": np.sqrt(np.mean(d_opk**2, axis=0)).tolist(),
        "centre_rms_diff_m": float(np.sqrt(np.mean(np.sum(d_pos**2, axis=1)))),
        "per_image": {iid: {"d_opk_deg": d_opk[n].round(5).tolist(), "d_centre_m": d_pos[n].round(3).tolist()}
                      for n, iid in enumerate(eo_ids)},
    }


def sample_dem_bilinear(dem_path, x, y) -> np.ndarray:
    """DEM heights at (x, y) (the DEM's horizontal CRS) by bilinear interpolation between cell centres;
    NaN outside the DEM or next to a nodata cell."""
    with rasterio.open(dem_path) as ds:
        a = ds.read(1, masked=True).astype(float).filled(np.nan)
        inv = ~ds.transform
    x, y = np.asarray(x, float), np.asarray(y, float)
    # cell-centre coordinates (the cell's top-left corner is at whole numbers)
    col = inv.a * x + inv.b * y + inv.c - 0.5
    row = inv.d * x + inv.e * y + inv.f - 0.5
    c0, r0 = np.floor(col).astype(int), np.floor(row).astype(int)
    fc, fr = col - c0, row - r0
    ok = (c0 >= 0) & (r0 >= 0) & (c0 + 1 < a.shape[1]) & (r0 + 1 < a.shape[0])
    out = np.full(x.shape, np.nan)
    c, r, u, v = c0[ok], r0[ok], fc[ok], fr[ok]
    out[ok] = (a[r, c] * (1 - u) * (1 - v) + a[r, c + 1] * u * (1 - v)
               + a[r + 1, c] * (1 - u) * v + a[r + 1, c + 1] * u * v)
    return out


def height_stats(z_m, dem_m) -> dict:
    """Median, RMS and mean of (point height - DEM height) over the points inside the DEM."""
    d = np.asarray(z_m, float) - np.asarray(dem_m, float)
    d = d[np.isfinite(d)]
    if not len(d):
        return {"n": 0, "median_m": math.nan, "rms_m": math.nan, "mean_m": math.nan, "nmad_m": math.nan}
    med = float(np.median(d))
    return {"n": int(len(d)), "median_m": med, "rms_m": float(np.sqrt(np.mean(d**2))), "mean_m": float(np.mean(d)),
            "nmad_m": float(1.4826 * np.median(np.abs(d - med)))}


def read_object_points(path, kind: str = "tie") -> tuple[np.ndarray, np.ndarray]:
    """``at/object_points.csv``: ids and x, y, z (N, 3) of the points of ``kind``."""
    ids, xyz = [], []
    lines = Path(path).read_text().splitlines()
    head = lines[0].split(",")
    ci = {k: head.index(k) for k in ("id", "kind", "x", "y", "z")}
    for line in lines[1:]:
        f = line.split(",")
        if f[ci["kind"]] == kind:
            ids.append(f[ci["id"]])
            xyz.append([float(f[ci["x"]]), float(f[ci["y"]]), float(f[ci["z"]])])
    return np.array(ids, dtype=object), np.array(xyz, dtype=float).reshape(-1, 3)


def read_tiepoints(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``at/tiepoints.csv`` through the toolkit's reader: point ids, image ids, (K, 2) pixels."""
    from aerotri.geom.observations import read_image_points

    obs = read_image_points(path)
    return np.asarray(obs.point_id, dtype=object), np.asarray(obs.image_id, dtype=object), np.asarray(obs.xy_px)


def intersect_with_orientation(root, image_ids, centre_m, opk_deg, point_id, obs_image, obs_xy_px,
                               min_rays: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intersect tie points (forward intersection, least squares over the rays) with a given orientation
    in the project's local frame (aerotri.geom.local_frame, as the adjustment). Returns the point ids,
    their map coordinates (P, 3) and the RMS reprojection residual per point (px)."""
    from aerotri.core.project import Project
    from aerotri.geom.camera import project_camera
    from aerotri.geom.local_frame import LocalFrame
    from aerotri.geom.rotation import rotation_matrix_opk

    project = Project.open(root)
    cam = project_camera(project)
    centre_m, opk_deg = np.asarray(centre_m, float), np.asarray(opk_deg, float)
    frame = LocalFrame.at_centre(project.crs, centre_m)
    C = frame.to_local(centre_m)
    # grid-axis attitude -> local ENU axes (as aerotri.adjust.pipeline does for given orientations)
    R = frame.rotation_local_from_map(centre_m) @ rotation_matrix_opk(opk_deg[:, 0], opk_deg[:, 1], opk_deg[:, 2])
    k = {iid: n for n, iid in enumerate(image_ids)}
    img = np.array([k.get(i, -1) for i in obs_image], dtype=int)
    keep = img >= 0
    pids, inv = np.unique(np.asarray(point_id)[keep].astype(str), return_inverse=True)
    img, xy = img[keep], np.asarray(obs_xy_px, float)[keep]
    d = np.empty((len(img), 3))
    for n in range(len(image_ids)):
        m = img == n
        if m.any():
            d[m] = cam.rays(xy[m, 0], xy[m, 1], R[n])
    # sum over rays of (I - d d^T) (X - C) = 0
    A = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    b = np.einsum("kij,kj->ki", A, C[img])
    AA = np.zeros((len(pids), 3, 3))
    bb = np.zeros((len(pids), 3))
    np.add.at(AA, inv, A)
    np.add.at(bb, inv, b)
    rays = np.bincount(inv, minlength=len(pids))
    ok = rays >= min_rays
    X = np.full((len(pids), 3), np.nan)
    X[ok] = np.linalg.solve(AA[ok], bb[ok][:, :, None])[:, :, 0]
    # reprojection residuals
    res2 = np.zeros(len(pids))
    for n in range(len(image_ids)):
        m = img == n
        if m.any():
            u, v, _ = cam.project(X[inv[m]], C[n], R[n])
            np.add.at(res2, inv[m], (u - xy[m, 0]) ** 2 + (v - xy[m, 1]) ** 2)
    rms = np.sqrt(res2 / np.maximum(2 * rays, 1))
    Xm = np.full_like(X, np.nan)
    Xm[ok] = frame.to_map(X[ok])
    return pids[ok], Xm[ok], rms[ok]
