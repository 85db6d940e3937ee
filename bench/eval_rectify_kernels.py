"""Same products, same speed: ``ortho rectify`` of the demo, conventional and true ortho, with this code against an
earlier commit's (issue 42: the lens fold and the view angle tested in the kernels; issue 40: the kernels' argument
groups packed into tuples).

Each side runs in its own process with ``PYTHONPATH`` set to its code (``--before``: a copy of the package folders
of the earlier commit, e.g. ``git archive main aerotri lidarctl ortho | tar -x -C DIR``) on a copy of the demo
project (images linked; camera, project.toml, at/eo.txt, lidar_out/dem.tif and dsm.tif copied): ``rectify_block``
of every frame on the DEM (conventional) and with ``--true-ortho --dsm lidar_out/dsm.tif``. Products: SHA-256 of
every frame ortho's samples and mask (decoded, so file metadata does not count), per frame and over the block.
Cost: CPU (user + sys of every thread of the process) and wall per MP of frame ortho; one frame of each way first,
not counted (the compiled code loaded, the height rasters scanned). The sides alternate ``--rounds`` times (the
machine's load changes); each side's least CPU is reported with the load average of every run.

    python bench/eval_rectify_kernels.py --before DIR [--demo out/demo/project] [--rounds 3] [--work DIR]
        [--images DIR] [--dem lidar_out/dem.tif] [--dsm lidar_out/dsm.tif] [--max-view-angle-deg DEG] [--crs CRS]
        [--json bench/results/rectify_kernels.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WAYS = ("conventional", "true_ortho")


def _small_project(src: Path, dst: Path, images: Path, rasters: tuple[str, ...]) -> None:
    """What rectify needs of ``src`` in ``dst``: the frames of ``images`` linked, the rest copied (``rasters``:
    the DEM and DSM, paths relative to the project)."""
    if dst.exists():
        shutil.rmtree(dst)
    (dst / "images").mkdir(parents=True)
    for f in sorted(images.iterdir()):
        os.symlink(f.resolve(), dst / "images" / f.name)
    for name in ("camera.toml", "project.toml", "at/eo.txt") + rasters:
        (dst / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src / name, dst / name)


def _products(project: Path) -> dict:
    """SHA-256 of every frame ortho's samples and mask, and of them all in frame order."""
    import rasterio

    index = json.loads((project / "ortho" / "frames" / "index.json").read_text())
    frames, block = {}, hashlib.sha256()
    for e in index["frames"]:
        with rasterio.open(project / "ortho" / "frames" / e["file"]) as ds:
            h = hashlib.sha256(ds.read().tobytes())
            h.update(ds.read_masks(1).tobytes())
            h.update(repr((tuple(ds.transform), ds.shape)).encode())
        frames[e["image_id"]] = h.hexdigest()
        block.update(h.digest())
    mp = sum(e["width"] * e["height"] for e in index["frames"]) / 1e6
    return {"sha256": block.hexdigest(), "frames": frames, "frame_ortho_mp": round(mp, 3)}


def _measure(demo: Path, work: Path, images: Path, dem: str, dsm: str, extra: dict) -> dict:
    from aerotri.geom.eo import read_eo
    from ortho.block import rectify_block
    from ortho.settings import RectifySettings

    frames = list(read_eo(demo / "at" / "eo.txt").image_id)
    out = {}
    for way in WAYS:
        p = work / way
        _small_project(demo, p, images, tuple(dict.fromkeys((dem, dsm))))
        s = RectifySettings(dem=str(p / dem), true_ortho=True, dsm=str(p / dsm), **extra) if way == "true_ortho" \
            else RectifySettings(dem=str(p / dem), **extra)
        rectify_block(p, s, frames=frames[:1])  # not counted
        shutil.rmtree(p / "ortho")
        c, t = time.process_time(), time.perf_counter()
        rectify_block(p, s)
        cpu, wall = time.process_time() - c, time.perf_counter() - t
        prod = _products(p)
        out[way] = {"sha256": prod["sha256"], "frames": prod["frames"], "frame_ortho_mp": prod["frame_ortho_mp"],
                    "cpu_s": round(cpu, 3), "wall_s": round(wall, 3),
                    "cpu_s_per_mp": round(cpu / prod["frame_ortho_mp"], 4),
                    "wall_s_per_mp": round(wall / prod["frame_ortho_mp"], 4),
                    "load_average": [round(v, 2) for v in os.getloadavg()]}
    return out


