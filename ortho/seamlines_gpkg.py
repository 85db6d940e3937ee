"""Seamlines a user can edit: ``ortho/seamlines.gpkg`` (one polygon per frame, its ``frame`` name, the mosaic's CRS;
layer ``seamlines``, openable and editable in QGIS), and the edited polygons read back and checked for
``ortho mosaic --seamlines EDITED.gpkg``.

An edited file is checked whole before the mosaic writes anything (``InputError`` naming the file, the feature and
the frame; exit 2): every feature names a frame of ``ortho/frames/index.json`` (field ``frame``, or ``image_id``
as in seamlines.geojson, whose features of another ``kind`` than ``frame_region``, the seam lines, are passed over)
and holds a valid polygon in the mosaic's CRS (a frame's polygon may come in several features, single parts: they
are merged); no two polygons overlap (by more than
``OVERLAP_TOLERANCE_CELLS`` seam cells); every seam cell some frame sees is inside a polygon (no gap); and every
polygon lies inside its frame's footprint (the cells its ortho covers, holes of occlusion included, widened by one
seam cell for the rounding of edited vertices).

The polygons are rasterised onto the mosaic's seam grid (a cell belongs to the polygon holding its centre): the
seams follow the edited edges to within a seam cell (``seam_factor`` mosaic pixels, about 1.5 m).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np

from aerotri.core.errors import InputError

LAYER = "seamlines"
REGION_KIND = "frame_region"  # seamlines.geojson's "kind" of a frame's polygon (its seam lines: "seamline")
OVERLAP_TOLERANCE_CELLS = 0.5  # overlaps smaller than half a seam cell are rounding of shared vertices


@dataclasses.dataclass(frozen=True)
class EditedSeamlines:
    """The edited polygons as seam labels: ``labels`` (seam grid, frame index or -1) and per frame name the ids of
    the features its polygon came from (a tuple)."""

    path: Path
    labels: np.ndarray
    feature_of_frame: dict
    gaps_given: tuple = ()  # ``GapGiven`` s: the gaps one frame alone sees, given to it (``give_sole_gaps``)


@dataclasses.dataclass(frozen=True)
class GapGiven:
    """Seam cells in no edited polygon that one frame alone sees, given to that frame: how many, their area (m2) and
    a point (map x, y) of the largest area of them."""

    frame: str
    cells: int
    area_m2: float
    areas: int
    x: float
    y: float

    def record(self) -> dict:
        return dataclasses.asdict(self)


def write_seamlines_gpkg(path, labels: np.ndarray, transform, names: list[str], crs, features: list | None = None
                         ) -> None:
    """``path`` (a GeoPackage, written whole): layer ``seamlines``, one MultiPolygon per labelled frame with the
    fields ``frame`` (its image id) and ``area_m2``, in ``crs`` (the mosaic's). ``features``: ``label_polygons`` of
    the same labels, if already made."""
    import shapely
    from shapely.geometry import shape

    from aerotri.core.vector_files import VectorLayer, write_layers
    from ortho.seamlines import label_polygons

    if features is None:
        features = label_polygons(labels, transform, names)
    geoms = [shapely.geometry.MultiPolygon([g]) if g.geom_type == "Polygon" else g
             for g in (shape(f["geometry"]) for f in features)]
    frames = np.array([f["properties"]["image_id"] for f in features], dtype=object)
    areas = np.array([f["properties"]["area_m2"] for f in features], dtype=np.float64)
    write_layers(path, [VectorLayer(LAYER, "MultiPolygon", geoms, {"frame": frames, "area_m2": areas})], crs=crs)


def require_seamlines_file(path) -> None:
    """An ``InputError`` unless ``path`` is a file (a folder was "not found": trial s98 L4)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder; expected the edited seamlines file, a GeoPackage such as ortho mosaic "
                         "writes (ortho/seamlines.gpkg, edited in a copy) (--seamlines)")
    if not path.is_file():
        raise InputError(f"{path}: edited seamlines not found (--seamlines)")


