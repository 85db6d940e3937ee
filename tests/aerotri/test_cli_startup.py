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


def test_the_adjustment_and_control_transfer_start_without_scipy_stats_and_optimize():
    """Their statistical tests take quantiles from scipy.special (aerotri.core.quantiles): importing scipy.stats,
    and scipy.optimize with it, cost 0.5 s of every `aerotri adjust` (4.0 -> 3.5 s on the tiny block)."""
    code = ("import sys, aerotri.adjust.pipeline, aerotri.control.pipeline, aerotri.adjust.report; "
            "print(' '.join(m for m in ('scipy.stats', 'scipy.optimize', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
