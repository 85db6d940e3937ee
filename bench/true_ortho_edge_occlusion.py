"""How much of a true ortho's occlusion reaches the frame's edge (issue 42, fill3): per frame ortho of a project, its
invalid pixels that valid ones enclose (the holes the mosaic found before fill3) and those inside the frame's footprint
(``FrameEntry.footprint_xy_m``, one pixel in: ``ortho.mosaic._inside_footprint``) that are joined to the outside
(4-connected): occlusion that runs off the frame's edge, which before fill3 had no hole margin in the mosaic and did
not count in its farthest-from-holes rule.

Usage: python bench/true_ortho_edge_occlusion.py PROJECT [PROJECT ...]   (prints JSON per project)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def edge_occlusion(project: Path) -> dict:
    import cv2
    import rasterio

    from ortho.block import read_index
    from ortho.grid import OrthoGrid
    from ortho.mosaic import _inside_footprint

    index = read_index(project)
    mosaic = OrthoGrid.union(index.grids)
    out = {"frames": 0, "enclosed_px": 0, "joined_to_the_outside_inside_the_footprint_px": 0,
           "invalid_inside_the_footprint_px": 0}
    for e, g in zip(index.frames, index.grids):
        with rasterio.open(project / "ortho" / "frames" / e.file) as ds:
            m = ds.read_masks(1) > 0
        c0, r0 = g.offset_in(mosaic)
        inside = _inside_footprint(e.footprint_xy_m, m.shape, mosaic, r0, c0)
        if inside is None:
            continue
        inv = np.pad((~m).view(np.uint8), 1, constant_values=1)
        cv2.floodFill(inv, None, (0, 0), 2)
        out["frames"] += 1
        out["enclosed_px"] += int((inv[1:-1, 1:-1] == 1).sum())
        out["joined_to_the_outside_inside_the_footprint_px"] += int(((inv[1:-1, 1:-1] == 2) & inside).sum())
        out["invalid_inside_the_footprint_px"] += int((~m & inside).sum())
    out["joined_share_of_invalid_inside"] = (out["joined_to_the_outside_inside_the_footprint_px"]
                                            / max(1, out["invalid_inside_the_footprint_px"]))
    return out


if __name__ == "__main__":
    for p in sys.argv[1:]:
        print(json.dumps({"project": p, **edge_occlusion(Path(p))}))
