"""Benchmark ``ortho mosaic`` against ``gdalwarp -of COG`` on the same frame orthos in the same run (issue 41).

Two sets of frame orthos (``ortho/frames`` + ``index.json`` as ``ortho rectify`` writes them):

- ``demo``: the 18 frame orthos of a demo project (``aerotri demo``; ``--demo DIR``, its ``project``
  folder or the project itself), copied with what ``ortho mosaic`` reads (project.toml, camera.toml,
  at/, lidar_out/dem.tif and ndsm.tif, truth/ortho.tif) into the work folder; the inputs are never changed.
- ``large``: synthetic frame orthos for a DOM of at least ``--gp`` gigapixels (default 4.2): DMC-sized
  frames (7,700 x 13,900 px at 0.1 m, 8-bit RGB, tiled ZSTD-1 + predictor with an internal mask, as
  ``ortho rectify`` writes them) in strips with 20 % forward and 10 % side overlap, each a slightly
  rotated footprint (kappa within +-1.5 deg, the corners outside it masked) with its own exposure gain
  (0.93 .. 1.07). Their content is one ground image: the demo's truth orthophoto (0.25 m) mirrored
  across the block and interpolated to 0.1 m, so that overlapping frames agree (no sensor noise: the
  files stay small enough for this machine's shared disk; smooth content compresses better than real
  imagery, for both programs). No nDSM (the seams follow image differences only). The frames are made
  once per work folder and kept (``--keep-large``) or removed at the end.

For each set, in one run, alternating (``--repeats``, default 3 for the demo and 1 for the large set):

- ``ours``: ``ortho mosaic WORK`` (seamlines, gain balancing, feathering, COG with internal overviews);
- ``peer``: ``gdalwarp -q -overwrite -of COG -co COMPRESS=ZSTD -co NUM_THREADS=2 -wo NUM_THREADS=2 -multi``
  of the same frame files (no seamlines, no balancing; the frames' masks are its source validity).
  gdalwarp comes from Debian's gdal-bin (``make bench`` installs it); rasterio's own GDAL has no command
  line tools. Without gdalwarp the run stops and says so.

Each command runs in its own process: wall time, CPU seconds (user + system of that process, from
``os.wait4``; they depend much less on the load of this shared machine than the wall time), peak RSS, output
megapixels per second of wall time and the output file's size; the 1-minute load average before and after each
run and the start time (UTC). On the large set both also run under a ``Sampler`` of the work folder (every 2 s): the
disk they take at their peak above what was there before (outputs, scratch, gdalwarp's temporary files, which it
writes beside its output), the least free disk of the file system and the mean load while they ran. ``ratio`` =
peer wall / ours wall of the same repetition (the median is reported).

The large set's first runs are recorded as they end (``first_ours`` with the DOM's size and sha256, ``first_peer``), so
that a run stopped later loses nothing. The disk is shared: the mosaics start only when ``--min-free-gb`` (default 7)
plus about 2.6 GB per GP of DOM are free; ``ortho mosaic`` is killed (and the run stopped) if the free disk falls under
``--min-free-gb``; our DOM is kept through gdalwarp only when twice its size stays free above it, and removed if the
free disk falls under it while gdalwarp runs. ``--peer-deadline HH:MM`` kills the large set's gdalwarp at that UTC
time (the session's end): its CPU seconds so far are recorded, a lower bound (``peer_unfinished``).

With ``--large-check``, ``ortho check`` of the first large DOM against a reference orthophoto of the same ground image at
0.5 m: its wall, CPU and peak RSS (the check reads the DOM by blocks), and the accuracy it finds; after gdalwarp when
our DOM was kept through it, else between the two (the DOM is then removed, for the disk); ``--check-by HH:MM``: only
if it can start before that UTC time.
On the demo, the DOM check against the truth orthophoto (accuracy before and after this mosaic, from the
demo's own ``ortho/dom_report.json``).

With ``--block DIR`` (repeatable; ``--block-repeats``, default 1) the frame orthos of a chain project ``DIR`` (e.g. a
full-size DMC block run; read only): a project of links to its inputs in the work folder (``link_project``, nothing
copied), ours (and ``--before-src``'s, with the two mosaics' sha256) and the peer on it, under ``block_<name>``.

With ``--subset S,F`` (repeatable) the large set is measured on parts of its frames instead: the first F
frames of the first S strips (a project of links to the frames), smallest first, so that time and peak memory
per gigapixel can be compared across DOM sizes; ``--subset all`` is the whole set.

Writes bench/results/mosaic_speed.json (``--out``); ``--skip-demo`` leaves the demo out (a large-set run on its own,
e.g. ``--out bench/results/mosaic_speed_large.json``). With ``--label KEY`` the run goes under KEY of the ``--out``
file, whose other keys (earlier rounds) are kept. The commit of the code measured is recorded (``commit``). With
``--before-src DIR`` (a source tree of the code before a change, e.g. ``git archive main``) the demo runs that code's
``ortho mosaic`` too, first in every repetition, and records whether the two mosaics have the same sha256.

With ``--floor N`` the start-up floor on the demo: N runs of a process that only imports the modules an ``ortho
mosaic`` run imports (in its order), their CPU seconds, and what that leaves for the mosaic's own work at half of
gdalwarp's CPU seconds (``floor``).

With ``--bytecode`` the measured sources (this tree's ``ortho`` and ``aerotri``, and ``--before-src``'s) are compiled to
bytecode first (``__pycache__``, as pip writes it for a wheel install): an editable install run with
PYTHONDONTWRITEBYTECODE=1 (this machine's sessions) compiles every module of this project in every run, about 0.08
CPU-s of ``ortho mosaic``; recorded as ``bytecode``.

With ``--phases N``, after the timed runs, ``ortho mosaic -v`` runs N more times on the demo (alternately with
``--before-src``'s): the CPU seconds of each phase from its phase timer, medians, as ``phases_cpu_s`` (what is not in a
phase, ``outside_phases``, is the start-up, its imports and the end; ``outputs``: seams.tif, the vector files, the
preview and the summary after the COG).

Usage: python bench/mosaic_speed.py [--demo DIR] [--work DIR] [--gp 4.2] [--repeats N] [--large-repeats N]
       [--skip-demo] [--skip-large] [--keep-large] [--large-check] [--check-by HH:MM] [--peer-deadline HH:MM]
       [--min-free-gb 7] [--subset S,F ...] [--block DIR ...] [--block-repeats N] [--out FILE] [--label KEY]
       [--before-src DIR] [--bytecode] [--phases N] [--floor N]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
PEER = ["gdalwarp", "-q", "-overwrite", "-of", "COG", "-co", "COMPRESS=ZSTD", "-co", "NUM_THREADS=2", "-wo",
        "NUM_THREADS=2", "-multi"]
RES_M = 0.1
FRAME_W, FRAME_H = 7700, 13900  # a DMC frame (13,824 x 7,680 px across x along track) flown east, on the ground
FORWARD, SIDE = 0.20, 0.10  # overlaps
REF_RES_M = 0.5
ORIGIN = (452000.0, 3420000.0)  # top-left corner of the large block (UTM 49N, as the demo)


def tool(name: str) -> str:
    """A console script of this project (next to the interpreter), else from PATH."""
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else (shutil.which(name) or name)


class Sampler:
    """While a command runs, every ``every_s`` seconds: the bytes allocated under ``dirs`` (where the command writes
    its output and scratch), the free bytes of their file system and the 1-minute load average. Peaks (the bytes above
    what was there at the start: the command's peak disk use) and the mean load. ``low_disk()`` is called (once)
    when the free space falls under ``min_free_gb``: e.g. to remove a file kept for later, for the shared disk; without
    ``low_disk`` the command is killed then (``measured`` stops the run and says so)."""

    def __init__(self, dirs, every_s: float = 2.0, min_free_gb: float | None = None, low_disk=None,
                 deadline_utc: str | None = None):
        import threading

        self.dirs, self.every_s, self.min_free_gb, self.low_disk = [Path(d) for d in dirs], every_s, min_free_gb, low_disk
        self.stop_event, self.thread = threading.Event(), threading.Thread(target=self._run, daemon=True)
        self.base = self.peak = self._bytes()
        self.free_min = shutil.disk_usage(self.dirs[0]).free
        self.loads, self.low_disk_at, self.proc = [], None, None
        # HH:MM UTC: the command is killed then (a run that would not end within the session); measured records it
        self.deadline_utc, self.deadline_at = deadline_utc, None

    def _bytes(self) -> int:
        total = 0
        for d in self.dirs:
            for root, _, files in os.walk(d):
                for f in files:
                    try:  # files come and go while the command runs
                        total += os.lstat(os.path.join(root, f)).st_blocks * 512
                    except OSError:
                        pass
        return total

    def _run(self) -> None:
        t0 = time.perf_counter()
        while not self.stop_event.wait(self.every_s):
            self.peak = max(self.peak, self._bytes())
            free = shutil.disk_usage(self.dirs[0]).free
            self.free_min = min(self.free_min, free)
            self.loads.append(os.getloadavg()[0])
            if self.min_free_gb is not None and free < self.min_free_gb * 1e9 and self.low_disk_at is None:
                self.low_disk_at = round(time.perf_counter() - t0, 1)
                if self.low_disk is not None:
                    self.low_disk()
                elif self.proc is not None:
                    self.proc.kill()
            if (self.deadline_utc and self.deadline_at is None and self.proc is not None
                    and time.strftime("%H:%M", time.gmtime()) >= self.deadline_utc):
                self.deadline_at = round(time.perf_counter() - t0, 1)
                self.proc.kill()

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop_event.set()
        self.thread.join()

    def figures(self) -> dict:
        out = {"disk_peak_gb": round((self.peak - self.base) / 1e9, 3), "disk_free_min_gb": round(self.free_min / 1e9, 2),
               "load_1min_mean": round(statistics.fmean(self.loads), 2) if self.loads else None}
        if self.low_disk_at is not None:
            out["low_disk_after_s"] = self.low_disk_at
            if self.low_disk is None:
                out["killed_low_disk"] = f"free disk under {self.min_free_gb} GB after {self.low_disk_at} s: unfinished"
        if self.deadline_at is not None:
            out["killed_at_deadline"] = f"{self.deadline_utc} UTC, after {self.deadline_at} s: unfinished"
        return out


def measured(cmd: list[str], cwd=None, keep_stderr: bool = False, sampler: Sampler | None = None,
             allow_fail: bool = False) -> dict:
    """Run ``cmd`` in its own process: wall s, CPU s (user + system), peak RSS MB, exit code (and its ``stderr`` with
    ``keep_stderr``); with a ``sampler``, its peak disk use, the least free disk and the mean load while it ran. A
    failed command stops the run, or with ``allow_fail`` is returned with ``failed`` (exit code, last error line)."""
    import tempfile

    load = os.getloadavg()[0]
    started = time.strftime("%H:%M:%S", time.gmtime())
    t0 = time.perf_counter()
    # output into files, not pipes: a command writing more than a pipe holds (gdalwarp repeating an error per block)
    # would block until it is read, i.e. for ever
    with tempfile.TemporaryFile() as out_f, tempfile.TemporaryFile() as err_f:
        p = subprocess.Popen(cmd, cwd=cwd, stdout=out_f, stderr=err_f)
        if sampler is not None:
            sampler.proc = p
            sampler.__enter__()
        try:
            # wait4 gives this child's own resource use (RUSAGE_CHILDREN would mix all children so far)
            _, status, ru = os.wait4(p.pid, 0)
        finally:
            if sampler is not None:
                sampler.__exit__(None, None, None)
        wall = time.perf_counter() - t0
        out_f.seek(0)
        err_f.seek(0)
        out, err = out_f.read().decode(errors="replace"), err_f.read().decode(errors="replace")
    code = os.waitstatus_to_exitcode(status)
    figures = {"wall_s": round(wall, 3), "cpu_s": round(ru.ru_utime + ru.ru_stime, 3),
               "peak_rss_mb": round(ru.ru_maxrss / 1024.0, 1), "load_1min_before": round(load, 2),
               "load_1min_after": round(os.getloadavg()[0], 2), "started_utc": started,
               **(sampler.figures() if sampler is not None else {})}
    # killed by the sampler (deadline, disk): the figures so far (``killed_*`` say so), the caller records them
    if code != 0 and any(k.startswith("killed") for k in figures):
        return figures
    if code != 0 and allow_fail:
        return {**figures, "failed": f"exit code {code}: {(err.strip().splitlines() or [''])[-1][:300]}"}
    if code != 0:
        raise SystemExit(f"{' '.join(map(str, cmd))} failed ({code}):\n{err[-3000:]}")
    return {**figures, "stdout": out.strip()[-500:], **({"stderr": err} if keep_stderr else {})}


PHASE_LINE = re.compile(r"mosaic: (.+?) [0-9.]+ s \(CPU ([0-9.]+) s\)")


def phase_cpu(cmd: list[str], cwd=None) -> dict:
    """One ``ortho mosaic -v`` run (``cmd`` ends with its arguments): CPU s of each phase from its phase timer (user +
    system of the whole process, all threads, between the ends of two phases; ``ortho.mosaic._PhaseTimer``), and of
    the whole process (``total``); what is not in a phase is the start-up and the end."""
    r = measured(cmd[:-1] + ["-v", cmd[-1]], cwd=cwd, keep_stderr=True)
    out = {name: float(cpu) for name, cpu in PHASE_LINE.findall(r["stderr"])}
    out["total"] = r["cpu_s"]
    # the run's phases follow one another (``blend and COG`` holds the tiles, overviews and COG, and then the seams'
    # raster, vector files, preview and summary: ``outputs``)
    outer = ("checks", "seam grid", "nDSM", "seams", "gains", "blend and COG")
    out["outputs"] = round(out.get("blend and COG", 0.0) - sum(out.get(k, 0.0) for k in ("tiles", "overviews", "COG")), 3)
    out["outside_phases"] = round(r["cpu_s"] - sum(out.get(k, 0.0) for k in outer), 3)
    return out


def phases(work: Path, runs: int, before_src: Path | None = None) -> dict:
    """``phase_cpu`` of ours (and of ``before_src``'s code) ``runs`` times alternately on ``work``: per phase the
    median."""
    got = {"ours": [], **({"before": []} if before_src is not None else {})}
    for _ in range(runs):
        if before_src is not None:
            got["before"].append(phase_cpu(before_command(before_src) + ["mosaic", str(work)], cwd=work))
        got["ours"].append(phase_cpu([tool("ortho"), "mosaic", str(work)]))
    return {"runs": runs, **{who: {k: round(statistics.median(r[k] for r in rs if k in r), 3) for k in rs[0]}
                             for who, rs in got.items()}}


def mosaic_modules(work: Path) -> list[str]:
    """The modules an ``ortho mosaic`` run of ``work`` has imported by its end, in the order they were imported
    (its click group run in a process of its own, ``sys.modules`` printed after it)."""
    code = ("import json, sys; import ortho.cli as cli; "
            f"cli.main.main(['mosaic', '-q', {str(work)!r}], standalone_mode=False); "
            "print('MODULES ' + json.dumps([m for m in sys.modules if m != '__main__']))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=work)
    line = [x for x in r.stdout.splitlines() if x.startswith("MODULES ")]
    if r.returncode != 0 or not line:
        raise SystemExit(f"ortho mosaic {work} failed ({r.returncode}):\n{r.stderr[-3000:]}")
    return json.loads(line[0][len("MODULES "):])


def floor(work: Path, runs: int, peer_cpu_s: float) -> dict:
    """The start-up floor of ``ortho mosaic`` on ``work``: a process that only imports the modules a run of it imports
    (``mosaic_modules``, in their order), ``runs`` times: its CPU seconds (median), what the run's own work could take
    at most for ``ortho mosaic`` to use half of ``peer_cpu_s`` (gdalwarp's, same run), and the CPU ratio gdalwarp /
    ours if that work took no time at all."""
    mods = mosaic_modules(work)
    # ended as the console script ends (``aerotri.core.console``: no module teardown, which ``ortho`` does not do)
    code = ("import importlib, os, sys\nfor m in sys.argv[1:]:\n    try:\n        importlib.import_module(m)\n"
            "    except Exception:\n        pass\nos._exit(0)\n")
    got = [measured([sys.executable, "-c", code, *mods], cwd=work) for _ in range(runs)]
    cpu = statistics.median(g["cpu_s"] for g in got)
    return {"runs": runs, "modules": len(mods), "imports_cpu_s": round(cpu, 3),
            "imports_wall_s": round(statistics.median(g["wall_s"] for g in got), 3),
            "peer_cpu_s": peer_cpu_s, "work_cpu_s_left_at_2x": round(peer_cpu_s / 2 - cpu, 3),
            "ratio_cpu_if_no_work": round(peer_cpu_s / cpu, 2)}


# --- the demo's frames -----------------------------------------------------------------------------------

def demo_project(demo: Path) -> Path:
    for p in (demo, demo / "project"):
        if (p / "ortho" / "frames" / "index.json").is_file():
            return p
    raise SystemExit(f"{demo}: no demo project with ortho/frames/index.json (run `aerotri demo {demo}` first)")


def copy_demo(src: Path, work: Path) -> Path:
    """The parts of the demo project that ``ortho mosaic`` and ``ortho check`` read, in ``work``."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    for name in ("project.toml", "camera.toml"):
        shutil.copy2(src / name, work / name)
    shutil.copytree(src / "at", work / "at")
    shutil.copytree(src / "ortho" / "frames", work / "ortho" / "frames")
    for rel in ("lidar_out/dem.tif", "lidar_out/ndsm.tif", "truth/ortho.tif", "ortho/dom_report.json"):
        if (src / rel).exists():
            (work / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src / rel, work / rel)
    # the index names the DEM it was rectified on by its path inside the project: the copy has it too
    return work


# --- the large synthetic block ---------------------------------------------------------------------------

def large_layout(gp: float):
    """Frame origins (col, row of the top-left pixel in the block grid), block width and height (px)."""
    step_x, step_y = round(FRAME_W * (1 - FORWARD)), round(FRAME_H * (1 - SIDE))
    side = math.sqrt(gp * 1e9)
    n_x = max(1, math.ceil((side - FRAME_W) / step_x) + 1)
    n_y = max(1, math.ceil((side - FRAME_H) / step_y) + 1)
    while (FRAME_W + (n_x - 1) * step_x) * (FRAME_H + (n_y - 1) * step_y) < gp * 1e9:
        n_x += 1
    frames = [(i * step_x, j * step_y) for j in range(n_y) for i in range(n_x)]
    return frames, FRAME_W + (n_x - 1) * step_x, FRAME_H + (n_y - 1) * step_y, n_x


class Ground:
    """The ground image of the large block: the demo's truth orthophoto mirrored across the block, sampled
    at any resolution (bilinear); RGB uint8."""

    def __init__(self, truth: Path):
        import rasterio

        with rasterio.open(truth) as ds:
            self.img = np.ascontiguousarray(np.moveaxis(ds.read([1, 2, 3]), 0, -1))
            self.res = abs(ds.transform.a)

    def window(self, x0_m: float, y0_m: float, width: int, height: int, res_m: float) -> np.ndarray:
        """(height, width, 3) uint8 of the block area whose top-left corner is (x0_m, y0_m) metres from the
        block's top-left corner (x east, y south), pixels of res_m."""
        import cv2

        h, w = self.img.shape[:2]
        s = res_m / self.res  # source pixels per output pixel
        c0, r0 = x0_m / self.res, y0_m / self.res
        cc = np.floor(c0 + (np.arange(int(width * s) + 3) - 1)).astype(np.int64)
        rr = np.floor(r0 + (np.arange(int(height * s) + 3) - 1)).astype(np.int64)
        period_c, period_r = 2 * w, 2 * h
        mc, mr = cc % period_c, rr % period_r
        mc = np.where(mc < w, mc, period_c - 1 - mc)
        mr = np.where(mr < h, mr, period_r - 1 - mr)
        src = self.img[np.ix_(mr, mc)]
        # output pixel centre (i + 0.5) * s source px from c0 -> index in src: that - (floor(c0) - 1) - 0.5
        ox, oy = c0 - (np.floor(c0) - 1), r0 - (np.floor(r0) - 1)
        M = np.array([[s, 0.0, ox + 0.5 * s - 0.5], [0.0, s, oy + 0.5 * s - 0.5]])
        return cv2.warpAffine(src, M, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REFLECT)


def make_large(work: Path, demo_src: Path, gp: float, seed: int = 41) -> dict:
    """Write the synthetic frame orthos, index.json and the minimal project around them; returns the layout."""
    import cv2
    import rasterio
    from pyproj import CRS
    from rasterio.transform import Affine
    from rasterio.windows import Window

    from aerotri.core.project import Project
    from aerotri.core.records import to_record
    from aerotri.geom.camera import orientations_camera
    from aerotri.core.digest import file_sha256
    from ortho.block import _camera_sha256, file_fingerprint, frame_profile
    from ortho.grid import OrthoGrid

    frames, width, height, per_strip = large_layout(gp)
    marker = work / "large_done.json"
    if marker.is_file():
        done = json.loads(marker.read_text())
        if done.get("gp") == gp and done.get("frames") == len(frames):
            return done
    if work.exists():
        shutil.rmtree(work)
    (work / "ortho" / "frames").mkdir(parents=True)
    for name in ("project.toml", "camera.toml"):
        shutil.copy2(demo_src / name, work / name)
    shutil.copytree(demo_src / "at", work / "at")
    (work / "lidar_out").mkdir()
    shutil.copy2(demo_src / "lidar_out" / "dem.tif", work / "lidar_out" / "dem.tif")
    ground = Ground(demo_src / "truth" / "ortho.tif")
    crs = CRS.from_epsg(32649)
    rng = np.random.default_rng(seed)
    entries = []
    t0 = time.perf_counter()
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        for k, (c0, r0) in enumerate(frames):
            image_id = f"s{k // per_strip + 1:02d}_{k % per_strip + 1:03d}"
            grid = OrthoGrid(crs, ORIGIN[0] + c0 * RES_M, ORIGIN[1] - r0 * RES_M, RES_M, FRAME_W, FRAME_H)
            kappa = np.deg2rad(rng.uniform(-1.5, 1.5))
            gain = rng.uniform(0.93, 1.07)
            inset = 0.02 * min(FRAME_W, FRAME_H)
            # the footprint: the frame rectangle shrunk by 2 % and turned by kappa about its centre
            cx, cy = FRAME_W / 2, FRAME_H / 2
            hw, hh = cx - inset, cy - inset
            corners = np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])
            rot = np.array([[np.cos(kappa), -np.sin(kappa)], [np.sin(kappa), np.cos(kappa)]])
            poly = (corners @ rot.T + [cx, cy]).astype(np.float32)
            path = work / "ortho" / "frames" / f"{image_id}.tif"
            prof = frame_profile(grid, 3, "uint8")
            lut = np.clip(np.rint(np.arange(256) * gain), 0, 255).astype(np.uint8)
            valid_px = 0
            with rasterio.open(path, "w", **prof) as dst:
                for y in range(0, FRAME_H, 1024):
                    h = min(1024, FRAME_H - y)
                    img = cv2.LUT(ground.window(c0 * RES_M, (r0 + y) * RES_M, FRAME_W, h, RES_M), lut)
                    mask = np.zeros((h, FRAME_W), np.uint8)
                    cv2.fillPoly(mask, [np.rint((poly - [0, y]) * 16).astype(np.int32)], 255, shift=4)
                    img = cv2.bitwise_and(img, img, mask=mask)
                    valid_px += int(np.count_nonzero(mask))
                    w = Window(0, y, FRAME_W, h)
                    dst.write(np.ascontiguousarray(np.moveaxis(img, -1, 0)), window=w)
                    dst.write_mask(mask, window=w)
            centre = (grid.x_left_m + cx * RES_M, grid.y_top_m - cy * RES_M)
            entries.append({"image_id": image_id, "file": path.name, "x_left_m": grid.x_left_m, "y_top_m": grid.y_top_m,
                            "width": FRAME_W, "height": FRAME_H, "centre_m": [centre[0], centre[1], 1300.0],
                            "nadir_xy_m": [centre[0], centre[1]], "valid_fraction": valid_px / (FRAME_W * FRAME_H),
                            **to_record(file_fingerprint(path))})
            print(f"  frame {k + 1}/{len(frames)} {image_id} ({time.perf_counter() - t0:.0f} s)", flush=True)
    project = Project.open(work)
    dem = work / "lidar_out" / "dem.tif"
    st = dem.stat()
    index = {"crs": crs.to_wkt(), "crs_name": crs.name, "epsg": 32649, "res_m": RES_M, "project_crs": "EPSG:32649",
             "dem": str(dem), "eo": str(work / "at" / "eo.txt"), "true_ortho": False, "dsm": None,
             "interpolation": "bilinear", "coordinate_operation": None, "operation": None, "height_operation": None,
             "inputs": {"eo": {"file": "at/eo.txt", "given": False, "sha256": file_sha256(work / "at" / "eo.txt")},
                        "camera": {"file": None, "sha256": _camera_sha256(orientations_camera(project)[0])},
                        "dem": {"file": "lidar_out/dem.tif", "size": st.st_size, "mtime_ns": st.st_mtime_ns,
                                "sha256": file_sha256(dem)}},
             "frames": entries}
    (work / "ortho" / "frames" / "index.json").write_text(json.dumps(index, indent=1) + "\n")
    # the reference orthophoto of the check: the same ground at 0.5 m
    ref_w, ref_h = math.ceil(width * RES_M / REF_RES_M), math.ceil(height * RES_M / REF_RES_M)
    ref = work / "reference.tif"
    with rasterio.open(ref, "w", driver="GTiff", width=ref_w, height=ref_h, count=3, dtype="uint8", crs=crs,
                       transform=Affine(REF_RES_M, 0, ORIGIN[0], 0, -REF_RES_M, ORIGIN[1]), tiled=True,
                       blockxsize=512, blockysize=512, compress="zstd", predictor=2) as dst:
        for y in range(0, ref_h, 1024):
            h = min(1024, ref_h - y)
            img = ground.window(0.0, y * REF_RES_M, ref_w, h, REF_RES_M)
            dst.write(np.ascontiguousarray(np.moveaxis(img, -1, 0)), window=Window(0, y, ref_w, h))
    done = {"gp": gp, "frames": len(frames), "frame_px": [FRAME_W, FRAME_H], "block_px": [width, height],
            "block_gp": width * height / 1e9, "frames_gp": len(frames) * FRAME_W * FRAME_H / 1e9,
            "frames_bytes": sum(e["size"] for e in entries), "make_s": round(time.perf_counter() - t0, 1)}
    marker.write_text(json.dumps(done) + "\n")
    return done


# --- runs ------------------------------------------------------------------------------------------------

def mosaic_px(path: Path) -> int:
    import rasterio

    with rasterio.open(path) as ds:
        return ds.width * ds.height


def subset_project(large: Path, work: Path, strips: int, per_strip: int) -> Path:
    """A project in ``work`` of the first ``per_strip`` frames of the first ``strips`` strips of the large set
    (links to its frames and inputs; the large set is not changed)."""
    if work.exists():
        shutil.rmtree(work)
    (work / "ortho" / "frames").mkdir(parents=True)
    for name in ("project.toml", "camera.toml", "reference.tif", "at"):
        os.symlink((large / name).resolve(), work / name)
    (work / "lidar_out").mkdir()
    os.symlink((large / "lidar_out" / "dem.tif").resolve(), work / "lidar_out" / "dem.tif")
    index = json.loads((large / "ortho" / "frames" / "index.json").read_text())
    # image ids are s<strip>_<frame> (make_large)
    index["frames"] = [e for e in index["frames"]
                       if int(e["image_id"][1:3]) <= strips and int(e["image_id"][4:7]) <= per_strip]
    for e in index["frames"]:
        os.symlink((large / "ortho" / "frames" / e["file"]).resolve(), work / "ortho" / "frames" / e["file"])
    (work / "ortho" / "frames" / "index.json").write_text(json.dumps(index, indent=1) + "\n")
    return work


def link_project(src: Path, work: Path) -> Path:
    """A project in ``work`` of links to what ``ortho mosaic`` reads of the chain project ``src`` (project.toml,
    camera.toml, at, lidar_out, ortho/frames); its outputs go to ``work/ortho``, ``src`` is not changed."""
    if not (src / "ortho" / "frames" / "index.json").is_file():
        raise SystemExit(f"{src}: no ortho/frames/index.json (a project after `ortho rectify`)")
    if work.exists():
        shutil.rmtree(work)
    (work / "ortho").mkdir(parents=True)
    for name in ("project.toml", "camera.toml", "at", "lidar_out"):
        if (src / name).exists():
            os.symlink((src / name).resolve(), work / name)
    os.symlink((src / "ortho" / "frames").resolve(), work / "ortho" / "frames")
    return work


def per_gp(result: dict) -> dict:
    """Wall and CPU seconds per gigapixel of DOM of the medians (ours and the peer)."""
    gp, m = result["mosaic_px"] / 1e9, result["median"]
    return {"ours_wall_s_per_gp": round(m["ours_wall_s"] / gp, 1), "ours_cpu_s_per_gp": round(m["ours_cpu_s"] / gp, 1),
            "peer_wall_s_per_gp": round(m["peer_wall_s"] / gp, 1), "peer_cpu_s_per_gp": round(m["peer_cpu_s"] / gp, 1),
            "ratio_peer_over_ours_cpu": round(m["peer_cpu_s"] / m["ours_cpu_s"], 3)}


def sha256_of(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 24), b""):
            h.update(chunk)
    return h.hexdigest()


