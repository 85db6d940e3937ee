"""The tiled classification resumes the tiles an interrupted run finished (``classify_files(resume_dir=...)``,
the chain's work/classify_resume): a re-run computes only the rest and writes the same bytes."""

from __future__ import annotations

import functools
import logging
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import tile_faults  # tests/lidarctl/tile_faults.py, through tests/lidarctl/conftest.py

from aerotri.core.errors import InputError
from aerotri.core.executor import Executor
from lidarctl import io, synthetic, tiles

TILING = dict(tile_size_m=70.0, buffer_m=28.0)  # 2 x 2 tiles over the 140 m scene


@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    """A 140 m scene (2.5 points/m2) cut into two strips along y."""
    d = tmp_path_factory.mktemp("resume_strips")
    cloud, _ = synthetic.synthetic_scene(width_m=140.0, density_per_m2=2.5, seed=5, n_buildings=4, n_trees=30)
    paths = []
    for k, sel in enumerate((cloud.y < np.median(cloud.y), cloud.y >= np.median(cloud.y))):
        part = io.PointCloud(*(getattr(cloud, f)[sel] for f in ("x", "y", "z", "intensity", "return_number",
                                                                  "number_of_returns", "classification")))
        paths.append(d / "lidar" / f"strip_{k}.laz")
        paths[-1].parent.mkdir(exist_ok=True)
        synthetic.write_las(paths[-1], part, crs="EPSG:32632")
    return paths


def _tree(folder) -> dict:
    return {f.name: f.read_bytes() for f in sorted(folder.iterdir())}


# ``tiles._classify_tile`` counting the tiles it computes, raising KeyboardInterrupt (or ``exc``) at the ``at``-th
_Tiles = functools.partial(tile_faults.Tiles, tiles._classify_tile)


def _classify(paths, root, resume=True, params=None):
    with Executor("synchronous") as ex:  # one tile after the other: the interrupt comes at a known tile
        return tiles.classify_files(paths, root / "classified", params=params, executor=ex, suffix=".laz",
                                    resume_dir=root / "work" / "classify_resume" if resume else None, **TILING)


def test_a_rerun_resumes_the_tiles_an_interrupted_run_finished(strips, tmp_path, monkeypatch, caplog):
    """Ctrl-C at the third tile: the two classified before are kept; the next run classifies only the others
    and writes the strips of one uninterrupted run, byte for byte, then clears the folder."""
    ref = _classify(strips, tmp_path / "ref", resume=False)
    n = ref.run.n_tiles
    assert n == 4
    want = _tree(tmp_path / "ref" / "classified")
    root = tmp_path / "p"
    keep = root / "work" / "classify_resume"

    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    with pytest.raises(KeyboardInterrupt):
        _classify(strips, root)
    assert not (root / "classified").exists()  # the set: all or none
    assert len(list(keep.glob("*.json"))) == 2 and len(list(keep.glob("*.npy"))) == 4
    assert [p.name for p in root.iterdir()] == ["work"]  # the tiles' work folder went

    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    with caplog.at_level(logging.INFO, logger="lidarctl.tiles"):
        st = _classify(strips, root)
    assert count.done == n - 2
    assert f"tiles: resumed 2 of {n} tiles an interrupted run finished" in caplog.text
    assert _tree(root / "classified") == want
    assert st.run.class_counts == ref.run.class_counts and st.run.tiled_points == ref.run.tiled_points
    assert not keep.exists() and sorted(p.name for p in root.rglob("*")) == ["classified", "classify.json",
                                                                               "strip_0.laz", "strip_1.laz", "work"]


def test_a_changed_strip_resumes_nothing(strips, tmp_path, monkeypatch, caplog):
    """The kept tiles' key holds the strips' size and time: after a strip changed every tile is classified."""
    lidar = tmp_path / "lidar"
    shutil.copytree(strips[0].parent, lidar)
    paths = sorted(lidar.glob("*.laz"))
    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    with pytest.raises(KeyboardInterrupt):
        _classify(paths, tmp_path)
    st = os.stat(paths[1])
    os.utime(paths[1], ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    with caplog.at_level(logging.INFO, logger="lidarctl.tiles"):
        _classify(paths, tmp_path)
    assert count.done == 4 and "resumed" not in caplog.text
    assert not (tmp_path / "work" / "classify_resume").exists()


def test_an_error_leaves_nothing_and_nothing_to_resume(strips, tmp_path, monkeypatch):
    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    with pytest.raises(KeyboardInterrupt):
        _classify(strips, tmp_path)
    assert len(list((tmp_path / "work" / "classify_resume").glob("*.json"))) == 2
    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=2, exc=InputError))
    with pytest.raises(InputError, match="broken on purpose"):
        _classify(strips, tmp_path)
    assert list(tmp_path.iterdir()) == []  # work/ too: the interrupted run made it for the kept tiles only


