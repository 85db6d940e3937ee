"""chm.tif where the cell is finer than the point spacing: a cell no pulse hit takes its observed neighbours' mean, a
cell seen without trees stays nodata, a wide gap (a lake without returns) stays nodata (trial-forest: 0.5 m cells at
4.6 returns per m2 left 28 % of a closed canopy nodata, read as no trees)."""

import numpy as np
import pyproj
import rasterio

from lidarctl import io
from lidarctl.rasters import products as rasters

X0, Y0 = 500000.0, 5400000.0


def test_cells_no_return_hit_are_filled_and_gaps_stay_empty(tmp_path):
    g = np.arange(0.25, 60.0, 1.0)                       # pulses 1 m apart: one in four 0.5 m cells is hit
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    lake = (x > 40) & (x < 50) & (y > 40) & (y < 50)       # no returns at all
    x, y = x[~lake], y[~lake]
    crown = (x > 10) & (x < 30) & (y > 10) & (y < 30)      # a closed canopy, 12 m above the ground
    n, k = len(x), int(crown.sum())
    # the crown's pulses: a first return on the canopy and a last on the ground; elsewhere one ground return
    xs = np.r_[x, x[crown]]
    ys = np.r_[y, y[crown]]
    zs = np.r_[np.full(n, 100.0), np.full(k, 112.0)]
    cls = np.r_[np.full(n, 2), np.full(k, 5)].astype(np.uint8)
    rn = np.r_[np.where(crown, 2, 1), np.ones(k)].astype(np.uint8)
    nr = np.r_[np.where(crown, 2, 1), np.full(k, 2)].astype(np.uint8)
    cloud = io.PointCloud(X0 + xs, Y0 + ys, zs, np.full(len(xs), 100, np.uint16), rn, nr, cls,
                          crs=pyproj.CRS("EPSG:32632"))
    rasters.write_rasters(cloud, tmp_path / "r", 0.5)
    with rasterio.open(tmp_path / "r" / "chm.tif") as ds:
        chm = ds.read(1, masked=True)
        cx = ds.transform.c + (np.arange(ds.width) + 0.5) * ds.transform.a - X0
        cy = ds.transform.f + (np.arange(ds.height) + 0.5) * ds.transform.e - Y0
    inside = np.ix_((cy > 11) & (cy < 29), (cx > 11) & (cx < 29))
    assert (~chm.mask[inside]).mean() == 1.0 and np.allclose(chm[inside], 12.0, atol=1e-3)   # was 25 % of the cells
    open_ground = np.ix_((cy > 35) & (cy < 58), (cx > 2) & (cx < 8))
    assert chm.mask[open_ground].all()                                                     # seen, no trees
    in_lake = np.ix_((cy > 42) & (cy < 48), (cx > 42) & (cx < 48))
    assert chm.mask[in_lake].all()                                                         # never seen
