"""The truth simulator: geometry, LiDAR structure, determinism and refusal of bad parameters."""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import tomllib

import cv2
import laspy
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from shapely.geometry import Point

from aerotri.geom.camera import BrownCamera
from aerotri.cli import main as aerotri_main
from aerotri.geom.eo import read_eo, read_gnss
from aerotri.sim import load_preset, simulate
from aerotri.sim import raycast, render
from aerotri.sim.flight import block_layout
from aerotri.sim.scene import KIND_ROOF, build_scene


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_project_layout_and_truth_summary(tiny_project):
    p = tiny_project
    for rel in ("project.toml", "camera.toml", "gnss.txt", "truth/eo.txt", "truth/camera.toml", "truth/dem.tif",
                "truth/dsm.tif", "truth/ortho.tif", "truth/roof_corners.csv", "truth/checkpoints.csv",
                "truth/checkpoint_image_points.csv", "truth/truth.json"):
        assert (p / rel).is_file(), rel
    truth = json.loads((p / "truth/truth.json").read_text())
    eo = read_eo(p / "truth/eo.txt")
    gnss = read_gnss(p / "gnss.txt")
    assert len(eo) == truth["frames"] == 6 == len(list((p / "images").glob("*.tif")))
    assert gnss.image_id == eo.image_id
    cfg = tomllib.loads((p / "project.toml").read_text())
    assert cfg["project"]["crs"] == "EPSG:32649"
    # Nominal camera has no principal-point offset or distortion; the true one has both.
    nominal = BrownCamera.read(p / "camera.toml")
    true = BrownCamera.read(p / "truth/camera.toml")
    assert nominal.ppx_mm == 0 and nominal.k1 == 0 and true.ppx_mm != 0 and true.k1 != 0
    assert nominal.focal_mm == 120.0 and nominal.sensor_mm[0] == pytest.approx(165.888)
    # Attitudes within the specification: tilt < 2 deg, kappa within 7 deg of the strip direction.
    assert np.abs(eo.opk_deg[:, :2]).max() < 2.0
    kdev = np.abs(np.abs(eo.opk_deg[:, 2]) - 90.0)
    assert kdev.max() < 7.0
    # GNSS: antenna = centre + R lever arm + errors of a few decimetres at most.
    lever = np.array(cfg["gnss"]["lever_arm_m"])
    antenna = eo.centre_m + np.einsum("nij,j->ni", eo.rotations(), lever)
    err = np.linalg.norm(gnss.position_m - antenna, axis=1)
    assert 0.0 < err.max() < 1.0
    # Relief: the valley side reaches at least 30 degrees.
    assert truth["max_slope_deg"] >= 30.0
    # [adjust] states the GNSS correction the injected errors need: the strips' antenna positions drift
    # (truth/gnss_truth.toml), so shift_drift, with the a-priori sigma they were drawn with.
    drifts = np.array([s["drift_m_per_s"] for s in tomllib.loads((p / "truth/gnss_truth.toml").read_text())["strip"]])
    assert np.abs(drifts).max() > 0.0
    assert cfg["adjust"]["gnss_correction"] == "shift_drift" and cfg["adjust"]["gnss_shift_sigma_m"] > 0.0


def test_rendered_project_states_the_gnss_correction_of_its_errors():
    """The full simulator's [adjust] gnss_correction follows the preset's [gnss] errors as the observation-only
    simulator's does; one the preset or --set gives is kept."""
    from aerotri.sim.project import rendered_chain_table

    cfg = load_preset("tiny")
    assert rendered_chain_table(cfg)["adjust"]["gnss_correction"] == "shift_drift"
    cfg = load_preset("tiny", ["gnss.drift_sigma_m_per_s=0.0"])
    assert rendered_chain_table(cfg)["adjust"]["gnss_correction"] == "shift"
    cfg = load_preset("tiny", ["gnss.drift_sigma_m_per_s=0.0", "gnss.strip_shift_sigma_m=0.0"])
    adjust = rendered_chain_table(cfg)["adjust"]
    assert adjust["gnss_correction"] == "none" and "gnss_shift_sigma_m" not in adjust
    cfg = load_preset("demo")
    cfg = dataclasses.replace(cfg, chain={**cfg.chain, "adjust": {**cfg.chain["adjust"], "gnss_correction": "shift"}})
    assert rendered_chain_table(cfg)["adjust"]["gnss_correction"] == "shift"
    assert load_preset("demo").chain["adjust"]["self_calibration"] == ["pp", "radial"]


