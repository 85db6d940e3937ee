"""The frame renderer (z-buffer rasterisation) against the ray caster and the truth, the ground-material index,
tiled 16-bit frames."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import rasterio

from aerotri.geom.camera import BrownCamera
from aerotri.geom.eo import read_eo
from aerotri.sim import load_preset, raster, raycast, render, shading, simulate
from aerotri.sim.flight import block_layout
from aerotri.sim.scene import KIND_ROOF, build_scene, scene_counts


def _scene(name="tiny", sets=()):
    cfg = load_preset(name, sets)
    layout = block_layout(cfg)
    ss = np.random.SeedSequence(cfg.preset.seed).spawn(4)
    return cfg, build_scene(cfg.scene, layout.width_m, layout.height_m, np.zeros(3),
                            int(np.random.default_rng(ss[0]).integers(0, 2**31 - 1)))


@pytest.fixture(scope="module")
def tiny_truth(tiny_project):
    cfg, scene = _scene()
    origin = np.array(json.loads((tiny_project / "truth/truth.json").read_text())["origin_m"])
    return dict(cfg=cfg, scene=scene, accel=raycast.build_accel(scene), origin=origin,
                eo=read_eo(tiny_project / "truth/eo.txt"), cam=BrownCamera.read(tiny_project / "truth/camera.toml"))


def test_rasteriser_shows_what_the_ray_caster_hits(tiny_truth):
    """Surface ids at every pixel centre of every tiny frame: the z-buffer renderer and a ray per pixel agree
    except where a pixel centre lies on an edge between two surfaces."""
    t = tiny_truth
    renderer = raster.FrameRenderer(t["scene"], t["cam"], 0.96, samples=1, bits=8)
    total = differ = 0
    for i in range(len(t["eo"])):
        C, R = t["eo"].centre_m[i] - t["origin"], t["eo"].rotation(i)
        _, ids = renderer.render(C, R, with_ids=True)
        _, ids_ray = render.render_frame(t["scene"], t["accel"], t["cam"], C, R, samples=1, with_ids=True)
        total += ids.size
        differ += int((ids != ids_ray).sum())
    assert total == 6 * 432 * 240
    assert differ <= 1e-4 * total, differ


def test_rows_rendered_on_threads_are_the_rows_of_one_thread(tiny_truth, monkeypatch):
    """The bands of rows are rendered on the renderer's threads, 8-bit ones through a uint16 buffer (the kernel
    writes uint16 samples for 8- and 12-bit frames: one compiled signature): the whole frame on two threads, on
    one, and its rows submitted a band at a time (several calls in flight) give the same samples and surface
    ids."""
    t = tiny_truth
    C, R = t["eo"].centre_m[0] - t["origin"], t["eo"].rotation(0)
    expo = dict(noise_dn=2.0, noise_seed=7, with_ids=True)
    monkeypatch.setattr(raster.numba, "get_num_threads", lambda: 2)
    renderer = raster.FrameRenderer(t["scene"], t["cam"], 0.96, samples=1, bits=8)
    whole, ids = renderer.render(C, R, **expo)
    assert renderer._threads()._max_workers == 2
    frame = renderer.setup(C, R)
    jobs = [renderer.submit_rows(frame, r0, r0 + raster.BAND_ROWS, **expo)
            for r0 in range(0, 240, raster.BAND_ROWS)]
    banded = [job.result() for job in jobs]
    monkeypatch.setattr(raster.numba, "get_num_threads", lambda: 1)
    one, ids_one = raster.FrameRenderer(t["scene"], t["cam"], 0.96, samples=1, bits=8).render(C, R, **expo)
    assert whole.dtype == np.uint8 and whole.shape == (240, 432, 3) and whole.max() > 200
    assert np.array_equal(whole, one) and np.array_equal(ids, ids_one)
    assert np.array_equal(whole, np.concatenate([b[0] for b in banded]))
    assert np.array_equal(ids, np.concatenate([b[1] for b in banded]))


def test_roof_corners_with_their_relief_displacement(tiny_truth):
    """Flat-roof corners at their projected (relief-displaced) positions: 1 px inside the corner the rendered
    frame shows that roof, 1.5 px outside it does not; the displacement from the ground point under the corner
    is the relief displacement of the roof height (many pixels for tall buildings)."""
    t = tiny_truth
    renderer = raster.FrameRenderer(t["scene"], t["cam"], 0.96, samples=1, bits=8)
    checked, displaced = 0, []
    for i in range(len(t["eo"])):
        C, R = t["eo"].centre_m[i] - t["origin"], t["eo"].rotation(i)
        _, ids = renderer.render(C, R, with_ids=True)
        for b in t["scene"].buildings:
            if b.roof != "flat" or b.shape != "rectangle" or b.eave_z_m - b.base_z_m < 8.0:
                continue
            cen = np.array(b.outline.centroid.coords[0])
            for xy in np.asarray(b.outline.exterior.coords)[:-1]:
                corner = np.array([[*xy, b.eave_z_m]])
                x, y, _ = t["cam"].project(corner, C, R)
                if not t["cam"].inside(x, y, margin_px=4)[0]:
                    continue
                if not render.visible(t["accel"], C, corner + [0.3 * (cen - xy)[0] / np.linalg.norm(cen - xy),
                                                                0.3 * (cen - xy)[1] / np.linalg.norm(cen - xy), 0.01])[0]:
                    continue
                # image direction towards the roof's inside: the projected centroid
                cx, cy, _ = t["cam"].project(np.array([[*cen, b.eave_z_m]]), C, R)
                u = np.array([cx[0] - x[0], cy[0] - y[0]])
                u /= np.linalg.norm(u)
                inside = np.rint([x[0] + 1.0 * u[0] * np.sqrt(2), y[0] + 1.0 * u[1] * np.sqrt(2)]).astype(int)
                outside = np.rint([x[0] - 1.5 * u[0] * np.sqrt(2), y[0] - 1.5 * u[1] * np.sqrt(2)]).astype(int)
                roof_id = KIND_ROOF * 1_000_000 + b.building_id
                assert ids[inside[1], inside[0]] == roof_id
                assert ids[outside[1], outside[0]] != roof_id
                gx, gy, _ = t["cam"].project(np.array([[*xy, b.base_z_m]]), C, R)
                displaced.append(np.hypot(x[0] - gx[0], y[0] - gy[0]))
                checked += 1
    assert checked >= 8
    assert max(displaced) > 3.0  # relief displacement in pixels: the frames are central perspectives


def test_ground_index_gives_the_ray_casters_materials():
    """The grid index of targets, ponds and roads and the interpolated soil field: the reference's material at
    every point (random points over the scene, points near every feature, points outside the scene)."""
    _, scene = _scene("demo")
    G = shading.ground_index(scene)
    rng = np.random.default_rng(3)
    pts = [rng.uniform([-50, -50], [scene.width_m + 50, scene.height_m + 50], (200_000, 2))]
    for x, y, r in scene.targets:
        pts.append(rng.normal([x, y], 2 * r, (300, 2)))
    for x0, y0, x1, y1, w in scene.roads:
        s = rng.uniform(0, 1, (400, 1))
        pts.append(np.column_stack([x0, y0]) + s * [x1 - x0, y1 - y0] + rng.normal(0, w, (400, 2)))
    for cx, cy, a, b, _, _ in scene.ponds:
        pts.append(rng.normal([cx, cy], max(a, b), (500, 2)))
    p = np.vstack(pts)
    x, y = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
    fast = shading.ground_materials(x, y, G)
    ref = raycast.ground_materials(x, y, scene.roads, scene.ponds, scene.targets, scene.seed)
    assert np.array_equal(fast, ref)
    assert len(np.unique(ref)) == 7  # every material was among the points


def test_texture_follows_the_gsd():
    """The finest texture octave is about the GSD: a 0.1 m GSD scene has ground texture at 0.1-0.2 m, a
    0.36 m one stops at 0.5 m (no aliasing noise)."""
    assert shading.n_octaves(shading.SCALE_GROUND_M, 0.10) == 6  # 4 m ... 0.125 m
    assert shading.n_octaves(shading.SCALE_GROUND_M, 0.36) == 4  # 4 m ... 0.5 m
    # rendered straight down at 0.05 m, the 0.1 m texture has contrast between neighbouring 0.1 m cells
    _, scene = _scene("tiny")
    fine, coarse = raster.SceneLook(scene, 0.1), raster.SceneLook(scene, 0.36)
    x0, ytop = 100.0, 150.0
    grass = []
    for look in (fine, coarse):
        _, rad, ids = raster.ortho_render(look, x0, ytop, 0.05, r0=0, r1=200, ncols=200)
        g = rad[:, :, 1].astype(float)
        grass.append(np.abs(np.diff(g[:, ::2], axis=1)).mean())  # neighbours 0.1 m apart
    assert grass[0] > 1.5 * grass[1]


def test_scene_counts_scale_with_the_flight():
    cfg = load_preset("demo")
    layout = block_layout(cfg)
    assert scene_counts(cfg.scene, layout.width_m, layout.height_m) is cfg.scene  # its own flight: as given
    bigger = scene_counts(cfg.scene, 2 * layout.width_m, 2 * layout.height_m)
    assert bigger.buildings == 4 * cfg.scene.buildings and bigger.slope_trees == 2 * cfg.scene.slope_trees


def _digest(folder):
    return {str(f.relative_to(folder)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(folder.rglob("*")) if f.is_file()}


TILED = ["flight.strips=1", "flight.frames_per_strip=2", "render.bits=12", "render.tile_px=64",
         'render.compress="zstd"', "lidar.pulse_rate_hz=2000.0"]


def test_tiled_16_bit_frames_same_seed_same_bytes(tmp_path):
    """12-bit frames in tiled 16-bit TIFFs (64 px tiles, ZSTD), pixel-interleaved RGB; the same seed gives the
    same bytes; a panchromatic block has one band."""
    a, b = tmp_path / "a", tmp_path / "b"
    simulate(load_preset("tiny", TILED), a)
    simulate(load_preset("tiny", TILED), b)
    assert _digest(a / "images") == _digest(b / "images")
    frames = sorted((a / "images").glob("*.tif"))
    assert len(frames) == 2
    with rasterio.open(frames[0]) as ds:
        assert ds.count == 3 and ds.dtypes == ("uint16",) * 3 and (ds.width, ds.height) == (432, 240)
        assert ds.block_shapes == [(64, 64)] * 3 and ds.compression.name.lower() == "zstd"
        assert ds.interleaving.name.lower() == "pixel"
        img = ds.read()
    assert 0 < img.max() <= 4095 and img.mean() > 300  # 12-bit range, linear radiometry
    pan = tmp_path / "pan"
    simulate(load_preset("tiny", TILED + ['render.bands="pan"']), pan)
    with rasterio.open(sorted((pan / "images").glob("*.tif"))[0]) as ds:
        assert ds.count == 1 and ds.dtypes == ("uint16",)
        p = ds.read(1).astype(float)
    # the panchromatic band is the mean of R, G and B (the same noise-free radiance, its own noise)
    assert abs(p.mean() - img.astype(float).mean()) < 5.0


def test_simulate_reports_the_cost_of_each_phase(tmp_path):
    """``simulate(on_phase=...)``: wall, CPU and peak RSS of each phase and what it made (the bench of the
    full-size block reads them)."""
    costs = []
    truth = simulate(load_preset("tiny", TILED), tmp_path / "p", on_phase=costs.append)
    by = {c.phase: c for c in costs}
    assert list(by) == ["scene", "frames", "lidar", "truth_rasters", "other"]
    assert by["frames"].frames == 2 and by["frames"].megapixels == pytest.approx(2 * 432 * 240 / 1e6)
    assert by["lidar"].points == truth.lidar_points > 0 and by["lidar"].pulses > by["lidar"].points / 3
    assert by["truth_rasters"].megapixels > 0
    for c in costs:
        assert c.wall_s >= 0 and c.cpu_s >= 0 and (c.peak_rss_mb is None or c.peak_rss_mb > 50)