def read_edited_seamlines(path, names: list[str], crs, *, labels_shape, transform, valid: list, offsets: list,
                          excluded=(), give_sole_gaps: bool = False) -> EditedSeamlines:
    """The polygons of an edited seamlines GeoPackage (or any OGR vector file) as labels on the seam grid
    (``labels_shape``, ``transform``), checked against the frames (``names``; ``valid``/``offsets``: each frame's
    valid seam cells and the (row, col) of its first cell) as the module doc says; ``excluded``: frames of ortho/frames
    the mosaic leaves out (``[mosaic] exclude``), named as such when a polygon holds one. ``give_sole_gaps``: a gap's
    cells that one frame alone sees go to that frame (``EditedSeamlines.gaps_given``) instead of being refused; the
    cells several frames see still are (the chain re-making an edited mosaic over frame orthos made again since the
    edit: their new edges left the operator's polygons short of cells no other frame could take, trial s105 F3)."""
    import pyogrio
    import shapely
    from pyproj import CRS
    from rasterio import features

    path, excluded = Path(path), frozenset(excluded)
    require_seamlines_file(path)
    try:
        layers = [name for name, _ in pyogrio.list_layers(path)]
        if len(layers) > 1:
            # a second layer (QGIS "Save features as..." into the same file) was passed over for 'seamlines' or the
            # first one, the edit dropped without a word (trial-ortho2): the layer of polygons named by frame only
            framed = [n for n in layers if {"frame", "image_id"} & set(pyogrio.read_info(path, layer=n)["fields"])]
            if len(framed) > 1:
                raise InputError(f"{path}: {len(framed)} layers of frame polygons ({', '.join(framed)}): expected one "
                                 "(the mosaic reads one layer: keep the edited polygons in a file of their own, or "
                                 "delete the other layers)")
            layers = framed or layers
        layer = LAYER if LAYER in layers else layers[0]
        meta, fids, wkb, fields = pyogrio.raw.read(path, layer=layer, return_fids=True)
    except InputError:
        raise
    except Exception as exc:  # pyogrio's errors (DataSourceError, DataLayerError ...) and GDAL's
        raise InputError(f"{path}: cannot read the edited seamlines ({exc}); expected a GeoPackage as ortho mosaic "
                         "writes (ortho/seamlines.gpkg)") from None
    columns = list(meta["fields"])
    name_field = "frame" if "frame" in columns else "image_id" if "image_id" in columns else None
    if name_field is None:
        raise InputError(f"{path}: layer {layer!r} has no field 'frame' naming the frame of each polygon "
                         f"(fields: {', '.join(columns) or 'none'})")
    if meta.get("crs") is None:
        raise InputError(f"{path}: layer {layer!r} has no CRS; expected the mosaic's ({crs.name})")
    if not CRS.from_user_input(meta["crs"]).equals(crs, ignore_axis_order=True):
        raise InputError(f"{path}: layer {layer!r} is in {CRS.from_user_input(meta['crs']).name}; expected the "
                         f"mosaic's CRS ({crs.name}): save the edited layer in it")
    frame_names = fields[columns.index(name_field)]
    known = {n: k for k, n in enumerate(names)}
    geoms = shapely.from_wkb(wkb)
    region = np.array([k == REGION_KIND for k in fields[columns.index("kind")]], bool) if "kind" in columns else None
    if region is not None and region.any():  # seamlines.geojson as the mosaic writes it: seam lines beside polygons
        fids, frame_names, geoms = fids[region], frame_names[region], geoms[region]
    feature_of_frame: dict[int, tuple] = {}
    parts: dict[int, list] = {}
    for fid, name, g in zip(fids, frame_names, geoms):
        where = f"{path}: feature {fid}"
        if name is None or not str(name).strip():
            raise InputError(f"{where}: no frame name (field 'frame' empty); expected one of the mosaic's frames "
                             f"(ortho/frames/index.json: {len(names)} frames, e.g. {', '.join(names[:3])})")
        if name in excluded:
            raise InputError(f"{where}: frame {name} is left out of the mosaic ([mosaic] exclude / --exclude): give "
                             "its cells to the neighbouring polygons, or take it off the list")
        if name not in known:
            raise InputError(f"{where}: frame {name!r} is not a frame of the mosaic (ortho/frames/index.json: "
                             f"{len(names)} frames, e.g. {', '.join(names[:3])})")
        k = known[name]
        if g is None or g.is_empty or g.geom_type not in ("Polygon", "MultiPolygon"):
            got = "nothing" if g is None else f"an empty {g.geom_type}" if g.is_empty else g.geom_type
            raise InputError(f"{where} (frame {name}): expected a polygon, got {got}")
        if not g.is_valid:
            raise InputError(f"{where} (frame {name}): invalid polygon ({shapely.is_valid_reason(g)})")
        # a frame's polygon may come in several features: QGIS's "Multipart to singleparts", or a part drawn as a
        # feature of its own, were refused with "merge them" (trial s105 F4); they are one region of the frame
        feature_of_frame[k] = feature_of_frame.get(k, ()) + (int(fid),)
        parts.setdefault(k, []).append(g)
    polygons = [(k, g[0] if len(g) == 1 else shapely.union_all(g)) for k, g in parts.items()]
    if not polygons:
        raise InputError(f"{path}: no polygons in layer {layer!r}")
    cell_m2 = abs(transform.a * transform.e)
    tree = shapely.STRtree([g for _, g in polygons])
    for a, b in zip(*tree.query([g for _, g in polygons], predicate="intersects")):
        if a < b:
            area = polygons[a][1].intersection(polygons[b][1]).area
            if area > OVERLAP_TOLERANCE_CELLS * cell_m2:
                c = polygons[a][1].intersection(polygons[b][1]).representative_point()
                raise InputError(f"{path}: the polygons of frames {names[polygons[a][0]]} "
                                 f"({features_text(feature_of_frame[polygons[a][0]])}) and {names[polygons[b][0]]} "
                                 f"({features_text(feature_of_frame[polygons[b][0]])}) overlap by {area:.1f} m2 "
                                 f"around ({c.x:.1f}, {c.y:.1f}); a cell belongs to one frame")
    labels = features.rasterize(((g, k) for k, g in polygons), out_shape=labels_shape, transform=transform,
                                fill=-1, dtype="int32")
    # the polygons' parts beyond the seam grid are not in ``labels``: said with the part inside it (trial s98 M2: a
    # polygon grown 200 m past the block's edge was "768 m2 outside the frame", 8,592 m2 by its geometry)
    (h, w), (x0, y0) = labels_shape, transform @ (0, 0)
    x1, y1 = transform @ (w, h)
    grid = shapely.box(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))
    beyond_grid = {k: float(g.difference(grid).area) for k, g in polygons}
    given = _check_coverage(path, labels, names, feature_of_frame=feature_of_frame, transform=transform, valid=valid,
                            offsets=offsets, beyond_grid_m2=beyond_grid, give_sole_gaps=give_sole_gaps)
    return EditedSeamlines(path, labels, {names[k]: fid for k, fid in feature_of_frame.items()}, given)