def test_checkpoint_truth_matches_rendered_targets(tiny_project):
    """Truth image coordinates of check targets agree with their rendered centroids to 0.1 px."""
    p = tiny_project
    rows = _rows(p / "truth/checkpoint_image_points.csv")
    assert len(rows) >= 8
    errors = []
    true = BrownCamera.read(p / "truth/camera.toml")
    gsd = json.loads((p / "truth/truth.json").read_text())["gsd_m"]
    cfg = load_preset("tiny")
    r_px = cfg.scene.target_radius_m / gsd
    for r in rows:
        img = cv2.imread(str(p / "images" / f"{r['image_id']}.tif"), cv2.IMREAD_GRAYSCALE).astype(float)
        x0, y0 = float(r["x_px"]), float(r["y_px"])
        half = int(np.ceil(1.5 * r_px)) + 1
        cx, cy = int(round(x0)), int(round(y0))
        if cx - half < 0 or cy - half < 0 or cx + half >= true.width or cy + half >= true.height:
            continue
        win = img[cy - half: cy + half + 1, cx - half: cx + half + 1]
        yy, xx = np.mgrid[cy - half: cy + half + 1, cx - half: cx + half + 1]
        # Inside the black ring only the white disc is bright: weight by brightness above the ring level.
        inside = (xx - x0) ** 2 + (yy - y0) ** 2 <= (1.6 * r_px) ** 2
        w = np.where(inside, np.clip(win - np.percentile(win[inside], 10), 0, None), 0.0)
        errors.append(np.hypot((w * xx).sum() / w.sum() - x0, (w * yy).sum() / w.sum() - y0))
    errors = np.array(errors)
    assert len(errors) >= 8
    assert errors.max() < 0.1, errors


def test_truth_corners_lie_on_rendered_roofs(tiny_project):
    """Rays through the projected truth corners (nudged inside the roof) hit that roof at that point."""
    cfg = load_preset("tiny")
    layout = block_layout(cfg)
    truth = json.loads((tiny_project / "truth/truth.json").read_text())
    origin = np.array(truth["origin_m"])
    # Rebuild the scene from the same seed stream as the simulator.
    ss = np.random.SeedSequence(cfg.preset.seed).spawn(4)
    scene_seed = int(np.random.default_rng(ss[0]).integers(0, 2**31 - 1))
    scene = build_scene(cfg.scene, layout.width_m, layout.height_m, origin, scene_seed)
    accel = raycast.build_accel(scene)
    corners = _rows(tiny_project / "truth/roof_corners.csv")
    assert len(corners) == sum(len(b.outline.exterior.coords) - 1 + sum(len(r.coords) - 1 for r in b.outline.interiors)
                               for b in scene.buildings)
    eo = read_eo(tiny_project / "truth/eo.txt")
    cam = BrownCamera.read(tiny_project / "truth/camera.toml")
    by_id = {b.building_id: b for b in scene.buildings}
    checked = 0
    for i in range(len(eo)):
        C = eo.centre_m[i] - origin
        R = eo.rotation(i)
        for c in corners:
            b = by_id[int(c["building_id"])]
            P = np.array([float(c["x"]), float(c["y"]), float(c["z"])]) - origin
            # Nudge 0.3 m into the roof along the direction to the outline centroid (still on the roof).
            cen = np.array(b.outline.representative_point().coords[0])
            v = cen - P[:2]
            q = P.copy()
            q[:2] += 0.3 * v / np.linalg.norm(v)
            if b.roof != "flat" or not b.outline.contains(Point(q[:2])):
                continue
            x, y, depth = cam.project(q[None], C, R)
            if not cam.inside(x, y, margin_px=1)[0]:
                continue
            d = cam.rays(x, y, R)[0]
            t, kind, obj, *_ = raycast.cast(C, d, accel, True, -1)
            hit = C + d * t
            if np.linalg.norm(hit - q) > 0.01:
                continue  # occluded by a taller building or a crown
            assert kind == KIND_ROOF and obj == b.building_id
            checked += 1
    assert checked >= 20


