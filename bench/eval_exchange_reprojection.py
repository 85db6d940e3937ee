"""Do the exported models put the adjusted points where the adjustment does? -> bench/results/exchange_reprojection.json

For each adjusted project given, the block is exported (colmap, colmap-bin, odm, metashape, patb) into a temporary
folder (the project is only read) and a random sample of the tie-point measurements is projected:

- ``reference``: at/eo.txt (PATB omega phi kappa: camera x right, y up, z back -> the grid axes at the centre) and
  at/camera.toml (focal, principal point with y up, pixel-centre origin, OpenCV Brown on normalised coordinates),
  written out here with pyproj (map -> ECEF; the grid axes at each centre by differences), not aerotri's code;
- COLMAP text and binary through pycolmap (``Image.project_point``, the world frame from georef.txt), minus 0.5 px;
- OpenSfM ``reconstruction.json`` by OpenSfM's documented conventions (topocentric at reference_lla, axis-angle
  world -> camera, brown normalised by max(width, height), pixel (0, 0) at the centre of the top-left pixel);
- Metashape ``cameras.xml`` by its manual (chunk transform to ECEF, camera transform camera -> chunk, cx cy from
  the image centre, P1 / P2 swapped against OpenCV, pixel (0.5, 0.5) at the centre of the top-left pixel);
- PAT-B ``block.ori`` and ``block.im`` as a Cartesian PAT-B reader takes them (map coordinates), and with the plan
  offsets divided by the projection's scale factor at the block.

Reported: the largest and RMS difference of each model's projection from the reference (px), the reference's RMS
against the measurements, PAT-B's RMS against its own ``.im``. ``--k3 K --p1 P --p2 P`` first copy the project's
files with these put into camera.toml and at/camera.toml (an export test only: the orientations do not fit them).

Usage: python bench/eval_exchange_reprojection.py LABEL=PROJECT [LABEL=PROJECT ...] [--k3 0.05 --p1 0.002 --p2 -0.001]
       [--sample 500] [--out bench/results/exchange_reprojection.json]  (the results file keeps other labels)
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import shutil
import tempfile
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pyproj
from scipy.spatial.transform import Rotation

from aerotri.exchange import export_project

FORMATS = ["colmap", "colmap-bin", "odm", "metashape", "patb"]
TO_ECEF = {}


def ecef(crs: str, p) -> np.ndarray:
    t = TO_ECEF.setdefault(crs, pyproj.Transformer.from_crs(crs, "EPSG:4978", always_xy=True))
    p = np.atleast_2d(np.asarray(p, float))
    return np.stack(t.transform(p[:, 0], p[:, 1], p[:, 2]), -1)


def enu_axes(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Rows: east, north, up in ECEF."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return np.array([[-np.sin(lo), np.cos(lo), 0], [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                     [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])


def brown(x, y, k1, k2, k3, p1, p2):
    """OpenCV: p1 with 2xy in x, p2 with r2 + 2x2 in x."""
    r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y


def opk_matrix(o, p, k):
    o, p, k = np.radians([o, p, k])
    rx = np.array([[1, 0, 0], [0, np.cos(o), -np.sin(o)], [0, np.sin(o), np.cos(o)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(k), -np.sin(k), 0], [np.sin(k), np.cos(k), 0], [0, 0, 1]])
    return rx @ ry @ rz


def read_eo(path) -> dict:
    rows = (line.split() for line in open(path))
    return {f[0]: np.array(f[1:7], float) for f in rows if f and not f[0].startswith("#")}


def reference_px(crs, cam, eo, X):
    """The adjustment's projection of map point X into the frame of eo (X Y Z omega phi kappa)."""
    C = eo[:3]
    c0 = ecef(crs, C)[0]
    g = [ecef(crs, C + d)[0] - c0 for d in np.eye(3)]
    G = np.stack([v / np.linalg.norm(v) for v in g], 1)  # grid axes at C (columns) in ECEF
    d = (ecef(crs, X)[0] - c0) @ (G @ opk_matrix(*eo[3:]))  # photo frame
    f = cam["focal_mm"] / cam["pixel_um"] * 1000
    cx = (cam["width"] - 1) / 2 + cam["ppx_mm"] / cam["pixel_um"] * 1000
    cy = (cam["height"] - 1) / 2 - cam["ppy_mm"] / cam["pixel_um"] * 1000
    xd, yd = brown(d[0] / -d[2], -d[1] / -d[2], *(cam.get(k, 0.0) for k in ("k1", "k2", "k3", "p1", "p2")))
    return np.array([f * xd + cx, f * yd + cy])


