"""Same bits, same speed (issue 40, fourth round): the numba kernels whose argument groups are now tuples or
NamedTuples (scene geometry, a camera, a triangle's vertices, a grid, a tile layout, ...) or keyword-only, called
through the public functions above them, against the code before the change.

Calls: the simulator's ray caster (``render.render_frame``: ``raycast.cast``, ``render_rays``, ``surface_albedo``)
and rasteriser (``raster.FrameRenderer.render`` and ``ortho_render``: ``_raster_tri``, ``_hit_normal``,
``_expose_row``, ``shading.shade_points``), ``ortho.synthetic.render_frame``, ``lidarctl``'s ``knn_2d``,
``CellStats.core_grids``, ``locate_in_tin``, ``low_outliers``/``high_outliers``, ``delaunay_lattice``,
``local_plane_offsets``, ``fill_nodata_tin``, ``TileGrid.memberships``/``core_near``, ``condition`` (fill and
breach), ``segment_cell_minima``, and the adjustment's ``schur.reduced_camera_system`` / ``sum_of_squares`` /
``point_increments`` and ``check_points.refined_normals`` / ``ray_leverages``.

Each side runs in its own process with ``PYTHONPATH`` set to its code (``--before``: the package folders of the
earlier commit, ``git archive main aerotri lidarctl ortho datasets/presets | tar -x -C DIR``), on the same seeded inputs: SHA-256
of every output array and CPU seconds per call (the median of ``--repeat`` calls after a warm-up call that
compiles or loads the kernels; the sides alternate ``--rounds`` times and each side's least median is reported,
as the machine's load changes, and the median of its rounds' medians).

    python bench/eval_kernel_args.py --before DIR [--rounds 3] [--repeat 5] [--only CALL]
        [--json bench/results/kernel_args.json]

``--compile``: instead, numba's compilation of the calls (each side with an empty ``NUMBA_CACHE_DIR``, one call
each): the compile CPU seconds per call and in all, timed by ``bench/eval_numba_compile.py``'s listener of
numba's ``numba:compile`` event (exclusive thread CPU seconds), ``--rounds`` runs a side, the least reported.

    python bench/eval_kernel_args.py --before DIR --compile [--rounds 2] [--json bench/results/kernel_args_compile.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _calls() -> dict:
    import numpy as np

    calls = {}

    # --- the simulator: ray caster and rasteriser on the tiny preset's scene
    def sim_inputs():
        from aerotri.geom.camera import BrownCamera
        from aerotri.geom.rotation import rotation_matrix_opk as opk_to_matrix
        from aerotri.sim import load_preset
        from aerotri.sim.flight import block_layout
        from aerotri.sim.scene import build_scene

        cfg = load_preset("tiny", ())
        layout = block_layout(cfg)
        scene = build_scene(cfg.scene, layout.width_m, layout.height_m, np.zeros(3), 12345)
        cam = BrownCamera(focal_mm=20.0, pixel_um=12.0, width=640, height=384, ppx_mm=0.05, ppy_mm=-0.03, k1=-0.01)
        C = np.array([0.45 * layout.width_m, 0.5 * layout.height_m, float(scene.terrain_z.max()) + 220.0])
        return scene, cam, C, opk_to_matrix(2.0, -3.0, 10.0)

    sim = {}

    def sim_get():
        if not sim:
            sim["v"] = sim_inputs()
        return sim["v"]

    def ray_caster():
        from aerotri.sim import raycast, render

        scene, cam, C, R = sim_get()
        rad, ids = render.render_frame(scene, raycast.build_accel(scene), cam, C, R, samples=1, with_ids=True)
        return [rad, ids]

    def rasteriser():
        from aerotri.sim import raster

        scene, cam, C, R = sim_get()
        fr = raster.FrameRenderer(scene, cam, 0.5, samples=2, bits=12)
        img, ids = fr.render(C, R, with_ids=True, gain=1.1, vignetting=0.2, noise_dn=2.0, noise_seed=5)
        img8, _ = raster.FrameRenderer(scene, cam, 0.5, samples=1, bits=8, look=fr.look).render(C, R, noise_dn=1.0)
        return [img, ids, img8]

    def ortho_render():
        from aerotri.sim import raster

        scene = sim_get()[0]
        look = raster.SceneLook(scene, 0.5)
        z, rad, ids = raster.ortho_render(look, 5.0, float(scene.height_m) - 5.0, 0.2, r0=0, r1=700, ncols=900)
        return [z, rad, ids]

    calls.update(sim_ray_caster=ray_caster, sim_rasteriser=rasteriser, sim_ortho_render=ortho_render)

    # --- ortho.synthetic: frames rendered from an orthophoto on a DEM
    def ortho_synthetic():
        from aerotri.geom.camera import BrownCamera
        from aerotri.geom.rotation import rotation_matrix_opk as opk_to_matrix
        from ortho.grid import OrthoGrid
        from ortho.synthetic import add_box_buildings, render_frame, smooth_dem, textured_orthophoto

        cam = BrownCamera(focal_mm=24.0, pixel_um=12.0, width=300, height=200, ppx_mm=0.05, ppy_mm=-0.03, k1=-0.04)
        e0, n0 = 452000.0, 3407000.0
        grid = OrthoGrid(None, e0, n0 + 160.0, 0.2, 1000, 800)
        ortho = textured_orthophoto(grid.height, grid.width, 3, 7)
        dem = smooth_dem((e0 - 40, n0 - 40, e0 + 240, n0 + 200), 0.5, base_m=300.0, amplitude_m=6.0)
        dsm, _ = add_box_buildings(dem, 10, size_m=(8.0, 16.0), height_m=(8.0, 15.0), seed=7,
                                   bounds=(e0 + 30, n0 + 30, e0 + 170, n0 + 130))
        C, R = np.array([e0 + 100.0, n0 + 80.0, 700.0]), opk_to_matrix(1.0, -2.0, 3.0)
        a, va = render_frame(ortho, grid, dem, cam, C, R)
        b, vb = render_frame(ortho, grid, dsm, cam, C, R, march=True)
        return [a, va, b, vb]

    calls["ortho_synthetic_render"] = ortho_synthetic

    # --- lidarctl
    rng = np.random.default_rng(40)
    n = 300_000
    x = rng.uniform(0.0, 300.0, n)
    y = rng.uniform(0.0, 200.0, n)
    z = 50.0 + 0.05 * x + np.sin(y / 20.0) + rng.normal(0.0, 0.05, n)
    z[rng.choice(n, 300, replace=False)] -= 8.0
    z[rng.choice(n, 300, replace=False)] += 30.0

    def knn():
        from lidarctl.knn import knn_2d

        q = slice(0, n, 7)
        d, i, tied = knn_2d(x, y, x[q] + 0.01, y[q], 12, 3.0)
        return [d, i, np.array([tied])]

    def cell_stats():
        from lidarctl.rasters.cells import CellStats

        st = CellStats(0.5, 0.0, 0.0, 400, 600)
        cls = np.where(rng.random(n) < 0.6, 2, 5).astype(np.uint8)
        rgen = np.random.default_rng(1)
        st.add(x, y, z, cls, rgen.integers(1, 3, n).astype(np.uint8), rgen.integers(0, 4000, n).astype(np.uint16))
        dem = 50.0 + 0.05 * (np.arange(600) * 0.5 + 0.25)[None, :] + np.zeros((400, 1))
        st.add_chm(x, y, z, cls, dem)
        fp = np.ones((400, 600), bool)
        fp[:20] = False
        dsm = dem + rgen.normal(0.0, 0.3, dem.shape)
        dsm[50:60, 50:70] = np.nan
        a = st.core_grids(fp, dem, dsm, (slice(10, 390), slice(20, 580)), z_m=1.0, metric=True, nodata=-9999.0)
        b = st.core_grids(fp, dem, dsm, (slice(0, 400), slice(0, 600)), z_m=0.3048, metric=False, nodata=-1.0)
        return [a, b]

    def locate():
        from scipy.spatial import Delaunay

        from lidarctl.classify.ground import locate_in_tin

        k = slice(0, n, 40)
        tri = Delaunay(np.column_stack([x[k], y[k]]))
        return [locate_in_tin(x[k], y[k], tri.simplices, x, y)]

    def noise():
        from lidarctl.classify.noise import high_outliers, low_outliers

        return [low_outliers(x, y, z, 2.0), high_outliers(x, y, z, 2.0)]

    def tin_lattice():
        from lidarctl.raster_tin import delaunay_lattice

        r = np.random.default_rng(3)
        rows, cols = np.nonzero(r.random((300, 300)) < 0.3)
        pts = np.column_stack([cols + r.uniform(-0.004, 0.004, len(cols)), rows + r.uniform(-0.004, 0.004, len(rows))])
        simp, status = delaunay_lattice(pts, rows.astype(np.int64), cols.astype(np.int64))
        return [simp, np.array([status])]

    def plane_offsets():
        from lidarctl.classify.pipeline import local_plane_offsets

        q = np.arange(0, n, 5)
        return list(local_plane_offsets(x, y, z, np.arange(n), q, k=8, radius_m=1.5))

    def fill_tin():
        from lidarctl.raster_ops import fill_nodata_tin

        r = np.random.default_rng(5)
        a = 50.0 + np.cumsum(r.normal(0.0, 0.1, (400, 500)), axis=1)
        a[r.random(a.shape) < 0.2] = np.nan
        a[100:140, 200:260] = np.nan
        return [fill_nodata_tin(a, 30.0)]

    def tiles():
        from lidarctl.tiles import TileGrid

        g = TileGrid(-10.0, -5.0, 50.0, 6.0, 5, 7)
        return [*g.memberships(x, y), *g.core_near(x, y)]

    def drainage():
        from lidarctl.terrain.drainage import condition

        r = np.random.default_rng(6)
        d = 100.0 + np.cumsum(np.cumsum(r.normal(0.0, 0.05, (400, 400)), axis=0), axis=1) * 0.01
        d[r.random(d.shape) < 0.01] = np.nan
        return [condition(d, "fill").dem, condition(d, "breach").dem]

    def minima():
        from lidarctl.grid import segment_cell_minima

        s = segment_cell_minima(x, y, z, 1.0, 0.5, 0.3)
        return [s.lowest, s.label, s.size, s.ua, s.ub, s.dz]

    calls.update(lidar_knn=knn, lidar_cell_stats=cell_stats, lidar_locate_in_tin=locate, lidar_noise=noise,
                 lidar_delaunay_lattice=tin_lattice, lidar_plane_offsets=plane_offsets, lidar_fill_tin=fill_tin,
                 lidar_tiles=tiles, lidar_drainage=drainage, lidar_minima=minima)

    # --- the adjustment: a block of rays through a Brown camera
    def block():
        from aerotri.adjust import schur
        from aerotri.geom.rotation import rotation_matrix_opk as opk_to_matrix

        r = np.random.default_rng(9)
        n_im, m = 24, 20000
        centre = np.column_stack([np.repeat(np.arange(6) * 300.0, 4), np.tile(np.arange(4) * 400.0, 6),
                                  np.full(n_im, 1500.0)]) + r.normal(0.0, 5.0, (n_im, 3))
        R_cv = np.array([opk_to_matrix(*r.normal(0.0, 2.0, 3)) @ np.diag([1.0, -1.0, -1.0]) for _ in range(n_im)])
        pts = np.column_stack([r.uniform(0, 1500, m), r.uniform(0, 1200, m), r.normal(0.0, 10.0, m)])
        cal = np.array([10000.0, 10000.0, 0.0, 6900.0, 3800.0, -1e-2, 1e-3, 1e-5, -1e-5])
        pi, ii = [], []
        for j in range(m):
            near = np.argsort(np.hypot(*(centre[:, :2] - pts[j, :2]).T))[: r.integers(2, 7)]
            pi += [j] * len(near)
            ii += list(near)
        pi, ii = np.array(pi), np.array(ii)
        pc = np.einsum("kji,kj->ki", R_cv[ii], pts[pi] - centre[ii])
        xn, yn = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
        xy = np.column_stack([cal[0] * xn + cal[3], cal[1] * yn + cal[4]]) + r.normal(0.0, 0.5, (len(pi), 2))
        pr = schur.ray_pairs(np.arange(len(pi)), pi, ii, n_im)
        return schur, xy[pr.obs], ii[pr.obs], pr, centre, R_cv, pts + r.normal(0.0, 0.3, pts.shape), cal, pi, ii, xy

    blk = {}

    def block_get():
        if not blk:
            blk["v"] = block()
        return blk["v"]

    def adjust_schur():
        schur, xy, image, pr, centre, R_cv, pts, cal, _, _, _ = block_get()
        out = []
        for with_cal, huber_k in ((False, 0.0), (True, 1.5)):
            rs = schur.reduced_camera_system(
                xy, image, pr.row, pr.start, pr.a, pr.b, pair_block=pr.pair_block, n_blocks=len(pr.images),
                n_images=len(centre), centre=centre, R_cv=R_cv, points=pts, cal=cal, inv_sigma=2.0, with_cal=with_cal,
                huber_k=huber_k, point_r=np.zeros(len(pts)), point_B=np.zeros((len(pts), 3)), point_damping=1e-3)
            out += [np.asarray(a, float) for a in rs[:5]] + [rs[5], rs[6], rs[7], rs[8], rs[9], rs[10], rs[11]]
            d_pose = np.random.default_rng(2).normal(0.0, 1e-3, (len(centre), 6))
            out.append(schur.point_increments(rs[5], rs[6], rs[7], rs[11], image, pr.start, d_pose=d_pose,
                                              d_cal=np.full(9, 1e-4)))
            out.append(np.array([schur.sum_of_squares(xy, image, pr.row, centre, R_cv, pts, cal=cal, inv_sigma=2.0,
                                                      huber_k=huber_k)]))
        return out

    def adjust_check_points():
        from aerotri.adjust.check_points import ray_leverages, refined_normals

        _, _, _, _, centre, R_cv, pts, cal, pi, ii, xy = block_get()
        p, N = refined_normals(xy, pi, ii, centre, R_cv, cal, points=pts, iterations=3)
        return [p, N, ray_leverages(pi, ii, centre, R_cv, cal, p, N_inv=np.linalg.inv(N + 1e-9 * np.eye(3)))]

    calls.update(adjust_schur=adjust_schur, adjust_check_points=adjust_check_points)
    return calls


def _measure(repeat: int, only: list[str] | None = None) -> dict:
    import numpy as np

    out = {}
    for name, fn in _calls().items():
        if only and name not in only:
            continue
        c0 = time.process_time()
        first = fn()
        warm = time.process_time() - c0
        h = hashlib.sha256()
        for a in first:
            a = np.ascontiguousarray(a)
            h.update(str((a.dtype.str, a.shape)).encode())
            h.update(a.tobytes())
        cpu = []
        for _ in range(repeat):
            c0 = time.process_time()
            fn()
            cpu.append(time.process_time() - c0)
        out[name] = {"sha256": h.hexdigest(), "cpu_s_median": float(np.median(cpu)),
                     "cpu_s_all": [round(c, 4) for c in cpu], "cpu_s_first_call": round(warm, 3)}
    return out


def _measure_compile(only: list[str] | None = None) -> dict:
    """Compile CPU seconds of each call's first run (an empty numba cache) and the numba compilations in all."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from eval_numba_compile import _Timer, records, summary
    from numba.core import event as ev

    ev.register("numba:compile", _Timer())
    out = {}
    for name, fn in _calls().items():
        if only and name not in only:
            continue
        n0 = len(records)
        fn()
        out[name] = round(sum(r["exclusive_cpu_s"] for r in records[n0:]), 3)
    s = summary(records)
    return {"calls": out, "compile_cpu_s": round(s["compile_cpu_s"], 3), "compilations": s["compilations"],
            "per_function_exclusive_cpu_s_count": s["per_function_exclusive_cpu_s_count"]}


