"""AHN3 Delft crop: what the building and ground errors are, per spatial quarter.

Runs the classification (shipped defaults) once and breaks the errors down by the AHN3 truth class
and by where the points lie:
- false buildings (we say 6, AHN3 says 1/26): *over a roof* (a truth building point within 1 m
  horizontally lies more than 0.5 m lower: rooftop installations, crowns or cables over the roof),
  *at a building edge* (truth building within 3 m) or *isolated* (vans, sheds AHN3 leaves 1); each
  split into single- and multi-return points;
- false ground (we say 2, AHN3 says 1/6/9/26): their height above the truth ground (the median of
  the 8 nearest truth ground points) and multi-return share;
- missed buildings: what we called them instead.
Quarters as bench/eval_ahn3_holdout.py (split at the median x and y). The false ground is also
given without the ground refinement (``ground_lift_sigma`` 0: what the ground filter hands over).
The bridge-deck rule (``classify.bridge_decks``: ground between two water gaps along a watercourse,
above the quays -> 17) is shown by its own picture, bench/results/ahn3_ground_errors_se.png: the
south-east quarter's false ground by truth class with the rule off and on, the deck points it finds
and the dropout gaps (water without returns) it reads; per quarter the false ground without it.
Writes bench/results/lidar_ahn3_errors.json and bench/results/ahn3_errors_<quarter>.png (errors over the
quarter: grey correct building, light grey correct ground; the legend counts each error kind).
Run: .venv/bin/python bench/eval_ahn3_errors.py
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_ahn3_holdout import PARTS, part_of, scores  # noqa: E402
from lidar_common import DATA, REPO  # noqa: E402

from lidarctl import grid, io  # noqa: E402
from lidarctl.classify import pipeline as classify

ERROR_KINDS = (  # (truth classes, our AHN3-mapped class, colour, label)
    ((1, 26), 6, "red", "false building (truth 1/26)"),
    ((6,), 1, "blue", "missed building (we: vegetation/1)"),
    ((6,), 2, "magenta", "missed building (we: ground)"),
    ((1,), 2, "orange", "false ground (truth 1)"),
    ((6, 9, 26), 2, "green", "false ground (truth 6/9/26)"),
)


def pct(a: np.ndarray) -> list:
    return [round(float(v), 3) for v in np.percentile(a, [10, 50, 90])] if len(a) else []


def breakdown(x, y, z, nr, truth, pred, m) -> dict:
    """Error kinds in the points ``m``; heights relative to the truth ground."""
    multi = nr > 1
    g = truth == 2
    hag = z - np.median(z[g][cKDTree(np.column_stack([x[g], y[g]])).query(np.column_stack([x, y]), k=8)[1]],
                        axis=1)
    b = truth == 6
    dist, nb = cKDTree(np.column_stack([x[b], y[b]])).query(np.column_stack([x, y]), k=4,
                                                             distance_upper_bound=1.0)
    zb = np.where(np.isfinite(dist), z[b][np.minimum(nb, b.sum() - 1)], np.inf)
    over = (z[:, None] - zb > 0.5).any(axis=1)
    d1 = cKDTree(np.column_stack([x[b], y[b]])).query(np.column_stack([x, y]))[0]
    fb = m & np.isin(truth, (1, 26)) & (pred == 6)
    where = {"over_roof": fb & (d1 < 1.0) & over, "edge": fb & (d1 < 3.0) & ~((d1 < 1.0) & over),
             "isolated": fb & (d1 >= 3.0)}
    fg = m & (truth != 2) & (pred == 2)
    missed = m & (truth == 6) & (pred != 6)
    return {
        "false_building": {k: {"single_return": int((v & ~multi).sum()), "multi_return": int((v & multi).sum()),
                               "height_above_truth_ground_p10_50_90_m": pct(hag[v])} for k, v in where.items()},
        "false_ground_by_truth": {str(k): int((fg & (truth == k)).sum()) for k in (1, 6, 9, 26)},
        "false_ground_truth1_height_p10_50_90_m": pct(hag[fg & (truth == 1)]),
        "false_ground_truth1_multi_return_share": round(float(multi[fg & (truth == 1)].mean()), 3)
        if (fg & (truth == 1)).any() else None,
        "true_ground_height_p10_50_90_m": pct(hag[m & g & (pred == 2)]),
        "missed_building_as": {str(k): int((missed & (pred == k)).sum()) for k in np.unique(pred[missed])},
        "missed_building_multi_return_share": round(float(multi[missed].mean()), 3) if missed.any() else None,
    }


def plot(path: Path, name: str, x, y, truth, mapped, m):
    fig, ax = plt.subplots(figsize=(9, 9))
    ok = m & (mapped == truth)
    ax.scatter(x[ok & (truth == 6)], y[ok & (truth == 6)], s=0.3, c="0.7", lw=0, label="building, correct")
    ax.scatter(x[ok & (truth == 2)], y[ok & (truth == 2)], s=0.3, c="0.9", lw=0, label="ground, correct")
    for tcls, pcls, colour, label in ERROR_KINDS:
        s = m & np.isin(truth, tcls) & (mapped == pcls)
        ax.scatter(x[s], y[s], s=1.5, c=colour, lw=0, label=f"{label}: {s.sum():,}")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, EPSG:28992)")
    ax.set_ylabel("y (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_title(f"AHN3 crop 1, {name} quarter: classification errors (defaults)")
    ax.legend(loc="upper left", markerscale=8, fontsize=8, framealpha=0.9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_ground_errors(path: Path, x, y, truth, preds: dict, gaps, m):
    """False ground by truth class over one quarter, one panel per classification in ``preds``;
    dropout gaps (``gaps``: (mask, cell m, x0, y0)) shaded, bridge-deck points (17) by truth."""
    mask, c, x0, y0 = gaps
    fig, axes = plt.subplots(1, len(preds), figsize=(8 * len(preds), 6.2))
    for ax, (title, pred) in zip(np.atleast_1d(axes), preds.items()):
        ax.imshow(np.where(mask, 1.0, np.nan), origin="lower", cmap="Blues", vmin=0, vmax=2.5,
                  extent=(x0, x0 + mask.shape[1] * c, y0, y0 + mask.shape[0] * c), interpolation="nearest")
        ok = m & (truth == 2) & (pred == 2)
        ax.scatter(x[ok], y[ok], s=0.3, c="0.85", lw=0, label="ground, correct")
        for t, colour in ((1, "green"), (6, "red"), (9, "blue"), (26, "darkorange")):
            s = m & (truth == t) & (pred == 2)
            ax.scatter(x[s], y[s], s=2, c=colour, lw=0, label=f"we: ground, AHN3: {t}: {s.sum():,}")
        for t, colour in ((26, "purple"), (2, "black")):
            s = m & (truth == t) & (pred == classify.BRIDGE_DECK)
            if s.any():
                ax.scatter(x[s], y[s], s=2, c=colour, lw=0, label=f"we: bridge deck (17), AHN3: {t}: {s.sum():,}")
        ax.scatter([], [], marker="s", s=3, c="lightsteelblue", label="dropout gap (water without returns)")
        ax.set_xlim(x[m].min(), x[m].max())
        ax.set_ylim(y[m].min(), y[m].max())
        ax.set_aspect("equal")
        ax.set_xlabel("x (m, EPSG:28992)")
        ax.set_ylabel("y (m)")
        ax.ticklabel_format(useOffset=False, style="plain")
        ax.set_title(title)
        ax.legend(loc="upper left", markerscale=6, fontsize=8, framealpha=0.9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main():
    c = io.read_cloud(DATA / "ahn3_delft" / "ahn3_cropped_1.laz", crs="EPSG:28992")
    truth = c.classification
    pred = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
    mapped = np.where(np.isin(pred, (2, 6, 9)), pred, 1)
    part = part_of(c.x, c.y)
    nr = np.asarray(c.number_of_returns)
    unrefined = classify.classify_points(
        c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity,
        params=dataclasses.replace(classify.ClassifySettings(), ground_lift_sigma=0.0))
    nobridge = classify.classify_points(
        c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity,
        params=dataclasses.replace(classify.ClassifySettings(), bridge_max_width_m=0.0))
    out = {"data": "ahn3_cropped_1.laz, shipped ClassifySettings defaults", "parts": {}}
    for k, name in enumerate(PARTS):
        m = part == k
        before = breakdown(c.x, c.y, c.z, nr, truth, unrefined, m)
        out["parts"][name] = {"scores": scores(pred[m], truth[m]),
                              **breakdown(c.x, c.y, c.z, nr, truth, pred, m),
                              "without_ground_refinement": {
                                  "scores": scores(unrefined[m], truth[m]),
                                  **{key: before[key] for key in before if "ground" in key}},
                              "without_bridge_rule": {
                                  "scores": scores(nobridge[m], truth[m]),
                                  "false_ground_by_truth": breakdown(c.x, c.y, c.z, nr, truth, nobridge, m)[
                                      "false_ground_by_truth"]},
                              "bridge_deck_points_by_truth": {str(int(t)): int(k) for t, k in zip(
                                  *np.unique(truth[m & (pred == classify.BRIDGE_DECK)], return_counts=True))}}
        png = REPO / "bench" / "results" / f"ahn3_errors_{name}.png"
        plot(png, name, c.x, c.y, truth, mapped, m)
        print(name, json.dumps(out["parts"][name]))
    spacing = grid.mean_spacing_m(c.x, c.y)
    labels, _, _, _, cell = classify.dropout_gaps(c.x, c.y, c.z, pred == 2, pred == 6, spacing,
                                                  classify.ClassifySettings())
    se = part == PARTS.index("south-east")
    plot_ground_errors(REPO / "bench" / "results" / "ahn3_ground_errors_se.png", c.x, c.y, truth,
                       {"south-east quarter, bridge rule off": nobridge, "bridge rule on (shipped)": pred},
                       (labels > 0, cell, float(c.x.min()), float(c.y.min())), se)
    dest = REPO / "bench" / "results" / "lidar_ahn3_errors.json"
    dest.write_text(json.dumps(out, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
