"""The seam rows of the accuracy report on a run: the block RMS and the worst seam, as measured and with one frame's
ortho moved by a known shift.

``ortho.mosaic.seam_misalignment`` on the run as it is, then once per ``--shift FRAME:DX:DY``, with that frame's
ortho read ``DX`` columns and ``DY`` rows off (every window ``seam_misalignment`` reads of it moved: what the seams
see of a frame whose orientation put it that many pixels off). Per pass: the block's patches and RMS (px), the patches
left out below the texture floor, the worst seam of at least ``--min-patches`` patches (``SEAM_MIN_PATCHES``) and the
seams of at least that many patches beside it (the largest RMS of the others), and for a shift every seam of the
shifted frame (patches, RMS); the textured patches that found no match, per seam and in all, the largest share of
them on a seam of at least ``--min-patches`` textured patches (of the shifted frame's and of the others'), and the
seams above ``SEAM_MAX_UNMATCHED_SHARE`` that fail the worst-seam row (review 26). The run folder is only read. Writes ``bench/results/seam_rows.json`` under ``--key``.

Usage: python bench/eval_seam_rows.py RUN_DIR --key demo [--shift s02_002:1:0 ...] [--min-patches 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.results_json import git_commit, store_result  # noqa: E402

import ortho.mosaic as M  # noqa: E402


def _seam(p) -> dict | None:
    return None if p is None else {"pair": f"{p.image_a} / {p.image_b}", "patches": p.patches,
                                   "rms_px": None if p.rms_px is None else round(p.rms_px, 4),
                                   "max_px": None if p.max_px is None else round(p.max_px, 4),
                                   "unmatched": p.unmatched}


def _largest_share(seams, min_patches: int) -> float | None:
    shares = [p.unmatched_share for p in seams if p.textured >= min_patches and p.unmatched_share is not None]
    return round(max(shares), 4) if shares else None


def measure(root: Path, min_patches: int, shift: tuple[str, int, int] | None = None) -> dict:
    """One pass of ``seam_misalignment``, ``shift`` (frame, columns, rows) applied to that frame's reads."""
    original = M.read_window

    def moved(ds, c, r, w, h):
        name = Path(ds.name).stem
        return original(ds, c + shift[1], r + shift[2], w, h) if name == shift[0] else original(ds, c, r, w, h)

    M.read_window = moved if shift else original
    try:
        t = time.process_time()
        s = M.seam_misalignment(root, min_patches=min_patches)
        cpu = time.process_time() - t
    finally:
        M.read_window = original
    judged = s.judged()
    worst = s.worst()
    others = [p for p in judged if p is not worst]
    out = {"patches": s.patches, "one_direction": s.one_direction, "unsettled": s.unsettled,
           "min_texture_ratio": s.min_texture_ratio, "rms_px": None if s.rms_px is None else round(s.rms_px, 4),
           "seams": len(s.per_seam), "seams_judged": len(judged), "worst_seam": _seam(worst),
           "next_worst_rms_px": round(max(p.rms_px for p in others), 4) if others else None, "cpu_s": round(cpu, 2),
           "unmatched": s.unmatched, "unmatched_seams": [_seam(p) for p in s.unmatched_seams()]}
    if not shift:
        out["largest_unmatched_share"] = _largest_share(s.per_seam, min_patches)
    if shift:
        mine = [p for p in s.per_seam if shift[0] in (p.image_a, p.image_b)]
        out["largest_unmatched_share_of_frame"] = _largest_share(mine, min_patches)
        out["least_unmatched_share_of_frame"] = min(
            (round(p.unmatched_share, 4) for p in mine if p.textured >= min_patches and p.unmatched_share is not None),
            default=None)
        out["largest_unmatched_share_of_others"] = _largest_share([p for p in s.per_seam if p not in mine],
                                                                  min_patches)
        out["shift"] = {"frame": shift[0], "dx_px": shift[1], "dy_px": shift[2]}
        out["seams_of_frame"] = [_seam(p) for p in s.per_seam if shift[0] in (p.image_a, p.image_b)]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--key", required=True)
    ap.add_argument("--shift", action="append", default=[], help="FRAME:DX:DY (px), repeatable")
    ap.add_argument("--min-patches", type=int, default=M.SEAM_MIN_PATCHES)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "seam_rows.json")
    args = ap.parse_args()
    shifts = []
    for text in args.shift:
        frame, dx, dy = text.split(":")
        shifts.append((frame, int(dx), int(dy)))
    entry = {"run_dir": str(args.run_dir), "commit": git_commit(ROOT), "min_patches": args.min_patches,
             "as_made": measure(args.run_dir, args.min_patches)}
    print("as made:", entry["as_made"])
    entry["shifted"] = []
    for sh in shifts:
        r = measure(args.run_dir, args.min_patches, sh)
        print(sh, {k: v for k, v in r.items() if k != "seams_of_frame"})
        entry["shifted"].append(r)
    store_result(args.out, entry, key=args.key)


if __name__ == "__main__":
    main()
