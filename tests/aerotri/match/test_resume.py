"""``aerotri match`` resumes what an interrupted run finished (work/match_resume, aerotri.core.resume)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_main
from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.geom.camera import project_camera
from aerotri.match import MatchSettings
from aerotri.match import features as F
from aerotri.match import matching as M
from aerotri.match.pipeline import _frame_key


def run(p, *args):
    return CliRunner().invoke(aerotri_main, ["match", str(p), "--workers", "1", *args])


def tree(folder) -> dict:
    return {str(f.relative_to(folder)): f.read_bytes() for f in sorted(folder.rglob("*")) if f.is_file()}


def _untimed(doc: dict) -> dict:
    return {k: v for k, v in doc.items() if k not in ("seconds", "phase_seconds")}


def _npz(b: bytes) -> dict:
    import io

    with np.load(io.BytesIO(b)) as z:
        return {k: z[k] for k in z.files}


@pytest.fixture(scope="module")
def block(tiny_project, tmp_path_factory):
    """The tiny project's inputs and the outputs of one uninterrupted ``aerotri match``."""
    base = tmp_path_factory.mktemp("resume")
    p = shutil.copytree(tiny_project, base / "inputs", ignore=shutil.ignore_patterns("at", "work", "truth"))
    ref = shutil.copytree(p, base / "ref")
    r = run(ref)
    assert r.exit_code == 0, r.output
    return p, ref


class _Breaks:
    """A stand-in for ``real`` that raises ``exc`` at its ``at``-th call (counted over all calls)."""

    def __init__(self, real, at=None, exc=KeyboardInterrupt):
        self.real, self.at, self.exc, self.calls = real, at, exc, 0

    def __call__(self, *a, **k):
        self.calls += 1
        if self.calls == self.at:
            raise self.exc("broken on purpose") if self.exc is InputError else self.exc
        return self.real(*a, **k)


def test_a_rerun_resumes_the_frames_and_pairs_an_interrupted_run_finished(block, tmp_path, monkeypatch):
    """Ctrl-C in the fourth frame's features, then Ctrl-C in the fifth pair's matching: each run keeps what it
    finished in work/match_resume and does only the rest; the last one writes the outputs of one uninterrupted
    run (byte for byte but for the report's times) and clears the folder."""
    inputs, ref = block
    p = shutil.copytree(inputs, tmp_path / "p")
    keep = p / "work" / "match_resume"
    n_frames = len(list((ref / "work" / "features").glob("*.npz")))
    n_pairs = len(list((ref / "work" / "matches").glob("*.npy")))
    assert n_frames == 6 and n_pairs >= 8

    extract = _Breaks(F.extract_level, at=4)
    monkeypatch.setattr(F, "extract_level", extract)
    r = run(p)
    assert r.exit_code != 0 and not (p / "at").exists(), r.output
    assert not list((p / "work" / "features").glob("*.npz"))  # the stage's own outputs are rolled back
    # the frames finished before the interrupt: the three before it, and the tasks that started beside it run to their
    # end (two threads, in dask's order)
    done = len(list(keep.glob("*.npz")))
    assert 3 <= done <= 5 and len(list(keep.iterdir())) == done, list(keep.iterdir())

    extract = _Breaks(F.extract_level)
    matcher = _Breaks(M.match_pair, at=5)
    monkeypatch.setattr(F, "extract_level", extract)
    monkeypatch.setattr(M, "match_pair", matcher)
    r = run(p)
    assert r.exit_code != 0 and not (p / "at").exists(), r.output
    assert extract.calls == 6 - done, "only the frames the first run did not finish"
    assert f"features: resumed {done} of 6 frames an interrupted run finished" in r.stderr, r.stderr
    pairs_done = len(list(keep.glob("*.npy")))
    assert 4 <= pairs_done < n_pairs and len(list(keep.glob("*.npz"))) == 6

    extract = _Breaks(F.extract_level)
    matcher = _Breaks(M.match_pair)
    monkeypatch.setattr(F, "extract_level", extract)
    monkeypatch.setattr(M, "match_pair", matcher)
    r = run(p)
    assert r.exit_code == 0, r.output
    assert extract.calls == 0 and matcher.calls == n_pairs - pairs_done
    assert "features: resumed 6 of 6 frames" in r.stderr, r.stderr
    assert f"matching: resumed {pairs_done} of {n_pairs} pairs" in r.stderr, r.stderr
    assert not keep.exists()

    got, want = tree(p), tree(ref)
    assert sorted(got) == sorted(want)
    for name in want:
        if name == "at/connectivity.json":  # equal but for the times
            assert _untimed(json.loads(got[name])) == _untimed(json.loads(want[name]))
        elif name.endswith(".npz"):  # (a zip member's time)
            a, b = _npz(got[name]), _npz(want[name])
            assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), name
        elif not name.startswith("work/stages/"):
            assert got[name] == want[name], name

    extract = _Breaks(F.extract_level)
    monkeypatch.setattr(F, "extract_level", extract)
    shutil.rmtree(p / "work" / "features")
    r = run(p)  # committed: nothing is resumed, the features are extracted again
    assert r.exit_code == 0 and extract.calls == 6 and "resumed" not in r.stderr, r.output


