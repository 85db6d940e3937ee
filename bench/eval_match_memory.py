"""Peak memory of ``aerotri match`` phase by phase, before and after issue 41 (features by tiles, descriptors
left in the cache files) -> bench/results/match_memory.json (docs/performance.md, "Matching memory").

Each run is a fresh process (``--worker``) that matches a copy of a project with an empty feature and match cache
and samples its resident memory every 20 ms; the phases are ``match_project``'s own (plan, features, matching,
tracks, densify, output: its ``_PhaseClock`` laps are recorded with their time). Per phase: wall and CPU seconds
and the largest sampled RSS; per run: the process's high-water mark (``VmHWM``, which the sampling cannot miss),
CPU seconds, and what was matched (pairs, pairs with ties, tracks, observations) and, with ``--adjust ARGS``, the
adjust's sigma0 (and check point RMS where the project has check points) on the matched ties.

"before" runs the code of a git commit (``--before``, default: the merge base with main) exported into a
temporary folder, "after" this working tree.

Usage (nice -n 10 on a shared machine; the runs inherit it):
  python bench/eval_match_memory.py --project NAME=DIR [--adjust NAME="ARGS" ...] ... [--before COMMIT]
       [--work DIR] [--out bench/results/match_memory.json] [--only before|after]
A run replaces the named projects' records in the JSON and keeps the others.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _status_mb(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def worker(project: Path, tree: Path | None) -> dict:
    """Match ``project`` in this process (the code of ``tree`` when given); the measurements."""
    if tree is not None:  # the exported tree before the editable install's finder
        sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f).lower()]
        sys.path.insert(0, str(tree))
    from aerotri.match import pipeline

    assert tree is None or pipeline.__file__.startswith(str(tree)), pipeline.__file__
    laps: list[tuple[str, float]] = []
    lap = pipeline._PhaseClock.lap

    def recording_lap(self, name):
        laps.append((name, time.perf_counter()))
        lap(self, name)

    pipeline._PhaseClock.lap = recording_lap
    samples: list[tuple[float, float]] = []
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            samples.append((time.perf_counter(), _status_mb("VmRSS")))
            stop.wait(0.02)

    th = threading.Thread(target=sample, daemon=True)
    t0, c0 = time.perf_counter(), time.process_time()
    th.start()
    report = pipeline.match_project(project)
    stop.set()
    th.join()
    phases, start = {}, t0
    for name, end in laps:
        rss = [r for t, r in samples if start <= t <= end]
        wall, cpu = report.phase_seconds[name]
        phases[name] = {"wall_s": wall, "cpu_s": cpu, "peak_rss_mb": round(max(rss), 1) if rss else None}
        start = end
    ru = resource.getrusage(resource.RUSAGE_SELF)
    peak_mb = round(_status_mb("VmHWM"), 1)
    truth = {}
    if (project / "truth" / "eo.txt").exists():  # a simulated block: the ties against the true orientations
        import dataclasses

        from aerotri.sim.evaluate import tie_point_errors

        truth = {"tie_points_vs_truth": dataclasses.asdict(tie_point_errors(project))}
    return truth | {
        "peak_rss_mb": peak_mb, "cpu_s": round(ru.ru_utime + ru.ru_stime, 1),
        "match_cpu_s": round(time.process_time() - c0, 1), "wall_s": round(time.perf_counter() - t0, 1),
        "load_avg_1min": round(os.getloadavg()[0], 2), "phases": phases,
        "frames": report.frames, "pairs": report.pairs, "pairs_with_ties": report.pairs_with_ties,
        "tracks": report.tracks, "observations": report.observations,
        "tracks_3plus_fraction": round(report.tracks_3plus_fraction, 4),
        "weak_models": len(report.weak_models), "densified_pairs": len(report.densified.models),
    }


def sift_worker(frame: Path, max_dim_px: int, tile_px: int) -> dict:
    """One frame's dense-setting features (``[match.dense]``'s budget, grid and contrast, ``max_dim_px``) by tiles of
    ``tile_px`` (a huge value: the whole level, as before tiles): the detection level's size and the memory the
    extraction added to the level in memory (high-water mark, reset after the level is read)."""
    import dataclasses

    import rasterio

    from aerotri.geom.images import pyramid_level, read_gray_level
    from aerotri.match.features import extract_level
    from aerotri.match.settings import MatchSettings

    p = dataclasses.replace(MatchSettings().dense, max_dim_px=max_dim_px, tile_px=tile_px)
    with rasterio.open(frame) as ds:
        size = (ds.width, ds.height)
    level = pyramid_level(*size, p.max_dim_px)
    small = read_gray_level(frame, level, size)
    Path("/proc/self/clear_refs").write_text("5")
    base, c0 = _status_mb("VmHWM"), time.process_time()
    f = extract_level(small, level, p)
    return {"frame_px": list(size), "level": level, "level_px": [small.shape[1], small.shape[0]], "tile_px": tile_px,
            "keypoints": len(f.xy_px), "cpu_s": round(time.process_time() - c0, 1),
            "extraction_peak_mb": round(_status_mb("VmHWM") - base, 1)}


def _sift_probe(frame: Path, max_dim_px: int) -> dict:
    out = {"frame": str(frame), "max_dim_px": max_dim_px}
    for label, tile in (("whole_level", 10**6), ("tiles", None)):
        from aerotri.match.settings import MatchSettings

        tile = tile or MatchSettings().dense.tile_px
        p = subprocess.run([sys.executable, __file__, "--sift", str(frame), str(max_dim_px), str(tile)],
                           capture_output=True, text=True)
        if p.returncode != 0:
            raise SystemExit(f"sift {frame}: {p.stderr.strip().splitlines()[-1:]}")
        out[label] = json.loads(p.stdout.strip().splitlines()[-1])
    print(f"sift {frame.name} level {out['tiles']['level_px']}: whole {out['whole_level']['extraction_peak_mb']:.0f} MB, "
          f"tiles {out['tiles']['extraction_peak_mb']:.0f} MB", flush=True)
    return out


def _adjust(matched: Path, args: str, k: int) -> dict:
    """sigma0 (and check point RMS, and with --dem and --ndsm the ground tie points' heights against that DEM:
    bench/eval_brighton.py's measure) of ``aerotri adjust ARGS`` (the console command of this tree) on a copy of the
    matched project."""
    project = matched.with_name(f"{matched.name}_adjust{k}")
    if project.exists():
        shutil.rmtree(project)
    shutil.copytree(matched, project, symlinks=True, ignore=shutil.ignore_patterns("work"))
    aerotri = Path(sys.executable).parent / "aerotri"
    argv = shlex.split(args)
    p = subprocess.run([str(aerotri), "adjust", str(project), *argv], capture_output=True, text=True)
    if p.returncode != 0:
        return {"args": args, "error": (p.stderr or p.stdout).strip().splitlines()[-1:]}
    rep = json.loads((project / "at" / "report.json").read_text())
    ks = rep["key_statistics"]
    out = {"args": args, "sigma0_um": ks.get("sigma0_um"), "sigma0_px": ks.get("sigma0_px"),
           "verdict": _find(rep, "verdict")}
    if rep.get("check_points"):
        out |= {"check_points": len(rep["check_points"]), "check_rms_m": rep["check_rms_m"]}
    if "--dem" in argv and "--ndsm" in argv:
        sys.path.insert(0, str(REPO / "bench"))
        from eval_brighton import tie_minus_dem

        out["tie_minus_dem"] = tie_minus_dem(project / "at" / "object_points.csv",
                                             Path(argv[argv.index("--dem") + 1]), Path(argv[argv.index("--ndsm") + 1]))
    return out


def _find(d, key):
    """The first value of ``key`` in a nested report (depth first)."""
    if isinstance(d, dict):
        if key in d and not isinstance(d[key], (dict, list)):
            return d[key]
        for v in d.values():
            r = _find(v, key)
            if r is not None:
                return r
    elif isinstance(d, list):
        for v in d:
            r = _find(v, key)
            if r is not None:
                return r
    return None


def _copy_project(src: Path, dst: Path) -> Path:
    """A copy of a project without its match caches and products; the frames and the LiDAR products (inputs that
    neither stage writes) linked, not copied."""
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for p in src.iterdir():
        if p.name in ("work", "at", "ortho", "reports"):
            continue
        if p.name in ("images", "lidar", "lidar_out", "truth", "trajectory"):
            os.symlink(p.resolve(), dst / p.name)
        elif p.is_dir():
            shutil.copytree(p, dst / p.name, symlinks=True)
        else:
            shutil.copy2(p, dst / p.name)
    return dst


def _run(label: str, project: Path, tree: Path | None, work: Path, adjust: list[str]) -> dict:
    copy = _copy_project(project, work / f"{project.name}_{label}")
    cmd = [sys.executable, __file__, "--worker", str(copy)]  # at the niceness of this process
    if tree is not None:
        cmd += ["--tree", str(tree)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{label} {project}: {p.stderr.strip().splitlines()[-1:]}")
    rec = json.loads(p.stdout.strip().splitlines()[-1])
    rec["tiepoints_csv"] = str(copy / "at" / "tiepoints.csv")
    rec["adjust"] = [_adjust(copy, args, k) for k, args in enumerate(adjust)]
    print(f"{label:6s} {project.name}: peak {rec['peak_rss_mb']:.0f} MB, {rec['cpu_s']:.0f} CPU-s, "
          f"{rec['pairs']} pairs, {rec['tracks']} tracks, {rec['observations']} observations, adjust {rec['adjust']}",
          flush=True)
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--tree", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--sift", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--sift-frame", action="append", default=[],
                    help="NAME=FRAME[:MAX_DIM_PX]: one SIFT extraction (dense settings) of the frame, whole level and "
                         "by tiles, one process each")
    ap.add_argument("--project", action="append", default=[], help="NAME=DIR of a project to match")
    ap.add_argument("--adjust", action="append", default=[], help='NAME="ARGS": adjust a copy of the matched project '
                                                                   "(repeatable)")
    ap.add_argument("--before", default=None, help="git commit of the code before (default: merge base with main)")
    ap.add_argument("--only", choices=("before", "after"), default=None)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "match_memory.json")
    a = ap.parse_args()
    if a.worker is not None:
        print(json.dumps(worker(a.worker, a.tree)))
        return
    if a.sift is not None:
        print(json.dumps(sift_worker(Path(a.sift[0]), int(a.sift[1]), int(a.sift[2]))))
        return
    projects = dict(s.split("=", 1) for s in a.project)
    adjust: dict[str, list[str]] = {}
    for s in a.adjust:
        name, args = s.split("=", 1)
        adjust.setdefault(name, []).append(args)
    before = a.before or subprocess.run(["git", "-C", str(REPO), "merge-base", "HEAD", "main"], capture_output=True,
                                        text=True, check=True).stdout.strip()
    work = a.work or Path(tempfile.mkdtemp(prefix="match_memory_"))
    work.mkdir(parents=True, exist_ok=True)
    tree = work / f"tree_{before[:10]}"
    if a.only != "after" and not tree.exists():
        tree.mkdir()
        archive = subprocess.run(["git", "-C", str(REPO), "archive", before, "aerotri"], capture_output=True,
                                 check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    results = json.loads(a.out.read_text()) if a.out.exists() else {}
    results.setdefault("projects", {})
    for name, root in projects.items():
        rec = results["projects"].get(name, {})
        rec["project"] = str(root)
        if a.only != "after":
            rec["before"] = _run("before", Path(root), tree, work, adjust.get(name, [])) | {"commit": before}
        if a.only != "before":
            rec["after"] = _run("after", Path(root), None, work, adjust.get(name, []))
        results["projects"][name] = rec
    for spec in a.sift_frame:
        name, frame = spec.split("=", 1)
        frame, _, dim = frame.partition(":")
        results.setdefault("sift_calls", {})[name] = _sift_probe(Path(frame), int(dim or 4500))
    results["machine"] = {"cores": os.cpu_count(), "note": "shared machine: load in each run's load_avg_1min"}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = a.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(results, indent=1) + "\n")
    tmp.replace(a.out)


if __name__ == "__main__":
    main()
