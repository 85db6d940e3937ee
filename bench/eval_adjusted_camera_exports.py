"""Exports from at/camera.toml instead of report.json's 8-decimal self-calibration: how much every export changes
-> bench/results/adjusted_camera_exports.json.

``aerotri.exchange.adjusted.read_adjusted_block`` took the adjusted interior orientation (Cal3DS2 fx fy skew u0 v0
k1 k2 p1 p2) from at/report.json, rounded to 8 decimals; it now takes the camera the orientations belong to from
at/camera.toml (``aerotri.geom.camera.oriented_camera``, every digit), as every other stage does. The camera file
holds one focal length: fx and fy of the adjustment are averaged into it (``Camera.from_calibration_vector``), and
the skew (held at 0 by its prior) is 0.

For the exchange tests' block (``geometric_block(2, 5, seed=7)``, 80 tie points per frame, 5 control and 4 check
points, GNSS shift) adjusted with each self-calibration below, every export format is written from the block as
read now and from the same block with the report's ``cal`` (the code before, in one process: the only
difference between the two readings). Per file: identical or not, and the largest absolute and relative difference
of the numbers in it (text files token by token; COLMAP's binary cameras.bin by its PARAMS doubles). Files that
differ between two writes of the very same block (a GeoPackage's timestamps) are listed apart, not compared.

Usage: python bench/eval_adjusted_camera_exports.py [--out /work/tmp/eval_adjusted_camera_exports]
       [--results bench/results/adjusted_camera_exports.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import shutil
import time
from pathlib import Path

import numpy as np

CASES = {"pp_radial": ("pp", "radial"), "focal_pp_radial": ("focal", "pp", "radial"), "none": ()}
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
CAL_NAMES = ("fx_px", "fy_px", "skew_px", "u0_px", "v0_px", "k1", "k2", "p1", "p2")


def _numbers_diff(pairs) -> dict:
    """Largest absolute and relative difference of number pairs (relative to the larger; 0 for two zeros)."""
    worst_abs = worst_rel = 0.0
    n = 0
    for fa, fb in pairs:
        if fa != fb:
            n += 1
            worst_abs = max(worst_abs, abs(fa - fb))
            worst_rel = max(worst_rel, abs(fa - fb) / max(abs(fa), abs(fb)))
    return {"identical": False, "numbers_differing": n, "max_abs": worst_abs, "max_rel": worst_rel}


def _cameras_bin_params(data: bytes) -> np.ndarray:
    """The PARAMS doubles of a COLMAP cameras.bin with one camera (uint64 count; int32 id, int32 model,
    uint64 width, uint64 height, then the doubles)."""
    return np.frombuffer(data[8 + 4 + 4 + 8 + 8:], "<f8")


def _compare(path: str, a, b) -> dict:
    if a == b:
        return {"identical": True}
    if isinstance(a, bytes):
        if path.endswith("cameras.bin") and len(a) == len(b):
            return _numbers_diff(zip(_cameras_bin_params(a), _cameras_bin_params(b)))
        return {"identical": False, "note": "binary file, not compared number by number"}
    ta, tb = a.split(), b.split()
    if len(ta) != len(tb):
        return {"identical": False, "note": "token counts differ"}
    pairs = []
    for u, v in zip(ta, tb):
        if u == v:
            continue
        nu, nv = NUMBER.findall(u), NUMBER.findall(v)
        if len(nu) != len(nv) or not nu:
            return {"identical": False, "note": f"non-numeric token differs: {u!r} / {v!r}"}
        pairs += [(float(p), float(q)) for p, q in zip(nu, nv)]
    return _numbers_diff(pairs)


def run_case(name: str, groups: tuple, out: Path) -> dict:
    from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
    from aerotri.core.project import Project
    from aerotri.core.textio import read_json
    from aerotri.exchange.adjusted import read_adjusted_block
    from aerotri.exchange.registry import EXPORT_FORMATS
    from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

    block = geometric_block(2, 5, seed=7)
    root = write_block_project(block, out / name / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=4, seed=2)
    run_adjustment(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3, self_calibration=groups),
                   html=False)
    project = Project.open(root)
    now = read_adjusted_block(root)
    sc = read_json(project.adjustment_report_path, "report").get("self_calibration") or {}
    before_cal = np.array([sc["adjusted"][k] for k in CAL_NAMES], float) if sc.get("adjusted") else now.cal
    before = dataclasses.replace(now, cal=before_cal)
    files, unstable = {}, []
    for fmt, exporter in EXPORT_FORMATS.items():
        a = {f.path: f.content for f in exporter.files(now, project)}
        again = {f.path: f.content for f in exporter.files(now, project)}
        b = {f.path: f.content for f in exporter.files(before, project)}
        for path in sorted(a):
            if a[path] != again[path]:
                unstable.append(path)
            else:
                files[path] = _compare(path, b[path], a[path])
    changed = {k: v for k, v in files.items() if not v["identical"]}
    return {"self_calibration": list(groups),
            "cal_before": dict(zip(CAL_NAMES, before_cal.tolist())), "cal_now": dict(zip(CAL_NAMES, now.cal.tolist())),
            "cal_difference": dict(zip(CAL_NAMES, (now.cal - before_cal).tolist())),
            "fx_minus_fy_px_adjusted": float(before_cal[0] - before_cal[1]),
            "files": len(files), "files_identical": len(files) - len(changed), "files_changed": changed,
            "not_compared_differ_between_two_writes": unstable}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/work/tmp/eval_adjusted_camera_exports"))
    ap.add_argument("--results", type=Path, default=Path(__file__).parent / "results" / "adjusted_camera_exports.json")
    a = ap.parse_args()
    shutil.rmtree(a.out, ignore_errors=True)
    t0, c0 = time.perf_counter(), time.process_time()
    cases = {name: run_case(name, groups, a.out) for name, groups in CASES.items()}
    doc = {"command": "python bench/eval_adjusted_camera_exports.py", "cases": cases,
           "wall_s": round(time.perf_counter() - t0, 1), "cpu_s": round(time.process_time() - c0, 1)}
    a.results.write_text(json.dumps(doc, indent=2) + "\n")
    for name, c in cases.items():
        print(f"{name}: fx-fy {c['fx_minus_fy_px_adjusted']:.3g} px; {c['files_identical']} of {c['files']} files "
              f"identical (not compared: {', '.join(c['not_compared_differ_between_two_writes'])}); changed: " + ", ".join(f"{p} (max abs {v.get('max_abs', float('nan')):.3g}, rel "
                                                 f"{v.get('max_rel', float('nan')):.3g})"
                                                 for p, v in c["files_changed"].items()))
    shutil.rmtree(a.out, ignore_errors=True)


if __name__ == "__main__":
    main()