def before_command(src: Path) -> list[str]:
    """``ortho`` of the source tree ``src`` (e.g. ``git archive`` of main), run by this interpreter: that tree's
    packages first on the path, the editable install of this one left out; through its console script's function
    (``ortho.cli.run``: the process ends without Python's teardown, as ``ortho`` does) where the tree has one, else
    its click group (until i41-mosaic4 always the group: the teardown, 0.2 CPU-s, was counted to the code before)."""
    code = ("import sys; sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f)]; "
            f"sys.path.insert(0, {str(src)!r}); import ortho; assert ortho.__file__.startswith({str(src)!r}); "
            "import ortho.cli as cli; sys.argv = ['ortho'] + sys.argv[1:]; getattr(cli, 'run', cli.main)()")
    return [sys.executable, "-c", code]


def compare(work: Path, repeats: int, label: str, between=None, before_src: Path | None = None, after=None,
            min_free_gb: float | None = None, low_disk=None, peer_deadline: str | None = None) -> dict:
    """Ours and the peer alternately ``repeats`` times on ``work``'s frames. ``between(ours)`` runs after the first of
    ours (record it, e.g. the DOM check); when it returns False our DOM is removed before the peer runs (``between``
    set: disk), when True it is kept. ``after(peer)`` runs after the first of the peer (its output removed), e.g. the
    DOM check of our kept DOM. With ``min_free_gb`` both run under a ``Sampler`` of ``work`` (peak disk use, least
    free disk, mean load) and ``low_disk()`` is called if the free disk falls under it while the peer runs; the peer is
    killed at ``peer_deadline`` (HH:MM UTC; its figures so far are returned, unfinished, without medians). With
    ``before_src`` (a source tree of the code before a change) its ``ortho mosaic`` runs first in every repetition
    (``before``), and the sha256 of both mosaics are recorded."""
    sampler = (lambda **kw: Sampler([work], min_free_gb=min_free_gb, **kw)) if min_free_gb is not None \
        else (lambda **kw: None)
    frames = sorted((work / "ortho" / "frames").glob("*.tif"))
    listing = work / "peer_inputs.txt"
    listing.write_text("\n".join(str(f) for f in frames) + "\n")
    peer_out = work / "peer_mosaic.tif"
    runs = []
    for k in range(repeats):
        before = None
        if before_src is not None:
            print(f"{label}: run {k + 1}/{repeats}: ortho mosaic of {before_src}", flush=True)
            before = measured(before_command(before_src) + ["mosaic", "-q", str(work)], cwd=work)
            before["sha256"] = sha256_of(work / "ortho" / "mosaic.tif")
            print(f"  {before['wall_s']} s wall, {before['cpu_s']} CPU-s, {before['peak_rss_mb']} MB", flush=True)
        print(f"{label}: run {k + 1}/{repeats}: ortho mosaic", flush=True)
        ours = measured([tool("ortho"), "mosaic", "-q", str(work)], sampler=sampler())
        if "killed_low_disk" in ours:
            print(f"  killed, the disk short: {ours}", flush=True)
            for q in (work / "ortho").glob(".mosaic.part-*"):  # its scratch (SIGKILL: not cleaned)
                shutil.rmtree(q, ignore_errors=True)
            return {"ours_killed": ours}
        ours["file_mb"] = round((work / "ortho" / "mosaic.tif").stat().st_size / 1e6, 1)
        if before is not None:
            ours["sha256"] = sha256_of(work / "ortho" / "mosaic.tif")
        print(f"  {ours['wall_s']} s wall, {ours['cpu_s']} CPU-s, {ours['peak_rss_mb']} MB", flush=True)
        if k == 0:
            px = mosaic_px(work / "ortho" / "mosaic.tif")
            if between is not None and not between(ours):
                (work / "ortho" / "mosaic.tif").unlink()
        print(f"{label}: run {k + 1}/{repeats}: gdalwarp", flush=True)
        # in the work folder: whatever temporary files gdalwarp writes there are in its disk peak
        peer = measured(PEER + ["--optfile", str(listing), str(peer_out)], cwd=work,
                        sampler=sampler(low_disk=low_disk if k == 0 else None, deadline_utc=peer_deadline),
                        allow_fail=True)
        if "killed_at_deadline" in peer or "failed" in peer:
            for f in work.glob(peer_out.name + "*"):
                f.unlink()
            print(f"  unfinished: {peer}", flush=True)
            if after is not None:
                after(peer)
            return {"mosaic_px": px, "mosaic_gp": round(px / 1e9, 4), "runs": [{"ours": ours, "peer": peer}],
                    "peer_unfinished": True}
        peer["file_mb"] = round(peer_out.stat().st_size / 1e6, 1)
        print(f"  {peer['wall_s']} s wall, {peer['cpu_s']} CPU-s, {peer['peak_rss_mb']} MB", flush=True)
        runs.append({"ours": ours, "peer": peer, "ratio": round(peer["wall_s"] / ours["wall_s"], 3),
                     **({"before": before} if before is not None else {})})
        peer_px = mosaic_px(peer_out)
        peer_out.unlink()
        if k == 0 and after is not None:
            after(peer)
    for r in runs:
        r["ours"]["mp_per_s"] = round(px / 1e6 / r["ours"]["wall_s"], 2)
        r["peer"]["mp_per_s"] = round(peer_px / 1e6 / r["peer"]["wall_s"], 2)
    med = lambda key, who: statistics.median(r[who][key] for r in runs)  # noqa: E731
    with_before = {}
    if before_src is not None:
        with_before = {"before_src": str(before_src), "before_wall_s": med("wall_s", "before"),
                       "before_cpu_s": med("cpu_s", "before"),
                       "before_peak_rss_mb": max(r["before"]["peak_rss_mb"] for r in runs),
                       "same_mosaic_bytes": all(r["before"]["sha256"] == r["ours"]["sha256"] for r in runs)}
    return {"mosaic_px": px, "mosaic_gp": round(px / 1e9, 4), "peer_px": peer_px, "runs": runs, **with_before,
            "median": {"ours_wall_s": med("wall_s", "ours"), "peer_wall_s": med("wall_s", "peer"),
                       "ours_cpu_s": med("cpu_s", "ours"), "peer_cpu_s": med("cpu_s", "peer"),
                       "ours_peak_rss_mb": max(r["ours"]["peak_rss_mb"] for r in runs),
                       "peer_peak_rss_mb": max(r["peer"]["peak_rss_mb"] for r in runs),
                       "ours_mp_per_s": med("mp_per_s", "ours"), "peer_mp_per_s": med("mp_per_s", "peer"),
                       "ratio_peer_over_ours_wall": statistics.median(r["ratio"] for r in runs),
                       "ratio_peer_over_ours_cpu": round(statistics.median(r["peer"]["cpu_s"] / r["ours"]["cpu_s"]
                                                                           for r in runs), 3)}}