def test_rendered_id_buffer_shows_roofs_at_projected_corners(tiny_project):
    """The rendered image itself (pixel centres) shows each flat roof just inside its projected corners."""
    cfg = load_preset("tiny")
    layout = block_layout(cfg)
    origin = np.array(json.loads((tiny_project / "truth/truth.json").read_text())["origin_m"])
    ss = np.random.SeedSequence(cfg.preset.seed).spawn(4)
    scene = build_scene(cfg.scene, layout.width_m, layout.height_m, origin,
                        int(np.random.default_rng(ss[0]).integers(0, 2**31 - 1)))
    accel = raycast.build_accel(scene)
    eo = read_eo(tiny_project / "truth/eo.txt")
    cam = BrownCamera.read(tiny_project / "truth/camera.toml")
    C, R = eo.centre_m[0] - origin, eo.rotation(0)
    _, ids = render.render_frame(scene, accel, cam, C, R, samples=1, with_ids=True)
    hits = total = 0
    for b in scene.buildings:
        if b.roof != "flat" or min(b.size_m) < 10:
            continue
        cen = np.array(b.outline.centroid.coords[0])
        for xy in np.asarray(b.outline.exterior.coords)[:-1]:
            inner = xy + 2.5 * (cen - xy) / np.linalg.norm(cen - xy)  # ~2.5 px inside at 0.96 m GSD
            if not b.outline.contains(Point(inner).buffer(1.0)):
                continue  # concave corner of an L-shape: the centroid direction leaves the roof
            x, y, _ = cam.project(np.array([[*inner, b.eave_z_m]]), C, R)
            col, row = int(round(x[0])), int(round(y[0]))
            if not (0 <= col < cam.width and 0 <= row < cam.height):
                continue
            if not render.visible(accel, C, np.array([[*inner, b.eave_z_m + 0.01]]))[0]:
                continue
            total += 1
            hits += ids[row, col] == KIND_ROOF * 1_000_000 + b.building_id
    assert total >= 10 and hits == total


def test_lidar_files_are_valid_las_with_crs_and_returns(tiny_project):
    files = sorted((tiny_project / "lidar").glob("*.las"))
    assert len(files) >= 2
    for f in files:
        las = laspy.read(f)
        truth = laspy.read(tiny_project / "truth/lidar" / f.name)
        assert las.header.version.major == 1 and las.header.version.minor == 4
        assert las.header.point_format.id == 6
        assert las.header.parse_crs().to_epsg() == 32649
        assert len(las.points) == len(truth.points) > 10000
        assert np.array_equal(las.x, truth.x) and np.array_equal(las.gps_time, truth.gps_time)
        assert np.all(las.classification == 1)
        rn, nr = np.asarray(las.return_number), np.asarray(las.number_of_returns)
        assert np.all((rn >= 1) & (rn <= nr))
        assert np.all(np.diff(np.asarray(las.gps_time)) >= 0)
        cls = np.asarray(truth.classification)
        multi = nr > 1
        assert multi.any()
        # Several returns come from vegetation; the last of them reaches the ground (or a roof).
        first_multi = multi & (rn == 1)
        last_multi = multi & (rn == nr)
        assert np.isin(cls[first_multi], [3, 4, 5]).mean() > 0.95
        assert np.isin(cls[last_multi], [2, 6, 9]).mean() > 0.8
        assert set(np.unique(cls)) <= {2, 3, 4, 5, 6, 7, 9, 18}
        assert np.asarray(las.intensity).max() > 0
        assert np.abs(np.asarray(las.scan_angle) * 0.006).max() <= 20.5
    # Low outliers lie 50-110 m below the true ground; high outliers well above.
    truth = laspy.read(tiny_project / "truth/lidar" / files[0].name)
    with rasterio.open(tiny_project / "truth/dem.tif") as dem:
        z_dem = np.array([v[0] for v in dem.sample(np.column_stack([truth.x, truth.y]))])
    inside = z_dem != -9999.0  # beams at the scene edge may end outside the DEM
    cls = np.asarray(truth.classification)[inside]
    dz = (np.asarray(truth.z) - z_dem)[inside]
    assert (cls == 7).any() and dz[cls == 7].max() < -40
    assert (cls == 18).any() and dz[cls == 18].min() > 20
    assert np.abs(dz[cls == 2]).max() < 1.0  # ground returns: range noise and DEM sampling only


