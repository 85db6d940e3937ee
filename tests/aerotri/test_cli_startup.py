"""Start-up of the ``aerotri`` command: a subcommand's imports wait until that subcommand runs."""

import subprocess
import sys

HEAVY = ("numpy", "scipy", "gtsam", "matplotlib", "rasterio", "pyproj", "numba", "lidarctl", "cv2", "pycolmap", "dask")


def test_the_aerotri_group_imports_no_stage():
    code = ("import sys, aerotri.cli; "
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""


def test_every_subcommand_is_listed_and_resolves():
    from click.testing import CliRunner

    from aerotri.cli import main

    names = ["adjust", "compare", "control", "crs", "demo", "export", "import", "init", "match", "report", "run", "settings", "sim"]
    assert main.list_commands(None) == names
    for name in names:
        assert main.get_command(None, name).name == name
    r = CliRunner().invoke(main, ["--help"])
    assert r.exit_code == 0 and all(f"  {n} " in r.output for n in names)
