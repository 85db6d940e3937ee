"""ISPRS filter test: where the default ground filter errs, sample by sample.

Points grey by height; type I errors (bare earth rejected) red, type II (objects accepted as ground)
blue; the same path as ``bench/eval_isprs.py`` "lidarctl_default_morph_tin" (noise flags, then
``lidarctl.classify.ground.ground_filter``). Writes bench/results/lidar_isprs_errors.png.
Run: .venv/bin/python bench/plot_isprs_errors.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO, SAMPLES  # noqa: E402

from lidarctl import io  # noqa: E402
from lidarctl.checks import classes as evaluate
from lidarctl.classify import ground
from lidarctl.classify import noise


def main():
    fig, axes = plt.subplots(2, 4, figsize=(22, 11))
    for ax, s in zip(axes.ravel(), SAMPLES):
        c = io.read_cloud(DATA / "isprs_filtertest" / f"{s}-utm.laz")
        keep = noise.detect_noise(c.x, c.y, c.z) == 0
        g = np.zeros(len(c), bool)
        g[keep] = ground.ground_filter(c.x[keep], c.y[keep], c.z[keep])
        truth = c.classification == 2
        e = evaluate.filter_errors(g, truth)
        x, y = c.x - c.x.min(), c.y - c.y.min()
        lo, hi = np.percentile(c.z[keep], [1, 99])  # noise points would stretch the grey scale
        sc = ax.scatter(x, y, c=c.z, s=1, cmap="gray", vmin=lo, vmax=hi)
        fig.colorbar(sc, ax=ax, shrink=0.7, label="height (m)")
        for mask, colour, name in ((truth & ~g, "red", "type I"), (~truth & g, "blue", "type II")):
            ax.scatter(x[mask], y[mask], s=3, c=colour, label=f"{name}: {mask.sum()}")
        ax.set_title(f"{s}: total {e.total_error_pct:.2f} %, type I {e.type_i_error_pct:.1f} %, "
                     f"type II {e.type_ii_error_pct:.1f} %", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("easting from the sample's corner (m)")
        ax.legend(loc="lower right", fontsize=8, markerscale=3)
    axes.ravel()[-1].axis("off")
    fig.suptitle("Default ground filter (morph + local-surface test + TIN refinement) on the ISPRS samples")
    fig.tight_layout()
    path = REPO / "bench" / "results" / "lidar_isprs_errors.png"
    fig.savefig(path, dpi=70)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
