"""Visible ground the true ortho masks on slopes (issue 42, slope-occlusion): a project's true orthos against its
conventional ones made on the same heights (a DEM given as the DSM too: no building, so every pixel the true ortho
masks should be hidden by the terrain itself).

Per frame: the conventional ortho's valid pixels the true ortho masks, and of up to ``--sample`` of them (seeded) how
many an independent march finds hidden: 4,000 steps from the ground point (its bilinear height) to the projection
centre over the bilinear DSM (scipy's map_coordinates, order 1), the first 3 m left out, hidden where the surface
rises above the line of sight anywhere (as /work/tmp/trial-ortho/raymarch.py of the operator trial).

    python bench/eval_slope_occlusion.py --conventional P_CONV --true P_TRUE --dsm DSM [--eo P/imported/eo.txt]
        [--key KEY] [--out bench/results/slope_occlusion.json]

(``P_CONV``, ``P_TRUE``: projects rectified by ``ortho rectify P --dem DEM`` and ``... --true-ortho --dsm DEM``.)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, store_result  # noqa: E402


def main() -> None:
    import rasterio
    from scipy.ndimage import map_coordinates

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conventional", type=Path, required=True)
    ap.add_argument("--true", type=Path, required=True)
    ap.add_argument("--dsm", type=Path, required=True)
    ap.add_argument("--eo", type=Path, help="image_id X Y Z ... (default: CONVENTIONAL/imported/eo.txt)")
    ap.add_argument("--sample", type=int, default=3000)
    ap.add_argument("--key", default=None)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "slope_occlusion.json")
    a = ap.parse_args()
    eo_path = a.eo or a.conventional / "imported" / "eo.txt"
    eo = {ln.split()[0]: [float(v) for v in ln.split()[1:4]] for ln in eo_path.read_text().splitlines()
          if ln.strip() and not ln.startswith("#")}
    with rasterio.open(a.dsm) as s:
        Z, T = s.read(1).astype(float), s.transform

    def height(x, y):
        return map_coordinates(Z, [(y - T.f) / T.e - 0.5, (x - T.c) / T.a - 0.5], order=1, mode="nearest")

    rng = np.random.default_rng(0)
    frames = {}
    for f in sorted(eo):
        with rasterio.open(a.conventional / "ortho" / "frames" / f"{f}.tif") as ca, \
                rasterio.open(a.true / "ortho" / "frames" / f"{f}.tif") as tr:
            seen, kept, tf = ca.dataset_mask() > 0, tr.dataset_mask() > 0, ca.transform
        r, c = np.nonzero(seen & ~kept)
        k = rng.choice(len(r), min(a.sample, len(r)), replace=False) if len(r) else np.zeros(0, int)
        x, y = tf.c + (c[k] + 0.5) * tf.a, tf.f + (r[k] + 0.5) * tf.e
        z, C = height(x, y), eo[f]
        d = np.hypot(C[0] - x, C[1] - y)
        worst = np.full(len(x), -np.inf)
        for t in np.linspace(0.0, 1.0, 4001)[1:]:
            e = height(x + t * (C[0] - x), y + t * (C[1] - y)) - (z + t * (C[2] - z))
            worst = np.where(t * d > 3.0, np.maximum(worst, e), worst)
        frames[f] = {"valid_conventional": int(seen.sum()), "masked": int(len(r)),
                     "masked_share": round(len(r) / max(int(seen.sum()), 1), 5), "sampled": int(len(k)),
                     "sampled_hidden_by_the_march": int((worst > 0.0).sum())}
        print(f, frames[f], flush=True)
    store_result(a.out, {"frames": frames, "commit": git_commit(REPO), "conventional": str(a.conventional),
                         "true": str(a.true), "dsm": str(a.dsm),
                         "command": "python bench/eval_slope_occlusion.py " + " ".join(sys.argv[1:])}, key=a.key)
    print("wrote", a.out)


if __name__ == "__main__":
    main()
