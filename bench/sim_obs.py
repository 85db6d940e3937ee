"""Benchmark: an observations-only block of 10,000 frames (``aerotri sim --observations-only``) and what it cost.

``aerotri sim --preset demo --observations-only --set flight.strips=50 --set flight.frames_per_strip=200 OUT``
in a child process: wall and CPU seconds, its peak RSS, the block's tie points, image observations, control
points and the DEM resolution (the truth terrain, coarser for a block this size), written outside the
repository (``--out``, default ``$AEROTRI_BENCH_BLOCKS/obs_10k``). With ``--adjust``, ``aerotri adjust OUT --dem
OUT/dem.tif --self-cal pp,radial --gnss-correction shift_drift`` follows (the models of the simulated camera
and GNSS errors), timed likewise, and its orientations are compared with the truth in units of the sigmas it
reports (RMS and largest per parameter).

Writes bench/results/sim_obs.json (one entry per block size, ``<strips>x<frames>``).

Usage:
  python bench/sim_obs.py                                  # the 10,000-frame block (about 3 min)
  python bench/sim_obs.py --strips 3 --frames 6 --adjust   # the demo's flight, adjusted and checked
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
sys.path.insert(0, str(ROOT))

from aerotri.core.resources import measure  # noqa: E402

RESULT = ROOT / "bench" / "results" / "sim_obs.json"
BLOCKS = Path(os.environ.get("AEROTRI_BENCH_BLOCKS", "/work/bench_blocks"))
ADJUST_OPTIONS = ["--self-cal", "pp,radial", "--gnss-correction", "shift_drift", "--no-html", "--no-exports"]


def _load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _timed(cmd: list[str]) -> dict:
    load0 = _load()
    with measure() as u:
        proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    # the child's peak: RUSAGE_CHILDREN (the largest child reaped), not this process's
    return dict(command=" ".join([Path(cmd[0]).name] + cmd[1:]), wall_s=round(u.wall_s, 1), cpu_s=round(u.cpu_s, 1),
                peak_rss_mb=round(u.workers_peak_rss_mb, 1), load_avg_before=load0, load_avg_after=_load())


def orientation_check(out: Path) -> dict:
    """Adjusted minus true orientations in units of their reported sigmas: RMS and largest of X, Y, Z, omega,
    phi, kappa over the frames."""
    import numpy as np

    from aerotri.geom.eo import read_eo

    adjusted, true = read_eo(out / "at" / "eo.txt"), read_eo(out / "truth" / "eo.txt")
    k = true.rows(adjusted.image_id)
    d = np.hstack([adjusted.centre_m - true.centre_m[k], (adjusted.opk_deg - true.opk_deg[k] + 180.0) % 360.0 - 180.0])
    z = d / adjusted.sigma
    names = ("X", "Y", "Z", "omega", "phi", "kappa")
    return dict(frames=len(k), rms_error={n: float(v) for n, v in zip(names, np.sqrt((d ** 2).mean(axis=0)).round(5))},
                rms_normalised={n: float(v) for n, v in zip(names, np.sqrt((z ** 2).mean(axis=0)).round(2))},
                max_normalised={n: float(v) for n, v in zip(names, np.abs(z).max(axis=0).round(2))})


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--strips", type=int, default=50)
    ap.add_argument("--frames", type=int, default=200, help="frames per strip")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--adjust", action="store_true", help="also adjust the block and check it against the truth")
    args = ap.parse_args()
    name = f"{args.strips}x{args.frames}"
    out = args.out or BLOCKS / ("obs_10k" if name == "50x200" else f"obs_{name}")
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    r = dict(sim=_timed([str(BIN / "aerotri"), "sim", "--preset", "demo", "--observations-only", "--set",
                         f"flight.strips={args.strips}", "--set", f"flight.frames_per_strip={args.frames}", str(out)]))
    truth = json.loads((out / "truth" / "truth.json").read_text())
    r["block"] = {k: truth[k] for k in ("frames", "tie_points", "tie_observations", "control_points", "check_points",
                                        "terrain_res_m", "scene_width_m", "scene_height_m", "gsd_m")}
    r["block"]["tie_points_per_frame"] = round(truth["tie_points"] / truth["frames"], 1)
    r["block"]["rays_per_tie_point"] = round(truth["tie_observations"] / truth["tie_points"], 2)
    r["block"]["disk_mb"] = round(sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) / 1e6, 1)
    if args.adjust:
        r["adjust"] = _timed([str(BIN / "aerotri"), "adjust", str(out), "--dem", str(out / "dem.tif"), *ADJUST_OPTIONS])
        r["adjust"]["check"] = orientation_check(out)
    results = json.loads(RESULT.read_text()) if RESULT.exists() else {}
    results[name] = r
    RESULT.parent.mkdir(exist_ok=True)
    RESULT.write_text(json.dumps(results, indent=1) + "\n")
    print(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
