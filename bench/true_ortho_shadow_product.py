"""The LiDAR's shadow at the DEM in the product (issue 42, i42-shadow): a project's rasters and crowns made again
by the product's CLIs (``lidarctl rasters`` then ``lidarctl crowns``, what the chain's rasters stage runs) from its
classified strips into a scratch folder, compared with the project's own (made before the rule) and with the
i42-fill2 trial's lowered occlusion DSM (``bench/true_ortho_empty_cells_trial.py``'s
``dsm_crowns_empty_at_dem.tif``, made from the project's dsm_crowns.tif):

    python bench/true_ortho_shadow_product.py --project PROJECT --trial TRIAL_TIF --work DIR [--key shadow_product]

The project is only read. Writes ``bench/results/true_ortho_fill.json`` key ``--key`` (per ``--block``): which
rasters equal the project's (every one but dsm_nearest.tif and dsm_crowns.tif should), the cells lowered, and
whether dsm_crowns.tif equals the trial's cell for cell (then the trial's fill, ghosts and roofs measured on it,
key ``fill_causes10``, are the product's), and the cells dsm_crowns.tif would keep higher without the DEM given to
the crowns (``write_crown_model`` without ``dem_path``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
RESULTS = REPO / "bench" / "results" / "true_ortho_fill.json"


def _read(path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--project", type=Path, required=True)
    ap.add_argument("--trial", type=Path, required=True, help="the trial's dsm_crowns_empty_at_dem.tif")
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--block", default="demo")
    ap.add_argument("--res-m", default="0.5")
    ap.add_argument("--key", default="shadow_product")
    a = ap.parse_args()
    lo = a.project / "lidar_out"
    strips = sorted(str(p) for p in (lo / "classified").glob("*.la[sz]"))
    if not strips:
        raise SystemExit(f"{lo / 'classified'}: no classified strips")
    out = a.work / a.block / "product"
    out.mkdir(parents=True, exist_ok=True)
    bin_ = Path(sys.executable).parent
    t0 = time.perf_counter()
    subprocess.run([str(bin_ / "lidarctl"), "rasters", *strips, str(out), "--res-m", a.res_m, "-q"], check=True)
    t1 = time.perf_counter()
    subprocess.run([str(bin_ / "lidarctl"), "crowns", *strips, str(out)], check=True, stdout=subprocess.DEVNULL)
    t2 = time.perf_counter()
    rec = {"strips": len(strips), "rasters_wall_s": round(t1 - t0, 1), "crowns_wall_s": round(t2 - t1, 1)}
    for name in ("dem", "dsm", "ndsm", "chm", "intensity"):
        (x, tx), (y, ty) = _read(out / f"{name}.tif"), _read(lo / f"{name}.tif")
        rec[f"{name}_equal_to_the_project"] = bool(tx == ty and np.array_equal(x, y, equal_nan=True))
    new, _ = _read(out / "dsm_nearest.tif")
    old, _ = _read(lo / "dsm_nearest.tif")
    dem, _ = _read(out / "dem.tif")
    ch = new != old
    rec.update(cells=int(new.size), dsm_nearest_lowered=int(ch.sum()),
               dsm_nearest_lowered_all_to_the_dem=bool(((new[ch] == dem[ch]) & (new[ch] < old[ch])).all()),
               dsm_nearest_lowered_by_more_than_2m=int((ch & (old - new > 2)).sum()))
    (crowns, tc), (trial, tt) = _read(out / "dsm_crowns.tif"), _read(a.trial)
    before, _ = _read(lo / "dsm_crowns.tif")
    rec.update(dsm_crowns_lowered=int((crowns != before).sum()),
               dsm_crowns_cells_differing_from_the_trial=int((crowns != trial).sum()),
               dsm_crowns_equal_to_the_trial=bool(tc == tt and np.array_equal(crowns, trial)))
    # the crowns without their second lowering (dsm_nearest.tif lowered, no DEM given)
    from lidarctl.rasters.crown_model import write_crown_model

    nodem = a.work / a.block / "crowns_without_the_dem"
    nodem.mkdir(parents=True, exist_ok=True)
    _, tif = write_crown_model([Path(p) for p in strips], out / "dsm_nearest.tif", nodem)
    plain, _ = _read(tif)
    rec.update(dsm_crowns_without_the_dem_cells_differing=int((plain != crowns).sum()),
               dsm_crowns_without_the_dem_cells_higher_by_more_than_2m=int((plain - crowns > 2).sum()))
    print(json.dumps(rec, indent=1))
    doc = json.loads(RESULTS.read_text())
    entry = doc.setdefault(a.key, {"note": __doc__.split("\n\n")[0].replace("\n", " "), "blocks": {}})
    entry["blocks"][a.block] = {"project": str(a.project), "trial": str(a.trial), **rec}
    RESULTS.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
