"""Every real data set of ../shared/data run as a user runs it, with the commands of docs/your-own-block.md ->
bench/results/real_blocks.json (docs/real-blocks.md tabulates it).

Each command runs as a console command (the project's .venv), timed (wall and CPU seconds), with its exit code and
last output line kept; a command that exits otherwise than expected is recorded and the data set goes on where it
can. Then the accuracy against the set's reference:

- ngi_dmc (4 Z/I DMC frames): ``aerotri init`` (a folder of the frames: the data folder also holds dem.tif),
  ``aerotri import --format orthority`` (camera; the national AT's projection centres as GNSS, ``--as-gnss``,
  0.05 m), ``aerotri match``, ``aerotri adjust`` without and with the 24 m SUDEM as surface control (``--dem``),
  ``ortho rectify``/``mosaic``, ``aerotri report``. Reference: the national AT's omega/phi/kappa (the attitudes
  come from the images; the centres are the GNSS). Tie points against the DEM.
- tuniu_drone (4 DJI P4 RTK frames, 30 degrees oblique): init, ``import --format exif`` (RTK accuracies; the
  take-off height it states goes into ``[flight] mean_terrain_height_m``), match, adjust without and with ODM's
  surface model as surface control, ``ortho dem --min-rays 2``/rectify/mosaic, report. Reference: the OpenSfM
  reconstruction of the same frames (a peer's solution 2.2 m and 0.9 deg from the RTK positions), compared after the
  similarity between the two sets of centres (tests/realdata_tuniu.py).
- brighton_beach (18 DJI FC300S frames, consumer GNSS): init, import exif, ``[flight]`` from the import's note,
  match, ``adjust --self-cal focal,pp,radial`` (and ``pp,radial``) without a DEM; ``lidarctl classify``/``rasters``
  of the ODM point cloud; the same adjustments with its DEM and nDSM as surface control; ``ortho dem``/rectify/mosaic, report.
  Reference: tie point heights against that DEM (bench/eval_brighton.py's measure: ground tie points by the nDSM).
- copr_kite (22 kite frames, no GNSS, 10 targets): the commands of docs/blocks-without-gnss.md. Reference: the
  leave-one-out plan RMS at the targets against their own scatter about the block (at/leave_one_out.json).
- LiDAR (isprs_filtertest, ahn3_delft, autzen, lidr_topography, lidr_mixedconifer, laspy_nebraska):
  ``lidarctl classify`` and ``lidarctl evaluate --truth`` (the files' own classes; for AHN3 our classes mapped
  onto its scheme) and, for AHN3, ``lidarctl evaluate --reference`` against the 160 BGT footprints (written as a
  GeoPackage first: the data's SQLite table is no format the command reads). The truth of Autzen and lidR's
  topography is a production classification whose class 1 ("unclassified") also holds ground: their type II and
  total errors are recorded but only type I (ground points kept as ground) is a measure there.

Usage: python bench/eval_real_blocks.py [--data DIR] [--work DIR] [--only ngi,tuniu,brighton,kite,lidar]
       [--out bench/results/real_blocks.json]
A run with --only replaces those data sets in the JSON and keeps the others.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import resource
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
sys.path.insert(0, str(REPO / "bench"))

SETS = ("ngi", "tuniu", "brighton", "kite", "lidar")


def _load(name: str):
    """A tests/<name>.py helper module (the one reader of a real data set, shared with the tests)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, REPO / "tests" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


