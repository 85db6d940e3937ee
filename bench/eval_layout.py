"""Control layout on simulated blocks (issue 21): layout targets filled without and with the fallbacks,
why the empty ones are empty, and why corners end as "too few rays" -> bench/results/control_layout.json.

    .venv/bin/python bench/eval_layout.py [PROJECT ...] [--before BASE_PROJECT ...] [--out FILE]

Each PROJECT is a simulated project after a whole chain run (``aerotri demo`` / ``aerotri sim`` +
``aerotri run``) with the fallbacks on (the default). For each, the control transfer is repeated here
with the orientations and camera of the first adjustment (``work/at_first/``, as the chain does),
once with ``fallback = false`` (today's rule) and once with the fallbacks. The "too few rays" corners
are split by the frames their predicted position falls in; with the simulator's truth (the scene is
rebuilt from the preset and the seed in ``truth/truth.json``) the true eave corner is ray-cast
against buildings and trees in every frame it falls in, so "measurements failed" is told apart from
"hidden in all but one frame". ``--before``: the same projects run by the code before the fallbacks
(one per PROJECT, same order); their check RMS (at/report.json) is reported beside PROJECT's.
Nothing is tuned here: the tiers follow fixed rules (aerotri.control.layout), so the numbers are the
same kind on every seed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.control.corners import read_corners  # noqa: E402
from aerotri.control.pipeline import summary, transfer_control  # noqa: E402
from aerotri.control.settings import ControlSettings  # noqa: E402
from aerotri.core.atomic import write_text_atomic  # noqa: E402
from aerotri.core.project import Project  # noqa: E402
from aerotri.geom.camera import BrownCamera  # noqa: E402
from aerotri.geom.eo import read_eo  # noqa: E402
from aerotri.geom.local_frame import FramesOnEarth  # noqa: E402


def truth_visibility(root: Path, res) -> dict:
    """For the too_few_rays corners falling in 2+ frames: in how many of those frames the true corner is
    unblocked (ray cast from the true projection centre). Returns counts by outcome."""
    from aerotri.sim import load_preset, raycast
    from aerotri.sim.evaluate import truth_roof_corners
    from aerotri.sim.flight import block_layout
    from aerotri.sim.render import visible
    from aerotri.sim.scene import build_scene

    truth = json.loads((root / "truth" / "truth.json").read_text())
    cfg = load_preset(truth["preset"], [f"preset.seed={int(truth['seed'])}"])
    s_scene = np.random.SeedSequence(int(truth["seed"])).spawn(4)[0]  # as aerotri.sim.project.simulate
    origin = np.array([cfg.crs.origin_e_m, cfg.crs.origin_n_m, cfg.crs.base_height_m])
    layout = block_layout(cfg)
    scene = build_scene(cfg.scene, layout.width_m, layout.height_m, origin,
                        int(np.random.default_rng(s_scene).integers(0, 2**31 - 1)))
    accel = raycast.build_accel(scene)
    cam = BrownCamera.read(root / "truth" / "camera.toml")
    eo = read_eo(root / "truth" / "eo.txt")
    on_earth = FramesOnEarth(Project.open(root).crs, eo.centre_m, eo.rotations())  # as the simulator rendered
    t = truth_roof_corners(root)
    frames = Counter(k for k, _ in res.predicted)
    out = Counter()
    for k, r in res.rays.items():
        if r.reason != "too_few_rays" or frames.get(k, 0) < 2:
            continue
        d = np.hypot(*(t.xyz_m[:, :2] - res.corners.xyz_m[k, :2]).T)
        if d.min() > 1.5:
            out["no_true_corner_within_1.5_m"] += 1
            continue
        X = t.xyz_m[int(np.argmin(d))]
        seen = 0
        for i in range(len(eo.image_id)):
            x, y, _ = on_earth.project(cam, i, X[None])
            if cam.inside(np.atleast_1d(x), np.atleast_1d(y), margin_px=2.0)[0]:
                # 5 cm above the eave, so the roof the corner belongs to does not block its own ray
                seen += bool(visible(accel, eo.centre_m[i] - origin, (X - origin + [0, 0, 0.05])[None], tol_m=0.1)[0])
        out["visible_in_2plus_frames" if seen >= 2 else "visible_in_at_most_one_frame"] += 1
    return dict(sorted(out.items()))


def layout_numbers(res) -> dict:
    sm = summary(res)
    return {
        "layout_targets": sm.layout_targets, "layout_targets_filled": sm.layout_targets - sm.layout_targets_unfilled,
        "layout_targets_by_tier": sm.layout_targets_by_tier, "control_full": sm.control_full,
        "control_height": sm.control_height, "check_points": sm.check_points,
        "corners_measured": sm.corners_measured, "corners_measured_fallback": sm.corners_measured_fallback,
        "corners_rejected": sm.corners_rejected, "too_few_rays_by_cause": sm.too_few_rays_by_cause,
        "targets": [{"kind": t.kind, "x_m": round(t.target_x_m, 1), "y_m": round(t.target_y_m, 1),
                     "corner": None if t.corner is None else str(res.corners.id[t.corner]), "tier": t.tier,
                     "corner_kind": t.corner_kind, "distance_m": None if t.distance_m is None else round(t.distance_m, 1),
                     "empty_reason": t.empty_reason} for t in res.targets],
    }


def check_rms(root: Path, ids=None) -> dict | None:
    """Check-point RMS of the final adjustment (at/report.json), over the check points ``ids`` when given
    (the points both runs kept: a corner that became control in one run is no check point there)."""
    p = root / "at" / "report.json"
    if not p.is_file():
        return None
    pts = {c["id"]: c["d_m"] for c in json.loads(p.read_text())["check_points"]}
    d = np.array([pts[i] for i in (sorted(pts) if ids is None else ids)])
    rms = np.sqrt(np.mean(d**2, axis=0))
    return {"check_points": len(d), "rms_check_xyz_m": [round(float(v), 4) for v in rms],
            "rms_check_xy_m": round(float(np.hypot(rms[0], rms[1])), 4), "rms_check_z_m": round(float(rms[2]), 4)}


def check_ids(root: Path) -> set:
    return {c["id"] for c in json.loads((root / "at" / "report.json").read_text())["check_points"]}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("projects", nargs="*", type=Path, help="default: the project of `make demo` (out/demo/project)")
    ap.add_argument("--before", nargs="*", type=Path, default=[])
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "control_layout.json")
    a = ap.parse_args(argv)
    if not a.projects:
        demo = REPO / "out" / "demo" / "project"
        if not (demo / "work" / "at_first" / "eo.txt").is_file():
            # `make bench` runs every script without arguments
            print(f"no project given and no chain run in {demo}: run `make demo` or pass PROJECT folders")
            return
        a.projects = [demo]
    out = {"load_avg_start": list(os.getloadavg()), "projects": []}
    for n, root in enumerate(a.projects):
        t0 = time.perf_counter()
        truth = json.loads((root / "truth" / "truth.json").read_text())
        corners = read_corners(root / "lidar_out" / "corners.csv")
        eo = read_eo(root / "work" / "at_first" / "eo.txt")
        camera = BrownCamera.read(root / "work" / "at_first" / "camera.toml")
        s = ControlSettings(chips=False)
        rec = {"project": str(root), "preset": truth["preset"], "seed": truth["seed"], "gsd_m": truth["gsd_m"],
               "buildings": truth["buildings"], "true_roof_corners": truth["roof_corners"]}
        crs = Project.open(root).crs  # the frames over the earth (issue 42)
        off = transfer_control(corners, camera, eo, root / "images",
                               dataclasses.replace(s, layout=dataclasses.replace(s.layout, fallback=False)), crs=crs)
        on = transfer_control(corners, camera, eo, root / "images", s, crs=crs)
        rec["fallback_off"] = layout_numbers(off)
        rec["fallback_on"] = layout_numbers(on)
        rec["too_few_rays_truth_visibility"] = truth_visibility(root, off)
        rec["check_rms_after"] = check_rms(root)
        if n < len(a.before):
            rec["check_rms_before"] = check_rms(a.before[n])
            common = sorted(check_ids(root) & check_ids(a.before[n]))
            rec["check_rms_common_points"] = {"before": check_rms(a.before[n], common), "after": check_rms(root, common)}
        rec["seconds"] = round(time.perf_counter() - t0, 1)
        out["projects"].append(rec)
        print(json.dumps({k: v for k, v in rec.items() if k not in ("fallback_off", "fallback_on")}, indent=1))
        for which in ("fallback_off", "fallback_on"):
            r = rec[which]
            print(which, f"{r['layout_targets_filled']} of {r['layout_targets']} filled", r["layout_targets_by_tier"])
    out["load_avg_end"] = list(os.getloadavg())
    write_text_atomic(a.out, json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
