"""offsets-fixes (review of i42-offsets): what the fixes change, measured in one process ->
bench/results/offsets_fixes.json.

- ``demo`` (a copy of the demo project made by `make demo` on main before i42-offsets, its ortho/mosaic.tif and
  mosaic.json kept as the reference): the default mosaic (gains only) now, and with the gains' pair weights of
  i42-offsets (cells instead of sqrt(cells)^2, patched in this process): the gains against the reference's to the bit,
  and the decoded mosaic's samples and mask (sha256) against the reference's.
- ``brighton`` (a copy of the ortho trial's rectified Brighton project) with offsets: the frames and bands whose offset
  is at +-``OFFSET_MAX_SHARE`` x white, the warnings of frames and bands held (``held_messages``; before offsets-fixes
  none), the free fit's offsets of those held.
- ``synthetic_haze``: the 2 x 3 synthetic block of tests/ortho/test_colour_offsets.py (seed 11) with 12 DN added to
  every other frame, offsets: hazy - clear mean offset (the truth -12), independent of the demo_haze block the spreads'
  weight was chosen on.

Nothing is tuned. Usage: python bench/check_offsets_fixes.py --demo PROJECT --brighton PROJECT [--work DIR]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import rasterio

import ortho.mosaic as om
from ortho.settings import MosaicSettings
from ortho.synthetic import write_synthetic_project

SKIP = shutil.ignore_patterns("images", "lidar", "truth", "reports", "work")


class _Warnings(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def _decoded_sha256(path) -> str:
    with rasterio.open(path) as ds:
        return hashlib.sha256(ds.read().tobytes() + ds.read_masks(1).tobytes()).hexdigest()


def _mosaic(root, **settings):
    handler = _Warnings()
    om.logger.addHandler(handler)
    try:
        om.mosaic_block(root, MosaicSettings(**settings))
    finally:
        om.logger.removeHandler(handler)
    return json.loads((Path(root) / "ortho" / "mosaic.json").read_text()), handler.messages


def demo(project: Path, work: Path) -> dict:
    ref_summary = json.loads((project / "ortho" / "mosaic.json").read_text())
    ref_sha = _decoded_sha256(project / "ortho" / "mosaic.tif")
    out = {"reference_blend_rules": ref_summary.get("blend_rules"), "reference_sha256": ref_sha}
    cells_weights = property(lambda self: self.cells.astype(float))  # i42-offsets' weights
    for run, patch in (("offsets_fixes", None), ("i42_offsets_weights", cells_weights)):
        root = work / f"demo_{run}"
        shutil.rmtree(root, ignore_errors=True)
        shutil.copytree(project, root, ignore=SKIP)
        saved = om.OverlapPairs.row_weights2
        if patch is not None:
            om.OverlapPairs.row_weights2 = patch
        try:
            summary, _ = _mosaic(root)
        finally:
            om.OverlapPairs.row_weights2 = saved
        diff = max(abs(a - b) for n, g in ref_summary["gains"].items() for a, b in zip(g, summary["gains"][n]))
        out[run] = {"gains_bit_identical": summary["gains"] == ref_summary["gains"], "gains_max_abs_diff": diff,
                    "mosaic_decoded_identical": _decoded_sha256(root / "ortho" / "mosaic.tif") == ref_sha}
        shutil.rmtree(root)
    return out


def brighton(project: Path, work: Path) -> dict:
    root = work / "brighton"
    shutil.rmtree(root, ignore_errors=True)
    shutil.copytree(project, root, ignore=SKIP)
    summary, warnings = _mosaic(root, offsets=True)
    offs = np.array(list(summary["offsets"].values()))
    bound = om.OFFSET_MAX_SHARE * 255
    held = [w for w in warnings if "held at its" in w]
    asked = [float(re.search(r"asked gain [-+.\d]+, offset ([-+.\d]+) DN", w).group(1)) for w in held
             if ": offset " in w]
    shutil.rmtree(root)
    return {"offsets": int(offs.size), "offsets_at_bound": int((np.abs(np.abs(offs) - bound) < 1e-6).sum()),
            "held_warnings": len(held), "held_offsets_lower": sum("lower bound" in w for w in held),
            "held_offsets_upper": sum("upper bound" in w for w in held),
            "held_gains": sum("held at its cap" in w for w in held),
            "free_offsets_asked_of_held_dn": [min(asked), max(asked)] if asked else None,
            "example": held[0] if held else None}


def synthetic_haze(work: Path, haze_dn: int = 12) -> dict:
    root = work / "haze"
    shutil.rmtree(root, ignore_errors=True)
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=11)
    hazy = ["s01_002", "s02_001", "s02_003"]
    for name in hazy:
        p = root / "images" / f"{name}.tif"
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.int32)
        cv2.imwrite(str(p), np.clip(img + haze_dn, 0, 254).astype(np.uint8))
    from ortho.block import rectify_block

    rectify_block(root)
    summary, _ = _mosaic(root, seams="voronoi", offsets=True)
    names = list(summary["gains"])
    offs = np.array([summary["offsets"][n] for n in names])
    is_hazy = np.array([n in hazy for n in names])
    shutil.rmtree(root)
    return {"haze_dn": haze_dn, "hazy_minus_clear_dn": float(offs[is_hazy].mean() - offs[~is_hazy].mean()),
            "per_band_dn": [float(v) for v in offs[is_hazy].mean(axis=0) - offs[~is_hazy].mean(axis=0)]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, required=True)
    ap.add_argument("--brighton", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("/tmp/offsets_fixes"))
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "offsets_fixes.json")
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    result = {"demo": demo(a.demo, a.work), "brighton": brighton(a.brighton, a.work),
              "synthetic_haze": synthetic_haze(a.work)}
    tmp = a.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    tmp.replace(a.out)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
