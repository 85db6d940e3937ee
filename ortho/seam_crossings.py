"""Where edited seamlines cross buildings and trees (``ortho mosaic --seamlines EDITED.gpkg``).

An edited seam is never routed again (the user's polygons are the seams); this check only measures it. Per pair of
neighbouring frames, on the seam grid's labels (the edited polygons as rasterised: what the mosaic cuts along) and
on the labels the automatic seams would have (``ortho mosaic`` without ``--seamlines``, on the same frames):

- the seam: the shared outline of the two frames' regions, its cell staircase smoothed (the line through its
  edges' middles, ``_smoothed``: a straight edit rasterised comes back straight, its length within a cell);
- its length (m) and the length over raised objects: nDSM above ``RAISED_M`` (0.5 m), sampled every
  ``SAMPLE_STEP_CELLS`` of the nDSM's cell along the seam; a raised sample is a tree where the CHM (``chm.tif``
  beside the nDSM, the LiDAR's vegetation classes 4/5 above the DEM) is above ``RAISED_M`` too, else a building
  (any raised non-vegetation: roofs, walls, also cars and sheds); without a CHM every raised sample is a "raised
  object";
- the crossings: runs of raised samples along the seam (gaps shorter than one seam cell joined); a crossing of the
  edited seam is *new* when fewer than half its samples lie within one seam cell of the automatic seam of the same
  pair (an unedited edge's crossings are the automatic seams' own).

A pair whose new crossings add up to one seam cell or more is a warning naming the two frames (and
their features in the edited file) and the longest new crossing (length, kind, x, y). Thresholds a priori: 0.5 m is
the brief's raised-object height (a roof, a crown, not the ground's noise); one seam cell is the rasterisation's
rounding of an edge.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

RAISED_M = 0.5  # nDSM (and CHM) height above which a cell is a raised object (building, tree), metres
SAMPLE_STEP_CELLS = 0.5  # sampling step along a seam, nDSM cells
LAYER = "seam_crossings"
FILE = "seam_crossings.gpkg"


@dataclasses.dataclass(frozen=True)
class Crossing:
    """One run of a seam over raised objects: its frames, kind ("building", "tree", "raised"), length (m), middle
    (x, y, mosaic CRS), whether the automatic seams do not have it (``new``), and the line (shapely)."""

    frame_a: str
    frame_b: str
    kind: str
    length_m: float
    x_m: float
    y_m: float
    new: bool
    line: object


@dataclasses.dataclass(frozen=True)
class PairFigures:
    """One seam (frames a < b by index): its length and length over buildings / trees / raised objects (m), on the
    edited labels and on the automatic ones (None: the automatic seams have no such pair), and the new crossings."""

    frame_a: str
    frame_b: str
    seam_m: float
    building_m: float
    tree_m: float
    crossings: int
    new_m: float
    automatic_seam_m: float | None
    automatic_building_m: float | None
    automatic_tree_m: float | None
    longest_new: Crossing | None

    def record(self) -> dict:
        d = {k: (round(v, 2) if isinstance(v, float) else v) for k, v in dataclasses.asdict(self).items()
             if k != "longest_new"}
        c = self.longest_new
        d["longest_new"] = None if c is None else {"kind": c.kind, "length_m": round(c.length_m, 2),
                                                   "x_m": round(c.x_m, 2), "y_m": round(c.y_m, 2)}
        return d


@dataclasses.dataclass(frozen=True)
class SeamCrossings:
    """The check of one edited run: ``checked`` False with ``why`` when it was not made (no nDSM); the nDSM and
    CHM read (None: no CHM, kinds "raised"), the pairs, every crossing of the edited seams, and the warnings."""

    checked: bool
    why: str | None
    ndsm: str | None = None
    chm: str | None = None
    seam_cell_m: float | None = None
    pairs: tuple[PairFigures, ...] = ()
    crossings: tuple[Crossing, ...] = ()
    warnings: tuple[str, ...] = ()

    def record(self) -> dict:
        """mosaic.json's "seam_crossings"."""
        if not self.checked:
            return {"checked": False, "why": self.why}
        tot = {k: round(sum(getattr(p, k) or 0.0 for p in self.pairs), 2)
               for k in ("seam_m", "building_m", "tree_m", "new_m", "automatic_seam_m", "automatic_building_m",
                         "automatic_tree_m")}
        return {"checked": True, "ndsm": self.ndsm, "chm": self.chm,
                "kinds": "building / tree (CHM)" if self.chm else "raised objects (no CHM: building_m holds them all)",
                "raised_m": RAISED_M, "seam_cell_m": self.seam_cell_m, "totals": tot,
                "crossings": len(self.crossings), "new_crossings": sum(c.new for c in self.crossings),
                "pairs_with_new_crossings": sum(p.new_m >= self.seam_cell_m for p in self.pairs),
                "file": FILE, "warnings": list(self.warnings), "pairs": [p.record() for p in self.pairs]}