def _side(code: Path, a: argparse.Namespace, work: Path) -> dict:
    from lidar_common import measure_on_tree

    return measure_on_tree(code, __file__, ["--demo", a.demo.resolve(), "--work", work, "--images", a.images.resolve(),
                                            "--dem", a.dem, "--dsm", a.dsm, "--max-view-angle-deg", a.max_view_angle_deg]
                           + (["--crs", a.crs] if a.crs else []))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="folder holding the earlier commit's aerotri, lidarctl, ortho")
    ap.add_argument("--demo", type=Path, default=ROOT / "out" / "demo" / "project", help="the project")
    ap.add_argument("--images", type=Path, help="its frames (default: its images folder)")
    ap.add_argument("--dem", default="lidar_out/dem.tif", help="the DEM, relative to the project")
    ap.add_argument("--dsm", default="lidar_out/dsm.tif", help="the true ortho's DSM, relative to the project")
    ap.add_argument("--max-view-angle-deg", type=float, default=90.0, help="ortho rectify --max-view-angle-deg")
    ap.add_argument("--crs", help="ortho rectify --crs (default: the project CRS)")
    ap.add_argument("--rounds", type=int, default=3, help="before/after runs, alternating")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "rectify_kernels")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    a.images = a.images or a.demo / "images"
    if a.measure:
        extra = {"max_view_angle_deg": a.max_view_angle_deg} | ({"crs": a.crs} if a.crs else {})
        print(json.dumps(_measure(a.demo, a.work, a.images, a.dem, a.dsm, extra)))
        return
    if a.before is None:
        ap.error("--before DIR is needed")
    from lidar_common import alternate_rounds

    def measure(code: Path, side: str, k: int) -> dict:
        r = _side(code, a, a.work / side)
        print(f"round {k + 1} {side:6s} " + "  ".join(
            f"{w} {r[w]['cpu_s_per_mp']:.4f} CPU-s/MP (wall {r[w]['wall_s_per_mp']:.4f}, load "
            f"{r[w]['load_average'][0]:.1f})" for w in WAYS), flush=True)
        return r

    runs = alternate_rounds(a.before.resolve(), ROOT, a.rounds, measure)
    rows = {}
    for w in WAYS:
        ref = runs["before"][0][w]
        rows[w] = {"identical": all(r[w]["sha256"] == ref["sha256"] for side in runs.values() for r in side),
                   "sha256_before": ref["sha256"], "sha256_after": runs["after"][0][w]["sha256"],
                   "frame_ortho_mp": ref["frame_ortho_mp"],
                   "cpu_s_per_mp_before": min(r[w]["cpu_s_per_mp"] for r in runs["before"]),
                   "cpu_s_per_mp_after": min(r[w]["cpu_s_per_mp"] for r in runs["after"]),
                   "cpu_s_per_mp_median_before": sorted(r[w]["cpu_s_per_mp"] for r in runs["before"])[a.rounds // 2],
                   "cpu_s_per_mp_median_after": sorted(r[w]["cpu_s_per_mp"] for r in runs["after"])[a.rounds // 2]}
        r = rows[w]
        print(f"{w:13s} identical {r['identical']}  CPU per MP least {r['cpu_s_per_mp_before']:.4f} -> "
              f"{r['cpu_s_per_mp_after']:.4f} s, median {r['cpu_s_per_mp_median_before']:.4f} -> "
              f"{r['cpu_s_per_mp_median_after']:.4f} s")
    if a.json:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                                text=True).stdout.strip()
        doc = {"project": str(a.demo), "dem": a.dem, "dsm": a.dsm, "max_view_angle_deg": a.max_view_angle_deg,
               "crs": a.crs, "rounds": a.rounds, "commit": commit,
               "before": str(a.before), "ways": rows, "runs": runs}
        from aerotri.core.atomic import write_text_atomic

        write_text_atomic(a.json, json.dumps(doc, indent=1) + "\n")
        print(f"wrote {a.json}")


if __name__ == "__main__":
    main()