class Runner:
    """Runs one data set's commands in ``work``, recording them with ``data`` shown as DATA and ``work`` left out."""

    def __init__(self, work: Path, data: Path):
        self.work, self.data = work, data
        self.commands: list[dict] = []

    def _show(self, text: str) -> str:
        return text.replace(str(self.data), "DATA").replace(str(self.work) + "/", "").replace(str(self.work), ".")

    def run(self, *args, expect: int = 0) -> tuple[int, str]:
        args = [str(a) for a in args]
        t0 = time.perf_counter()
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        p = subprocess.run([str(BIN / args[0])] + args[1:], capture_output=True, text=True, cwd=self.work)
        wall = time.perf_counter() - t0
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        out = p.stdout + p.stderr
        lines = [ln for ln in out.splitlines() if ln.strip()]
        rec = {"command": self._show(shlex.join(args)), "exit": p.returncode, "expected_exit": expect,
               "wall_s": round(wall, 1), "cpu_s": round((c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime), 1),
               "last_line": self._show(lines[-1]) if lines else "",
               "verdict_line": next((self._show(ln) for ln in reversed(lines)
                                     if re.search(r"Solution (Successful|weak|failed)|^Error:|: (pass|fail) \(", ln)), None),
               "traceback": "Traceback" in out}
        self.commands.append(rec)
        print(f"{rec['wall_s']:7.1f} s {rec['cpu_s']:7.1f} CPU-s  exit {p.returncode}  {rec['command']}", file=sys.stderr,
              flush=True)
        if p.returncode != expect:
            print(out[-3000:], file=sys.stderr)
        return p.returncode, out

    def edit(self, what: str) -> None:
        """A step the user does by hand (an edit of project.toml, a folder of links)."""
        self.commands.append({"command": f"(by hand) {self._show(what)}", "exit": None, "expected_exit": None,
                              "wall_s": 0.0, "cpu_s": 0.0, "last_line": "", "verdict_line": None, "traceback": False})

    def summary(self) -> dict:
        run = [c for c in self.commands if c["exit"] is not None]
        return {"commands": self.commands,
                "wall_s": round(sum(c["wall_s"] for c in run), 1), "cpu_s": round(sum(c["cpu_s"] for c in run), 1),
                "unexpected_exits": [c["command"] for c in run if c["exit"] != c["expected_exit"]],
                "tracebacks": [c["command"] for c in run if c["traceback"]]}


def _key_statistics(root: Path) -> dict:
    p = root / "at" / "report.json"
    if not p.is_file():
        p = root / "work" / "adjust_failed" / "report.json"
    if not p.is_file():
        return {}
    ks = json.loads(p.read_text())["key_statistics"]
    return {k: ks.get(k) for k in ("verdict", "message", "sigma0_px", "weak_geometry", "calibration_fixed",
                                   "calibration_flagged")}


def _qa(root: Path) -> dict | None:
    p = root / "reports" / "summary.json"
    if not p.is_file():
        return None
    q = json.loads(p.read_text())
    return {"overall": q["overall"], "passed": q["passed"], "failed": q["failed"], "table": q["table"]["key"]}


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


def _add_flight_height(root: Path, height_m: float) -> None:
    with open(root / "project.toml", "a") as f:
        f.write(f"\n[flight]\nmean_terrain_height_m = {height_m}\n")


def _takeoff_height(import_output: str) -> float | None:
    m = re.search(r"\[flight\] mean_terrain_height_m = ([-0-9.]+)", import_output)
    return float(m.group(1)) if m else None


def _flight_height_from_import(r: Runner, root: Path, import_output: str) -> float | None:
    """The take-off height the EXIF import states; put into project.toml by hand only where the import did not
    (it writes ``[flight] mean_terrain_height_m`` itself since i43-gnss2: a second [flight] table is invalid TOML)."""
    import tomllib

    takeoff = _takeoff_height(import_output)
    written = tomllib.loads((root / "project.toml").read_text()).get("flight", {})
    if takeoff is not None and "mean_terrain_height_m" not in written:
        _add_flight_height(root, takeoff)
        r.edit(f"{root.name}/project.toml: [flight] mean_terrain_height_m = {takeoff:g} (the import's note)")
    return takeoff


# -- photo blocks ----------------------------------------------------------------------------------------