KILLED = """
import logging
import sys
from pathlib import Path
from aerotri.core.atomic import remove_leftovers
from aerotri.core.executor import Executor
from lidarctl import tiles
logging.basicConfig(level=logging.INFO)
root, paths = Path(sys.argv[1]), sys.argv[2:]
remove_leftovers(root)  # what a killed run left of its atomic writes, as the chain's classify stage does
with Executor("synchronous") as ex:
    tiles.classify_files(paths, root / "classified", executor=ex, suffix=".laz",
                         resume_dir=root / "work" / "classify_resume", tile_size_m=70.0, buffer_m=28.0)
"""


def _kept_records(keep) -> int:
    """The tiles' statistics kept whole: not a record being written (``.<key>.part-keep.json``, which pathlib's glob
    counts too; a kill can leave one, swept by the next command)."""
    return sum(1 for f in keep.glob("*.json") if not f.name.startswith("."))


def test_sigkill_in_the_middle_keeps_the_finished_tiles(strips, tmp_path):
    """A process killed (SIGKILL) once two tiles are kept: the next run takes them and writes the same bytes."""
    ref = tmp_path / "ref"
    _classify(strips, ref, resume=False)
    root = tmp_path / "p"
    keep = root / "work" / "classify_resume"
    proc = subprocess.Popen([sys.executable, "-c", KILLED, str(root), *map(str, strips)], start_new_session=True)
    t0 = time.monotonic()
    while proc.poll() is None and time.monotonic() - t0 < 120:
        if keep.is_dir() and _kept_records(keep) >= 2:
            os.killpg(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.02)
    assert proc.wait(timeout=60) == -signal.SIGKILL
    kept = _kept_records(keep)
    assert 2 <= kept < 4 and not (root / "classified").exists()
    done = subprocess.run([sys.executable, "-c", KILLED, str(root), *map(str, strips)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"resumed {kept} of 4 tiles an interrupted run finished" in done.stderr, done.stderr
    assert _tree(root / "classified") == _tree(ref / "classified")
    assert not keep.exists() and not [p for p in root.rglob(".*")]


def test_the_chain_classify_stage_resumes_its_tiles(tiny_project, tmp_path, monkeypatch, caplog):
    """The chain's classify stage keeps its tiles in work/classify_resume: Ctrl-C at the third tile, then the
    re-run classifies the rest, says so, and commits the strips of one uninterrupted run and its stamp."""
    from aerotri.chain import chain_stages, run_stages
    from aerotri.core.executor import activate

    # tiles of 300 m (+ 30 m buffer): 4 over the tiny block's first two strips, which fit one tile by default (100 m
    # + 50 m made 54, each classified three times here)
    plan = tiles.plan_tiles
    monkeypatch.setattr(tiles, "plan_tiles", lambda header, _t, _b, *a, **k: plan(header, 300.0, 30.0, *a, **k))

    def classify(root):
        with Executor("synchronous") as ex, activate(ex):
            return run_stages(root, [s for s in chain_stages(root) if s.name == "classify"])

    ref, root = tmp_path / "ref", tmp_path / "p"
    for d in (ref, root):
        shutil.copytree(tiny_project, d, ignore=shutil.ignore_patterns("truth", "images", "strip_0[34].*"))
    n = classify(ref)[0]["tiles"]
    assert n == 4
    want = _tree(ref / "lidar_out" / "classified")

    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    with pytest.raises(KeyboardInterrupt):
        classify(root)
    keep = root / "work" / "classify_resume"
    assert len(list(keep.glob("*.json"))) == 2 and not (root / "lidar_out" / "classified").exists()
    assert not (root / "work" / "stages" / "classify.json").exists()

    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    with caplog.at_level(logging.INFO, logger="lidarctl.tiles"):
        row = classify(root)[0]
    assert row["status"] == "done" and count.done == n - 2
    assert f"tiles: resumed 2 of {n} tiles an interrupted run finished" in caplog.text
    assert _tree(root / "lidar_out" / "classified") == want
    assert (root / "work" / "stages" / "classify.json").is_file() and not keep.exists()
    assert [p for p in root.rglob(".*")] == []


# ----------------------------------------------------------------------------------------------
# `lidarctl classify`: the same per tile, in OUT.resume beside the output

CLI_TILING = ["--tile-size-m", "70", "--buffer-m", "28", "--scheduler", "synchronous"]


def _cli(paths, out, *options):
    from click.testing import CliRunner

    from lidarctl.cli.main import main

    return CliRunner().invoke(main, ["classify", *map(str, paths), str(out), *CLI_TILING, *options])


@pytest.fixture(scope="module")
def cli_reference(strips, tmp_path_factory):
    """The classified strips of one uninterrupted `lidarctl classify` (4 tiles), file name -> bytes."""
    out = tmp_path_factory.mktemp("cli_ref") / "classified"
    r = _cli(strips, out)
    assert r.exit_code == 0, r.output
    assert not (out.parent / "classified.resume").exists()
    return _tree(out)


def test_lidarctl_classify_resumes_after_ctrl_c(strips, cli_reference, tmp_path, monkeypatch):
    """Ctrl-C at the third tile: the command exits 130, writes no output and keeps two tiles in classified.resume;
    the next run says it resumed them, classifies the other two, writes the uninterrupted run's bytes and removes
    the folder."""
    out, keep = tmp_path / "classified", tmp_path / "classified.resume"
    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    r = _cli(strips, out)
    assert r.exit_code == 130, r.output
    assert not out.exists() and len(list(keep.glob("*.json"))) == 2
    assert f"{keep}: what this run finished is kept there" in r.stderr

    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    r = _cli(strips, out)
    assert r.exit_code == 0, r.output
    assert "tiles: resumed 2 of 4 tiles an interrupted run finished" in r.stderr and count.done == 2
    assert _tree(out) == cli_reference
    assert sorted(p.name for p in tmp_path.iterdir()) == ["classified"]


def test_lidarctl_classify_changed_setting_or_no_resume_starts_over(strips, cli_reference, tmp_path, monkeypatch):
    """A ground filter setting changed since the interrupted run: no tile is taken (the key holds the settings);
    --no-resume removes the kept tiles and classifies every tile, to the uninterrupted run's bytes."""
    out, keep = tmp_path / "classified", tmp_path / "classified.resume"
    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    assert _cli(strips, out).exit_code == 130 and len(list(keep.glob("*.json"))) == 2

    count = _Tiles(at=3)
    monkeypatch.setattr(tiles, "_classify_tile", count)
    r = _cli(strips, out, "--morph-cell-m", "2.0")  # interrupted again: kept its own two tiles beside the others
    assert r.exit_code == 130 and "resumed" not in r.stderr and count.done == 2
    assert len(list(keep.glob("*.json"))) == 4

    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    r = _cli(strips, out, "--no-resume")
    tile_faults.check_started_over(r, count, 4, keep, _tree(out), cli_reference)


def test_lidarctl_classify_sigkill_then_resume(strips, cli_reference, tmp_path):
    """A `lidarctl classify` process killed (SIGKILL) as its third tile starts: no output, no temporary left after
    the next run's start, two tiles kept; the next run takes them and writes the uninterrupted run's bytes."""
    from click.testing import CliRunner

    out, keep = tmp_path / "classified", tmp_path / "classified.resume"
    args = ["classify", *map(str, strips), str(out), *CLI_TILING]
    assert tile_faults.killed_at("lidarctl.tiles", "_classify_tile", 3, args) == -signal.SIGKILL
    assert not out.exists() and len(list(keep.glob("*.json"))) == 2
    assert [p for p in tmp_path.iterdir() if ".part-" in p.name]  # the killed run's temporaries, swept next

    from lidarctl.cli.main import main

    count = _Tiles()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tiles, "_classify_tile", count)
        r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "tiles: resumed 2 of 4 tiles an interrupted run finished" in r.stderr and count.done == 2
    assert _tree(out) == cli_reference
    assert sorted(p.name for p in tmp_path.rglob("*") if p.parent == tmp_path) == ["classified"]


def test_lidarctl_classify_one_file_resumes_beside_it(strips, tmp_path, monkeypatch):
    """One file into OUT.laz: the tiles are kept in OUT.laz.resume; the resumed run writes the bytes of one
    uninterrupted run."""
    tiling = ["--tile-size-m", "40", "--buffer-m", "20"]  # over CLI_TILING's (the last value wins)
    r = _cli(strips[:1], tmp_path / "ref.laz", *tiling)
    assert r.exit_code == 0, r.output
    out, keep = tmp_path / "out.laz", tmp_path / "out.laz.resume"
    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    assert _cli(strips[:1], out, *tiling).exit_code == 130
    assert not out.exists() and len(list(keep.glob("*.json"))) == 2
    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    r = _cli(strips[:1], out, *tiling)
    assert r.exit_code == 0, r.output
    n = count.done + 2
    assert n >= 4 and f"tiles: resumed 2 of {n} tiles an interrupted run finished ({keep})" in r.stderr
    assert out.read_bytes() == (tmp_path / "ref.laz").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.laz", "ref.laz"]


def test_tiles_kept_before_a_rule_change_are_not_reused(strips, tmp_path, monkeypatch, caplog):
    """Reviewer 8: the key held the toolkit's version (0.1.0) only: tiles kept before a rule change (i44-water) were
    reused after it. The rules' version (``lidarctl.classify.RULES_VERSION``) is in the key: bumped, nothing resumes."""
    import lidarctl.classify

    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    with pytest.raises(KeyboardInterrupt):
        _classify(strips, tmp_path)
    assert len(list((tmp_path / "work" / "classify_resume").glob("*.json"))) == 2
    monkeypatch.setattr(lidarctl.classify, "RULES_VERSION", lidarctl.classify.RULES_VERSION + 1)
    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    with caplog.at_level(logging.INFO, logger="lidarctl.tiles"):
        _classify(strips, tmp_path)
    assert count.done == 4 and "resumed" not in caplog.text


def test_a_rule_change_under_an_option_that_is_off_reuses_the_tiles(strips, tmp_path, monkeypatch, caplog):
    """Review 19: RULES_VERSION 10 (level-bodies-sparse, classes changed only with ``water_whole_level_bodies`` on)
    made every project classify again (the demo 250 s, a big block hours) for the same classes. A version whose
    changes decide classes only with an option on (``OPTION_ONLY_VERSIONS``) is in the key of runs with it on only:
    with it off the key holds the version before (9, as the projects made before level-bodies-sparse hold), and the
    kept tiles resume; with it on, nothing resumes. (On by default since level-wire, version 12.)"""
    import lidarctl.classify
    from lidarctl.classify import pipeline

    off, on = pipeline.ClassifySettings(water_whole_level_bodies=False), pipeline.ClassifySettings()
    assert lidarctl.classify.rules_version(off) == 18   # versions 13 to 18 decide classes with it off too
    assert lidarctl.classify.rules_version(on) == lidarctl.classify.RULES_VERSION
    monkeypatch.setattr(tiles, "_classify_tile", _Tiles(at=3))
    with pytest.raises(KeyboardInterrupt):
        _classify(strips, tmp_path, params=off)
    bumped = lidarctl.classify.RULES_VERSION + 1
    monkeypatch.setattr(lidarctl.classify, "RULES_VERSION", bumped)
    monkeypatch.setattr(lidarctl.classify, "OPTION_ONLY_VERSIONS",
                        {**lidarctl.classify.OPTION_ONLY_VERSIONS, bumped: "water_whole_level_bodies"})
    assert lidarctl.classify.rules_version(off) == 18 and lidarctl.classify.rules_version(on) == bumped
    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)
    with caplog.at_level(logging.INFO, logger="lidarctl.tiles"):
        _classify(strips, tmp_path, params=off)
    assert count.done == 2 and "resumed 2 of 4 tiles" in caplog.text


def test_every_tile_resumed_skips_the_water_grid(strips, tmp_path, monkeypatch):
    """Interrupted while writing (all four tiles kept): the re-run classifies no tile and skips the whole cloud's
    water grid (two passes over the tile files; the kept tiles hold its verdicts), writing the same bytes."""
    _classify(strips, tmp_path / "ref", resume=False)
    root = tmp_path / "p"
    write = io.write_classified

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(io, "write_classified", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _classify(strips, root)
    assert len(list((root / "work" / "classify_resume").glob("*.json"))) == 4
    monkeypatch.setattr(io, "write_classified", write)
    count = _Tiles()
    monkeypatch.setattr(tiles, "_classify_tile", count)

    def no_water_grid(*args, **kwargs):
        raise AssertionError("water_grid computed though every tile was resumed")

    monkeypatch.setattr(tiles, "water_grid", no_water_grid)
    _classify(strips, root)
    assert count.done == 0
    assert _tree(root / "classified") == _tree(tmp_path / "ref" / "classified")