def _side(code: Path, repeat: int, only: list[str] | None = None, compile_: bool = False) -> dict:
    import tempfile

    from lidar_common import measure_on_tree

    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR")) as cache:
        return measure_on_tree(code, __file__, ["--repeat", repeat, *(["--compile"] if compile_ else []),
                                                *[a for name in only or [] for a in ("--only", name)]],
                               # both sides read this checkout's presets (``git archive`` of the packages has none)
                               env={"AEROTRI_PRESETS": str(ROOT / "datasets" / "presets")}
                               | ({"NUMBA_CACHE_DIR": cache} if compile_ else {}), cwd=code)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="folder holding the earlier commit's aerotri, lidarctl, ortho")
    ap.add_argument("--rounds", type=int, default=3, help="before/after runs, alternating")
    ap.add_argument("--repeat", type=int, default=5, help="timed calls per run (after one warm-up call)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--only", action="append", help="measure only this call (repeatable)")
    ap.add_argument("--compile", action="store_true", help="measure numba's compilation instead (empty cache)")
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.measure:
        print(json.dumps(_measure_compile(a.only) if a.compile else _measure(a.repeat, a.only)))
        return
    if a.before is None:
        ap.error("--before DIR is needed")
    from lidar_common import alternate_rounds

    if a.compile:
        runs = alternate_rounds(a.before.resolve(), ROOT, a.rounds, lambda code, side, k: _side(code, 0, a.only, True))
        rows = {k: {"compile_cpu_s_before": min(r["calls"][k] for r in runs["before"]),
                    "compile_cpu_s_after": min(r["calls"][k] for r in runs["after"])} for k in runs["before"][0]["calls"]}
        total = {side: min(r["compile_cpu_s"] for r in rs) for side, rs in runs.items()}
        for k, r in rows.items():
            print(f"{k:26s} compile CPU {r['compile_cpu_s_before']:.2f} -> {r['compile_cpu_s_after']:.2f} s")
        print(f"{'all':26s} compile CPU {total['before']:.2f} -> {total['after']:.2f} s")
        if a.json:
            doc = {"rounds": a.rounds, "load_average": list(os.getloadavg()), "calls": rows,
                   "compile_cpu_s": total, "runs": runs}
            a.json.write_text(json.dumps(doc, indent=1) + "\n")
        return
    runs = alternate_rounds(a.before.resolve(), ROOT, a.rounds, lambda code, side, k: _side(code, a.repeat, a.only))
    before = runs["before"][0]
    rows = {k: {"identical": all(r[k]["sha256"] == before[k]["sha256"] for side in runs.values() for r in side),
                "cpu_s_before": round(min(r[k]["cpu_s_median"] for r in runs["before"]), 4),
                "cpu_s_after": round(min(r[k]["cpu_s_median"] for r in runs["after"]), 4),
                "cpu_s_before_median_of_rounds": round(statistics.median(r[k]["cpu_s_median"] for r in runs["before"]), 4),
                "cpu_s_after_median_of_rounds": round(statistics.median(r[k]["cpu_s_median"] for r in runs["after"]), 4)}
            for k in before}
    for k, r in rows.items():
        print(f"{k:26s} identical {r['identical']}  CPU {r['cpu_s_before']:.4f} -> {r['cpu_s_after']:.4f} s a call "
              f"(median of the rounds {r['cpu_s_before_median_of_rounds']:.4f} -> {r['cpu_s_after_median_of_rounds']:.4f})")
    if a.json:
        doc = {"rounds": a.rounds, "repeat": a.repeat, "load_average": list(os.getloadavg()), "calls": rows,
               "runs": runs}
        a.json.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
