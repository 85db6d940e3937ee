"""Synthetic airborne LiDAR scenes with known truth, for tests and benchmarks.

Terrain: smooth hills on a tilted plane. Buildings: rectangular blocks with flat or gabled roofs.
Trees: ellipsoidal crowns; a pulse hitting a crown gives a first return in the crown and, with
probability ``canopy_gap``, a last return on the ground below (sparse ground under canopy).
Outliers: low points 3-20 m below ground, high points 40-200 m above. Classes are ASPRS codes
(2 ground, 3/4/5 vegetation by height, 6 building, 7 low noise, 18 high noise).

Scenes are generated in metres; ``write_las`` writes them in the units of the CRS it is given (a
scene written in a foot CRS holds feet). ``metric_twin_crs`` and ``metric_copy`` make the metric
copy of a cloud in feet (same projection, metre units, same points), for unit tests.
"""

from __future__ import annotations

import numpy as np
import pyproj

from lidarctl.io import PointCloud


def terrain_height(x, y, x0=0.0, y0=0.0):
    """True terrain height (m) at (x, y)."""
    u, v = np.asarray(x) - x0, np.asarray(y) - y0
    return 100.0 + 0.03 * u + 0.02 * v + 3.0 * np.sin(u / 40.0) * np.cos(v / 55.0)


def synthetic_scene(*, width_m: float = 200.0, height_m: float | None = None, density_per_m2: float = 4.0,
                    n_buildings: int = 6, n_trees: int = 40, n_low_outliers: int = 50,
                    n_high_outliers: int = 20, canopy_gap: float = 0.35, seed: int = 0,
                    x0: float = 500000.0, y0: float = 5400000.0, u0: float = 0.0,
                    v0: float = 0.0) -> tuple[PointCloud, np.ndarray]:
    """Return (cloud, truth classes). Buildings and trees do not overlap.

    (u0, v0): offset of this tile inside a larger scene (the terrain is continuous across tiles);
    the cloud's coordinates are x0 + u0 + u, y0 + v0 + v.
    """
    rng = np.random.default_rng(seed)

    def tile_terrain(a, b):
        return terrain_height(np.asarray(a) + u0, np.asarray(b) + v0)

    height_m = width_m if height_m is None else height_m
    n = int(width_m * height_m * density_per_m2)
    u = rng.uniform(0, width_m, n)
    v = rng.uniform(0, height_m, n)
    ground_z = tile_terrain(u, v)
    z = ground_z + rng.normal(0, 0.03, n)
    cls = np.full(n, 2, np.uint8)
    rn = np.ones(n, np.uint8)
    nr = np.ones(n, np.uint8)
    intensity = rng.normal(300, 30, n).clip(1, 65535)

    # Buildings on a coarse lattice so that they never overlap each other or the trees.
    occupied = []
    slots = [(a, b) for a in np.arange(30, width_m - 40, 60) for b in np.arange(30, height_m - 40, 60)]
    rng.shuffle(slots)
    for a, b in slots[:n_buildings]:
        w, d = rng.uniform(12, 35), rng.uniform(10, 30)
        h = rng.uniform(4, 15)
        inside = (u >= a) & (u < a + w) & (v >= b) & (v < b + d)
        base = tile_terrain(a + w / 2, b + d / 2)
        if rng.random() < 0.5:
            roof = base + h
            zr = np.full(inside.sum(), roof)
        else:   # gabled: ridge along u, 30 deg pitch
            zr = base + h + 0.0 * u[inside] + np.tan(np.radians(30)) * (d / 2 - np.abs(v[inside] - (b + d / 2)))
        z[inside] = zr + rng.normal(0, 0.03, inside.sum())
        cls[inside] = 6
        intensity[inside] = rng.normal(500, 40, inside.sum())
        occupied.append((a - 5, a + w + 5, b - 5, b + d + 5))

    def free(px, py, r):
        return all(not (lo_a - r < px < hi_a + r and lo_b - r < py < hi_b + r) for lo_a, hi_a, lo_b, hi_b in occupied)

    extra = []
    trees = 0
    tries = 0
    while trees < n_trees and tries < 50 * n_trees:
        tries += 1
        cx, cy, r = rng.uniform(5, width_m - 5), rng.uniform(5, height_m - 5), rng.uniform(2.5, 6)
        if not free(cx, cy, r):
            continue
        trees += 1
        top = rng.uniform(6, 25)
        d2 = ((u - cx) ** 2 + (v - cy) ** 2) / (r * r)
        hit = (d2 < 1.0) & (cls == 2)
        k = int(hit.sum())
        if k == 0:
            continue
        shape = np.sqrt(1.0 - d2[hit])                       # ellipsoidal crown surface
        crown_base = 0.35 * top
        zc = ground_z[hit] + crown_base + (top - crown_base) * shape * rng.uniform(0.6, 1.0, k)
        through = rng.random(k) < canopy_gap
        idx = np.flatnonzero(hit)
        # First return in the crown; where the pulse goes through, a last return on the ground.
        extra.append((u[idx[through]], v[idx[through]], z[idx[through]]))
        z[idx] = zc
        cls[idx] = np.where(zc - ground_z[idx] > 5.0, 5, np.where(zc - ground_z[idx] > 2.0, 4, 3))
        nr[idx] = np.where(through, 2, 1)
        intensity[idx] = rng.normal(150, 30, k)
    if extra:
        eu = np.concatenate([e[0] for e in extra])
        ev = np.concatenate([e[1] for e in extra])
        ez = np.concatenate([e[2] for e in extra])
        m = len(eu)
        u = np.concatenate([u, eu]); v = np.concatenate([v, ev]); z = np.concatenate([z, ez])
        cls = np.concatenate([cls, np.full(m, 2, np.uint8)])
        rn = np.concatenate([rn, np.full(m, 2, np.uint8)])
        nr = np.concatenate([nr, np.full(m, 2, np.uint8)])
        intensity = np.concatenate([intensity, rng.normal(200, 30, m)])

    lo_u, lo_v = rng.uniform(0, width_m, n_low_outliers), rng.uniform(0, height_m, n_low_outliers)
    hi_u, hi_v = rng.uniform(0, width_m, n_high_outliers), rng.uniform(0, height_m, n_high_outliers)
    u = np.concatenate([u, lo_u, hi_u]); v = np.concatenate([v, lo_v, hi_v])
    z = np.concatenate([z, tile_terrain(lo_u, lo_v) - rng.uniform(3, 20, n_low_outliers),
                        tile_terrain(hi_u, hi_v) + rng.uniform(40, 200, n_high_outliers)])
    cls = np.concatenate([cls, np.full(n_low_outliers, 7, np.uint8), np.full(n_high_outliers, 18, np.uint8)])
    k = n_low_outliers + n_high_outliers
    rn = np.concatenate([rn, np.ones(k, np.uint8)]); nr = np.concatenate([nr, np.ones(k, np.uint8)])
    intensity = np.concatenate([intensity, rng.normal(100, 10, k)])
    order = rng.permutation(len(u))       # no spatial ordering to lean on
    cloud = PointCloud(x=u[order] + x0 + u0, y=v[order] + y0 + v0, z=z[order],
                       intensity=np.clip(intensity[order], 1, 65535).astype(np.uint16),
                       return_number=rn[order], number_of_returns=nr[order],
                       classification=np.zeros(len(u), np.uint8))
    return cloud, cls[order]


