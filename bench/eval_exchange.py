"""Round trips of the exchange formats -> bench/results/exchange_roundtrip.json.

- ``simulated``: small geometric blocks (2 strips x 5 frames, seeds 7 and 11) adjusted with self-calibration,
  exported (odm, patb, colmap, orthority, metashape) and imported into fresh projects. Reported per format: the
  largest difference of the imported orientations from at/eo.txt (centre m, rotation degrees) through the
  files, and for OpenSfM also in memory (before eo.txt's 0.1 mm / 1e-7 degree rounding); the RMS of OpenSfM's
  own projection (its documented brown model and topocentric frame, written out here with pyproj) of the
  exported points against the measurements, next to the adjustment's residual RMS.
- ``tuniu`` (needs ../shared/data/tuniu_drone): ODM's reconstruction imported and written again with its
  reference point: shot centre and rotation differences (from the files and in memory) and the largest
  difference of OpenSfM's projection of the ODM surface model's points (inside each frame's field of view)
  through the original and the written reconstruction.

Usage: python bench/eval_exchange.py [--data ../shared/data] [--out bench/results/exchange_roundtrip.json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from pyproj import CRS, Transformer
from scipy.spatial.transform import Rotation

from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
from aerotri.core.project import Project
from aerotri.exchange import ImportSettings, export_project, import_files, opensfm
from aerotri.exchange.adjusted import read_adjusted_block
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SIGMA_PX = 0.3
FILES = {"odm": ("opensfm", ["odm/opensfm/reconstruction.json"]),
         "patb": ("patb", ["patb/block.ori", "patb/block.cam", "patb/numbers.txt"]),
         "colmap": ("colmap", ["colmap"]),
         "orthority": ("orthority", ["orthority/int_param.yaml", "orthority/ext_param.csv"]),
         "metashape": ("metashape", ["metashape/cameras.xml"])}


def rotation_deg(Ra, Rb) -> np.ndarray:
    return np.degrees(Rotation.from_matrix(np.swapaxes(Ra, -1, -2) @ Rb).magnitude())


def topocentric(xyz_map, crs, ref) -> np.ndarray:
    ecef = np.column_stack(Transformer.from_crs(CRS(crs).to_3d(), CRS("EPSG:4978"), always_xy=True).transform(*xyz_map.T))
    ecef0 = np.array(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(
        ref["longitude"], ref["latitude"], ref["altitude"]))
    la, lo = np.radians(ref["latitude"]), np.radians(ref["longitude"])
    R = np.array([[-np.sin(lo), np.cos(lo), 0], [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                  [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])
    return (ecef - ecef0) @ R.T


def opensfm_pixels(cam, shot, X):
    R = Rotation.from_rotvec(shot["rotation"]).as_matrix()
    p = X @ R.T + np.array(shot["translation"])
    xn, yn = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    r2 = xn ** 2 + yn ** 2
    rad = 1 + r2 * (cam["k1"] + r2 * (cam["k2"] + r2 * cam["k3"]))
    xd = xn * rad + 2 * cam["p1"] * xn * yn + cam["p2"] * (r2 + 2 * xn ** 2)
    yd = yn * rad + cam["p1"] * (r2 + 2 * yn ** 2) + 2 * cam["p2"] * xn * yn
    s = max(cam["width"], cam["height"])
    return np.column_stack([(cam["focal_x"] * xd + cam["c_x"]) * s + (cam["width"] - 1) / 2,
                            (cam["focal_y"] * yd + cam["c_y"]) * s + (cam["height"] - 1) / 2])


def simulated(seed: int, work: Path) -> dict:
    import csv

    root = write_block_project(geometric_block(2, 5, seed=seed), work / f"blk{seed}")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=5, points_per_image=80, n_check=4, seed=2)
    ba = run_adjustment(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX,
                                                self_calibration=("pp", "radial"))).adjustment
    out = work / f"exp{seed}"
    export_project(root, list(FILES), out)
    eo = read_eo(root / "at" / "eo.txt")
    row = {}
    for name, (fmt, files) in FILES.items():
        dst = work / f"imp{seed}_{name}"
        dst.mkdir()
        shutil.copy(root / "project.toml", dst / "project.toml")
        import_files(dst, fmt, [out / f for f in files])
        back = read_eo(dst / "imported" / "eo.txt")
        row[name] = {"files_centre_max_m": float(np.abs(back.centre_m - eo.centre_m).max()),
                     "files_rotation_max_deg": float(rotation_deg(back.rotations(), eo.rotations()).max())}
    block = opensfm.read([out / "odm/opensfm/reconstruction.json"], Project.open(work / f"imp{seed}_odm"),
                         ImportSettings())
    row["odm"]["memory_centre_max_m"] = float(np.abs(block.eo.centre_m - eo.centre_m).max())
    row["odm"]["memory_rotation_max_deg"] = float(rotation_deg(block.eo.rotations(), eo.rotations()).max())
    (rec,) = json.loads((out / "odm/opensfm/reconstruction.json").read_text())
    (cam,) = rec["cameras"].values()
    blk = read_adjusted_block(root)
    rows = list(csv.DictReader(open(root / "at" / "object_points.csv")))
    topo = dict(zip((r["id"] for r in rows), topocentric(np.array([[float(r[k]) for k in "xyz"] for r in rows]),
                                                         blk.crs, rec["reference_lla"])))
    res = [opensfm_pixels(cam, rec["shots"][iid], np.array([topo[str(blk.point_id[j])] for j in blk.obs_point[k]]))
           - blk.obs_xy_px[k] for i, iid in enumerate(blk.image_id) for k in [np.flatnonzero(blk.obs_image == i)]]
    row["odm"]["opensfm_reprojection_rms_px"] = float(np.sqrt(np.mean(np.vstack(res) ** 2)))
    row["odm"]["adjustment_residual_rms_px"] = float(np.sqrt(np.mean(ba.result.residual_px[ba.result.obs_active] ** 2)))
    return row


def tuniu(data: Path, work: Path) -> dict:
    import rasterio

    src = data / "tuniu_drone" / "opensfm" / "reconstruction.json"
    (orig,) = json.loads(src.read_text())
    root = work / "tuniu"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "tuniu"\ncrs = "EPSG:32651"\n')
    shutil.copytree(data / "tuniu_drone" / "images", root / "images")
    import_files(root, "opensfm", [src])
    project = Project.open(root)
    eo, cam = read_eo(root / "imported" / "eo.txt"), read_camera(root / "camera.toml")
    with rasterio.open(data / "tuniu_drone" / "odm_dem" / "dsm.tif") as ds:
        z = ds.read(1, masked=True)
        rr, cc = np.mgrid[0:ds.height:9, 0:ds.width:9]
        ok = ~np.ma.getmaskarray(z)[rr, cc]
        xs, ys = rasterio.transform.xy(ds.transform, rr[ok], cc[ok])
        ground = topocentric(np.column_stack([xs, ys, z[rr, cc][ok].filled(np.nan)]), "EPSG:32651",
                             orig["reference_lla"])
    xc, yc = cam.pixel_to_normalized(np.array([-0.5, cam.width - 0.5] * 2), np.repeat([-0.5, cam.height - 0.5], 2))
    r_max = float(np.hypot(xc, yc).max())
    out = {}
    block = opensfm.read([src], project, ImportSettings())
    for label, again in (("files", opensfm.reconstruction(eo, cam, project, orig["reference_lla"])),
                         ("memory", opensfm.reconstruction(block.eo, block.camera, project, orig["reference_lla"]))):
        (c0,), (c1,) = orig["cameras"].values(), again["cameras"].values()
        dc, dr, dpx = [], [], []
        for sid, s0 in orig["shots"].items():
            s1 = again["shots"][sid]
            R0, R1 = (Rotation.from_rotvec(s["rotation"]).as_matrix() for s in (s0, s1))
            C0, C1 = -R0.T @ np.array(s0["translation"]), -R1.T @ np.array(s1["translation"])
            dc.append(np.abs(C1 - C0).max())
            dr.append(rotation_deg(R0[None], R1[None])[0])
            d = (ground - C0) @ R0.T
            seen = (d[:, 2] > 0) & (np.hypot(d[:, 0], d[:, 1]) < r_max * d[:, 2])
            dpx.append(np.abs(opensfm_pixels(c1, s1, ground) - opensfm_pixels(c0, s0, ground))[seen].max())
        out[label] = {"shot_centre_max_m": float(max(dc)), "shot_rotation_max_deg": float(max(dr)),
                      "dsm_projection_max_px": float(max(dpx)),
                      "camera_max_rel": float(max(abs(c1[k] - c0[k]) / max(abs(c0[k]), 1e-12) for k in c0
                                                  if not isinstance(c0[k], str)))}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("AEROTRI_SHARED_DATA", "../shared/data")))
    ap.add_argument("--out", type=Path, default=Path("bench/results/exchange_roundtrip.json"))
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="eval-exchange-") as tmp:
        work = Path(tmp)
        result = {"simulated": {f"seed_{s}": simulated(s, work) for s in (7, 11)}}
        if (a.data / "tuniu_drone").is_dir():
            result["tuniu"] = tuniu(a.data, work)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