def check(work: Path, reference: Path, out_stem: str) -> dict:
    r = measured([tool("ortho"), "check", "-q", str(work), "--reference", str(reference), "--out",
                  str(work / out_stem)])
    rep = json.loads((work / f"{out_stem}.json").read_text())
    d = rep["displacement"]
    r.pop("stdout", None)
    r.update(patches=d.get("count"), rms_xy_m=d.get("rms_xy_m"), rms_xy_gsd=d.get("rms_xy_gsd"),
             max_xy_m=d.get("max_xy_m"), seam_patches=(rep.get("seams") or {}).get("patches"),
             seam_rms_px=(rep.get("seams") or {}).get("rms_px"))
    return r


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--demo", type=Path, default=REPO / "out" / "demo")
    ap.add_argument("--work", type=Path, default=REPO / "out" / "mosaic_speed")
    ap.add_argument("--gp", type=float, default=4.2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--large-repeats", type=int, default=1)
    ap.add_argument("--skip-demo", action="store_true")
    ap.add_argument("--skip-large", action="store_true")
    ap.add_argument("--subset", action="append", default=[],
                    help="S,F: the first F frames of the first S strips of the large set ('all': every frame)")
    ap.add_argument("--block", type=Path, action="append", default=[],
                    help="a chain project whose frame orthos are measured too (read only, through links)")
    ap.add_argument("--block-repeats", type=int, default=1)
    ap.add_argument("--keep-large", action="store_true")
    ap.add_argument("--large-check", action="store_true", help="also ortho check the large DOM (long): after gdalwarp "
                    "when our DOM could be kept through it (--min-free-gb), else before gdalwarp")
    ap.add_argument("--check-by", metavar="HH:MM", help="start the large DOM check only before this UTC time (else it "
                    "is skipped and recorded so)")
    ap.add_argument("--peer-deadline", metavar="HH:MM", help="kill the large set's gdalwarp at this UTC time (end of "
                    "session): its CPU seconds so far are recorded, a lower bound")
    ap.add_argument("--peer-only", action="store_true", help="the large set's gdalwarp alone (when the disk has no "
                    "room for ortho mosaic's scratch beside the frames)")
    ap.add_argument("--ours-only", action="store_true", help="the large set's ortho mosaic alone (gdalwarp measured in "
                    "another run of the same session, --peer-only)")
    ap.add_argument("--ours-deadline", metavar="HH:MM", help="kill the large set's ortho mosaic at this UTC time")
    ap.add_argument("--min-free-gb", type=float, default=7.0,
                    help="the free disk to leave to others (default 7): the large runs stop before a step that would "
                         "need more, our DOM is kept through gdalwarp only when twice its size stays free above this, "
                         "and is removed as soon as the free disk falls under it while gdalwarp runs")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "mosaic_speed.json")
    ap.add_argument("--before-src", type=Path, help="source tree of the code before a change (git archive of main): "
                    "its ortho mosaic also runs on the demo, alternately, and the two mosaics' sha256 are compared")
    ap.add_argument("--phases", type=int, default=0, metavar="N",
                    help="after the timed runs, N runs of `ortho mosaic -v` on the demo (and of --before-src's) for "
                         "the CPU seconds of each phase (medians, `phases_cpu_s`)")
    ap.add_argument("--floor", type=int, default=0, metavar="N",
                    help="after the timed runs, N runs of a process that only imports what ortho mosaic imports on the "
                         "demo: the start-up floor (CPU-s) against gdalwarp's CPU-s (`floor`)")
    ap.add_argument("--peer-co", action="append", default=[], metavar="NAME=VALUE",
                    help="one more creation option of gdalwarp (repeatable), e.g. BIGTIFF=YES: the issue's command writes a "
                         "classic TIFF, which stops at 4 GiB (a DOM of about 4 GP)")
    ap.add_argument("--label", help="write this run under this key of --out, keeping the file's other keys")
    ap.add_argument("--bytecode", action="store_true",
                    help="compile the measured sources (this tree's and --before-src's ortho and aerotri) to bytecode "
                         "first, as a wheel install has them: an editable install under PYTHONDONTWRITEBYTECODE=1 "
                         "compiles every module of this project in every run")
    a = ap.parse_args()
    for co in a.peer_co:
        PEER.extend(["-co", co])
    if shutil.which("gdalwarp") is None:
        raise SystemExit("gdalwarp not found: the peer of this benchmark is GDAL's command line gdalwarp (Debian "
                         "package gdal-bin, installed by `make bench`); rasterio's bundled GDAL has no command line "
                         "tools")
    peer_version = subprocess.run(["gdalwarp", "--version"], capture_output=True, text=True).stdout.strip()
    import rasterio

    src = demo_project(a.demo)
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--", "ortho", "aerotri"],
                           capture_output=True, text=True).stdout.strip()
    result = {"commit": commit.stdout.strip() + (" (with uncommitted changes)" if dirty else ""),
              "machine": {"cpus": os.cpu_count(), "gdal_peer": peer_version, "gdal_ours": rasterio.__gdal_version__},
              "peer_command": " ".join(PEER) + " --optfile <frames> <out.tif>",
              "ours_command": "ortho mosaic <project>",
              "command": "nice -n " + str(os.nice(0)) + " python " + " ".join(sys.argv)}
    if a.bytecode:
        import compileall

        trees = [REPO] + ([a.before_src] if a.before_src else [])
        for tree in trees:
            for pkg in ("ortho", "aerotri"):
                if not compileall.compile_dir(str(tree / pkg), quiet=1):
                    raise SystemExit(f"{tree / pkg}: bytecode compilation failed")
        result["bytecode"] = [str(t) for t in trees]

    def save():
        """The results so far into --out (under --label, beside the file's other keys; written atomically)."""
        from bench.results_json import store_result

        if a.label:
            store_result(a.out, result, key=a.label)
        else:
            a.out.parent.mkdir(parents=True, exist_ok=True)
            a.out.write_text(json.dumps(result, indent=1) + "\n")

    demo = copy_demo(src, a.work / "demo")
    if not a.skip_demo:
        print(f"demo: {len(list((demo / 'ortho' / 'frames').glob('*.tif')))} frames from {src}", flush=True)
        result["demo"] = compare(demo, a.repeats, "demo", before_src=a.before_src)
        result["demo"]["per_gp"] = per_gp(result["demo"])
        if a.phases:
            print(f"demo: CPU per phase, {a.phases} run(s) each", flush=True)
            result["demo"]["phases_cpu_s"] = phases(demo, a.phases, a.before_src)
        if a.floor:
            print(f"demo: start-up floor, {a.floor} run(s)", flush=True)
            result["demo"]["floor"] = floor(demo, a.floor, result["demo"]["median"]["peer_cpu_s"])
    if not a.skip_demo and (demo / "truth" / "ortho.tif").exists():
        before = json.loads((demo / "ortho" / "dom_report.json").read_text())["displacement"] \
            if (demo / "ortho" / "dom_report.json").exists() else None
        after = check(demo, demo / "truth" / "ortho.tif", "dom_report_bench")
        result["demo"]["dom_check"] = {
            "after": after,
            "before": None if before is None else {"patches": before["count"], "rms_xy_m": before["rms_xy_m"],
                                                   "rms_xy_gsd": before["rms_xy_gsd"], "max_xy_m": before["max_xy_m"],
                                                   "source": "the demo's ortho/dom_report.json"}}
    save()
    for block in a.block:
        key = f"block_{block.name}"
        proj = link_project(block, a.work / key)
        n = len(json.loads((proj / "ortho" / "frames" / "index.json").read_text())["frames"])
        print(f"{key}: {n} frame orthos of {block}", flush=True)
        result[key] = {"source": str(block), "frames": n,
                       **compare(proj, a.block_repeats, key, before_src=a.before_src)}
        result[key]["per_gp"] = per_gp(result[key])
        save()
        for f in (proj / "ortho").glob("*"):  # the outputs (the frames are links)
            if f.name != "frames":
                shutil.rmtree(f) if f.is_dir() else f.unlink()
    if not a.skip_large:
        large = a.work / "large"
        print(f"large: making the synthetic frame orthos for {a.gp} GP", flush=True)
        layout = make_large(large, src, a.gp)
        print(f"large: {layout['frames']} frames, {layout['frames_gp']:.2f} GP of frames, "
              f"{layout['frames_bytes'] / 1e9:.2f} GB", flush=True)
        result["large"] = {"layout": layout}
        subsets = a.subset or ["all"]
        for sub in subsets:
            if sub == "all":
                key, proj = "large", large
            else:
                strips, per_strip = (int(v) for v in sub.split(","))
                key, proj = f"large_{strips}x{per_strip}", subset_project(large, a.work / f"sub_{strips}x{per_strip}",
                                                                          strips, per_strip)
            part = result["large"] if key == "large" else result.setdefault(key, {})
            part["frames"] = len(json.loads((proj / "ortho" / "frames" / "index.json").read_text())["frames"])

            dom = proj / "ortho" / "mosaic.tif"
            free_gb = lambda: shutil.disk_usage(proj).free / 1e9  # noqa: E731

            def run_check(part=part, proj=proj, key=key):
                if a.check_by and time.strftime("%H:%M", time.gmtime()) >= a.check_by:
                    part["dom_check"] = f"skipped: not started before {a.check_by} UTC"
                    return save()
                print(f"{key}: ortho check", flush=True)
                part["dom_check"] = check(proj, proj / "reference.tif", "dom_report_bench")
                part["dom_check"]["reference"] = f"the ground image at {REF_RES_M} m"
                save()

            def first_ours(ours, part=part, dom=dom):
                """Record the first of ours at once (a later kill loses nothing); keep our DOM through gdalwarp
                when the disk allows (True), else check it now (--large-check) and let it be removed."""
                size = dom.stat().st_size
                part["first_ours"] = {**ours, "dom_bytes": size, "dom_sha256": sha256_of(dom),
                                      "mosaic_px": mosaic_px(dom)}
                keep = a.large_check and free_gb() - 2 * size / 1e9 >= a.min_free_gb
                part["dom_kept_through_peer"] = keep
                save()
                if a.large_check and not keep:
                    run_check()
                return keep

            def first_peer(peer, part=part, dom=dom):
                part["first_peer"] = peer
                save()
                if dom.exists():
                    run_check()
                    dom.unlink()
                elif a.large_check and "dom_check" not in part:
                    part["dom_check"] = "skipped: our DOM was removed while gdalwarp ran (free disk under " \
                                        f"{a.min_free_gb} GB)"
                    save()

            def low_disk(dom=dom):
                print(f"{key}: free disk under {a.min_free_gb} GB: our DOM removed", flush=True)
                dom.unlink(missing_ok=True)

            # ortho mosaic's scratch and output peak at about 2.5 GB per GP of DOM (docs/performance.md)
            need_gb = a.min_free_gb + 2.6 * layout["block_gp"] * part["frames"] / layout["frames"]
            if a.peer_only:
                listing = proj / "peer_inputs.txt"
                listing.write_text("\n".join(str(f) for f in sorted((proj / "ortho" / "frames").glob("*.tif"))) + "\n")
                peer_out = proj / "peer_mosaic.tif"
                print(f"{key}: {free_gb():.1f} GB free; gdalwarp alone", flush=True)
                peer = measured(PEER + ["--optfile", str(listing), str(peer_out)], cwd=proj,
                                sampler=Sampler([proj], min_free_gb=a.min_free_gb, deadline_utc=a.peer_deadline),
                                allow_fail=True)
                if peer_out.exists() and not any(k.startswith(("killed", "failed")) for k in peer):
                    peer.update(file_mb=round(peer_out.stat().st_size / 1e6, 1), mosaic_px=mosaic_px(peer_out))
                    gp = peer["mosaic_px"] / 1e9
                    peer.update(mp_per_s=round(gp * 1e3 / peer["wall_s"], 2), cpu_s_per_gp=round(peer["cpu_s"] / gp, 1))
                for f in proj.glob(peer_out.name + "*"):
                    f.unlink()
                print(f"  {peer}", flush=True)
                part["first_peer"] = peer
                save()
                continue
            print(f"{key}: {free_gb():.1f} GB free before the mosaics, {need_gb:.1f} needed", flush=True)
            if free_gb() < need_gb:
                raise SystemExit(f"{key}: {free_gb():.1f} GB free, {need_gb:.1f} GB needed ({a.min_free_gb} GB left to "
                                 "others and about 2.6 GB per GP of DOM): stopped before the mosaics")
            if a.ours_only:
                ours = measured([tool("ortho"), "mosaic", "-q", str(proj)],
                                sampler=Sampler([proj], min_free_gb=a.min_free_gb, deadline_utc=a.ours_deadline))
                if not any(k.startswith("killed") for k in ours):
                    size, px = dom.stat().st_size, mosaic_px(dom)
                    ours.update(file_mb=round(size / 1e6, 1), dom_bytes=size, dom_sha256=sha256_of(dom), mosaic_px=px,
                                mp_per_s=round(px / 1e6 / ours["wall_s"], 2), cpu_s_per_gp=round(ours["cpu_s"] / (px / 1e9), 1))
                    if a.large_check:
                        part["first_ours"] = ours
                        run_check()
                    dom.unlink()
                for q in (proj / "ortho").glob(".mosaic.part-*"):  # a killed run's scratch (SIGKILL: not cleaned)
                    shutil.rmtree(q, ignore_errors=True)
                print(f"  {ours}", flush=True)
                part["first_ours"] = ours
                save()
                continue
            part.update(compare(proj, a.large_repeats, key, between=first_ours, after=first_peer,
                                min_free_gb=a.min_free_gb, low_disk=low_disk, peer_deadline=a.peer_deadline))
            if "ours_killed" in part:
                save()
                raise SystemExit(f"{key}: ortho mosaic killed, the free disk under {a.min_free_gb} GB (recorded)")
            if "median" in part:
                part["per_gp"] = per_gp(part)
            save()
            if proj != large:
                shutil.rmtree(proj)
        if not a.keep_large:
            shutil.rmtree(large)
    save()
    if "demo" in result:
        d = result["demo"]["median"]
        print(f"demo: ours {d['ours_wall_s']} s, gdalwarp {d['peer_wall_s']} s: {d['ratio_peer_over_ours_wall']}x")
    for key, part in result.items():
        if key.startswith("large") and "median" in part:
            m = part["median"]
            print(f"{key} ({part['mosaic_gp']} GP): ours {m['ours_wall_s']} s ({m['ours_peak_rss_mb']} MB), "
                  f"gdalwarp {m['peer_wall_s']} s: {m['ratio_peer_over_ours_wall']}x")
    print(f"-> {a.out}")


if __name__ == "__main__":
    main()