def features_text(fids) -> str:
    """The features of one frame's polygon (a tuple of ids) as said in messages: "feature 3", "features 3, 7"."""
    return f"feature{'s' if len(fids) > 1 else ''} {', '.join(str(f) for f in fids)}"


def footprint(valid: np.ndarray) -> np.ndarray:
    """The cells a frame's polygon may hold: the cells the mosaic's own seams may give it
    (``ortho.seamlines.footprint``: its valid seam cells with the holes inside them filled, and for a true ortho
    the convex hull of its valid cells), widened by one cell (the rounding of edited vertices onto the seam grid)."""
    from ortho.seamlines import footprint as region_footprint

    return cv2.dilate(region_footprint(valid).view(np.uint8), np.ones((3, 3), np.uint8)) > 0


def _place(a: np.ndarray, off, shape) -> np.ndarray:
    """A frame's array on the whole seam grid (False outside it)."""
    out = np.zeros(shape, bool)
    r0, c0 = off
    r1, c1 = min(shape[0], r0 + a.shape[0]), min(shape[1], c0 + a.shape[1])
    out[max(r0, 0):r1, max(c0, 0):c1] = a[max(0, -r0):r1 - r0, max(0, -c0):c1 - c0]
    return out


def _check_coverage(path, labels, names, *, feature_of_frame, transform, valid, offsets,
                    beyond_grid_m2=None, give_sole_gaps: bool = False) -> tuple:
    """No polygon beyond its frame's footprint, no gap (a cell some frame sees outside every polygon);
    ``beyond_grid_m2``: per frame, its polygon's area beyond the seam grid (no frame's there), added to what is said.
    ``give_sole_gaps``: the gap cells one frame alone sees are labelled with it (``labels`` changed in place) and
    returned as ``GapGiven`` s; the other gap cells are refused as before."""
    cell_m2 = abs(transform.a * transform.e)
    # a polygon beyond its frame first: a polygon dragged off its frame leaves a gap too, and the gap's remedy
    # ("extend one over it") misled (trial s105 F5: 64,072 m2 to cover instead of the polygon to move back)
    for k, fid in sorted(feature_of_frame.items(), key=lambda kv: kv[1]):
        beyond = (labels == k) & ~_place(footprint(valid[k]), offsets[k], labels.shape)
        if beyond.any():
            r, c = np.argwhere(beyond)[0]
            x, y = transform @ (c + 0.5, r + 0.5)
            past = (beyond_grid_m2 or {}).get(k, 0.0)
            raise InputError(f"{path}: {features_text(fid)}: frame {names[k]} does not cover its polygon: "
                             f"{beyond.sum() * cell_m2 + past:.0f} m2 of it lie outside the "
                             f"frame's ortho (e.g. at ({x:.1f}, {y:.1f})"
                             + (f"; {past:.0f} m2 of them beyond the mosaic's extent" if past >= 1.0 else "")
                             + "); move the edge back inside the frame")
    # how many frames see each cell (2: more than one), and the (last) one that does
    count, owner = np.zeros(labels.shape, np.uint8), np.full(labels.shape, -1, np.int32)
    for k, (v, off) in enumerate(zip(valid, offsets)):
        placed = _place(v, off, labels.shape)
        count[placed] = np.minimum(count[placed], 1) + 1
        owner[placed] = k
    seen = count > 0
    gap = seen & (labels < 0)
    given = []
    if give_sole_gaps and gap.any():
        for k in np.unique(owner[gap & (count == 1)]):
            mine = gap & (count == 1) & (owner == k)
            n, lab = cv2.connectedComponents(mine.view(np.uint8), connectivity=4)
            r, c = np.argwhere(lab == 1 + int(np.argmax(np.bincount(lab.ravel())[1:])))[0]
            x, y = transform @ (c + 0.5, r + 0.5)
            given.append(GapGiven(names[k], int(mine.sum()), round(float(mine.sum() * cell_m2), 1), n - 1,
                                  round(float(x), 2), round(float(y), 2)))
            labels[mine] = k
        gap = seen & (labels < 0)
    if gap.any():
        n, lab = cv2.connectedComponents(gap.view(np.uint8), connectivity=4)
        sizes = np.bincount(lab.ravel())[1:]
        largest = lab == 1 + int(np.argmax(sizes))
        r, c = np.argwhere(largest)[0]
        x, y = transform @ (c + 0.5, r + 0.5)
        # who can take it (trial s98 L2: the gap was named by a coordinate only): the frames that see it, and the
        # polygons beside it by feature id
        seeing = [names[k] for k, (v, off) in enumerate(zip(valid, offsets)) if (_place(v, off, labels.shape)
                                                                                  & largest).any()]
        ring = cv2.dilate(largest.view(np.uint8), np.ones((3, 3), np.uint8)) > 0
        beside = sorted({int(k) for k in np.unique(labels[ring & ~largest]) if k >= 0},
                        key=lambda k: feature_of_frame.get(k, (-1,)))
        beside_text = ", ".join(f"{names[k]} ({features_text(feature_of_frame[k])})" for k in beside
                                if k in feature_of_frame) or "none"
        # cells only one frame sees are left by frame orthos that cover more than when the polygons were drawn
        # (rectified again since): said apart, with where they come from (trial s106 F2/F5: "4 seam cells" at the
        # block's corners, lumped with the edit's own hole, passed `aerotri run` and failed here without a reason)
        sole = gap & (count == 1)
        sole_text = "" if not sole.any() else (
            f"; {int(sole.sum())} of the cells ({sole.sum() * cell_m2:.0f} m2) are seen by one frame alone (frame "
            "orthos rectified again since the polygons were drawn cover a little more: aerotri run gives such cells "
            "to their frame; or start from the run's own ortho/seamlines.gpkg)")
        raise InputError(f"{path}: a gap between the polygons: {int(gap.sum())} seam cells "
                         f"({gap.sum() * cell_m2:.0f} m2, {n - 1} area(s)) that frames see are "
                         f"in no polygon; the largest around ({x:.1f}, {y:.1f}), seen by {', '.join(seeing[:6])}"
                         f"{' ...' if len(seeing) > 6 else ''}; the polygons beside it: {beside_text}: extend one "
                         f"over it{sole_text}")
    return tuple(given)