def eval_ngi(data: Path, work: Path) -> dict:
    import rasterio

    from aerotri.geom.eo import read_eo

    ngi = _load("realdata_ngi")
    D = data / "ngi_dmc"
    r = Runner(work, D)
    frames = work / "ngi_frames"
    frames.mkdir()
    for f in sorted(D.glob("*_RGB.tif")):
        (frames / f.name).symlink_to(f.resolve())
    prj = (D / "formats" / "ngi_xyz_opk.prj").read_text().strip()
    P = work / "ngi"
    r.run("aerotri", "init", P, "--images", D, "--crs", prj, expect=2)  # dem.tif lies beside the frames
    r.edit(f"mkdir {frames}; ln -s DATA/*_RGB.tif {frames}/")
    with rasterio.open(D / ngi.DEM_FILE) as ds:
        mean_m = round(float(ds.read(1, masked=True).mean()), 0)
    # the GNSS's and the DEM's EGM2008 heights, and the DEM's mean height for the frames' footprints (match pairs by it)
    r.run("aerotri", "init", P, "--images", frames, "--crs", prj, "--set", f"project.heights={ngi.HEIGHTS}",
          "--set", f"flight.mean_terrain_height_m={mean_m:g}")
    r.run("aerotri", "import", P, "--format", "orthority", D / "formats" / "ngi_int_param.yaml",
          D / "formats" / "ngi_xyz_opk.csv", "--as-gnss", "--sigma-xyz-m", "0.05", "0.05", "0.05")
    r.run("aerotri", "match", P)
    P0 = _copy(P, work / "ngi_nodem")
    r.run("aerotri", "adjust", P0)
    r.run("aerotri", "adjust", P, "--dem", D / ngi.DEM_FILE)
    r.run("ortho", "rectify", P, "--dem", D / ngi.DEM_FILE)
    r.run("ortho", "mosaic", P)
    r.run("aerotri", "report", P)
    ref = ngi.read_reference(D)
    acc = {}
    for name, root in (("without_dem", P0), ("dem_as_surface_control", P)):
        if not (root / "at" / "eo.txt").is_file():
            acc[name] = {"adjustment": _key_statistics(root)}
            continue
        eo = read_eo(root / "at" / "eo.txt")
        d = ngi.opk_differences(list(eo.image_id), eo.opk_deg, eo.centre_m, ref)
        _, xyz = ngi.read_object_points(root / "at" / "object_points.csv", "tie")
        h = ngi.height_stats(xyz[:, 2], ngi.sample_dem_bilinear(D / ngi.DEM_FILE, xyz[:, 0], xyz[:, 1]))
        acc[name] = {"adjustment": _key_statistics(root),
                     "opk_rms_diff_deg": round(d["opk_rms_diff_deg"], 4),
                     "omega_phi_kappa_rms_diff_deg": [round(v, 4) for v in d["omega_phi_kappa_rms_diff_deg"]],
                     "opk_max_abs_diff_deg": round(d["opk_max_abs_diff_deg"], 4),
                     "centre_rms_diff_m": round(d["centre_rms_diff_m"], 4),
                     "tie_minus_dem": {k: (round(v, 3) if isinstance(v, float) else v) for k, v in h.items()}}
    a = acc["dem_as_surface_control"]
    return r.summary() | {
        "data": "ngi_dmc", "kind": "DMC frames, GNSS (the national AT's centres), DEM",
        "reference": "the national aerial triangulation's omega/phi/kappa (camera_pos_ori.txt); the SUDEM for the tie "
                     "points' heights",
        "accuracy": acc, "report": _qa(P),
    }


