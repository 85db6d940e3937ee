"""Bad input over every command: exit code 2, one message naming the file/record or option, no traceback,
no partial output and inputs byte-identical (issue 17; extended to every command and input kind for issue 39).

One workspace is built per module: the simulator's ``tiny`` project (the session fixture) with every stage
run once (tie points, control from the truth corners, adjustment, rectification, mosaic, DOM check,
report), so that a later stage's command has valid inputs, plus a small synthetic classified LAS/LAZ and
point lists for ``lidarctl`` and ``aerotri crs``. Every case copies that workspace, breaks one thing,
snapshots the whole tree (hash of every file, every folder), runs the command in-process with click's
``CliRunner`` and checks:

- exit code 2 and a ``SystemExit`` (no other exception escaped: no traceback);
- exactly one ``Error:`` line on stderr, naming the expected file/option (``expect``);
- the tree afterwards is identical: no output written, nothing changed or removed, no temporaries left.

A few cases run again through a real subprocess (the console scripts) to show that no traceback escapes.

Issue 39 added, for every command of the three command lines (``test_corpus_is_large_and_ids_unique`` checks
that each has cases): every height raster a command reads in every odd form (1 x 1, one row or column,
infinities, all nodata or NaN, an undeclared nodata value, no CRS, RGB or two bands, another zone, US feet,
degrees), LiDAR strips given twice (by name or as a byte copy), of another zone, empty or of one point, text
tables empty, header-only, with inf, text in a number column or a field missing, ids and images that exist
nowhere, coordinates of another zone or place, and NaN, infinite, negative, tiny and huge option values.
``ACCEPTED``: unusual but valid inputs that must work (units from the CRS: a DEM or cloud in US feet; NaN
as nodata). ``EXCHANGE_CASES``: imports, whose checks another task of issue 39 owns, reported by
``bench/eval_bad_input.py`` (which runs the whole corpus and classifies every case) and not asserted here.
Each case copies only the workspace folders it names (as hard links, but for the files its setup names: the
``linked_copy`` fixture fails a case that wrote into a linked file), runs under a time limit (a hang fails the
case), and compares the tree before and after by size, time and inode.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------------------------
# The workspace (built once per module)


def _cli(prog: str):
    if prog == "aerotri":
        from aerotri.cli import main
    elif prog == "lidarctl":
        from lidarctl.cli.main import main
    else:
        from ortho.cli import main
    return main


def _ok(prog, *args):
    r = CliRunner().invoke(_cli(prog), [str(a) for a in args], catch_exceptions=False)
    assert r.exit_code == 0, f"{prog} {' '.join(map(str, args))}: {r.output}"
    return r


@pytest.fixture(scope="module")
def workspace(tiny_project, build_once) -> Path:
    # read-only (every case copies what it needs): built once per run, shared by the xdist workers
    return build_once("badinput", lambda w: build_workspace(tiny_project, w))


def build_workspace(tiny_project: Path, w: Path) -> Path:
    """``w/p``: the tiny project with every stage's outputs; ``w/las``: small LAS/LAZ and point lists."""
    from aerotri.sim.evaluate import write_truth_corners_csv

    p = w / "p"
    p.mkdir(parents=True)
    shutil.copytree(tiny_project / "images", p / "images")
    for name in ("camera.toml", "project.toml", "gnss.txt"):
        shutil.copy(tiny_project / name, p / name)
    (p / "truth").mkdir()
    for name in ("eo.txt", "camera.toml", "dem.tif", "dsm.tif", "ortho.tif", "checkpoints.csv", "roof_corners.csv",
                 "buildings.geojson", "truth.json"):
        shutil.copy(tiny_project / "truth" / name, p / "truth" / name)
    (p / "lidar_out").mkdir()
    shutil.copy(p / "truth" / "dem.tif", p / "lidar_out" / "dem.tif")
    with rasterio.open(p / "truth" / "dem.tif") as a, rasterio.open(p / "truth" / "dsm.tif") as b:
        nd = (b.read(1, masked=True) - a.read(1, masked=True)).filled(-9999).astype(np.float32)
        prof = dict(a.profile, dtype="float32", nodata=-9999)
    with rasterio.open(p / "lidar_out" / "ndsm.tif", "w", **prof) as dst:
        dst.write(nd, 1)
    write_truth_corners_csv(p, p / "lidar_out" / "corners.csv")
    _ok("aerotri", "match", p)
    _ok("aerotri", "control", p, "--eo", p / "truth" / "eo.txt", "--camera", p / "truth" / "camera.toml",
        "--min-frames", "2")
    _ok("aerotri", "adjust", p, "--gnss-correction", "shift", "--self-cal", "pp,radial", "--no-html")
    _ok("ortho", "rectify", p)
    _ok("ortho", "mosaic", p)
    _ok("ortho", "check", p, "--reference", p / "truth" / "ortho.tif", "--patch-px", "24", "--search-px", "4")
    _ok("aerotri", "report", p, "--no-pdf")
    shutil.rmtree(p / "work")  # caches: a failing command must not need them
    _lidar_files(w / "las")
    _lidar_products(w / "lid", w / "las")
    return w


def _lidar_files(d: Path) -> None:
    from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7, simulate_spatial, write_common_points
    from lidarctl import synthetic

    d.mkdir(parents=True)
    cloud, truth = synthetic.synthetic_scene(width_m=60.0, density_per_m2=2.0, n_buildings=1, n_trees=4,
                                             n_low_outliers=5, n_high_outliers=2, seed=3)
    synthetic.write_las(d / "cloud.las", cloud, classification=truth, crs="EPSG:32632")
    synthetic.write_las(d / "cloud.laz", cloud, classification=truth, crs="EPSG:32632")
    synthetic.write_las(d / "raw.las", cloud, crs="EPSG:32632")
    synthetic.write_las(d / "nocrs.las", cloud, classification=truth, version="1.2")
    rng = np.random.default_rng(0)
    px, py = cloud.x.min() + rng.uniform(5, 55, 8), cloud.y.min() + rng.uniform(5, 55, 8)
    pz = synthetic.terrain_height(px - 500000.0, py - 5400000.0)
    (d / "points.csv").write_text("id,x,y,z\n" + "".join(f"P{k},{a:.3f},{b:.3f},{c:.3f}\n"
                                                          for k, (a, b, c) in enumerate(zip(px, py, pz))))
    lon, lat, h = rng.uniform(109.6, 110.2, 8), rng.uniform(34.0, 34.5, 8), rng.uniform(400, 900, 8)
    src, dst, _ = simulate_spatial(TRUE_BURSA_WOLF7, 32649, 2361, lon_deg=lon, lat_deg=lat, h_m=h, noise_m=0.01, seed=2)
    write_common_points(d / "common.csv", [f"C{i}" for i in range(8)], src, dst)
    x, y = src[:, 0], src[:, 1]
    (d / "heights.csv").write_text("id,x,y,h,H\n" + "".join(f"H{i},{x[i]:.3f},{y[i]:.3f},{h[i]:.3f},{h[i] + 27.1:.3f}\n"
                                                            for i in range(8)))
    (d / "pts.csv").write_text("id,x,y,z\n" + "".join(f"Q{i},{x[i]:.3f},{y[i]:.3f},{h[i]:.3f}\n" for i in range(8)))


def _lidar_products(d: Path, las: Path) -> None:
    """``d``: a classified cloud with a flat-roofed building (``bldg.las``), two overlapping strips of
    ``las/cloud.las`` (``strip_1.las``, ``strip_2.las``, point source ids 1 and 2) with a trajectory
    (``traj.txt``), the rasters of ``cloud.las`` (``r/dem.tif`` ...), an RGB orthophoto over it (``rgb.tif``),
    the line map of ``bldg.las`` (``v.gpkg``) and its roof corners (``c/``)."""
    import importlib.util

    import laspy
    from shapely import affinity
    from shapely.geometry import box

    from lidarctl import synthetic

    d.mkdir(parents=True)
    spec = importlib.util.spec_from_file_location("corners_synth", REPO / "tests" / "lidarctl" / "corners_synth.py")
    synth = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(synth)
    roof = affinity.rotate(box(19.0, 23.5, 41.0, 36.5), 0.0)
    x, y, z, cls, _ = synth.make_cloud([(roof, "flat", 9.0, 0.0, 0.0)], extent=(0.0, 60.0, 0.0, 60.0), seed=4)
    n = len(x)
    cloud = synthetic.PointCloud(x=x + 500000.0, y=y + 5400000.0, z=z + 100.0, intensity=np.full(n, 300, np.uint16),
                                 return_number=np.ones(n, np.uint8), number_of_returns=np.ones(n, np.uint8),
                                 classification=np.zeros(n, np.uint8))
    synthetic.write_las(d / "bldg.las", cloud, classification=cls.astype(np.uint8), crs="EPSG:32632")
    src = laspy.read(las / "cloud.las")
    u = src.x - src.x.min()
    for k, (lo, hi) in enumerate([(-1.0, 40.0), (20.0, 61.0)]):
        m = (u >= lo) & (u < hi)
        strip = laspy.LasData(src.header)
        strip.points = src.points[m].copy()
        strip.point_source_id = np.full(int(m.sum()), k + 1, np.uint16)
        strip.gps_time = 1000.0 * k + np.linspace(0.0, 100.0, int(m.sum()))
        strip.write(str(d / f"strip_{k + 1}.las"))
    t = np.arange(-10.0, 1200.0, 1.0)
    (d / "traj.txt").write_text("# time_s x y z roll_deg pitch_deg heading_deg\n" + "".join(
        f"{a:.3f} {500000.0 + 0.05 * a:.3f} {5400030.0:.3f} 600.000 0.0 0.0 90.0\n" for a in t))
    _ok("lidarctl", "rasters", las / "cloud.las", d / "r", "--res-m", "1")
    with rasterio.open(d / "r" / "dem.tif") as dem:
        prof = dict(dem.profile, count=3, dtype="uint8", nodata=None, width=dem.width * 2, height=dem.height * 2,
                    transform=dem.transform @ rasterio.transform.Affine.scale(0.5))
    rgb = np.random.default_rng(1).integers(60, 200, (3, prof["height"], prof["width"]), dtype=np.uint8)
    with rasterio.open(d / "rgb.tif", "w", **prof) as dst:
        dst.write(rgb)
    _ok("lidarctl", "vectors", d / "bldg.las", d / "v.gpkg")
    _ok("lidarctl", "corners", d / "bldg.las", d / "c", "--no-figure")


# ----------------------------------------------------------------------------------------------
# How to break things (each returns a setup function of the case's workspace)


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def utf16(rel):
    def f(w):
        q = w / rel
        q.write_bytes(_text(q).encode("utf-16"))
    return f


def binary(rel):
    def f(w):
        (w / rel).write_bytes(bytes(np.random.default_rng(5).integers(0, 256, 4096, dtype=np.uint8)))
    return f


def as_dir(rel):
    def f(w):
        q = w / rel
        if q.is_dir():
            shutil.rmtree(q)
        elif q.exists():
            q.unlink()
        q.mkdir(parents=True)
        (q / "x.txt").write_text("a folder, not a file\n")
    return f


def remove(*rels):
    def f(w):
        for rel in rels:
            q = w / rel
            if q.is_dir():
                shutil.rmtree(q)
            elif q.exists():
                q.unlink()
    return f


def write(rel, text):
    def f(w):
        (w / rel).parent.mkdir(parents=True, exist_ok=True)
        (w / rel).write_text(text.format(w=w))
    return f


def empty(rel):
    return write(rel, "")


def line(rel, lineno, fn):
    """Replace line ``lineno`` (1-based) with ``fn(fields of a comma or whitespace split line) -> line``."""
    def f(w):
        q = w / rel
        lines = _text(q).splitlines()
        s = lines[lineno - 1]
        sep = "," if "," in s else " "
        lines[lineno - 1] = fn(s.split(sep)) if callable(fn) else fn
        if callable(fn) and not isinstance(lines[lineno - 1], str):
            lines[lineno - 1] = sep.join(lines[lineno - 1])
        q.write_text("\n".join(lines) + "\n")
    return f


def field(rel, lineno, k, value):
    def fn(parts):
        parts = list(parts)
        parts[k] = value
        return parts
    return line(rel, lineno, fn)


def swap_fields(rel, a, b):
    """Swap two fields on every data line (e.g. X and Y of gnss.txt)."""
    def f(w):
        q = w / rel
        out = []
        for s in _text(q).splitlines():
            sep = "," if "," in s else " "
            parts = s.split(sep)
            if s.startswith("#") or not s.strip() or not all(_is_number(parts[k]) for k in (a, b)):
                out.append(s)
                continue
            parts[a], parts[b] = parts[b], parts[a]
            out.append(sep.join(parts))
        q.write_text("\n".join(out) + "\n")
    return f


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def duplicate_line(rel, lineno):
    def f(w):
        q = w / rel
        lines = _text(q).splitlines()
        lines.insert(lineno, lines[lineno - 1])
        q.write_text("\n".join(lines) + "\n")
    return f


def keep_lines(rel, n):
    def f(w):
        q = w / rel
        q.write_text("\n".join(_text(q).splitlines()[:n]) + "\n")
    return f


def toml_set(rel, section, key, value):
    """Set ``key = value`` (TOML text) in ``[section]`` of a TOML file (``section`` None: top level)."""
    def f(w):
        q = w / rel
        lines = _text(q).splitlines()
        start = 0
        if section is not None:
            start = next((i + 1 for i, s in enumerate(lines) if s.strip() == f"[{section}]"), None)
            if start is None:
                lines += ["", f"[{section}]"]
                start = len(lines)
        end = next((i for i in range(start, len(lines)) if lines[i].startswith("[")), len(lines))
        for i in range(start, end):
            if lines[i].split("=")[0].strip() == key:
                lines[i] = f"{key} = {value}"
                break
        else:
            lines.insert(end, f"{key} = {value}")
        q.write_text("\n".join(lines) + "\n")
    return f


def remove_key(rel, key):
    def f(w):
        q = w / rel
        q.write_text("\n".join(s for s in _text(q).splitlines() if s.split("=")[0].strip() != key) + "\n")
    return f


def truncate(rel, fraction=0.6):
    def f(w):
        q = w / rel
        q.write_bytes(q.read_bytes()[: int(q.stat().st_size * fraction)])
    return f


def _cut_in_its_header(images, out, name):
    """A copy of the frames with ``name`` rewritten as GDAL writes a tiled TIFF (its IFD first, as the Tuniu frames
    have it) and cut at 2,000 bytes, inside the tags a camera's EXIF would follow: the file still opens."""
    import rasterio
    from rasterio.shutil import copy as rio_copy

    shutil.copytree(images, out)
    q = out / name
    rio_copy(images / name, q, driver="GTiff", tiled=True, blockxsize=256, blockysize=256)
    q.write_bytes(q.read_bytes()[:2000])
    with rasterio.open(q):  # the case is a file that opens
        pass


def _jpeg_frames_one_cut(images, out, name):
    """The frames as JPEG (OpenCV), ``name``'s cut at 38 % of its bytes (kite trial: a copy that stopped)."""
    import cv2

    out.mkdir()
    for tif in sorted(images.glob("*.tif")):
        cv2.imwrite(str(out / (tif.stem + ".jpg")), cv2.imread(str(tif), cv2.IMREAD_COLOR))
    q = out / name
    q.write_bytes(q.read_bytes()[: int(q.stat().st_size * 0.38)])


def patch_bytes(rel, offset, data):
    def f(w):
        q = w / rel
        b = bytearray(q.read_bytes())
        b[offset:offset + len(data)] = data
        q.write_bytes(bytes(b))
    return f


def las_point_count(rel, delta):
    """Header point count ``delta`` off the records in the file (legacy and LAS 1.4 counts)."""
    def f(w):
        q = w / rel
        b = bytearray(q.read_bytes())
        n = struct.unpack_from("<Q", b, 247)[0]
        struct.pack_into("<Q", b, 247, n + delta)
        if struct.unpack_from("<I", b, 107)[0]:
            struct.pack_into("<I", b, 107, n + delta)
        q.write_bytes(bytes(b))
    return f