def test_truth_rasters_are_georeferenced(tiny_project):
    with rasterio.open(tiny_project / "truth/dem.tif") as dem, rasterio.open(tiny_project / "truth/dsm.tif") as dsm:
        assert dem.crs.to_epsg() == 32649 and dem.nodata == -9999.0
        a, b = dem.read(1), dsm.read(1)
        assert np.all(b >= a - 1e-3)  # the surface is never below the terrain
        assert (b - a).max() > 5.0  # buildings and trees stand out
    with rasterio.open(tiny_project / "truth/ortho.tif") as o:
        assert o.count == 3 and o.crs.to_epsg() == 32649


def _digest(folder):
    h = {}
    for f in sorted(folder.rglob("*")):
        if f.is_file():
            h[str(f.relative_to(folder))] = hashlib.sha256(f.read_bytes()).hexdigest()
    return h


def test_same_seed_same_bytes(tiny_project, tmp_path):
    """The same seed gives the same bytes in another process (as `aerotri sim` runs)."""
    import subprocess
    import sys

    again = tmp_path / "again"
    subprocess.run([sys.executable, "-c", "import sys; from pathlib import Path; from aerotri.sim import load_preset, "
                    "simulate; simulate(load_preset('tiny'), Path(sys.argv[1]))", str(again)], check=True)
    assert _digest(again) == _digest(tiny_project)


@pytest.fixture
def proj_cache_without_wgs84_ensemble():
    """This thread's PROJ context left as the suite's worker had it in CI 64 and 65: a CRS object kept across
    ``pyproj.datadir.set_data_dir`` (``parse_crs``'s cache keeps them; the geoid fixture renews the context) and
    identified in the new context, which caches WGS 84's datum ensemble turned into a plain datum
    (``DatumEnsemble::asDatum``) before the ensemble: EPSG codes on WGS 84 then come from the database with a plain
    DATUM. Afterwards a new context whose cache holds the ensemble first."""
    import pyproj

    data_dir = pyproj.datadir.get_data_dir()
    pyproj.datadir.set_data_dir(data_dir)  # a new context first: the kept CRS has the ensemble whatever ran before
    kept = pyproj.CRS.from_epsg(32651)
    pyproj.datadir.set_data_dir(data_dir)
    try:
        kept.to_epsg()
        yield
    finally:
        pyproj.datadir.set_data_dir(data_dir)
        pyproj.CRS.from_epsg(4326)


def test_same_bytes_in_a_process_whose_proj_cache_lost_the_wgs84_ensemble(tiny_project, tmp_path,
                                                                            proj_cache_without_wgs84_ensemble):
    """In the process itself, with PROJ's cache giving EPSG:32649 a plain DATUM for the WGS 84 ensemble, the
    simulator writes the bytes of a fresh process: every LAS file's WKT record is PROJ's database text made in a
    fresh context (``epsg_wkt``). Before, the pytest worker wrote all 8 LAS files with the shorter WKT (points the
    same) after about 1,400 other tests (CI 64, 65)."""
    import pyproj

    from aerotri.geom.crs.definition import epsg_wkt

    assert "ENSEMBLE[" not in pyproj.CRS.from_epsg(32649).to_wkt()  # the state this test is about is there
    epsg_wkt.cache_clear()
    assert "ENSEMBLE[" in epsg_wkt(32649)
    again = tmp_path / "again"
    simulate(load_preset("tiny"), again)
    assert _digest(again) == _digest(tiny_project)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--preset", "nosuch"], "unknown preset 'nosuch'"),
        (["--preset", "tiny", "--set", "flight.side_overlap=-0.2"], "[flight] side_overlap = -0.2: out of range, expected >= 0 and <= 0.95"),
        (["--preset", "tiny", "--set", "flight.forward_overlap=1.2"], "[flight] forward_overlap = 1.2: out of range"),
        (["--preset", "tiny", "--set", "flight.height_above_ground_m=-100"], "[flight] height_above_ground_m = -100.0: out of range, expected > 0"),
        (["--preset", "tiny", "--set", "flight.height_above_ground_m=120"], "does not clear the terrain"),
        (["--preset", "tiny", "--set", "camera.width=abc"], "camera.width must be a number"),
        (["--preset", "tiny", "--set", "flight.nosuch=1"], "unknown parameter 'flight.nosuch'"),
    ],
)
def test_bad_parameters_exit_2_without_output(tmp_path, args, message):
    out = tmp_path / "out"
    res = CliRunner().invoke(aerotri_main, ["sim", *args, str(out)])
    assert res.exit_code == 2, res.output
    assert message in res.output
    assert not out.exists()