def eval_tuniu(data: Path, work: Path) -> dict:
    from aerotri.geom.eo import read_eo

    tuniu = _load("realdata_tuniu")
    D = data / "tuniu_drone"
    r = Runner(work, D)
    P = work / "tuniu"
    r.run("aerotri", "init", P, "--images", D / "images", "--crs", tuniu.CRS)
    _, out = r.run("aerotri", "import", P, "--format", "exif", P / "images")
    takeoff = _flight_height_from_import(r, P, out)
    r.run("aerotri", "match", P)
    P1 = _copy(P, work / "tuniu_dsm")
    r.run("aerotri", "adjust", P)
    r.run("aerotri", "adjust", P1, "--dem", D / tuniu.DSM)
    # the oblique frames reach beyond the DSM: rectified where it covers them (90-100 %), nodata elsewhere, warned
    r.run("ortho", "rectify", P1, "--dem", D / tuniu.DSM)
    r.run("ortho", "dem", P1, "--min-rays", "2")  # a DEM to the frames' edges; 4 % of the tie points have 3 rays
    r.run("ortho", "rectify", P1, "--dem", P1 / "at" / "dem.tif")
    r.run("ortho", "mosaic", P1)
    r.run("aerotri", "report", P1)
    ref = tuniu.reference_orientations(D, work / "tuniu_opensfm")
    acc = {"gimbal_angles": tuniu.compare_with_reference(read_eo(P / "imported" / "eo.txt"), ref)}
    for name, root in (("without_surface", P), ("dsm_as_surface_control", P1)):
        acc[name] = {"adjustment": _key_statistics(root)}
        if (root / "at" / "eo.txt").is_file():
            acc[name] |= tuniu.compare_with_reference(read_eo(root / "at" / "eo.txt"), ref)
    a, b = acc["dsm_as_surface_control"], acc["without_surface"]
    return r.summary() | {
        "data": "tuniu_drone", "kind": "drone frames with EXIF (RTK), 30 deg oblique",
        "reference": "the OpenSfM reconstruction of the same frames (ODM), after the similarity between its centres "
                     "and ours (its block lies 2.2 m and 0.9 deg from the RTK positions): attitudes, and relative "
                     "rotations between frames",
        "takeoff_height_m": takeoff, "accuracy": acc, "report": _qa(P1),
    }


def eval_brighton(data: Path, work: Path) -> dict:
    from eval_brighton import tie_minus_dem

    D = data / "brighton_beach"
    r = Runner(work, D)
    P = work / "brighton"
    r.run("aerotri", "init", P, "--images", D / "images", "--crs", "EPSG:32615")
    _, out = r.run("aerotri", "import", P, "--format", "exif", P / "images")
    takeoff = _flight_height_from_import(r, P, out)
    r.run("aerotri", "match", P)
    P1 = _copy(P, work / "brighton_dem")
    P2, P3 = _copy(P, work / "brighton_nofocal"), _copy(P, work / "brighton_dem_nofocal")
    r.run("aerotri", "adjust", P, "--self-cal", "focal,pp,radial")
    r.run("aerotri", "adjust", P2, "--self-cal", "pp,radial")
    lidar = work / "brighton_lidar"
    r.run("lidarctl", "classify", D / "model.laz", lidar / "model_classified.laz")
    r.run("lidarctl", "rasters", lidar / "model_classified.laz", lidar, "--res-m", "0.5")
    r.run("aerotri", "adjust", P1, "--self-cal", "focal,pp,radial", "--dem", lidar / "dem.tif", "--ndsm",
          lidar / "ndsm.tif")
    r.run("aerotri", "adjust", P3, "--self-cal", "pp,radial", "--dem", lidar / "dem.tif", "--ndsm", lidar / "ndsm.tif")
    r.run("ortho", "dem", P1)  # the cloud covers the middle of the block only: a DEM to the frames' edges
    r.run("ortho", "rectify", P1, "--dem", P1 / "at" / "dem.tif")
    r.run("ortho", "mosaic", P1)
    r.run("aerotri", "report", P1)
    r.run("aerotri", "report", P)
    acc = {}
    for name, root in (("without_dem", P), ("without_dem_no_focal", P2), ("dem_as_surface_control", P1),
                       ("dem_no_focal", P3)):
        rep_path = root / "at" / "report.json"
        acc[name] = {"adjustment": _key_statistics(root)}
        if rep_path.is_file() and (lidar / "dem.tif").is_file():
            sc = json.loads(rep_path.read_text())["self_calibration"] or {}
            f = lambda c: round(0.5 * (c["fx_px"] + c["fy_px"]), 1)  # noqa: E731
            acc[name] |= {"focal_px": {"apriori": f(sc["apriori"]), "adjusted": f(sc["adjusted"])},
                          "fixed": sc.get("fixed"),
                          "tie_minus_dem": tie_minus_dem(root / "at" / "object_points.csv", lidar / "dem.tif",
                                                         lidar / "ndsm.tif")}
    a, b = acc["dem_as_surface_control"], acc["without_dem"]
    return r.summary() | {
        "data": "brighton_beach", "kind": "drone frames with EXIF (consumer GNSS), self-calibration",
        "reference": "the DEM of the block's OpenDroneMap point cloud (lidarctl classify + rasters; a peer's product): "
                     "ground tie points (nDSM < 1 m) against it",
        "takeoff_height_m": takeoff, "accuracy": acc, "report": _qa(P1),
    }


