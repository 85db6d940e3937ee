"""The rectifier on the earth against the flat collinearity, on a simulated full-size DMC frame (issue 42).

Issue 42's small full-size block (``docs/true-ortho.md``) was 1.9 GSD RMS off its truth ortho on open ground, and its
roofs 0.74-0.87 px south on average, with the TRUE orientations. The cause: the simulator renders a UTM block as a
camera over the earth sees it (``aerotri.sim.earth``) and the adjustment solves in the ENU frame, while
``ortho.rectify`` took easting, northing and height as a Cartesian frame: ground 400 ppm too near each nadir (UTM's
scale factor 0.99963 at the presets' origin and (R + h) / R), 2.8 px 700 m from it at 0.1 m GSD, radial, north-south
across a strip flown east-west.

One frame of such a project rectified in this process twice with its true orientation and camera onto the 0.5 m DEM
(a conventional ortho: open ground only, occlusion plays no part): ``flat`` (``rectify_frame(earth=False)``: the
rectifier before) and ``earth`` (now). Each against ``truth/ortho.tif`` on open ground (``ortho.check.
check_against_reference`` with the nDSM below 0.5 m: the DOM check's row), and the displacements fitted as a radial
scale about the nadir, ``d = s (p - nadir) + t`` (ppm). ``predicted_flat``: the displacement the flat mapping makes
at each patch by the geometry alone (the ground point whose exact image position, ``CameraOnEarth.to_camera``, is
where the flat mapping samples); ``flat_minus_predicted``: what is left of the flat figures when it is taken off.

Make the project (about 100 CPU-s, 0.9 GB; frames identical to the block of ``bench/results/true_ortho_roofs.json``
``dmc_3_frames_*``):
  aerotri sim DIR --preset dmc_block --set flight.strips=1 --set flight.frames_per_strip=3 \\
      --set truth.raster_res_m=0.1 --set lidar.pulse_rate_hz=10000
and its 0.5 m DEM and nDSM (every fifth cell of truth/dem.tif and dsm.tif from the third: the cell centres of 0.5 m).
Usage: python bench/eval_ortho_earth.py --project DIR --dem DEM_0.5 --ndsm NDSM_0.5 --work SCRATCH
       [--frames s01_002|all|ID,ID] [--eo truth/eo.txt] [--camera truth/camera.toml] [--res-m 0.1] [--key ...]
       [--out bench/results/true_ortho_roofs.json]
The demo with its adjusted orientation (the chain's at/eo.txt and at/camera.toml, its LiDAR DEM and nDSM; every
frame; a copy of /work/ref/demo_chain/project): ``--project DIR --dem DIR/lidar_out/dem.tif --ndsm
DIR/lidar_out/ndsm.tif --frames all --eo at/eo.txt --camera at/camera.toml --res-m 0.4 --key demo_adjusted_eo_...``.
The figures pool the patches of every frame's whole ortho (before a mosaic keeps each cell's nadir-most frame).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from bench.results_json import store_result  # noqa: E402


def stats(dx_px, dy_px) -> dict:
    d = np.hypot(dx_px, dy_px)
    return {"count": int(len(d)), "rms_gsd": float(np.sqrt(np.mean(d ** 2))), "median_gsd": float(np.median(d)),
            "p90_gsd": float(np.percentile(d, 90)), "max_gsd": float(d.max()),
            "mean_dx_dy_px": [float(np.mean(dx_px)), float(np.mean(dy_px))],
            "rms_dx_dy_px": [float(np.sqrt(np.mean(dx_px ** 2))), float(np.sqrt(np.mean(dy_px ** 2)))]}


def radial_fit(x_m, y_m, de_m, dn_m, nadir) -> dict:
    """Least squares of (dE, dN) = s (x - nadir) + (tE, tN): the scale in ppm and the shift in metres (``nadir``
    (2,) or the nadir of each point's frame (N, 2))."""
    nadir = np.broadcast_to(np.asarray(nadir, float), (len(x_m), 2))
    ox, oy = x_m - nadir[:, 0], y_m - nadir[:, 1]
    n = len(x_m)
    A = np.zeros((2 * n, 3))
    A[:n, 0], A[n:, 0] = ox, oy
    A[:n, 1] = A[n:, 2] = 1.0
    sol, *_ = np.linalg.lstsq(A, np.concatenate([de_m, dn_m]), rcond=None)
    return {"scale_ppm": float(sol[0] * 1e6), "shift_e_n_m": [float(sol[1]), float(sol[2])]}


def predicted_flat(cam, C, R, earth, x_m, y_m, z_m, res_m):
    """DOM minus truth (dx, dy px) the flat mapping makes at ground points: the content at P is that of P' whose
    exact image position is the flat one of P (two Newton steps, horizontal)."""
    def exact(P):
        v = earth.to_camera(P)
        return np.stack(cam.normalized_to_pixel(v[:, 0] / v[:, 2], v[:, 1] / v[:, 2]), axis=-1)

    P = np.stack([x_m, y_m, z_m], axis=-1)
    target = np.stack(cam.project(P, C, R)[:2], axis=-1)
    Q = P.copy()
    for _ in range(2):
        q = exact(Q)
        J = np.stack([(exact(Q + [h, 0, 0]) - exact(Q - [h, 0, 0])) / (2 * h) for h in (1.0,)]
                     + [(exact(Q + [0, 1.0, 0]) - exact(Q - [0, 1.0, 0])) / 2.0], axis=-1)
        Q[:, :2] += np.linalg.solve(J, (target - q)[..., None])[..., 0]
    d = P - Q
    return d[:, 0] / res_m, -d[:, 1] / res_m


def rectify_to(path: Path, image, cam, C, R, dem, grid, earth: bool) -> float:
    import rasterio
    from rasterio.windows import Window

    from ortho.block import frame_profile
    from ortho.rectify import rectify_frame

    c0 = time.process_time()
    bands = 1 if image.ndim == 2 else image.shape[2]  # in the frame's channel order: the check takes their mean
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), \
            rasterio.open(path, "w", **frame_profile(grid, bands, image.dtype.name)) as dst:
        def sink(r0, c0_, o, m):
            w = Window(c0_, r0, m.shape[1], m.shape[0])
            dst.write(o, window=w, indexes=list(range(1, bands + 1)))
            dst.write_mask(m, window=w)

        rectify_frame(image, cam, C, R, dem, grid, sink=sink, sink_bands_first=True, earth=earth)
    return time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, required=True)
    ap.add_argument("--dem", type=Path, required=True)
    ap.add_argument("--ndsm", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True, help="scratch folder for the frame orthos")
    ap.add_argument("--frames", default="s01_002", help="image ids, comma-separated, or 'all'")
    ap.add_argument("--eo", default="truth/eo.txt", help="orientations, relative to the project")
    ap.add_argument("--camera", default="truth/camera.toml", help="the camera of --eo, relative to the project")
    ap.add_argument("--res-m", type=float, default=0.1, help="the orthos' cell (the frames' GSD)")
    ap.add_argument("--key", default="dmc_1_frame_true_eo_open_ground_flat_vs_earth")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_roofs.json")
    args = ap.parse_args()
    t0, cpu0 = time.perf_counter(), time.process_time()

    import rasterio

    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.eo import read_eo
    from aerotri.geom.images import read_native
    from aerotri.geom.local_frame import CameraOnEarth
    from ortho.check import check_against_reference
    from ortho.dem import open_height_raster, read_height_window
    from ortho.grid import GridToProject
    from ortho.rectify import WINDOWED_FRAME_BYTES, FrameFile, frame_grid

    p = args.project
    eo = read_eo(p / args.eo)
    cam = BrownCamera.read(p / args.camera)
    frames = eo.image_id if args.frames == "all" else args.frames.split(",")
    with open_height_raster(args.dem, None) as ds:  # nodata as NaN
        dem, crs = read_height_window(ds, tuple(ds.bounds)), ds.crs
    result = {"project": str(p), "eo": args.eo, "camera": args.camera, "frames": list(frames), "res_m": args.res_m,
              "dem": str(args.dem), "ndsm": str(args.ndsm), "earth_ppm_note": "scale_ppm > 0: the DOM's ground moved "
              "away from the nadir (the flat mapping samples the frame too near its principal point)"}
    args.work.mkdir(parents=True, exist_ok=True)
    found = {"flat": [], "earth": []}  # per frame: dx, dy px, x, y m, nadir, predicted dx, dy (flat)
    cpu = {"flat": [0.0, 0.0], "earth": [0.0, 0.0]}
    for iid in frames:
        k = eo.row(iid)
        C, R = eo.centre_m[k], eo.rotation(k)
        grid = frame_grid(cam, C, R, dem, args.res_m, crs, to_project=GridToProject(crs, crs), image_id=iid,
                          partial=True)
        path = p / "images" / f"{iid}.tif"
        with rasterio.open(path) as ds:
            big = ds.width * ds.height * ds.count * np.dtype(ds.dtypes[0]).itemsize > WINDOWED_FRAME_BYTES
        image = FrameFile(path) if big else read_native(path, (cam.width, cam.height))[0]
        for name, on_earth in (("flat", False), ("earth", True)):
            out = args.work / f"{iid}_{name}.tif"
            cpu[name][0] += rectify_to(out, image, cam, C, R, dem, grid, on_earth)
            c1 = time.process_time()
            pd, _ = check_against_reference(out, p / "truth" / "ortho.tif", args.ndsm)
            cpu[name][1] += time.process_time() - c1
            x = grid.x_left_m + (pd.col_px + 0.5) * grid.res_m
            y = grid.y_top_m - (pd.row_px + 0.5) * grid.res_m
            pred = predicted_flat(cam, C, R, CameraOnEarth(crs, C, R), x, y, dem.sample(x, y), grid.res_m) \
                if name == "flat" else (np.zeros(0), np.zeros(0))
            found[name].append((pd.dx_px, pd.dy_px, x, y, np.tile(C[:2], (len(x), 1)), *pred))
        if isinstance(image, FrameFile):
            image.close()
    cat = {name: [np.concatenate(a) for a in zip(*rows)] for name, rows in found.items()}
    for name in ("flat", "earth"):
        dx, dy, x, y, nadir = cat[name][:5]
        result[name] = {"open_ground": stats(dx, dy),
                        "radial_fit": radial_fit(x, y, dx * args.res_m, -dy * args.res_m, nadir),
                        "rectify_cpu_s": round(cpu[name][0], 1), "check_cpu_s": round(cpu[name][1], 1)}
        print(name, json.dumps(result[name]), flush=True)
    dx, dy, x, y, nadir, px, py = cat["flat"]
    result["predicted_flat"] = stats(px, py)
    result["predicted_flat"]["radial_fit"] = radial_fit(x, y, px * args.res_m, -py * args.res_m, nadir)
    result["flat_minus_predicted"] = stats(dx - px, dy - py)
    result["cpu_s"] = round(time.process_time() - cpu0, 1)
    result["wall_s"] = round(time.perf_counter() - t0, 1)
    result["load_avg_1min_at_end"] = os.getloadavg()[0]
    result["command"] = "python bench/eval_ortho_earth.py " + " ".join(sys.argv[1:])
    result["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                      text=True).stdout.strip()
    print(json.dumps(result, indent=1))
    store_result(args.out, result, key=args.key)


if __name__ == "__main__":
    main()