def test_sim_observations_option_writes_adjustable_files(tmp_path):
    out = tmp_path / "obs"
    res = CliRunner().invoke(aerotri_main, ["sim", "--preset", "tiny", "--observations", "--blunder-fraction", "0.03",
                                            str(out)])
    assert res.exit_code == 0, res.output
    ties = _rows(out / "at/tiepoints.csv")
    ctrl = _rows(out / "control/points.csv")
    assert len(ties) > 50 and {"point_id", "image_id", "x_px", "y_px"} <= set(ties[0])
    assert sum(r["kind"] == "full" for r in ctrl) >= 3 and any(r["kind"] == "check" for r in ctrl)
    res = CliRunner().invoke(aerotri_main, ["sim", "--preset", "tiny", "--observations", "--blunder-fraction", "2",
                                            str(tmp_path / "bad")])
    assert res.exit_code == 2 and "--blunder-fraction" in res.output


def test_land_cover_truth_beside_the_true_ortho(tiny_project):
    """truth/classes.tif and truth/ortho_nir.tif on the grid of truth/ortho.tif: roofs (eave outlines) are
    building, and the NIR band is bright on vegetation and dark on roofs, roads and water."""
    import shapely
    from rasterio.features import rasterize

    t = tiny_project / "truth"
    with rasterio.open(t / "ortho.tif") as o, rasterio.open(t / "classes.tif") as c, rasterio.open(t / "ortho_nir.tif") as n:
        assert c.transform == o.transform and n.transform == o.transform and c.shape == n.shape == o.shape
        assert c.crs == o.crs and c.nodata == 255
        classes, nir, transform = c.read(1), n.read(1).astype(float), o.transform
    assert set(np.unique(classes)) <= {2, 3, 5, 6, 9, 11, 255}
    assert {3, 6, 11}.issubset(set(np.unique(classes)))
    feats = json.loads((t / "buildings.geojson").read_text())["features"]
    eaves = [shapely.geometry.shape(f["geometry"]) for f in feats if f["properties"]["part"] == "roof_outline"]
    assert len(eaves) == len(feats) // 2
    roof = rasterize(((g, 1) for g in eaves), out_shape=classes.shape, transform=transform, fill=0).astype(bool)
    inner = rasterize(((g.buffer(-1.0), 1) for g in eaves), out_shape=classes.shape, transform=transform,
                      fill=0).astype(bool)
    # trees may hang over a roof edge; 1 m inside the eave a pixel is roof unless a crown covers it
    assert np.mean(classes[inner] == 6) > 0.97
    assert np.mean(classes[~roof] == 6) < 0.005
    mean_nir = {k: nir[classes == k].mean() for k in (3, 5, 6, 11)}
    assert min(mean_nir[3], mean_nir[5]) > 1.3 * max(mean_nir[6], mean_nir[11])


def test_buildings_geojson_opens_in_the_projects_crs(tiny_project):
    """truth/buildings.geojson holds grid coordinates: GDAL (and so QGIS) must read it in the project's CRS, not
    as RFC 7946's WGS 84 degrees."""
    import pyogrio
    import pyproj

    crs = tomllib.loads((tiny_project / "project.toml").read_text())["project"]["crs"]
    info = pyogrio.read_info(tiny_project / "truth" / "buildings.geojson")
    assert pyproj.CRS(info["crs"]) == pyproj.CRS(crs)
