"""Bad input over every command: exit code 2, one message naming the file/record or option, no traceback,
no partial output and inputs byte-identical (issue 17).

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
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
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
        from lidarctl.cli import main
    else:
        from ortho.cli import main
    return main


def _ok(prog, *args):
    r = CliRunner().invoke(_cli(prog), [str(a) for a in args], catch_exceptions=False)
    assert r.exit_code == 0, f"{prog} {' '.join(map(str, args))}: {r.output}"
    return r


@pytest.fixture(scope="module")
def workspace(tiny_project, tmp_path_factory) -> Path:
    """``w/p``: the tiny project with every stage's outputs; ``w/las``: small LAS/LAZ and point lists."""
    from aerotri.sim.evaluate import write_truth_corners_csv

    w = tmp_path_factory.mktemp("badinput") / "w"
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
    return w


def _lidar_files(d: Path) -> None:
    from aerotri.crs.synthetic import TRUE_BURSA_WOLF7, simulate_spatial, write_common_points
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
    src, dst, _ = simulate_spatial(TRUE_BURSA_WOLF7, 32649, 2361, lon, lat, h, noise_m=0.01, seed=2)
    write_common_points(d / "common.csv", [f"C{i}" for i in range(8)], src, dst)
    x, y = src[:, 0], src[:, 1]
    (d / "heights.csv").write_text("id,x,y,h,H\n" + "".join(f"H{i},{x[i]:.3f},{y[i]:.3f},{h[i]:.3f},{h[i] + 27.1:.3f}\n"
                                                            for i in range(8)))
    (d / "pts.csv").write_text("id,x,y,z\n" + "".join(f"Q{i},{x[i]:.3f},{y[i]:.3f},{h[i]:.3f}\n" for i in range(8)))


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
    C("match_terrain_height_option_nan", "aerotri", "match {p} --terrain-height nan", "--terrain-height"),
    C("match_budget_zero", "aerotri", "match {p} --budget 0", "--budget"),
    C("match_max_dim_zero", "aerotri", "match {p} --max-dim 0", "--max-dim"),
    C("match_ratio_above_one", "aerotri", "match {p} --ratio 1.5", "--ratio"),
    C("match_min_overlap_negative", "aerotri", "match {p} --min-overlap -0.2", "--min-overlap"),
    C("match_project_is_file", "aerotri", "match {w}/p/gnss.txt", "gnss.txt"),

    # --- aerotri adjust
    C("adjust_alpha_5", "aerotri", "adjust {p} --alpha 5", "--alpha"),
    C("adjust_alpha_0", "aerotri", "adjust {p} --alpha 0", "--alpha"),
    C("adjust_image_sigma_0", "aerotri", "adjust {p} --image-sigma 0", "--image-sigma"),
    C("adjust_image_sigma_negative", "aerotri", "adjust {p} --image-sigma -0.5", "--image-sigma"),
    C("adjust_image_sigma_toml_0", "aerotri", "adjust {p}", ["project.toml", "image_sigma_px"],
      toml_set("p/project.toml", "adjust", "image_sigma_px", "0")),
    C("adjust_image_sigma_toml_string", "aerotri", "adjust {p}", ["project.toml", "image_sigma_px"],
      toml_set("p/project.toml", "adjust", "image_sigma_px", '"half"')),
    C("adjust_lever_arm_toml_nan", "aerotri", "adjust {p}", ["project.toml", "lever_arm_m"],
      toml_set("p/project.toml", "gnss", "lever_arm_m", "[0.05, nan, 1.45]")),
    C("adjust_lever_arm_toml_strings", "aerotri", "adjust {p}", ["project.toml", "lever_arm_m"],
      toml_set("p/project.toml", "gnss", "lever_arm_m", '["a", "b", "c"]')),
    C("adjust_lever_arm_option_nan", "aerotri", "adjust {p} --lever-arm nan 0 1", "--lever-arm"),
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
    C("control_report_json_corrupt", "aerotri", "control {p}", "report.json", binary("p/at/report.json")),
    C("control_report_json_truncated", "aerotri", "control {p}", "report.json", truncate("p/at/report.json", 0.5)),
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
    C("crs_transform_chunk_size_0", "aerotri", "crs transform {w}/las/cloud.las {w}/out.las --to 32633 --chunk-size 0",
      "--chunk-size"),
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
    C("classify_tile_size_negative", "lidarctl", "classify {w}/las/raw.las {w}/out.las --tile-size -50", "--tile-size"),
    C("classify_buffer_negative", "lidarctl", "classify {w}/las/raw.las {w}/out.las --buffer -5", "--buffer"),
    C("classify_unknown_crs", "lidarctl", "classify {w}/las/nocrs.las {w}/out.las --crs EPSG:999999", "--crs"),
    C("classify_geographic_crs", "lidarctl", "classify {w}/las/nocrs.las {w}/out.las --crs EPSG:4326", "--crs"),
    C("rasters_res_zero", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res 0", "--res"),
    C("rasters_res_negative", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res -1", "--res"),
    C("rasters_truncated", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res 1", "cloud.las", truncate("las/cloud.las")),
    C("rasters_no_crs", "lidarctl", "rasters {w}/las/nocrs.las {w}/r --res 1", "nocrs.las"),
    C("rasters_zero_scale", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res 1", "cloud.las",
      patch_bytes("las/cloud.las", 139, struct.pack("<d", 0.0))),
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
    C("check_heights_radius_negative", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv --radius -1",
      "--radius"),
    C("check_heights_exclude_negative", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv --exclude -1",
      "--exclude"),
    C("check_heights_points_utf16", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      utf16("las/points.csv")),
    C("check_heights_points_binary", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      binary("las/points.csv")),
    C("check_heights_points_nan", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      field("las/points.csv", 3, 3, "nan")),
    C("check_heights_points_no_z", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv", "points.csv",
      line("las/points.csv", 1, "id,x,y,q")),
    C("check_heights_points_directory", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv",
      "points.csv", as_dir("las/points.csv")),
    C("check_heights_truncated_cloud", "lidarctl", "check-heights {w}/las/cloud.laz {w}/las/points.csv", "cloud.laz",
      truncate("las/cloud.laz")),
    C("check_plan_radius_negative", "lidarctl", "check-plan {w}/las/cloud.las {w}/las/points.csv --radius -1",
      "--radius"),
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
    C("rectify_res_zero", "ortho", "rectify {p} --res 0", "--res"),
    C("rectify_res_negative", "ortho", "rectify {p} --res -0.5", "--res"),
    C("rectify_res_too_fine", "ortho", "rectify {p} --res 0.0005", ["--res", "GiB"]),
    C("rectify_before_adjust", "ortho", "rectify {p}", "eo.txt", remove("p/at")),
    C("rectify_dem_missing", "ortho", "rectify {p}", "dem.tif", remove("p/lidar_out/dem.tif")),
    C("rectify_dem_truncated", "ortho", "rectify {p}", "dem.tif", truncate("p/lidar_out/dem.tif", 0.5)),
    C("rectify_dem_binary", "ortho", "rectify {p}", "dem.tif", binary("p/lidar_out/dem.tif")),
    C("rectify_dem_partial", "ortho", "rectify {p}", "dem.tif", dem_part("p/lidar_out/dem.tif")),
    C("rectify_dem_rgb", "ortho", "rectify {p}", "band", dem_as_rgb("p/lidar_out/dem.tif")),
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
    C("rectify_crs_bad_gk", "ortho", "rectify {p} --crs gk3:nosuch", "--crs"),
    C("rectify_true_ortho_without_dsm", "ortho", "rectify {p} --true-ortho", "--dsm"),
    C("rectify_project_crs_geographic", "ortho", "rectify {p}", ["project.toml", "crs"],
      toml_set("p/project.toml", "project", "crs", '"EPSG:4326"')),
    C("rectify_report_json_corrupt", "ortho", "rectify {p}", "report.json", binary("p/at/report.json")),

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
    C("run_res_zero", "aerotri", "run {p} --res 0", "--res"),
    C("run_reference_missing", "aerotri", "run {p} --reference {w}/nope.tif", "nope.tif"),
    # a DEM of another CRS or an image given as the DEM stops the run before its first stage
    C("run_dem_other_crs", "aerotri", "run {p} --dem {w}/p/lidar_out/dem.tif", ["dem.tif", "CRS"],
      raster_crs("p/lidar_out/dem.tif", "EPSG:32650")),
    C("run_dem_rgb", "aerotri", "run {p} --dem {w}/p/lidar_out/dem.tif", ["dem.tif", "band"],
      dem_as_rgb("p/lidar_out/dem.tif")),
]


def _write_other_las(w):
    from lidarctl import synthetic

    cloud, truth = synthetic.synthetic_scene(width_m=30.0, density_per_m2=2.0, n_buildings=0, n_trees=2, seed=9)
    synthetic.write_las(w / "las" / "other.las", cloud, classification=truth, crs="EPSG:32632")


def test_corpus_is_large_and_ids_unique():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids))
    assert len(ids) >= 100
    progs = {(c.prog, c.args[0]) for c in CASES}
    for cmd in [("aerotri", "sim"), ("aerotri", "match"), ("aerotri", "adjust"), ("aerotri", "control"),
                ("aerotri", "report"), ("aerotri", "crs"), ("aerotri", "run"), ("lidarctl", "classify"),
                ("lidarctl", "rasters"), ("lidarctl", "evaluate"), ("lidarctl", "check-heights"),
                ("lidarctl", "corners"), ("ortho", "rectify"), ("ortho", "mosaic"), ("ortho", "check")]:
        assert cmd in progs, cmd


