"""The LiDAR's shadow behind a wall at the DEM (bench/true_ortho_shadow_rule.py, the trial's rule): a constructed block, a scanner flying north
east of a 10 m building; the ground west of its west wall is hidden from it. The shadow's cells are lowered; a
4 x 4 m dropout in the middle of the roof (enclosed by roof returns) and the cells of a crown disk are not."""

import numpy as np
from scipy.spatial import cKDTree

BENCH_SCRIPT = "true_ortho_shadow_rule.py"

RES_M = 0.5
W_M, H_M = 70.0, 40.0
SCANNER_X_M, SCANNER_Z_M, SPEED_M_S = 60.0, 120.0, 50.0
BUILDING = (10.0, 20.0, 5.0, 35.0)   # x0, x1, y0, y1 (m)
ROOF_M = 10.0
DROPOUT = (13.0, 17.0, 18.0, 22.0)
CROWN = (7.5, 12.0, 2.0)              # a disk over part of the shadow: x, y, radius (m)


def _block():
    rng = np.random.default_rng(7)
    g = np.arange(0.25, W_M, 0.5)
    x, y = np.meshgrid(g, np.arange(0.25, H_M, 0.5))
    x = (x + rng.uniform(-0.1, 0.1, x.shape)).ravel()
    y = (y + rng.uniform(-0.1, 0.1, y.shape)).ravel()
    bx0, bx1, by0, by1 = BUILDING
    roof = (x >= bx0) & (x <= bx1) & (y >= by0) & (y <= by1)
    z = np.where(roof, ROOF_M, 0.0)
    # the ground west of the wall is hidden where the line to the scanner passes under the wall's top
    with np.errstate(divide="ignore"):
        wall_z = (bx0 - x) * SCANNER_Z_M / (SCANNER_X_M - x)
    hidden = ~roof & (x < bx0) & (y >= by0) & (y <= by1) & (wall_z < ROOF_M)
    d0, d1, d2, d3 = DROPOUT
    dropout = (x > d0) & (x < d1) & (y > d2) & (y < d3)
    keep = ~hidden & ~dropout
    x, y, z = x[keep], y[keep], z[keep]
    angle = np.degrees(np.arctan((SCANNER_X_M - x) / SCANNER_Z_M))
    return x, y, z, y / SPEED_M_S, np.ones(len(x), np.int64), angle


def _cells(shadow):
    x, y, z, t, sid, ang = _block()
    nr, nc = int(H_M / RES_M), int(W_M / RES_M)
    cy, cx = np.mgrid[0:nr, 0:nc]
    cx, cy = (cx + 0.5) * RES_M, H_M - (cy + 0.5) * RES_M
    surface = z[cKDTree(np.column_stack([x, y])).query(np.column_stack([cx.ravel(), cy.ravel()]))[1]].reshape(nr, nc)
    dem = np.zeros((nr, nc))
    keep = shadow.disk_cells([CROWN[0]], [CROWN[1]], [CROWN[2]], (nr, nc), x0_m=0.0, y_top_m=H_M, res_m=RES_M)
    scan, missing = shadow.scan_geometry(x, y, t, sid, ang)
    cells = shadow.shadow_cells(surface, dem, x0_m=0.0, y_top_m=H_M, res_m=RES_M, x_m=x, y_m=y, z_m=z, scan=scan,
                                keep=keep, strips_without_line=missing)
    return cells, surface, keep, cx, cy


def test_shadow_lowered_roof_dropout_and_crown_kept(bench_script):
    cells, surface, keep, cx, cy = _cells(bench_script)
    bx0, bx1, by0, by1 = BUILDING
    # the shadow's cells the nearest-return DSM stands at the roof's height, beyond a radius of the wall's returns
    in_shadow = (surface == ROOF_M) & (cx < bx0 - 0.75) & (cy > by0 + 1) & (cy < by1 - 1) & ~keep
    assert in_shadow.sum() > 50
    assert cells.lower[in_shadow].mean() > 0.9
    roof = (cx > bx0) & (cx < bx1) & (cy > by0) & (cy < by1)
    assert not cells.lower[roof].any()                  # the dropout in the middle of the roof stays a roof
    d0, d1, d2, d3 = DROPOUT
    dropout = (cx > d0 + 0.5) & (cx < d1 - 0.5) & (cy > d2 + 0.5) & (cy < d3 - 0.5)
    assert cells.empty[dropout].all()                   # empty, as the shadow, but enclosed by roof returns
    shadow_in_crown = keep & (surface == ROOF_M) & (cx < bx0)
    assert shadow_in_crown.sum() > 5 and not cells.lower[keep].any()
    assert not cells.lower[cx > bx1].any()              # the scanner's side of the building: seen, never lowered
    assert cells.strips_without_line == ()


def test_reverted_rule_would_lower_the_dropout(bench_script):
    # what the second condition is for: the dropout's cells have no return within the radius, as the shadow's
    cells, surface, keep, cx, cy = _cells(bench_script)
    d0, d1, d2, d3 = DROPOUT
    dropout = (cx > d0 + 0.5) & (cx < d1 - 0.5) & (cy > d2 + 0.5) & (cy < d3 - 0.5)
    assert cells.empty[dropout].sum() >= 25 and not cells.touches_ground[dropout].any()


def test_strip_without_nadir_returns_makes_no_shadow(bench_script):
    x, y, z, t, sid, ang = _block()
    far = np.abs(ang) > 5
    scan, missing = bench_script.scan_geometry(x[far], y[far], t[far], sid[far], ang[far])
    assert missing == (1,) and np.isnan(scan.toward_e).all()
