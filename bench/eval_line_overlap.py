"""The line overlap of ``lidarctl check-vectors`` (completeness / correctness of line layers) before and after
issue 40's change: the buffer of a window's lines as the union of each line's buffer (now) against the buffer of
the union of the window's lines (before; GEOS buffers the union, noded into thousands of pieces, 100 times slower).

    .venv/bin/python bench/eval_line_overlap.py [--keep DIR] [--presets tiny demo] [--out JSON]

Cases: the random-walk layers of tests/lidarctl/test_map_vectors.py (60 reference lines of 40 vertices, 47 product
lines; default window and one window), and the road centre lines of the simulator's projects (``--presets``; the
DLG of bench/eval_vectors.py: the strips classified with the true orthophoto, ``lidarctl vectors``, the reference
from the scene; ``--keep DIR`` reuses DIR/<preset> and DIR/<preset>_fused, e.g. a symlink to a simulated project).
Per case: the completeness and correctness (per cent) and the process CPU seconds of each way.
Writes bench/results/line_overlap.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import numpy as np
import shapely

from lidarctl.checks import vectors as vc

REPO = Path(__file__).resolve().parents[1]


def _buffer_of_union(lines, tree, rect, buffer):
    """Before: the buffer of the union of the lines clipped to ``rect``."""
    near = vc._clipped_union(lines, tree, rect)
    return near.buffer(buffer) if near.length else shapely.Polygon()


def both_ways(prod: list, ref: list, buffer: float, **kw) -> dict:
    out = {}
    for way, patch in (("before_buffer_of_union", mock.patch.object(vc, "_clipped_buffers", _buffer_of_union)),
                       ("now_union_of_buffers", mock.patch.object(vc, "_clipped_buffers", vc._clipped_buffers))):
        with patch:
            t = time.process_time()
            r = vc.buffer_overlap(prod, ref, buffer, **kw)
            out[way] = {"completeness_pct": r.completeness_pct, "correctness_pct": r.correctness_pct,
                        "reference_length": r.reference_size, "product_length": r.product_size,
                        "cpu_s": round(time.process_time() - t, 3)}
    b, n = out["before_buffer_of_union"], out["now_union_of_buffers"]
    out["difference_pct_points"] = {k: n[k] - b[k] for k in ("completeness_pct", "correctness_pct")}
    return out


def random_walks() -> tuple[list, list]:
    """The layers of test_line_overlap_window_by_window_equals_the_whole_layer_at_once."""
    rng = np.random.default_rng(5)
    ref = [shapely.LineString(np.cumsum(rng.normal(0, 3, (40, 2)), axis=0) + rng.uniform(0, 300, 2)) for _ in range(60)]
    prod = [shapely.LineString(np.asarray(g.coords) + rng.normal(0, 0.8, (40, 2))) for g in ref[:45]]
    return prod + [ref[0], ref[0]], ref


def road_centrelines(name: str, root: Path, tmp: Path) -> tuple[list, list, float]:
    sys.path.insert(0, str(REPO / "bench"))
    import eval_vectors as ev
    from lidarctl.vectors.layers import MapVectorSettings, vectors_to_file

    proj, strips = ev.project(name, root)
    dlg, ref = tmp / f"{name}_dlg.gpkg", tmp / f"{name}_reference.gpkg"
    vectors_to_file(strips, dlg, params=MapVectorSettings(), dem=proj / "truth" / "dem.tif",
                    image=proj / "truth" / "ortho.tif")
    scene, origin, epsg = ev.true_scene(name)
    ev.write_reference(scene, origin, epsg, ref)
    prod, _, _ = vc.read_layers(dlg)
    refs, _, _ = vc.read_layers(ref)
    return prod["road_centrelines"], refs["road_centrelines"], vc.VectorCheckSettings().buffer_m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--keep", type=Path, default=None, help="Simulated projects (and their classified strips) here.")
    ap.add_argument("--presets", nargs="*", default=["tiny", "demo"])
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "line_overlap.json")
    args = ap.parse_args(argv)
    prod, ref = random_walks()
    result = {"command": "bench/eval_line_overlap.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "cases": {"random_walks_default_window": {"buffer": 1.5, **both_ways(prod, ref, 1.5)},
                        "random_walks_one_window": {"buffer": 1.5, **both_ways(prod, ref, 1.5, window=1000.0)}}}
    with tempfile.TemporaryDirectory(prefix="eval_line_overlap_") as tmp:
        for name in args.presets:
            p, r, buffer_m = road_centrelines(name, args.keep or Path(tmp), Path(tmp))
            result["cases"][f"{name}_road_centrelines"] = {"buffer": buffer_m, "n_product": len(p),
                                                          "n_reference": len(r), **both_ways(p, r, buffer_m)}
    for k, v in result["cases"].items():
        b, n = v["before_buffer_of_union"], v["now_union_of_buffers"]
        print(f"{k}: completeness {b['completeness_pct']:.6f} -> {n['completeness_pct']:.6f} %, correctness "
              f"{b['correctness_pct']:.6f} -> {n['correctness_pct']:.6f} %, CPU {b['cpu_s']} -> {n['cpu_s']} s")
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
