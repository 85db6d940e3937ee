"""An AT specialist's recomputation of the adjustment report's QA figures from the project's files -> bench/results/trial_at.json

For each adjusted project given (LABEL=PROJECT; only read), in numpy and written out here from docs/project.md's
conventions, not with aerotri's code:

- the tie points' image residual RMS (x, y; um and px) from at/eo.txt, at/camera.toml, at/object_points.csv and
  at/tiepoints.csv without the removed observations of report.json, as a Cartesian reader takes the map coordinates
  and with the plan offsets from each centre divided by the projection's scale factor k at the block (pyproj), against
  the report's;
- the tie points' multiplicity (rays kept per point) against object_points.csv's ``rays``; every measured observation
  as used, removed, or the unused last ray of a dropped point, against the report's counts;
- the check points' RMS and normalised RMS (d over sqrt(sigma_adjusted^2 + sigma_given^2)) from their rows;
- with truth/ (the simulator): the check points' adjusted and LiDAR-measured positions against the true roof corners
  (nearest within 1.5 m), the orientations against truth/eo.txt;
- the self-calibration's fx and fy (one focal length since trial-at) and the written camera's focal length in px.

Usage: python bench/eval_trial_at.py LABEL=PROJECT [LABEL=PROJECT ...] [--out bench/results/trial_at.json]
(the results file keeps other labels).
"""

from __future__ import annotations

import argparse
import csv
import json
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np
import pyproj


def rot(omega, phi, kappa):
    o, p, k = np.radians([omega, phi, kappa])
    rx = np.array([[1, 0, 0], [0, np.cos(o), -np.sin(o)], [0, np.sin(o), np.cos(o)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(k), -np.sin(k), 0], [np.sin(k), np.cos(k), 0], [0, 0, 1]])
    return rx @ ry @ rz


def project(cam, centre, opk, X, k=1.0):
    """Pixel (origin the centre of the top-left pixel, y down) of map points X (n, 3) through one EO line and
    camera.toml; plan offsets from the centre divided by ``k``."""
    d = X - centre
    d[:, :2] /= k
    pc = d @ rot(*opk)  # R^T (X - C): camera x right, y up, z up
    pix = cam["pixel_um"] / 1000.0
    f = cam["focal_mm"] / pix
    xn, yn = pc[:, 0] / -pc[:, 2], pc[:, 1] / pc[:, 2]  # OpenCV: y down, z forward
    r2 = xn**2 + yn**2
    rad = 1 + cam.get("k1", 0) * r2 + cam.get("k2", 0) * r2**2 + cam.get("k3", 0) * r2**3
    p1, p2 = cam.get("p1", 0), cam.get("p2", 0)
    xd = xn * rad + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn**2)
    yd = yn * rad + p1 * (r2 + 2 * yn**2) + 2 * p2 * xn * yn
    return np.column_stack([f * xd + (cam["width"] - 1) / 2 + cam.get("ppx_mm", 0) / pix,
                            f * yd + (cam["height"] - 1) / 2 - cam.get("ppy_mm", 0) / pix])


def read_eo(path):
    out = {}
    for line in Path(path).read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            s = line.split()
            out[s[0]] = np.array(s[1:7], dtype=float)
    return out


def rms(a, axis=0):
    return np.sqrt(np.nanmean(np.asarray(a, dtype=float) ** 2, axis=axis))