def write_las(path, cloud: PointCloud, classification=None, crs=None, version: str = "1.4") -> None:
    """Write a cloud (x, y, z in metres) as LAS/LAZ (point format 6 for 1.4, 1 for 1.2), scale 0.001
    of the CRS's unit; coordinates in the CRS's units (feet for a foot CRS; metres without CRS)."""
    import laspy

    from lidarctl.units import METRE, units_of

    fmt = 6 if version == "1.4" else 1
    header = laspy.LasHeader(version=version, point_format=fmt)
    header.scales = np.array([0.001, 0.001, 0.001])
    units = METRE
    if crs is not None:
        crs = pyproj.CRS.from_user_input(crs)
        units = units_of(crs)
    x, y, z = units.xy_from_m(cloud.x), units.xy_from_m(cloud.y), units.z_from_m(cloud.z)
    header.offsets = np.array([np.floor(x.min()), np.floor(y.min()), 0.0])
    if crs is not None:
        header.add_crs(crs)
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.intensity = cloud.intensity
    las.return_number = cloud.return_number
    las.number_of_returns = cloud.number_of_returns
    las.classification = cloud.classification if classification is None else classification
    las.write(str(path))


def metric_twin_crs(crs) -> pyproj.CRS:
    """The same projected CRS with metre units: axis units and length parameters (false easting and
    northing) converted to metres. Coordinates of a point in ``crs`` times its unit are that point's
    coordinates in the twin."""
    from aerotri.geom.crs.definition import horizontal_crs

    d = horizontal_crs(pyproj.CRS.from_user_input(crs)).to_json_dict()
    d.pop("id", None)
    d["name"] = f"{d['name']} (metre twin)"
    conversion = d["conversion"]
    conversion.pop("id", None)
    for p in conversion["parameters"]:
        unit = p.get("unit")
        if isinstance(unit, dict) and unit.get("type") == "LinearUnit":
            p["value"] = p["value"] * unit["conversion_factor"]
            p["unit"] = "metre"
    for axis in d["coordinate_system"]["axis"]:
        if isinstance(axis.get("unit"), dict) and axis["unit"].get("type") == "LinearUnit":
            axis["unit"] = "metre"
    return pyproj.CRS.from_json_dict(d)


def metric_copy(in_path, out_path) -> pyproj.CRS:
    """Copy a LAS/LAZ file in a foot CRS into metres without re-quantising: the same integer
    records, scales and offsets multiplied by the unit, and the metric twin of its CRS (a WKT
    record). Returns the twin CRS."""
    import laspy
    from laspy.vlrs.known import WktCoordinateSystemVlr

    from aerotri.geom import las
    from lidarctl import io

    header = las.read_header(in_path)
    crs, units = io.resolve_crs_units(in_path, header, None)
    twin = metric_twin_crs(crs)
    records = io.read_records(in_path)
    out = laspy.LasHeader(version=header.version, point_format=header.point_format)
    factor = np.array([units.xy_m, units.xy_m, units.z_m])
    out.scales, out.offsets = np.asarray(header.scales) * factor, np.asarray(header.offsets) * factor
    out.vlrs.append(WktCoordinateSystemVlr(twin.to_wkt()))
    if header.version.minor >= 4:
        out.global_encoding.wkt = True
    las = laspy.LasData(out)
    las.points = laspy.ScaleAwarePointRecord(records.array.copy(), header.point_format, out.scales, out.offsets)
    las.write(str(out_path))
    return twin
