"""The resumable stage runner: skip when up to date, re-run on changed inputs, nothing stamped on failure."""

from __future__ import annotations

import json

import pytest

from aerotri.run import Stage, format_summary, run_stages, stamp_path


def _stages(calls):
    def double(r):
        calls.append("double")
        v = int((r / "in.txt").read_text())
        (r / "mid.txt").write_text(str(2 * v))
        return dict(value=2 * v)

    def add(r):
        calls.append("add")
        v = int((r / "mid.txt").read_text())
        if v < 0:
            raise RuntimeError("negative")
        (r / "out.txt").write_text(str(v + 1))
        return dict(value=v + 1)

    return [
        Stage("double", lambda r: [r / "in.txt"], lambda r: [r / "mid.txt"], double),
        Stage("add", lambda r: [r / "mid.txt"], lambda r: [r / "out.txt"], add),
    ]


def test_rerun_skips_finished_stages_and_follows_changes(tmp_path):
    (tmp_path / "in.txt").write_text("3")
    calls = []
    rows = run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["double", "add"] and rows[-1]["value"] == 7
    calls.clear()
    rows = run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == [] and all(r["status"].startswith("skipped") for r in rows)
    assert rows[-1]["value"] == 7  # numbers come back from the stamp
    # A changed input re-runs its stage and, through the changed intermediate, the next one.
    (tmp_path / "in.txt").write_text("5")
    calls.clear()
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["double", "add"] and (tmp_path / "out.txt").read_text() == "11"
    # A deleted output re-runs only the stage that owns it.
    (tmp_path / "out.txt").unlink()
    calls.clear()
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["add"]
    assert "double" in format_summary(run_stages(tmp_path, _stages([]), log=lambda m: None))


def test_failed_stage_leaves_no_stamp_and_resumes(tmp_path):
    (tmp_path / "in.txt").write_text("-4")
    calls = []
    with pytest.raises(RuntimeError):
        run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert stamp_path(tmp_path, "double").exists() and not stamp_path(tmp_path, "add").exists()
    (tmp_path / "in.txt").write_text("1")
    calls.clear()
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["double", "add"]
    assert json.loads(stamp_path(tmp_path, "add").read_text())["result"]["value"] == 3


def test_stale_temporaries_of_a_killed_attempt_are_removed(tmp_path):
    (tmp_path / "in.txt").write_text("2")
    # What a SIGKILL during lidarctl.atomic.atomic_path leaves behind:
    (tmp_path / ".mid.abc123.txt").write_text("partial")
    (tmp_path / ".out.xyz.txt").write_text("partial")
    run_stages(tmp_path, _stages([]), log=lambda m: None)
    assert not list(tmp_path.glob(".*.txt"))
    assert (tmp_path / "out.txt").read_text() == "5"
