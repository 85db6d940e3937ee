"""LiDAR surface control: tie points on the ground observe the DEM height, against a block's known truth."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.adjust.surface import HeightGrid
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SIGMA_PX = 0.3
CELL_M = 2.0


def _terrain_dem(block, path, objects_m=None, seed=0):
    """The block's terrain as a GeoTIFF in the project CRS (heights as the project's); with ``objects_m`` the DEM
    lies up to that many metres lower in random patches (about a fifth of the area), so that the tie points there
    stand above it as on trees and roofs."""
    xmin, xmax, ymin, ymax = block.extent_local
    corners = block.frame.to_map(np.array([[xmin, ymin, 0], [xmax, ymax, 0]]))
    x0, y1 = corners[0, 0] - 200, corners[1, 1] + 200
    W = int((corners[1, 0] + 200 - x0) / CELL_M)
    H = int((y1 - (corners[0, 1] - 200)) / CELL_M)
    xs = x0 + (np.arange(W) + 0.5) * CELL_M
    ys = y1 - (np.arange(H) + 0.5) * CELL_M
    X, Y = np.meshgrid(xs, ys)
    h = np.zeros_like(X)
    for _ in range(4):  # the map height whose local point lies on the terrain
        p = block.frame.to_local(np.column_stack([X.ravel(), Y.ravel(), h.ravel()]))
        h = h + (block.terrain(p[:, 0], p[:, 1]) - p[:, 2]).reshape(h.shape)
    if objects_m:
        rng = np.random.default_rng(seed)
        # 40 m patches, about a fifth of the area, DEM 3-15 m below the points (trees, roofs)
        patch = rng.random((H // 20 + 1, W // 20 + 1)) < 0.2
        depth = np.where(patch, rng.uniform(3, objects_m, size=patch.shape), 0.0)
        h = h - np.kron(depth, np.ones((20, 20)))[:H, :W]
    with rasterio.open(path, "w", driver="GTiff", width=W, height=H, count=1, dtype="float32", crs=block.crs,
                       transform=from_origin(x0, y1, CELL_M, CELL_M), nodata=-9999.0) as ds:
        ds.write(h.astype(np.float32), 1)
    return path


@pytest.fixture(scope="module")
def surface_block(tmp_path_factory):
    # GNSS with height shifts per strip (0.5 m sigma; plan unbiased) and no control points at all
    block = geometric_block(3, 6, seed=5, gnss_shift_sigma_m=0.5, gnss_drift_sigma_m_per_km=0.0)
    block.gnss_local[:, :2] -= block.gnss_shift_m[block.strip, :2]
    block.gnss_shift_m[:, :2] = 0.0
    root = write_block_project(block, tmp_path_factory.mktemp("surf") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=0, points_per_image=150, n_check=12, seed=6)
    dem = _terrain_dem(block, root / "dem.tif")
    trees = _terrain_dem(block, root / "dem_trees.tif", objects_m=15.0, seed=7)
    return block, root, dem, trees


def _check_rms(ba):
    d = np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for c in ba.check.values()])
    return float(np.sqrt(np.mean(d[:, :2] ** 2))), float(np.sqrt(np.mean(d[:, 2] ** 2))), float(np.mean(d[:, 2]))


def test_height_grid_samples_heights_and_slopes():
    x, y = np.meshgrid(np.arange(50) * 2.0 + 1.0, 100.0 - (np.arange(40) * 2.0 + 1.0))
    g = HeightGrid(0.3 * x - 0.1 * y + 5.0, 0.0, 100.0, 2.0)  # a plane
    h, hx, hy = g.sample(np.array([10.3, 55.5, 200.0]), np.array([60.2, 33.3, 50.0]))
    assert np.allclose(h[:2], 0.3 * np.array([10.3, 55.5]) - 0.1 * np.array([60.2, 33.3]) + 5.0)
    assert np.allclose(hx[:2], 0.3) and np.allclose(hy[:2], -0.1)
    assert np.isnan(h[2])  # outside


def test_the_dem_fixes_the_heights_gnss_strip_shifts_cannot(surface_block):
    block, root, dem, _ = surface_block
    gsd = block.camera_true.gsd_m(block.flying_height_m)
    base = AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, point_covariances=False)
    import dataclasses

    without = adjust_project(root, base)
    with_dem = adjust_project(root, dataclasses.replace(base, dem=dem, surface_sigma_m=0.05))
    xy0, z0, _ = _check_rms(without)
    xy1, z1, bias1 = _check_rms(with_dem)
    sc = with_dem.result.surface
    assert sc.used > 0.9 * sc.candidates > 400 and sc.rms_m < 0.1
    # height errors of the GNSS per strip (-0.47, -0.31, 0.02 m) go into the block without control (check
    # points 0.35 m RMS in height, 0.15 m mean); the DEM observes the heights. What is left is the check
    # points' own intersection precision (a few points seen from the block edge at 0.3 to 0.4 m)
    assert z1 < 0.5 * z0 and abs(bias1) < 0.05 and xy1 < xy0, (xy0, z0, xy1, z1, bias1)
    assert z1 < 2 * gsd


def test_points_on_trees_and_roofs_do_not_bias_the_heights(surface_block):
    block, root, dem, trees = surface_block
    import dataclasses

    base = AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, point_covariances=False, surface_sigma_m=0.05)
    clean = adjust_project(root, dataclasses.replace(base, dem=dem))
    dirty = adjust_project(root, dataclasses.replace(base, dem=trees))
    sc = dirty.result.surface
    assert 0.1 < sc.rejected / sc.candidates < 0.35  # about the fifth of the area under "objects"
    # the used ones lie on the DEM within their sigmas (points at the edge of an "object" keep a large
    # sigma from the DEM's slope there, so their metres say little)
    assert abs(sc.median_m) < 0.05 and sc.rms_normalised < 1.5, sc
    _, z_clean, _ = _check_rms(clean)
    _, z_dirty, bias = _check_rms(dirty)
    assert z_dirty < z_clean + 0.05 and abs(bias) < 0.05, (z_clean, z_dirty, bias)


def test_a_dem_in_another_crs_is_refused(surface_block, tmp_path):
    from aerotri.core.errors import CrsError

    _, root, dem, _ = surface_block
    other = tmp_path / "dem_utm50.tif"
    with rasterio.open(dem) as src:
        prof, a = src.profile, src.read(1)
    prof["crs"] = "EPSG:32650"
    with rasterio.open(other, "w", **prof) as dst:
        dst.write(a, 1)
    with pytest.raises(CrsError, match="dem_utm50.tif"):
        adjust_project(root, AdjustSettings(dem=other))


def test_the_report_has_a_surface_control_section(surface_block, tmp_path):
    import json
    import shutil

    from aerotri.adjust.pipeline import write_outputs

    _, root, dem, trees = surface_block
    p = tmp_path / "p"
    shutil.copytree(root, p)
    ba = adjust_project(p, AdjustSettings(dem=trees, surface_sigma_m=0.05, point_covariances=False))
    write_outputs(ba, p)
    rep = json.loads((p / "at" / "report.json").read_text())
    sc = rep["surface_control"]
    assert sc["used"] == ba.result.surface.used and sc["rejected"] == ba.result.surface.rejected > 0
    # no lidar_out/dem.tif and no [flight] mean terrain height: the footprints stand on the DEM given
    assert rep["flight_acceptance"]["terrain"] == str(trees)  # outside the project: named in full
    assert sc["dem"].endswith("dem_trees.tif") and sc["sigma_m"] == 0.05
    assert "SURFACE CONTROL" in (p / "at" / "report.txt").read_text()
    assert "<h2>Surface control</h2>" in (p / "at" / "report.html").read_text()


# ---------------------------------------------------------------------------------------------- roof planes
SQUARE_M, FACE_M = 60.0, 50.0  # "roofs": 50 m faces on a 60 m grid over the block, planes tangent to the terrain


def _plane_faces(block, offset_m=None, seed=11):
    """Faces as roof_planes.geojson holds them (``lidarctl.corners.roof_corners._faces_in_crs_units``' keys, metric CRS):
    each a 50 m square of the block's terrain with the least-squares plane of 400 terrain points in map
    coordinates, its covariance (point noise 2 cm) and rms. ``offset_m``: {face index: metres} added to c."""
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = block.extent_local
    faces = []
    for cx in np.arange(xmin + SQUARE_M / 2, xmax - SQUARE_M / 2, SQUARE_M):
        for cy in np.arange(ymin + SQUARE_M / 2, ymax - SQUARE_M / 2, SQUARE_M):
            u = rng.uniform(-FACE_M / 2, FACE_M / 2, (400, 2)) + [cx, cy]
            m = block.frame.to_map(np.column_stack([u, block.terrain(u[:, 0], u[:, 1])]))
            m[:, 2] += rng.normal(0, 0.02, len(m))
            x0, y0 = m[:, :2].mean(axis=0)
            A = np.column_stack([m[:, 0] - x0, m[:, 1] - y0, np.ones(len(m))])
            abc, *_ = np.linalg.lstsq(A, m[:, 2], rcond=None)
            v = A @ abc - m[:, 2]
            s0 = float(np.sqrt(v @ v / (len(m) - 3)))
            sq = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]) * FACE_M / 2 + [cx, cy]
            ring = block.frame.to_map(np.column_stack([sq, np.zeros(5)]))[:, :2]
            faces.append(dict(building_id=len(faces), rings=[ring], centre_local=(cx, cy), x0=x0, y0=y0, a=abc[0], b=abc[1], c=abc[2],
                              cov_abc_m=s0**2 * np.linalg.inv(A.T @ A), rms_m=s0, n_points=len(m),
                              slope_deg=float(np.degrees(np.arctan(np.hypot(*abc[:2])))), margin_m=0.0,
                              area_m2=FACE_M**2))
    for k, dz in (offset_m or {}).items():
        faces[k]["c"] += dz
    return faces


def _write_planes(folder, faces, crs):
    from lidarctl.corners.roof_corners import roof_planes_geojson

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "roof_planes.geojson").write_text(roof_planes_geojson(faces, None, sigma_strip_xy_m=0.03,
                                                                    sigma_strip_z_m=0.03, crs=crs))
    return folder


def _constant_raster(like, path, value):
    with rasterio.open(like) as src:
        prof, a = src.profile, src.read(1)
    with rasterio.open(path, "w", **prof) as dst:
        dst.write(np.full_like(a, value), 1)
    return path


@pytest.fixture(scope="module")
def roof_block(surface_block, tmp_path_factory):
    """The surface block with roof planes over it, an nDSM that puts every point on an object (so only the
    planes hold heights), and the same planes with two faces 2 m too high."""
    import pyproj

    block, root, dem, _ = surface_block
    d = tmp_path_factory.mktemp("roofs")
    crs = pyproj.CRS(block.crs)
    good = _write_planes(d / "good", _plane_faces(block), crs)
    # every 7th face 2 m too high (a 50 m face holds a tie point or two of this sparse block)
    off = list(range(3, len(_plane_faces(block)), 7))
    wrong_faces = _plane_faces(block, offset_m={k: 2.0 for k in off})
    wrong = _write_planes(d / "wrong", wrong_faces, crs)
    ndsm = _constant_raster(dem, d / "ndsm_objects.tif", 10.0)
    return block, root, dem, ndsm, good, wrong, [wrong_faces[k]["rings"][0] for k in off]


def test_tie_points_on_roofs_observe_the_planes_and_fix_the_heights(roof_block):
    import dataclasses

    block, root, dem, ndsm, good, _, _ = roof_block
    base = AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, point_covariances=False, surface_sigma_m=0.05)
    _, z0, _ = _check_rms(adjust_project(root, base))
    ba_dem = adjust_project(root, dataclasses.replace(base, dem=dem))
    ba = adjust_project(root, dataclasses.replace(base, dem=dem, ndsm=ndsm, planes=good))
    sc = ba.result.surface
    ground, roofs = sc.classes["ground (DEM)"], sc.classes["roof planes"]
    # the nDSM leaves no point on the ground: every height observation is a roof plane's
    assert ground["candidates"] == 0 and sc.n_planes == len(_plane_faces(block))
    assert roofs["used"] > 0.9 * roofs["candidates"] > 300, roofs
    # the planes' residuals: distances from tangent planes of smooth hills (a few cm)
    assert abs(roofs["median_m"]) < 0.02 and roofs["rms_m"] < 0.06 and roofs["rms_normalised"] < 2.0, roofs
    _, z_dem, _ = _check_rms(ba_dem)
    _, z_planes, bias = _check_rms(ba)
    assert z_planes < 0.5 * z0 and abs(bias) < 0.05, (z0, z_dem, z_planes, bias)
    assert z_planes < z_dem + 0.05, (z_dem, z_planes)


def test_a_roof_plane_2_m_off_is_gated(roof_block):
    import dataclasses

    import shapely

    block, root, dem, ndsm, good, wrong, wrong_rings = roof_block
    base = AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, point_covariances=False, surface_sigma_m=0.05,
                          dem=dem, ndsm=ndsm)
    ok = adjust_project(root, dataclasses.replace(base, planes=good))
    bad = adjust_project(root, dataclasses.replace(base, planes=wrong))
    # the tie points inside the wrong faces (by their adjusted position) are all rejected by the gate
    P = bad.points_map
    inside = np.zeros(len(P), bool)
    for ring in wrong_rings:
        inside |= shapely.contains_xy(shapely.Polygon(ring), P[:, 0], P[:, 1])
    use = bad.result.surface_use
    assert inside.sum() > 10 and np.all(use[inside] == 2), np.bincount(use[inside])
    roofs_ok, roofs_bad = ok.result.surface.classes["roof planes"], bad.result.surface.classes["roof planes"]
    assert roofs_bad["rejected"] >= roofs_ok["rejected"] + inside.sum() - 2
    _, z_ok, _ = _check_rms(ok)
    _, z_bad, bias = _check_rms(bad)
    assert z_bad < z_ok + 0.03 and abs(bias) < 0.05, (z_ok, z_bad, bias)


def test_aerotri_adjust_refuses_planes_in_another_crs_or_without_a_dem(roof_block, tmp_path):
    import pyproj
    from click.testing import CliRunner

    from aerotri.cli import main

    block, root, dem, _, _, _, _ = roof_block
    other = _write_planes(tmp_path / "utm50", _plane_faces(block)[:3], pyproj.CRS("EPSG:32650"))
    r = CliRunner().invoke(main, ["adjust", str(root), "--dem", str(dem), "--planes", str(other)])
    err = [line for line in r.output.splitlines() if line.startswith("Error: ")]
    assert r.exit_code == 2 and len(err) == 1 and "Traceback" not in r.output, r.output
    assert "utm50/roof_planes.geojson: the roof planes are in EPSG:32650, the project in" in err[0]
    r = CliRunner().invoke(main, ["adjust", str(root), "--planes", str(other)])
    assert r.exit_code == 2 and "--planes" in r.output and "without a DEM" in r.output, r.output


def test_the_report_has_a_surface_control_section_per_class(roof_block, tmp_path):
    import json
    import shutil

    from aerotri.adjust.pipeline import write_outputs

    block, root, dem, _, _, wrong, _ = roof_block
    p = tmp_path / "p"
    shutil.copytree(root, p)
    ba = adjust_project(p, AdjustSettings(dem=dem, planes=wrong, surface_sigma_m=0.05, point_covariances=False))
    write_outputs(ba, p)
    sc = json.loads((p / "at" / "report.json").read_text())["surface_control"]
    st = ba.result.surface
    ground, roofs = sc["classes"]["ground (DEM)"], sc["classes"]["roof planes"]
    assert sc["planes"].endswith("wrong/roof_planes.geojson") and sc["n_planes"] == len(_plane_faces(block))
    assert ground["used"] > 50 and roofs["used"] > 200 and roofs["rejected"] > 10 and ground["rejected"] < 5, sc
    assert ground["candidates"] + roofs["candidates"] == sc["candidates"] == st.candidates
    assert ground["used"] + roofs["used"] == sc["used"] and roofs["rms_m"] == pytest.approx(
        st.classes["roof planes"]["rms_m"], abs=1e-4)
    txt = (p / "at" / "report.txt").read_text()
    row = next(line for line in txt.splitlines() if line.strip().startswith("roof planes ") and "faces" not in line)
    assert row.split()[2:5] == [str(roofs["candidates"]), str(roofs["used"]), str(roofs["rejected"])], row
    assert "distance above the plane along its normal" in txt
    html = (p / "at" / "report.html").read_text()
    assert "<h2>Surface control</h2>" in html


def test_a_point_keeps_its_roof_face_in_a_subset_of_the_points(roof_block):
    """The solve observes the tie points with two rays or more (a subset, ``of_points``): each keeps the face
    ``candidates`` gave it while it moves (a face looked up anew at every trial step made the cost jump and
    the demo's first adjustment fail to converge)."""
    import dataclasses

    from aerotri.adjust.pipeline import prepare_project

    _, root, dem, ndsm, good, _, _ = roof_block
    pb, state = prepare_project(root, AdjustSettings(dem=dem, ndsm=ndsm, planes=good))
    sc = pb.block.surface
    cand = sc.candidates(state.points)
    roof = np.flatnonzero(sc.face >= 0)
    assert cand[roof].all() and len(roof) > 100
    idx = roof[::2]
    sub = sc.of_points(idx)
    # 20 m north: out of their 50 m faces for about 40 % of them; the plane goes on under them
    moved = state.points[idx] + [0.0, 20.0, 0.0]
    e, J, sigma = sub.observe(moved)
    e0, _, _ = sub.observe(state.points[idx])
    pl = sc.planes
    a, b = pl.abc[sc.face[idx], 0], pl.abc[sc.face[idx], 1]
    # distance along the normal changes by the plane's rise over the move (the terrain's slope), for every point
    d = sc.frame.to_map(moved) - sc.frame.to_map(state.points[idx])
    s = np.sqrt(1 + a * a + b * b)
    assert np.allclose(e - e0, (d[:, 2] - a * d[:, 0] - b * d[:, 1]) / s, atol=1e-3)
    assert np.allclose(J[:, 2], 1 / s, atol=1e-3) and np.all(sigma < 0.05)
    # looked up at the moved positions instead, some points would change face or fall to the DEM
    looked_up = dataclasses.replace(sc, face=None).planes.face_of(*sc.frame.to_map(moved)[:, :2].T)
    assert (looked_up != sc.face[idx]).mean() > 0.2


def test_surface_residuals_are_metres_in_a_foot_crs():
    """A project in US survey feet (heights in feet too): the residual, its sigma and Jacobian are metres, the
    nDSM threshold is metres, as in a metric project."""
    from aerotri.adjust.surface import SurfaceControl
    from aerotri.geom.local_frame import LocalFrame

    ft = 1200.0 / 3937.0
    frame = LocalFrame("EPSG:2227", (6_000_000.0, 2_100_000.0, 300.0))
    xs = 6_000_000.0 - 500.0
    g = HeightGrid(np.full((100, 100), 300.0), xs, 2_100_000.0 + 500.0, 10.0)  # flat at 300 ft, 10 ft cells
    nd = HeightGrid(np.full((100, 100), 2.0), xs, 2_100_000.0 + 500.0, 10.0)  # 2 ft = 0.61 m above the ground
    sc = SurfaceControl(g, frame, sigma_m=0.15, ndsm=nd, max_ndsm_m=1.0, map_unit_m=(ft, ft))
    p = frame.to_local(np.array([[6_000_010.0, 2_100_020.0, 310.0]]))  # 10 ft above the DEM
    e, J, sigma = sc.observe(p)
    assert e[0] == pytest.approx(10.0 * ft, rel=1e-6) and sigma[0] == pytest.approx(0.15)
    assert J[0] @ np.array([0.0, 0.0, 1.0]) == pytest.approx(1.0, abs=1e-3)  # a metre up is a metre of residual
    assert sc.candidates(p)[0]  # 0.61 m above the ground: below the 1 m limit


def test_a_dem_larger_than_the_memory_budget_is_read_averaged(tmp_path, monkeypatch):
    """A DEM window of more cells than MAX_GRID_CELLS is read averaged over whole f x f cells (square cells, the
    window's corner kept), float32 as in the file: memory bounded by the budget, not by the DEM."""
    from rasterio.transform import from_origin

    from aerotri.adjust import surface
    from aerotri.geom.crs.definition import parse_crs

    z = (np.arange(300)[:, None] * 0.1 + np.arange(200)[None, :] * 0.05).astype(np.float32)  # a plane
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=200, height=300, count=1, dtype="float32", crs="EPSG:32649",
                       transform=from_origin(420000.0, 3380000.0, 1.0, 1.0), nodata=-9999.0) as ds:
        ds.write(z, 1)
    full = surface.read_height_grid(path, parse_crs("EPSG:32649", "crs"))
    assert full.z.dtype == np.float32 and full.z.shape == (300, 200) and full.res == 1.0
    monkeypatch.setattr(surface, "MAX_GRID_CELLS", 10_000)
    coarse = surface.read_height_grid(path, parse_crs("EPSG:32649", "crs"))
    assert coarse.res == 3.0 and coarse.z.shape == (100, 66)  # f = ceil(sqrt(60000 / 10000)) = 3
    assert (coarse.x0, coarse.y0) == (full.x0, full.y0)
    x, y = 420000.0 + np.array([50.2, 120.7]), 3380000.0 - np.array([80.4, 200.9])
    # a plane averaged is the same plane: the coarse grid samples it as the full one does
    np.testing.assert_allclose(coarse.sample(x, y)[0], full.sample(x, y)[0], atol=1e-4)


def test_a_point_the_last_snooping_left_without_rays_is_no_surface_observation(surface_block):
    """The last snooping round can leave a point the surface gate had made a candidate (and used) without rays: it
    is in no solve since, but report.json counted it (the demo: surface control 16,064 used, the variance
    components' surface group 16,063). ``held_by_rays`` leaves it out of the candidates and the used ones."""
    from aerotri.adjust.solve import held_by_rays

    _, root, dem, _ = surface_block
    ba = adjust_project(root, AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, dem=dem))
    b, r = ba.block, ba.result
    vc = {c.group: c.n for c in r.variance_components}
    assert r.surface.used == vc["surface"] == int(np.sum(r.surface_use == 1))
    # one used point's rays removed after the gate (what a last snooping round does)
    j = int(np.flatnonzero(r.surface_use == 1)[0])
    active = r.obs_active & (b.obs_point != j)
    cand, used = held_by_rays(b, active, r.surface_use > 0, r.surface_use == 1)
    assert not cand[j] and not used[j] and used.sum() == np.sum(r.surface_use == 1) - 1



