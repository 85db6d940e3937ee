"""What the false building area against the BGT footprints physically is (AHN3 Delft, issue 44).

The scoring of bench/eval_buildings_bgt.py (0.5 m cells, highest point's class, 0.5 m band around the
outlines ignored, BGT block hulls, quarters at the median x / y). For every false building cell and,
beside it, every found one (building on a footprint), the kind of surface its highest return lies on:

* height above the ground of the cell's highest return (DEM: the mean of our ground returns per cell,
  empty cells from the nearest cell): under 1.5 m, 1.5-4 m ("low": a storey or less), 4 m and more;
* split pulses: the share of multi-return points in the 3 x 3 cells around it (at least 0.4: crowns and
  hedges split the pulse, a roof stops it; roof edges split it too);
* AHN3's class of that return (6: AHN3's operators call it building);
* for the low cells: the share of returns more than 1 m below their cell's highest one (3 x 3 cells);
* pulses through to the ground (third round): the last returns of split pulses at most 0.5 m above the
  ground over the first returns above it (3 x 3 cells; a roof stops every pulse, a hedge or crown lets a
  share through: ``pierced_growth_max_fraction`` of the classification).

A rule that removes a kind of cell removes its found area too: the "found_m2" beside each "false_m2" is
what completeness would lose. Also per quarter: the false area by distance from the footprint, and
the cells at the height of the roof next to them (eaves: within 1.5 m of the highest found roof within
1.5 m); the per-point building PA / UA against AHN3's class 6 per quarter. With ``--low H`` the same for
the classification with ``low_growth_max_height_m = H`` (``--pierced F``: ``pierced_growth_max_fraction = F``),
each on the rules shipped before the third round; with ``--before`` for those rules (no low-growth and no
pierced-growth test).
Figures: bench/results/buildings_bgt_false_<quarter>.png (found grey, false red, missed blue over the
BGT outlines; the height of the highest return above the ground; the split-pulse share; the share of
pulses through to the ground), ``..._before_<quarter>.png`` for ``--before``.
Writes bench/results/buildings_bgt_false_area.json.
Run: nice .venv/bin/python bench/eval_buildings_bgt_false.py [--low 3.5] [--pierced 0.1] [--before]
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import matplotlib
import numpy as np
import shapely
from scipy import ndimage

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_buildings_bgt as bgt  # noqa: E402

from lidarctl import io, tiles  # noqa: E402
from lidarctl.classify import class_grid as cg  # noqa: E402
from lidarctl.classify.pipeline import BUILDING, GROUND, ClassifySettings  # noqa: E402

SPLIT_SHARE = 0.4
PIERCED_BANDS = {"under 0.1": (0.0, 0.1), "0.1-0.2": (0.1, 0.2), "0.2-0.3": (0.2, 0.3), "0.3 and more": (0.3, np.inf)}
GROUND_LEVEL_M = 0.5     # the classification's wall_min_height_m: returns this close to the ground are on it
BEFORE = {"low_growth_max_height_m": 0.0, "pierced_growth_max_fraction": 0.0}
LOW_M = (1.5, 4.0)
DISTANCE_BANDS_M = {"0.5-1.5 m": (0.0, 1.5), "1.5-3 m": (1.5, 3.0), "over 3 m": (3.0, np.inf)}
BOXES = {"north-west": (84830, 84890, 447520, 447580), "north-east": (84880, 85005, 447485, 447620)}


@dataclasses.dataclass(frozen=True)
class CellKinds:
    """Per 0.5 m cell of the scoring grid: height of the highest return above the ground (m), split-pulse
    share, share of returns more than 1 m below their cell's top and share of the pulses through to the
    ground (all over the 3 x 3 cells), AHN3's class of the highest return, and the height of the highest found
    roof within 1.5 m (m above the ground; -inf where none)."""

    hag_m: np.ndarray
    split_share: np.ndarray
    below_share: np.ndarray
    pierced_share: np.ndarray
    ahn3_class: np.ndarray
    roof_near_m: np.ndarray


def top_returns(flat: np.ndarray, z: np.ndarray, shape: tuple) -> np.ndarray:
    """Index of the highest return of each cell of the grid ``shape`` (``flat``: each return's cell); a cell without
    returns takes the nearest cell's."""
    order = np.lexsort((z, flat))
    last = np.r_[flat[order][1:] != flat[order][:-1], True]
    top = np.full(shape[0] * shape[1], -1)
    top[flat[order][last]] = order[last]
    top = top.reshape(shape)
    return top[tuple(ndimage.distance_transform_edt(top < 0, return_distances=False, return_indices=True))]


def cell_kinds(classified: Path, laz: Path, grid: cg.ClassGrid, found: np.ndarray) -> CellKinds:
    c, ref = io.read_cloud(classified, crs=bgt.CRS), io.read_cloud(laz, crs=bgt.CRS)
    t, shape = grid.transform, grid.shape
    col = np.floor((c.x - t.c) / t.a).astype(int)
    row = np.floor((c.y - t.f) / t.e).astype(int)
    flat = np.clip(row, 0, shape[0] - 1) * shape[1] + np.clip(col, 0, shape[1] - 1)
    size = shape[0] * shape[1]
    top = top_returns(flat, c.z, shape)
    g = c.classification == GROUND
    n_g = np.bincount(flat[g], minlength=size)
    dem = np.where(n_g > 0, np.bincount(flat[g], c.z[g], minlength=size) / np.maximum(n_g, 1), np.nan).reshape(shape)
    dem = dem[tuple(ndimage.distance_transform_edt(np.isnan(dem), return_distances=False, return_indices=True))]
    hag = c.z[top] - dem
    k3 = np.ones((3, 3))
    n = np.bincount(flat, minlength=size).reshape(shape).astype(float)
    n_multi = np.bincount(flat[c.number_of_returns > 1], minlength=size).reshape(shape).astype(float)
    split = ndimage.correlate(n_multi, k3) / np.maximum(ndimage.correlate(n, k3), 1.0)
    # returns more than 1 m below their cell's highest one: the pulse went on under the surface
    below = c.z < c.z[top.ravel()[flat]] - 1.0
    n_below = np.bincount(flat[below], minlength=size).reshape(shape).astype(float)
    below_share = ndimage.correlate(n_below, k3) / np.maximum(ndimage.correlate(n, k3), 1.0)
    # pulses through to the ground: last returns of split pulses on it over first returns above it
    hag_pt = c.z - dem.ravel()[flat]
    on_ground = hag_pt <= GROUND_LEVEL_M
    through = (c.number_of_returns > 1) & (c.return_number == c.number_of_returns) & on_ground
    above = (c.return_number == 1) & ~on_ground
    n_through = ndimage.correlate(np.bincount(flat[through], minlength=size).reshape(shape).astype(float), k3)
    n_above = ndimage.correlate(np.bincount(flat[above], minlength=size).reshape(shape).astype(float), k3)
    pierced = n_through / np.maximum(n_above, 1.0)
    roof_near = ndimage.maximum_filter(np.where(found, hag, -np.inf), size=7)
    return CellKinds(hag, split, below_share, pierced, ref.classification[top], roof_near)


def kinds(k: CellKinds) -> dict:
    low = (k.hag_m >= LOW_M[0]) & (k.hag_m < LOW_M[1])
    split = k.split_share >= SPLIT_SHARE
    eave = k.hag_m >= k.roof_near_m - 1.5
    ahn3_bld = k.ahn3_class == BUILDING
    return {
        "under 1.5 m": k.hag_m < LOW_M[0],
        "1.5-4 m, split pulses (hedges, low crowns, low roofs' edges)": low & split,
        "1.5-4 m, stops the pulse, AHN3 building (extensions, sheds, canopies)": low & ~split & ahn3_bld,
        "1.5-4 m, stops the pulse, AHN3 not building (vehicles, walls, sheds)": low & ~split & ~ahn3_bld,
        "4 m and more, at the level of the roof beside it (eaves)": (k.hag_m >= LOW_M[1]) & eave,
        "4 m and more, other": (k.hag_m >= LOW_M[1]) & ~eave,
    }


def scoring_grid(classified: Path, polys: list) -> tuple[cg.ClassGrid, np.ndarray, np.ndarray]:
    """(grid, footprint cells, scored cells) of eval_buildings_bgt.py's area scoring over ``classified``."""
    grid, _ = cg.cloud_grid(classified, bgt.CELL_M, bgt.CRS)
    ref_polys = cg.ClassPolygons(polys, np.full(len(polys), BUILDING, np.uint8), None, Path("bgt"))
    ref = cg.rasterize_polygons(ref_polys, grid)[0] == BUILDING
    band = cg.rasterize_mask([shapely.union_all([p.boundary for p in polys]).buffer(bgt.BAND_M)], grid)
    return grid, ref, cg.rasterize_mask(cg.block_hulls(ref_polys), grid) & ~band


def diagnose(classified: Path, laz: Path, polys: list, split_xy: tuple, png_stem: str | None) -> dict:
    grid, ref, scored = scoring_grid(classified, polys)
    xc, yc = grid.centres()
    part = bgt._quarter_of(xc[None, :], yc[:, None], *split_xy)
    bld = bgt.building_raster(classified, grid)[0]
    k = cell_kinds(classified, laz, grid, bld & ref)
    dist_m = ndimage.distance_transform_edt(~ref) * bgt.CELL_M
    low = (k.hag_m >= LOW_M[0]) & (k.hag_m < LOW_M[1])
    a = bgt.CELL_M ** 2
    out = {}
    for q, name in enumerate(bgt.PARTS):
        s = scored & (part == q)
        if not (ref & s).any():
            continue
        fp, tp = bld & ~ref & s, bld & ref & s
        lab, n_obj = ndimage.label(fp, np.ones((3, 3), int))
        touching = np.unique(lab[ndimage.binary_dilation(bld & ref, np.ones((3, 3), bool)) & fp])
        out[name] = {
            "false_m2": float(fp.sum() * a), "found_m2": float(tp.sum() * a),
            "false_hag_m_percentiles_10_50_90": np.percentile(k.hag_m[fp], [10, 50, 90]).round(2).tolist(),
            "found_hag_m_percentiles_10_50_90": np.percentile(k.hag_m[tp], [10, 50, 90]).round(2).tolist(),
            "by_kind": {kn: {"false_m2": float((fp & m).sum() * a), "found_m2": float((tp & m).sum() * a)}
                        for kn, m in kinds(k).items()},
            "low_cells_hag_m_median_false_found": [float(np.median(k.hag_m[fp & low])) if (fp & low).any() else None,
                                                   float(np.median(k.hag_m[tp & low])) if (tp & low).any() else None],
            "low_cells_by_share_of_returns_1m_below_the_top": {
                f"over {t:g}": {"false_m2": float((fp & low & (k.below_share > t)).sum() * a),
                                "found_m2": float((tp & low & (k.below_share > t)).sum() * a)}
                for t in (0.1, 0.2, 0.3, 0.4)},
            "by_share_of_pulses_through_to_the_ground": {
                b: {"false_m2": float((fp & (k.pierced_share >= lo) & (k.pierced_share < hi)).sum() * a),
                    "false_ahn3_unclassified_m2": float((fp & (k.pierced_share >= lo) & (k.pierced_share < hi)
                                                         & (k.ahn3_class == 1)).sum() * a),
                    "found_m2": float((tp & (k.pierced_share >= lo) & (k.pierced_share < hi)).sum() * a)}
                for b, (lo, hi) in PIERCED_BANDS.items()},
            "false_m2_by_ahn3_class": {str(int(v)): float((k.ahn3_class[fp] == v).sum() * a)
                                       for v in np.unique(k.ahn3_class[fp])},
            "false_pieces": int(n_obj),
            "false_m2_in_pieces_touching_a_found_footprint": float(np.isin(lab, touching[touching > 0]).sum() * a),
            "false_m2_by_distance": {b: float((fp & (dist_m > lo) & (dist_m <= hi)).sum() * a)
                                     for b, (lo, hi) in DISTANCE_BANDS_M.items()},
        }
        if png_stem and name in BOXES:
            plot(grid, ref & s, fp, tp, ~bld & ref & s, s, k, polys, name, BOXES[name],
                 bgt.REPO / "bench" / "results" / f"{png_stem}_{name}.png")
    return out


def per_point_building(classified: Path, laz: Path, split_xy: tuple) -> dict:
    """Building PA / UA per point against AHN3's class 6, per quarter (the reported per-point figure)."""
    ours, ref = io.read_cloud(classified, crs=bgt.CRS), io.read_cloud(laz, crs=bgt.CRS)
    q = bgt._quarter_of(ref.x, ref.y, *split_xy)
    b, t = ours.classification == BUILDING, ref.classification == BUILDING
    return {name: {"building_pa_pct": 100.0 * float((b & t & (q == k)).sum()) / max(int((t & (q == k)).sum()), 1),
                   "building_ua_pct": 100.0 * float((b & t & (q == k)).sum()) / max(int((b & (q == k)).sum()), 1)}
            for k, name in enumerate(bgt.PARTS)}


def plot(grid, ref, fp, tp, fn, scored, k: CellKinds, polys, name, box, path: Path):
    t = grid.transform
    extent = (t.c, t.c + t.a * grid.shape[1], t.f + t.e * grid.shape[0], t.f)
    fig, axs = plt.subplots(1, 4, figsize=(32, 8.5))
    st = np.ones(grid.shape + (3,))
    st[scored] = (0.9, 0.9, 0.9)
    st[tp], st[fp], st[fn] = (0.55, 0.55, 0.55), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    axs[0].imshow(st, extent=extent, interpolation="nearest")
    axs[0].set_title(f"{name}: building found (grey), false (red), missed (blue); black: BGT")
    im = axs[1].imshow(k.hag_m, extent=extent, cmap="viridis", vmin=0, vmax=10, interpolation="nearest")
    plt.colorbar(im, ax=axs[1], shrink=0.7)
    axs[1].set_title("highest return above the ground (m)")
    im = axs[2].imshow(k.split_share, extent=extent, cmap="magma", vmin=0, vmax=1, interpolation="nearest")
    plt.colorbar(im, ax=axs[2], shrink=0.7)
    axs[2].set_title("split-pulse share, 3 x 3 cells")
    im = axs[3].imshow(k.pierced_share, extent=extent, cmap="magma", vmin=0, vmax=0.5, interpolation="nearest")
    plt.colorbar(im, ax=axs[3], shrink=0.7)
    axs[3].set_title("pulses through to the ground, 3 x 3 cells")
    for ax in axs:
        for p in polys:
            ax.plot(*p.exterior.xy, "k-" if ax is axs[0] else "c-", lw=0.8)
        ax.set_xlim(box[0], box[1])
        ax.set_ylim(box[2], box[3])
    fig.tight_layout()
    fig.savefig(path, dpi=60)
    plt.close(fig)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    laz = bgt.SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = bgt.read_bgt(bgt.SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    c = io.read_cloud(laz, crs=bgt.CRS)
    split_xy = (float(np.median(c.x)), float(np.median(c.y)))
    runs = {"defaults": {}}
    if "--before" in argv:
        runs["before"] = BEFORE
    if "--low" in argv:     # on the rules shipped before the third round
        h = float(argv[argv.index("--low") + 1])
        runs[f"low_growth_max_height_m {h:g}"] = {**BEFORE, "low_growth_max_height_m": h}
    if "--pierced" in argv:     # likewise
        f = float(argv[argv.index("--pierced") + 1])
        runs[f"pierced_growth_max_fraction {f:g}"] = {**BEFORE, "pierced_growth_max_fraction": f}
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    result = {"command": "bench/eval_buildings_bgt_false.py " + " ".join(argv),"data": "ahn3_cropped_1.laz vs the BGT footprints (bgt_pand.sqlite); scoring of eval_buildings_bgt.py",
              "split_share_min": SPLIT_SHARE, "low_m": list(LOW_M)}
    with tempfile.TemporaryDirectory(prefix="eval_bgt_false_") as tmp:
        for key, overrides in runs.items():
            path = Path(tmp) / "classified.laz"
            tiles.classify_file(laz, path, crs=bgt.CRS, params=dataclasses.replace(ClassifySettings(), **overrides))
            png = {"defaults": "buildings_bgt_false", "before": "buildings_bgt_false_before"}.get(key)
            result[key] = {"overrides": overrides, "quarters": diagnose(path, laz, polys, split_xy, png),
                           "per_point_vs_ahn3": per_point_building(path, laz, split_xy)}
    result["seconds"] = time.perf_counter() - t0
    result["load_average_before_after"] = [load0, os.getloadavg()[0]]
    for key in runs:
        for name, v in result[key]["quarters"].items():
            print(f"{key} {name}: false {v['false_m2']:.1f} m2, found {v['found_m2']:.1f} m2")
            for kn, kv in v["by_kind"].items():
                print(f"    {kn}: false {kv['false_m2']:.2f}, found {kv['found_m2']:.2f}")
            pp = result[key]["per_point_vs_ahn3"][name]
            print(f"    per point vs AHN3: building PA {pp['building_pa_pct']:.1f} %, UA {pp['building_ua_pct']:.1f} %")
    out = bgt.REPO / "bench" / "results" / "buildings_bgt_false_area.json"
    out.write_text(json.dumps(result, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
