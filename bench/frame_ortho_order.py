"""Frame orthos whose bytes do not depend on GDAL's block cache: the chain's rectify stage run again, alternately with
the code before a change (``--before-src``, a ``git archive`` of main) and with this tree, on a finished chain project;
per run the stage's wall and CPU seconds and peak RSS (from its stage record) and the SHA-1 of every frame ortho.

    git archive <rev> aerotri lidarctl ortho | tar -x -C BEFORE
    python bench/frame_ortho_order.py --project RUN --before-src BEFORE --rounds 3 \\
        --out bench/results/frame_ortho_order.json --key K [--reference TRUTH/ortho.tif --points TRUTH/checkpoints.csv]

Each run removes the rectify stage's stamp, runs ``aerotri run`` (the stages before it are up to date and skipped) and
stops the chain once rectify is done (the mosaic after it is rolled back by the next run). The project is changed:
give a copy.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ortho.block import file_fingerprint  # noqa: E402


def rectify_once(project: Path, src: Path | None, extra: list[str]) -> dict:
    """The rectify stage of ``project`` again with the code of ``src`` (None: this tree)."""
    (project / "work" / "stages" / "rectify.json").unlink(missing_ok=True)
    env = dict(os.environ, PYTHONPATH=str(src) if src else str(ROOT))
    log = project.parent / f"{project.name}.rectify.log"
    # (aerotri.cli has no __main__: the console script's call)
    cmd = [sys.executable, "-c", "import sys; from aerotri.cli import main; sys.exit(main())", "run", str(project), *extra]
    with open(log, "w") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        while proc.poll() is None and "[rectify] done" not in log.read_text(errors="replace"):
            time.sleep(0.5)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
        proc.wait()
    if "[rectify] done" not in log.read_text(errors="replace"):
        raise SystemExit(f"{' '.join(cmd)}: rectify did not finish, see {log}")
    stamp = json.loads((project / "work" / "stages" / "rectify.json").read_text())
    frames = sorted((project / "ortho" / "frames").glob("*.tif"))
    # the SHA-1 ortho/frames/index.json records
    return {**stamp["usage"], "frames_sha1": {f.name: file_fingerprint(f).sha1 for f in frames}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, required=True, help="a finished chain project (a copy: it is changed)")
    ap.add_argument("--before-src", type=Path, required=True, help="the code before the change (git archive)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--reference", type=Path, help="passed to aerotri run as the chain was run")
    ap.add_argument("--points", type=Path, help="passed to aerotri run as the chain was run")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--key", required=True)
    a = ap.parse_args()
    extra = [*(["--reference", str(a.reference)] if a.reference else []),
             *(["--points", str(a.points)] if a.points else [])]
    runs = {"before": [], "after": []}
    for r in range(a.rounds):
        for side, src in (("before", a.before_src), ("after", None)):
            runs[side].append(rectify_once(a.project, src, extra))
            u = runs[side][-1]
            print(f"round {r + 1} {side}: {u['wall_s']:.1f} s wall, {u['cpu_s']:.1f} CPU-s, {u['peak_rss_mb']:.0f} MB",
                  flush=True)

    def median(side, k):
        v = sorted(x[k] for x in runs[side])
        return v[len(v) // 2]

    result = {
        "project": str(a.project), "before_src": str(a.before_src), "rounds": a.rounds, "runs": runs,
        "median_cpu_s": {s: median(s, "cpu_s") for s in runs}, "median_wall_s": {s: median(s, "wall_s") for s in runs},
        "cpu_ratio_after_over_before_by_round": [round(b["cpu_s"] / max(x["cpu_s"], 1e-9), 3)
                                                 for x, b in zip(runs["before"], runs["after"])],
        # the same frame ortho bytes in every run of a side: byte-deterministic
        "after_frames_identical_in_every_run": all(x["frames_sha1"] == runs["after"][0]["frames_sha1"]
                                                   for x in runs["after"]),
        "before_frames_identical_in_every_run": all(x["frames_sha1"] == runs["before"][0]["frames_sha1"]
                                                    for x in runs["before"]),
        "measured_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "load_avg_after": os.getloadavg(),
    }
    doc = json.loads(a.out.read_text()) if a.out.exists() else {}
    doc[a.key] = result
    a.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"median CPU-s before {result['median_cpu_s']['before']:.1f}, after {result['median_cpu_s']['after']:.1f}; "
          f"frames identical run to run: before {result['before_frames_identical_in_every_run']}, "
          f"after {result['after_frames_identical_in_every_run']} -> {a.out} [{a.key}]")


if __name__ == "__main__":
    main()
