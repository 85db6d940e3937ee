"""The occlusion masks of a true ortho against the simulator's own visibility (issue 42): a small town of tall
buildings built by the simulator (``aerotri.sim.scene``, the ``tall`` preset's buildings on 200 x 200 m), its exact
DSM (straight-down ray casts at the centres of 0.5 m cells, as ``truth/dsm.tif``), two frames over it; every ground
cell of a 0.4 m ortho grid is ray cast from the frame's projection centre (``aerotri.sim.raycast``): the frame sees
it when the first hit is the terrain within 0.2 m of the point (as ``bench/eval_true_ortho_occlusion.py``).

Both errors are counted as shares of the hidden ground cells: they lie along the edges of the hidden areas (the DSM
places an edge to within about a cell), whose length goes with the hidden area. The limits are 1.5 x the worst of
seed 11's two frames, rounded up (there: hidden left valid 1.5 % and 2.0 %, visible masked 5.8 % and 4.9 %), and
hold on seed 12 (16 buildings against 9; measured 2.0 % and 2.8 %, 6.4 % and 6.5 %). The march before this change
(steps of one DSM cell over the bilinear DSM, a z-buffer test cell by cell) left 8.8-18 % of the hidden ground
valid on these frames (visible masked 2.3-3.8 % of the hidden).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pyproj import CRS

from aerotri.geom.camera import BrownCamera
from aerotri.geom.rotation import rotation_matrix_opk
from ortho.dem import HeightRaster
from ortho.grid import OrthoGrid
from ortho.rectify import rectify_frame

SIZE_M = 200.0
DSM_RES_M = 0.5
ORTHO_RES_M = 0.4
VISIBLE_TOL_M = 0.2
# chosen on seed 11, as shares of the hidden ground cells
MAX_HIDDEN_VALID = 0.03  # hidden ground the mask leaves valid
MAX_VISIBLE_MASKED = 0.09  # seen ground the mask drops
# two frames (x, y, height above the median DSM height, omega, phi, kappa): over the town's corner (oblique rays into
# the streets) and over its middle
POSES = ((30.0, 40.0, 300.0, 1.5, -2.0, 5.0), (100.0, 95.0, 300.0, -1.0, 1.0, -8.0))


def town(seed: int):
    """The simulator's scene (``tall`` preset's buildings and trees, 200 x 200 m), its ray-cast acceleration and its
    exact DSM (heights of straight-down rays at the centres of 0.5 m cells)."""
    from aerotri.sim import raycast
    from aerotri.sim.config import load_preset
    from aerotri.sim.scene import build_scene

    cfg = dataclasses.replace(load_preset("tall").scene, buildings=60, single_trees=6, tree_clusters=0, slope_trees=0,
                              bushes=0, check_targets=0, urban_margin_m=20.0, road_spacing_m=120.0)
    scene = build_scene(cfg, SIZE_M, SIZE_M, np.zeros(3), seed)
    accel = raycast.build_accel(scene)
    n = int(SIZE_M / DSM_RES_M)
    c = (np.arange(n) + 0.5) * DSM_RES_M
    X, Y = np.meshgrid(c, SIZE_M - c)
    _, z, _ = surface(accel, X.ravel(), Y.ravel())
    dsm = HeightRaster(z.reshape(n, n).astype(np.float32), 0.0, SIZE_M, DSM_RES_M, CRS.from_epsg(32649), "DSM")
    return scene, accel, dsm


def cast(accel, origins, dirs):
    from aerotri.sim import raycast

    t, kind, _, _ = raycast.cast_many(np.ascontiguousarray(origins), np.ascontiguousarray(dirs), accel, True)
    return t, kind


def surface(accel, x, y):
    """(kind, height, t) of the first hit of straight-down rays at (x, y)."""
    top = float(accel[-1]) + 10.0
    o = np.stack([x, y, np.full_like(x, top)], axis=1)
    d = np.tile([0.0, 0.0, -1.0], (len(x), 1))
    t, kind = cast(accel, o, d)
    return kind, top - t, t


def mask_against_truth(scene, accel, dsm, pose) -> dict:
    """The true ortho's mask of one frame against the ray-cast visibility of the ground cells it images."""
    from aerotri.sim.scene import KIND_TERRAIN

    cam = BrownCamera(focal_mm=60.0, pixel_um=60.0, width=1200, height=1200)
    C = np.array([pose[0], pose[1], pose[2] + float(np.median(dsm.heights_m))])
    R = rotation_matrix_opk(*pose[3:])
    grid = OrthoGrid(dsm.crs, 20.0, SIZE_M - 20.0, ORTHO_RES_M, int(160 / ORTHO_RES_M), int(130 / ORTHO_RES_M))
    image = np.zeros((cam.height, cam.width), np.uint8)
    _, imaged = rectify_frame(image, cam, C, R, dsm, grid, tile_px=256)
    _, valid = rectify_frame(image, cam, C, R, dsm, grid, occlusion_dsm=dsm, tile_px=256)
    xs, ys = grid.centres()
    X, Y = (a.ravel() for a in np.meshgrid(xs, ys))
    kind, _, _ = surface(accel, X, Y)
    ground = (kind == KIND_TERRAIN) & (imaged.ravel() > 0)
    idx = np.flatnonzero(ground)
    Zg = scene.terrain_height(X[idx], Y[idx])
    d = np.stack([X[idx] - C[0], Y[idx] - C[1], Zg - C[2]], axis=1)
    t, hit = cast(accel, np.broadcast_to(C, d.shape), d)
    length = np.linalg.norm(d, axis=1)
    sees = (hit == KIND_TERRAIN) & (t * length >= length - VISIBLE_TOL_M)
    ok = valid.ravel()[idx] > 0
    return {"ground": len(idx), "hidden": int((~sees).sum()), "seen": int(sees.sum()),
            "hidden_valid": int((~sees & ok).sum()), "visible_masked": int((sees & ~ok).sum())}


@pytest.fixture(scope="module", params=[11, 12], ids=["seed11-chosen-on", "seed12-held-out"])
def scene(request):
    return town(request.param)


@pytest.mark.parametrize("pose", POSES, ids=["corner", "middle"])
def test_the_masks_match_the_simulators_visibility(scene, pose):
    got = mask_against_truth(*scene, pose)
    assert got["hidden"] > 0.05 * got["ground"], got  # the tall buildings hide much of the ground
    assert got["hidden_valid"] <= MAX_HIDDEN_VALID * got["hidden"], got
    assert got["visible_masked"] <= MAX_VISIBLE_MASKED * got["hidden"], got
