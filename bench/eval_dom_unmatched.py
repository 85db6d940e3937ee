"""The DOM check's unmatched textured patches (``ortho.check.unmatched_patches``) as made and with the DOM, or one
frame's region of it, moved by whole pixels in a scratch copy: the share of the textured patches that found no match,
in all and by frame region (ortho/seams.tif), with the RMS of the patches matched.

    nice .venv/bin/python bench/eval_dom_unmatched.py PROJECT --key K [--as-made] [--shift=FRAME:DX,DY ...]

FRAME "-" moves the whole DOM; the results go into bench/results/dom_unmatched.json under K (its cases replaced, the
others kept). The reference and nDSM are those the project's ortho/dom_report.json names.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ortho.check import (DOM_MAX_UNMATCHED_SHARE, DOM_MIN_REGION_PATCHES, check_against_reference,  # noqa: E402
                         displacement_statistics, frame_regions, unmatched_patches)


def shifted_copy(root: Path, frame: str, dx: int, dy: int, out: Path) -> Path:
    """The project's mosaic with its content moved ``dx`` px right and ``dy`` px down, in all (``frame`` "-") or
    only inside ``frame``'s region of ortho/seams.tif."""
    import rasterio

    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        profile, img, mask = ds.profile, ds.read(), ds.dataset_mask()
        transform = ds.transform
    moved = np.roll(img, (dy, dx), axis=(1, 2))
    moved_mask = np.roll(mask, (dy, dx), axis=(0, 1))
    if frame != "-":
        region = frame_regions(root, root / "ortho" / "mosaic.tif")
        rows, cols = np.mgrid[0:img.shape[1], 0:img.shape[2]]
        at = (np.asarray(region(rows.ravel(), cols.ravel()), dtype=object) == frame).reshape(img.shape[1:])
        moved = np.where(at[None], moved, img)
        moved_mask = np.where(at, moved_mask, mask)
    profile.update(driver="GTiff", tiled=True, compress="deflate")
    profile.pop("photometric", None)
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(moved)
        dst.write_mask(moved_mask)
    assert dst.transform == transform
    return out


def measure(root: Path, dom: Path, reference: str, ndsm: str | None, label: str) -> dict:
    t0 = time.time()
    p, _ = check_against_reference(dom, reference, ndsm, 0.5, patch_px=48, step_px=48, search_px=6)
    u = unmatched_patches(p, min_ncc=0.7, search_px=6, region_of=frame_regions(root, root / "ortho" / "mosaic.tif"))
    stats = displacement_statistics(p.de_m, p.dn_m, p.res_m)
    worst = max((r for r in u.per_region if r.textured >= u.min_region_patches), key=lambda r: r.unmatched_share,
                default=None)
    return dict(case=label, matched=len(p), unmatched=u.patches, textured=u.textured,
                share=None if u.share is None else round(u.share, 4),
                rms_xy_m=None if stats.rms_xy_m is None else round(stats.rms_xy_m, 4),
                worst_region=None if worst is None else dict(name=worst.name, textured=worst.textured,
                                                             unmatched=worst.unmatched,
                                                             share=round(worst.unmatched_share, 4)),
                regions=[dict(name=r.name, textured=r.textured, unmatched=r.unmatched) for r in u.per_region],
                fails=u.fails(), lost=[r.name for r in u.lost_regions()], seconds=round(time.time() - t0, 1))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("project", type=Path)
    ap.add_argument("--shift", action="append", default=[], help="FRAME:DX,DY (FRAME - : the whole DOM)")
    ap.add_argument("--as-made", action="store_true")
    ap.add_argument("--key", required=True)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "dom_unmatched.json")
    a = ap.parse_args()
    root = a.project
    rep = json.loads((root / "ortho" / "dom_report.json").read_text())
    fix = lambda p: str(p) if Path(p).is_absolute() or Path(p).exists() else str(root.parents[2] / p)
    reference, ndsm = fix(rep["reference"]), fix(rep["ndsm"]) if rep.get("ndsm") else None
    results = []
    if a.as_made:
        results.append(measure(root, root / "ortho" / "mosaic.tif", reference, ndsm, "as made"))
        print(json.dumps({k: v for k, v in results[-1].items() if k != "regions"}), flush=True)
    with tempfile.TemporaryDirectory(dir="/work/tmp") as tmp:
        for spec in a.shift:
            frame, d = spec.split(":")
            dx, dy = (int(v) for v in d.split(","))
            dom = shifted_copy(root, frame, dx, dy, Path(tmp) / "mosaic.tif")
            results.append(measure(root, dom, reference, ndsm, f"{frame} dx={dx} dy={dy}"))
            print(json.dumps({k: v for k, v in results[-1].items() if k != "regions"}), flush=True)
    doc = json.loads(a.out.read_text()) if a.out.is_file() else {}
    old = {r["case"]: r for r in (doc.get(a.key) or {}).get("results", [])}
    old.update({r["case"]: r for r in results})
    doc[a.key] = dict(project=str(root), max_share=DOM_MAX_UNMATCHED_SHARE, min_region_patches=DOM_MIN_REGION_PATCHES,
                      results=list(old.values()))
    a.out.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
