"""Checks of pipeline products against a simulated project's truth (used by tests and bench scripts)."""

from __future__ import annotations

import csv
import tomllib
from dataclasses import dataclass

import numpy as np
import rasterio
from scipy.ndimage import maximum_filter, minimum_filter

from aerotri.adjust.check_points import intersect_rays
from aerotri.geom.camera import BrownCamera
from aerotri.geom.eo import read_eo
from aerotri.geom.local_frame import LocalFrame


def read_tiepoints(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return ([r["point_id"] for r in rows], [r["image_id"] for r in rows],
            np.array([[float(r["x_px"]), float(r["y_px"])] for r in rows]).reshape(-1, 2))


@dataclass(frozen=True)
class TiePointErrors:
    """Tie observations checked against the truth: how many are off by more than ``off_by_more_than_px``."""

    observations: int
    tracks: int
    off_by_more_than_px: float
    off_count: int
    off_fraction: float
    median_residual_px: float
    rms_residual_px: float  # of the observations not off


@dataclass(frozen=True)
class TruthRoofCorners:
    """The simulator's roof corners (N): ids, positions (N, 3) in map metres, grid bearings (N, 2) of the
    incoming and outgoing outline edge in [0, 180), corner angles and roof kinds."""

    id: np.ndarray
    xyz_m: np.ndarray
    bearing_deg: np.ndarray
    angle_deg: np.ndarray
    roof: np.ndarray


def tie_point_errors(project, tiepoints_csv=None, tol_px: float = 1.0) -> TiePointErrors:
    """Which tie observations are off by more than ``tol_px`` from their true image positions.

    Each track is intersected with the true orientations and the true camera (in the ENU frame of
    ``aerotri.geom.local_frame``, where the simulator's rays are straight); an observation is off
    when its reprojection residual exceeds ``tol_px``. Two-ray tracks cannot show errors along the
    epipolar line in their residuals, so their intersected point must also lie on the true DSM
    within the height error that ``tol_px`` of parallax would cause (tested against the DSM's local
    minimum and maximum, so building edges do not count against the matcher).
    """
    from pathlib import Path

    project = Path(project)
    pid, iid, xy = read_tiepoints(tiepoints_csv or project / "at" / "tiepoints.csv")
    eo = read_eo(project / "truth" / "eo.txt")
    cam = BrownCamera.read(project / "truth" / "camera.toml")
    with open(project / "project.toml", "rb") as f:
        frame = LocalFrame.at_centre(tomllib.load(f)["project"]["crs"], eo.centre_m)
    centre = frame.to_local(eo.centre_m)
    img = eo.rows(iid)
    _, track = np.unique(pid, return_inverse=True)
    n = int(track.max()) + 1 if len(track) else 0
    R = frame.rotation_local_from_map(eo.centre_m) @ eo.rotations()
    d = np.empty((len(xy), 3))
    for k in np.unique(img):
        sel = img == k
        d[sel] = cam.rays(xy[sel, 0], xy[sel, 1], R[k])
    C = centre[img]
    X, ok = intersect_rays(C, d, track, n)
    res = np.empty(len(xy))
    for k in np.unique(img):
        sel = img == k
        px, py, _ = cam.project(X[track[sel]], centre[k], R[k])
        res[sel] = np.hypot(px - xy[sel, 0], py - xy[sel, 1])
    Xm = np.where(np.isfinite(X), frame.to_map(np.nan_to_num(X)), np.nan)  # for the DSM (map grid)
    off = (res > tol_px) | ~ok[track]  # a track whose rays do not intersect counts as wrong
    length = np.bincount(track, minlength=n)
    two = length[track] == 2
    with rasterio.open(project / "truth" / "dsm.tif") as ds:
        dsm = ds.read(1)
        hi, lo = maximum_filter(dsm, 5), minimum_filter(dsm, 5)
        T = ds.transform  # north-up grid: x = c + a col, y = f + e row
        rows = np.clip(np.floor((Xm[:, 1] - T.f) / T.e).astype(int), 0, ds.height - 1)
        cols = np.clip(np.floor((Xm[:, 0] - T.c) / T.a).astype(int), 0, ds.width - 1)
    # Height error caused by tol_px of x-parallax in each two-ray track: dZ = tol * GSD * H / B.
    first = np.full(n, -1)
    second = np.full(n, -1)
    for k in range(len(track)):
        t = track[k]
        if first[t] < 0:
            first[t] = img[k]
        elif second[t] < 0:
            second[t] = img[k]
    ok2 = second >= 0
    B = np.where(ok2, np.linalg.norm(centre[first] - centre[np.maximum(second, 0)], axis=1), np.inf)
    Hh = centre[np.maximum(first, 0), 2] - X[:, 2]
    dz_tol = tol_px * cam.pixel_um * 1e-6 / (cam.focal_mm * 1e-3) * Hh ** 2 / np.maximum(B, 1e-6) + 0.3
    bad_height = (Xm[:, 2] > hi[rows, cols] + dz_tol) | (Xm[:, 2] < lo[rows, cols] - dz_tol)
    off |= two & bad_height[track]
    return TiePointErrors(observations=int(len(xy)), tracks=n, off_by_more_than_px=float(tol_px),
                          off_count=int(off.sum()), off_fraction=float(off.mean()) if len(off) else 0.0,
                          median_residual_px=float(np.median(res)) if len(res) else 0.0,
                          rms_residual_px=float(np.sqrt(np.mean(res[~off] ** 2))) if (~off).any() else 0.0)


def truth_roof_corners(project) -> TruthRoofCorners:
    """The simulator's roof corners with their edge bearings, in the ``lidarctl corners`` layout.

    Reads ``truth/roof_corners.csv`` and the roof outlines of ``truth/buildings.geojson``. For development
    and tests of the control transfer only.
    """
    import json
    from pathlib import Path

    truth = Path(project) / "truth"
    rows = list(csv.DictReader(open(truth / "roof_corners.csv", newline="")))
    outlines = {}
    for f in json.loads((truth / "buildings.geojson").read_text())["features"]:
        if f["properties"].get("part") == "roof_outline":
            outlines[int(f["properties"]["building_id"])] = np.array(f["geometry"]["coordinates"][0])[:-1, :2]
    ids, xyz, bearing, angle, roof = [], [], [], [], []
    for r in rows:
        ring = outlines.get(int(r["building_id"]))
        xy = np.array([float(r["x"]), float(r["y"])])
        if ring is None:
            continue
        k = int(np.argmin(np.hypot(*(ring - xy).T)))
        if np.hypot(*(ring[k] - xy)) > 0.01:
            continue
        b = []
        for other in (ring[k - 1], ring[(k + 1) % len(ring)]):
            d = other - ring[k]
            b.append(np.mod(np.degrees(np.arctan2(d[0], d[1])), 180.0))
        ids.append(r["id"])
        xyz.append([float(r["x"]), float(r["y"]), float(r["z"])])
        bearing.append(b)
        angle.append(float(r["angle_deg"]))
        roof.append(r["roof"])
    return TruthRoofCorners(id=np.array(ids, dtype=object), xyz_m=np.array(xyz), bearing_deg=np.array(bearing),
                            angle_deg=np.array(angle), roof=np.array(roof, dtype=object))


def write_truth_corners_csv(project, path, sigma_xy_m: float = 0.1, sigma_z_m: float = 0.05, seed: int = 0,
                            noise: bool = False) -> None:
    """A ``corners.csv`` from the simulator truth (score 1; optional Gaussian noise with the given sigmas)."""
    t = truth_roof_corners(project)
    xyz = t.xyz_m.copy()
    if noise:
        rng = np.random.default_rng(seed)
        xyz += rng.normal(0.0, 1.0, xyz.shape) * [sigma_xy_m, sigma_xy_m, sigma_z_m]
    lines = ["id,x,y,z,sx_m,sy_m,sz_m,roof,building_id,edge1_deg,edge2_deg,angle_deg,support_pts,score,usable"]
    for k in range(len(t.id)):
        usable = int(t.roof[k] == "flat")
        lines.append(f"{t.id[k]},{xyz[k, 0]:.4f},{xyz[k, 1]:.4f},{xyz[k, 2]:.4f},{sigma_xy_m},{sigma_xy_m},{sigma_z_m},"
                     f"{t.roof[k]},0,{t.bearing_deg[k, 0]:.3f},{t.bearing_deg[k, 1]:.3f},{t.angle_deg[k]:.2f},"
                     f"100,1.0,{usable}")
    from aerotri.core.atomic import write_text_atomic

    write_text_atomic(path, "\n".join(lines) + "\n")
