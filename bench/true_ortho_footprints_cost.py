"""The cost of the true ortho with building footprints against the conventional one and the true ortho without them,
per MP of frame ortho, on the demo's whole block (issue 42: at most 2x the conventional rectify time per MP) ->
a key of bench/results/true_ortho_cost.json (the other keys are kept).

Three ways, each one ``rectify_block`` of every frame of the block (the footprints' occluder is built once a block,
``ortho.block._block_footprint_cells``), in the same process, alternating round by round (conventional, true,
true + footprints, conventional, ...), so that the load of the shared machine falls on all alike:

- conventional: on the DEM (lidar_out/dem.tif), as ``ortho rectify P``;
- true: ``--true-ortho --dsm P/lidar_out/dsm.tif``;
- true + footprints: the same with ``--footprints P/truth/footprints.gpkg`` (the simulator's wall lines,
  ``aerotri.sim.project.write_footprints_gpkg`` of truth/buildings.geojson);
- true + footprints + crowns (``--crowns``): the same with ``--crown-base P/lidar_out/crown_base.tif`` (the LiDAR's
  crown bases from the chain's classified strips, ``eval_true_ortho_dsm_cell.lidar_crown_base``).

CPU is the process's (user + sys of all its threads, ``time.process_time``) per call; one call of each way runs first
and is not counted (numba's compiled-code cache, the imports). Per way: the CPU-s per MP of each round, their median,
the load average, the process's peak RSS during the call (VmHWM, reset before each call through /proc/self/clear_refs)
and the CPU of the footprints' occluder (``ortho.block._frame_occluder``, the thread's CPU, summed over the frames;
the first call of a block rasterises the block's footprint cells in it). ``--sha256``: also the sha256 of each frame
ortho's decoded samples and mask of the last true + footprints round (to compare the frames of two commits).

Full-size frames: ``--project`` a chain's project instead of the demo (e.g.
/work/bench_blocks/dmc_block_subset_2x2_run_cccbc0a: 4 DMC frames of 13824 x 7680 px, its LiDAR DEM and DSM of 0.5 m,
its adjusted orientations and camera) and ``--truth`` the simulator's truth folder of the same block (the run folder
has none; /work/bench_blocks/dmc_block_subset_2x2/truth): the footprints are written from its buildings.geojson.
With ``--truth`` the roofs of each way's frame orthos of the last round are measured too (``roofs``): every frame
ortho against truth/ortho.tif at the corners of truth/roof_corners.csv (``ortho.check.measure_roof_patches``, as the
DOM check's roofs row), RMS and median of the displacements of all frames together, in m and GSD.

``--occlusion`` adds the chain's default (``aerotri run``: the occlusion test on lidar_out/dsm_nearest.tif, a second
raster beside the DSM the ortho is rectified on, ``--occlusion-dsm``), without and with the footprints
(``true_ortho_occlusion``, ``true_ortho_footprints_occlusion``; the project must hold lidar_out/dsm_nearest.tif).
``--code DIR``: the toolkit's packages from DIR (e.g. main's, ``git archive main aerotri lidarctl ortho``) instead of
this checkout, so that two commits are measured by the same script; ``--sha256-against FILE``: the frame orthos of
each way compared with FILE (``--sha256-all`` of such a run; ``identical_to``).

``--chain-crowns`` adds the chain's default since the fitted crowns (``aerotri run``: the occlusion test on
lidar_out/dsm_crowns.tif with the trees' disks of lidar_out/crowns.gpkg, ``--crowns``), without and with the footprints
(``true_ortho_crowns``, ``true_ortho_crowns_footprints``). Each way's CPU in the occluder's steps:
``--steps`` (``STEPS``: the thread CPU of each step per block, ``steps_cpu_s`` in every run).

``--frames A,B``: only those frames (each way's block of them). The footprints are written for every way when the
truth folder has buildings.geojson; without it (a chain's run folder of a block whose truth is gone) the ways
without footprints still run.

``--per-frame`` adds a fourth way, the true ortho with footprints rasterised per frame (as ``ortho.block`` does when
the block's DSM window exceeds ``SHARED_FOOTPRINT_CELLS_MAX`` cells, e.g. the 120-frame DMC block), and compares its
frame orthos with the shared rasterisation's (sha256 of samples and mask); ``--ways`` runs a subset of the ways.

Usage: python bench/true_ortho_footprints_cost.py [--demo /work/ref/demo_chain/project | --project P --truth T]
       [--work DIR] [--rounds 3] [--key footprints_demo] [--out bench/results/true_ortho_cost.json] [--sha256 FILE]
       [--per-frame] [--occlusion] [--ways conventional,true_ortho_footprints] [--no-roofs | --roofs-only]
       [--code DIR] [--sha256-all FILE] [--sha256-against FILE] [--chain-crowns] [--steps]
``--roofs-only`` (with ``--truth`` and the ``--work`` of an earlier run): the roofs again into that run's ``--key``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

WAYS = ("conventional", "true_ortho", "true_ortho_footprints")
PER_FRAME = "true_ortho_footprints_per_frame"  # --per-frame: the footprints rasterised per frame, as above
# ``ortho.block.SHARED_FOOTPRINT_CELLS_MAX`` DSM cells of the block's window (the 120-frame DMC block: 170 M)
CROWNS = "true_ortho_footprints_crowns"
OCCLUSION = ("true_ortho_occlusion", "true_ortho_footprints_occlusion")  # --occlusion: on dsm_nearest.tif, the chain's
# --chain-crowns: the chain's default since the fitted crowns, the occlusion test on lidar_out/dsm_crowns.tif with
# lidar_out/crowns.gpkg (``--crowns``), without and with the footprints
CHAIN_CROWNS = ("true_ortho_crowns", "true_ortho_crowns_footprints")


def settings(project: Path, way: str):
    from ortho.settings import RectifySettings

    if way == "conventional":
        return RectifySettings()
    crowns = {"crown_base": str(project / "lidar_out" / "crown_base.tif")} if way == CROWNS else {}
    if way in OCCLUSION:
        crowns["occlusion_dsm"] = str(project / "lidar_out" / "dsm_nearest.tif")
    if way in CHAIN_CROWNS:
        crowns["occlusion_dsm"] = str(project / "lidar_out" / "dsm_crowns.tif")
        crowns["crowns"] = str(project / "lidar_out" / "crowns.gpkg")
    return RectifySettings(true_ortho=True, dsm=str(project / "lidar_out" / "dsm.tif"),
                           footprints=str(project / "truth" / "footprints.gpkg") if "footprints" in way else None,
                           **crowns)


_occluder_cpu_s: list = []  # the thread CPU of each ``_frame_occluder`` call of the current block


def _timed_occluder():
    """Wrap ``ortho.block._frame_occluder`` to add each call's thread CPU to ``_occluder_cpu_s``."""
    import ortho.block

    inner = ortho.block._frame_occluder

    def timed(*a, **k):
        c = time.thread_time()
        try:
            return inner(*a, **k)
        finally:
            _occluder_cpu_s.append(time.thread_time() - c)

    ortho.block._frame_occluder = timed


