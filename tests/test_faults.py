"""Faults over every command that writes (issue 39): disk full, a read-only output folder, a kill in the middle
and the re-run after it, a failure between two files, an input that vanishes while the command runs.

One workspace is built per module: the simulator's ``tiny`` project with every stage's products (tie points,
control from the truth corners, adjustment and exports, frame orthos, mosaic, DOM check, report, and a
resumable-run stamp set), small synthetic LiDAR files with each ``lidarctl`` command's products, two synthetic
strips, the ``aerotri crs`` inputs and products. So every output a fault case's command writes exists
already: "all old" is checked against real earlier products (files compared by content *and* inode, so a
new file that happens to equal the old one still counts as new).

The faults are injected in-process (``FaultInjector``): creating a file or folder below the output area fails
with ENOSPC (disk full) or EROFS (read-only), the n-th move of a finished temporary onto its output fails
(a failure between two files), an input is deleted when the command first opens it (vanished). A kill is a
real SIGKILL of a forked child process running the command at its first or second output move. Every case
expects: exit code 2, one ``Error:`` line naming the path and the cause, no traceback, and the workspace as
it was (after a kill: once the next run of the same command has rolled back and swept what was left).
``test_real_*`` repeat disk full (a file size limit, RLIMIT_FSIZE) and read-only (chmod, run as an
unprivileged user when the tests run as root) on real processes without injection.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
MARKERS = (".part-", ".commit-")


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


# ----------------------------------------------------------------------------------------------
# The commands that write, and how each is run in the workspace (w: workspace, p: the project)


@dataclasses.dataclass(frozen=True)
class Writer:
    id: str
    prog: str
    args: tuple  # formatted with w, p
    area: str  # where its outputs are made (workspace-relative; "." for a folder replaced as a whole): faults of
    # "the output folder" are injected there
    vanish: str | None = None  # an input (workspace-relative) that vanishes when the command first opens it
    moves: int = 2  # output moves it makes: >= 2 gets a failure between two files
    setup: tuple = ()  # workspace-relative paths removed before the case (a stage of `aerotri run` to redo)
    kill_on: str = "move"  # the kill comes at its (second) output move, or ("create") at its third file created


def W(id, prog, args, area, vanish=None, moves=2, setup=(), kill_on="move"):
    return Writer(id, prog, tuple(args.split()), area, vanish, moves, tuple(setup), kill_on)


TRANSFER = "--eo {w}/p/truth/eo.txt --camera {w}/p/truth/camera.toml --min-frames 2"
WRITERS = [
    # aerotri: the project stages
    W("match", "aerotri", "match {p}", "p", "p/images/s01_002.tif"),
    W("adjust", "aerotri", "adjust {p} --gnss-correction shift --self-cal pp,radial", "p", "p/at/tiepoints.csv"),
    W("control", "aerotri", f"control {{p}} {TRANSFER}", "p", "p/lidar_out/corners.csv"),
    W("report", "aerotri", "report {p} --no-pdf", "p", "p/at/report.json"),
    W("export", "aerotri", "export {p} --format patb --format colmap", "p", "p/at/object_points.csv"),
    W("import", "aerotri", "import {p} --format patb {w}/imp/block.ori {w}/imp/block.cam {w}/imp/numbers.txt --force", "p",
      "imp/block.ori"),
    W("run", "aerotri", "run {p} --reference {w}/p/truth/ortho.tif", "p", "p/ortho/frames/s01_002.tif",
      setup=("p/ortho/mosaic.tif",)),  # the mosaic stage (and the checks after it) run again
    W("init", "aerotri", "init {w}/newp --images {p}/images --crs EPSG:32649 --camera {p}/camera.toml", ".",
      "p/camera.toml", moves=1),
    W("sim", "aerotri", "sim --preset {w}/tiny.toml {w}/simout", ".", "tiny.toml", moves=1, kill_on="create"),
    W("crs_fit", "aerotri", "crs fit {w}/las/common.csv --model bursa-wolf7 --from 32649 --to 2361 -o {w}/o/fit.json",
      "o", "las/common.csv", moves=1),
    W("crs_fit_heights", "aerotri", "crs fit-heights {w}/las/heights.csv -o {w}/o/fh.json", "o", "las/heights.csv",
      moves=1),
    W("crs_warp", "aerotri", "crs warp {w}/r/dem.tif {w}/o/warped.tif --to EPSG:32633", "o", "r/dem.tif", moves=1),
    W("crs_transform", "aerotri", "crs transform {w}/las/cloud.las {w}/o/tr.las --to 32633", "o", "las/cloud.las",
      moves=1),
    # lidarctl
    W("classify", "lidarctl", "classify {w}/las/raw.las {w}/o/cls.las", "o", "las/raw.las", moves=1),
    W("rasters", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res-m 1", "r", "las/cloud.las"),
    W("evaluate", "lidarctl", "evaluate {w}/las/cloud.las --truth {w}/las/cloud.laz --json {w}/o/ev.json", "o",
      "las/cloud.laz", moves=1),
    W("check_heights", "lidarctl", "check-heights {w}/las/cloud.las {w}/las/points.csv --json {w}/o/ch.json", "o",
      "las/points.csv", moves=1),
    W("check_plan", "lidarctl", "check-plan {w}/las/roofs.las {w}/las/corners.csv --json {w}/o/cp.json --png "
      "{w}/o/cp.png", "o", "las/corners.csv"),
    W("smooth", "lidarctl", "smooth {w}/r/dem.tif {w}/o/sm.tif", "o", "r/dem.tif", moves=1),
    W("contours", "lidarctl", "contours {w}/r/dem.tif {w}/o/ct.gpkg --interval-m 1", "o", "r/dem.tif"),
    W("drainage", "lidarctl", "drainage {w}/r/dem.tif {w}/dr --min-area-m2 100", ".", "r/dem.tif", moves=1),
    W("vectors", "lidarctl", "vectors {w}/las/cloud.las {w}/o/vec.gpkg", "o", "las/cloud.las", moves=1),
    W("check_vectors", "lidarctl", "check-vectors {w}/o/vec.gpkg --reference {w}/las/ref.gpkg --json {w}/o/cv.json",
      "o", "las/ref.gpkg", moves=1),
    W("corners", "lidarctl", "corners {w}/las/roofs.las {w}/c", "c", "las/roofs.las"),
    W("merge", "lidarctl", "merge {w}/strips/s0.las {w}/strips/s1.las {w}/o/merged.las", "o", "strips/s1.las",
      moves=1),
    W("strips_check", "lidarctl", "strips check {w}/strips/s0.las {w}/strips/s1.las {w}/sc", ".", "strips/s0.las",
      moves=1),
    W("strips_adjust", "lidarctl", "strips adjust {w}/strips/s0.las {w}/strips/s1.las {w}/sa", ".", "strips/s1.las",
      moves=1),
    W("trees", "lidarctl", "trees {w}/las/cloud.las {w}/t", "t", "las/cloud.las"),
    # ortho
    W("rectify", "ortho", "rectify {p}", "p", "p/lidar_out/dem.tif", moves=1),
    W("mosaic", "ortho", "mosaic {p}", "p", "p/ortho/frames/s01_002.tif"),
    W("check", "ortho", "check {p} --reference {w}/p/truth/ortho.tif --patch-px 24 --search-px 4", "p",
      "p/truth/ortho.tif"),
]
# `aerotri demo` is `aerotri sim` followed by `aerotri run` on the simulated project (both here).
WRITER_IDS = [w.id for w in WRITERS]


def formatted(args, w: Path) -> list[str]:
    return [a.format(w=w, p=w / "p") for a in args]


# ----------------------------------------------------------------------------------------------
# The workspace (built once per module)


def _load(name: str, rel: str):
    """A helper module of the other tests (not a test module), loaded by path."""
    spec = importlib.util.spec_from_file_location(name, REPO / "tests" / rel)
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(name, mod)
    spec.loader.exec_module(mod)
    return sys.modules[name]


def _roofs(las: Path) -> None:
    """roofs.las: two flat-roofed buildings on flat ground (classified, UTM 49N) and corners.csv, their eave
    corners as surveyed points (the inputs of ``lidarctl corners`` and ``check-plan``)."""
    import laspy
    import pyproj

    cs = _load("corners_synth", "lidarctl/corners_synth.py")
    buildings = cs.default_buildings()[:2]
    x, y, z, cls, sid = cs.make_cloud(buildings, extent=(0.0, 95.0, 0.0, 85.0), seed=3, heading_deg=-20.0)
    e0, n0 = 452000.0, 3407000.0
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001, 0.001, 0.001]), np.array([e0, n0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(32649))
    data = laspy.LasData(header)
    data.x, data.y, data.z = x + e0, y + n0, z
    data.classification, data.point_source_id = cls, sid
    data.write(las / "roofs.las")
    xyz, _, _ = cs.truth_corners(buildings)
    (las / "corners.csv").write_text("id,x,y,z\n" + "".join(f"K{k},{a + e0:.3f},{b + n0:.3f},{c:.3f}\n"
                                                            for k, (a, b, c) in enumerate(xyz)))


@pytest.fixture(scope="module")
def workspace(request, tmp_path_factory) -> Path:
    """The workspace (module docstring); AEROTRI_FAULTS_WORKSPACE names one built before (by ``build_workspace``,
    for working on these tests: it is copied, never changed)."""
    given = os.environ.get("AEROTRI_FAULTS_WORKSPACE")
    if given:
        w = tmp_path_factory.mktemp("faults") / "w"
        shutil.copytree(given, w, symlinks=True)
        return w
    # every case copies it (prepare): built once per run, shared by the xdist workers
    tiny = request.getfixturevalue("tiny_project")
    return request.getfixturevalue("build_once")("faults", lambda w: build_workspace(tiny, w))


def build_workspace(tiny_project: Path, w: Path) -> None:
    from aerotri.sim.evaluate import write_truth_corners_csv
    from lidarctl import synthetic

    p = w / "p"
    p.mkdir(parents=True)
    shutil.copytree(tiny_project / "images", p / "images")
    for name in ("camera.toml", "project.toml", "gnss.txt"):
        shutil.copy(tiny_project / name, p / name)
    (p / "truth").mkdir()
    for name in ("eo.txt", "camera.toml", "dem.tif", "dsm.tif", "ortho.tif", "roof_corners.csv", "buildings.geojson",
                 "truth.json"):
        shutil.copy(tiny_project / "truth" / name, p / "truth" / name)
    (p / "lidar_out").mkdir()
    shutil.copy(p / "truth" / "dem.tif", p / "lidar_out" / "dem.tif")
    with rasterio.open(p / "truth" / "dem.tif") as a, rasterio.open(p / "truth" / "dsm.tif") as b:
        nd = (b.read(1, masked=True) - a.read(1, masked=True)).filled(-9999).astype(np.float32)
        prof = dict(a.profile, dtype="float32", nodata=-9999)
    with rasterio.open(p / "lidar_out" / "ndsm.tif", "w", **prof) as dst:
        dst.write(nd, 1)
    write_truth_corners_csv(p, p / "lidar_out" / "corners.csv")
    with open(p / "project.toml", "a") as f:  # no LiDAR in the project: the orthophotos' DEM
        f.write('\n[rectify]\ndem = "lidar_out/dem.tif"\n')
    # the project's products: control, an import (PATB files of an earlier adjustment), then the resumable run
    # (its stamps up to date: a fault case's `aerotri run` redoes only what the case removes)
    _ok("aerotri", "control", p, *formatted(TRANSFER.split(), w))
    _ok("aerotri", "match", p)
    _ok("aerotri", "adjust", p, "--no-html")
    (w / "imp").mkdir()
    for name in ("block.ori", "block.cam", "numbers.txt"):
        shutil.copy(p / "at" / "patb" / name, w / "imp" / name)
    _ok("aerotri", "import", p, "--format", "patb", w / "imp" / "block.ori", w / "imp" / "block.cam",
        w / "imp" / "numbers.txt", "--force")
    _ok("aerotri", "run", p, "--reference", p / "truth" / "ortho.tif")
    # LiDAR files
    las = w / "las"
    las.mkdir()
    cloud, truth = synthetic.synthetic_scene(width_m=80.0, density_per_m2=2.0, n_buildings=2, n_trees=4,
                                             n_low_outliers=5, n_high_outliers=2, seed=3)
    synthetic.write_las(las / "cloud.las", cloud, classification=truth, crs="EPSG:32632")
    synthetic.write_las(las / "cloud.laz", cloud, classification=truth, crs="EPSG:32632")
    synthetic.write_las(las / "raw.las", cloud, crs="EPSG:32632")
    rng = np.random.default_rng(0)
    px, py = cloud.x.min() + rng.uniform(5, 55, 8), cloud.y.min() + rng.uniform(5, 55, 8)
    pz = synthetic.terrain_height(px - 500000.0, py - 5400000.0)
    (las / "points.csv").write_text("id,x,y,z\n" + "".join(f"P{k},{a:.3f},{b:.3f},{c:.3f}\n"
                                                            for k, (a, b, c) in enumerate(zip(px, py, pz))))
    from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7, simulate_spatial, write_common_points

    lon, lat, h = rng.uniform(109.6, 110.2, 8), rng.uniform(34.0, 34.5, 8), rng.uniform(400, 900, 8)
    src, dst, _ = simulate_spatial(TRUE_BURSA_WOLF7, 32649, 2361, lon_deg=lon, lat_deg=lat, h_m=h, noise_m=0.01, seed=2)
    write_common_points(las / "common.csv", [f"C{i}" for i in range(8)], src, dst)
    (las / "heights.csv").write_text("id,x,y,h,H\n" + "".join(
        f"H{i},{src[i, 0]:.3f},{src[i, 1]:.3f},{h[i]:.3f},{h[i] + 27.1:.3f}\n" for i in range(8)))
    _roofs(las)
    strips = _load("strips_conftest", "lidarctl/strips/conftest.py")
    (w / "strips").mkdir()
    errors = strips.Errors(shifts_m=np.array([[0.0, 0.0, 0.0], [0.05, -0.03, 0.08]]))
    for k in range(2):
        strips.scan(w / "strips" / f"s{k}.las", w / "strips" / f"t{k}.txt", k, errors, seed=5, n_pulses=8000)
    # the sim case's preset: the tiny block with a quarter of the pixels and of the LiDAR pulses
    (w / "tiny.toml").write_text((REPO / "datasets" / "presets" / "tiny.toml").read_text()
                                 .replace("width = 432", "width = 216").replace("height = 240", "height = 120")
                                 .replace("pulse_rate_hz = 10000.0", "pulse_rate_hz = 2500.0"))
    # every other writer's products, so that a fault case has old outputs to keep
    for wr in sorted(WRITERS, key=lambda wr: wr.id != "rasters"):  # (its DEM is the input of several)
        if wr.area != "p" and wr.id not in ("sim", "init"):  # (those two make new folders)
            _ok(wr.prog, *formatted(wr.args, w))
        if wr.id == "vectors":
            shutil.copy(w / "o" / "vec.gpkg", las / "ref.gpkg")


# ----------------------------------------------------------------------------------------------
# Snapshots


_SHA1: dict[tuple[int, int, int, int], str] = {}


def snapshot(root: Path) -> dict:
    """Every file (sha1 of its bytes, inode) and folder below ``root``; links by their target. A file's bytes are
    hashed once per (device, inode, size, modification time): the cases' files are hard links to the shared
    workspace's, whose times are older than any case, and a write sets the time."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        for n in dirnames:
            q = d / n
            out[str(q.relative_to(root)) + "/"] = "link" if q.is_symlink() else "dir"
        for n in filenames:
            q = d / n
            st = q.lstat()
            if q.is_symlink():
                out[str(q.relative_to(root))] = ("link", os.readlink(q))
                continue
            key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
            if key not in _SHA1:
                _SHA1[key] = hashlib.sha1(q.read_bytes()).hexdigest()
            out[str(q.relative_to(root))] = (_SHA1[key], st.st_ino)
    return out