def eval_kite(data: Path, work: Path) -> dict:
    D = data / "copr_kite"
    r = Runner(work, D)
    P = work / "kite"
    r.run("aerotri", "init", P, "--images", D / "images", "--crs", "EPSG:32611")
    r.run("aerotri", "import", P, "--format", "odm", D / "gcp_list.txt", "--sigma-xyz-m", "1", "1", "5", expect=2)
    fixed = work / "gcp_list_fixed.txt"
    lines = (D / "gcp_list.txt").read_text().splitlines()
    fixed.write_text("\n".join(ln for ln in lines if not (ln.split()[-2:] == ["IMG_0031.jpg", "gcp04"])) + "\n")
    r.edit("grep -v -P 'IMG_0031.jpg\\tgcp04' DATA/gcp_list.txt > gcp_list_fixed.txt")
    r.run("aerotri", "import", P, "--format", "odm", fixed, "--sigma-xyz-m", "1", "1", "5")
    r.run("aerotri", "match", P)
    r.run("aerotri", "adjust", P, "--self-cal", "pp,radial", "--leave-one-out")
    r.run("ortho", "dem", P)
    r.run("ortho", "rectify", P, "--dem", P / "at" / "dem.tif", "--res-m", "0.01")
    r.run("ortho", "mosaic", P)
    r.run("aerotri", "report", P)
    acc = {"adjustment": _key_statistics(P)}
    loo_path = P / "at" / "leave_one_out.json"
    if loo_path.is_file():
        loo = json.loads(loo_path.read_text())
        sc = loo["control_scatter"]
        acc |= {"leave_one_out_rms_xy_m": loo["rms_xy_m"], "leave_one_out_rms_x_m": loo["rms_x_m"],
                "leave_one_out_rms_y_m": loo["rms_y_m"], "checked": loo["checked"],
                "targets_scatter_xy_m": sc["rms_xy_dof_corrected_m"], "targets_in_scatter": sc["n"],
                "ratio": round(loo["rms_xy_m"] / sc["rms_xy_dof_corrected_m"], 3)}
    return r.summary() | {
        "data": "copr_kite", "kind": "kite frames without GNSS, 10 plan-only targets",
        "reference": "the targets' own plan scatter about the block (all targets as control, scaled by "
                     "sqrt(n / (n - 2))): averaged handheld GNSS, no better survey in the data",
        "accuracy": acc, "report": _qa(P),
    }


# -- LiDAR -------------------------------------------------------------------------------------------------

def _filter(js: dict) -> dict:
    f = js["filter_test"]
    return {k: round(f[k], 2) for k in ("type_i_error_pct", "type_ii_error_pct", "total_error_pct", "kappa_pct")}