_cells_shapes: list = []  # the grid shape of each ``footprint_cells`` rasterisation of the current block


def _counted_cells():
    """Wrap ``ortho.footprints.footprint_cells`` to record the shape of each grid it rasterises: one call over the
    block's window, or one per frame (the window above ``ortho.block.SHARED_FOOTPRINT_CELLS_MAX``)."""
    import ortho.footprints

    inner = ortho.footprints.footprint_cells

    def counted(x_left_m, y_top_m, res_m, shape, *a, **k):
        _cells_shapes.append([int(v) for v in shape])
        return inner(x_left_m, y_top_m, res_m, shape, *a, **k)

    ortho.footprints.footprint_cells = counted


# --steps: the thread CPU of each call of these functions, summed per block (a step's CPU includes the steps it
# calls: ``_frame_occluder`` holds ``footprint_cells``, ``occluder_of_cells`` and ``outline_heights``;
# ``with_crown_disks`` holds ``crown_sub_cells``)
STEPS = (("ortho.block", "_frame_occluder"), ("ortho.footprints", "footprint_cells"),
         ("ortho.footprints", "occluder_of_cells"), ("ortho.footprints", "outline_heights"),
         ("ortho.block", "_crowns_of"), ("ortho.crown_cells", "with_crown_disks"),
         ("aerotri.geom.crown_disks", "crown_sub_cells"), ("ortho.rectify", "frame_zbuffer"),
         ("ortho.rectify", "march_bound"), ("ortho.rectify", "occlusion_mask"), ("ortho.rectify", "heights_by_side"),
         ("ortho.rectify", "zbuffer_occlusion_affine"), ("ortho.rectify", "zbuffer_occlusion_from_maps"),
         ("ortho.rectify", "fixed_point_maps"), ("ortho.block", "read_height_window"), ("ortho.block", "ground_flags"))