def differences(before: dict, after: dict) -> list[str]:
    return sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))


def leftovers(root: Path) -> list[str]:
    return sorted(str(q.relative_to(root)) for q in root.rglob(".*")
                  if any(m in q.name for m in MARKERS) or q.name.endswith(".lock"))


def prepare(wr: Writer, workspace: Path, tmp_path: Path, linked_copy, written=()) -> Path:
    """The case's workspace: hard links to the shared one's files (the commands replace their outputs, never write
    into them; ``linked_copy`` fails a case that did), copies of the files the case writes in place (``written``)."""
    w = tmp_path / "w"
    linked_copy(workspace, w, copied=lambda rel: rel in written, symlinks=True)
    for rel in wr.setup:
        (w / rel).unlink()
    return w


# ----------------------------------------------------------------------------------------------
# Fault injection (in-process)


hooks = _load("fault_hooks", "fault_hooks.py")
patched, creation_fails, output_move_fails, vanishes = (hooks.patched, hooks.creation_fails, hooks.output_move_fails,
                                                      hooks.vanishes)


def run_in_process(wr: Writer, w: Path):
    return CliRunner().invoke(_cli(wr.prog), formatted(wr.args, w))


def expect_failure(r, w: Path, before: dict, *needles, allow=()):
    assert "Traceback" not in r.stderr, r.stderr
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert r.exit_code == 2, f"exit {r.exit_code}: {r.stderr}"
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1, r.stderr
    for s in needles:
        assert s in errors[0], f"{s!r} not in {errors[0]!r}"
    # (aerotri run's record of itself: a run that stops writes its rows so far and the stage that stopped, never
    # leaving the last run's "done" rows, trial-overnight; not a product)
    allow = set(allow) | {"p/work/run_summary.json"}
    # (and the earlier run's report, which says that a run stopped before making its own when the disk takes the
    # banner: overnight-fixes)
    marked = {"p/reports/index.html", "p/reports/summary.json"} & set(differences(before, snapshot(w)))
    if marked:
        assert "Stale: the run of " in (w / "p" / "reports" / "index.html").read_text()
        assert "stopped at" in json.loads((w / "p" / "reports" / "summary.json").read_text())["stale"]
    allow |= marked
    changed = [k for k in differences(before, snapshot(w)) if k not in allow]
    assert not changed, f"changed, added or removed: {changed[:12]}"
    assert leftovers(w) == []
    return errors[0]