def colmap_px(folder: Path, crs, keys, pts):
    import pycolmap

    rec = pycolmap.Reconstruction(str(folder))
    by_id = {im.name.rsplit(".", 1)[0]: im for im in rec.images.values()}
    origin = next([float(v) for v in line.split()[1:4]] for line in open(folder / "georef.txt")
                  if line.startswith("origin_map"))
    c0 = ecef(crs, origin)[0]
    lon, lat, _ = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*c0)
    R = enu_axes(lat, lon)
    return np.array([np.asarray(by_id[i].project_point((ecef(crs, pts[p])[0] - c0) @ R.T)) - 0.5 for p, i in keys])


def opensfm_px(path: Path, crs, keys, pts):
    rj = json.loads(path.read_text())[0]
    ref = rj["reference_lla"]
    e0 = np.array(pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
                  .transform(ref["longitude"], ref["latitude"], ref["altitude"]))
    R_t = enu_axes(ref["latitude"], ref["longitude"])
    (c,) = rj["cameras"].values()
    W, H = c["width"], c["height"]
    S = max(W, H)
    shots = {k.rsplit(".", 1)[0]: v for k, v in rj["shots"].items()}
    out = []
    for p, i in keys:
        s = shots[i]
        x = Rotation.from_rotvec(s["rotation"]).as_matrix() @ ((ecef(crs, pts[p])[0] - e0) @ R_t.T) + s["translation"]
        xd, yd = brown(x[0] / x[2], x[1] / x[2], c["k1"], c["k2"], c.get("k3", 0.0), c["p1"], c["p2"])
        out.append([(c["focal_x"] * xd + c["c_x"]) * S - 0.5 + W / 2, (c["focal_y"] * yd + c["c_y"]) * S - 0.5 + H / 2])
    return np.array(out)


def metashape_px(path: Path, crs, keys, pts):
    ch = ET.parse(path).getroot().find("chunk")
    cal = ch.find("sensors/sensor/calibration")
    g = {k: float(cal.find(k).text) if cal.find(k) is not None else 0.0 for k in ("f", "cx", "cy", "k1", "k2", "k3", "p1", "p2")}
    W, H = int(cal.find("resolution").get("width")), int(cal.find("resolution").get("height"))
    T = ch.find("transform")
    Rc = np.array(T.find("rotation").text.split(), float).reshape(3, 3)
    tc, sc = np.array(T.find("translation").text.split(), float), float(T.find("scale").text)
    cams = {c.get("label"): np.linalg.inv(np.array(c.find("transform").text.split(), float).reshape(4, 4))
            for c in ch.findall("cameras/camera")}
    out = []
    for p, i in keys:
        xc = cams[i] @ np.append(Rc.T @ (ecef(crs, pts[p])[0] - tc) / sc, 1.0)
        x, y = xc[0] / xc[2], xc[1] / xc[2]
        # Metashape's P1 goes with r2 + 2x2 in x (OpenCV's p2): brown() with the two swapped
        xd, yd = brown(x, y, g["k1"], g["k2"], g["k3"], g["p2"], g["p1"])
        out.append([W / 2 + g["cx"] + g["f"] * xd - 0.5, H / 2 + g["cy"] + g["f"] * yd - 0.5])
    return np.array(out)


def patb_residuals_um(folder: Path, cam, pts, k_plan: float):
    """RMS (um) of .im against .ori's projection of the adjusted points (photo x right, y up, mm)."""
    num = {}
    for line in open(folder / "numbers.txt"):
        f = line.split()
        if f and f[0] == "point":
            num[int(f[1])] = f[2]
    lines = [s for s in (folder / "block.ori").read_text().splitlines() if s.strip()]
    ori = {int(lines[n].split()[0]): (np.array(lines[n].split()[-3:], float),
                                      np.array(lines[n + 1].split() + lines[n + 2].split(), float).reshape(3, 3))
           for n in range(0, len(lines), 3)}
    c, res, photo = cam["focal_mm"], [], None
    for line in open(folder / "block.im"):
        f = line.split()
        if len(f) == 1:
            photo = None if f[0] == "-99" else int(f[0])
        elif len(f) == 3 and photo is not None and num.get(int(f[0])) in pts:
            C, a = ori[photo]
            D = pts[num[int(f[0])]] - C
            D[:2] /= k_plan
            q = a.T @ D
            res.append([-c * q[0] / q[2] - float(f[1]), -c * q[1] / q[2] - float(f[2])])
    return float(np.sqrt(np.mean(np.square(res)))) * 1000, len(res)


