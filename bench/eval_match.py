"""Evaluate ``aerotri match``: the simulated demo block against truth, and the two real blocks.

    python bench/eval_match.py [--demo-project DIR] [--skip-real]

Writes ``bench/results/match.json`` (``--skip-real`` keeps the real blocks' entries of the last run that made them).
The demo project is simulated into out/eval/match_demo unless given.
Real blocks are set up as project folders under out/eval/ with the images linked, never copied.
"""

from __future__ import annotations

import argparse
import dataclasses
import csv
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pyproj

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.match import match_project  # noqa: E402
from aerotri.geom.images import ImageFiles, camera_from_exif, find_images  # noqa: E402
from aerotri.sim import load_preset, simulate  # noqa: E402
from aerotri.sim.evaluate import tie_point_errors  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
OUT = REPO / "out" / "eval"


def summary(report) -> dict:
    """The numbers of a ``MatchReport`` this evaluation records."""
    rep = dataclasses.asdict(report)
    keys = ("frames", "strips", "pairs", "pairs_by_kind", "pairs_with_ties", "components", "tracks", "observations",
            "tracks_3plus_fraction", "track_length_histogram", "weak_models", "weak_strip_pairs", "densified", "seconds")
    out = {k: rep[k] for k in keys}
    if rep["models"]:
        out["min_ties_in_a_von_gruber_region"] = int(min(np.min(m["regions"]) for m in rep["models"]))
        out["models"] = len(rep["models"])
    out["cross_strip_ties"] = rep["cross_strip"]
    return out


def link_project(name: str, images: ImageFiles, camera, crs: str, gnss_lines=None, terrain_m=None) -> Path:
    p = OUT / name
    if p.exists():
        shutil.rmtree(p)
    (p / "images").mkdir(parents=True)
    for src in images.path:
        (p / "images" / src.name).symlink_to(src)
    (p / "camera.toml").write_text(camera.to_toml())
    toml = f'[project]\nname = "{name}"\ncrs = "{crs}"\n'
    if terrain_m is not None:
        toml += f"\n[flight]\nmean_terrain_height_m = {terrain_m:.2f}\n"
    (p / "project.toml").write_text(toml)
    if gnss_lines:
        (p / "gnss.txt").write_text("\n".join(gnss_lines) + "\n")
    return p


def brighton() -> dict:
    d = SHARED / "brighton_beach"
    images = find_images(d / "images")
    cam = camera_from_exif(images.path[0], sensor_width_mm=6.17)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32615", always_xy=True)
    rows = list(csv.DictReader(open(d / "exif_positions.csv")))
    lines, ground = [], []
    for r in rows:
        e, n = to_utm.transform(float(r["lon"]), float(r["lat"]))
        lines.append(f"{Path(r['image']).stem} {e:.3f} {n:.3f} {float(r['abs_alt_m']):.3f} 5.0 5.0 10.0")
        ground.append(float(r["abs_alt_m"]) - float(r["rel_alt_m"]))
    p = link_project("brighton_beach", images, cam, "EPSG:32615", lines, float(np.mean(ground)))
    return summary(match_project(p))


def copr() -> dict:
    d = SHARED / "copr_kite"
    images = find_images(d / "images")
    cam = camera_from_exif(images.path[0])
    p = link_project("copr_kite", images, cam, "EPSG:32611")
    return summary(match_project(p))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--demo-project", type=Path)
    ap.add_argument("--skip-real", action="store_true")
    args = ap.parse_args()
    results = {}
    proj = args.demo_project
    if proj is None:
        proj = OUT / "match_demo"
        if not (proj / "truth" / "truth.json").exists():
            simulate(load_preset("demo"), proj, force=True)
    t = time.perf_counter()
    rep = match_project(proj)
    res = summary(rep)
    res["truth_check"] = dataclasses.asdict(tie_point_errors(proj))
    res["wall_s"] = round(time.perf_counter() - t, 1)
    results["demo"] = res
    print(json.dumps(res["truth_check"]), flush=True)
    if not args.skip_real and SHARED.is_dir():
        results["brighton_beach"] = brighton()
        results["copr_kite"] = copr()
    (REPO / "bench" / "results").mkdir(exist_ok=True)
    path = REPO / "bench" / "results" / "match.json"
    if args.skip_real and path.exists():
        results = json.loads(path.read_text()) | results
    path.write_text(json.dumps(results, indent=1) + "\n")
    for k, v in results.items():
        print(f"{k}: frames {v['frames']} pairs {v['pairs']} components {v['components']} tracks {v['tracks']} "
              f"observations {v['observations']} 3+ rays {100 * v['tracks_3plus_fraction']:.1f} %")


if __name__ == "__main__":
    main()
