"""Issue 41/42: the DOM check's roofs with corners whose evidence lies in the DOM's nodata counted as not measurable
(``ortho.check.roof_evidence_in_nodata``), on a chain run's mosaic against the simulator's truth. The DOM was made
with the adjusted orientation and the LiDAR DSM: a roof displacement beyond 1 m is a wrong match.

    python bench/roof_corners_in_nodata.py --run B/dmc_block_subset_2x2_run_d0d98f7 \\
        --truth B/dmc_block_subset_2x2/truth --key dmc_2x2
(writes bench/results/roof_corners_in_nodata.json, the key's entry replaced)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from aerotri.core.atomic import write_text_atomic
from aerotri.core.resources import measure
from ortho.check import measure_roof_patches, read_roof_corners

OUT = Path(__file__).parent / "results" / "roof_corners_in_nodata.json"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", required=True, help="chain run folder (ortho/mosaic.tif)")
    ap.add_argument("--dom", default=None, help="the DOM (default RUN/ortho/mosaic.tif)")
    ap.add_argument("--truth", required=True, help="the simulator's truth folder (ortho.tif, roof_corners.csv)")
    ap.add_argument("--key", required=True)
    a = ap.parse_args()
    dom = a.dom or f"{a.run}/ortho/mosaic.tif"
    x, y = read_roof_corners(f"{a.truth}/roof_corners.csv")
    with measure() as use:
        r = measure_roof_patches(dom, f"{a.truth}/ortho.tif", x, y)
    before = json.loads(Path(f"{a.run}/ortho/dom_report.json").read_text()).get("roofs", {})
    res = before.get("gsd_m", 0.1)
    e = np.hypot(r.de_m, r.dn_m)
    row = dict(dom=str(dom), truth=str(a.truth), corners=r.corners, measured=int(e.size),
               outside_or_invalid=r.outside_or_invalid, weak=r.weak, in_nodata=r.in_nodata,
               rms_xy_gsd=float(np.sqrt(np.mean(e ** 2)) / res), median_xy_gsd=float(np.median(e) / res),
               max_xy_m=float(e.max()), beyond_1m=int((e > 1.0).sum()),
               beyond_1m_corners=[[round(float(a), 3), round(float(b), 3), round(float(c), 3)]
                                  for a, b, c in zip(r.x_m[e > 1.0], r.y_m[e > 1.0], e[e > 1.0])],
               before=dict(count=before.get("count"), rms_xy_gsd=before.get("rms_xy_gsd"),
                           median_xy_gsd=before.get("median_xy_gsd"), max_xy_m=before.get("max_xy_m"),
                           not_measured=before.get("not_measured")),
               usage=use.record(), load_avg=list(np.round(__import__("os").getloadavg(), 2)),
               date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()))
    print(json.dumps(row, indent=1))
    results = json.loads(OUT.read_text()) if OUT.is_file() else {}
    results[a.key] = row
    write_text_atomic(OUT, json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