@pytest.mark.parametrize("grid, dem_heights, expected_z", [
    ("+proj=utm +zone=49 +datum=WGS84 +units=us-ft +no_defs", "EPSG:3855", 1000.0 / 0.3048006096012192),
    ("EPSG:32649", "EPSG:3855", 1000.0),
    ("EPSG:32649", "EPSG:5773", None)])
def test_a_dem_is_taken_only_in_the_projects_heights_and_their_unit(tmp_path, grid, dem_heights, expected_z):
    """[project] heights = "EPSG:3855": beside a US-feet grid the project's heights are EGM2008 in US feet (docs/
    project.md), a DEM declaring EPSG:3855 (metres) is converted to feet (review 43: its metres were read as feet;
    review 48: then refused although ortho converts it); beside UTM in metres it is the project's; a DEM of EGM96
    heights (EPSG:5773) is refused naming both (was taken: the check compared the bare vertical CRS as a compound
    one, "same" whatever it was)."""
    import pyproj

    from aerotri.adjust import surface
    from aerotri.core.errors import CrsError
    from aerotri.geom.crs.definition import parse_crs

    grid = parse_crs(grid, "crs")
    egm2008 = pyproj.CRS("EPSG:3855")
    dem_crs = pyproj.crs.CompoundCRS("dem", [grid, pyproj.CRS(dem_heights)])
    x, y = pyproj.Transformer.from_crs("EPSG:32649", grid, always_xy=True).transform(452555.0, 3407828.0)
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=20, height=30, count=1, dtype="float32",
                       crs=rasterio.crs.CRS.from_wkt(dem_crs.to_wkt()), transform=from_origin(x, y, 3.0, 3.0),
                       nodata=-9999.0) as ds:
        ds.write(np.full((30, 20), 1000.0, np.float32), 1)
    if expected_z is not None:
        z = surface.read_height_grid(path, grid, egm2008).z
        assert np.allclose(z, expected_z, rtol=1e-6)
    else:
        with pytest.raises(CrsError, match=r"heights are in EGM96 height \(EPSG:5773\), the project's in EGM2008 "
                                           r"height \(EPSG:3855\) \(\[project\] heights\): give a DEM"):
            surface.read_height_grid(path, grid, egm2008)


