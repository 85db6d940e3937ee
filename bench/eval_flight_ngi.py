"""Flight acceptance of the NGI block (4 real Z/I DMC frames, 2 strips) -> bench/results/flight_ngi.json.

Reads ../shared/data/ngi_dmc directly: the national AT's orientations (``camera_pos_ori.txt``, and the
same in ``formats/ngi_xyz_opk.csv`` as a cross-check), the interior orientation
(``formats/ngi_int_param.yaml``: pinhole, f = 120 mm, sensor 92.16 x 165.888 mm, 640 x 1152 px) and the
24 m SUDEM (``dem.tif``, EGM2008 heights as the orientations), then runs
``aerotri.adjust.flight_acceptance`` with the thesis's limits (tolerance table 1:5000) and prints the
table. The frames are a subset of the flight (``..._05_0182`` and ``_0184``: every second exposure), so
the forward overlap between them is not the flight's.

Usage: python bench/eval_flight_ngi.py [--data ../shared/data/ngi_dmc] [--results bench/results/flight_ngi.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import csv
import json
import os
import re
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.adjust.flight_acceptance import LIMIT_KEYS, Terrain, flight_acceptance  # noqa: E402
from aerotri.core.tolerances import load_table  # noqa: E402
from aerotri.geom.camera import PinholeCamera  # noqa: E402
from aerotri.geom.eo import read_eo  # noqa: E402


def ngi_camera(path: Path) -> PinholeCamera:
    """The pinhole camera of orthority's interior-parameter YAML (one camera; sizes in mm and px)."""
    text = path.read_text()

    def nums(key):
        m = re.search(rf"^\s*{key}:\s*\[?([^\]\n]+)\]?", text, re.M)
        if not m:
            raise SystemExit(f"{path}: no {key}")
        return [float(v) for v in m.group(1).split(",")]

    (w, h), (f,), (sw, _sh) = nums("im_size"), nums("focal_len"), nums("sensor_size")
    return PinholeCamera(focal_mm=f, pixel_um=sw * 1000.0 / w, width=int(w), height=int(h), name="NGI DMC (1/12)")


def opk_csv(path: Path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return ([r["filename"] for r in rows], np.array([[float(r[k]) for k in ("x", "y", "z")] for r in rows]),
            np.array([[float(r[k]) for k in ("omega", "phi", "kappa")] for r in rows]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
                    / "ngi_dmc")
    ap.add_argument("--results", type=Path, default=REPO / "bench" / "results" / "flight_ngi.json")
    a = ap.parse_args(argv)
    if not (a.data / "camera_pos_ori.txt").is_file():
        print(f"skip: {a.data} not found")
        return 0
    cam = ngi_camera(a.data / "formats" / "ngi_int_param.yaml")
    eo = read_eo(a.data / "camera_pos_ori.txt")
    terrain = Terrain.from_dem(a.data / "dem.tif")
    limits = {k: v for k, v in load_table("1:5000", "flat").limits.items() if k in LIMIT_KEYS}
    order = np.argsort(eo.image_id)
    ids = [eo.image_id[i] for i in order]
    fa = flight_acceptance(ids, eo.centre_m[order], eo.opk_deg[order], cam, terrain, None, limits=limits)
    # the same from the OPK CSV (3 decimals): the file's precision moves nothing that matters
    cids, cc, copk = opk_csv(a.data / "formats" / "ngi_xyz_opk.csv")
    corder = np.argsort(cids)
    fb = flight_acceptance([cids[i] for i in corder], cc[corder], copk[corder], cam, terrain, None, limits=limits)
    diff = max(abs((x["value"] or 0) - (y["value"] or 0)) for x, y in zip(fa.checks, fb.checks))
    out = dataclasses.asdict(fa)
    for f in out["frames"]:
        f.pop("footprint")
    out.update(data=str(a.data), camera=cam.to_dict(), dem_mean_height_m=round(terrain.mean_height_m, 2),
               opk_csv_max_check_difference=round(diff, 3),
               note="2 frames per strip, every second exposure of the flight: forward overlap of the pair, not "
                    "of the flight")
    a.results.parent.mkdir(parents=True, exist_ok=True)
    a.results.write_text(json.dumps(out, indent=1) + "\n")
    print(f"{'check':48} {'worst':>8} {'limit':>7} {'unit':5} {'at':30} verdict")
    for c in fa.checks:
        print(f"{c['quantity']:48} {'' if c['value'] is None else c['value']:>8} {c['limit']:>7g} {c['unit']:5} "
              f"{c['where']:30} {c['verdict'] or 'not measured'}")
    print(f"{'image':30} {'strip':>5} {'Z m':>9} {'AGL m':>7} {'tilt':>6} {'kappa':>6} {'fwd %':>6} {'side %':>6}")
    for f in fa.frames:
        print(f"{f['image_id']:30} {f['strip']:5d} {f['z_m']:9.1f} {f['height_above_ground_m']:7.1f} "
              f"{f['tilt_deg']:6.2f} {f['kappa_deviation_deg']:6.2f} {f['forward_overlap_pct'] or '':>6} "
              f"{f['side_overlap_pct'] or '':>6}")
    print(f"OPK CSV instead of camera_pos_ori.txt: largest difference of a check value {diff:.3f}")
    print(f"wrote {a.results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