# ----------------------------------------------------------------------------------------------
# The cases


@pytest.mark.parametrize("wr", WRITERS, ids=WRITER_IDS)
def test_disk_full(wr, workspace, tmp_path, linked_copy):
    """No space left for the first file or folder the command makes for its outputs."""
    w = prepare(wr, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    with creation_fails(w / wr.area, errno.ENOSPC) as hits:
        r = run_in_process(wr, w)
    assert hits, "the command created nothing below its output folder"
    line = expect_failure(r, w, before, "no space left on device")
    assert str(w) in line  # names the output


def _cases(writers):
    return [pytest.param(w, id=w.id) for w in writers]


@pytest.mark.parametrize("wr", _cases([w for w in WRITERS if w.moves >= 2]))
def test_failure_between_two_files(wr, workspace, tmp_path, linked_copy):
    """The second output cannot be completed after the first was: every output stays as it was."""
    w = prepare(wr, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    # (aerotri run's first two moves mark the earlier report as under way, reports/index.html and summary.json,
    # trial s96 M1: a failure there is warned, not the run's; the second move of its first stage's commit fails)
    nth = 2 + (MARK_MOVES if wr.id == "run" else 0)
    with output_move_fails(w / wr.area, nth) as count:
        r = run_in_process(wr, w)
    assert count[0] >= nth, f"only {count[0]} output move(s)"
    expect_failure(r, w, before, "no space left on device")


@pytest.mark.parametrize("wr", WRITERS, ids=WRITER_IDS)
def test_read_only_output_folder(wr, workspace, tmp_path, linked_copy):
    """The output folder is read-only: nothing can be created there (the command's lock is the first thing)."""
    w = prepare(wr, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    area = w / wr.area if (w / wr.area).exists() else (w / wr.area).parent
    with creation_fails(area, errno.EROFS, skip_ours=False) as hits:
        r = run_in_process(wr, w)
    assert hits
    expect_failure(r, w, before, "read-only file system")


@pytest.mark.parametrize("wr", [w for w in WRITERS if w.vanish], ids=[w.id for w in WRITERS if w.vanish])
def test_input_vanishes(wr, workspace, tmp_path, linked_copy):
    """An input is deleted the moment the command opens it: named, nothing written."""
    w = prepare(wr, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    with vanishes(w / wr.vanish) as gone:
        r = run_in_process(wr, w)
    assert gone, f"{wr.vanish} was never opened"
    allow = {wr.vanish}
    if wr.id == "run":
        # aerotri run commits stage by stage: the frame orthos, remade first (the copied workspace's stamp holds
        # the DEM's absolute path), stay; the mosaic stage that found the frame gone leaves its outputs as they were
        allow |= {k for k in before if k.startswith("p/ortho/frames/")} | {"p/work/stages/rectify.json"}
    line = expect_failure(r, w, before, Path(wr.vanish).name, allow=allow)
    if wr.id == "run":
        assert "stopped at mosaic" in json.loads((w / "p" / "reports" / "summary.json").read_text())["stale"]
    assert "not found" in line or "No such file" in line or "cannot read" in line, line


CHILD = """
import importlib.util, os, signal, sys
from pathlib import Path
spec = importlib.util.spec_from_file_location("fault_hooks", {hooks!r})
hooks = importlib.util.module_from_spec(spec)
sys.modules["fault_hooks"] = hooks
spec.loader.exec_module(hooks)
from click.testing import CliRunner
from {module} import main
kill = lambda: os.kill(os.getpid(), signal.SIGKILL)
if {create!r}:
    hook = hooks.creation_kills(Path({area!r}), 3)
else:
    hook = hooks.output_move_fails(Path({area!r}), {at!r}, action=kill)
with hook:
    r = CliRunner().invoke(main, {args!r})
Path({report!r}).write_text(f"exit {{r.exit_code}}\\n{{r.output}}\\n{{r.exception!r}}")
"""


@pytest.fixture(scope="module")
def forkserver():
    """Processes forked from a clean server that has imported the command lines once (a kill case's child
    starts in milliseconds, without the threads of the test process)."""
    import multiprocessing

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["aerotri.cli", "lidarctl.cli.main", "ortho.cli", "click.testing"])
    return ctx


def _kill_child(ctx, wr: Writer, w: Path, at: int) -> tuple[int, str]:
    """Run the command in a child process that SIGKILLs itself at its ``at``-th output move (or its third file
    created); the child's exit code (-9: killed) and what it said when it finished instead."""
    module = {"aerotri": "aerotri.cli", "lidarctl": "lidarctl.cli.main", "ortho": "ortho.cli"}[wr.prog]
    area = w / wr.area if (w / wr.area).exists() else (w / wr.area).parent
    report = w.parent / "child.txt"
    code = CHILD.format(hooks=str(REPO / "tests" / "fault_hooks.py"), module=module, create=wr.kill_on == "create",
                        area=str(area), at=at, args=formatted(wr.args, w), report=str(report))
    p = ctx.Process(target=exec, args=(code, {"__name__": "fault_child"}))
    p.start()
    p.join(600)
    if p.exitcode is None:
        p.kill()
        p.join()
        raise AssertionError("the child did not finish in 600 s")
    return p.exitcode, report.read_text() if report.exists() else ""


FULL_RERUN = {"match", "adjust", "run", "rasters", "classify", "mosaic", "corners", "import", "strips_check"}
MARK_MOVES = 2  # aerotri run's mark of the earlier report (index.html, summary.json) before its first stage


def _command(wr: Writer):
    """The click command object a writer runs (through its groups)."""
    cmd, args = _cli(wr.prog), list(wr.args)
    while hasattr(cmd, "commands"):
        cmd = cmd.commands[args.pop(0)]
    return cmd


@pytest.mark.parametrize("wr", _cases(WRITERS))
def test_kill_and_rerun(wr, workspace, forkserver, tmp_path, linked_copy):
    """SIGKILL in the middle of the command's outputs; the next run of the same command undoes what the killed one
    changed, sweeps its temporaries and (a full re-run) makes valid products."""
    w = prepare(wr, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    code, said = _kill_child(forkserver, wr, w, min(2, wr.moves) + (MARK_MOVES if wr.id == "run" else 0))
    assert code == -signal.SIGKILL, f"child exit code {code}: {said}"
    left = leftovers(w)
    assert left, "the kill left nothing to clean up (killed too late?)"
    # the same command again, up to the point where its work would start (its callback replaced): the
    # clean-up of the killed run is the command's own start
    with patched(_command(wr), "callback", lambda **kw: None):
        r = run_in_process(wr, w)
    assert r.exit_code == 0, r.output
    assert leftovers(w) == [], f"left after the re-run's start: {leftovers(w)[:8]} (before it: {left[:8]})"
    changed = differences(before, snapshot(w))
    # what the killed run finished, kept on purpose for the next run to resume (ortho.block.RESUME_DIR_NAME,
    # aerotri.match.pipeline.RESUME_DIR_NAME, aerotri.control.pipeline.CONTROL_RESUME_DIR_NAME,
    # ortho.mosaic.RESUME_DIR_NAME, aerotri.chain.stages.CLASSIFY_RESUME_DIR_NAME, RASTERS_RESUME_DIR_NAME; lidarctl
    # classify's and rasters' OUT.resume beside the output; an error removes them, a committed run too)
    resume_of = {"rectify": "p/work/rectify_resume/", "match": "p/work/match_resume/",
                 "control": "p/work/control_resume/", "mosaic": "p/work/mosaic_resume/",
                 "classify": "o/cls.las.resume/", "rasters": "r.resume/"}
    chain = ("p/work/rectify_resume/", "p/work/match_resume/", "p/work/control_resume/", "p/work/mosaic_resume/",
             "p/work/classify_resume/", "p/work/rasters_resume/")
    # `aerotri run` may be killed inside any of its stages: whichever stage it was in keeps its finished part
    # (and a killed run leaves no run_summary.json: the last run's would say its stages were done, trial-overnight)
    # (and its mark on the earlier report stays: a run killed in a stage left last night's "pass" unmarked, s96 M1)
    resume = chain + ("p/work/run_summary.json", "p/reports/index.html", "p/reports/summary.json") \
        if wr.id == "run" else resume_of.get(wr.id)
    if resume is not None:
        changed = [c for c in changed if not c.startswith(resume)]
    assert not changed, f"not as before the killed run: {changed[:12]}"
    if wr.id in FULL_RERUN:
        r = run_in_process(wr, w)
        assert r.exit_code == 0, r.output
        assert "Traceback" not in r.stderr
        assert leftovers(w) == []
        after = snapshot(w)
        assert set(after) >= {k for k in before if not k.startswith("p/work/")}, "outputs missing after the re-run"


# ----------------------------------------------------------------------------------------------
# `aerotri run`: the inputs of every stage are checked before the first stage writes


@pytest.mark.parametrize("case", ["reference_truncated", "control_nan_after_match"])
def test_run_refuses_a_bad_later_input_before_its_first_stage(case, workspace, tmp_path, linked_copy):
    """A stage that would run late (the DOM check, the adjustment) has a bad input while earlier stages are out of
    date (the mosaic, the tie points): the run stops before anything is written."""
    wr = next(w for w in WRITERS if w.id == "run")
    # the mosaic (and the DOM check, report after it) would run again
    w = prepare(wr, workspace, tmp_path, linked_copy, written=("p/control/points.csv",))
    args = formatted(wr.args, w)
    if case == "reference_truncated":
        ref = w / "ref.tif"
        ref.write_bytes((w / "p" / "truth" / "ortho.tif").read_bytes()[:4000])
        args[args.index(str(w / "p" / "truth" / "ortho.tif"))] = str(ref)
        expect = "ref.tif"
    else:
        (w / "p" / "work" / "stages" / "match.json").unlink()  # the tie points would be matched again first
        lines = (w / "p" / "control" / "points.csv").read_text().splitlines()
        parts = lines[1].split(",")
        parts[2] = "nan"
        lines[1] = ",".join(parts)
        (w / "p" / "control" / "points.csv").write_text("\n".join(lines) + "\n")
        expect = "points.csv:2"
    before = snapshot(w)
    r = CliRunner().invoke(_cli("aerotri"), args)
    expect_failure(r, w, before, expect)


# ----------------------------------------------------------------------------------------------
# Real faults on real processes (no injection)


def _console(prog, args, cwd, env=None, preexec=None, timeout=900):
    module = {"aerotri": "aerotri.cli", "lidarctl": "lidarctl.cli.main", "ortho": "ortho.cli"}[prog]
    code = f"import sys; sys.argv[0] = {prog!r}; from {module} import main; sys.exit(main())"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]), **(env or {}))
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=cwd, env=env,
                          preexec_fn=preexec, timeout=timeout)


