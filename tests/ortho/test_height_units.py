"""Height rasters in another vertical unit (new-user trial 2026-11-30, ortho operator): each of the DEM and the
true ortho's DSM is read through the operation of its own vertical CRS. A DSM in feet beside a DEM in metres was
read in feet (the DEM's operation, none, applied to every height raster: the NGI frames' true orthos 26 DN off on
average, half their pixels masked as occluded), and a DEM in feet gave the default pixel size from heights in feet
(the NGI block 5 m for 6 m; this block refused: "projection centres are below the DEM")."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from ortho.cli import main
from tests.shared_builds import write_synthetic_project

FOOT_M = 0.3048
METRES = 'UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Gravity-related height",UP],AUTHORITY["EPSG","3855"]'
FEET = 'UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]],AXIS["Gravity-related height",UP]'


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _compound_wkt(feet: bool) -> str:
    """UTM 49N + EGM2008 height, in metres or in international feet (the same vertical datum)."""
    wkt = rasterio.crs.CRS.from_user_input("EPSG:32649+3855").to_wkt()
    assert METRES in wkt
    return wkt.replace(METRES, FEET) if feet else wkt


def _write_heights(src, dst, feet: bool):
    with rasterio.open(src) as ds:
        a, prof = ds.read(1).astype(np.float32), ds.profile
    prof.update(crs=rasterio.crs.CRS.from_wkt(_compound_wkt(feet)), dtype="float32", nodata=np.nan)
    with rasterio.open(dst, "w", **prof) as out:
        out.write((a / FOOT_M).astype(np.float32) if feet else a, 1)


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """The 4-frame synthetic block in EGM2008 heights, its truth DEM and DSM in metres and in feet."""
    root = tmp_path_factory.mktemp("height_units") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=6, seed=5)
    toml = root / "project.toml"
    text = toml.read_text()
    assert "heights" not in text and 'crs = "EPSG:32649"\n' in text
    toml.write_text(text.replace('crs = "EPSG:32649"\n', 'crs = "EPSG:32649"\nheights = "EPSG:3855"\n'))
    for what in ("dem", "dsm"):
        for feet in (False, True):
            _write_heights(root / "truth" / f"{what}.tif", root / f"{what}_{'ft' if feet else 'm'}.tif", feet)
    return root


def _rectified(block, tmp_path, name, *args):
    root = tmp_path / name
    shutil.copytree(block, root)
    r = run("rectify", root, *args)
    assert r.exit_code == 0, r.output
    index = json.loads((root / "ortho" / "frames" / "index.json").read_text())
    frames = {}
    for e in index["frames"]:
        with rasterio.open(root / "ortho" / "frames" / e["file"]) as ds:
            frames[e["image_id"]] = (ds.read().astype(np.int32), ds.read_masks(1) > 0, ds.transform)
    return index, frames


def _assert_same_orthos(a, b):
    assert a.keys() == b.keys() and len(a) == 4
    for k in a:
        (pa, ma, ta), (pb, mb, tb) = a[k], b[k]
        assert ta == tb, k
        assert ma.sum() > 0.5 * ma.size
        assert (ma != mb).mean() < 1e-3, k   # the same cells valid (bilinear heights of float32 feet)
        both = ma & mb
        assert np.abs(pa - pb)[:, both].max() <= 1, k


def test_a_true_ortho_dsm_in_feet_beside_a_dem_in_metres_gives_the_metres_dsms_ortho(block, tmp_path):
    """The DSM's heights through its own vertical unit, whatever the DEM's: the true orthos on the DSM in feet are
    those on the same DSM in metres (to 1 DN), with the same cells occluded."""
    common = ("--dem", block / "dem_m.tif", "--true-ortho", "--res-m", "0.2")
    index_m, metres = _rectified(block, tmp_path, "m", *common, "--dsm", block / "dsm_m.tif")
    index_ft, feet = _rectified(block, tmp_path, "ft", *common, "--dsm", block / "dsm_ft.tif")
    _assert_same_orthos(metres, feet)
    assert index_m["height_operation"] is None and index_ft["height_operation"] is None  # the DEM's: none
    assert "dsm_height_operation" not in index_m
    assert index_ft["dsm_height_operation"] is not None   # recorded: the DSM's heights were converted


def test_a_dem_in_feet_gives_the_default_pixel_size_and_orthos_of_the_dem_in_metres(block, tmp_path):
    """The default pixel size (the median nadir GSD) from the DEM's heights in the project's unit: a DEM in feet
    gives the pixel size and orthos of the same DEM in metres."""
    index_m, metres = _rectified(block, tmp_path, "m", "--dem", block / "dem_m.tif")
    index_ft, feet = _rectified(block, tmp_path, "ft", "--dem", block / "dem_ft.tif")
    assert index_m["res_m"] == index_ft["res_m"] == 0.2
    _assert_same_orthos(metres, feet)


def _write_tie_points(root, dz_m: float, n: int = 60):
    """at/object_points.csv as aerotri adjust writes it: n tie points of 2 rays on the truth DEM raised by dz_m."""
    with rasterio.open(root / "truth" / "dem.tif") as ds:
        b = ds.bounds
        rng = np.random.default_rng(3)
        x = rng.uniform(b.left + 60, b.right - 60, n)
        y = rng.uniform(b.bottom + 60, b.top - 60, n)
        z = np.array([v[0] for v in ds.sample(zip(x, y))], float) + dz_m
    lines = ["id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px"]
    lines += [f"T{i:07d},tie,{x[i]:.4f},{y[i]:.4f},{z[i]:.4f},0.05,0.05,0.08,2,0.1" for i in range(n)]
    (root / "at" / "object_points.csv").write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("dz_m", [0.0, -3.0])
def test_rectify_warns_when_the_blocks_tie_points_lie_off_its_dem(block, tmp_path, dz_m):
    """The adjusted tie points 3 m below the DEM the orthos are rectified on (Brighton Beach's GNSS-only block on
    its ODM DEM: -3.56 m, the orthos 1-2 m off): a warning giving the offset and the displacement at the frames'
    corners, naming `aerotri adjust --dem`; none when they lie on it."""
    root = tmp_path / "p"
    shutil.copytree(block, root)
    _write_tie_points(root, dz_m)
    r = CliRunner().invoke(main, ["rectify", str(root), "--dem", str(root / "dem_m.tif"), "--frames", "s01_001"])
    assert r.exit_code == 0, r.output
    if dz_m == 0.0:
        assert "tie points" not in r.stderr, r.stderr
    else:
        assert "lie 3.00 m below the DEM" in r.stderr and "--dem" in r.stderr, r.stderr
        # the corner's displacement: 3 m x the tangent of the corner's view angle (600 x 400 px, f 24 mm, 12 um)
        corner = np.hypot(300, 200) * 12e-3 / 24.0
        assert f"up to {3.0 * corner:.2f} m" in r.stderr, r.stderr


def test_tie_points_above_the_dem_are_not_warned_of_but_above_the_dsm_they_are(block, tmp_path):
    """Above a DEM tie points may stand on roofs and crowns (a forest's all of them): no warning for a conventional
    ortho; the true ortho's DSM is the surface they lie on: 3 m above it is warned of."""
    root = tmp_path / "p"
    shutil.copytree(block, root)
    _write_tie_points(root, 3.0)
    r = CliRunner().invoke(main, ["rectify", str(root), "--dem", str(root / "dem_m.tif"), "--frames", "s01_001"])
    assert r.exit_code == 0, r.output
    assert "tie points" not in r.stderr, r.stderr
    r = CliRunner().invoke(main, ["rectify", str(root), "--dem", str(root / "dem_m.tif"), "--true-ortho",
                                  "--dsm", str(root / "dem_m.tif"), "--frames", "s01_001"])
    assert r.exit_code == 0, r.output
    assert "lie 3.00 m above the DSM" in r.stderr, r.stderr



def _trees(block, tmp_path):
    """The block's truth DSM with 12 trees on open ground (flat crowns 12 m over the ground, radius 4 m) in metres
    and in feet, and the crowns' disks (base 5 m over the ground: the lines of sight beneath them reach the ground)
    in metres and in feet (lidarctl rasters writes them in the clouds' height unit, the DSM's)."""
    import shapely

    from aerotri.core.project import Project
    from aerotri.core.vector_files import VectorLayer, write_layers

    with rasterio.open(block / "truth" / "dsm.tif") as ds:
        dsm, prof = ds.read(1).astype(np.float64), ds.profile
    with rasterio.open(block / "truth" / "dem.tif") as ds:
        dem = ds.read(1).astype(np.float64)
    tf, radius_m = prof["transform"], 4.0
    rows, cols = np.mgrid[0:dsm.shape[0], 0:dsm.shape[1]]
    X, Y = tf * (cols + 0.5, rows + 0.5)
    fields = {k: [] for k in ("x_m", "y_m", "radius_m", "top_m", "base_m")}
    for r in np.linspace(0.25, 0.75, 3) * dsm.shape[0]:
        for c in np.linspace(0.2, 0.8, 4) * dsm.shape[1]:
            x, y = tf * (c, r)
            near = np.hypot(X - x, Y - y)
            if (dsm - dem)[near < 3 * radius_m].max() > 0.5:   # on open ground only
                continue
            canopy = near < radius_m
            top = dem[canopy].max() + 12.0
            dsm[canopy] = top
            for k, v in zip(fields, (x, y, radius_m, top + 0.05, dem[canopy].min() + 5.0)):
                fields[k].append(v)
    fields = {k: np.array(v) for k, v in fields.items()}
    assert len(fields["x_m"]) >= 8
    disks = [shapely.Point(x, y).buffer(radius_m) for x, y in zip(fields["x_m"], fields["y_m"])]
    for feet in (False, True):
        unit = "ft" if feet else "m"
        prof.update(crs=rasterio.crs.CRS.from_wkt(_compound_wkt(feet)), dtype="float32", nodata=np.nan)
        with rasterio.open(tmp_path / f"dsm_trees_{unit}.tif", "w", **prof) as out:
            out.write((dsm / FOOT_M if feet else dsm).astype(np.float32), 1)
        heights = {k: fields[k] / FOOT_M if feet else fields[k] for k in ("top_m", "base_m")}
        write_layers(tmp_path / f"crowns_{unit}.gpkg", [VectorLayer("crowns", "Polygon", disks, {**fields, **heights})],
                     crs=Project.open(block).crs)


def test_crowns_beside_a_dsm_in_feet_occlude_as_beside_the_dsm_in_metres(block, tmp_path):
    """``--crowns`` with a DSM in feet (the crowns' heights in feet too, as lidarctl rasters writes them beside it):
    the crowns' heights go through the occlusion DSM's own height operation, so the true orthos are those of the
    DSM and crowns in metres (to 1 DN, the same cells valid). Before (review of b59af49) the crowns' feet were
    compared with the DSM's metres: every crown base (~1,000 "m") above its top, the crowns dropped without a word."""
    _trees(block, tmp_path)
    common = ("--dem", block / "dem_m.tif", "--true-ortho", "--res-m", "0.4")
    _, plain = _rectified(block, tmp_path, "plain", *common, "--dsm", tmp_path / "dsm_trees_m.tif")
    _, metres = _rectified(block, tmp_path, "m", *common, "--dsm", tmp_path / "dsm_trees_m.tif",
                           "--crowns", tmp_path / "crowns_m.gpkg")
    index_ft, feet = _rectified(block, tmp_path, "ft", *common, "--dsm", tmp_path / "dsm_trees_ft.tif",
                                "--crowns", tmp_path / "crowns_ft.gpkg")
    assert index_ft["dsm_height_operation"] is not None
    # the crowns let through the lines of sight beside their disks in the cells at their rims (55 pixels here)
    gained = sum(int((metres[k][1] & ~plain[k][1]).sum()) for k in plain)
    assert gained >= 40, gained
    _assert_same_orthos(metres, feet)
    differ = sum(int((metres[k][1] != feet[k][1]).sum()) for k in plain)
    assert differ <= gained // 5, (differ, gained)   # the crowns in feet occluded as those in metres (was: none)


def test_a_feet_projects_egm2008_heights_are_in_feet_for_the_dem():
    """[project] heights = "EPSG:3855" beside a US-feet grid: project heights are EGM2008 in US feet (docs/project.md:
    z in the project CRS's unit). A DEM declaring EPSG:3855 (metres) is converted to feet (review 43: taken as the
    project's, its metres read as feet), one declaring EGM2008 in US feet is taken as it is (was divided by 3.28)."""
    import pyproj

    from aerotri.geom.crs.definition import heights_in_unit
    from ortho.dem import dem_height_operation

    us_ft_m = 1200 / 3937
    grid = pyproj.CRS("+proj=utm +zone=49 +datum=WGS84 +units=us-ft +no_defs")
    egm2008 = pyproj.CRS("EPSG:3855")
    in_metres = pyproj.crs.CompoundCRS("UTM 49N US ft + EGM2008 height", [grid, egm2008])
    in_feet = pyproj.crs.CompoundCRS("UTM 49N US ft + EGM2008 height (ftUS)", [grid, heights_in_unit(egm2008, us_ft_m)])
    x, y = 1484747.6, 11179048.4  # the demo block's
    op = dem_height_operation(in_metres, grid, egm2008)
    assert op is not None and abs(op.transform(x, y, 100.0)[2] - 100.0 / us_ft_m) < 1e-6
    same = dem_height_operation(in_feet, grid, egm2008)
    assert same is None or abs(same.transform(x, y, 100.0)[2] - 100.0) < 1e-9
