"""Quiet, honest console: what the libraries underneath say (Python warnings such as numpy's RuntimeWarning,
rasterio's and Dask's log records, C/C++ code writing to the process's stderr such as gtsam's exception notes)
goes to the debug log (``-v``, ``--log-file``), not to the console; real commands print no third-party
warning or traceback."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))

NOISY = textwrap.dedent("""
    import ctypes, logging, sys, warnings
    import click
    import numpy as np
    from aerotri.core.commands import Command

    @click.command(cls=Command)
    def noisy():
        np.nanmean(np.full(3, np.nan))                          # numpy: RuntimeWarning: Mean of empty slice
        warnings.warn("NotGeoreferencedWarning: no geotransform", UserWarning)
        logging.getLogger("rasterio._env").warning("CPLE_AppDefined in TIFFReadDirectory: unknown tag")
        logging.getLogger("distributed.worker").warning("Worker is at 85% memory usage")
        libc = ctypes.CDLL(None)
        libc.write(2, b"CheiralityException: Point is behind the camera\\n", 48)  # C code on descriptor 2
        logging.getLogger("aerotri.test").warning("our own warning")
        click.echo("result line")

    noisy()
""")


def _noisy(tmp_path, *args):
    return subprocess.run([sys.executable, "-c", NOISY, *args], capture_output=True, text=True, env=ENV, cwd=tmp_path,
                          timeout=300)


def test_third_party_output_goes_to_the_debug_log(tmp_path):
    log = tmp_path / "run.log"
    r = _noisy(tmp_path, "--log-file", str(log))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "result line"
    assert r.stderr.strip() == "warning: our own warning"  # ours only, nothing from below
    text = log.read_text()
    for what in ("Mean of empty slice", "NotGeoreferencedWarning", "CPLE_AppDefined", "85% memory",
                 "CheiralityException", "our own warning"):
        assert what in text, what
    # trial "overnight" L4: a monitor looking for WARNING lines finds ours only; the libraries' keep their level
    # in the message
    warning_lines = [x for x in text.splitlines() if " WARNING " in x or " ERROR " in x]
    assert len(warning_lines) == 1 and "aerotri.test: our own warning" in warning_lines[0], warning_lines
    assert "(warning of rasterio._env) CPLE_AppDefined" in text and "(warning of py.warnings)" in text


def test_verbose_shows_third_party_details(tmp_path):
    r = _noisy(tmp_path, "-v")
    assert r.returncode == 0
    assert "Mean of empty slice" in r.stderr and "CPLE_AppDefined" in r.stderr
    assert ": CheiralityException: Point is behind" in r.stderr  # C output, as a debug line naming the command


@pytest.fixture(scope="module")
def cloud(tmp_path_factory) -> Path:
    from lidarctl import synthetic

    d = tmp_path_factory.mktemp("console")
    c, truth = synthetic.synthetic_scene(width_m=60.0, density_per_m2=2.0, n_buildings=1, n_trees=4, seed=3)
    synthetic.write_las(d / "cloud.las", c, classification=truth, crs="EPSG:32632")
    return d


def _run(prog, *args, cwd):
    module = {"aerotri": "aerotri.cli", "lidarctl": "lidarctl.cli.main", "ortho": "ortho.cli"}[prog]
    code = f"import sys; sys.argv[0] = {prog!r}; from {module} import main; sys.exit(main())"
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=ENV,
                          cwd=cwd, timeout=600)


def test_real_commands_print_no_third_party_warning(cloud):
    """A few commands as a user runs them (real processes): no Python warning, no traceback on stderr."""
    runs = [("lidarctl", "rasters", cloud / "cloud.las", cloud / "r", "--res-m", "1"),
            ("lidarctl", "contours", cloud / "r" / "dem.tif", cloud / "c.gpkg", "--interval-m", "1"),
            ("lidarctl", "smooth", cloud / "r" / "dem.tif", cloud / "s.tif"),
            ("aerotri", "crs", "warp", cloud / "r" / "dem.tif", cloud / "w.tif", "--to", "EPSG:32633")]
    for prog, *args in runs:
        r = _run(prog, *args, cwd=cloud)
        assert r.returncode == 0, (args, r.stderr)
        assert "Warning" not in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
