"""The cost of the true ortho against the conventional one, per MP of frame ortho, on the demo and on full-size
DMC frames (issue 42) -> bench/results/true_ortho_cost.json.

Both ways in the same process and run, frame by frame, alternating (conventional, true, conventional, ...), so
that the load of the shared machine falls on both alike:

- conventional: ``rectify_block`` of the frame on the DEM (lidar_out/dem.tif), as ``ortho rectify P --frames F``;
- true: ``rectify_block`` with ``true_ortho`` on the LiDAR DSM (lidar_out/dsm.tif), as
  ``ortho rectify P --frames F --true-ortho --dsm P/lidar_out/dsm.tif``.

CPU is the process's (user + sys of all its threads, ``time.process_time``) per call; one call of each way runs
first and is not counted (numba's compiled-code cache, the one-time scan of each height raster per process).
Wall time is stated with the machine's load average. Also measured:

- ``cli``: each way as one ``ortho rectify`` command over the same frames (a child process: CPU = the child's
  user + sys), which includes the start-up and the per-run scans of the DEM and the DSM;
- ``occlusion_agreement`` (full-size frames only): on a spread of 1024 px tiles of one frame, the true ortho's
  mask (z-buffer candidates, then the march) against the march over every pixel of the tile, and the march with
  its jumps over DSM blocks against the march step by step (the same sample positions: no pixel may differ).

The full-size project is made from /work/bench_blocks/dmc_block_subset_3x8_run (read only): images as symlinks,
camera, project.toml, at/eo.txt, lidar_out/dem.tif and dsm.tif copied into ``--work``.

Usage: python bench/true_ortho_cost.py [--demo /work/ref/demo_chain/project]
       [--dmc /work/bench_blocks/dmc_block_subset_3x8_run] [--dmc-frames s02_004,s02_005,s02_006] [--work DIR]
       python bench/true_ortho_cost.py --demo PROJECT --agreement-only FRAME [--agreement-tile-px 480]
       (the occlusion agreement alone, on a project with frame orthos: the march over columns only and over the
       ground cells)
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def small_project(src: Path, dst: Path) -> None:
    """What rectify needs of ``src`` in ``dst``: images linked, the rest copied."""
    if dst.exists():
        shutil.rmtree(dst)
    (dst / "images").mkdir(parents=True)
    for f in sorted((src / "images").iterdir()):
        os.symlink(f.resolve(), dst / "images" / f.name)
    for name in ("camera.toml", "project.toml"):
        shutil.copy2(src / name, dst / name)
    (dst / "at").mkdir()
    shutil.copy2(src / "at" / "eo.txt", dst / "at" / "eo.txt")
    (dst / "lidar_out").mkdir()
    for name in ("dem.tif", "dsm.tif"):
        shutil.copy2(src / "lidar_out" / name, dst / "lidar_out" / name)


def settings(project: Path, true_ortho: bool):
    from ortho.settings import RectifySettings

    return RectifySettings(true_ortho=True, dsm=str(project / "lidar_out" / "dsm.tif")) if true_ortho \
        else RectifySettings()


def one_frame(project: Path, frame: str, true_ortho: bool) -> dict:
    from ortho.block import read_index, rectify_block

    t, c = time.perf_counter(), time.process_time()
    rectify_block(project, settings(project, true_ortho), frames=[frame])
    cpu, wall = time.process_time() - c, time.perf_counter() - t
    e = next(e for e in read_index(project).document["frames"] if e["image_id"] == frame)  # with valid_fraction
    mp = e["width"] * e["height"] / 1e6
    return {"frame": frame, "frame_ortho_mp": round(mp, 3), "cpu_s": round(cpu, 3), "wall_s": round(wall, 3),
            "load_avg_1min": round(os.getloadavg()[0], 2), "valid_fraction": e["valid_fraction"]}


def in_process(work: Path, src: Path, frames: list[str], name: str) -> dict:
    ways = {"conventional": False, "true_ortho": True}
    projects = {}
    for way in ways:
        projects[way] = work / f"{name}_{way}"
        small_project(src, projects[way])
    for way, true in ways.items():  # not counted: compiled code, the scans of the height rasters
        one_frame(projects[way], frames[0], true)
    runs = {way: [] for way in ways}
    for f in frames:
        for way, true in ways.items():
            r = one_frame(projects[way], f, true)
            runs[way].append(r)
            print(name, way, r, flush=True)
    out = {"frames": frames, "ways": {}}
    for way, rs in runs.items():
        mp = sum(r["frame_ortho_mp"] for r in rs)
        cpu = sum(r["cpu_s"] for r in rs)
        wall = sum(r["wall_s"] for r in rs)
        out["ways"][way] = {"frames": rs, "frame_ortho_mp": round(mp, 2), "cpu_s": round(cpu, 2),
                            "cpu_s_per_frame": round(cpu / len(rs), 3), "cpu_s_per_mp": round(cpu / mp, 4),
                            "wall_s_per_mp": round(wall / mp, 4)}
    c, t = out["ways"]["conventional"], out["ways"]["true_ortho"]
    out["cpu_per_mp_ratio"] = round(t["cpu_s_per_mp"] / c["cpu_s_per_mp"], 3)
    out["wall_per_mp_ratio"] = round(t["wall_s_per_mp"] / c["wall_s_per_mp"], 3)
    return out


def cli(work: Path, name: str, frames: list[str] | None) -> dict:
    """Each way as one ``ortho rectify`` child process over ``frames`` (None: all)."""
    out = {}
    exe = Path(sys.executable).with_name("ortho")
    for way in ("conventional", "true_ortho"):
        p = work / f"{name}_{way}"
        shutil.rmtree(p / "ortho", ignore_errors=True)
        args = [str(exe), "rectify", str(p)] + (["--frames", ",".join(frames)] if frames else [])
        if way == "true_ortho":
            args += ["--true-ortho", "--dsm", str(p / "lidar_out" / "dsm.tif")]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(args, check=True, capture_output=True)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        index = json.loads((p / "ortho" / "frames" / "index.json").read_text())
        mp = sum(e["width"] * e["height"] for e in index["frames"]) / 1e6
        out[way] = {"frames": len(index["frames"]), "frame_ortho_mp": round(mp, 2), "cpu_s": round(cpu, 2),
                    "wall_s": round(wall, 2), "cpu_s_per_mp": round(cpu / mp, 4),
                    "load_avg_1min": round(os.getloadavg()[0], 2)}
        print(name, "cli", way, out[way], flush=True)
    out["cpu_per_mp_ratio"] = round(out["true_ortho"]["cpu_s_per_mp"] / out["conventional"]["cpu_s_per_mp"], 3)
    return out


def occlusion_agreement(project: Path, frame: str, tiles: int = 6, tile_px: int = 1024,
                        columns: bool = False) -> dict:
    """The true ortho's occlusion (z-buffer, then the march for its candidates) against the march over every
    pixel, on ``tiles`` tiles spread over the frame's grid; and the jumping march against the step-by-step one. The
    march's continuous surface over the ground cells of the DSM on the DEM (lidar_out/dem.tif), as ``ortho rectify
    --true-ortho`` passes them; ``columns``: none, every DSM cell a column (this bench before 2026-12-01)."""
    from aerotri.geom.rotation import rotation_matrix_opk
    from ortho import rectify as RF
    from ortho.block import _plane_footprint_bounds, load_block
    from ortho.dem import open_height_raster, read_height_window
    from ortho.grid import GridToProject

    b = load_block(project)
    i = b.eo.row(frame)
    C, R = b.eo.centre_m[i], rotation_matrix_opk(*b.eo.opk_deg[i])
    index = json.loads((project / "ortho" / "frames" / "index.json").read_text())
    with open_height_raster(project / "lidar_out" / "dsm.tif", b.project_crs, "DSM") as ds:
        zlo, zhi = float(np.nanmin(ds.read(1, masked=True))), float(np.nanmax(ds.read(1, masked=True)))
        bounds = _plane_footprint_bounds(b.camera, C, R, zlo - 5.0, zhi + 5.0, frame)
        dsm = read_height_window(ds, bounds, margin_m=4 * ds.transform.a, what="DSM")
    with open_height_raster(project / "lidar_out" / "dem.tif", b.project_crs, "DEM") as ds:
        dem = read_height_window(ds, bounds, margin_m=4 * ds.transform.a, what="DEM")
    ground = None if columns else RF.ground_cells(dsm, dem)
    to_project = GridToProject(b.project_crs, b.project_crs)
    grid = RF.frame_grid(b.camera, C, R, dsm, float(index["res_m"]), b.project_crs, to_project=to_project, partial=True)
    geometry = RF.FrameGeometry(b.camera, np.asarray(C, float), np.asarray(R, float))
    zbuffer = RF.frame_zbuffer(geometry, dsm, grid, to_project, tile_px)
    bound = RF.march_bound(dsm)
    stepwise = RF.MarchBound(bound.max_m, np.full_like(bound.block_max_m, np.inf), bound.block,
                             np.full_like(bound.coarse_max_m, np.inf), bound.coarse)
    rng = np.random.default_rng(42)
    starts = [(r0, c0) for r0 in range(0, grid.height - tile_px + 1, tile_px)
              for c0 in range(0, grid.width - tile_px + 1, tile_px)]
    picked = [starts[k] for k in sorted(rng.choice(len(starts), size=min(tiles, len(starts)), replace=False))]
    imaged = occluded = disagree = jump_differs = candidates = 0
    t_full = t_jump = t_step = 0.0
    for r0, c0 in picked:
        tile = grid.window(c0, r0, tile_px, tile_px)
        map_int, _, mask, z, anchors = RF.fixed_point_maps(geometry, dsm, tile, to_project)
        ok = mask > 0
        behind = RF.zbuffer_occlusion_from_maps(geometry, zbuffer, tile, map_int, mask, z,
                                                out=np.empty(z.shape, bool))
        occ = RF.occlusion_mask(geometry, dsm, tile, z, anchors, candidates=behind, bound=bound, ground=ground)
        c = time.process_time()
        full = RF.occlusion_mask(geometry, dsm, tile, z, anchors, bound=bound, ground=ground)
        t_full += time.process_time() - c
        c = time.process_time()
        jump = RF.occlusion_mask(geometry, dsm, tile, z, anchors, candidates=behind, bound=bound, ground=ground)
        t_jump += time.process_time() - c
        c = time.process_time()
        step = RF.occlusion_mask(geometry, dsm, tile, z, anchors, candidates=behind, bound=stepwise, ground=ground)
        t_step += time.process_time() - c
        imaged += int(ok.sum())
        occluded += int((full & ok).sum())
        candidates += int((behind & ok).sum())
        disagree += int(((occ != full) & ok).sum())
        jump_differs += int(((jump != step) & ok).sum())
    return {"frame": frame, "march": "columns only" if columns else "ground cells of the DSM on the DEM",
            "tiles": [list(t) for t in picked], "tile_px": tile_px, "imaged_px": imaged,
            "occluded_by_full_march": occluded, "occluded_share": round(occluded / imaged, 5),
            "zbuffer_candidates": candidates, "candidate_share": round(candidates / imaged, 5),
            "differ_from_full_march": disagree, "differ_share": disagree / imaged,
            "jumping_vs_stepwise_march_differ": jump_differs,
            "march_cpu_s": {"candidates_jumping": round(t_jump, 2), "candidates_stepwise": round(t_step, 2),
                            "every_pixel_jumping": round(t_full, 2)}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--demo", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--demo-frames", default=None, help="comma-separated (default: every frame of the demo)")
    ap.add_argument("--dmc", type=Path, default=Path("/work/bench_blocks/dmc_block_subset_3x8_run"))
    ap.add_argument("--dmc-frames", default="s02_004,s02_005,s02_006")
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_cost")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_cost.json")
    ap.add_argument("--skip-dmc", action="store_true")
    ap.add_argument("--agreement-only", default=None, metavar="FRAME",
                    help="only the occlusion agreement on FRAME of --demo (its ortho/frames/index.json), tiles of "
                         "--agreement-tile-px, with and without the ground cells; merged into --out as "
                         "occlusion_agreement_<project>")
    ap.add_argument("--agreement-tile-px", type=int, default=1024)
    args = ap.parse_args()
    if args.agreement_only:
        from aerotri.core.atomic import write_text_atomic

        got = {way: occlusion_agreement(args.demo, args.agreement_only, tile_px=args.agreement_tile_px,
                                        columns=way == "columns_only")
               for way in ("columns_only", "ground_cells")}
        got["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                       text=True).stdout.strip()
        print(json.dumps(got, indent=1), flush=True)
        doc = json.loads(args.out.read_text()) if args.out.exists() else {}
        doc[f"occlusion_agreement_{args.demo.parent.name}"] = got
        write_text_atomic(args.out, json.dumps(doc, indent=1) + "\n")
        return
    args.work.mkdir(parents=True, exist_ok=True)
    out = {"machine": {"cores": os.cpu_count()}, "note": "CPU = user + sys of every thread of the process (in-process) "
           "or of the child (cli); the first call of each way in-process is not counted"}
    from aerotri.geom.eo import read_eo

    demo_frames = args.demo_frames.split(",") if args.demo_frames else list(read_eo(args.demo / "at" / "eo.txt").image_id)
    out["demo"] = {"project": str(args.demo), "in_process": in_process(args.work, args.demo, demo_frames, "demo")}
    out["demo"]["cli"] = cli(args.work, "demo", None)
    if not args.skip_dmc:
        frames = args.dmc_frames.split(",")
        out["full_size"] = {"project": str(args.dmc), "in_process": in_process(args.work, args.dmc, frames, "dmc")}
        out["full_size"]["cli"] = cli(args.work, "dmc", frames)
        out["full_size"]["occlusion_agreement"] = occlusion_agreement(args.work / "dmc_true_ortho", frames[0])
        print(json.dumps(out["full_size"]["occlusion_agreement"], indent=1), flush=True)
    out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    from aerotri.core.atomic import write_text_atomic

    write_text_atomic(args.out, json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