def test_a_dem_that_does_not_reach_the_block_is_refused_naming_both_extents(tmp_path):
    """New-user trial s51: NGI's DEM moved 200 km east (or gnss.txt in degrees) stopped `aerotri adjust --dem` with
    rasterio's "WindowError: Intersection is empty" traceback, exit 1; now an InputError naming the DEM's extent."""
    from aerotri.adjust import surface
    from aerotri.core.errors import InputError
    from aerotri.geom.crs.definition import parse_crs

    path = tmp_path / "far.tif"
    with rasterio.open(path, "w", driver="GTiff", width=20, height=30, count=1, dtype="float32", crs="EPSG:32649",
                       transform=from_origin(620000.0, 3380000.0, 10.0, 10.0)) as ds:
        ds.write(np.zeros((30, 20), np.float32), 1)
    with pytest.raises(InputError, match=r"far\.tif: the DEM does not reach the block: it covers x 620000\.0 \.\. "
                                         r"620200\.0, y 3379700\.0 \.\. 3380000\.0"):
        surface.read_height_grid(path, parse_crs("EPSG:32649", "crs"), bounds=(420000.0, 3370000.0, 421000.0,
                                                                                  3371000.0))


def test_points_off_the_dem_are_counted():
    """trial-relief F6: a DEM over 63 % of the tie points made the solve fail with a message about the
    self-calibration and the GNSS; ``off_dem`` counts the points outside it or on its nodata, and the solve warns
    beyond ``OFF_DEM_SHARE`` of the block's points."""
    from aerotri.adjust.solve import OFF_DEM_SHARE
    from aerotri.adjust.surface import SurfaceControl
    from aerotri.geom.local_frame import LocalFrame

    frame = LocalFrame("EPSG:32631", (500_000.0, 5_700_000.0, 50.0))
    z = np.full((50, 100), 50.0)
    z[:, 80:] = np.nan  # nodata over the grid's east fifth
    sc = SurfaceControl(HeightGrid(z, 499_900.0, 5_700_050.0, 2.0), frame)  # 200 x 100 m, 2 m cells
    xy = np.array([[499_950.0, 5_700_000.0], [500_000.0, 5_700_000.0], [500_080.0, 5_700_000.0],  # on, on, nodata
                   [500_500.0, 5_700_000.0]])  # beyond the grid
    p = frame.to_local(np.column_stack([xy, np.full(4, 50.0)]))
    assert sc.off_dem(p).tolist() == [False, False, True, True]
    assert 0.05 <= OFF_DEM_SHARE <= 0.5


