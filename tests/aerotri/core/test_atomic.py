"""Commits of many outputs (aerotri.core.atomic.commit_outputs): all new when the block ends, all old when it
raises or its process is killed (the next run rolls the journal back)."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from aerotri.core import atomic
from aerotri.core.atomic import (atomic_dir, atomic_path, commit_outputs, move_into, recover_commits,
                                 remove_leftovers, remove_output, write_text_atomic)

REPO = Path(__file__).resolve().parents[3]


def tree(root: Path) -> dict:
    """Every file (sha1) and folder below ``root``."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        for n in dirnames:
            out[str((d / n).relative_to(root)) + "/"] = "dir"
        for n in filenames:
            out[str((d / n).relative_to(root))] = hashlib.sha1((d / n).read_bytes()).hexdigest()
    return out


def old_project(root: Path) -> None:
    (root / "at").mkdir(parents=True)
    (root / "at" / "eo.txt").write_text("old eo\n")
    (root / "at" / "report.txt").write_text("old report\n")
    (root / "at" / "stale.txt").write_text("a product the new run removes\n")
    (root / "frames").mkdir()
    (root / "frames" / "a.tif").write_text("old a\n")


def new_outputs(root: Path, fail_after: int | None = None) -> None:
    """What a stage writes: two replaced files, a new file in a new folder, a replaced folder, a removal."""
    steps = [lambda: write_text_atomic(root / "at" / "eo.txt", "new eo\n"),
             lambda: write_text_atomic(root / "at" / "report.txt", "new report\n"),
             lambda: write_text_atomic(root / "at" / "patb" / "block.im", "new patb\n"),
             lambda: remove_output(root / "at" / "stale.txt"),
             lambda: _new_frames(root)]
    for k, step in enumerate(steps):
        if fail_after is not None and k == fail_after:
            raise OSError(28, "No space left on device")
        step()


def _new_frames(root):
    with atomic_dir(root / "frames") as tmp:
        (tmp / "b.tif").write_text("new b\n")


@pytest.mark.parametrize("fail_after", [1, 2, 3, 4, 5])
def test_failure_between_files_leaves_all_old(tmp_path, fail_after):
    old_project(tmp_path)
    before = tree(tmp_path)
    with pytest.raises(OSError):
        with commit_outputs(tmp_path):
            new_outputs(tmp_path, fail_after)
            raise OSError(28, "No space left on device")  # (fail_after 5: after the last file)
    assert tree(tmp_path) == before
    assert not [p for p in tmp_path.rglob(".*")]


def test_commit_is_all_new_and_reads_see_new_files(tmp_path):
    old_project(tmp_path)
    with commit_outputs(tmp_path):
        new_outputs(tmp_path)
        assert (tmp_path / "at" / "eo.txt").read_text() == "new eo\n"  # later steps read what earlier wrote
    t = tree(tmp_path)
    assert (tmp_path / "at" / "patb" / "block.im").read_text() == "new patb\n"
    assert "at/stale.txt" not in t and "frames/a.tif" not in t and (tmp_path / "frames" / "b.tif").exists()
    assert not [p for p in tmp_path.rglob(".*")]


def test_joined_and_separate_commits(tmp_path):
    old_project(tmp_path)
    before = tree(tmp_path)
    with pytest.raises(RuntimeError):
        with commit_outputs(tmp_path):
            with commit_outputs(tmp_path / "at"):  # joins: final only with the outer one
                write_text_atomic(tmp_path / "at" / "eo.txt", "new eo\n")
            raise RuntimeError("later step fails")
    assert tree(tmp_path) == before
    with pytest.raises(RuntimeError):
        with commit_outputs(tmp_path):
            with commit_outputs(tmp_path / "at", join=False):  # a stage of the resumable chain: final at once
                write_text_atomic(tmp_path / "at" / "eo.txt", "new eo\n")
            write_text_atomic(tmp_path / "at" / "report.txt", "new report\n")
            raise RuntimeError("later stage fails")
    assert (tmp_path / "at" / "eo.txt").read_text() == "new eo\n"
    assert (tmp_path / "at" / "report.txt").read_text() == "old report\n"


def test_threads_write_into_one_commit(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    (tmp_path / "out").mkdir()
    for k in range(20):
        (tmp_path / "out" / f"{k}.txt").write_text("old")
    before = tree(tmp_path)
    with pytest.raises(RuntimeError), commit_outputs(tmp_path):
        with ThreadPoolExecutor(4) as ex:
            list(ex.map(lambda k: write_text_atomic(tmp_path / "out" / f"{k}.txt", "new"), range(20)))
        raise RuntimeError
    assert tree(tmp_path) == before


KILLED = textwrap.dedent("""
    import os, sys, time
    from pathlib import Path
    from aerotri.core.atomic import commit_outputs, write_text_atomic, atomic_dir
    root = Path(sys.argv[1])
    with commit_outputs(root):
        write_text_atomic(root / "at" / "eo.txt", "new eo\\n")
        write_text_atomic(root / "at" / "new.txt", "new file\\n")
        with atomic_dir(root / "frames") as tmp:
            (tmp / "b.tif").write_text("new b\\n")
        print("half", flush=True)
        time.sleep(60)
""")


def test_killed_commit_is_rolled_back_by_the_next_run(tmp_path):
    old_project(tmp_path)
    before = tree(tmp_path)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    p = subprocess.Popen([sys.executable, "-c", KILLED, str(tmp_path)], stdout=subprocess.PIPE, text=True, env=env)
    assert p.stdout.readline().strip() == "half"
    assert (tmp_path / "at" / "eo.txt").read_text() == "new eo\n"
    # alive: another process leaves its journal alone
    assert recover_commits(tmp_path) == []
    assert (tmp_path / "at" / "eo.txt").read_text() == "new eo\n"
    p.kill()
    p.wait()
    assert any(atomic.COMMIT_MARKER in q.name for q in tmp_path.iterdir())
    restored = remove_leftovers(tmp_path)
    assert {Path(q).name for q in restored} >= {"eo.txt", "new.txt", "frames"}
    assert tree(tmp_path) == before


SWAP_KILLED = textwrap.dedent("""
    import os, sys
    from pathlib import Path
    from aerotri.core import atomic
    root = Path(sys.argv[1])
    real = os.replace
    calls = []
    def replace(a, b):
        calls.append(b)
        real(a, b)
        if len(calls) == 1:     # the old folder moved aside, the new one not yet in: the process dies
            os._exit(9)
    os.replace = replace
    with atomic.atomic_dir(root / "frames") as tmp:
        (tmp / "b.tif").write_text("new b\\n")
""")


def test_folder_swap_killed_between_renames_keeps_the_old_folder(tmp_path):
    old_project(tmp_path)
    before = tree(tmp_path)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run([sys.executable, "-c", SWAP_KILLED, str(tmp_path)], env=env)
    assert r.returncode == 9
    assert not (tmp_path / "frames").exists()  # what the kill left: no frames/ at all
    remove_leftovers(tmp_path)
    assert tree(tmp_path) == before


def test_move_into_and_atomic_path_annotate_disk_errors(tmp_path, monkeypatch):
    def full(*a, **k):
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError) as e:
        with atomic_path(tmp_path / "x.txt") as tmp:
            monkeypatch.setattr(Path, "write_text", full)
            tmp.write_text("x")
    assert e.value.filename == str(tmp_path / "x.txt")
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "a").write_text("a")
    move_into(tmp_path / "a", tmp_path / "b")
    assert (tmp_path / "b").read_text() == "a"