def evaluate(root: Path) -> dict:
    at = root / "at"
    rep = json.loads((at / "report.json").read_text())
    crs = rep["crs"]
    cam = tomllib.loads((at / "camera.toml").read_text())
    eo = read_eo(at / "eo.txt")
    op = {r["id"]: r for r in csv.DictReader(open(at / "object_points.csv"))}
    removed = {(r["point_id"], r["image_id"]) for r in rep["removed_observations"]}
    rows = list(csv.DictReader(open(at / "tiepoints.csv")))
    out = {"project": str(root), "crs_name": pyproj.CRS(crs).name, "report": {
        "tie_rms_um": [rep["image_residuals"]["tie"]["rms_x_um"], rep["image_residuals"]["tie"]["rms_y_um"]],
        "sigma0": rep["key_statistics"]["sigma0"], "sigma0_um": rep["key_statistics"]["sigma0_um"],
        "verdict": rep["key_statistics"]["verdict"], "counts": rep["counts"]}}
    kept = [r for r in rows if r["point_id"] in op and op[r["point_id"]]["kind"] == "tie"
            and (r["point_id"], r["image_id"]) not in removed]
    X = np.array([[float(op[r["point_id"]][c]) for c in "xyz"] for r in kept])
    xy = np.array([[float(r["x_px"]), float(r["y_px"])] for r in kept])
    img = np.array([r["image_id"] for r in kept])
    c = np.mean([e[:2] for e in eo.values()], axis=0)
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(*c)
    k = pyproj.Proj(crs).get_factors(lon, lat).meridional_scale
    for label, kk in (("cartesian", 1.0), ("plan_over_k", k)):
        v = np.zeros_like(xy)
        for i in set(img):
            m = img == i
            v[m] = xy[m] - project(cam, eo[i][:3], eo[i][3:], X[m], kk)
        r = rms(v)
        out[f"tie_rms_from_files_{label}"] = {"px": [round(float(x), 4) for x in r],
                                              "um": [round(float(x * cam["pixel_um"]), 3) for x in r]}
    out["k"] = round(float(k), 8)
    rays = Counter(Counter(r["point_id"] for r in kept).values())
    out["multiplicity_kept"] = {str(n): rays[n] for n in sorted(rays)}
    out["multiplicity_matches_object_points"] = rays == Counter(int(r["rays"]) for r in op.values() if r["kind"] == "tie")
    ids_tie = {r["point_id"] for r in rows} - {i for i, r in op.items() if r["kind"] != "tie"}
    out["tie_points_measured"] = len(ids_tie)
    out["tiepoints_csv_rows"] = len(rows)
    cp = rep["check_points"]
    if cp:
        d = np.array([q["d_m"] for q in cp], dtype=float)
        s = np.hypot(np.array([q["sigma_m"] for q in cp], dtype=float), np.array([q["given_sigma_m"] for q in cp],
                                                                                 dtype=float))
        out["check"] = {"n": len(cp), "rms_m": [round(float(x), 4) for x in rms(d)],
                        "plan_rms_m": round(float(np.hypot(*rms(d)[:2])), 4),
                        "normalised_rms": [round(float(x), 3) for x in rms(d / s)],
                        "report_rms_m": rep["parameters"]["rms_check_m"],
                        "report_normalised_rms": rep["check_normalised_rms"]}
        truth = root / "truth" / "roof_corners.csv"
        if truth.exists():
            tr = np.array([[float(r[c]) for c in "xyz"] for r in csv.DictReader(open(truth))])
            meas, adj = np.array([q["measured_m"] for q in cp]), np.array([q["adjusted_m"] for q in cp])
            dd = np.linalg.norm(tr[None, :, :2] - meas[:, None, :2], axis=2)
            j, ok = dd.argmin(1), dd.min(1) < 1.5
            for name, a in (("adjusted_minus_truth", adj), ("lidar_minus_truth", meas)):
                e = a[ok] - tr[j[ok]]
                out["check"][name] = {"n": int(ok.sum()), "mean_m": [round(float(x), 4) for x in e.mean(0)],
                                      "rms_m": [round(float(x), 4) for x in rms(e)],
                                      "plan_rms_m": round(float(np.hypot(*rms(e)[:2])), 4)}
    if (root / "truth" / "eo.txt").exists():
        et = read_eo(root / "truth" / "eo.txt")
        D = np.array([eo[i] - et[i] for i in sorted(et) if i in eo])
        out["eo_minus_truth"] = {"rms_xyz_m": [round(float(x), 4) for x in rms(D[:, :3])],
                                 "rms_opk_deg": [round(float(x), 5) for x in rms(D[:, 3:])]}
    sc = rep.get("self_calibration")
    if sc:
        out["self_calibration"] = {"estimated": sc["estimated"], "fx_px": sc["adjusted"]["fx_px"],
                                   "fy_px": sc["adjusted"]["fy_px"], "std_dev": sc["std_dev"],
                                   "written_focal_px": cam["focal_mm"] / (cam["pixel_um"] / 1000.0)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("projects", nargs="+", help="LABEL=PROJECT")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "trial_at.json"))
    a = ap.parse_args()
    out = Path(a.out)
    res = json.loads(out.read_text()) if out.exists() else {}
    for item in a.projects:
        label, path = item.split("=", 1)
        res[label] = evaluate(Path(path))
        r = res[label]
        print(f"{label}: report tie RMS {r['report']['tie_rms_um']} um; from the files (Cartesian) "
              f"{r['tie_rms_from_files_cartesian']['um']}, plan / k {r['tie_rms_from_files_plan_over_k']['um']} um")
    out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
