"""Frames of the full-size block per CPU-second: the simulator's frames phase (``aerotri.sim.project._render_frames``:
render, expose, write the tiled 16-bit ZSTD TIFFs) of ``dmc_block`` frames (13824 x 7680 px) with this code against
an earlier commit's, each side in its own process, in the same session (issue 41: a renderer at 20+ MP/s, i.e. at
least 10 MP per CPU-second on the 2 cores).

Each side (``--before``: the package folders of the earlier commit, e.g. ``git archive main aerotri lidarctl ortho |
tar -x -C DIR``) builds the scene of ``dmc_block`` with ``--set`` overrides (default one strip of 3 frames: the
scene grows with the flight), compiles (or loads) the renderer by rendering one band, then makes the frames as
``simulate`` does (same seeds, same GDAL cache), timed with ``aerotri.core.resources.measure`` (CPU: user + sys
of every thread of the process). Then, not counted: the frames' pixels are hashed (SHA-256 of the decoded
samples, so file metadata does not count) and the first frame is written again from memory, to give the share of
the TIFF writing and its compression. The sides alternate ``--rounds`` times (the machine's load changes); the
least CPU of each side and the ratio of MP per CPU-second are reported with the load average of every run.

    python bench/sim_frame_speed.py --before DIR [--rounds 2] [--work DIR] [--json bench/results/sim_frame_speed.json
        [--key NAME]] [--set flight.frames_per_strip=3 ...] [--busy-threads N]

``--busy-threads N``: N busy single-threaded processes run beside each measured run (a shared machine's other work,
the same for both sides); ``cores_busy`` of a run is its CPU-s over its wall seconds.

With ``--key`` the result goes under that key of the JSON file, the file's other keys kept (without: the file is
the result).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRESET = "dmc_block"
SETS = ["flight.strips=1", "flight.frames_per_strip=3"]


def _measure(sets: list[str], work: Path) -> dict:
    import numba
    import numpy as np
    import rasterio

    from aerotri.core.gdal_cache import stage_block_cache
    from aerotri.core.resources import measure
    from aerotri.geom.rotation import rotation_matrix_opk
    from aerotri.sim import load_preset, raster
    from aerotri.sim import project as P
    from aerotri.sim.flight import block_layout, cameras_from_config, plan_frames
    from aerotri.sim.scene import build_scene

    cfg = load_preset(PRESET, sets)
    ss = np.random.SeedSequence(int(cfg.preset.seed))
    s_scene, s_flight, s_frames, _ = ss.spawn(4)
    origin = np.array([cfg.crs.origin_e_m, cfg.crs.origin_n_m, cfg.crs.base_height_m])
    layout = block_layout(cfg)
    scene = build_scene(cfg.scene, layout.width_m, layout.height_m, origin,
                        int(np.random.default_rng(s_scene).integers(0, 2**31 - 1)))
    plan = plan_frames(cfg, layout, np.random.default_rng(s_flight))
    cam, _ = cameras_from_config(cfg.camera)
    look = raster.SceneLook(scene, P.texture_fine_m(cfg, cam))
    earth = P.sim_earth(cfg, layout)
    fl = P.frame_layout(cfg)
    # compile (or load the cached) renderer: one band of the first frame
    c0, t0 = time.process_time(), time.perf_counter()
    r = raster.FrameRenderer(scene, cam, look.fine_m, samples=int(cfg.render.samples), bits=fl.bits,
                             look=look, bands=fl.bands)
    R = rotation_matrix_opk(*plan.opk_deg[0])
    r.render_rows(r.setup(plan.centre_m[0], R, earth.frame_earth(plan.centre_m[0], R)), 0, raster.BAND_ROWS)
    compile_cpu = time.process_time() - c0
    compile_wall = time.perf_counter() - t0
    images = work / "images"
    shutil.rmtree(images, ignore_errors=True)
    images.mkdir(parents=True)
    load0 = os.getloadavg()
    with stage_block_cache(P.SIM_CACHE_BYTES), measure() as usage:
        P._render_frames(images, cfg, look=look, plan=plan, cam_true=cam, s_frames=s_frames, earth=earth)
    load1 = os.getloadavg()
    frames, block = {}, hashlib.sha256()
    for image_id in plan.image_id:
        with rasterio.open(images / f"{image_id}.tif") as ds:
            h = hashlib.sha256(ds.read().tobytes()).hexdigest()
        frames[str(image_id)] = h
        block.update(bytes.fromhex(h))
    # the TIFF writing alone: the first frame written again from memory by the same function (``_write_tiled_frame``)
    with rasterio.open(images / f"{plan.image_id[0]}.tif") as ds:
        pixels = np.moveaxis(ds.read(), 0, 2)
    size_mb = (images / f"{plan.image_id[0]}.tif").stat().st_size / 1e6

    class _Rendered:  # the rows at once, through either side's interface
        camera = cam

        def render_rows(self, frame, r0, r1, **expo):
            return pixels[r0:r1], None

        def submit_rows(self, frame, r0, r1, **expo):
            rows = pixels[r0:r1]
            return type("Done", (), {"result": lambda self: (rows, None)})()

    c, t = time.process_time(), time.perf_counter()
    with stage_block_cache(P.SIM_CACHE_BYTES):
        P._write_tiled_frame(work / "again.tif", _Rendered(), None, {}, fl)
    write_cpu, write_wall = time.process_time() - c, time.perf_counter() - t
    shutil.rmtree(images)
    (work / "again.tif").unlink()
    n = len(plan.image_id)
    mp = n * cam.width * cam.height / 1e6
    return {"frames": n, "frame_px": [cam.width, cam.height], "megapixels": round(mp, 1), "sha256": block.hexdigest(),
            "frame_sha256": frames, "cpu_s": round(usage.cpu_s, 2), "wall_s": round(usage.wall_s, 2),
            "peak_rss_mb": None if usage.peak_rss_mb is None else round(usage.peak_rss_mb, 1),
            "mp_per_cpu_s": round(mp / usage.cpu_s, 2), "mp_per_wall_s": round(mp / usage.wall_s, 2),
            "compile_cpu_s": round(compile_cpu, 2), "compile_wall_s": round(compile_wall, 2),
            "tiff_write_cpu_s_per_frame": round(write_cpu, 2), "tiff_write_wall_s_per_frame": round(write_wall, 2),
            "tiff_mb_per_frame": round(size_mb, 1), "compression": fl.compress,
            "numba_threads": numba.get_num_threads(), "numba_threading_layer": numba.threading_layer(),
            "load_average_before": [round(v, 2) for v in load0], "load_average_after": [round(v, 2) for v in load1]}


def _side(code: Path, a: argparse.Namespace, work: Path) -> dict:
    from lidar_common import measure_on_tree

    # other work on the machine, the same for both sides: busy single-threaded processes at this niceness
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.busy_threads)]
    try:
        # both sides read this checkout's presets (a tree from ``git archive`` has no datasets/presets)
        r = measure_on_tree(code, __file__, ["--work", work] + [x for s in a.set for x in ("--set", s)],
                            env={"AEROTRI_PRESETS": str(ROOT / "datasets" / "presets")})
    finally:
        for p in busy:
            p.kill()
            p.wait()
    return {**r, "busy_threads": a.busy_threads, "cores_busy": round(r["cpu_s"] / r["wall_s"], 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="folder holding the earlier commit's aerotri, lidarctl, ortho")
    ap.add_argument("--set", action="append", help=f"preset override (default {' '.join(SETS)})")
    ap.add_argument("--rounds", type=int, default=2, help="before/after runs, alternating")
    ap.add_argument("--busy-threads", type=int, default=0,
                    help="busy single-threaded processes beside each run (other work on a shared machine)")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "sim_frame_speed")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--key", help="store the result under this key of the --json file, keeping its other keys")
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    a.set = a.set or SETS
    if a.measure:
        a.work.mkdir(parents=True, exist_ok=True)
        print(json.dumps(_measure(a.set, a.work)))
        return
    if a.before is None:
        ap.error("--before DIR is needed")
    sys.path.insert(0, str(ROOT / "bench"))
    from lidar_common import alternate_rounds
    from results_json import git_commit, store_result

    def measure(code: Path, side: str, k: int) -> dict:
        r = _side(code, a, a.work / side)
        print(f"round {k + 1} {side:6s} {r['megapixels']} MP: {r['cpu_s']} CPU-s ({r['mp_per_cpu_s']} MP per "
              f"CPU-s), "
              f"wall {r['wall_s']} s ({r['mp_per_wall_s']} MP/s, {r['cores_busy']} cores), TIFF write {r['tiff_write_cpu_s_per_frame']} "
              f"CPU-s a frame, load {r['load_average_before'][0]}-{r['load_average_after'][0]}", flush=True)
        return r

    runs = alternate_rounds(a.before.resolve(), ROOT, a.rounds, measure)
    best = {s: min(v, key=lambda r: r["cpu_s"]) for s, v in runs.items()}
    identical = len({r["sha256"] for v in runs.values() for r in v}) == 1
    ratio = best["after"]["mp_per_cpu_s"] / best["before"]["mp_per_cpu_s"]
    print(f"frames identical {identical}; MP per CPU-s (least CPU of each side) {best['before']['mp_per_cpu_s']} -> "
          f"{best['after']['mp_per_cpu_s']}: {ratio:.2f}x")
    if a.json:
        commit = git_commit(ROOT)
        doc = {"preset": PRESET, "sets": a.set, "rounds": a.rounds, "busy_threads": a.busy_threads, "commit": commit,
               "before": str(a.before), "identical": identical, "mp_per_cpu_s_before": best["before"]["mp_per_cpu_s"],
               "mp_per_cpu_s_after": best["after"]["mp_per_cpu_s"], "ratio": round(ratio, 3), "runs": runs}
        if a.key:
            store_result(a.json, doc, key=a.key)
        else:  # the whole file is this run
            from aerotri.core.atomic import write_text_atomic

            write_text_atomic(a.json, json.dumps(doc, indent=1) + "\n")
            print(f"wrote {a.json}")


if __name__ == "__main__":
    main()