def test_the_strip_checks_offsets_size_the_surface_bias(tmp_path):
    """trial-density F0: strips 0.6 m apart in height by the chain's strip check, the orientations' sigmas computed
    for 0.03 m strip offsets (8-10 times too small, "Solution Successful"). ``measured_strip_sigma``: one strip's
    offset sigma from the pairs' mean differences (the check after the strip adjustment first)."""
    import json

    from aerotri.adjust.pipeline import MEASURED_STRIP_FACTOR, measured_strip_sigma
    from aerotri.core.project import Project

    root = tmp_path / "p"
    (root / "lidar_out" / "strips").mkdir(parents=True)
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32649"\n')
    project = Project.open(root)
    assert measured_strip_sigma(project) is None
    pairs = [{"a": "s1", "b": "s2", "n_cells": 9409, "mean_m": 0.599}, {"a": "s2", "b": "s3", "n_cells": 6090,
                                                                        "mean_m": -0.452},
             {"a": "s1", "b": "s3", "n_cells": 0, "mean_m": None}]
    project.strips_check_path.write_text(json.dumps({"pairs": pairs}))
    sigma, source, rms = measured_strip_sigma(project)
    assert rms == pytest.approx(np.sqrt((0.599**2 + 0.452**2) / 2)) and sigma == pytest.approx(rms / np.sqrt(2))
    assert source == "lidar_out/strips/strips.json" and sigma > MEASURED_STRIP_FACTOR * 0.03
    # after a strip adjustment its check is the one that counts
    project.strips_check_after_path.parent.mkdir(parents=True)
    project.strips_adjust_path.write_text("{}")
    project.strips_check_after_path.write_text(json.dumps({"pairs": [{"n_cells": 10, "mean_m": 0.02}]}))
    assert measured_strip_sigma(project)[0] == pytest.approx(0.02 / np.sqrt(2))
    project.strips_check_after_path.write_text("{not json")
    assert measured_strip_sigma(project) is None