def eval_lidar(data: Path, work: Path) -> dict:
    from lidar_common import SAMPLES

    out = {}
    # ISPRS filter test: 7 samples, labels 2 (bare earth) / 0 (object)
    D = data / "isprs_filtertest"
    r = Runner(work, D)
    (work / "isprs").mkdir()
    samples = {}
    for s in SAMPLES:
        r.run("lidarctl", "classify", D / f"{s}-utm.laz", work / "isprs" / f"{s}.laz")
        r.run("lidarctl", "evaluate", work / "isprs" / f"{s}.laz", "--truth", D / f"{s}-utm.laz", "--json",
              work / "isprs" / f"{s}.json")
        samples[s] = _filter(json.loads((work / "isprs" / f"{s}.json").read_text()))
    mean = round(float(np.mean([v["total_error_pct"] for v in samples.values()])), 2)
    out["isprs_filtertest"] = r.summary() | {
        "kind": "LiDAR only", "reference": "ISPRS WG III/3 per-point bare-earth / object labels",
        "accuracy": {"samples": samples, "mean_total_error_pct": mean}}
    # AHN3 Delft: classes and the BGT footprints
    from eval_buildings_ahn3 import write_bgt_gpkg

    D = data / "ahn3_delft"
    r = Runner(work, D)
    (work / "ahn3").mkdir()
    cls = work / "ahn3" / "classified.laz"
    r.run("lidarctl", "classify", D / "ahn3_cropped_1.laz", cls, expect=2)  # no CRS record: never guessed
    r.run("lidarctl", "classify", D / "ahn3_cropped_1.laz", cls, "--crs", "EPSG:28992")
    r.run("lidarctl", "evaluate", cls, "--truth", D / "ahn3_cropped_1.laz", "--map-pred", "1:1,3:1,4:1,5:1,7:1,17:1,18:1",
          "--json", work / "ahn3" / "classes.json")
    bgt = work / "ahn3" / "bgt.gpkg"
    r.run("lidarctl", "evaluate", cls, "--reference", D / "bgt_pand.sqlite", "--reference-class", "building", "--crs",
          "EPSG:28992", "--within", "hull", expect=2)  # a SQLite table: no format the command reads
    write_bgt_gpkg(D / "bgt_pand.sqlite", bgt)
    r.edit("ogr2ogr -f GPKG ahn3/bgt.gpkg DATA/bgt_pand.sqlite buildingpart -a_srs EPSG:28992")
    r.run("lidarctl", "evaluate", cls, "--reference", bgt, "--reference-class", "building", "--crs", "EPSG:28992",
          "--within", "hull", "--json", work / "ahn3" / "buildings.json")
    conf = json.loads((work / "ahn3" / "classes.json").read_text())["confusion"]
    b = json.loads((work / "ahn3" / "buildings.json").read_text())["buildings"]
    comp, corr = b["completeness_area_pct"], b["correctness_area_pct"]
    f1 = round(2 * comp * corr / (comp + corr), 2)
    pa, ua = conf["producers_accuracy_pct"], conf["users_accuracy_pct"]
    out["ahn3_delft"] = r.summary() | {
        "kind": "LiDAR only", "reference": "AHN3 production classes (1, 2, 6, 9, 26); 160 surveyed BGT footprints",
        "accuracy": {"class_overall_accuracy_pct": round(conf["overall_accuracy_pct"], 2),
                     "class_kappa_pct": round(conf["kappa_pct"], 2),
                     "building_producers_users_pct": [round(pa["6"], 2), round(ua["6"], 2)],
                     "ground_producers_users_pct": [round(pa["2"], 2), round(ua["2"], 2)],
                     "footprints_completeness_area_pct": round(comp, 2), "footprints_correctness_area_pct": round(corr, 2),
                     "footprints_f1_area_pct": f1,
                     "footprints_by_count": [b["n_found"], b["n_reference"], b["n_correct"], b["n_detected"]]}}
    # the other clouds against their own classes
    for key, rel, note in (
            ("autzen", "autzen/autzen_trim.laz", "class 1 holds unlabelled ground: type I only"),
            ("lidr_topography", "lidr_topography/Topography.laz", "class 1 holds unlabelled ground: type I only"),
            ("lidr_mixedconifer", "lidr_mixedconifer/MixedConifer.laz", "class 1 is the canopy"),
            ("laspy_nebraska", "laspy_nebraska/file_with_both_wkt_and_geotiff_vlrs.las", "classes 2-7")):
        D = data / rel.split("/")[0]
        r = Runner(work, D)
        (work / key).mkdir()
        r.run("lidarctl", "classify", data / rel, work / key / "classified.laz")
        r.run("lidarctl", "evaluate", work / key / "classified.laz", "--truth", data / rel, "--json",
              work / key / "evaluate.json")
        js = json.loads((work / key / "evaluate.json").read_text())
        acc = _filter(js)
        if key == "laspy_nebraska":
            pa, ua = js["confusion"]["producers_accuracy_pct"], js["confusion"]["users_accuracy_pct"]
            acc["building_producers_users_pct"] = [round(pa["6"], 2), round(ua["6"], 2)]
        out[key] = r.summary() | {"kind": "LiDAR only", "reference": f"the file's own classes ({note})",
                                  "accuracy": acc}
    return out