def _stats(d) -> dict:
    d = np.asarray(d)
    return {"rms_px": round(float(np.sqrt(np.mean(d ** 2))), 5), "max_px": round(float(np.abs(d).max()), 5)}


def measure(root: Path, sample: int, lens: dict) -> dict:
    with tempfile.TemporaryDirectory(prefix="xreproj-") as tmp:
        if lens:  # a copy with the lens terms put into both cameras
            src, root = root, Path(tmp) / "p"
            root.mkdir()
            for name in ("project.toml", "camera.toml", "control"):
                if (src / name).exists():
                    (shutil.copytree if (src / name).is_dir() else shutil.copy)(src / name, root / name)
            (root / "images").symlink_to((src / "images").resolve())
            shutil.copytree(src / "at", root / "at", ignore=lambda d, names: [n for n in names if (Path(d) / n).is_dir()])
            for cam in (root / "camera.toml", root / "at" / "camera.toml"):
                text = cam.read_text()
                for k, v in lens.items():
                    text = re.sub(rf"(?m)^{k} = .*$", f"{k} = {v!r}", text)
                cam.write_text(text)
        out = Path(tmp) / "out"
        export_project(root, FORMATS, out)
        crs = tomllib.loads((root / "project.toml").read_text())["project"]["crs"]
        cam = tomllib.loads((root / "at" / "camera.toml").read_text())
        eo = read_eo(root / "at" / "eo.txt")
        pts = {r["id"]: np.array([float(r[k]) for k in "xyz"]) for r in csv.DictReader(open(root / "at" / "object_points.csv"))}
        obs = [r for r in csv.DictReader(open(root / "at" / "tiepoints.csv")) if r["point_id"] in pts and r["image_id"] in eo]
        pick = np.random.default_rng(0).choice(len(obs), min(sample, len(obs)), replace=False)
        keys = [(obs[k]["point_id"], obs[k]["image_id"]) for k in pick]
        meas = np.array([[float(obs[k]["x_px"]), float(obs[k]["y_px"])] for k in pick])
        ref = np.array([reference_px(crs, cam, eo[i], pts[p]) for p, i in keys])
        res = {"measurements": len(keys), "reference_minus_measured": _stats(ref - meas), "lens": lens or None}
        res["colmap"] = _stats(colmap_px(out / "colmap", crs, keys, pts) - ref)
        res["colmap_bin"] = _stats(colmap_px(out / "colmap_bin", crs, keys, pts) - ref)
        res["opensfm"] = _stats(opensfm_px(out / "odm" / "opensfm" / "reconstruction.json", crs, keys, pts) - ref)
        res["metashape"] = _stats(metashape_px(out / "metashape" / "cameras.xml", crs, keys, pts) - ref)
        centre = np.mean([e[:3] for e in eo.values()], axis=0)
        p = pyproj.Proj(crs)
        k = float(p.get_factors(*p(centre[0], centre[1], inverse=True)).meridional_scale)
        as_map, n = patb_residuals_um(out / "patb", cam, pts, 1.0)
        scaled, _ = patb_residuals_um(out / "patb", cam, pts, k)
        res["patb"] = {"im_observations": n, "scale_factor": round(k, 8),
                       "rms_um_as_cartesian": round(as_map, 3), "rms_px_as_cartesian": round(as_map / cam["pixel_um"], 4),
                       "rms_um_plan_over_k": round(scaled, 3), "rms_px_plan_over_k": round(scaled / cam["pixel_um"], 4)}
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("projects", nargs="+", help="LABEL=PROJECT (an adjusted project folder; only read)")
    ap.add_argument("--sample", type=int, default=500)
    ap.add_argument("--k3", type=float)
    ap.add_argument("--p1", type=float)
    ap.add_argument("--p2", type=float)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "exchange_reprojection.json")
    a = ap.parse_args()
    lens = {k: v for k, v in (("k3", a.k3), ("p1", a.p1), ("p2", a.p2)) if v is not None}
    results = json.loads(a.out.read_text()) if a.out.is_file() else {}
    for item in a.projects:
        label, _, path = item.partition("=")
        results[label] = measure(Path(path), a.sample, lens)
        print(label, json.dumps(results[label]))
    a.out.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
