"""Killing the production run in the middle of a stage, then re-running it, gives the same outputs as
an uninterrupted run and leaves no partial files behind."""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time

SCRIPT = """
import sys
from pathlib import Path
from aerotri.chain import chain_stages, run_stages
root = Path(sys.argv[1])
run_stages(root, [s for s in chain_stages(root) if s.name == "classify"], log=lambda m: print(m, file=sys.stderr, flush=True))
"""


def _digest(root):
    out = {}
    for p in sorted((root / "lidar_out").rglob("*")):
        if p.is_file():
            out[str(p.relative_to(root))] = hashlib.sha1(p.read_bytes()).hexdigest()
    return out


def _run(root, kill_at=None):
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT, str(root)], stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    if kill_at is None:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
        return err
    for line in proc.stderr:
        if line.startswith(f"[{kill_at}] running"):
            time.sleep(0.5)  # well inside the stage
            os.killpg(proc.pid, signal.SIGKILL)
            break
    proc.wait(timeout=60)
    return None


def test_killed_stage_resumes_to_the_same_outputs(tiny_project, tmp_path):
    ref, killed = tmp_path / "ref", tmp_path / "killed"
    for d in (ref, killed):
        shutil.copytree(tiny_project, d, ignore=shutil.ignore_patterns("truth", "images"))
    _run(ref)
    _run(killed, kill_at="classify")
    assert not (killed / "work" / "stages" / "classify.json").exists()
    assert not (killed / "lidar_out" / "classified").exists()  # the set of classified strips: all or none
    err = _run(killed)
    assert "[classify] done" in err
    assert _digest(killed) == _digest(ref) and len(_digest(ref)) == 5  # the classified strips, classify.json
    leftovers = [p for p in killed.rglob(".*") if p.name not in (".", "..")]
    assert leftovers == []
