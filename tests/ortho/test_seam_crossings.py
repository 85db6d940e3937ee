"""Edited seamlines that cross buildings are reported (issue 42, ``ortho.seam_crossings``): an edge moved through a
known box building of the synthetic project is a warning naming both frames, its crossing in
ortho/seam_crossings.gpkg within a seam cell of the drawn line's length over the building; the unedited copy has
nothing new; no nDSM: the check says it was not made. The edited seams are never changed."""

from __future__ import annotations

import json
import logging
import math
import shutil

import numpy as np
import pyogrio
import pytest
import rasterio
import shapely
from click.testing import CliRunner
from rasterio import features

from ortho.cli import main
from tests.shared_builds import write_synthetic_project

TILE_PX = 128


@pytest.fixture(scope="module")
def mosaicked(tmp_path_factory):
    root = tmp_path_factory.mktemp("crossings") / "p"
    sp = write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=6, seed=3)
    for args in (["rectify", str(root)], ["mosaic", str(root), "--tile-px", str(TILE_PX)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    return root, sp.buildings


def _polygons(path):
    meta, _, wkb, fields = pyogrio.raw.read(path, return_fids=True)
    return meta, list(fields[list(meta["fields"]).index("frame")]), list(shapely.from_wkb(wkb))


def _write(path, names, geoms, crs):
    geoms = [shapely.MultiPolygon([g]) if g.geom_type == "Polygon" else g for g in geoms]
    pyogrio.raw.write(str(path), shapely.to_wkb(np.array(geoms, dtype=object)), [np.array(names, dtype=object)],
                      ["frame"], layer="seamlines", driver="GPKG", geometry_type="MultiPolygon", crs=crs)


def _through_a_building(root, names, geoms, boxes, theta_deg=30.0, margin_m=4.0):
    """Frame j takes the part of frame i's polygon right of a line through a building's centre (``theta_deg`` from
    north), within the building's box widened by ``margin_m``; no other building near. Returns the edited polygons,
    the two frames and the drawn line's length over the building (its box: the truth)."""

    def valid_of(k):
        with rasterio.open(root / "ortho" / "frames" / f"{names[k]}.tif") as f:
            m = f.read_masks(1)
            shapes = [shapely.geometry.shape(g) for g, _ in features.shapes(m, mask=m > 0, transform=f.transform)]
        return shapely.union_all(shapes).buffer(-3)

    valid = [valid_of(k) for k in range(len(names))]
    t = math.radians(theta_deg)
    dx, dy, L = math.sin(t), math.cos(t), 60.0
    for x0, y0, x1, y1, _ in boxes:
        box = shapely.box(x0, y0, x1, y1)
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        line = shapely.LineString([(cx - dx * L, cy - dy * L), (cx + dx * L, cy + dy * L)])
        right = shapely.Polygon([(cx - dx * L, cy - dy * L), (cx + dx * L, cy + dy * L),
                                 (cx + dx * L + dy * L, cy + dy * L - dx * L), (cx - dx * L + dy * L, cy - dy * L - dx * L)])
        region = right.intersection(shapely.box(x0 - margin_m, y0 - margin_m, x1 + margin_m, y1 + margin_m))
        if any(shapely.box(*o[:4]).intersects(region.buffer(3)) for o in boxes if o[:4] != (x0, y0, x1, y1)):
            continue
        for i in range(len(names)):
            if not geoms[i].contains(box.buffer(1)):
                continue
            for j in range(len(names)):
                if j != i and valid[j].contains(region):
                    take = region.intersection(geoms[i])
                    moved = list(geoms)
                    moved[i], moved[j] = geoms[i].difference(take), geoms[j].union(take)
                    return moved, names[i], names[j], line.intersection(box).length
    raise AssertionError("no building inside one frame's polygon whose neighbour covers it")


def _mosaic(root, edited, caplog):
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        r = CliRunner().invoke(main, ["mosaic", str(root), "--tile-px", str(TILE_PX), "--seamlines", str(edited)])
    assert r.exit_code == 0, r.output
    warnings = [rec.getMessage() for rec in caplog.records if rec.levelno >= logging.WARNING]
    return json.loads((root / "ortho" / "mosaic.json").read_text()), warnings


def test_an_edge_moved_through_a_building_is_reported_with_its_length(mosaicked, tmp_path, caplog):
    src, boxes = mosaicked
    root = tmp_path / "p"
    shutil.copytree(src, root)
    meta, names, geoms = _polygons(root / "ortho" / "seamlines.gpkg")
    seam_cell_m = json.loads((root / "ortho" / "mosaic.json").read_text())["seam_factor"] * 0.2
    moved, a, b, truth_m = _through_a_building(root, names, geoms, boxes)
    edited = tmp_path / "edited.gpkg"
    _write(edited, names, moved, meta["crs"])
    summary, warnings = _mosaic(root, edited, caplog)
    sc = summary["seam_crossings"]
    assert sc["checked"] and sc["chm"] is None and sc["seam_cell_m"] == pytest.approx(seam_cell_m)
    # the warning names the two frames (their features in the edited file) and the crossing's place
    said = [w for w in warnings if w.startswith("edited seam between")]
    fa, fb = names.index(a) + 1, names.index(b) + 1  # the file's feature ids (1-based, in order)
    assert len(said) == 1 and {f"{a} (feature {fa})", f"{b} (feature {fb})"} <= set(
        s.strip() for s in said[0].replace(" and ", ",").split("frames")[1].split(" crosses")[0].split(","))
    pair = next(p for p in sc["pairs"] if {p["frame_a"], p["frame_b"]} == {a, b})
    # the crossing's length against the drawn line over the building (its box), within a seam cell; the automatic
    # seams do not cross it (they go round buildings)
    assert abs(pair["building_m"] - truth_m) < seam_cell_m, (pair, truth_m)
    assert abs(pair["new_m"] - truth_m) < seam_cell_m and pair["automatic_building_m"] == 0
    assert sc["new_crossings"] == 1 and sc["pairs_with_new_crossings"] == 1
    x, y = pair["longest_new"]["x_m"], pair["longest_new"]["y_m"]
    assert any(x0 <= x <= x1 and y0 <= y <= y1 for x0, y0, x1, y1, _ in boxes)
    # the GeoPackage: one line over the building, CRS set, new
    info = pyogrio.read_info(root / "ortho" / "seam_crossings.gpkg")
    assert info["layer_name"] == "seam_crossings" and info["crs"] == "EPSG:32649"
    cmeta, _, cwkb, cfields = pyogrio.raw.read(root / "ortho" / "seam_crossings.gpkg", return_fids=True)
    f = dict(zip(cmeta["fields"], cfields))
    assert list(f["new"]) == [1] and list(f["kind"]) == ["raised"] and {f["frame_a"][0], f["frame_b"][0]} == {a, b}
    assert abs(shapely.from_wkb(cwkb[0]).length - truth_m) < seam_cell_m
    # never changes the edited seams: seams.tif is the edited polygons rasterised
    with rasterio.open(root / "ortho" / "seams.tif") as ds:
        got, t, shape = ds.read(1), ds.transform, ds.shape
    want = features.rasterize(((g, names.index(n)) for n, g in zip(names, moved)), out_shape=shape, transform=t,
                              fill=-1, dtype="int32")
    assert np.array_equal(got, want)

    # with a CHM beside the nDSM (the LiDAR's vegetation above the DEM) saying the box is a crown: a tree crossing
    with rasterio.open(root / "lidar_out" / "ndsm.tif") as ds:
        profile, nd = ds.profile, ds.read(1)
    with rasterio.open(root / "lidar_out" / "chm.tif", "w", **profile) as dst:
        dst.write(np.where(nd > 0.5, nd, 0).astype(profile["dtype"]), 1)
    summary, warnings = _mosaic(root, edited, caplog)
    pair = next(p for p in summary["seam_crossings"]["pairs"] if {p["frame_a"], p["frame_b"]} == {a, b})
    assert abs(pair["tree_m"] - truth_m) < seam_cell_m and pair["building_m"] == 0
    assert pair["longest_new"]["kind"] == "tree" and any("trees" in w for w in warnings)


def test_the_unedited_copy_has_nothing_new_and_without_an_ndsm_the_check_is_not_made(mosaicked, tmp_path, caplog):
    src, _ = mosaicked
    root = tmp_path / "p"
    shutil.copytree(src, root)
    same = tmp_path / "same.gpkg"
    shutil.copy(root / "ortho" / "seamlines.gpkg", same)
    before = (root / "ortho" / "mosaic.tif").read_bytes()
    summary, warnings = _mosaic(root, same, caplog)
    sc = summary["seam_crossings"]
    assert sc["checked"] and sc["new_crossings"] == 0 and sc["warnings"] == [] and sc["pairs"]
    assert not [w for w in warnings if "edited seam" in w and "change no cell" not in w]
    assert any("change no cell" in w for w in warnings)   # given back unedited: said (trial-ortho2)
    for p in sc["pairs"]:  # the same seams: the same figures as the automatic ones
        assert p["seam_m"] == p["automatic_seam_m"] and p["building_m"] == p["automatic_building_m"]
    assert summary["tiles"]["blended"] == 0 and (root / "ortho" / "mosaic.tif").read_bytes() == before
    assert (root / "ortho" / "seam_crossings.gpkg").is_file()
    # a CHM beside the nDSM that cannot be read: one line naming it, exit 2, nothing written
    (root / "lidar_out" / "chm.tif").write_bytes(b"not a raster")
    stamp = (root / "ortho" / "mosaic.json").stat().st_mtime_ns
    r = CliRunner().invoke(main, ["mosaic", str(root), "--tile-px", str(TILE_PX), "--seamlines", str(same)])
    assert r.exit_code == 2 and "chm.tif: cannot read the CHM" in r.output and "Traceback" not in r.output, r.output
    assert (root / "ortho" / "mosaic.json").stat().st_mtime_ns == stamp
    (root / "lidar_out" / "chm.tif").unlink()
    # no nDSM: said, in the log and mosaic.json; no crossings file (the earlier one removed with the commit)
    (root / "lidar_out" / "ndsm.tif").unlink()
    summary, warnings = _mosaic(root, same, caplog)
    assert summary["seam_crossings"]["checked"] is False and "not checked" in summary["seam_crossings"]["why"]
    assert any("not checked" in w for w in warnings)
    assert not (root / "ortho" / "seam_crossings.gpkg").exists()