def test_an_error_leaves_the_project_as_it_was_and_nothing_to_resume(block, tmp_path, monkeypatch):
    """An error (here a bad frame among the features left to extract) after an interrupted run: no output, and the
    frames that run kept are gone too; only an interrupt or a kill keeps them."""
    inputs, _ = block
    p = shutil.copytree(inputs, tmp_path / "p")
    monkeypatch.setattr(F, "extract_level", _Breaks(F.extract_level, at=2))
    r = run(p)
    assert r.exit_code != 0 and (p / "work" / "match_resume").is_dir(), r.output
    before = tree(p)
    monkeypatch.setattr(F, "extract_level", _Breaks(F.extract_level, at=1, exc=InputError))
    r = run(p)
    assert r.exit_code == 2 and "broken on purpose" in r.output, r.output
    assert tree(p) == {k: v for k, v in before.items() if not k.startswith("work/match_resume/")}
    assert not (p / "work" / "match_resume").exists()


def test_a_changed_image_is_not_resumed(block, tmp_path, monkeypatch):
    """The key of a kept frame holds its image's size and time: a frame rewritten after the interrupt is extracted
    again, the others are resumed."""
    import os

    inputs, _ = block
    p = shutil.copytree(inputs, tmp_path / "p")
    monkeypatch.setattr(F, "extract_level", _Breaks(F.extract_level, at=4))
    assert run(p).exit_code != 0
    keep = p / "work" / "match_resume"
    done = len(list(keep.glob("*.npz")))
    camera = project_camera(Project.open(p))
    first = next(f for f in sorted((p / "images").glob("*.tif"))  # a frame that was kept
                 if (keep / f"{_frame_key(f, MatchSettings().sparse, (camera.width, camera.height))}.npz").exists())
    st = first.stat()
    os.utime(first, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    extract = _Breaks(F.extract_level)
    monkeypatch.setattr(F, "extract_level", extract)
    r = run(p)
    assert r.exit_code == 0, r.output
    assert extract.calls == 6 - done + 1 and f"resumed {done - 1} of 6 frames" in r.stderr, r.stderr


def test_pairs_kept_before_a_matching_change_are_matched_again(block, tmp_path, monkeypatch):
    """resume-keys: a pair's key held the toolkit's version (0.1.0, never bumped) only, so matches kept before a
    change of the matching were reused after it. ``MATCH_VERSION`` is in the key: bumped, every pair is matched
    again, while the frames' features (the same ``FEATURES_VERSION``) resume."""
    from aerotri.match import settings

    inputs, ref = block
    p = shutil.copytree(inputs, tmp_path / "p")
    keep = p / "work" / "match_resume"
    n_pairs = len(list((ref / "work" / "matches").glob("*.npy")))
    monkeypatch.setattr(M, "match_pair", _Breaks(M.match_pair, at=5))
    assert run(p).exit_code != 0
    assert len(list(keep.glob("*.npz"))) == 6 and len(list(keep.glob("*.npy"))) >= 4

    monkeypatch.setattr(settings, "MATCH_VERSION", settings.MATCH_VERSION + 1)
    extract, matcher = _Breaks(F.extract_level), _Breaks(M.match_pair)
    monkeypatch.setattr(F, "extract_level", extract)
    monkeypatch.setattr(M, "match_pair", matcher)
    r = run(p)
    assert r.exit_code == 0, r.output
    assert extract.calls == 0 and "features: resumed 6 of 6 frames" in r.stderr, r.stderr
    assert matcher.calls == n_pairs and "matching: resumed" not in r.stderr, r.stderr
    assert (p / "at" / "tiepoints.csv").read_bytes() == (ref / "at" / "tiepoints.csv").read_bytes()
