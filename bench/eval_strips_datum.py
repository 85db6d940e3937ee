"""The free strip adjustment's datum: the block's height at held-out check points, main's code against this
branch's, on the QA trial's simulated blocks (bench/eval_trial_qa.py; docs/lidar-products.md "Strip adjustment's
datum").

Per seed: ``aerotri sim --preset tiny`` with boresight (0.05, -0.03, 0.04) deg and a 5 cm range offset (on top of
the preset's per-strip shifts), the trial's check points (40 open, the odd ones as ``--control``, the even 20
held out), then ``lidarctl strips adjust`` with the trajectories, without and with ``--control``, by main's code
(``--main-tree``: an extracted ``lidarctl`` package put first on PYTHONPATH) and by this branch's; each corrected
block classified and its ground points checked at the held-out points (``lidarctl check-heights``), and the raw
strips as well (not adjusted). Recorded: mean and RMS of dz at the held-out points, the block's mean height move
(every point's z after minus before, numpy), the boresight and range offset against the simulator's truth in
sigmas, the strip differences before and after.
Seed 5 was looked at while developing (it is the trial's run); seeds 6, 7, 8 were scored once with a first
version (the z shifts' prior kept beside the constraint: it pulled the range offset to 0, 2.3-2.7 sigma off the
truth) and again with this one, seeds 9, 10 scored once with this one only.
Writes bench/results/strips_datum.json.
Run: .venv/bin/python bench/eval_strips_datum.py --main-tree /work/tmp/strips-height/old
     [--seeds 9 10 --merge]   (main's lidarctl: git archive <main> lidarctl | tar -x -C /work/tmp/strips-height/old;
     about 2 min a seed)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_trial_qa import BIN, BORESIGHT_DEG, RANGE_OFFSET_M, REPO, checkpoints  # noqa: E402

import subprocess  # noqa: E402

SENSOR = ("boresight_roll_deg", "boresight_pitch_deg", "boresight_heading_deg", "range_offset_m")
TRUTH = dict(zip(SENSOR, (*BORESIGHT_DEG, RANGE_OFFSET_M)))


def run(*args, env=None) -> str:
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True, env=env)
    if r.returncode:
        raise SystemExit(f"{' '.join(map(str, args))}: exit {r.returncode}\n{r.stdout}\n{r.stderr}")
    return r.stdout


def held_out(strips: list[Path], chk: Path, d: Path) -> dict:
    """The strips classified, their ground points checked at ``chk``: mean and RMS of dz (m)."""
    run(BIN / "lidarctl", "classify", *strips, d / "classified", "--format", "laz")
    run(BIN / "lidarctl", "check-heights", *sorted((d / "classified").glob("*.laz")), chk, "--json", d / "hc.json")
    e = np.array([q["dz_m"] for q in json.loads((d / "hc.json").read_text())["points"] if q.get("dz_m") is not None])
    return {"n": int(e.size), "mean_dz_m": float(e.mean()), "rmse_m": float(np.sqrt(np.mean(e ** 2)))}


def one_seed(work: Path, seed: int, main_tree: Path) -> dict:
    sim = work / f"sim{seed}"
    run(BIN / "aerotri", "sim", sim, "--preset", "tiny", "--seed", seed, "--force",
        "--set", f"lidar.boresight_error_deg=[{','.join(map(str, BORESIGHT_DEG))}]",
        "--set", f"lidar.range_offset_m={RANGE_OFFSET_M}")
    strips = sorted((sim / "lidar").glob("*.las"))
    trajs = [a for t in sorted((sim / "trajectory").glob("*.txt")) for a in ("--trajectory", t)]
    pts = checkpoints(sim, work / f"cp{seed}.csv", seed)
    opens = [p for p in pts if p["group"] == "open"]
    ctl, chk = work / f"control{seed}.csv", work / f"check{seed}.csv"
    for path, sel in ((ctl, opens[0::2]), (chk, opens[1::2])):
        path.write_text("id,x,y,z\n" + "".join(f"{p['id']},{p['x']:.3f},{p['y']:.3f},{p['z']:.4f}\n" for p in sel))
    z0 = np.concatenate([np.asarray(laspy.read(p).z, float) for p in strips])
    out = {"seed": seed, "looked_at": seed == 5, "not_adjusted": held_out(strips, chk, work / f"raw{seed}")}
    env_main = {**os.environ, "PYTHONPATH": str(main_tree)}
    for code, env in (("main", env_main), ("branch", None)):
        for name, extra in (("without_control", []), ("with_control", ["--control", ctl])):
            d = work / f"{code}{seed}_{name}"
            shutil.rmtree(d, ignore_errors=True)
            run(BIN / "lidarctl", "strips", "adjust", *strips, d, *trajs, *extra, "--no-png", env=env)
            adj = json.loads((d / "adjust.json").read_text())
            corrected = [d / p.name for p in strips]
            z1 = np.concatenate([np.asarray(laspy.read(p).z, float) for p in corrected])
            par = adj["parameters"]
            out[f"{code}_{name}"] = {
                **held_out(corrected, chk, d), "block_mean_height_move_m": float(np.mean(z1 - z0)),
                "datum": adj.get("datum", "(main: the shifts' prior)"),
                "strip_rms_before_after_m": [adj["check_before"]["rms_m"], adj["check_after"]["rms_m"]],
                "sensor": {k: {"truth": TRUTH[k], "estimate": par[k]["value"], "sigma": par[k]["sigma"],
                               "error_in_sigmas": (par[k]["value"] - TRUTH[k]) / par[k]["sigma"]} for k in SENSOR}}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/strips-height/bench"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[5, 6, 7, 8])
    ap.add_argument("--main-tree", type=Path, required=True, help="folder holding main's lidarctl package")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "strips_datum.json")
    ap.add_argument("--merge", action="store_true", help="keep the other seeds of an existing --out")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    out = {"what": __doc__.split("\n\n")[0], "boresight_deg": BORESIGHT_DEG, "range_offset_m": RANGE_OFFSET_M,
           "held_out": "the 20 even open check points; control: the 20 odd ones",
           "seeds": [one_seed(args.work, s, args.main_tree.resolve()) for s in args.seeds]}
    path = args.out
    if args.merge and path.exists():
        kept = [r for r in json.loads(path.read_text())["seeds"] if r["seed"] not in args.seeds]
        out["seeds"] = sorted(kept + out["seeds"], key=lambda r: r["seed"])
    path.write_text(json.dumps(out, indent=2) + "\n")
    for s in out["seeds"]:
        print(s["seed"], "not adjusted", round(s["not_adjusted"]["mean_dz_m"], 3))
        for k in ("main_without_control", "branch_without_control", "main_with_control", "branch_with_control"):
            r = s[k]
            print(f"  {k:24s} mean dz {r['mean_dz_m']:+.3f} rmse {r['rmse_m']:.3f} block move "
                  f"{r['block_mean_height_move_m']:+.3f} strips {r['strip_rms_before_after_m'][1]:.4f}",
                  {n: round(v["error_in_sigmas"], 2) for n, v in r["sensor"].items()})
    print(path)


if __name__ == "__main__":
    main()