def image(rel, how):
    """Rewrite an image: ``black`` (all zeros, same size), ``small`` (half size)."""
    def f(w):
        q = w / rel
        with rasterio.open(q) as ds:
            a, prof = ds.read(), ds.profile
        if how == "black":
            a[:] = 0
        else:
            a = np.ascontiguousarray(a[:, ::2, ::2])
            prof.update(width=a.shape[2], height=a.shape[1])
            prof.pop("blockxsize", None)
            prof.pop("blockysize", None)
            prof["tiled"] = False
        with rasterio.open(q, "w", **prof) as dst:
            dst.write(a)
    return f


def raster_crs(rel, crs):
    def f(w):
        with rasterio.open(w / rel, "r+") as ds:
            ds.crs = rasterio.crs.CRS.from_user_input(crs)
    return f


def dem_part(rel):
    """Keep only the southern third of a DEM (the northern frames are not covered)."""
    def f(w):
        q = w / rel
        with rasterio.open(q) as ds:
            a, prof, t = ds.read(1), ds.profile, ds.transform
        keep = a[2 * a.shape[0] // 3:]
        prof.update(height=keep.shape[0], transform=rasterio.transform.Affine(
            t.a, t.b, t.c, t.d, t.e, t.f + t.e * (a.shape[0] - keep.shape[0])))
        q.unlink()
        with rasterio.open(q, "w", **prof) as dst:
            dst.write(keep, 1)
    return f


def dem_as_rgb(rel):
    """The DEM replaced by a 3-band 8-bit image on the same grid (an orthophoto given as the DEM)."""
    def f(w):
        q = w / rel
        with rasterio.open(q) as ds:
            prof = ds.profile
        prof.update(count=3, dtype="uint8", nodata=None)
        q.unlink()
        with rasterio.open(q, "w", **prof) as dst:
            dst.write(np.full((3, prof["height"], prof["width"]), 100, np.uint8))
    return f


def copy(src_rel, dst_rel):
    def f(w):
        shutil.copy(w / src_rel, w / dst_rel)
    return f


def manual(x="{x}", y="{y}", extra=""):
    """``w/manual.csv`` from the first accepted control measurement, with x/y replaced; ``extra`` lines may
    use {pid} (its point id)."""
    def f(w):
        first = _text(w / "p/control/image_points.csv").splitlines()[1].split(",")
        text = ("point_id,image_id,x_px,y_px\n" + f"{first[0]},{first[1]},{x},{y}\n".format(x=first[2], y=first[3])
                + extra.format(pid=first[0]))
        (w / "manual.csv").write_text(text)
    return f


def readjusted(rel, dx_m=0.5):
    """An EO file as a new adjustment leaves it: the first frame moved by ``dx_m`` in X."""
    def f(w):
        from aerotri.geom.eo import read_eo, write_eo

        eo = read_eo(w / rel)
        eo.centre_m[0, 0] += dx_m
        write_eo(w / rel, eo)
    return f


def all_of(*fs):
    def f(w):
        for g in fs:
            g(w)
    return f


def _write_raster(q: Path, a: np.ndarray, prof: dict) -> None:
    """``a`` (bands, rows, cols) as a plain GeoTIFF at ``q`` with ``prof``'s grid, CRS and nodata."""
    prof = {k: v for k, v in prof.items() if k in ("crs", "transform", "nodata")}
    q.unlink()
    with rasterio.open(q, "w", driver="GTiff", count=a.shape[0], height=a.shape[1], width=a.shape[2],
                       dtype=a.dtype.name, **prof) as dst:
        dst.write(a)


def raster(rel, how):
    """Rewrite a raster in place. ``how``: ``1x1``, ``1row``, ``1col`` (that window from its centre, on the
    same grid); ``inf``, ``-inf`` (one cell); ``nodata`` (every cell nodata); ``nan`` (every cell NaN, no
    nodata value); ``float_min`` (a GDAL float32 nodata value in a third of the cells, not declared as nodata);
    ``no_crs``; ``EPSG:nnnn`` (tagged with another CRS, same numbers); ``us-ft`` (the same surface in the
    CRS's US-foot twin: coordinates and heights in feet); ``degrees`` (reprojected to longitude/latitude);
    ``two_bands`` (the heights twice); ``rgb`` (a 3-band 8-bit image on the same grid); ``rotated`` (the grid
    turned by 10 degrees about its corner)."""
    def f(w):
        q = w / rel
        with rasterio.open(q) as ds:
            a, prof = ds.read(), dict(ds.profile)
        t = prof["transform"]
        if how in ("1x1", "1row", "1col"):
            rows = 1 if how in ("1x1", "1row") else a.shape[1]
            cols = 1 if how in ("1x1", "1col") else a.shape[2]
            r0 = a.shape[1] // 2 if rows == 1 else 0
            c0 = a.shape[2] // 2 if cols == 1 else 0
            a = np.ascontiguousarray(a[:, r0:r0 + rows, c0:c0 + cols])
            prof["transform"] = t @ rasterio.transform.Affine.translation(c0, r0)
        elif how in ("inf", "-inf"):
            a[0, a.shape[1] // 3, a.shape[2] // 3] = float(how)
        elif how == "nodata":
            prof["nodata"] = -9999.0 if prof.get("nodata") is None else prof["nodata"]
            a[:] = prof["nodata"]
        elif how == "nan":
            a = a.astype(np.float32)
            a[:] = np.nan
            prof["nodata"] = None
        elif how == "float_min":
            a = a.astype(np.float32)
            a[:, : a.shape[1] // 3] = np.finfo(np.float32).min
            prof["nodata"] = None
        elif how == "no_crs":
            prof["crs"] = None
        elif how == "rotated":
            prof["transform"] = t * rasterio.transform.Affine.rotation(10.0)
        elif how.startswith("EPSG:"):
            prof["crs"] = rasterio.crs.CRS.from_user_input(how)
        elif how == "us-ft":
            from pyproj import CRS

            ft = 1200.0 / 3937.0
            zone = CRS(prof["crs"].to_wkt()).utm_zone  # the rasters here are in UTM zones, e.g. "49N"
            prof["crs"] = rasterio.crs.CRS.from_proj4(f"+proj=utm +zone={zone[:-1]}{' +south' if zone[-1] == 'S' else ''} "
                                                      "+datum=WGS84 +units=us-ft +no_defs")
            prof["transform"] = rasterio.transform.Affine(t.a / ft, 0.0, t.c / ft, 0.0, t.e / ft, t.f / ft)
            nd = prof.get("nodata")
            a = np.where(a == nd, a, a / ft).astype(a.dtype) if nd is not None else (a / ft).astype(a.dtype)
        elif how == "degrees":
            from rasterio.warp import calculate_default_transform, reproject

            dst_crs = rasterio.crs.CRS.from_epsg(4326)
            tr, width, height = calculate_default_transform(prof["crs"], dst_crs, a.shape[2], a.shape[1],
                                                            *rasterio.transform.array_bounds(a.shape[1], a.shape[2], t))
            out = np.full((a.shape[0], height, width), prof.get("nodata") or 0, a.dtype)
            reproject(a, out, src_transform=t, src_crs=prof["crs"], dst_transform=tr, dst_crs=dst_crs,
                      src_nodata=prof.get("nodata"), dst_nodata=prof.get("nodata"))
            a = out
            prof.update(crs=dst_crs, transform=tr)
        elif how == "two_bands":
            a = np.concatenate([a[:1], a[:1]])
        elif how == "rgb":
            a = np.full((3, a.shape[1], a.shape[2]), 100, np.uint8)
            prof["nodata"] = None
        else:
            raise ValueError(how)
        _write_raster(q, a, prof)
    return f


def las_edit(rel, how, src=None):
    """Rewrite a LAS file: ``empty`` (a valid header, no points), ``one_point``, ``same_xy`` (every point at
    one x, y), ``crs:EPSG:nnnn`` (tagged with another CRS, same numbers), ``copy`` (a byte copy of ``src``)."""
    def f(w):
        import laspy

        q = w / rel
        if how == "copy":
            shutil.copy(w / src, q)
            return
        las = laspy.read(str(q))
        if how in ("empty", "one_point"):
            las.points = las.points[: 0 if how == "empty" else 1].copy()
        elif how == "same_xy":
            las.x = np.full(len(las.x), float(las.x[0]))
            las.y = np.full(len(las.y), float(las.y[0]))
        elif how.startswith("crs:"):
            import pyproj

            las.header.vlrs = laspy.vlrs.vlrlist.VLRList([v for v in las.header.vlrs if "Projection" not in type(v).__name__
                                                          and "Wkt" not in type(v).__name__ and "GeoKey" not in type(v).__name__
                                                          and "GeoDouble" not in type(v).__name__
                                                          and "GeoAscii" not in type(v).__name__])
            las.header.add_crs(pyproj.CRS.from_user_input(how[4:]))
        else:
            raise ValueError(how)
        las.write(str(q))
    return f


def table(rel, how):
    """Rewrite a CSV/TXT table: ``header_only`` (the comment/header lines kept, no record), ``blank`` (white
    space only), ``inf`` (the first number of the first record as inf), ``text`` (the second number of the
    second record as 'abc'), ``columns`` (the last field of the third record dropped)."""
    def f(w):
        q = w / rel
        lines = _text(q).splitlines()
        head = 0
        while head < len(lines) and (lines[head].startswith("#") or not _is_number(_fields(lines[head])[-1])):
            head += 1
        if how == "header_only":
            q.write_text("\n".join(lines[:head]) + "\n")
            return
        if how == "blank":
            q.write_text("\n   \n\n")
            return
        k = {"inf": head, "text": head + 1, "columns": head + 2}[how]
        parts, sep = _fields(lines[k]), ("," if "," in lines[k] else " ")
        nums = [i for i, v in enumerate(parts) if _is_number(v)]
        if how == "inf":
            parts[nums[0]] = "inf"
        elif how == "text":
            parts[nums[1]] = "abc"
        else:
            parts = parts[:-1]
        lines[k] = sep.join(parts)
        q.write_text("\n".join(lines) + "\n")
    return f


def json_set(rel, keys, value):
    """Set ``value`` at ``keys`` (a path of keys and list indices) of a JSON file."""
    def f(w):
        q = w / rel
        d = json.loads(_text(q))
        o = d
        for k in keys[:-1]:
            o = o[k]
        o[keys[-1]] = value
        q.write_text(json.dumps(d))
    return f


def _fields(s: str) -> list:
    return s.split(",") if "," in s else s.split()


def shift_xy(rel, cols, dx):
    """Every record's x (field ``cols[0]``) moved by ``dx`` (a place elsewhere whose numbers still fit the CRS)."""
    def f(w):
        q = w / rel
        out = []
        for s in _text(q).splitlines():
            parts = _fields(s)
            if s.startswith("#") or len(parts) <= max(cols) or not all(_is_number(parts[k]) for k in cols):
                out.append(s)
                continue
            parts[cols[0]] = f"{float(parts[cols[0]]) + dx:.3f}"
            out.append(("," if "," in s else " ").join(parts))
        q.write_text("\n".join(out) + "\n")
    return f


def other_zone(rel, cols, src=32649, dst=32650):
    """The x, y of every record (fields ``cols``) as the same places in another UTM zone's numbers (the file
    still claims the project's zone: a file from a neighbouring sheet)."""
    def f(w):
        from pyproj import Transformer

        tr = Transformer.from_crs(src, dst, always_xy=True)
        q = w / rel
        out = []
        for s in _text(q).splitlines():
            parts = _fields(s)
            if s.startswith("#") or len(parts) <= max(cols) or not all(_is_number(parts[k]) for k in cols):
                out.append(s)
                continue
            x, y = tr.transform(float(parts[cols[0]]), float(parts[cols[1]]))
            parts[cols[0]], parts[cols[1]] = f"{x:.3f}", f"{y:.3f}"
            out.append(("," if "," in s else " ").join(parts))
        q.write_text("\n".join(out) + "\n")
    return f


# ----------------------------------------------------------------------------------------------
# The corpus


@dataclasses.dataclass(frozen=True)
class Case:
    id: str
    prog: str  # aerotri | lidarctl | ortho
    args: tuple  # formatted with w (workspace) and p (project)
    expect: tuple  # substrings of the error line (formatted likewise)
    setup: Callable | None = None
    caches: tuple = ()  # folders (workspace-relative) where caches may appear: they are not outputs


def C(id, prog, args, expect, setup=None, caches=()):
    """``args``: the command line split at white space, or a list (an argument with spaces: a PROJ string)."""
    return Case(id, prog, tuple(args.split()) if isinstance(args, str) else tuple(args),
                tuple(expect) if isinstance(expect, (list, tuple)) else (expect,), setup, caches)


CASES = [
    # --- aerotri init and settings
    C("init_images_missing", "aerotri", "init {w}/new --images {w}/nope --crs EPSG:32649", "nope"),
    C("init_images_empty", "aerotri", "init {w}/new --images {w}/empty --crs EPSG:32649", ["empty", "no images"],
      lambda w: (w / "empty").mkdir()),
    C("init_images_a_dsm", "aerotri", "init {w}/new --images {w}/dsm --crs EPSG:32649", ["dsm.tif", "not a camera frame"],
      lambda w: ((w / "dsm").mkdir(), shutil.copy(w / "p/truth/dsm.tif", w / "dsm/dsm.tif"))),
    # a frame cut inside its header opens, its tags gone: named as cut short, not as "no camera in the EXIF"
    C("init_image_cut_in_its_header", "aerotri", "init {w}/new --images {w}/cut --crs EPSG:32649",
      ["s01_002.tif", "truncated", "2,000 bytes"],
      lambda w: _cut_in_its_header(w / "p/images", w / "cut", "s01_002.tif")),
    C("init_jpeg_cut_short", "aerotri", "init {w}/new --images {w}/jpg --crs EPSG:32649",
      ["s01_002.jpg", "truncated", "end-of-image marker"],
      lambda w: _jpeg_frames_one_cut(w / "p/images", w / "jpg", "s01_002.jpg")),
    C("init_crs_geographic", "aerotri", "init {w}/new --images {p}/images --crs EPSG:4326", "--crs"),
    C("init_crs_unknown", "aerotri", "init {w}/new --images {p}/images --crs EPSG:999999", "--crs"),
    C("init_into_a_project", "aerotri", "init {p} --images {p}/images --crs EPSG:32649", ["exists", "not an empty"]),
    C("init_camera_wrong_size", "aerotri", "init {w}/new --images {p}/images --crs EPSG:32649 --camera {w}/cam.toml",
      "cam.toml", lambda w: (w / "cam.toml").write_text(_text(w / "p/camera.toml").replace("width = 432", "width = 400"))),
    C("settings_not_a_project", "aerotri", "settings {w}/nope", "nope"),
    C("settings_unknown_key", "aerotri", "settings {p}", ["project.toml", "nosuch"],
      toml_set("p/project.toml", "adjust", "nosuch", "1")),
    C("settings_bad_value", "aerotri", "settings {p}", ["project.toml", "image_sigma_px"],
      toml_set("p/project.toml", "adjust", "image_sigma_px", '"abc"')),

    # --- aerotri sim
    C("sim_unknown_preset", "aerotri", "sim --preset nosuch {w}/out", "nosuch"),
    C("sim_preset_bad_toml", "aerotri", "sim --preset {w}/bad.toml {w}/out", "bad.toml", write("bad.toml", "[preset\n")),
    C("sim_set_not_a_number", "aerotri", "sim --preset tiny --set flight.strips=abc {w}/out", "flight.strips"),
    C("sim_set_unknown_key", "aerotri", "sim --preset tiny --set flight.nosuch=1 {w}/out", "flight.nosuch"),
    C("sim_set_zero_strips", "aerotri", "sim --preset tiny --set flight.strips=0 {w}/out", "strips"),
    C("sim_blunder_fraction", "aerotri", "sim --preset tiny --blunder-fraction 2 {w}/out", "--blunder-fraction"),
    C("sim_outdir_is_file", "aerotri", "sim --preset tiny {w}/out", "out", write("out", "a file\n")),

    # --- aerotri match
    C("match_gnss_utf16", "aerotri", "match {p}", "gnss.txt", utf16("p/gnss.txt")),
    C("match_gnss_binary", "aerotri", "match {p}", "gnss.txt", binary("p/gnss.txt")),
    C("match_gnss_directory", "aerotri", "match {p}", "gnss.txt", as_dir("p/gnss.txt")),
    C("match_gnss_empty", "aerotri", "match {p}", "gnss.txt", empty("p/gnss.txt")),
    C("match_gnss_xy_swapped", "aerotri", "match {p}", "gnss.txt", swap_fields("p/gnss.txt", 1, 2)),
    C("match_gnss_nan", "aerotri", "match {p}", "gnss.txt:3", field("p/gnss.txt", 3, 2, "nan")),
    C("match_gnss_duplicate_id", "aerotri", "match {p}", "gnss.txt:4", duplicate_line("p/gnss.txt", 3)),
    C("match_gnss_wrong_field_count", "aerotri", "match {p}", "gnss.txt:2", field("p/gnss.txt", 2, 3, "1 2")),
    C("match_gnss_not_a_number", "aerotri", "match {p}", "gnss.txt:5", field("p/gnss.txt", 5, 1, "45x")),
    C("match_gnss_frame_missing", "aerotri", "match {p}", ["gnss.txt", "s02_003"], keep_lines("p/gnss.txt", 6)),
    C("match_gnss_zero_sigma", "aerotri", "match {p}", "gnss.txt:2", field("p/gnss.txt", 2, 4, "0")),
    C("match_camera_missing", "aerotri", "match {p}", "camera.toml", remove("p/camera.toml")),
    C("match_camera_bad_toml", "aerotri", "match {p}", "camera.toml", write("p/camera.toml", "focal_mm = = 1\n")),
    C("match_camera_bad_type", "aerotri", "match {p}", ["camera.toml", "focal_mm"],
      toml_set("p/camera.toml", None, "focal_mm", '"120"')),
    C("match_camera_unknown_key", "aerotri", "match {p}", ["camera.toml", "focus_mm"],
      toml_set("p/camera.toml", None, "focus_mm", "120.0")),
    C("match_camera_nan", "aerotri", "match {p}", ["camera.toml", "k1"], toml_set("p/camera.toml", None, "k1", "nan")),
    C("match_camera_size_mismatch", "aerotri", "match {p}", ["s01_001.tif", "864"],
      toml_set("p/camera.toml", None, "width", "864")),
    C("match_camera_utf16", "aerotri", "match {p}", "camera.toml", utf16("p/camera.toml")),
    # (found while extracting features: the features of the frames before it are cached in work/, not outputs)
    C("match_image_all_black", "aerotri", "match {p}", "s01_002.tif", image("p/images/s01_002.tif", "black"),
      caches=("p/work/",)),
    C("match_image_truncated", "aerotri", "match {p}", "s01_002.tif", truncate("p/images/s01_002.tif", 0.3),
      caches=("p/work/",)),
    C("match_image_wrong_size", "aerotri", "match {p}", "s02_001.tif", image("p/images/s02_001.tif", "small")),
    C("match_image_directory", "aerotri", "match {p}", "s01_003.tif", as_dir("p/images/s01_003.tif")),
    C("match_image_missing", "aerotri", "match {p}", ["gnss.txt", "s01_003"], remove("p/images/s01_003.tif")),
    C("match_no_images", "aerotri", "match {p}", "images", all_of(remove("p/images"), as_dir("p/images"))),
    C("match_single_image", "aerotri", "match {p}", "images",
      all_of(remove(*[f"p/images/s0{s}_00{i}.tif" for s in (1, 2) for i in (1, 2, 3) if (s, i) != (1, 1)]),
             keep_lines("p/gnss.txt", 2))),
    C("match_project_toml_missing", "aerotri", "match {p}", "project.toml", remove("p/project.toml")),
    C("match_project_toml_bad", "aerotri", "match {p}", "project.toml", write("p/project.toml", "[project\n")),
    C("match_project_toml_utf16", "aerotri", "match {p}", "project.toml", utf16("p/project.toml")),
    C("match_project_crs_unknown", "aerotri", "match {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:999999"')),
    C("match_project_crs_geographic", "aerotri", "match {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:4326"')),
    C("match_project_crs_mismatched", "aerotri", "match {p}", "gnss.txt",
      toml_set("p/project.toml", "project", "crs", '"EPSG:4526"')),
    C("match_lever_arm_nan", "aerotri", "match {p}", ["project.toml", "lever_arm_m"],
      toml_set("p/project.toml", "gnss", "lever_arm_m", "[nan, 0.0, 1.45]")),
    C("match_lever_arm_length", "aerotri", "match {p}", ["project.toml", "lever_arm_m"],
      toml_set("p/project.toml", "gnss", "lever_arm_m", "[0.0, 1.45]")),
    C("match_terrain_height_string", "aerotri", "match {p}", ["project.toml", "mean_terrain_height_m"],
      toml_set("p/project.toml", "flight", "mean_terrain_height_m", '"high"')),
    C("match_terrain_height_option_nan", "aerotri", "match {p} --terrain-height-m nan", "--terrain-height-m"),
    C("match_budget_zero", "aerotri", "match {p} --budget 0", "--budget"),
    C("match_max_dim_zero", "aerotri", "match {p} --max-dim-px 0", "--max-dim-px"),
    C("match_ratio_above_one", "aerotri", "match {p} --ratio 1.5", "--ratio"),
    C("match_min_overlap_negative", "aerotri", "match {p} --min-overlap -0.2", "--min-overlap"),
    C("match_project_is_file", "aerotri", "match {w}/p/gnss.txt", "gnss.txt"),

    # --- aerotri adjust
    C("adjust_alpha_5", "aerotri", "adjust {p} --alpha 5", "--alpha"),
    C("adjust_alpha_0", "aerotri", "adjust {p} --alpha 0", "--alpha"),
    C("adjust_image_sigma_0", "aerotri", "adjust {p} --image-sigma-px 0", "--image-sigma-px"),
    C("adjust_image_sigma_negative", "aerotri", "adjust {p} --image-sigma-px -0.5", "--image-sigma-px"),
    C("adjust_image_sigma_toml_0", "aerotri", "adjust {p}", ["project.toml", "image_sigma_px"],
      toml_set("p/project.toml", "adjust", "image_sigma_px", "0")),
    C("adjust_image_sigma_toml_string", "aerotri", "adjust {p}", ["project.toml", "image_sigma_px"],
      toml_set("p/project.toml", "adjust", "image_sigma_px", '"half"')),
    C("adjust_lever_arm_toml_nan", "aerotri", "adjust {p}", ["project.toml", "lever_arm_m"],
      toml_set("p/project.toml", "gnss", "lever_arm_m", "[0.05, nan, 1.45]")),
    C("adjust_lever_arm_toml_strings", "aerotri", "adjust {p}", ["project.toml", "lever_arm_m"],
      toml_set("p/project.toml", "gnss", "lever_arm_m", '["a", "b", "c"]')),
    C("adjust_lever_arm_option_nan", "aerotri", "adjust {p} --lever-arm-m nan 0 1", "--lever-arm-m"),
    # trial-at: a lever arm in millimetres put the camera 1.45 km below its antenna (a numpy traceback), as did
    # gnss.txt heights of the ground
    C("adjust_lever_arm_toml_millimetres", "aerotri", "adjust {p}", ["project.toml", "lever_arm_m = 50.0: out of range"],
      toml_set("p/project.toml", "gnss", "lever_arm_m", "[50.0, -120.0, 1450.0]")),
    C("adjust_lever_arm_option_millimetres", "aerotri", "adjust {p} --lever-arm-m 0 0 1450", "--lever-arm-m"),
    C("adjust_gnss_heights_of_the_ground", "aerotri", "adjust {p}",
      ["gnss.txt", "expected each frame above the control"],
      lambda w: (w / "p/gnss.txt").write_text("\n".join(
          s if s.startswith("#") else " ".join(f if k != 3 else "0.0" for k, f in enumerate(s.split()))
          for s in _text(w / "p/gnss.txt").splitlines()) + "\n")),
    C("adjust_gnss_sigma_toml_zero", "aerotri", "adjust {p}", ["project.toml", "sigma_xy_m"],
      all_of(toml_set("p/project.toml", "gnss", "sigma_xy_m", "0.0"),
             lambda w: (w / "p/gnss.txt").write_text("\n".join(" ".join(s.split()[:4]) for s in _text(w / "p/gnss.txt").splitlines()) + "\n"))),
    C("adjust_project_toml_unknown_key", "aerotri", "adjust {p}", ["project.toml", "lever_arm"],
      all_of(remove_key("p/project.toml", "lever_arm_m"), toml_set("p/project.toml", "gnss", "lever_arm", "[0.05, -0.12, 1.45]"))),
    C("adjust_control_sigma_toml_string", "aerotri", "adjust {p}", ["project.toml", "control"],
      toml_set("p/project.toml", "control", "sigma_xy_m", '"ten"')),
    C("adjust_project_crs_geographic", "aerotri", "adjust {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:4326"')),
    C("adjust_project_crs_unknown", "aerotri", "adjust {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:999999"')),
    C("adjust_before_match", "aerotri", "adjust {p}", "tiepoints.csv", remove("p/at/tiepoints.csv")),
    C("adjust_tiepoints_utf16", "aerotri", "adjust {p}", "tiepoints.csv", utf16("p/at/tiepoints.csv")),
    C("adjust_tiepoints_binary", "aerotri", "adjust {p}", "tiepoints.csv", binary("p/at/tiepoints.csv")),
    C("adjust_tiepoints_directory", "aerotri", "adjust {p}", "tiepoints.csv", as_dir("p/at/tiepoints.csv")),
    C("adjust_tiepoints_nan", "aerotri", "adjust {p}", "tiepoints.csv:7", field("p/at/tiepoints.csv", 7, 2, "nan")),
    C("adjust_tiepoints_fields", "aerotri", "adjust {p}", "tiepoints.csv:9", field("p/at/tiepoints.csv", 9, 3, "1,2")),
    C("adjust_tiepoints_duplicate", "aerotri", "adjust {p}", "tiepoints.csv:4", duplicate_line("p/at/tiepoints.csv", 3)),
    C("adjust_tiepoints_outside_frame", "aerotri", "adjust {p}", "tiepoints.csv", field("p/at/tiepoints.csv", 5, 2, "9999")),
    C("adjust_tiepoints_unknown_image", "aerotri", "adjust {p}", ["tiepoints.csv", "s09_001"],
      field("p/at/tiepoints.csv", 5, 1, "s09_001")),
    C("adjust_tiepoints_header_only", "aerotri", "adjust {p}", "tiepoints.csv", keep_lines("p/at/tiepoints.csv", 1)),
    C("adjust_planes_missing", "aerotri", "adjust {p} --dem {w}/p/lidar_out/dem.tif --planes {w}/nope", "nope"),
    # without a DEM: lidar_out/dem.tif is there, and aerotri adjust would take it (--no-lidar-surface)
    C("adjust_planes_without_dem", "aerotri", "adjust {p} --no-lidar-surface --planes {w}/p/lidar_out", ["--planes", "DEM"]),
    C("adjust_planes_not_json", "aerotri", "adjust {p} --dem {w}/p/lidar_out/dem.tif --planes {w}/planes",
      ["roof_planes.geojson", "line 2"], write("planes/roof_planes.geojson", '{{"type":\n ,}}')),
    C("adjust_planes_toml_number", "aerotri", "adjust {p}", ["project.toml", "planes"],
      toml_set("p/project.toml", "adjust", "planes", "3")),
    C("adjust_control_nan", "aerotri", "adjust {p}", "points.csv:2", field("p/control/points.csv", 2, 3, "nan")),
    C("adjust_control_kind", "aerotri", "adjust {p}", "points.csv:2", field("p/control/points.csv", 2, 1, "gcp")),
    C("adjust_control_sigma_zero", "aerotri", "adjust {p}", "points.csv:3", field("p/control/points.csv", 3, 5, "0")),
    C("adjust_control_duplicate", "aerotri", "adjust {p}", "points.csv:3", duplicate_line("p/control/points.csv", 2)),
    C("adjust_control_utf16", "aerotri", "adjust {p}", "points.csv", utf16("p/control/points.csv")),
    C("adjust_control_xy_swapped", "aerotri", "adjust {p}", "points.csv", swap_fields("p/control/points.csv", 2, 3)),
    C("adjust_image_points_outside", "aerotri", "adjust {p}", "image_points.csv",
      field("p/control/image_points.csv", 2, 3, "-400")),
    C("adjust_image_points_binary", "aerotri", "adjust {p}", "image_points.csv", binary("p/control/image_points.csv")),
    C("adjust_gnss_utf16", "aerotri", "adjust {p}", "gnss.txt", utf16("p/gnss.txt")),
    C("adjust_gnss_xy_swapped", "aerotri", "adjust {p}", "gnss.txt", swap_fields("p/gnss.txt", 1, 2)),
    C("adjust_camera_k3_nan", "aerotri", "adjust {p}", ["camera.toml", "k3"], toml_set("p/camera.toml", None, "k3", "nan")),
    C("adjust_camera_size_mismatch", "aerotri", "adjust {p}", "camera.toml",
      toml_set("p/camera.toml", None, "width", "100")),
    C("adjust_self_cal_unknown", "aerotri", "adjust {p} --self-cal pp,focus", "--self-cal"),
    C("adjust_check_unknown_id", "aerotri", "adjust {p} --check NOPE", "NOPE"),
    C("adjust_single_image", "aerotri", "adjust {p}", "gnss.txt", keep_lines("p/gnss.txt", 2)),

    # --- aerotri control
    C("control_before_adjust", "aerotri", "control {p}", "eo.txt", remove("p/at")),
    C("control_corners_missing", "aerotri", "control {p}", "corners.csv", remove("p/lidar_out/corners.csv")),
    C("control_corners_utf16", "aerotri", "control {p}", "corners.csv", utf16("p/lidar_out/corners.csv")),
    C("control_corners_binary", "aerotri", "control {p}", "corners.csv", binary("p/lidar_out/corners.csv")),
    C("control_corners_nan", "aerotri", "control {p}", "corners.csv:4", field("p/lidar_out/corners.csv", 4, 2, "nan")),
    C("control_corners_duplicate", "aerotri", "control {p}", "corners.csv:3", duplicate_line("p/lidar_out/corners.csv", 2)),
    C("control_corners_fields", "aerotri", "control {p}", "corners.csv:5",
      line("p/lidar_out/corners.csv", 5, lambda f: f[:6])),
    C("control_eo_nan", "aerotri", "control {p}", "eo.txt:3", field("p/at/eo.txt", 3, 4, "nan")),
    C("control_eo_fields", "aerotri", "control {p}", "eo.txt:2", line("p/at/eo.txt", 2, lambda f: f[:5])),
    C("control_eo_utf16", "aerotri", "control {p}", "eo.txt", utf16("p/at/eo.txt")),
    C("control_eo_directory", "aerotri", "control {p} --eo {w}/p/at/eo.txt", "eo.txt", as_dir("p/at/eo.txt")),
    C("control_eo_duplicate", "aerotri", "control {p}", "eo.txt:3", duplicate_line("p/at/eo.txt", 2)),
    C("control_camera_option_bad", "aerotri", "control {p} --camera {w}/cam.toml", "cam.toml",
      write("cam.toml", "focal_mm = 120.0\n")),
    C("control_adjusted_camera_corrupt", "aerotri", "control {p}", "at/camera.toml", binary("p/at/camera.toml")),
    C("control_adjusted_camera_truncated", "aerotri", "control {p}", "at/camera.toml",
      truncate("p/at/camera.toml", 0.5)),
    C("control_adjusted_camera_missing", "aerotri", "control {p}", ["eo.txt", "camera.toml", "aerotri adjust"],
      remove("p/at/camera.toml")),
    C("control_manual_outside_frame", "aerotri", "control {p} --import-manual {w}/manual.csv", "manual.csv:2",
      manual(x="4321.0")),
    C("control_manual_nan", "aerotri", "control {p} --import-manual {w}/manual.csv", "manual.csv:2", manual(y="nan")),
    C("control_manual_unknown_image", "aerotri", "control {p} --import-manual {w}/manual.csv", ["manual.csv:3", "s07_001"],
      manual(extra="{pid},s07_001,10,10\n")),
    C("control_manual_utf16", "aerotri", "control {p} --import-manual {w}/manual.csv", "manual.csv",
      all_of(manual(), utf16("manual.csv"))),
    C("control_manual_fields", "aerotri", "control {p} --import-manual {w}/manual.csv", "manual.csv:3",
      manual(extra="a,b,c\n")),
    C("control_image_truncated", "aerotri", "control {p}", "s01_002.tif", truncate("p/images/s01_002.tif", 0.3)),
    C("control_image_wrong_size", "aerotri", "control {p}", "s01_002.tif", image("p/images/s01_002.tif", "small")),
    C("control_image_missing", "aerotri", "control {p}", "s01_002", remove("p/images/s01_002.tif")),
    C("control_tol_px_zero", "aerotri", "control {p} --tol-px 0", "--tol-px"),

    # --- aerotri report
    C("report_no_stage_run", "aerotri", "report {p}", "report.json", remove("p/at", "p/control", "p/ortho", "p/reports")),
    C("report_at_report_corrupt", "aerotri", "report {p}", "report.json", binary("p/at/report.json")),
    C("compare_reference_missing", "aerotri", "compare {p} --format orthority {w}/none.csv", "none.csv: not found"),
    C("compare_reference_no_common_frame", "aerotri", "compare {p} --format orthority --crs EPSG:32649 {w}/ref.csv",
      ["ref.csv", "no frame in common with at/eo.txt"], write("ref.csv", "filename,x,y,z,omega,phi,kappa\nzz,1,2,3,0,0,0\n")),
    C("compare_no_adjustment", "aerotri", "compare {p} --format orthority --crs EPSG:32649 {w}/ref.csv",
      ["eo.txt", "run aerotri adjust first"], lambda w: (remove("p/at")(w), write("ref.csv", "filename,x,y,z,omega,"
                                                                              "phi,kappa\nzz,1,2,3,0,0,0\n")(w))),
    C("report_dom_report_truncated", "aerotri", "report {p}", "dom_report.json", truncate("p/ortho/dom_report.json", 0.5)),
    C("report_tolerances_bad_toml", "aerotri", "report {p} --tolerances {w}/tol.toml", "tol.toml",
      write("tol.toml", "[flat\n")),
    C("report_map_scale_unknown", "aerotri", "report {p}", ["map_scale", "1:3000"],
      toml_set("p/project.toml", "qa", "map_scale", '"1:3000"')),
    C("report_project_toml_missing", "aerotri", "report {p}", "project.toml", remove("p/project.toml")),
    C("report_project_toml_binary", "aerotri", "report {p}", "project.toml", binary("p/project.toml")),

    # --- aerotri crs
    C("crs_fit_unknown_from", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from EPSG:999999 --to 2361",
      "--from"),
    C("crs_fit_output_is_input", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361 -o "
      "{w}/las/common.csv", ["common.csv", "output"]),
    C("crs_fit_utf16", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361",
      "common.csv", utf16("las/common.csv")),
    C("crs_fit_binary", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361",
      "common.csv", binary("las/common.csv")),
    C("crs_fit_nan", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361",
      "common.csv: line 4", field("las/common.csv", 4, 1, "nan")),
    C("crs_fit_xy_swapped", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361",
      "common.csv", swap_fields("las/common.csv", 1, 2)),
    C("crs_fit_missing_column", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361",
      "common.csv", line("las/common.csv", 1, "id,x_from,y_from,z_from,x_to,y_to,zz")),
    C("crs_fit_heights_negative_smoothing", "aerotri", "crs fit-heights {w}/las/heights.csv --model tps --smoothing -1",
      "--smoothing"),
    C("crs_fit_heights_output_is_input", "aerotri", "crs fit-heights {w}/las/heights.csv -o {w}/las/heights.csv",
      "heights.csv"),
    C("crs_fit_heights_utf16", "aerotri", "crs fit-heights {w}/las/heights.csv", "heights.csv", utf16("las/heights.csv")),
    C("crs_fit_heights_duplicate", "aerotri", "crs fit-heights {w}/las/heights.csv", "heights.csv: line 3",
      duplicate_line("las/heights.csv", 2)),
    C("crs_transform_chunk_size_0", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to 32633 --chunk-points 0",
      "--chunk-points"),
    C("crs_transform_truncated_laz", "aerotri", "crs transform {w}/las/cloud.laz {w}/out.laz --to 32633",
      "cloud.laz", truncate("las/cloud.laz", 0.6)),
    C("crs_transform_truncated_las", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to 32633",
      "cloud.las", truncate("las/cloud.las", 0.6)),
    C("crs_transform_wrong_signature", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to 32633",
      "cloud.las", patch_bytes("las/cloud.las", 0, b"LASX")),
    C("crs_transform_empty_las", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to 32633",
      "cloud.las", empty("las/cloud.las")),
    C("crs_transform_zero_scale", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to 32633",
      "cloud.las", patch_bytes("las/cloud.las", 131, struct.pack("<d", 0.0))),
    C("crs_transform_no_crs", "aerotri", "crs transform {w}/las/nocrs.las {w}/out.las --to 32633", "nocrs.las"),
    C("crs_transform_mismatched_from", "aerotri",
      "crs transform {w}/las/cloud.las {w}/out.las --from 32650 --to 32633", "cloud.las"),
    C("crs_transform_unknown_to", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to EPSG:999999", "--to"),
    # aerotri crs assign (s27-fixes): re-tags a LAS/LAZ without moving a point
    C("crs_assign_truncated_laz", "aerotri", "crs assign {w}/las/cloud.laz {w}/out.laz --crs 32649",
      "cloud.laz", truncate("las/cloud.laz", 0.6)),
    C("crs_assign_wrong_signature", "aerotri", "crs assign {w}/las/cloud.las {w}/out.las --crs 32649",
      "cloud.las", patch_bytes("las/cloud.las", 0, b"LASX")),
    C("crs_assign_empty_las", "aerotri", "crs assign {w}/las/cloud.las {w}/out.las --crs 32649",
      "cloud.las", empty("las/cloud.las")),
    C("crs_assign_unknown_crs", "aerotri", "crs assign {w}/las/cloud.las {w}/out.las --crs EPSG:999999", "--crs"),
    # outside the area of use is a warning (national grids past their zone, review 31); a CRS the coordinates cannot
    # be in is refused: UTM eastings are no Gauss-Krueger zone 3 ones (no prefix 3), no degrees
    C("crs_assign_implausible_crs", "aerotri", "crs assign {w}/las/cloud.las {w}/out.las --crs EPSG:31467",
      ["cloud.las", "zone prefix 3", "not re-tagged"]),
    C("crs_assign_degrees_crs", "aerotri", "crs assign {w}/las/cloud.las {w}/out.las --crs EPSG:4326",
      ["cloud.las", "not a longitude", "not re-tagged"]),
    C("crs_assign_output_is_input", "aerotri", "crs assign {w}/las/cloud.las {w}/las/cloud.las --crs 32649",
      "cloud.las"),
    C("crs_assign_point_list", "aerotri", "crs assign {w}/las/pts.csv {w}/out.las --crs 32649",
      ["pts.csv", ".las or .laz"]),
    # a 3D projected CRS (vertical axis in US feet): GeoTIFF cannot store it, the product would have no CRS
    C("crs_warp_to_crs_geotiff_cannot_store", "aerotri",
      ["crs", "warp", "{w}/p/lidar_out/dem.tif", "{w}/dem_lcc.tif", "--to", "+proj=lcc +lat_1=30 +lat_2=32 +lat_0=29 "
       "+lon_0=111 +x_0=0 +y_0=0 +datum=WGS84 +units=us-ft +vunits=us-ft +no_defs"],
      ["--to", "cannot be stored in a GeoTIFF"]),
    C("crs_transform_output_is_input", "aerotri", "crs transform {w}/las/pts.csv {w}/las/pts.csv --from 32649 --to 2361",
      "pts.csv"),
    C("crs_transform_points_utf16", "aerotri", "crs transform {w}/las/pts.csv {w}/out.csv --from 32649 --to 4326",
      "pts.csv", utf16("las/pts.csv")),
    C("crs_transform_points_nan", "aerotri", "crs transform {w}/las/pts.csv {w}/out.csv --from 32649 --to 4326",
      "pts.csv: line 3", field("las/pts.csv", 3, 2, "nan")),
    C("crs_transform_points_degrees", "aerotri", "crs transform {w}/las/pts.csv {w}/out.csv --from 32649 --to 4326",
      "pts.csv", write("las/pts.csv", "id,x,y,z\nA,110.1,34.2,500\n")),
    C("crs_transform_params_corrupt", "aerotri",
      "crs transform {w}/las/pts.csv {w}/out.csv --from 32649 --to 2361 --params {w}/params.json", "params.json",
      write("params.json", '{{"model": "bursa-wolf7", ')),

    # --- lidarctl
    C("classify_truncated", "lidarctl", "classify {w}/las/raw.las {w}/out.las", "raw.las", truncate("las/raw.las")),
    C("classify_output_a_text_file", "lidarctl", "classify {w}/las/raw.las {w}/out.txt", ["out.txt", ".las/.laz file"]),
    C("classify_zero_scale", "lidarctl", "classify {w}/las/raw.las {w}/out.las", "raw.las",
      patch_bytes("las/raw.las", 131, struct.pack("<d", 0.0))),
    C("classify_wrong_signature", "lidarctl", "classify {w}/las/raw.las {w}/out.las", "raw.las",
      patch_bytes("las/raw.las", 0, b"XXXX")),
    C("classify_count_lower_than_records", "lidarctl", "classify {w}/las/raw.las {w}/out.las", "raw.las",
      las_point_count("las/raw.las", -100)),
    C("classify_count_higher_than_records", "lidarctl", "classify {w}/las/raw.las {w}/out.las", "raw.las",
      las_point_count("las/raw.las", 100)),
    C("classify_no_crs", "lidarctl", "classify {w}/las/nocrs.las {w}/out.las", "nocrs.las"),
    C("classify_empty", "lidarctl", "classify {w}/las/raw.las {w}/out.las", "raw.las", empty("las/raw.las")),
    C("classify_directory", "lidarctl", "classify {w}/las {w}/out.las", "las"),
    C("classify_output_is_input", "lidarctl", "classify {w}/las/raw.las {w}/las/raw.las", "raw.las"),
    C("classify_tile_size_negative", "lidarctl", "classify {w}/las/raw.las {w}/out.las --tile-size-m -50", "--tile-size-m"),
    C("classify_buffer_negative", "lidarctl", "classify {w}/las/raw.las {w}/out.las --buffer-m -5", "--buffer-m"),
    C("classify_unknown_crs", "lidarctl", "classify {w}/las/nocrs.las {w}/out.las --crs EPSG:999999", "--crs"),
    C("classify_geographic_crs", "lidarctl", "classify {w}/las/nocrs.las {w}/out.las --crs EPSG:4326", "--crs"),
    C("rasters_res_missing", "lidarctl", "rasters {w}/las/cloud.las {w}/r", "--res-m"),
    C("rasters_res_zero", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res-m 0", "--res-m"),
    C("rasters_res_negative", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res-m -1", "--res-m"),
    C("rasters_truncated", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res-m 1", "cloud.las", truncate("las/cloud.las")),
    C("rasters_no_crs", "lidarctl", "rasters {w}/las/nocrs.las {w}/r --res-m 1", "nocrs.las"),
    C("rasters_zero_scale", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res-m 1", "cloud.las",
      patch_bytes("las/cloud.las", 139, struct.pack("<d", 0.0))),
    C("crowns_dsm_missing", "lidarctl", "crowns {w}/las/cloud.las {w}/out", "dsm_nearest.tif"),
    C("crowns_truncated", "lidarctl", "crowns {w}/las/cloud.las {w}/out --dsm-nearest {w}/lid/r/dsm_nearest.tif",
      "cloud.las", truncate("las/cloud.las")),
    C("crowns_no_crs", "lidarctl", "crowns {w}/las/nocrs.las {w}/out --dsm-nearest {w}/lid/r/dsm_nearest.tif",
      "nocrs.las"),
    C("evaluate_truncated_truth", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/cloud.laz", "cloud.laz",
      truncate("las/cloud.laz")),
    C("evaluate_different_clouds", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/other.las", "other.las",
      lambda w: _write_other_las(w)),
    C("evaluate_bad_map", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/cloud.laz --map-pred 3-1",
      "--map-pred"),
    C("evaluate_json_is_input", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/cloud.laz --json "
      "{w}/las/cloud.las", "cloud.las"),
    C("evaluate_reference_and_truth", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/cloud.laz --reference "
      "{w}/las/cloud.laz", "either --truth"),
    C("evaluate_reference_not_a_map", "lidarctl", "evaluate {w}/las/cloud.las --reference {w}/las/points.csv --json "
      "{w}/e.json", "points.csv"),
    C("check_heights_radius_negative", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv --radius-m -1",
      "--radius-m"),
    C("check_heights_exclude_negative", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv --exclude-m -1",
      "--exclude-m"),
    C("check_heights_points_utf16", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      utf16("las/points.csv")),
    C("check_heights_points_binary", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      binary("las/points.csv")),
    C("check_heights_points_nan", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      field("las/points.csv", 3, 3, "nan")),
    # trial-qa: a point listed twice counted twice against a standard's minimum of check points
    C("check_heights_points_id_twice", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv",
      ["points.csv: line 4", "'P0' again (first on line 2)"], field("las/points.csv", 4, 0, "P0")),
    C("check_heights_points_no_z", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      line("las/points.csv", 1, "id,x,y,q")),
    C("check_heights_points_directory", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv",
      "points.csv", as_dir("las/points.csv")),
    C("check_heights_truncated_cloud", "lidarctl", "check-heights {w}/las/cloud.laz {w}/las/points.csv", "cloud.laz",
      truncate("las/cloud.laz")),
    C("check_plan_radius_negative", "lidarctl", "check-plan {w}/las/cloud.las {w}/las/points.csv --radius-m -1",
      "--radius-m"),
    C("check_plan_points_no_y", "lidarctl", "check-plan {w}/las/cloud.las {w}/las/points.csv --json {w}/p.json",
      "points.csv", line("las/points.csv", 1, "id,x,q,z")),
    C("check_plan_points_crs_mismatch", "lidarctl", "check-plan {w}/las/cloud.las {w}/las/points.csv --points-crs "
      "EPSG:32633 --json {w}/p.json", "--points-crs"),
    C("check_plan_truncated_cloud", "lidarctl", "check-plan {w}/las/cloud.laz {w}/las/points.csv --json {w}/p.json",
      "cloud.laz", truncate("las/cloud.laz")),
    C("corners_truncated", "lidarctl", "corners {w}/las/cloud.las {w}/c", "cloud.las", truncate("las/cloud.las")),
    C("corners_wrong_signature", "lidarctl", "corners {w}/las/cloud.las {w}/c", "cloud.las",
      patch_bytes("las/cloud.las", 0, b"LASX")),
    C("corners_empty", "lidarctl", "corners {w}/las/cloud.las {w}/c", "cloud.las", empty("las/cloud.las")),
    C("corners_count_lower_than_records", "lidarctl", "corners {w}/las/cloud.las {w}/c", "cloud.las",
      las_point_count("las/cloud.las", -100)),
    C("corners_min_edge_small", "lidarctl", "corners {w}/las/cloud.las {w}/c --min-edge-m 0.1", "--min-edge-m"),

    # --- ortho rectify
    C("rectify_res_zero", "ortho", "rectify {p} --res-m 0", "--res-m"),
    C("rectify_res_negative", "ortho", "rectify {p} --res-m -0.5", "--res-m"),
    C("rectify_res_too_fine", "ortho", "rectify {p} --res-m 0.0005", ["--res-m", "GiB"]),
    C("rectify_before_adjust", "ortho", "rectify {p}", "eo.txt", remove("p/at")),
    C("rectify_dem_missing", "ortho", "rectify {p}", "dem.tif", remove("p/lidar_out/dem.tif")),
    C("rectify_dem_truncated", "ortho", "rectify {p}", "dem.tif", truncate("p/lidar_out/dem.tif", 0.5)),
    C("rectify_dem_binary", "ortho", "rectify {p}", "dem.tif", binary("p/lidar_out/dem.tif")),
    C("rectify_dem_partial", "ortho", "rectify {p}", "dem.tif", dem_part("p/lidar_out/dem.tif")),
    C("rectify_dem_rgb", "ortho", "rectify {p}", "band", dem_as_rgb("p/lidar_out/dem.tif")),
    C("rectify_dem_a_folder", "ortho", "rectify {p}", ["dem.tif", "a folder, expected the DEM GeoTIFF"],
      as_dir("p/lidar_out/dem.tif")),
    C("rectify_dem_other_crs", "ortho", "rectify {p}", "dem.tif", raster_crs("p/lidar_out/dem.tif", "EPSG:32650")),
    C("rectify_image_missing", "ortho", "rectify {p}", "s01_002", remove("p/images/s01_002.tif")),
    C("rectify_image_truncated", "ortho", "rectify {p}", "s02_002.tif", truncate("p/images/s02_002.tif", 0.3)),
    C("rectify_image_wrong_size", "ortho", "rectify {p}", "s02_002.tif", image("p/images/s02_002.tif", "small")),
    C("rectify_image_directory", "ortho", "rectify {p}", "s02_002.tif", as_dir("p/images/s02_002.tif")),
    C("rectify_frames_unknown", "ortho", "rectify {p} --frames s01_001,nope", "nope"),
    C("rectify_eo_nan", "ortho", "rectify {p}", "eo.txt:4", field("p/at/eo.txt", 4, 5, "nan")),
    C("rectify_eo_utf16", "ortho", "rectify {p}", "eo.txt", utf16("p/at/eo.txt")),
    C("rectify_eo_missing_frame", "ortho", "rectify {p}", ["eo.txt", "s02_003"], keep_lines("p/at/eo.txt", 6)),
    C("rectify_camera_size_mismatch", "ortho", "rectify {p} --camera {w}/cam.toml", "cam.toml",
      lambda w: (w / "cam.toml").write_text(_text(w / "p/camera.toml").replace("width = 432", "width = 400"))),
    C("rectify_crs_unknown", "ortho", "rectify {p} --crs EPSG:999999", "--crs"),
    C("rectify_workers_huge", "ortho", "rectify {p} --workers 1000000", "--workers"),
    C("rectify_crs_bad_gk", "ortho", "rectify {p} --crs gk3:nosuch", "--crs"),
    C("rectify_true_ortho_without_dsm", "ortho", "rectify {p} --true-ortho", "--dsm"),
    C("rectify_project_crs_geographic", "ortho", "rectify {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:4326"')),
    C("rectify_adjusted_camera_corrupt", "ortho", "rectify {p}", "at/camera.toml", binary("p/at/camera.toml")),

    # --- ortho mosaic
    C("mosaic_before_rectify", "ortho", "mosaic {p}", ["index.json", "ortho rectify"], remove("p/ortho/frames")),
    C("mosaic_tile_px_zero", "ortho", "mosaic {p} --tile-px 0", "--tile-px"),
    C("mosaic_tile_px_huge", "ortho", "mosaic {p} --tile-px 2000000", "--tile-px"),
    C("mosaic_feather_negative", "ortho", "mosaic {p} --feather-m -2", "--feather-m"),
    C("mosaic_index_corrupt", "ortho", "mosaic {p}", "index.json", truncate("p/ortho/frames/index.json", 0.5)),
    C("mosaic_index_binary", "ortho", "mosaic {p}", "index.json", binary("p/ortho/frames/index.json")),
    C("mosaic_index_no_frames", "ortho", "mosaic {p}", "index.json",
      lambda w: (w / "p/ortho/frames/index.json").write_text(json.dumps(
          dict(json.loads(_text(w / "p/ortho/frames/index.json")), frames=[])))),
    C("mosaic_frame_missing", "ortho", "mosaic {p}", "s01_002.tif", remove("p/ortho/frames/s01_002.tif")),
    C("mosaic_frame_swapped", "ortho", "mosaic {p}", "s01_002.tif",
      copy("p/ortho/frames/s01_001.tif", "p/ortho/frames/s01_002.tif")),
    C("mosaic_frame_truncated", "ortho", "mosaic {p}", "s02_001.tif", truncate("p/ortho/frames/s02_001.tif", 0.5)),
    C("mosaic_ndsm_missing", "ortho", "mosaic {p} --ndsm {w}/nope.tif", "nope.tif"),
    C("mosaic_ndsm_truncated", "ortho", "mosaic {p}", "ndsm.tif", truncate("p/lidar_out/ndsm.tif", 0.4)),
    # frames rectified from an older at/eo.txt (the user re-adjusted since): never mosaicked silently
    C("mosaic_eo_readjusted", "ortho", "mosaic {p}", ["index.json", "eo.txt", "ortho rectify"],
      readjusted("p/at/eo.txt")),

    # --- ortho dem (a DEM from the adjusted tie points)
    C("dem_before_adjust", "ortho", "dem {p}", "object_points.csv", remove("p/at/object_points.csv")),
    C("dem_res_zero", "ortho", "dem {p} --res-m 0", "--res-m"),
    C("dem_res_nan", "ortho", "dem {p} --res-m nan", "--res-m"),
    C("dem_min_rays_one", "ortho", "dem {p} --min-rays 1", "--min-rays"),
    C("dem_object_points_text", "ortho", "dem {p}", "object_points.csv", table("p/at/object_points.csv", "text")),
    C("dem_object_points_header_only", "ortho", "dem {p}", "object_points.csv",
      table("p/at/object_points.csv", "header_only")),
    C("dem_object_points_binary", "ortho", "dem {p}", "object_points.csv", binary("p/at/object_points.csv")),

    # --- ortho check
    C("check_patch_px_zero", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --patch-px 0", "--patch-px"),
    C("check_patch_px_huge", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --patch-px 300000", "--patch-px"),
    C("check_search_px_negative", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --search-px -1", "--search-px"),
    C("check_max_ndsm_nan", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --max-ndsm-m nan", "--max-ndsm-m"),
    C("check_before_mosaic", "ortho", "check {p} --reference {w}/p/truth/ortho.tif", "mosaic.tif",
      remove("p/ortho/mosaic.tif")),
    C("check_reference_missing", "ortho", "check {p} --reference {w}/nope.tif", "nope.tif"),
    C("check_reference_truncated", "ortho", "check {p} --reference {w}/p/truth/ortho.tif", "ortho.tif",
      truncate("p/truth/ortho.tif", 0.4)),
    C("check_reference_and_points", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --points {w}/pts.csv",
      "--reference"),
    C("check_points_utf16", "ortho", "check {p} --points {w}/pts.csv", "pts.csv",
      all_of(write("pts.csv", "id,x,y,x_dom,y_dom\nA,452200.0,3407300.0,452200.1,3407300.1\n"), utf16("pts.csv"))),
    C("check_points_nan", "ortho", "check {p} --points {w}/pts.csv", "pts.csv:3",
      write("pts.csv", "id,x,y,x_dom,y_dom\nA,452200.0,3407300.0,452200.1,3407300.1\nB,nan,1,2,3\n")),
    C("check_points_id_twice", "ortho", "check {p} --points {w}/pts.csv", ["pts.csv:3", "'A' again (first on line 2)"],
      write("pts.csv", "id,x,y,x_dom,y_dom\nA,452200.0,3407300.0,452200.1,3407300.1\n"
                       "A,452200.0,3407300.0,452200.1,3407300.1\n")),
    C("check_points_missing_column", "ortho", "check {p} --points {w}/pts.csv", "pts.csv",
      write("pts.csv", "id,x,y,x_dom\nA,452200.0,3407300.0,452200.1\n")),
    C("check_out_is_an_output_of_mosaic", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --out {w}/p/ortho/mosaic",
      "--out"),
    C("check_index_stale", "ortho", "check {p} --reference {w}/p/truth/ortho.tif", "s01_002.tif",
      copy("p/ortho/frames/s01_001.tif", "p/ortho/frames/s01_002.tif")),
    C("check_eo_readjusted", "ortho", "check {p} --reference {w}/p/truth/ortho.tif",
      ["index.json", "eo.txt", "ortho rectify"], readjusted("p/at/eo.txt")),

    # --- aerotri run
    C("run_no_project_toml", "aerotri", "run {p}", "project.toml", remove("p/project.toml")),
    C("run_project_crs_unknown", "aerotri", "run {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:999999"')),
    C("run_res_zero", "aerotri", "run {p} --res-m 0", "--res-m"),
    C("run_reference_missing", "aerotri", "run {p} --reference {w}/nope.tif", "nope.tif"),
    # a DEM of another CRS or an image given as the DEM stops the run before its first stage
    C("run_dem_other_crs", "aerotri", "run {p} --dem {w}/p/lidar_out/dem.tif", ["dem.tif", "CRS"],
      raster_crs("p/lidar_out/dem.tif", "EPSG:32650")),
    C("run_dem_rgb", "aerotri", "run {p} --dem {w}/p/lidar_out/dem.tif", ["dem.tif", "band"],
      dem_as_rgb("p/lidar_out/dem.tif")),
]


# the building of lid/bldg.las as a reference polygon (EPSG:32632)
_BUILDING_GEOJSON = ('{{"type": "FeatureCollection", "crs": {{"type": "name", "properties": {{"name": '
                     '"urn:ogc:def:crs:EPSG::32632"}}}}, "features": [{{"type": "Feature", "properties": {{}}, '
                     '"geometry": {{"type": "Polygon", "coordinates": [[[500019, 5400023.5], [500041, 5400023.5], '
                     '[500041, 5400036.5], [500019, 5400036.5], [500019, 5400023.5]]]}}}}]}}')


def _first_tolerance_table() -> str:
    return sorted((REPO / "aerotri" / "core" / "tolerance_tables").glob("*.toml"))[0].read_text(encoding="utf-8")


def _crop(q: Path, rows: int, cols: int) -> None:
    with rasterio.open(q) as ds:
        a, prof = ds.read(window=((0, rows), (0, cols))), dict(ds.profile)
    _write_raster(q, a, prof)


def _nan_holes(rel):
    """NaN in some cells of a DEM whose nodata value is another number: NaN is nodata too."""
    def f(w):
        q = w / rel
        with rasterio.open(q) as ds:
            a, prof = ds.read(), dict(ds.profile)
        a[:, :5, :5] = np.nan  # a corner of the DEM outside the frames (a hole under a frame is refused by name)
        _write_raster(q, a, prof)
    return f


def _points_to_us_feet(rel):
    def f(w):
        ft = 1200.0 / 3937.0
        q = w / rel
        lines = _text(q).splitlines()
        rows = [s.split(",") for s in lines[1:]]
        q.write_text(lines[0] + "\n" + "".join(f"{r[0]},{float(r[1]) / ft:.3f},{float(r[2]) / ft:.3f},{float(r[3]) / ft:.3f}\n"
                                               for r in rows))
    return f


def _las_to_us_feet(q: Path) -> None:
    import laspy
    import pyproj

    from lidarctl import synthetic

    las = laspy.read(str(q))
    crs = pyproj.CRS.from_proj4("+proj=utm +zone=32 +datum=WGS84 +units=us-ft +no_defs")
    cloud = synthetic.PointCloud(x=np.asarray(las.x), y=np.asarray(las.y), z=np.asarray(las.z),
                                 intensity=np.asarray(las.intensity), return_number=np.asarray(las.return_number),
                                 number_of_returns=np.asarray(las.number_of_returns),
                                 classification=np.asarray(las.classification))
    q.unlink()
    synthetic.write_las(q, cloud, crs=crs)


# --- issue 39: odd rasters, tables, strips and option values over every command (the corpus of item 10 was
# kept apart; this one is ours, broader). Every height raster a command reads, in every odd form.
_NO_EXPORTS = "--no-html --no-exports"
HEIGHT_RASTER_READERS = [
    # (id, prog, args, the raster (workspace-relative), setup the command needs to read it)
    ("adjust_dem", "aerotri", f"adjust {{p}} --dem {{w}}/p/lidar_out/dem.tif {_NO_EXPORTS}", "p/lidar_out/dem.tif", None),
    ("adjust_ndsm", "aerotri", f"adjust {{p}} --dem {{w}}/p/truth/dem.tif --ndsm {{w}}/p/lidar_out/ndsm.tif {_NO_EXPORTS}",
     "p/lidar_out/ndsm.tif", None),
    ("match_dem", "aerotri", "match {p}", "p/lidar_out/dem.tif", remove_key("p/project.toml", "mean_terrain_height_m")),
    ("rectify_dem", "ortho", "rectify {p}", "p/lidar_out/dem.tif", None),
    ("rectify_dsm", "ortho", "rectify {p} --true-ortho --dsm {w}/p/truth/dsm.tif", "p/truth/dsm.tif", None),
    ("mosaic_ndsm", "ortho", "mosaic {p}", "p/lidar_out/ndsm.tif", None),
    ("check_ndsm", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --ndsm {w}/p/lidar_out/ndsm.tif --patch-px 24 "
     "--search-px 4", "p/lidar_out/ndsm.tif", None),
    ("export_gpkg_dem", "aerotri", "export {p} --format gpkg", "p/lidar_out/dem.tif", None),
    ("run_dem", "aerotri", "run {p} --dem {w}/p/lidar_out/dem.tif", "p/lidar_out/dem.tif", None),
    ("warp_dem", "aerotri", "crs warp {w}/p/lidar_out/dem.tif {w}/out.tif --to EPSG:32650", "p/lidar_out/dem.tif", None),
    ("contours_dem", "lidarctl", "contours {w}/lid/r/dem.tif {w}/out.gpkg --interval-m 1 --no-png", "lid/r/dem.tif", None),
    ("drainage_dem", "lidarctl", "drainage {w}/lid/r/dem.tif {w}/out --no-png", "lid/r/dem.tif", None),
    ("smooth_dem", "lidarctl", "smooth {w}/lid/r/dem.tif {w}/out.tif", "lid/r/dem.tif", None),
    ("check_heights_dem", "lidarctl", "check-heights {w}/las/points.csv --dem {w}/lid/r/dem.tif", "lid/r/dem.tif", None),
    ("vectors_dem", "lidarctl", "vectors {w}/lid/bldg.las --dem {w}/lid/r/dem.tif {w}/out.gpkg", "lid/r/dem.tif", None),
]
HEIGHT_RASTER_FAULTS = [
    # (id, how, words the message must hold besides the file name)
    ("1x1", "1x1", ["2 x 2"]),
    ("one_row", "1row", ["2 x 2"]),
    ("one_column", "1col", ["2 x 2"]),
    ("inf", "inf", ["inf"]),
    ("minus_inf", "-inf", ["inf"]),
    ("all_nodata", "nodata", ["no valid"]),
    ("all_nan", "nan", ["no valid"]),
    ("undeclared_nodata", "float_min", ["nodata"]),
    ("no_crs", "no_crs", ["CRS"]),
    ("rgb", "rgb", ["band"]),
    ("two_bands", "two_bands", ["band"]),
]


def _raster_cases():
    out = []
    for rid, prog, args, rel, setup in HEIGHT_RASTER_READERS:
        name = rel.rsplit("/", 1)[-1]
        for fid, how, words in HEIGHT_RASTER_FAULTS:
            if rid == "warp_dem" and fid in ("rgb", "two_bands"):
                continue  # crs warp takes images too (ACCEPTED: warp_rgb_image)
            out.append(C(f"{rid}_{fid}", prog, args, [name, *words],
                         all_of(*(g for g in (setup, raster(rel, how)) if g is not None))))
        if rel.startswith("p/") and rid != "warp_dem":
            # the photo block's rasters: in the project CRS or refused by name (ortho check maps an nDSM of another
            # CRS through the coordinate operation: ACCEPTED; but one of another place covers none of the DOM)
            for fid, how in (("other_zone", "EPSG:32650"), ("us_feet", "us-ft"), ("degrees", "degrees")):
                if rid == "check_ndsm" and fid != "other_zone":
                    continue
                out.append(C(f"{rid}_{fid}", prog, args, [name, "covers none"] if rid == "check_ndsm" else name,
                             all_of(*(g for g in (setup, raster(rel, how)) if g is not None))))
    return out


ISSUE39 = _raster_cases() + [
    # drainage areas and slopes need lengths: a DEM in degrees is refused (contours/smooth work on it)
    C("drainage_dem_degrees", "lidarctl", "drainage {w}/lid/r/dem.tif {w}/out --no-png", ["dem.tif", "geographic"],
      raster("lid/r/dem.tif", "degrees")),
    # the points of a height check in another zone than the DEM/cloud: nothing to compare, not "0 points"
    C("check_heights_dem_points_other_zone", "lidarctl", "check-heights {w}/las/points.csv --dem {w}/lid/r/dem.tif",
      ["points.csv"], other_zone("las/points.csv", (1, 2), 32632, 32633)),
    C("check_heights_points_other_zone", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv",
      ["points.csv"], other_zone("las/points.csv", (1, 2), 32632, 32633)),
    C("check_plan_points_other_zone", "lidarctl", "check-plan {w}/lid/bldg.las {w}/lid/c/corners.csv",
      ["corners.csv"], other_zone("lid/c/corners.csv", (1, 2), 32632, 32633)),
    C("vectors_dem_other_crs", "lidarctl", "vectors {w}/lid/bldg.las --dem {w}/lid/r/dem.tif {w}/out.gpkg",
      ["dem.tif", "CRS"], raster("lid/r/dem.tif", "EPSG:32633")),
    C("check_heights_dem_and_cloud_other_crs", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv "
      "--dem {w}/lid/r/dem.tif", ["dem.tif", "CRS"], raster("lid/r/dem.tif", "EPSG:32633")),

    # --- orthophotos and images given to a command
    C("check_reference_1x1", "ortho", "check {p} --reference {w}/p/truth/ortho.tif", ["ortho.tif", "2 x 2"],
      raster("p/truth/ortho.tif", "1x1")),
    C("check_reference_no_crs", "ortho", "check {p} --reference {w}/p/truth/ortho.tif", ["ortho.tif", "CRS"],
      raster("p/truth/ortho.tif", "no_crs")),
    C("check_reference_rotated", "ortho", "check {p} --reference {w}/p/truth/ortho.tif", ["ortho.tif", "north-up"],
      raster("p/truth/ortho.tif", "rotated")),
    C("check_reference_other_zone", "ortho", "check {p} --reference {w}/p/truth/ortho.tif", ["ortho.tif"],
      raster("p/truth/ortho.tif", "EPSG:32650")),
    C("check_dom_1x1", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --dom {w}/p/ortho/mosaic.tif",
      ["mosaic.tif", "2 x 2"], raster("p/ortho/mosaic.tif", "1x1")),
    C("classify_image_1x1", "lidarctl", "classify {w}/las/raw.las {w}/out.las --image {w}/lid/rgb.tif",
      ["rgb.tif", "2 x 2"], raster("lid/rgb.tif", "1x1")),
    C("classify_image_no_crs", "lidarctl", "classify {w}/las/raw.las {w}/out.las --image {w}/lid/rgb.tif",
      ["rgb.tif", "CRS"], raster("lid/rgb.tif", "no_crs")),
    C("classify_image_other_zone", "lidarctl", "classify {w}/las/raw.las {w}/out.las --image {w}/lid/rgb.tif",
      ["rgb.tif"], raster("lid/rgb.tif", "EPSG:32633")),
    C("classify_image_nir_band_missing", "lidarctl", "classify {w}/las/raw.las {w}/out.las --image {w}/lid/rgb.tif "
      "--nir 4", ["--nir", "4"]),
    C("classify_image_one_band", "lidarctl", "classify {w}/las/raw.las {w}/out.las --image {w}/lid/r/dem.tif",
      ["dem.tif", "band"]),
    C("vectors_image_1x1", "lidarctl", "vectors {w}/lid/bldg.las --image {w}/lid/rgb.tif {w}/out.gpkg",
      ["rgb.tif", "2 x 2"], raster("lid/rgb.tif", "1x1")),
    C("vectors_image_no_crs", "lidarctl", "vectors {w}/lid/bldg.las --image {w}/lid/rgb.tif {w}/out.gpkg",
      ["rgb.tif", "CRS"], raster("lid/rgb.tif", "no_crs")),

    # --- LiDAR strips: the same strip twice (by name or as a copy), another zone, empty, one point
    C("classify_same_strip_twice", "lidarctl", "classify {w}/lid/strip_1.las {w}/lid/strip_1.las {w}/out",
      ["strip_1.las", "twice"]),
    C("classify_same_strip_copy", "lidarctl", "classify {w}/lid/strip_1.las {w}/lid/strip_3.las {w}/out",
      ["strip_3.las", "strip_1.las"], las_edit("lid/strip_3.las", "copy", "lid/strip_1.las")),
    C("rasters_same_strip_twice", "lidarctl", "rasters {w}/lid/strip_1.las {w}/lid/strip_1.las {w}/out --res-m 1",
      ["strip_1.las", "twice"]),
    C("rasters_same_strip_copy", "lidarctl", "rasters {w}/lid/strip_1.las {w}/lid/strip_3.las {w}/out --res-m 1",
      ["strip_3.las", "strip_1.las"], las_edit("lid/strip_3.las", "copy", "lid/strip_1.las")),
    C("corners_same_file_twice", "lidarctl", "corners {w}/lid/bldg.las {w}/lid/bldg.las {w}/out",
      ["bldg.las", "twice"]),
    C("trees_same_file_twice", "lidarctl", "trees {w}/las/cloud.las {w}/las/cloud.las {w}/out",
      ["cloud.las", "twice"]),
    C("vectors_same_file_twice", "lidarctl", "vectors {w}/lid/bldg.las {w}/lid/bldg.las {w}/out.gpkg",
      ["bldg.las", "twice"]),
    C("merge_same_strip_twice", "lidarctl", "merge {w}/lid/strip_1.las {w}/lid/strip_1.las {w}/out.las",
      ["strip_1.las", "twice"]),
    C("merge_same_strip_copy", "lidarctl", "merge {w}/lid/strip_1.las {w}/lid/strip_3.las {w}/out.las",
      ["strip_3.las", "strip_1.las"], las_edit("lid/strip_3.las", "copy", "lid/strip_1.las")),
    C("strips_check_same_strip_twice", "lidarctl", "strips check {w}/lid/strip_1.las {w}/lid/strip_1.las {w}/out",
      ["strip_1.las", "twice"]),
    C("strips_adjust_same_strip_copy", "lidarctl", "strips adjust {w}/lid/strip_1.las {w}/lid/strip_3.las {w}/out",
      ["strip_3.las", "strip_1.las"], las_edit("lid/strip_3.las", "copy", "lid/strip_1.las")),
    C("check_heights_same_cloud_twice", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/cloud.las "
      "{w}/las/points.csv", ["cloud.las", "twice"]),
    C("check_plan_same_cloud_twice", "lidarctl", "check-plan {w}/lid/bldg.las {w}/lid/bldg.las {w}/lid/c/corners.csv",
      ["bldg.las", "twice"]),
    C("merge_strips_other_zone", "lidarctl", "merge {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out.las",
      ["strip_2.las", "EPSG:32633"], las_edit("lid/strip_2.las", "crs:EPSG:32633")),
    C("rasters_strips_other_zone", "lidarctl", "rasters {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out --res-m 1",
      ["strip_2.las"], las_edit("lid/strip_2.las", "crs:EPSG:32633")),
    C("classify_strips_other_zone", "lidarctl", "classify {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out",
      ["strip_2.las"], las_edit("lid/strip_2.las", "crs:EPSG:32633")),
    C("trees_strips_other_zone", "lidarctl", "trees {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out",
      ["strip_2.las"], las_edit("lid/strip_2.las", "crs:EPSG:32633")),
    C("strips_adjust_other_zone", "lidarctl", "strips adjust {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out",
      ["strip_2.las"], las_edit("lid/strip_2.las", "crs:EPSG:32633")),
    C("check_heights_clouds_other_zone", "lidarctl", "check-heights {w}/lid/strip_1.las {w}/lid/strip_2.las "
      "{w}/las/points.csv", ["strip_2.las"], las_edit("lid/strip_2.las", "crs:EPSG:32633")),
    C("rasters_geographic_las", "lidarctl", "rasters {w}/las/cloud.las {w}/out --res-m 1", ["cloud.las", "EPSG:4326"],
      las_edit("las/cloud.las", "crs:EPSG:4326")),
    C("rasters_no_points", "lidarctl", "rasters {w}/las/cloud.las {w}/out --res-m 1", ["cloud.las", "no points"],
      las_edit("las/cloud.las", "empty")),
    C("rasters_one_point", "lidarctl", "rasters {w}/las/cloud.las {w}/out --res-m 1", ["cloud.las"],
      las_edit("las/cloud.las", "one_point")),
    C("rasters_points_on_one_spot", "lidarctl", "rasters {w}/las/cloud.las {w}/out --res-m 1", ["cloud.las"],
      las_edit("las/cloud.las", "same_xy")),
    C("classify_no_points", "lidarctl", "classify {w}/las/raw.las {w}/out.las", ["raw.las", "no points"],
      las_edit("las/raw.las", "empty")),
    C("classify_one_point", "lidarctl", "classify {w}/las/raw.las {w}/out.las", ["raw.las"],
      las_edit("las/raw.las", "one_point")),
    C("corners_no_points", "lidarctl", "corners {w}/lid/bldg.las {w}/out", ["bldg.las", "no points"],
      las_edit("lid/bldg.las", "empty")),
    C("trees_no_points", "lidarctl", "trees {w}/las/cloud.las {w}/out", ["cloud.las", "no points"],
      las_edit("las/cloud.las", "empty")),
    C("trees_one_point", "lidarctl", "trees {w}/las/cloud.las {w}/out", ["cloud.las"],
      las_edit("las/cloud.las", "one_point")),
    C("vectors_no_points", "lidarctl", "vectors {w}/lid/bldg.las {w}/out.gpkg", ["bldg.las", "no points"],
      las_edit("lid/bldg.las", "empty")),
    C("merge_no_points", "lidarctl", "merge {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out.las",
      ["strip_2.las", "no points"], las_edit("lid/strip_2.las", "empty")),
    C("strips_check_no_points", "lidarctl", "strips check {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out",
      ["strip_2.las", "no points"], las_edit("lid/strip_2.las", "empty")),
    C("strips_check_one_point", "lidarctl", "strips check {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out",
      ["strip_2.las"], las_edit("lid/strip_2.las", "one_point")),
    C("check_heights_no_points", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv",
      ["cloud.las", "no points"], las_edit("las/cloud.las", "empty")),
    C("check_plan_no_points", "lidarctl", "check-plan {w}/lid/bldg.las {w}/lid/c/corners.csv",
      ["bldg.las", "no points"], las_edit("lid/bldg.las", "empty")),
    C("evaluate_no_points", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/cloud.laz",
      ["cloud.las", "no points"], las_edit("las/cloud.las", "empty")),
    C("crs_transform_no_points", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to 32633",
      ["cloud.las", "no points"], las_edit("las/cloud.las", "empty")),
    C("smooth_output_is_input", "lidarctl", "smooth {w}/lid/r/dem.tif {w}/lid/r/dem.tif", ["dem.tif"]),
    C("hydro_flatten_water_missing", "lidarctl", "hydro-flatten {w}/lid/r/dem.tif {w}/out.tif --water {w}/nope.gpkg",
      ["nope.gpkg", "no such file"]),
    C("hydro_flatten_output_is_input", "lidarctl",
      "hydro-flatten {w}/lid/r/dem.tif {w}/lid/r/dem.tif --water {w}/nope.gpkg", ["dem.tif"]),
    C("hydro_flatten_range_zero", "lidarctl",
      "hydro-flatten {w}/lid/r/dem.tif {w}/out.tif --water {w}/nope.gpkg --max-range-m 0", ["--max-range-m"]),
    C("contours_output_is_input", "lidarctl", "contours {w}/lid/r/dem.tif {w}/lid/r/dem.tif --interval-m 1",
      ["dem.tif"]),

    # --- text tables: empty, header only, inf, text in a number column, a field missing, ids that exist nowhere
    *[C(f"{cid}_{how}", prog, args, [rel.rsplit("/", 1)[-1], *words], table(rel, how))
      for cid, prog, args, rel in [
          ("match_gnss", "aerotri", "match {p}", "p/gnss.txt"),
          ("adjust_gnss", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", "p/gnss.txt"),
          ("adjust_tiepoints", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", "p/at/tiepoints.csv"),
          ("adjust_control_points", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", "p/control/points.csv"),
          ("adjust_image_points", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", "p/control/image_points.csv"),
          ("adjust_eo", "aerotri", f"adjust {{p}} --eo {{w}}/p/truth/eo.txt {_NO_EXPORTS}", "p/truth/eo.txt"),
          ("control_corners", "aerotri", "control {p}", "p/lidar_out/corners.csv"),
          ("control_eo", "aerotri", "control {p}", "p/at/eo.txt"),
          ("rectify_eo", "ortho", "rectify {p}", "p/at/eo.txt"),
          ("export_eo", "aerotri", "export {p} --format odm", "p/at/eo.txt"),
          ("check_heights_points", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "las/points.csv"),
          ("check_plan_points", "lidarctl", "check-plan {w}/lid/bldg.las {w}/lid/c/corners.csv", "lid/c/corners.csv"),
          ("strips_adjust_trajectory", "lidarctl", "strips adjust {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out "
           "--trajectory {w}/lid/traj.txt", "lid/traj.txt"),
          ("strips_adjust_control", "lidarctl", "strips adjust {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out "
           "--control {w}/las/points.csv", "las/points.csv"),
          ("crs_fit", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361",
           "las/common.csv"),
          ("crs_fit_heights", "aerotri", "crs fit-heights {w}/las/heights.csv", "las/heights.csv"),
          ("crs_transform_points", "aerotri", "crs transform {w}/las/pts.csv {w}/out.csv --from 32649 --to 4326",
           "las/pts.csv"),
      ]
      for how, words in [("header_only", []), ("blank", []), ("inf", []), ("text", ["abc"]), ("columns", [])]],
    C("check_points_header_only", "ortho", "check {p} --points {w}/pts.csv", "pts.csv", write("pts.csv", "id,x,y,x_dom,y_dom\n")),
    C("check_points_text", "ortho", "check {p} --points {w}/pts.csv", ["pts.csv:2", "abc"],
      write("pts.csv", "id,x,y,x_dom,y_dom\nA,452200.0,abc,452200.1,3407300.1\n")),
    C("check_points_inf", "ortho", "check {p} --points {w}/pts.csv", "pts.csv:2",
      write("pts.csv", "id,x,y,x_dom,y_dom\nA,452200.0,inf,452200.1,3407300.1\n")),
    C("check_points_other_zone", "ortho", "check {p} --points {w}/pts.csv", "pts.csv",
      write("pts.csv", "id,x,y,x_dom,y_dom\nA,-124000.0,3410000.0,-124000.1,3410000.1\n")),
    C("check_points_outside_dom", "ortho", "check {p} --points {w}/pts.csv", "pts.csv",
      write("pts.csv", "id,x,y,x_dom,y_dom\nA,462200.0,3417300.0,462200.1,3417300.1\n")),
    C("control_import_manual_header_only", "aerotri", "control {p} --import-manual {w}/manual.csv", "manual.csv",
      write("manual.csv", "point_id,image_id,x_px,y_px\n")),
    C("control_import_manual_unknown_point", "aerotri", "control {p} --import-manual {w}/manual.csv",
      ["manual.csv:2", "RC99999"], write("manual.csv", "point_id,image_id,x_px,y_px\nRC99999,s01_001,100,100\n")),
    C("control_import_manual_inf", "aerotri", "control {p} --import-manual {w}/manual.csv", "manual.csv:2",
      manual(x="inf")),
    C("control_import_manual_text", "aerotri", "control {p} --import-manual {w}/manual.csv", ["manual.csv:2", "abc"],
      manual(y="abc")),
    C("control_corners_other_zone", "aerotri", "control {p}", "corners.csv",
      other_zone("p/lidar_out/corners.csv", (1, 2))),
    C("control_eo_other_zone", "aerotri", "control {p}", "eo.txt", other_zone("p/at/eo.txt", (1, 2))),
    C("match_gnss_other_zone", "aerotri", "match {p}", "gnss.txt", other_zone("p/gnss.txt", (1, 2))),
    C("adjust_gnss_other_zone", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", "gnss.txt", other_zone("p/gnss.txt", (1, 2))),
    C("adjust_control_other_zone", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", "points.csv",
      other_zone("p/control/points.csv", (2, 3))),
    C("adjust_eo_other_zone", "aerotri", f"adjust {{p}} --eo {{w}}/p/truth/eo.txt {_NO_EXPORTS}", "eo.txt",
      other_zone("p/truth/eo.txt", (1, 2))),
    C("rectify_eo_other_zone", "ortho", "rectify {p}", "eo.txt", other_zone("p/at/eo.txt", (1, 2))),
    # coordinates of another place that the CRS's area of use lets through (300 km east, still in zone 49)
    C("adjust_control_300km_off", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["points.csv", "km from the block"],
      shift_xy("p/control/points.csv", (2, 3), 300000.0)),
    C("control_corners_300km_off", "aerotri", "control {p}", ["corners.csv", "km from the block"],
      shift_xy("p/lidar_out/corners.csv", (1, 2), 300000.0)),
    C("strips_adjust_control_other_zone", "lidarctl", "strips adjust {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out "
      "--control {w}/las/points.csv", "points.csv", other_zone("las/points.csv", (1, 2), 32632, 32633)),
    C("strips_adjust_trajectory_other_zone", "lidarctl", "strips adjust {w}/lid/strip_1.las {w}/lid/strip_2.las "
      "{w}/out --trajectory {w}/lid/traj.txt", "traj.txt", other_zone("lid/traj.txt", (1, 2), 32632, 32633)),
    # ids and images that exist nowhere
    C("adjust_control_unknown_id", "aerotri", f"adjust {{p}} --control NOPE {_NO_EXPORTS}", "NOPE"),
    C("adjust_check_and_control_same_id", "aerotri", f"adjust {{p}} --check RC00005 --control RC00005 {_NO_EXPORTS}",
      "RC00005"),
    C("adjust_image_points_unknown_point", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["image_points.csv", "RC99999"],
      field("p/control/image_points.csv", 2, 0, "RC99999")),
    C("adjust_image_points_unknown_image", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["image_points.csv", "s09_001"],
      field("p/control/image_points.csv", 2, 1, "s09_001")),
    C("adjust_eo_unknown_image", "aerotri", f"adjust {{p}} --eo {{w}}/p/truth/eo.txt {_NO_EXPORTS}",
      ["eo.txt", "s01_001"], field("p/truth/eo.txt", 2, 0, "s09_001")),
    C("adjust_gnss_unknown_image", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["gnss.txt", "s01_001"],
      field("p/gnss.txt", 2, 0, "s09_001")),
    C("rectify_eo_unknown_image", "ortho", "rectify {p}", ["eo.txt", "s01_001"], field("p/at/eo.txt", 2, 0, "s09_001")),
    C("rectify_frames_twice", "ortho", "rectify {p} --frames s01_001,s01_001", ["--frames", "s01_001"]),
    C("control_eo_unknown_image", "aerotri", "control {p}", ["images", "s09_001"], field("p/at/eo.txt", 2, 0, "s09_001")),
    C("control_image_points_for_frame_without_image", "aerotri", "control {p} --import-manual {w}/manual.csv",
      ["images", "s01_002"], all_of(manual(), remove("p/images/s01_002.tif"))),
    C("export_image_points_unknown_point", "aerotri", "export {p} --format odm", ["image_points.csv", "RC99999"],
      field("p/control/image_points.csv", 2, 0, "RC99999")),
    C("strips_adjust_fixed_unknown", "lidarctl", "strips adjust {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out "
      "--fixed nope", ["--fixed", "nope"]),
    C("check_vectors_layer_unknown", "lidarctl", "check-vectors {w}/lid/v.gpkg --reference {w}/lid/v.gpkg "
      "--layer nope", ["--layer", "nope"]),
    C("trees_classes_absent", "lidarctl", "trees {w}/las/cloud.las {w}/out --classes 13", ["--classes", "13"]),
    C("trees_classes_text", "lidarctl", "trees {w}/las/cloud.las {w}/out --classes a,b", "--classes"),
    C("evaluate_map_pred_unknown_class", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/cloud.laz "
      "--map-pred 300:1", "--map-pred"),
    C("check_vectors_product_missing", "lidarctl", "check-vectors {w}/nope.gpkg --reference {w}/lid/v.gpkg",
      "nope.gpkg"),
    C("check_vectors_reference_empty", "lidarctl", "check-vectors {w}/lid/v.gpkg --reference {w}/empty.gpkg",
      "empty.gpkg", empty("empty.gpkg")),
    C("check_vectors_reference_not_gpkg", "lidarctl", "check-vectors {w}/lid/v.gpkg --reference {w}/las/points.csv",
      "points.csv"),
    C("evaluate_reference_polygons_empty", "lidarctl", "evaluate {w}/lid/bldg.las --reference {w}/ref.geojson",
      "ref.geojson", write("ref.geojson", '{{"type": "FeatureCollection", "features": []}}')),
    C("evaluate_reference_polygons_no_crs_other_place", "lidarctl", "evaluate {w}/lid/bldg.las --reference "
      "{w}/ref.geojson --reference-class building", "ref.geojson",
      write("ref.geojson", '{{"type": "FeatureCollection", "features": [{{"type": "Feature", "properties": {{}}, '
            '"geometry": {{"type": "Polygon", "coordinates": [[[10, 50], [10.001, 50], [10.001, 50.001], [10, 50]]]}}}}]}}')),
    C("vectors_contours_layer_empty", "lidarctl", "vectors {w}/lid/bldg.las --contours {w}/c.geojson {w}/out.gpkg",
      "c.geojson", write("c.geojson", "")),
    C("adjust_planes_empty", "aerotri", f"adjust {{p}} --dem {{w}}/p/lidar_out/dem.tif --planes {{w}}/planes "
      f"{_NO_EXPORTS}", "roof_planes.geojson",
      write("planes/roof_planes.geojson", '{{"type": "FeatureCollection", "features": []}}')),
    C("classify_ground_params_inf", "lidarctl", "classify {w}/las/raw.las {w}/out.las --ground-params {w}/g.toml",
      ["g.toml", "cell_m"], write("g.toml", "[morph]\ncell_m = inf\n")),
    C("classify_ground_params_text", "lidarctl", "classify {w}/las/raw.las {w}/out.las --ground-params {w}/g.toml",
      ["g.toml", "cell_m"], write("g.toml", '[morph]\ncell_m = "abc"\n')),
    C("classify_ground_params_empty", "lidarctl", "classify {w}/las/raw.las {w}/out.las --ground-params {w}/g.toml",
      ["g.toml"], write("g.toml", "[morph\n")),
    C("report_tolerances_inf", "aerotri", "report {p} --no-pdf --tolerances {w}/tol.toml", "tol.toml",
      lambda w: (w / "tol.toml").write_text(
          _first_tolerance_table().replace("= 0.", "= inf  # was 0.", 1))),
    C("report_tolerances_text", "aerotri", "report {p} --no-pdf --tolerances {w}/tol.toml", "tol.toml",
      lambda w: (w / "tol.toml").write_text(_first_tolerance_table().replace("= 0.", '= "abc"  # was 0.', 1))),
    C("merge_output_is_input", "lidarctl", "merge {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/lid/strip_1.las",
      "strip_1.las"),
    C("merge_geographic_crs", "lidarctl", "merge {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out.las --crs EPSG:4326",
      "--crs"),
    C("merge_project_crs_other_zone", "lidarctl", "merge {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out.las "
      "--crs EPSG:32633", "strip_1.las"),
    C("camera_focal_inf", "aerotri", "match {p}", ["camera.toml", "focal_mm"],
      toml_set("p/camera.toml", None, "focal_mm", "inf")),
    C("camera_focal_negative", "aerotri", "match {p}", ["camera.toml", "focal_mm"],
      toml_set("p/camera.toml", None, "focal_mm", "-120.0")),
    C("camera_pixel_zero", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["camera.toml", "pixel_um"],
      toml_set("p/camera.toml", None, "pixel_um", "0.0")),
    C("camera_width_one", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["camera.toml", "1 x 240"],
      toml_set("p/camera.toml", None, "width", "1")),
    C("camera_empty", "aerotri", "match {p}", "camera.toml", empty("p/camera.toml")),
    C("project_toml_empty", "aerotri", "match {p}", "project.toml", empty("p/project.toml")),
    C("project_terrain_inf", "aerotri", "match {p}", ["project.toml", "mean_terrain_height_m"],
      toml_set("p/project.toml", "flight", "mean_terrain_height_m", "inf")),
    C("project_sigma_xy_inf", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["project.toml", "sigma_xy_m"],
      toml_set("p/project.toml", "gnss", "sigma_xy_m", "inf")),
    C("project_crs_feet_geographic_heights", "aerotri", "match {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:4979"')),
    C("sim_preset_inf", "aerotri", "sim --preset tiny --set flight.side_overlap=inf {w}/out", "flight.side_overlap"),
    C("sim_preset_nan", "aerotri", "sim --preset tiny --set flight.strips=nan {w}/out", "flight.strips"),

    # --- option values: NaN, infinities, negative, zero where the option names a size
    *[C(f"opt_{cid}_{opt[2:].replace('-', '_')}_{vid}", prog, f"{args} {opt} {val}", opt)
      for cid, prog, args, opts in [
          ("warp", "aerotri", "crs warp {w}/p/lidar_out/dem.tif {w}/out.tif --to EPSG:32650", ["--res-m"]),
          ("rasters", "lidarctl", "rasters {w}/las/cloud.las {w}/out --res-m 1", ["--dem-fill-radius-px"]),
          ("evaluate", "lidarctl", "evaluate {w}/lid/bldg.las --reference {w}/lid/c/corners.geojson", ["--min-building-m2"]),
          ("contours", "lidarctl", "contours {w}/lid/r/dem.tif {w}/out.gpkg --interval-m 1", ["--tension", "--tolerance-px"]),
          ("drainage", "lidarctl", "drainage {w}/lid/r/dem.tif {w}/out", ["--simplify-px", "--min-area-m2"]),
          ("smooth", "lidarctl", "smooth {w}/lid/r/dem.tif {w}/out.tif", ["--edge-m", "--step"]),
          ("sim", "aerotri", "sim --preset tiny {w}/out", ["--tie-sigma-px", "--bad-control-shift-m", "--blunder-fraction"]),
          ("trees", "lidarctl", "trees {w}/las/cloud.las {w}/out", ["--res-m", "--smooth-px", "--top-radius-m"]),
          ("corners", "lidarctl", "corners {w}/lid/bldg.las {w}/out", ["--tile-m", "--sigma-strip-xy-m"]),
          ("strips_check", "lidarctl", "strips check {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out", ["--cell-m"]),
          ("vectors", "lidarctl", "vectors {w}/lid/bldg.las {w}/out.gpkg", ["--cell-m", "--spot-spacing-m"]),
          ("check_vectors", "lidarctl", "check-vectors {w}/lid/v.gpkg --reference {w}/lid/v.gpkg", ["--buffer-m"]),
          ("check_plan", "lidarctl", "check-plan {w}/lid/bldg.las {w}/lid/c/corners.csv", ["--min-edge-m"]),
          ("adjust", "aerotri", f"adjust {{p}} {_NO_EXPORTS}", ["--surface-sigma-m", "--max-ndsm-m", "--plane-sigma-m"]),
          ("match", "aerotri", "match {p}", ["--image-top-deg"]),
          ("control", "aerotri", "control {p}", ["--full-spacing-baselines", "--eo-sigma-px"]),
          ("mosaic", "ortho", "mosaic {p}", ["--feather-m"]),
          ("rectify", "ortho", "rectify {p}", ["--res-m"]),
      ]
      for opt in opts
      for vid, val in [("nan", "nan"), ("inf", "inf"), ("minus_inf", "-inf")]
      if not (opt == "--blunder-fraction" and vid == "nan")],  # (sim_blunder_fraction: 2 is refused already)
    # --- numbers in JSON products a later stage reads
    C("rectify_adjusted_camera_text", "ortho", "rectify {p}", ["at/camera.toml", "focal_mm"],
      toml_set("p/at/camera.toml", None, "focal_mm", '"abc"')),
    C("control_adjusted_camera_inf", "aerotri", "control {p}", ["at/camera.toml", "focal_mm"],
      toml_set("p/at/camera.toml", None, "focal_mm", "inf")),
    C("mosaic_index_text", "ortho", "mosaic {p}", ["index.json", "x_left_m"],
      json_set("p/ortho/frames/index.json", ["frames", 0, "x_left_m"], "abc")),
    C("mosaic_index_nan", "ortho", "mosaic {p}", ["index.json", "res_m"],
      json_set("p/ortho/frames/index.json", ["res_m"], float("nan"))),
    C("export_report_local_frame_text", "aerotri", "export {p} --format colmap", ["report.json", "origin_map"],
      json_set("p/at/report.json", ["local_frame", "origin_map"], "abc")),
    # --- aerotri run: every input of a later stage is checked before the first stage runs
    C("run_reference_1x1", "aerotri", "run {p} --reference {w}/p/truth/ortho.tif", ["ortho.tif", "2 x 2"],
      raster("p/truth/ortho.tif", "1x1")),
    C("run_reference_no_crs", "aerotri", "run {p} --reference {w}/p/truth/ortho.tif", ["ortho.tif", "CRS"],
      raster("p/truth/ortho.tif", "no_crs")),
    C("run_points_text", "aerotri", "run {p} --points {w}/pts.csv", ["pts.csv", "abc"],
      write("pts.csv", "id,x,y,z\nA,452200.0,abc,310.0\n")),
    C("run_points_header_only", "aerotri", "run {p} --points {w}/pts.csv", "pts.csv", write("pts.csv", "id,x,y,z\n")),
    C("run_points_inf", "aerotri", "run {p} --points {w}/pts.csv", "pts.csv",
      write("pts.csv", "id,x,y,z\nA,452200.0,3407300.0,inf\n")),
    C("run_ndsm_inf", "aerotri", "run {p}", ["ndsm.tif", "inf"],
      all_of(toml_set("p/project.toml", "mosaic", "ndsm", '"lidar_out/ndsm.tif"'), raster("p/lidar_out/ndsm.tif", "inf"))),
    # --- import (the checks of imports are another task of issue 39: EXCHANGE_CASES below)
    C("import_exif_image_cut_in_its_header", "aerotri", "import {p} --format exif {w}/cut", ["s01_002.tif", "truncated"],
      lambda w: _cut_in_its_header(w / "p/images", w / "cut", "s01_002.tif")),
    C("import_file_missing", "aerotri", "import {p} --format patb {w}/nope.ori", "nope.ori"),
    C("import_patb_ori_text", "aerotri", "import {p} --format patb {w}/p/at/patb/block.ori --force", "block.ori",
      lambda w: (w / "p/at/patb/block.ori").write_text(_text(w / "p/at/patb/block.ori").replace("452166.6546", "abc"))),
    C("import_sigma_nan", "aerotri", "import {p} --format odm {w}/gcp_list.txt --sigma-xyz-m nan 1 1", "--sigma-xyz-m"),
    C("import_sigma_inf", "aerotri", "import {p} --format odm {w}/gcp_list.txt --sigma-xyz-m 1 inf 1", "--sigma-xyz-m"),
    C("import_patb_same_file_twice", "aerotri", "import {p} --format patb {w}/p/at/patb/block.ori "
      "{w}/p/at/patb/block.ori --force", ["block.ori", "second"]),
    # --- export and demo
    C("export_object_points_text", "aerotri", "export {p} --format odm", "object_points.csv",
      table("p/at/object_points.csv", "text")),
    C("export_object_points_header_only", "aerotri", "export {p} --format colmap", "object_points.csv",
      table("p/at/object_points.csv", "header_only")),
    C("export_eo_other_zone", "aerotri", "export {p} --format gpkg", "eo.txt", other_zone("p/at/eo.txt", (1, 2))),
    C("export_out_is_file", "aerotri", "export {p} --format odm --out {w}/out", "out", write("out", "a file\n")),
    C("demo_unknown_preset", "aerotri", "demo {w}/out --preset nosuch", "nosuch"),
    C("demo_outdir_is_file", "aerotri", "demo {w}/out --preset tiny", "out", write("out", "a file\n")),
    C("opt_sim_n_control_negative", "aerotri", "sim --preset tiny --n-control -1 {w}/out", "--n-control"),
    C("opt_sim_seed_negative", "aerotri", "sim --preset tiny --seed -1 {w}/out", "--seed"),
    C("opt_sim_tie_sigma_negative", "aerotri", "sim --preset tiny --tie-sigma-px -0.3 {w}/out", "--tie-sigma-px"),
    C("opt_warp_res_zero", "aerotri", "crs warp {w}/p/lidar_out/dem.tif {w}/out.tif --to EPSG:32650 --res-m 0", "--res-m"),
    C("opt_warp_res_tiny", "aerotri", "crs warp {w}/p/lidar_out/dem.tif {w}/out.tif --to EPSG:32650 --res-m 1e-7",
      ["--res-m", "GiB"]),
    C("opt_rasters_res_tiny", "lidarctl", "rasters {w}/las/cloud.las {w}/out --res-m 1e-7", ["--res-m", "GiB"]),
    C("opt_trees_res_tiny", "lidarctl", "trees {w}/las/cloud.las {w}/out --res-m 1e-7", ["--res-m", "GiB"]),
    C("opt_strips_cell_tiny", "lidarctl", "strips check {w}/lid/strip_1.las {w}/lid/strip_2.las {w}/out --cell-m 1e-7",
      "--cell-m"),
    C("opt_vectors_cell_tiny", "lidarctl", "vectors {w}/lid/bldg.las {w}/out.gpkg --cell-m 1e-7", "--cell-m"),
    C("opt_evaluate_res_tiny", "lidarctl", "evaluate {w}/lid/bldg.las --reference {w}/ref.geojson "
      "--reference-class building --res-m 1e-7", "--res-m",  # class_grid.check_grid names the option
      write("ref.geojson", _BUILDING_GEOJSON)),
    C("opt_classify_tile_tiny", "lidarctl", "classify {w}/las/raw.las {w}/out.las --tile-size-m 1e-7", "tile size"),
    C("opt_control_eo_sigma_huge", "aerotri", "control {p} --eo-sigma-px 1e9", "--eo-sigma-px"),
    C("opt_check_search_huge", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --search-px 1000000",
      "--search-px"),
    C("opt_trees_smooth_huge", "lidarctl", "trees {w}/las/cloud.las {w}/out --smooth-px 1e12", "--smooth-px"),
]


CASES += [c for c in ISSUE39 if c.id not in {c.id for c in CASES}]  # (a few existed already: rectify_dem_rgb)

def _exported(fmt: str):
    """``w/exp``: the project exported in ``fmt`` (the files an import reads)."""
    def f(w):
        _ok("aerotri", "export", w / "p", "--format", fmt, "--out", w / "exp")
    return f


# Imports (aerotri/exchange: their checks are another task of issue 39, i39-exchange): run by
# bench/eval_bad_input.py and reported, not asserted here.
EXCHANGE_CASES = [
    C("import_odm_project_crs_feet", "aerotri", "import {p} --format odm {w}/exp/odm/gcp_list.txt --force --sigma-xyz-m "
      "0.05 0.05 0.1", ["project.toml", "EPSG:2264"],
      all_of(_exported("odm"), toml_set("p/project.toml", "project", "crs", '"EPSG:2264"'))),
    C("import_odm_project_crs_degrees", "aerotri", "import {p} --format odm {w}/exp/odm/gcp_list.txt --force "
      "--sigma-xyz-m 0.05 0.05 0.1", ["project.toml", "crs"],
      all_of(_exported("odm"), toml_set("p/project.toml", "project", "crs", '"EPSG:4326"'))),
    C("import_odm_image_nowhere", "aerotri", "import {p} --format odm {w}/exp/odm/gcp_list.txt --force --sigma-xyz-m "
      "0.05 0.05 0.1", ["gcp_list.txt", "s09_001"],
      all_of(_exported("odm"), lambda w: (w / "exp/odm/gcp_list.txt").write_text(
          _text(w / "exp/odm/gcp_list.txt").replace("s01_001", "s09_001")))),
    C("import_patb_image_nowhere", "aerotri", "import {p} --format patb {w}/p/at/patb/block.ori --force",
      ["block.ori", "s09_001"], lambda w: (w / "p/at/patb/block.ori").write_text(
          _text(w / "p/at/patb/block.ori").replace("s01_001", "s09_001"))),
    C("import_patb_other_zone", "aerotri", "import {p} --format patb {w}/p/at/patb/block.con --force", "block.con",
      other_zone("p/at/patb/block.con", (1, 2))),
]


# Unusual but valid inputs: they must work (exit 0), not be refused. Units come from the CRS, NaN is nodata.
ACCEPTED = [
    C("check_ndsm_us_feet", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --ndsm {w}/p/lidar_out/ndsm.tif "
      "--patch-px 24 --search-px 4", [], raster("p/lidar_out/ndsm.tif", "us-ft")),
    C("check_ndsm_degrees", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --ndsm {w}/p/lidar_out/ndsm.tif "
      "--patch-px 24 --search-px 4", [], raster("p/lidar_out/ndsm.tif", "degrees")),
    C("warp_rgb_image", "aerotri", "crs warp {w}/p/truth/ortho.tif {w}/out.tif --to EPSG:32650", []),
    C("opt_vectors_spot_spacing_tiny", "lidarctl", "vectors {w}/lid/bldg.las {w}/out.gpkg --spot-spacing-m 1e-7", []),
    # a window wider than the CHM is the whole CHM: bounded work, one top per stand
    C("opt_trees_top_radius_huge", "lidarctl", "trees {w}/las/cloud.las {w}/out --top-radius-m 1e12", []),

    C("contours_dem_us_feet", "lidarctl", "contours {w}/lid/r/dem.tif {w}/out.gpkg --interval-m 1 --no-png", [],
      raster("lid/r/dem.tif", "us-ft")),
    C("smooth_dem_us_feet", "lidarctl", "smooth {w}/lid/r/dem.tif {w}/out.tif", [], raster("lid/r/dem.tif", "us-ft")),
    C("drainage_dem_us_feet", "lidarctl", "drainage {w}/lid/r/dem.tif {w}/out --no-png", [],
      raster("lid/r/dem.tif", "us-ft")),
    C("contours_dem_degrees", "lidarctl", "contours {w}/lid/r/dem.tif {w}/out.gpkg --interval-m 1 --no-png", [],
      raster("lid/r/dem.tif", "degrees")),
    C("contours_dem_2x2", "lidarctl", "contours {w}/lid/r/dem.tif {w}/out.gpkg --interval-m 0.5 --no-png", [],
      lambda w: _crop(w / "lid/r/dem.tif", 2, 2)),
    C("smooth_dem_2x2", "lidarctl", "smooth {w}/lid/r/dem.tif {w}/out.tif", [], lambda w: _crop(w / "lid/r/dem.tif", 2, 2)),
    C("check_heights_dem_us_feet", "lidarctl", "check-heights {w}/las/points.csv --dem {w}/lid/r/dem.tif", [],
      all_of(raster("lid/r/dem.tif", "us-ft"), _points_to_us_feet("las/points.csv"))),
    C("rectify_dem_nan_nodata", "ortho", "rectify {p}", [], _nan_holes("p/lidar_out/dem.tif")),
    C("rasters_cloud_us_feet", "lidarctl", "rasters {w}/las/cloud.las {w}/out --res-m 1", [],
      lambda w: _las_to_us_feet(w / "las/cloud.las")),
]


def _write_other_las(w):
    from lidarctl import synthetic

    cloud, truth = synthetic.synthetic_scene(width_m=30.0, density_per_m2=2.0, n_buildings=0, n_trees=2, seed=9)
    synthetic.write_las(w / "las" / "other.las", cloud, classification=truth, crs="EPSG:32632")


def _leaf_commands(prog: str) -> list[tuple]:
    """Every command of a command line as its words, e.g. ("crs", "fit"), ("rectify",)."""
    import click

    def walk(cmd, words):
        if isinstance(cmd, click.Group):
            for name, sub in cmd.commands.items():
                yield from walk(sub, words + (name,))
        else:
            yield words

    return list(walk(_cli(prog), ()))


def test_corpus_is_large_and_ids_unique():
    ids = [c.id for c in CASES + ACCEPTED + EXCHANGE_CASES]
    assert len(ids) == len(set(ids))
    assert len(CASES) >= 700
    # every command of the three command lines has bad-input cases
    covered = {(c.prog, *c.args[:2]) for c in CASES}
    for prog in ("aerotri", "lidarctl", "ortho"):
        for words in _leaf_commands(prog):
            assert any(k[:len(words) + 1] == (prog, *words) for k in covered), (prog, words)


# ----------------------------------------------------------------------------------------------
# Running a case


def snapshot(root: Path) -> dict:
    """Every file and folder below ``root``: a file by its size, modification time and inode (a write in place
    changes the time, an atomic replace the inode; hashing the 14 MB of every case's copy twice cost a third of
    the corpus's run time)."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        for n in dirnames:
            out[str((d / n).relative_to(root)) + "/"] = "dir"
        for n in filenames:
            q = d / n
            st = q.lstat()
            out[str(q.relative_to(root))] = "link" if q.is_symlink() else (st.st_size, st.st_mtime_ns, st.st_ino)
    return out


PARTS = ("p", "las", "lid")  # the workspace's top-level folders


def _strings(obj, depth: int = 0):
    """The strings of a case's setup: its closure's values and its code's constants, recursively."""
    if isinstance(obj, str):
        yield obj
    elif isinstance(obj, (tuple, list)):
        for o in obj:
            yield from _strings(o, depth + 1)
    elif depth < 6 and hasattr(obj, "co_consts"):
        for o in obj.co_consts:
            yield from _strings(o, depth + 1)
    elif depth < 6 and callable(obj):
        yield from _strings(getattr(obj, "__code__", None) and obj.__code__.co_consts or (), depth + 1)
        for cell in getattr(obj, "__closure__", None) or ():
            try:
                yield from _strings(cell.cell_contents, depth + 1)
            except ValueError:  # an empty cell
                pass


def needed_parts(case: Case) -> set:
    """The workspace folders a case reads or breaks (copied for it; the others are not): named in its
    command line as {p} or {w}/<part>, or as "<part>/..." in its setup (none: e.g. aerotri sim)."""
    text = " ".join(case.args)
    strings = list(_strings(case.setup)) if case.setup is not None else []
    out = {part for part in PARTS
           if f"{{w}}/{part}/" in text or f"{{w}}/{part}" in case.args or (part == "p" and "{p}" in text)
           or any(q.startswith(part + "/") or f"{{w}}/{part}/" in q for q in strings)}
    return out


def written_by_setup(case: Case) -> Callable[[str], bool]:
    """Whether a workspace-relative path may be written in place by the case's setup: named in it (a string of
    its closure or code), lying in a folder named there, or its file name named there. Those files are copied for
    the case, the others hard-linked (``linked_copy``, which fails the case if it wrote into a linked file)."""
    names = {s.replace("{w}/", "").replace("{p}", "p").strip("/") for s in _strings(case.setup)} \
        if case.setup is not None else set()
    names.discard("")
    return lambda rel: any(rel == s or rel.startswith(s + "/") or os.path.basename(rel) == s for s in names)


def prepare(case: Case, workspace: Path, tmp_path: Path, linked_copy) -> Path:
    w = tmp_path / "w"
    w.mkdir()
    written = written_by_setup(case)
    for part in needed_parts(case):
        linked_copy(workspace / part, w / part, copied=lambda rel, part=part: written(f"{part}/{rel}"))
    if case.setup is not None:
        case.setup(w)
    return w


def formatted(seq, w: Path):
    return [s.format(w=w, p=w / "p") for s in seq]


def check_failure(case: Case, w: Path, before: dict, exit_code: int, stderr: str, exception=None):
    after = snapshot(w)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k)
                     and not any(k.startswith(c) for c in case.caches))
    assert "Traceback" not in stderr, stderr
    assert exception is None or isinstance(exception, SystemExit), repr(exception)
    assert exit_code == 2, f"exit code {exit_code}; stderr: {stderr}"
    errors = [s for s in stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1, stderr
    for s in formatted(case.expect, w):
        assert s in errors[0], f"{s!r} not in {errors[0]!r}"
    assert not changed, f"files written, changed or removed: {changed[:10]}"


class Hang(BaseException):
    """A command still running after its time limit (a BaseException: the command's handlers let it through)."""


@contextlib.contextmanager
def time_limit(seconds: float):
    """``Hang`` raised in the main thread after ``seconds`` (a loop without end fails the case instead of the
    suite hanging); work in C that never returns to Python is not interrupted."""
    def alarm(signum, frame):
        raise Hang(f"still running after {seconds:g} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


CASE_SECONDS = 60.0  # every bad input is refused within a second or two; a case beyond a minute hangs


def invoke(case: Case, w: Path, seconds: float = CASE_SECONDS):
    """The command of ``case`` in-process (click's CliRunner) on workspace ``w``, with a time limit."""
    with time_limit(seconds):
        return CliRunner().invoke(_cli(case.prog), formatted(case.args, w))


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in CASES])
def test_bad_input(case: Case, workspace, tmp_path, linked_copy):
    w = prepare(case, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    r = invoke(case, w)
    check_failure(case, w, before, r.exit_code, r.stderr, r.exception)


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in ACCEPTED])
def test_accepted_input(case: Case, workspace, tmp_path, linked_copy):
    """Unusual but valid inputs (a DEM in US feet or degrees, NaN as nodata, 2 x 2 cells) are not refused."""
    w = prepare(case, workspace, tmp_path, linked_copy)
    r = invoke(case, w)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert r.exit_code == 0, r.stderr


SUBPROCESS_CASES = ["match_gnss_utf16", "match_image_all_black", "rectify_res_too_fine", "crs_transform_truncated_laz",
                    "contours_dem_1x1", "rasters_points_on_one_spot"]


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in CASES if c.id in SUBPROCESS_CASES])
def test_bad_input_subprocess(case: Case, workspace, tmp_path, linked_copy):
    """The console script itself: no traceback escapes a real process."""
    w = prepare(case, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    # what the console script does (``main()`` of the command group) in a fresh interpreter; the source tree
    # on the path, so that it does not depend on how the package is installed
    module = {"aerotri": "aerotri.cli", "lidarctl": "lidarctl.cli.main", "ortho": "ortho.cli"}[case.prog]
    code = f"import sys; sys.argv[0] = {case.prog!r}; from {module} import main; sys.exit(main())"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", code, *formatted(case.args, w)], capture_output=True, text=True,
                       timeout=120, env=env)
    check_failure(case, w, before, r.returncode, r.stderr)
