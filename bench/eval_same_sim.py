"""Same simulator output (issue 40, seventh round: the typed preset): ``aerotri.sim.simulate`` and
``simulate_observations`` of fixed presets and ``--set`` overrides, run once with the code before a change and once
with it, every file compared by SHA-256.

Each side runs in its own process with ``PYTHONPATH`` set to its code (``--before``: the package folders and presets
of the earlier commit, ``git archive main aerotri lidarctl ortho datasets/presets | tar -x -C DIR``; the after side
is this checkout). Text files (JSON, CSV, TOML, text) are compared with the side's output folder replaced, and the
name of the temporary folder a file was written in (``.NAME.part-XXXXXXXX``: random, different on every run, which
``truth/flight_acceptance.json`` of an observations-only block records) made one.

    python bench/eval_same_sim.py --before DIR --work SCRATCH [--json bench/results/i40_dicts_f_same_sim.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

# (folder, what, preset, overrides): the frames written whole and tiled (12-bit, deflate), counts scaled to another
# scene size, an injected LiDAR range offset, another seed; observation-only blocks of two presets
CASES = (
    ("tiny", "simulate", "tiny", ()),
    ("tiny_set", "simulate", "tiny", ("render.tile_px=256", "render.bits=12", 'render.compress="deflate"',
                                      "scene.counts_for_m=[600.0, 500.0]", "lidar.range_offset_m=0.05",
                                      "preset.seed=7")),
    ("obs_tiny", "observations", "tiny", ()),
    ("obs_demo", "observations", "demo", ("flight.strips=4", "preset.seed=5", "observations.tie_points_per_frame=60")),
)
TEXT = (".json", ".csv", ".txt", ".toml")
PART = re.compile(r"\.part-[A-Za-z0-9_]+")


def measure(out: Path) -> None:
    """One side, in its own process: every case into ``out``; prints the CPU seconds as the last line."""
    from aerotri.sim import load_preset, simulate
    from aerotri.sim.project import simulate_observations

    cpu = {}
    for folder, what, preset, sets in CASES:
        t = time.process_time()
        run = simulate if what == "simulate" else simulate_observations
        run(load_preset(preset, list(sets)), out / folder)
        cpu[folder] = round(time.process_time() - t, 2)
    print(json.dumps({"cpu_s": cpu}))


def digests(out: Path) -> dict:
    d = {}
    for p in sorted(out.rglob("*")):
        if p.is_file():
            data = p.read_bytes()
            if p.suffix in TEXT:
                data = PART.sub(".part-X", data.decode().replace(str(out), "OUT")).encode()
            d[str(p.relative_to(out))] = hashlib.sha256(data).hexdigest()
    return d


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, help="the code before the change (package folders and datasets/presets)")
    ap.add_argument("--work", type=Path, help="scratch folder (emptied)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--what", default="", help="the sides, for the JSON")
    ap.add_argument("--measure", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.measure:
        return measure(a.measure)
    from lidar_common import measure_on_tree

    shutil.rmtree(a.work, ignore_errors=True)
    sides = {}
    for side, code in (("before", a.before.resolve()), ("after", ROOT)):
        out = a.work / side
        out.mkdir(parents=True)
        run = measure_on_tree(code, Path(__file__), [out], env={"AEROTRI_PRESETS": str(code / "datasets" / "presets")})
        sides[side] = (digests(out), run["cpu_s"])
    (db, cpu_b), (da, cpu_a) = sides["before"], sides["after"]
    files = sorted(set(db) | set(da))
    different = [f for f in files if db.get(f) != da.get(f)]
    result = {"what": a.what, "cases": [{"folder": f, "what": w, "preset": p, "set": list(s)} for f, w, p, s in CASES],
              "files": len(files), "identical": len(files) - len(different), "different": different,
              "cpu_s_before": cpu_b, "cpu_s_after": cpu_a, "sha256": da}
    print(f"{len(files)} files, {result['identical']} identical" + (f"; different: {', '.join(different)}" if different
                                                                   else ""))
    if a.json:
        a.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