_step_cpu_s: dict = {}  # step -> [thread CPU of each call] of the current block


def _timed_steps() -> None:
    """Wrap each function of ``STEPS`` (looked up through its module at call time) to add its thread CPU to
    ``_step_cpu_s``."""
    import importlib

    for module, name in STEPS:
        m = importlib.import_module(module)
        inner = getattr(m, name, None)
        if inner is None:  # a step of another commit's code (``--code``)
            continue

        def timed(*a, _inner=inner, _name=name, **k):
            c = time.thread_time()
            try:
                return _inner(*a, **k)
            finally:
                _step_cpu_s.setdefault(_name, []).append(time.thread_time() - c)

        setattr(m, name, timed)


def _peak_rss_reset() -> None:
    with open("/proc/self/clear_refs", "w") as f:  # "5": reset the peak RSS (VmHWM) to the current RSS
        f.write("5")


def _peak_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def one_block(project: Path, way: str, frames=None) -> dict:
    import ortho.block
    from ortho.block import read_index, rectify_block

    shared_max = ortho.block.SHARED_FOOTPRINT_CELLS_MAX
    if way == PER_FRAME:
        ortho.block.SHARED_FOOTPRINT_CELLS_MAX = 0
    _occluder_cpu_s.clear()
    _cells_shapes.clear()
    _step_cpu_s.clear()
    _peak_rss_reset()
    t, c = time.perf_counter(), time.process_time()
    try:
        rectify_block(project, settings(project, way), frames=frames)
    finally:
        ortho.block.SHARED_FOOTPRINT_CELLS_MAX = shared_max
    cpu, wall = time.process_time() - c, time.perf_counter() - t
    entries = read_index(project).document["frames"]
    mp = sum(e["width"] * e["height"] for e in entries) / 1e6
    load = os.getloadavg()
    out = {"frame_ortho_mp": round(mp, 2), "cpu_s": round(cpu, 3), "wall_s": round(wall, 3),
           "cpu_s_per_mp": round(cpu / mp, 4), "load_avg_1min": round(load[0], 2), "load_avg_5min": round(load[1], 2),
           "peak_rss_mb": round(_peak_rss_mb(), 1)}
    if _occluder_cpu_s:
        out["occluder_cpu_s"] = round(sum(_occluder_cpu_s), 3)
        out["footprint_cells_grids"] = list(_cells_shapes)
    if _step_cpu_s:
        out["steps_cpu_s"] = {k: round(sum(v), 3) for k, v in _step_cpu_s.items()}
    return out


def frame_sha256(project: Path) -> dict:
    import numpy as np
    import rasterio

    out = {}
    for f in sorted((project / "ortho" / "frames").glob("*.tif")):
        with rasterio.open(f) as ds:
            h = hashlib.sha256(np.ascontiguousarray(ds.read()).tobytes())
            h.update(np.ascontiguousarray(ds.read_masks(1)).tobytes())
            out[f.stem] = h.hexdigest()
    return out