def _v(x, nd=2):
    return "-" if x is None else f"{x:.{nd}f}"


def figure(key: str, e: dict) -> str:
    """The accuracy of one data set in words, from its ``accuracy`` record."""
    a = e["accuracy"]
    if key == "ngi_dmc":
        d, n = a["dem_as_surface_control"], a["without_dem"]
        return (f"omega/phi/kappa {_v(d.get('opk_rms_diff_deg'), 4)} deg RMS from the national AT with the DEM as surface "
                f"control ({_v(n.get('opk_rms_diff_deg'), 4)} without); tie points "
                f"{_v(d.get('tie_minus_dem', {}).get('median_m'))} m from the DEM ({_v(n.get('tie_minus_dem', {}).get('median_m'))} "
                "without)")
    if key == "tuniu_drone":
        d, n, g = a["dsm_as_surface_control"], a["without_surface"], a["gimbal_angles"]
        return (f"after the similarity of the centres, attitudes {_v(n.get('attitude_rms_deg'))} deg RMS from OpenSfM's "
                f"(relative rotations {_v(n.get('relative_rotation_rms_deg'))}); with ODM's DSM as surface control "
                f"{_v(d.get('attitude_rms_deg'))} ({_v(d.get('relative_rotation_rms_deg'))}); the gimbal angles "
                f"{_v(g['attitude_rms_deg'])} ({_v(g['relative_rotation_rms_deg'])})")
    if key == "brighton_beach":
        out = []
        for name, r in (("without a DEM", a["without_dem"]), ("with the DEM as surface control", a["dem_as_surface_control"])):
            f = r.get("focal_px") or {}
            focal = (f"focal {f['apriori']:.0f} px fixed" if "focal" in (r.get("fixed") or [])
                     else f"focal {f.get('apriori', 0):.0f} -> {f.get('adjusted', 0):.0f} px")
            out.append(f"{name}: {focal}, tie points {_v(r.get('tie_minus_dem', {}).get('median_m'))} m from the DEM")
        text = "--self-cal focal,pp,radial " + "; ".join(out)
        if "without_dem_no_focal" in a:
            text += (f" (--self-cal pp,radial: {_v(a['without_dem_no_focal'].get('tie_minus_dem', {}).get('median_m'))} "
                     f"and {_v(a['dem_no_focal'].get('tie_minus_dem', {}).get('median_m'))} m)")
        return text
    if key == "copr_kite":
        return (f"leave-one-out plan RMS {_v(a.get('leave_one_out_rms_xy_m'))} m at {a.get('checked')} targets against "
                f"their own scatter {_v(a.get('targets_scatter_xy_m'))} m (ratio {_v(a.get('ratio'))})")
    if key == "isprs_filtertest":
        return f"total error {a['mean_total_error_pct']:.2f} % (mean of 7 samples; CSF as published: 4.64 %)"
    if key == "ahn3_delft":
        b, g = a["building_producers_users_pct"], a["ground_producers_users_pct"]
        return (f"{a['class_overall_accuracy_pct']:.1f} % of the points in AHN3's class (buildings {b[0]:.1f} % found / "
                f"{b[1]:.1f} % right, ground {g[0]:.1f} / {g[1]:.1f}); BGT footprints F1 {a['footprints_f1_area_pct']:.1f} % "
                f"by area ({a['footprints_completeness_area_pct']:.1f} % complete, "
                f"{a['footprints_correctness_area_pct']:.1f} % correct)")
    text = f"ground points kept as ground {100 - a['type_i_error_pct']:.2f} % (type I {a['type_i_error_pct']:.2f} %)"
    if key == "lidr_mixedconifer":
        text += f", type II {a['type_ii_error_pct']:.2f} %, total {a['total_error_pct']:.2f} %"
    if "building_producers_users_pct" in a:
        b = a["building_producers_users_pct"]
        text += f"; buildings {b[0]:.1f} % found, {b[1]:.1f} % right"
    return text


