"""Start-up of the ``lidarctl`` command: a subcommand's module (and the settings classes its options take their
defaults from, in modules that import numba, scipy and GDAL) is imported when that subcommand runs."""

import subprocess
import sys

HEAVY = ("numpy", "scipy", "numba", "rasterio", "pyproj", "matplotlib", "laspy", "lidarctl.classify", "lidarctl.tiles")
NAMES = ["check-heights", "check-plan", "check-vectors", "classify", "contours", "corners", "crowns", "drainage",
         "evaluate", "hydro-flatten", "merge", "rasters", "smooth", "strips", "trees", "vectors"]


def _imported_after(code: str, modules) -> str:
    code = f"import sys; {code}; print(' '.join(m for m in {tuple(modules)!r} if m in sys.modules))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()


def test_the_lidarctl_group_imports_no_subcommand():
    assert _imported_after("import lidarctl.cli.main", HEAVY) == ""


def test_a_dem_command_does_not_wait_for_the_classifier():
    code = "from lidarctl.cli.main import main; main.get_command(None, 'contours')"
    assert _imported_after(code, ("lidarctl.classify.pipeline", "lidarctl.tiles", "lidarctl.checks.heights")) == ""


def test_every_subcommand_is_listed_resolves_and_has_its_help():
    from click.testing import CliRunner

    from lidarctl.cli.main import main

    assert main.list_commands(None) == NAMES
    for name in NAMES:
        assert main.get_command(None, name).name == name
        r = CliRunner().invoke(main, [name, "--help"])
        assert r.exit_code == 0 and f"Usage: main {name} " in r.output, r.output
    r = CliRunner().invoke(main, ["--help"])
    assert r.exit_code == 0 and all(f"  {n} " in r.output for n in NAMES)


def test_threads_resolving_the_same_command_at_once_all_get_it():
    import threading

    from aerotri.core.commands import LazyGroup

    group = LazyGroup(name="g", lazy={"contours": "lidarctl.cli.terrain:contours"})
    barrier, found = threading.Barrier(8), []

    def resolve():
        barrier.wait()
        found.append(group.get_command(None, "contours"))

    threads = [threading.Thread(target=resolve) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(found) == 8 and all(c is not None and c.name == "contours" for c in found)
