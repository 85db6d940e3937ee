"""Render speed of the simulator's frames on the earth against another tree (issue 41): CPU seconds per megapixel
of ``FrameRenderer`` over a preset's frames (three passes after a warm-up pass that compiles), with the frames
projected through ``aerotri.sim.earth`` when the tree has it (this tree), else the flat world (a tree before
issue 41, e.g. ``git archive <commit> | tar -x -C /tmp/flat``). Run the two trees one after the other, several
times on a loaded machine.

Usage:
  python bench/sim_earth_speed.py [--code-root /tmp/flat] [--flat] tiny camera.width=1728 camera.height=960
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--code-root", type=Path, default=Path(__file__).resolve().parents[1])
    ap.add_argument("--flat", action="store_true", help="this tree's renderer in the flat world")
    ap.add_argument("preset")
    ap.add_argument("sets", nargs="*")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(a.code_root))
    import numpy as np

    from aerotri.geom.rotation import rotation_matrix_opk
    from aerotri.sim import load_preset, raster
    from aerotri.sim.flight import block_layout, cameras_from_config, plan_frames
    from aerotri.sim.project import texture_fine_m
    from aerotri.sim.scene import build_scene

    cfg = load_preset(a.preset, a.sets)
    layout = block_layout(cfg)
    ss = np.random.SeedSequence(cfg.preset.seed).spawn(4)
    origin = np.array([cfg.crs.origin_e_m, cfg.crs.origin_n_m, cfg.crs.base_height_m])
    scene = build_scene(cfg.scene, layout.width_m, layout.height_m, origin,
                        int(np.random.default_rng(ss[0]).integers(0, 2**31 - 1)))
    plan = plan_frames(cfg, layout, np.random.default_rng(ss[1]))
    cam, _ = cameras_from_config(cfg.camera)
    look = raster.SceneLook(scene, texture_fine_m(cfg, cam))
    r = raster.FrameRenderer(scene, cam, look.fine_m, samples=int(cfg.render.samples), bits=8, look=look)
    try:
        from aerotri.sim.project import sim_earth

        earth = None if a.flat else sim_earth(cfg, layout)
    except ImportError:  # a tree before issue 41
        earth = None

    def frame(i):
        R = rotation_matrix_opk(*plan.opk_deg[i])
        f = r.setup(plan.centre_m[i], R, earth.frame_earth(plan.centre_m[i], R)) if earth else r.setup(plan.centre_m[i], R)
        return r.render_rows(f, 0, cam.height)

    frame(0)
    t = time.process_time()
    for _ in range(3):
        for i in range(len(plan.image_id)):
            frame(i)
    mp = 3 * len(plan.image_id) * cam.width * cam.height / 1e6
    print(f"{a.code_root} {'earth' if earth else 'flat'}: {(time.process_time() - t) / mp:.4f} CPU s per MP ({mp:.1f} MP)")


if __name__ == "__main__":
    main()