def frame_roofs(project: Path, truth: Path, per_corner: dict | None = None) -> dict:
    """Roof-corner displacements of every frame ortho of ``project`` against ``truth``/ortho.tif, all frames
    together (a corner once per frame ortho that holds its patch); ``per_corner``: filled with (frame, x, y) ->
    displacement (m)."""
    import numpy as np

    from ortho.block import read_index
    from ortho.check import measure_roof_patches, read_roof_corners

    x, y = read_roof_corners(truth / "roof_corners.csv")
    index = read_index(project)
    de, dn, outside, weak = [], [], 0, 0
    t = time.process_time()
    for e in index.document["frames"]:
        r = measure_roof_patches(project / "ortho" / "frames" / e["file"], truth / "ortho.tif", x, y)
        de.append(r.de_m)
        dn.append(r.dn_m)
        if per_corner is not None:
            per_corner.update({(e["image_id"], float(a), float(b)): float(v)
                               for a, b, v in zip(r.x_m, r.y_m, np.hypot(r.de_m, r.dn_m))})
        outside += r.outside_or_invalid
        weak += r.weak
    d = np.hypot(np.concatenate(de), np.concatenate(dn))
    gsd = float(index.document["res_m"])
    return {"measured": int(d.size), "weak": weak, "outside_or_invalid": outside,
            "rms_m": round(float(np.sqrt(np.mean(d ** 2))), 4), "median_m": round(float(np.median(d)), 4),
            "rms_gsd": round(float(np.sqrt(np.mean(d ** 2))) / gsd, 3), "median_gsd": round(float(np.median(d)) / gsd, 3),
            "cpu_s": round(time.process_time() - t, 1)}