ORDER = ("ngi_dmc", "tuniu_drone", "brighton_beach", "copr_kite", "isprs_filtertest", "ahn3_delft", "autzen",
         "lidr_topography", "lidr_mixedconifer", "laspy_nebraska")


def markdown_table(res: dict) -> str:
    """The table of docs/real-blocks.md from bench/results/real_blocks.json."""
    rows = ["| data set | kind | commands (exit as expected / run) | wall s (CPU s) | adjustments' verdicts, in order; report | accuracy against the reference |",
            "|---|---|---|---|---|---|"]
    for key in [k for k in ORDER if k in res["data_sets"]] + sorted(set(res["data_sets"]) - set(ORDER)):
        e = res["data_sets"][key]
        run = [c for c in e["commands"] if c["exit"] is not None]
        ok = sum(c["exit"] == c["expected_exit"] for c in run)
        verdicts = [c["verdict_line"] for c in run if c["verdict_line"] and "Solution" in c["verdict_line"]]
        outcome = " / ".join(re.search(r"Solution (Successful|weak|failed)", v).group(1) for v in verdicts)
        if not outcome:
            outcome = "exit 0" if ok == len(run) else "unexpected exits"
        if e.get("report"):
            outcome += f"; report {e['report']['overall']} ({e['report']['table']})"
        if e["tracebacks"]:
            outcome += f"; {len(e['tracebacks'])} tracebacks"
        rows.append(f"| {key} | {e['kind']} | {ok} / {len(run)} | {e['wall_s']:g} ({e['cpu_s']:g}) | {outcome} | "
                    f"{figure(key, e)} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path,
                    default=Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data")))
    ap.add_argument("--work", type=Path, default=None, help="keep the projects here (default: a temporary folder)")
    ap.add_argument("--only", default=",".join(SETS), help=f"comma-separated: {', '.join(SETS)}")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "real_blocks.json")
    ap.add_argument("--table", action="store_true", help="print the markdown table of --out and stop (no runs)")
    a = ap.parse_args(argv)
    if a.table:
        print(markdown_table(json.loads(a.out.read_text())))
        return 0
    only = [s.strip() for s in a.only.split(",") if s.strip()]
    if set(only) - set(SETS):
        ap.error(f"--only: unknown {sorted(set(only) - set(SETS))}; choose from {', '.join(SETS)}")
    if not a.data.is_dir():
        sys.exit(f"real data not found at {a.data} (set AEROTRI_SHARED_DATA or --data)")
    tmp = None
    if a.work is None:
        tmp = tempfile.TemporaryDirectory(prefix="real_blocks_")
        work = Path(tmp.name)
    else:
        work = a.work.resolve()
        work.mkdir(parents=True, exist_ok=True)
    res = json.loads(a.out.read_text()) if a.out.is_file() else {}
    res.setdefault("data_sets", {})
    res.pop("code", None)  # each data set records the commit it ran at
    runs = {"ngi": eval_ngi, "tuniu": eval_tuniu, "brighton": eval_brighton, "kite": eval_kite, "lidar": eval_lidar}
    for name in only:
        w = work / name
        if w.exists():
            shutil.rmtree(w)
        w.mkdir()
        load0 = os.getloadavg()
        got = runs[name](a.data.resolve(), w)
        entries = got if name == "lidar" else {got.pop("data"): got}
        code = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
        for key, entry in entries.items():
            entry["code"] = code.stdout.strip() or None
            entry["figure"] = figure(key, entry)
            entry["load_average_before_after"] = [[round(v, 1) for v in load0], [round(v, 1) for v in os.getloadavg()]]
            res["data_sets"][key] = entry
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(res, indent=1) + "\n")  # after each set: a long run keeps what it finished
    for key, e in res["data_sets"].items():
        e["figure"] = figure(key, e)
    res["machine_note"] = (f"{os.cpu_count()} cores shared with other jobs: wall seconds depend on the load (given per "
                           "data set); CPU seconds are the commands' own")
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    for key, e in res["data_sets"].items():
        print(f"{key}: {e['wall_s']} s ({e['cpu_s']} CPU-s); unexpected exits {len(e['unexpected_exits'])}; "
              f"{figure(key, e)}")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
