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