@dataclasses.dataclass(frozen=True)
class CrossingsSummary:
    """mosaic.json's "seam_crossings" as read back (``ortho.mosaic.read_mosaic_summary``): whether the check was made
    (``why`` not), the totals over the pairs (m) of the edited seams and of the automatic ones, the new crossings and
    the pairs with any, and the warnings."""

    checked: bool
    why: str | None = None
    building_m: float = 0.0
    tree_m: float = 0.0
    automatic_building_m: float = 0.0
    automatic_tree_m: float = 0.0
    new_m: float = 0.0
    new_crossings: int = 0
    pairs_with_new_crossings: int = 0
    with_chm: bool = False
    warnings: tuple[str, ...] = ()

    @classmethod
    def from_record(cls, d: dict) -> CrossingsSummary:
        if not d["checked"]:
            return cls(False, d["why"])
        t = d["totals"]
        return cls(True, None, t["building_m"], t["tree_m"], t["automatic_building_m"], t["automatic_tree_m"],
                   t["new_m"], d["new_crossings"], d["pairs_with_new_crossings"], d["chm"] is not None,
                   tuple(d["warnings"]))


class _Sampler:
    """A height raster sampled at points of the mosaic's CRS (nearest cell), read by 512-cell windows."""

    def __init__(self, path, mosaic_crs, operation=None, what: str = "nDSM"):
        import rasterio

        from aerotri.core.errors import InputError
        from aerotri.geom.crs.definition import height_unit_m, parse_crs, same_horizontal
        from aerotri.geom.crs.transform import CrsTransformer

        self.path, self.what = path, what
        try:
            self.ds = rasterio.open(path)
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{path}: cannot read the {what} ({exc}); expected a height raster as lidarctl rasters "
                             "writes (remake it, or move it away)") from None
        if self.ds.crs is None:
            self.ds.close()
            raise InputError(f"{path}: the {what} has no CRS; expected the project's")
        self.unit = float(height_unit_m(parse_crs(self.ds.crs.to_wkt(), f"{path} CRS")))
        self.to = None if operation is None and same_horizontal(self.ds.crs, mosaic_crs) else \
            (operation or CrsTransformer(mosaic_crs, self.ds.crs))
        self.cell = abs(self.ds.transform.a) * self.unit if self.ds.crs.is_projected else None

    def close(self):
        self.ds.close()

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        import rasterio
        from rasterio.windows import Window

        from aerotri.core.errors import InputError

        if self.to is not None:
            x, y = self.to.transform(x, y)[:2]
        inv = ~self.ds.transform
        col, row = inv * (np.asarray(x), np.asarray(y))
        row, col = np.floor(row).astype(np.int64), np.floor(col).astype(np.int64)
        out = np.zeros(len(row), np.float32)
        inside = (row >= 0) & (row < self.ds.height) & (col >= 0) & (col < self.ds.width)
        B = 512
        keys = (row // B) * (self.ds.width // B + 1) + col // B
        for key in np.unique(keys[inside]):
            sel = inside & (keys == key)
            r0, c0 = int(row[sel][0] // B * B), int(col[sel][0] // B * B)
            w = Window(c0, r0, min(B, self.ds.width - c0), min(B, self.ds.height - r0))
            try:
                a = self.ds.read(1, window=w, masked=True)
            except rasterio.errors.RasterioIOError as exc:
                raise InputError(f"{self.path}: cannot read the {self.what} (truncated or corrupt? {exc})") from None
            v = np.ma.filled(a.astype(np.float32), np.nan)[row[sel] - r0, col[sel] - c0]
            out[sel] = np.nan_to_num(v, nan=0.0) * self.unit
        return out


def _pair_lines(labels, transform, names, cell_m):
    """(i, j) -> the simplified seam line (shapely) of every neighbouring pair of ``labels``."""
    from ortho.seamlines import seam_lines
    from shapely.geometry import shape

    out = {}
    index = {n: k for k, n in enumerate(names)}
    for f in seam_lines(labels, transform, names):
        p = f["properties"]
        out[index[p["image_a"]], index[p["image_b"]]] = _smoothed(shape(f["geometry"]), cell_m)
    return out


def _smoothed(line, cell_m: float):
    """The cell staircase of a seam (edges along the seam grid's rows and columns) as the line through its edges'
    middles (an edge longer than two cells: its points one cell from either end, so that a corner is cut by a cell,
    not half the edge); the ends kept. A straight edit rasterised comes back within a cell of its length (the
    module's test: straight edges at 0-80 deg, lengths within 1.1 m on 1.6 m cells; Douglas-Peucker on the staircase
    left up to 3.9 m)."""
    import shapely

    parts = []
    for part in getattr(line, "geoms", [line]):
        c = np.asarray(part.coords)
        pts = [c[0]]
        for a, b in zip(c[:-1], c[1:]):
            n = float(np.hypot(*(b - a)))
            if n <= 2 * cell_m * (1 + 1e-9):
                pts.append(0.5 * (a + b))
            else:
                pts += [a + (b - a) * (cell_m / n), b - (b - a) * (cell_m / n)]
        pts.append(c[-1])
        parts.append(shapely.LineString(np.array(pts)))
    return parts[0] if len(parts) == 1 else shapely.MultiLineString(parts)


def _runs(raised: np.ndarray, join: int) -> list[tuple[int, int]]:
    """[start, stop) of the runs of ``raised`` with gaps shorter than ``join`` samples joined."""
    idx = np.flatnonzero(raised)
    if len(idx) == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > join)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    stops = np.concatenate([idx[breaks], [idx[-1]]]) + 1
    return list(zip(starts.tolist(), stops.tolist()))


def _measure(line, ndsm: _Sampler, chm: _Sampler | None, step_m: float, join: int):
    """Per part of ``line``: (building m, tree m, length m, runs as (part, d0, d1, kind)) over the samples."""
    import shapely

    parts = list(getattr(line, "geoms", [line]))
    building = tree = 0.0
    runs = []
    for part in parts:
        n = max(1, int(math.ceil(part.length / step_m)))
        step = part.length / n
        d = (np.arange(n) + 0.5) * step
        pts = shapely.line_interpolate_point(part, d)
        x, y = shapely.get_x(pts), shapely.get_y(pts)
        raised = ndsm(x, y) > RAISED_M
        is_tree = raised & (chm(x, y) > RAISED_M) if chm is not None else np.zeros_like(raised)
        building += float(np.count_nonzero(raised & ~is_tree)) * step
        tree += float(np.count_nonzero(is_tree)) * step
        for a, b in _runs(raised, join):
            t = int(np.count_nonzero(is_tree[a:b]))
            kind = "raised" if chm is None else ("tree" if 2 * t > np.count_nonzero(raised[a:b]) else "building")
            runs.append((part, float(a * step), float(b * step), kind, x[a:b], y[a:b]))
    return building, tree, float(line.length), runs


def check_seam_crossings(labels: np.ndarray, automatic: np.ndarray, transform, names: list[str], mosaic_crs, *,
                         ndsm_path, operation=None, feature_of_frame: dict | None = None) -> SeamCrossings:
    """The edited seams (``labels``, seam grid of affine ``transform``) against the automatic ones (``automatic``)
    over the nDSM (``ndsm_path``, None: not checked; ``operation``: mosaic CRS -> nDSM CRS when they differ);
    ``feature_of_frame``: frame name -> feature ids in the edited file (for the warnings). The labels are not changed."""
    import shapely
    from shapely.ops import substring

    from ortho.seamlines_gpkg import features_text

    if ndsm_path is None:
        return SeamCrossings(False, "no nDSM (lidar_out/ndsm.tif or [mosaic] ndsm): where the edited seams cross "
                                    "buildings and trees was not checked")
    cell_m = abs(transform.a)
    chm_path = Path(ndsm_path).with_name("chm.tif")
    ndsm = _Sampler(ndsm_path, mosaic_crs, operation)
    try:
        chm = _Sampler(chm_path, mosaic_crs, operation, "CHM (beside the nDSM: trees vs buildings)") \
            if chm_path.is_file() else None
    except BaseException:
        ndsm.close()
        raise
    try:
        step_m = SAMPLE_STEP_CELLS * min(cell_m, ndsm.cell or cell_m)
        join = max(1, int(round(cell_m / step_m)))
        edited, auto = _pair_lines(labels, transform, names, cell_m), _pair_lines(automatic, transform, names, cell_m)
        feature_of_frame = feature_of_frame or {}
        pairs, crossings, warnings = [], [], []
        for (i, j), line in sorted(edited.items()):
            b_m, t_m, seam_m, runs = _measure(line, ndsm, chm, step_m, join)
            a_line = auto.get((i, j))
            if a_line is not None:
                ab_m, at_m, aseam_m, _ = _measure(a_line, ndsm, chm, step_m, join)
                near = a_line.buffer(cell_m)
                shapely.prepare(near)
            else:
                ab_m = at_m = aseam_m = near = None
            mine = []
            for part, d0, d1, kind, xs, ys in runs:
                along = near is not None and np.mean(shapely.contains_xy(near, xs, ys)) >= 0.5
                seg = substring(part, d0, d1)
                mid = part.interpolate(0.5 * (d0 + d1))
                mine.append(Crossing(names[i], names[j], kind, d1 - d0, mid.x, mid.y, not along, seg))
            crossings += mine
            new = [c for c in mine if c.new]
            new_m = float(sum(c.length_m for c in new))
            longest = max(new, key=lambda c: c.length_m) if new else None
            p = PairFigures(names[i], names[j], seam_m, b_m, t_m, len(mine), new_m, aseam_m, ab_m, at_m, longest)
            pairs.append(p)
            if new_m >= cell_m:
                fa, fb = feature_of_frame.get(names[i]), feature_of_frame.get(names[j])
                what = ("buildings %.1f m, trees %.1f m" % (b_m, t_m)) if chm is not None else \
                    ("raised objects (nDSM > %.1f m) %.1f m" % (RAISED_M, b_m))
                auto_what = "no seam between them" if a_line is None else (
                    ("%.1f m / %.1f m" % (ab_m, at_m)) if chm is not None else "%.1f m" % ab_m)
                warnings.append(
                    f"edited seam between frames {names[i]}{'' if fa is None else f' ({features_text(fa)})'} and "
                    f"{names[j]}{'' if fb is None else f' ({features_text(fb)})'} crosses {what} (automatic seams: "
                    f"{auto_what}); "
                    f"{len(new)} new crossing(s), {new_m:.1f} m, the longest {longest.length_m:.1f} m over "
                    f"{'a ' + longest.kind if longest.kind != 'raised' else 'a raised object'} at "
                    f"({longest.x_m:.1f}, {longest.y_m:.1f}): roofs and crowns tear there (ortho/{FILE})")
    finally:
        ndsm.close()
        if chm is not None:
            chm.close()
    return SeamCrossings(True, None, str(ndsm_path), str(chm_path) if chm is not None else None, cell_m,
                         tuple(pairs), tuple(crossings), tuple(warnings))


def write_crossings_gpkg(path, result: SeamCrossings, crs) -> None:
    """``path`` (GeoPackage, written whole): layer ``seam_crossings``, one LineString per crossing of the edited seams
    with ``frame_a``, ``frame_b``, ``kind``, ``length_m``, ``new`` (1: the automatic seams do not cross there)."""
    from aerotri.core.vector_files import VectorLayer, write_layers

    cs = result.crossings
    fields = {"frame_a": np.array([c.frame_a for c in cs], dtype=object),
              "frame_b": np.array([c.frame_b for c in cs], dtype=object),
              "kind": np.array([c.kind for c in cs], dtype=object),
              "length_m": np.array([round(c.length_m, 2) for c in cs], dtype=np.float64),
              "new": np.array([int(c.new) for c in cs], dtype=np.int32)}
    write_layers(path, [VectorLayer(LAYER, "LineString", [c.line for c in cs], fields)], crs=crs,
                 timestamp="2000-01-01T00:00:00.000Z")
