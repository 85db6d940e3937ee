"""The console-script wrapper (``aerotri.core.console``): exit status, buffered output, atexit handlers and threads are
kept although the process ends with ``os._exit``; the click groups themselves still run under CliRunner."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from click.testing import CliRunner

from aerotri.core.console import exit_status

SCRIPT = textwrap.dedent("""
    import atexit, sys, threading, time
    from pathlib import Path

    import click

    from aerotri.core.console import console_script

    out = Path(sys.argv[1])

    @click.group()
    def main():
        pass

    @main.command()
    @click.argument("code", type=int)
    def go(code):
        # a non-daemon thread still writing when the command returns: joined before the process ends
        def late():
            time.sleep(0.3)
            out.with_suffix(".thread").write_text("thread")
        threading.Thread(target=late).start()
        atexit.register(lambda: out.write_text("atexit ran"))
        click.echo("x" * 100000, nl=False)  # more than a pipe's buffer, no newline at the end
        click.echo("to stderr", err=True, nl=False)
        if code == 99:
            raise click.UsageError("bad option")
        if code == 77:
            sys.exit("a message")
        sys.exit(code)

    sys.argv = ["prog", "go", sys.argv[2]]
    console_script(main)()
    """)


def _run(tmp_path, code: str):
    marker = tmp_path / f"marker_{code}"
    p = subprocess.run([sys.executable, "-c", SCRIPT, str(marker), code], capture_output=True, text=True, timeout=60)
    return p, marker


def test_status_output_atexit_and_threads_kept(tmp_path):
    for code in ("0", "3"):
        p, marker = _run(tmp_path, code)
        assert p.returncode == int(code)
        assert p.stdout == "x" * 100000
        assert p.stderr == "to stderr"
        assert marker.read_text() == "atexit ran"
        assert marker.with_suffix(".thread").read_text() == "thread"


def test_click_errors_and_messages_keep_their_status(tmp_path):
    p, marker = _run(tmp_path, "99")
    assert p.returncode == 2 and "bad option" in p.stderr
    assert marker.read_text() == "atexit ran"
    p, _ = _run(tmp_path, "77")
    assert p.returncode == 1 and p.stderr.endswith("a message\n")


def test_exit_status_follows_sys_exit():
    assert exit_status(None) == 0
    assert exit_status(0) == 0
    assert exit_status(2) == 2


def test_ortho_console_script_runs_the_group_and_cli_runner_still_works():
    from ortho.cli import main, run

    p = subprocess.run([sys.executable, "-c", "import sys; sys.argv = ['ortho', '--version']; "
                        "from ortho.cli import run; run()"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stdout.startswith("ortho, version ")
    p = subprocess.run([sys.executable, "-c", "import sys; sys.argv = ['ortho', 'mosaic', '/nonexistent/project']; "
                        "from ortho.cli import run; run()"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and p.stderr.startswith("Error: ") and "Traceback" not in p.stderr
    # CliRunner runs the group in this process: the wrapper is not in its way (the test process goes on)
    r = CliRunner().invoke(main, ["--version"])
    assert r.exit_code == 0 and ", version " in r.output
