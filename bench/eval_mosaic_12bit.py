"""12-bit data in 16-bit frames (issue 42, the DMC's): the mosaic's saturated share against its frames' with the
saturation counted at the type's maximum (65535: before) and at the frames' white level (4095: now), on a tiny
simulated block -> bench/results/mosaic_12bit_saturation.json.

The block: ``aerotri sim --preset tiny --set render.bits=12 --set render.exposure_sigma=<sigma>`` (6 frames of
432 x 240 px, exposure changed from frame to frame so that the balance has gains to make), its frames rectified on
the truth DEM with the truth EO (``ortho rectify --eo truth/eo.txt --dem truth/dem.tif``; the adjustment is not what
is measured), then ``ortho mosaic --seams voronoi`` twice in this process: once with the white level forced to the
type's maximum (``ortho.mosaic.white_level`` replaced: what the code did before), once as it is. Per run: the share
of the valid pixels of the mosaic with a band at or above 4095, the samples above 4095, the largest sample, the
gains lowered (the warnings), against the frame orthos' largest share.

Usage: python bench/eval_mosaic_12bit.py [--work DIR] [--sigma 0.3] [--seed N]
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import rasterio

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

WHITE_12 = 4095


def shares(path: Path) -> dict:
    with rasterio.open(path) as ds:
        a, ok = ds.read(), ds.read_masks(1) > 0
    v = a[:, ok]
    return {"valid_px": int(ok.sum()), "saturated_share": float((v >= WHITE_12).any(axis=0).mean()),
            "samples_above_4095": int(np.count_nonzero(v > WHITE_12)), "max_sample": int(v.max())}


def mosaic_run(root: Path, forced_type_max: bool) -> dict:
    from click.testing import CliRunner

    import ortho.mosaic as m
    from ortho.cli import main

    lowered = []

    class Catch(logging.Handler):
        def emit(self, record):
            if "lowered" in record.getMessage():
                lowered.append(record.getMessage())

    h = Catch()
    logging.getLogger("ortho").addHandler(h)
    real = m.white_level
    if forced_type_max:
        m.white_level = lambda dtype, nbits, maxima: m.WhiteLevel(int(np.iinfo(dtype).max), "type (forced)")
    try:
        r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi"])
    finally:
        m.white_level = real
        logging.getLogger("ortho").removeHandler(h)
    assert r.exit_code == 0, r.output
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    return {"white_level": {k: v for k, v in summary["white_level"].items() if k != "saturated_share_frames"},
            "gains_lowered": len(lowered), "lowered": lowered,
            "gains": summary["gains"], "mosaic": shares(root / "ortho" / "mosaic.tif")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/eval_mosaic_12bit"))
    ap.add_argument("--sigma", type=float, default=0.3)
    ap.add_argument("--seed", type=int, default=None)
    args = ap.parse_args()
    root = args.work / "block"
    exe = Path(sys.executable).parent
    sim = [str(exe / "aerotri"), "sim", str(root), "--preset", "tiny", "--force", "--set", "render.bits=12",
           "--set", f"render.exposure_sigma={args.sigma}"] + (["--seed", str(args.seed)] if args.seed is not None else [])
    subprocess.run(sim, check=True, capture_output=True)
    subprocess.run([str(exe / "ortho"), "rectify", str(root), "--eo", str(root / "truth" / "eo.txt"), "--dem",
                    str(root / "truth" / "dem.tif")], check=True, capture_output=True)
    frames = {p.stem: shares(p) for p in sorted((root / "ortho" / "frames").glob("*.tif"))}
    res = {"command": " ".join(["python bench/eval_mosaic_12bit.py", f"--sigma {args.sigma}"]
                               + ([f"--seed {args.seed}"] if args.seed is not None else [])),
           "sim": " ".join(sim[1:]).replace(str(root), "<work>/block"), "frames": frames,
           "frames_saturated_share_max": max(f["saturated_share"] for f in frames.values()),
           "before_type_max": mosaic_run(root, True), "now_white_level": mosaic_run(root, False)}
    out = REPO / "bench" / "results" / "mosaic_12bit_saturation.json"
    out.write_text(json.dumps(res, indent=1) + "\n")
    for k in ("before_type_max", "now_white_level"):
        r = res[k]
        print(f"{k}: white {r['white_level']['value']} ({r['white_level']['from']}), gains lowered {r['gains_lowered']}, "
              f"mosaic saturated {100 * r['mosaic']['saturated_share']:.3f} % (frames max "
              f"{100 * res['frames_saturated_share_max']:.3f} %), samples > 4095: {r['mosaic']['samples_above_4095']}, "
              f"max {r['mosaic']['max_sample']}")
    shutil.rmtree(args.work, ignore_errors=True)


if __name__ == "__main__":
    main()
