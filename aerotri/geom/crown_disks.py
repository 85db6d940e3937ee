"""Tree crowns as disks (a fitted rim per tree, its top and crown base) and the grid cells they cover, shared by
``lidarctl.rasters.crown_model`` (which fits them to LiDAR returns) and ``ortho.crown_cells`` (which puts them in the
true ortho's occlusion test). Lengths and heights in metres or the CRS's unit, as given; grids north-up (row 0 at
``y_top_m``, columns from ``x0_m``).
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class TreeCrowns:
    """One entry per tree: the crown's disk (centre ``x_m``, ``y_m``, ``radius_m``), its ``top_m`` (highest
    vegetation first return), ``base_m`` (lowest vegetation return, any return number), the vegetation first
    returns it holds (``returns``), ``circle_fit`` (the circle fitted to its rim samples; False: centroid and median
    distance), and ``spacing_m`` (the cloud's first-return spacing)."""

    x_m: np.ndarray
    y_m: np.ndarray
    radius_m: np.ndarray
    top_m: np.ndarray
    base_m: np.ndarray
    returns: np.ndarray
    circle_fit: np.ndarray
    spacing_m: float

    def __len__(self) -> int:
        return len(self.x_m)


def crown_sub_cells(crowns: TreeCrowns, *, x0_m: float, y_top_m: float, res_m: float, shape: tuple[int, int],
                    sub: int, reach_m: float = 1.0, window: tuple[int, int, int, int] | None = None):
    """The cells a crown's disk reaches within ``reach_m``: rows, cols (int64), per cell the signed distance (cm,
    int16, positive inside) of its ``sub`` x ``sub`` sub-cell centres within the union of the disks (rows from the
    north, columns from the west), the lowest crown base and the highest top of the trees whose disks cover a
    sub-cell centre of it (NaN: none). ``window``: (row0, col0, rows, cols) of the grid, the only cells given (rows
    and columns still of the whole grid; a window's cells as in the whole grid, bit for bit)."""
    w_r0, w_c0, w_rows, w_cols = window if window is not None else (0, 0, *shape)
    off = (np.arange(sub) + 0.5) / sub
    cells, margins, bases, tops = [], [], [], []
    for t in range(len(crowns)):
        cx, cy, r = crowns.x_m[t], crowns.y_m[t], crowns.radius_m[t]
        r0 = max(w_r0, int((y_top_m - cy - r - reach_m) / res_m))
        r1 = min(w_r0 + w_rows, int((y_top_m - cy + r + reach_m) / res_m) + 1)
        c0 = max(w_c0, int((cx - r - reach_m - x0_m) / res_m))
        c1 = min(w_c0 + w_cols, int((cx + r + reach_m - x0_m) / res_m) + 1)
        if r1 <= r0 or c1 <= c0:
            continue
        rr, cc = np.meshgrid(np.arange(r0, r1), np.arange(c0, c1), indexing="ij")
        ys = y_top_m - (rr.ravel()[:, None, None] + off[None, :, None]) * res_m
        xs = x0_m + (cc.ravel()[:, None, None] + off[None, None, :]) * res_m
        m = r - np.hypot(xs - cx, ys - cy)  # (k, sub, sub)
        cells.append(rr.ravel() * shape[1] + cc.ravel())
        margins.append(m)
        covers = (np.round(m * 100.0) >= 0).any(axis=(1, 2))  # as the margins in cm below
        bases.append(np.where(covers, crowns.base_m[t], np.inf))
        tops.append(np.where(covers, crowns.top_m[t], -np.inf))
    if not cells:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros((0, sub, sub), np.int16), np.zeros(0, np.float32), np.zeros(0, np.float32)
    flat = np.concatenate(cells)
    order = np.argsort(flat, kind="stable")
    flat = flat[order]
    first = np.flatnonzero(np.concatenate([[True], flat[1:] != flat[:-1]]))
    margin = np.maximum.reduceat(np.concatenate(margins)[order], first, axis=0)
    base = np.minimum.reduceat(np.concatenate(bases)[order], first)
    top = np.maximum.reduceat(np.concatenate(tops)[order], first)
    rows, cols = np.divmod(flat[first], shape[1])
    cm = np.clip(np.round(margin * 100.0), -32000, 32000).astype(np.int16)
    return (rows, cols, cm, np.where(np.isfinite(base), base, np.nan).astype(np.float32),
            np.where(np.isfinite(top), top, np.nan).astype(np.float32))
