"""The command class: SIGTERM unwinds like Ctrl-C, so atomic writers leave no temporaries."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

SCRIPT = textwrap.dedent("""
    import sys, time
    import click
    from aerotri.core.atomic import atomic_dir
    from aerotri.core.commands import Command

    @click.command(cls=Command)
    @click.argument("out")
    def slow(out):
        with atomic_dir(out) as tmp:
            (tmp / "a.txt").write_text("partial")
            print("writing", flush=True)
            time.sleep(60)

    slow()
""")


def test_sigterm_leaves_no_partial_output(tmp_path):
    out = tmp_path / "frames"
    p = subprocess.Popen([sys.executable, "-c", SCRIPT, str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    assert p.stdout.readline().strip() == "writing"
    assert any(q.name.startswith(".frames.part-") for q in tmp_path.iterdir())
    p.send_signal(signal.SIGTERM)
    t0 = time.time()
    _, err = p.communicate(timeout=30)
    assert time.time() - t0 < 30 and p.returncode == 143 and "Interrupted." in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # neither the output nor its temporary


WRAPPED = textwrap.dedent("""
    import click
    from aerotri.core.commands import Command

    @click.command(cls=Command)
    def numba_like():
        # what numba's compiled functions raise for a Ctrl-C inside them: the KeyboardInterrupt as the context of a
        # SystemError "returned a result with an exception set"
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(<function _runs_parallel>) returned a result with an exception set")

    numba_like()
""")


def test_ctrl_c_inside_compiled_code_is_an_interrupt():
    """Trial s97 M4: Ctrl-C in a numba phase of `aerotri adjust` printed a chained traceback (KeyboardInterrupt ->
    SystemError -> SystemError) and exited 1; it is "Interrupted.", 130, as elsewhere."""
    p = subprocess.run([sys.executable, "-c", WRAPPED], capture_output=True, text=True, timeout=120)
    assert p.returncode == 130 and "Interrupted." in p.stderr and "Traceback" not in p.stderr, p.stderr


def test_unchained_gdal_write_failure_is_a_one_line_disk_error():
    """rasterio's 'Write failed' of a window (a full disk under a 1 GP mosaic, GDAL's cause not chained) is a
    file-system fault with the output named, not a traceback."""
    import rasterio.errors

    from aerotri.core.commands import fault_message

    exc = rasterio.errors.RasterioIOError("Write failed. See previous exception for details.")
    msg = fault_message(exc, "ortho mosaic", "P/ortho/mosaic.tif")
    assert msg.startswith("P/ortho/mosaic.tif: a write was cut short") and "outputs are as they were" in msg
    assert fault_message(ValueError("Write failed. See previous exception"), "ortho mosaic") is None


def test_numpy_reservation_failure_is_a_one_line_disk_error():
    """numpy's tofile of a large array reserves the space first; on a full disk it raises an OSError without an
    errno (seen in the corners stage of the 120-frame DMC block): a disk-full message, not a traceback."""
    from aerotri.core.commands import fault_message

    exc = OSError("Not enough free space to write 25695486 bytes after offset 17698158")
    msg = fault_message(exc, "stage corners", "P/lidar_out/corners.csv")
    assert msg.startswith("P/lidar_out/corners.csv: no space left on device; stage corners stopped")
    assert fault_message(OSError("something else entirely"), "stage corners") is None


def test_a_file_it_could_not_open_is_named_not_the_output_being_written():
    """Review 51: since a rasterio error (an OSError without errno) inside a write carries the output's name, a frame
    ortho GDAL could not open ("Permission denied", naming it) was reported as the mosaic; a full disk still names the
    output, and a permission fault on the output's own temporary names the output."""
    from rasterio.errors import RasterioIOError

    from aerotri.core.atomic import annotate_output
    from aerotri.core.commands import fault_message

    exc = RasterioIOError("/p/ortho/frames/s01_002.tif: Permission denied")
    annotate_output(exc, "/p/ortho/mosaic.tif")
    assert fault_message(exc, "ortho mosaic").startswith("/p/ortho/frames/s01_002.tif: ")
    for named in ("p/ortho/frames/s01_002.tif", "/work/my project/s01_002.tif"):  # relative, spaces: review 52
        exc = RasterioIOError(f"{named}: Permission denied")
        annotate_output(exc, "p/ortho/mosaic.tif")
        assert fault_message(exc, "ortho mosaic").startswith(f"{named}: "), named
    exc = RasterioIOError("/p/ortho/.mosaic.tif.part-1a2b/rows.tif: Permission denied")
    annotate_output(exc, "/p/ortho/mosaic.tif")
    assert fault_message(exc, "ortho mosaic").startswith("/p/ortho/mosaic.tif: ")
    exc = RasterioIOError("_tiffWriteProc: File too large.")
    annotate_output(exc, "/p/ortho/mosaic.tif")
    assert fault_message(exc, "ortho mosaic").startswith("/p/ortho/mosaic.tif: ")


def test_an_error_is_an_error_line_of_the_log_file(tmp_path):
    """Trial s96 M4: a failed night run's --log-file held no ERROR line (the cause only in a DEBUG traceback), so a
    monitor grepping for ERROR read it as clean. The console's error is the log's ERROR record too."""
    from click.testing import CliRunner

    from aerotri.cli import main

    log_file = tmp_path / "night.log"
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "project.toml").write_text('[project]\nname = "p"\ncrs = "EPSG:32649"\n')
    r = CliRunner().invoke(main, ["report", str(tmp_path / "p"), "--log-file", str(log_file)])
    assert r.exit_code == 2, r.output
    errors = [ln for ln in log_file.read_text().splitlines() if " ERROR " in ln]
    assert len(errors) == 1 and "nothing to report yet" in errors[0], log_file.read_text()


def test_a_folder_holding_the_project_one_level_down_names_it(tmp_path):
    """Docs trial s98 L6: `aerotri run out/demo` where the demo's project is out/demo/project said only that
    out/demo/project.toml is missing; it names the project inside as well, and says nothing more where none is."""
    import pytest

    from aerotri.core.errors import InputError
    from aerotri.core.project import Project

    (tmp_path / "demo" / "project").mkdir(parents=True)
    (tmp_path / "demo" / "project" / "project.toml").write_text('[project]\ncrs = "EPSG:32633"\n')
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"demo/project.toml: missing .*; .*demo/project is a project$"):
        Project.open(tmp_path / "demo")
    with pytest.raises(InputError, match=r"missing \(every project folder needs project.toml with \[project\] crs\)$"):
        Project.open(tmp_path / "empty")
