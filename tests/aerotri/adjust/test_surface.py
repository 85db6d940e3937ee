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
    rep = write_outputs(ba, p)
    sc = json.loads((p / "at" / "report.json").read_text())["surface_control"]
    assert sc["used"] == ba.result.surface.used and sc["rejected"] == ba.result.surface.rejected > 0
    assert sc["dem"].endswith("dem_trees.tif") and rep["surface_control"]["sigma_m"] == 0.05
    assert "SURFACE CONTROL" in (p / "at" / "report.txt").read_text()
    assert "<h2>Surface control</h2>" in (p / "at" / "report.html").read_text()