REAL = [W("adjust", "aerotri", "adjust {p} --no-html", "p/at"),
        W("rasters", "lidarctl", "rasters {w}/las/cloud.las {w}/r --res-m 1", "r"),
        W("crs_warp", "aerotri", "crs warp {w}/r/dem.tif {w}/o/warped.tif --to EPSG:32633", "o")]


def _file_size_limit(n_bytes: int):
    def preexec():
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (n_bytes, n_bytes))
    return preexec


@pytest.mark.parametrize("wr", REAL, ids=[w.id for w in REAL])
def test_real_file_size_limit(wr, workspace, tmp_path, linked_copy):
    """The process may not write files beyond 3 kB (RLIMIT_FSIZE): its outputs' writes fail in the middle of a
    file (GDAL's and Python's writes alike), as on a full disk."""
    w = prepare(wr, workspace, tmp_path, linked_copy)
    before = snapshot(w)
    r = _console(wr.prog, formatted(wr.args, w), cwd=w, preexec=_file_size_limit(3000))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and str(w) in errors[0], r.stderr
    assert any(c in errors[0] for c in ("file too large", "no space left", "cut short", "ulimit -f")), errors[0]
    assert differences(before, snapshot(w)) == [] and leftovers(w) == []


def _read_only(folders, tmp_path):
    """Make ``folders`` read-only for this process: ``chmod a-w``, or for root (whom chmod does not stop) the
    immutable attribute (``chattr +i``: no new entry, even for root). Returns the undo, or skips the test
    where neither works (a file system without the attribute, no CAP_LINUX_IMMUTABLE)."""
    if os.geteuid() != 0:
        for d in folders:
            d.chmod(0o555)
        return lambda: [d.chmod(0o755) for d in folders]
    probe = tmp_path / "probe"
    probe.mkdir()
    if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(probe)], capture_output=True).returncode:
        pytest.skip("running as root without chattr +i: no real read-only folder (the injected cases cover it)")
    try:
        (probe / "x").write_text("x")
        works = False
    except OSError:
        works = True
    subprocess.run(["chattr", "-i", str(probe)], check=True)
    if not works:
        pytest.skip("chattr +i does not stop root writing here")
    for d in folders:
        subprocess.run(["chattr", "+i", str(d)], check=True)
    return lambda: [subprocess.run(["chattr", "-i", str(d)], check=True) for d in folders]


@pytest.mark.parametrize("wr", REAL, ids=[w.id for w in REAL])
def test_real_read_only_folder(wr, workspace, tmp_path, linked_copy):
    """The output folder (for a project command the project folder too) is read-only for the command's process."""
    w = prepare(wr, workspace, tmp_path, linked_copy)
    folders = [w / wr.area] + ([w / "p"] if wr.area.startswith("p/") else [])
    before = snapshot(w)
    undo = _read_only(folders, tmp_path)
    try:
        r = _console(wr.prog, formatted(wr.args, w), cwd=w)
    finally:
        undo()
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and str(w) in errors[0], r.stderr
    assert any(c in errors[0] for c in ("permission denied", "operation not permitted", "read-only")), errors[0]
    assert differences(before, snapshot(w)) == []
