"""``aerotri control`` resumes the frames an interrupted transfer measured (work/control_resume)."""

from __future__ import annotations

import shutil

from click.testing import CliRunner

import aerotri.control.pipeline as P
from aerotri.cli import main
from aerotri.core.errors import InputError
from tests.aerotri.control.test_cli import project_copy


def run(root):
    return CliRunner().invoke(main, ["control", str(root), "--eo", str(root / "truth" / "eo.txt"), "--camera",
                                     str(root / "truth" / "camera.toml"), "--min-frames", "2"])


def tree(folder) -> dict:
    return {str(f.relative_to(folder)): f.read_bytes() for f in sorted(folder.rglob("*")) if f.is_file()}


class _Windows:
    """``FrameWindows`` counting the frames opened; raises ``exc`` at the ``at``-th."""

    def __init__(self, at=None, exc=KeyboardInterrupt):
        self.at, self.exc, self.opened = at, exc, 0
        self.real = P.FrameWindows

    def __call__(self, *a, **k):
        self.opened += 1
        if self.opened == self.at:
            raise self.exc("broken on purpose") if self.exc is InputError else self.exc
        return self.real(*a, **k)


def test_a_rerun_resumes_the_frames_an_interrupted_transfer_measured(tiny_project, tmp_path, monkeypatch):
    """Ctrl-C when the fourth frame is opened: the three measured before are kept; the next run measures only the
    others and writes the outputs of one uninterrupted run, byte for byte, then clears the folder."""
    root = project_copy(tiny_project, tmp_path)
    keep = root / "work" / "control_resume"
    count = _Windows()
    monkeypatch.setattr(P, "FrameWindows", count)
    r = run(root)
    assert r.exit_code == 0, r.output
    measured = count.opened
    assert measured >= 5
    want = tree(root / "control")
    shutil.rmtree(root / "control")

    monkeypatch.setattr(P, "FrameWindows", _Windows(at=4))
    r = run(root)
    assert r.exit_code != 0 and not (root / "control").exists(), r.output
    assert len(list(keep.glob("*.json"))) == 3

    count = _Windows()
    monkeypatch.setattr(P, "FrameWindows", count)
    r = run(root)
    assert r.exit_code == 0, r.output
    assert count.opened == measured - 3
    assert "control transfer: resumed 3 of 6 frames an interrupted run finished" in r.stderr, r.stderr
    assert tree(root / "control") == want
    assert not keep.exists()


def test_an_error_leaves_the_project_as_it_was_and_nothing_to_resume(tiny_project, tmp_path, monkeypatch):
    root = project_copy(tiny_project, tmp_path)
    monkeypatch.setattr(P, "FrameWindows", _Windows(at=3))
    assert run(root).exit_code != 0
    before = tree(root)
    assert any(k.startswith("work/control_resume/") for k in before)
    monkeypatch.setattr(P, "FrameWindows", _Windows(at=2, exc=InputError))
    r = run(root)
    assert r.exit_code == 2 and "broken on purpose" in r.output, r.output
    assert tree(root) == {k: v for k, v in before.items() if not k.startswith("work/control_resume/")}
    assert not (root / "work").exists()  # the interrupted run made it for the kept frames only


def test_frames_measured_before_a_measurement_change_are_measured_again(tiny_project, tmp_path, monkeypatch):
    """resume-keys: a frame's key held the toolkit's version (0.1.0, never bumped) only, so measurements kept before
    a change of the measurement were reused after it. ``MEASURE_VERSION`` is in the key: bumped, no frame resumes;
    the same version resumes the frames it kept."""
    root = project_copy(tiny_project, tmp_path)
    keep = root / "work" / "control_resume"
    count = _Windows()
    monkeypatch.setattr(P, "FrameWindows", count)
    assert run(root).exit_code == 0
    measured, want = count.opened, tree(root / "control")
    shutil.rmtree(root / "control")

    monkeypatch.setattr(P, "FrameWindows", _Windows(at=4))
    assert run(root).exit_code != 0 and len(list(keep.glob("*.json"))) == 3
    monkeypatch.setattr(P, "MEASURE_VERSION", P.MEASURE_VERSION + 1)
    monkeypatch.setattr(P, "FrameWindows", _Windows(at=4))
    r = run(root)
    assert r.exit_code != 0 and "resumed" not in r.stderr and len(list(keep.glob("*.json"))) == 3 + 3, r.stderr

    count = _Windows()
    monkeypatch.setattr(P, "FrameWindows", count)
    r = run(root)  # the same (bumped) version: its three frames resume
    assert r.exit_code == 0, r.output
    assert count.opened == measured - 3 and "control transfer: resumed 3 of 6 frames" in r.stderr, r.stderr
    assert tree(root / "control") == want