# ----------------------------------------------------------------------------------------------
# Running a case


def snapshot(root: Path) -> dict:
    """Every file (sha1 of its bytes) and folder below ``root``."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        for n in dirnames:
            out[str((d / n).relative_to(root)) + "/"] = "dir"
        for n in filenames:
            q = d / n
            out[str(q.relative_to(root))] = hashlib.sha1(q.read_bytes()).hexdigest() if not q.is_symlink() else "link"
    return out


def prepare(case: Case, workspace: Path, tmp_path: Path) -> Path:
    w = tmp_path / "w"
    shutil.copytree(workspace, w)
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


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in CASES])
def test_bad_input(case: Case, workspace, tmp_path):
    w = prepare(case, workspace, tmp_path)
    before = snapshot(w)
    r = CliRunner().invoke(_cli(case.prog), formatted(case.args, w))
    check_failure(case, w, before, r.exit_code, r.stderr, r.exception)


SUBPROCESS_CASES = ["match_gnss_utf16", "match_image_all_black", "rectify_res_too_fine", "crs_transform_truncated_laz"]


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in CASES if c.id in SUBPROCESS_CASES])
def test_bad_input_subprocess(case: Case, workspace, tmp_path):
    """The console script itself: no traceback escapes a real process."""
    w = prepare(case, workspace, tmp_path)
    before = snapshot(w)
    # what the console script does (``main()`` of the command group) in a fresh interpreter; the source tree
    # on the path, so that it does not depend on how the package is installed
    module = {"aerotri": "aerotri.cli", "lidarctl": "lidarctl.cli", "ortho": "ortho.cli"}[case.prog]
    code = f"import sys; sys.argv[0] = {case.prog!r}; from {module} import main; sys.exit(main())"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", code, *formatted(case.args, w)], capture_output=True, text=True,
                       timeout=120, env=env)
    check_failure(case, w, before, r.returncode, r.stderr)
