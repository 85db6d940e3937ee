"""Every command logs through Python logging: -q keeps warnings and errors only, -v adds debug details,
--log-file gets everything with time stamps, and off a terminal progress comes as periodic log lines
with counts and an ETA (tqdm only on a terminal)."""

from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core import log as core_log
from lidarctl import synthetic


@pytest.fixture()
def las(tmp_path):
    cloud, truth = synthetic.synthetic_scene(width_m=60.0, seed=3)
    path = tmp_path / "in.las"
    synthetic.write_las(path, cloud, classification=truth, crs="EPSG:32649")
    return path


def _transform(las, out, *extra):
    return CliRunner().invoke(aerotri_cli, ["crs", "transform", str(las), str(out), "--to", "EPSG:4326",
                                            "--chunk-points", "2000", *extra])


def test_progress_lines_off_a_terminal(las, tmp_path, monkeypatch):
    monkeypatch.setattr(core_log, "PROGRESS_INTERVAL_S", 0.0)
    r = _transform(las, tmp_path / "out.las")
    assert r.exit_code == 0, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("transform in.las:")]
    assert len(lines) >= 3
    assert re.search(r"[\d,]+/[\d,]+ points \(\d+\.\d %\), \d+ s elapsed, ETA \d+", lines[0])
    assert "\r" not in r.stderr  # no tqdm bar off a terminal


def test_quiet_and_log_file(las, tmp_path, monkeypatch):
    monkeypatch.setattr(core_log, "PROGRESS_INTERVAL_S", 0.0)
    log_file = tmp_path / "run.log"
    r = _transform(las, tmp_path / "out.las", "-q", "--log-file", str(log_file))
    assert r.exit_code == 0, r.output
    assert "transform in.las:" not in r.stderr  # -q: no progress, no info on stderr
    text = log_file.read_text()
    assert re.search(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+ INFO +aerotri.progress: transform in.las: ", text, re.M)


def test_errors_go_through_the_handler_with_exit_code_2(tmp_path):
    r = CliRunner().invoke(aerotri_cli, ["crs", "transform", str(tmp_path / "missing.las"), str(tmp_path / "o.las"),
                                         "--to", "EPSG:4326", "-v"])
    assert r.exit_code == 2
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("Error: ")]  # -v: debug lines around it
    assert len(errors) == 1 and "missing.las" in errors[0] and "Traceback" not in r.stderr


def test_log_file_records_the_command_and_never_appends_to_another_file(las, tmp_path):
    log_file = tmp_path / "run.log"
    for out in ("a.las", "b.las"):
        assert _transform(las, tmp_path / out, "-q", "--log-file", str(log_file)).exit_code == 0
    text = log_file.read_text()
    assert text.count("crs transform started with") == 2 and text.count("finished in") == 2
    before = las.read_bytes()
    r = _transform(las, tmp_path / "c.las", "--log-file", str(las))  # the input given as the log by mistake
    assert r.exit_code == 2 and "not a log" in r.stderr and "Traceback" not in r.stderr
    assert las.read_bytes() == before and not (tmp_path / "c.las").exists()


def test_eta_from_the_rate_after_the_first_item(monkeypatch):
    """The simulator's first frame carries numba's compilation: 18 frames, the first 60 s, then 1 s each; after 3
    frames the ETA extrapolated from the mean (62 s / 3 x 15 = 310 s) was far off the 15 s left."""
    from aerotri.core import log as L

    clock = [0.0]
    monkeypatch.setattr(L.time, "monotonic", lambda: clock[0])
    p = L._LogProgress(18, "frames", "items", interval_s=1e9)
    for t in (60.0, 61.0, 62.0):
        clock[0] = t
        p.update()
    assert p._line(clock[0]).endswith("ETA 15 s")


def test_a_stage_of_short_phases_logs_a_line_with_the_stage_elapsed(monkeypatch):
    """trial-overnight: `lidarctl rasters` ran 90 s on the full-size 2 x 2 block without a progress line, each of its
    phases ending inside the 30 s interval; classify's first line said "34 s elapsed" 86 s into the stage (its tile
    split not counted). Inside ``doing`` (a command, a stage) the interval and the elapsed time are the block's."""
    from aerotri.core import log as L

    clock, lines = [0.0], []
    monkeypatch.setattr(L.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(L._log, "info", lines.append)
    with L.doing("rasters"):
        with L.progress(20, "rasters: bin points into tiles", "pt") as bar:  # 0-25 s: 1.25 s a chunk
            for _ in range(20):
                clock[0] += 1.25
                bar.update(1)
        with L.progress(10, "rasters: tiles", "tile") as bar:  # 25-45 s: 2 s a tile
            for _ in range(10):
                clock[0] += 2.0
                bar.update(1)
    assert lines == ["rasters: tiles: 3/10 tile (30.0 %), 31 s elapsed, ETA 14 s"], lines
    lines.clear()
    with L.doing("classify"):  # a 52 s tile split, then tiles of 40 s: the first tile's line counts the split
        with L.progress(8, "tiles: split", "pt") as bar:
            clock[0] += 52.0
            bar.update(8)
        lines.clear()  # (the split's own closing line)
        with L.progress(8, "classify", "tiles") as bar:
            clock[0] += 40.0
            bar.update(1)
    assert lines and lines[0].startswith("classify: 1/8 tiles (12.5 %), 1 min 32 s elapsed, ETA 4 min 40 s"), lines


def test_the_closing_line_is_not_logged_twice(monkeypatch):
    """Review 51: a phase whose last update logged its 100 % line (on the stage's clock) logged it again when it
    closed (on its own start): "phase: 4/4 it (100.0 %), 1 min 0 s elapsed" twice."""
    from aerotri.core import log as L

    clock, lines = [0.0], []
    monkeypatch.setattr(L.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(L._log, "info", lines.append)
    with L.doing("stage"):
        clock[0] += 20.0  # other work of the stage first
        with L.progress(4, "phase", "it") as bar:
            for _ in range(4):
                clock[0] += 10.0
                bar.update(1)
    assert sum("4/4" in line for line in lines) == 1, lines
    assert lines[-1].startswith("phase: 4/4 it (100.0 %), 1 min 0 s elapsed"), lines