def roofs_of_ways(projects: dict, truth: Path, ways) -> dict:
    """``frame_roofs`` of each way, and the true ortho without and with footprints on the corners both measure
    (rectified on the same DSM: only the masks, and so the patches' valid cells, differ)."""
    import numpy as np

    corners = {way: {} for way in ways}
    out = {way: frame_roofs(projects[way], truth, corners[way]) for way in ways}
    a, b = corners.get("true_ortho"), corners.get("true_ortho_footprints")
    if a and b:
        both = sorted(set(a) & set(b))
        da, db = np.array([a[k] for k in both]), np.array([b[k] for k in both])
        gsd = out["true_ortho"]["rms_m"] / out["true_ortho"]["rms_gsd"]
        out["common_corners_true_ortho_vs_footprints"] = {
            "corners": len(both), "rms_gsd": [round(float(np.sqrt(np.mean(v ** 2))) / gsd, 3) for v in (da, db)],
            "median_gsd": [round(float(np.median(v)) / gsd, 3) for v in (da, db)],
            "footprints_worse_by_over_0_5_gsd": int(np.sum(db - da > 0.5 * gsd)),
            "footprints_better_by_over_0_5_gsd": int(np.sum(da - db > 0.5 * gsd)),
            "only_without_footprints": len(set(a) - set(b)), "only_with_footprints": len(set(b) - set(a))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--demo", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--project", type=Path, default=None, help="a chain's project instead of the demo (full-size frames)")
    ap.add_argument("--footprints", type=Path, default=None,
                    help="the footprints of the footprints' ways (copied into each way's truth/footprints.gpkg) "
                         "instead of those written from the truth's buildings.geojson, e.g. a chain's "
                         "lidar_out/roof_outlines.gpkg (its default since stop 113)")
    ap.add_argument("--truth", type=Path, default=None,
                    help="the simulator's truth folder of the block (default: truth/ of the demo or --project)")
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_footprints_cost")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--key", default="footprints_demo")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_cost.json")
    ap.add_argument("--sha256", type=Path, default=None)
    ap.add_argument("--per-frame", action="store_true",
                    help=f"a fourth way, {PER_FRAME}: the footprints rasterised per frame (the frame orthos compared)")
    ap.add_argument("--no-roofs", action="store_true", help="with --truth: leave the roofs out")
    ap.add_argument("--roofs-only", action="store_true",
                    help="with --truth: only the roofs of the frame orthos --work holds, into the key --key has")
    ap.add_argument("--ways", default=None, help="comma-separated subset of the ways (conventional first)")
    ap.add_argument("--sha256-all", type=Path, default=None)
    ap.add_argument("--crowns", action="store_true", help="a further way: footprints and the LiDAR's crown bases")
    ap.add_argument("--occlusion", action="store_true",
                    help="two further ways: the occlusion test on lidar_out/dsm_nearest.tif (the chain's), without and "
                         "with footprints")
    ap.add_argument("--chain-crowns", action="store_true",
                    help="two further ways: the chain's default, the occlusion test on lidar_out/dsm_crowns.tif with "
                         "the fitted crowns lidar_out/crowns.gpkg, without and with footprints")
    ap.add_argument("--steps", action="store_true",
                    help="the thread CPU of the occlusion test's steps (STEPS) per block, in each run")
    ap.add_argument("--frames", default=None, help="comma-separated image ids: only these frames (default: all)")
    ap.add_argument("--code", type=Path, default=None, help="import the toolkit from this folder (e.g. main's)")
    ap.add_argument("--sha256-against", type=Path, default=None,
                    help="compare each way's frame orthos with this --sha256-all file")
    args = ap.parse_args()
    import shutil

    from eval_true_ortho_dsm_cell import lidar_crown_base
    from results_json import store_result
    from true_ortho_cost import small_project

    if args.code is not None:  # the bench modules above put this checkout first: the toolkit imported again from DIR
        sys.path.insert(0, str(args.code.resolve()))
        for name in [m for m in sys.modules if m.split(".")[0] in ("aerotri", "ortho", "lidarctl")]:
            del sys.modules[name]
        import ortho

        if not Path(ortho.__file__).resolve().is_relative_to(args.code.resolve()):
            raise SystemExit(f"--code {args.code}: ortho imported from {ortho.__file__}")

    from aerotri.core.atomic import write_text_atomic
    from aerotri.core.project import Project
    from aerotri.sim.project import write_footprints_gpkg

    ways = WAYS + ((PER_FRAME,) if args.per_frame else ()) + ((CROWNS,) if args.crowns else ()) \
        + (OCCLUSION if args.occlusion else ()) + (CHAIN_CROWNS if args.chain_crowns else ())
    if args.ways:
        ways = tuple(w for w in args.ways.split(",") if w in ways)
    if args.roofs_only:  # the frame orthos of an earlier run of this script: its key gets the roofs
        from results_json import read_results

        out = read_results(args.out)[args.key]
        out["roofs"] = roofs_of_ways({way: args.work / way for way in ways}, args.truth, ways)
        out["roofs_command"] = "python bench/true_ortho_footprints_cost.py " + " ".join(sys.argv[1:])
        print(json.dumps(out["roofs"], indent=1))
        store_result(args.out, out, key=args.key)
        return
    source = args.project or args.demo
    truth = args.truth or source / "truth"
    buildings = truth / "buildings.geojson"
    projects, n = {}, None
    for way in ways:
        p = projects[way] = args.work / way
        small_project(source, p)
        if args.project is not None and (source / "at" / "camera.toml").is_file():
            shutil.copy2(source / "at" / "camera.toml", p / "at" / "camera.toml")  # the camera of at/eo.txt
        (p / "truth").mkdir()
        if args.footprints is not None:
            shutil.copy2(args.footprints, p / "truth" / "footprints.gpkg")
        elif "footprints" in way or buildings.is_file():  # ways without footprints run on a block without truth
            n = write_footprints_gpkg(buildings, p / "truth" / "footprints.gpkg", Project.open(p).crs)
        if way in OCCLUSION:
            shutil.copy2(source / "lidar_out" / "dsm_nearest.tif", p / "lidar_out" / "dsm_nearest.tif")
        if way in CHAIN_CROWNS:
            for name in ("dsm_crowns.tif", "crowns.gpkg"):
                shutil.copy2(source / "lidar_out" / name, p / "lidar_out" / name)
        if way == CROWNS:
            lidar_crown_base(source, False, p / "lidar_out" / "dsm.tif", p / "lidar_out" / "crown_base.tif")
    if args.steps:
        _timed_steps()
    _timed_occluder()
    _counted_cells()
    frames = args.frames.split(",") if args.frames else None
    first = {}
    for way in ways:  # not counted: compiled code, imports
        first[way] = one_block(projects[way], way, frames)
        print("first", way, first[way], flush=True)
    runs = {way: [] for way in ways}
    for k in range(args.rounds):
        for way in ways:
            r = one_block(projects[way], way, frames)
            runs[way].append(r)
            print(k, way, r, flush=True)
    out = {"project": str(source), "buildings": str(buildings) if args.footprints is None else None,
           "footprints_file": str(args.footprints) if args.footprints is not None else None,
           "footprints": n, "rounds": args.rounds,
           "first_calls_not_counted": first, "ways": {}}
    for way, rs in runs.items():
        per_mp = sorted(r["cpu_s_per_mp"] for r in rs)
        out["ways"][way] = {"runs": rs, "cpu_s_per_mp_median": per_mp[len(per_mp) // 2], "cpu_s_per_mp_best": per_mp[0],
                            "wall_s_median": sorted(r["wall_s"] for r in rs)[len(rs) // 2],
                            "peak_rss_mb_max": max(r["peak_rss_mb"] for r in rs)}
    conv = out["ways"]["conventional"]["cpu_s_per_mp_median"]
    out["cpu_per_mp_ratio_to_conventional"] = {way: round(out["ways"][way]["cpu_s_per_mp_median"] / conv, 3)
                                               for way in ways[1:]}
    out["cpu_per_mp_ratio_best"] = {way: round(out["ways"][way]["cpu_s_per_mp_best"]
                                               / out["ways"]["conventional"]["cpu_s_per_mp_best"], 3)
                                    for way in ways[1:]}  # each way's least CPU over the conventional's least
    out["wall_ratio_to_conventional"] = {way: round(out["ways"][way]["wall_s_median"]
                                                    / out["ways"]["conventional"]["wall_s_median"], 3)
                                         for way in ways[1:]}
    # the same ratio round by round (each round's three calls ran back to back)
    out["cpu_per_mp_ratio_by_round"] = {way: [round(runs[way][k]["cpu_s_per_mp"] / runs["conventional"][k]["cpu_s_per_mp"], 3)
                                              for k in range(args.rounds)] for way in ways[1:]}
    out["command"] = "python bench/true_ortho_footprints_cost.py " + " ".join(sys.argv[1:])
    out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    if args.code is not None:
        out["code"] = str(args.code)
    print(json.dumps({k: v for k, v in out.items() if k != "ways"}, indent=1))
    if PER_FRAME in ways and "true_ortho_footprints" in ways:
        a, b = frame_sha256(projects["true_ortho_footprints"]), frame_sha256(projects[PER_FRAME])
        out["per_frame_identical_frame_orthos"] = f"{sum(a[k] == b.get(k) for k in a)} of {len(a)}"
    if args.sha256:
        write_text_atomic(args.sha256, json.dumps(frame_sha256(projects["true_ortho_footprints"]), indent=1) + "\n")
    if args.sha256_all or args.sha256_against:
        sha = {way: frame_sha256(projects[way]) for way in ways}
        if args.sha256_all:
            write_text_atomic(args.sha256_all, json.dumps(sha, indent=1) + "\n")
        if args.sha256_against:
            ref = json.loads(args.sha256_against.read_text())
            out["identical_to"] = {"file": str(args.sha256_against), **{
                way: f"{sum(ref[way].get(k) == v for k, v in sha[way].items())} of {len(sha[way])}"
                for way in ways if way in ref}}
            print(json.dumps(out["identical_to"], indent=1))
    if args.truth is not None and not args.no_roofs:
        out["roofs"] = roofs_of_ways(projects, args.truth, [way for way in ways if way != PER_FRAME])
        print(json.dumps(out["roofs"], indent=1))
    store_result(args.out, out, key=args.key)


if __name__ == "__main__":
    main()
