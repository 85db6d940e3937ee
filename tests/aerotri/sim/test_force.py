"""`aerotri sim --force` replaces only a dataset the simulator made (trial-paths: it deleted any folder, a real
project's gnss.txt, at/ and ortho/ with it), and a project's folder under the project's lock."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner

from aerotri.cli import main


def test_force_replaces_a_simulated_block_and_refuses_anything_else(tmp_path):
    out = tmp_path / "blk"
    args = ["sim", "--preset", "tiny", "--observations-only", "--set", "flight.strips=1",
            "--set", "flight.frames_per_strip=3"]
    assert CliRunner().invoke(main, args + [str(out)]).exit_code == 0
    r = CliRunner().invoke(main, args + ["--force", str(out)])
    assert r.exit_code == 0, r.output
    mine = tmp_path / "project"
    (mine / "at").mkdir(parents=True)
    (mine / "gnss.txt").write_text("f1 1 2 3\n")
    (mine / "project.toml").write_text('[project]\nname = "mine"\ncrs = "EPSG:32649"\n')
    r = CliRunner().invoke(main, args + ["--force", str(mine)])
    assert r.exit_code == 2 and "holds no truth/ folder" in r.output
    assert (mine / "gnss.txt").read_text() == "f1 1 2 3\n" and (mine / "at").is_dir()


def test_force_waits_for_no_run_in_the_project(tmp_path):
    from aerotri.core.lock import LOCK_NAME, hold_lock

    out = tmp_path / "blk"
    args = ["sim", "--preset", "tiny", "--observations-only", "--set", "flight.strips=1",
            "--set", "flight.frames_per_strip=3"]
    assert CliRunner().invoke(main, args + [str(out)]).exit_code == 0
    # (another process: a lock is re-entered within one)
    code = "import sys; from aerotri.cli import main; sys.argv = ['aerotri'] + sys.argv[1:]; main()"
    with hold_lock(out / LOCK_NAME, "aerotri run blk", 0.0, f"project {out}"):
        r = subprocess.run([sys.executable, "-c", code, *args, "--force", str(out)], capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[3])})
    assert r.returncode == 2 and "`aerotri run blk`" in r.stderr and "is writing it" in r.stderr, r.stderr
    assert (out / "truth").is_dir()
