"""Outputs replaced as a whole (review 12b): the OS's clutter (.DS_Store, Thumbs.db, desktop.ini, ._*) and QGIS's
saved styles do not stop a rerun; a folder or GeoPackage is judged ours by provenance (a strips record, names
derived from the inputs, the GeoPackage's mark), names alone only with a warning naming what is replaced."""

from __future__ import annotations

import json
import logging
import sqlite3

import pytest
import shapely

from aerotri.core.atomic import atomic_dir, refuse_foreign_contents
from aerotri.core.errors import InputError, OptionError
from aerotri.core.vector_files import MARK, VectorLayer, refuse_foreign_layers, write_layers

CLUTTER = (".DS_Store", "Thumbs.db", "desktop.ini", "._strip_0.las")


def _las_only(entry) -> bool:
    return entry.suffix.lower() in (".las", ".laz")


def test_os_clutter_goes_with_the_output_and_a_users_file_is_named_to_move(tmp_path):
    out = tmp_path / "classified"
    out.mkdir()
    for name in (*CLUTTER, "strip_0.las"):
        (out / name).write_bytes(b"x")
    refuse_foreign_contents(out, _las_only, "lidarctl classify")  # no error: Finder's and Explorer's files pass
    with atomic_dir(out) as tmp:
        (tmp / "strip_0.las").write_bytes(b"new")
    assert sorted(p.name for p in out.iterdir()) == ["strip_0.las"]  # they went with the replaced folder
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OptionError, match=r"holds notes.txt, which lidarctl classify did not write: move it out "
                                          r"of the folder \(or remove it\) and run again"):
        refuse_foreign_contents(out, _las_only, "lidarctl classify")
    assert (out / "notes.txt").read_text() == "mine"


def test_a_strips_folder_is_ours_by_its_record_not_by_names(tmp_path):
    from lidarctl.strips.check import refuse_replacing

    out = tmp_path / "strips"
    out.mkdir()
    for name in ("a.las", "index.html", "overview.png", "diff_1_2.tif", ".DS_Store"):
        (out / name).write_bytes(b"x")
    with pytest.raises(OptionError, match="holds a.las, diff_1_2.tif, index.html and 1 more, which lidarctl strips "
                                          r"\(the folder holds no strips.json or adjust.json of it\) did not write"):
        refuse_replacing(out, [])
    (out / "strips.json").write_text(json.dumps({"schema_version": 1, "why": "no overlap"}))
    refuse_replacing(out, [])  # a previous check: replaced
    (out / "strips.json").write_text(json.dumps({"my": "notes"}))  # a user's strips.json is no record
    with pytest.raises(OptionError, match="did not write"):
        refuse_replacing(out, [])
    # records written before 2026-11-28 have no schema_version: ours by their keys (reviewer 14)
    for legacy in ({"convention": "b - a", "cell_m": 1.0, "pairs": []}, {"why": "nothing to compare"}):
        (out / "strips.json").write_text(json.dumps(legacy))
        refuse_replacing(out, [])
    (out / "strips.json").unlink()
    (out / "adjust.json").write_text(json.dumps({"model": "strip", "cell_m": 1.0, "parameters": {}}))
    refuse_replacing(out, [])
    (out / "adjust.json").write_text(json.dumps({"cell_m": 1.0}))  # one key of ours is not a record
    with pytest.raises(OptionError) as err:
        refuse_replacing(out, [], option=None)  # the chain: the folder named, not OUTDIR
    assert err.value.param is None and err.value.user_message().startswith(f"Error: {out}: ")
    (out / "adjust.json").unlink()
    for p in out.iterdir():
        p.unlink()
    (out / "Thumbs.db").write_bytes(b"x")
    refuse_replacing(out, [])  # empty but for clutter


def test_classify_claims_its_recorded_names_or_without_a_record_those_of_its_inputs(tmp_path, caplog):
    """Reviewer 14: `lidarctl classify strips... OUT_DIR` deleted a user's LAS/LAZ in OUT_DIR with a warning. Now
    its record (classify.json) names what it wrote; without one only the names derived from this run's inputs
    (an output written before the record) are replaced, other LAS/LAZ refused (exit 2, named)."""
    from lidarctl import tiles

    strips = [tmp_path / "in" / f"strip_{i}.las" for i in range(2)]
    strips[0].parent.mkdir()
    for p in strips:
        p.write_bytes(f"not a LAS file: {p.name}".encode())
    out = tmp_path / "out"
    out.mkdir()
    for name in ("strip_0.las", "strip_1.las", ".DS_Store"):
        (out / name).write_bytes(b"x")
    with caplog.at_level(logging.WARNING), pytest.raises(InputError, match="strip_0.las: not a LAS"):
        tiles.classify_files(strips, out)  # an old output of exactly our names: past the folder check, silent
    assert not [r for r in caplog.records if "replacing" in r.getMessage()]
    (out / "users_tile.laz").write_bytes(b"x")
    with pytest.raises(OptionError, match=r"holds users_tile.laz, which lidarctl classify \(the folder has no "
                                          r"classify.json"):
        tiles.classify_files(strips, out)
    assert (out / "users_tile.laz").read_bytes() == b"x"
    # with the record: what it names is ours (a run on other strips), nothing else
    (out / tiles.CLASSIFY_RECORD).write_text(json.dumps({"schema_version": 1, "kind": tiles.CLASSIFY_RECORD_KIND,
                                                         "files": ["users_tile.laz", "strip_0.las"]}))
    with pytest.raises(OptionError, match=r"holds strip_1.las, which lidarctl classify did not write"):
        tiles.classify_files(strips, out)
    (out / "strip_1.las").unlink()
    with pytest.raises(InputError, match="strip_0.las: not a LAS"):
        tiles.classify_files(strips, out)


def _contours():
    return [VectorLayer("contours", "LineString", [shapely.LineString([(500000, 3400000), (500010, 3400010)])])]


def test_our_geopackage_is_marked_and_keeps_qgis_styles_a_users_is_refused(tmp_path, caplog):
    import pyogrio

    path = write_layers(tmp_path / "contours.gpkg", _contours(), crs="EPSG:32649")
    with sqlite3.connect(path) as db:
        assert db.execute("SELECT description FROM gpkg_contents WHERE table_name='contours'").fetchone() == (MARK,)
        # QGIS's "Save style ... in database"
        db.execute("CREATE TABLE layer_styles (id INTEGER PRIMARY KEY AUTOINCREMENT, f_table_name TEXT, styleQML TEXT)")
        db.execute("INSERT INTO layer_styles (f_table_name, styleQML) VALUES ('contours', '<qgis/>')")
        db.execute("INSERT INTO gpkg_contents (table_name, data_type, identifier) VALUES "
                   "('layer_styles', 'attributes', 'layer_styles')")
    with caplog.at_level(logging.WARNING):
        refuse_foreign_layers(path, ("contours",), "lidarctl contours")
        write_layers(path, _contours(), crs="EPSG:32649")
    assert not [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert [str(n) for n, _ in pyogrio.list_layers(path)] == ["contours", "layer_styles"]
    with sqlite3.connect(path) as db:
        assert db.execute("SELECT f_table_name, styleQML FROM layer_styles").fetchall() == [("contours", "<qgis/>")]
    # a user's GeoPackage whose only layer has our name: refused, naming it (trial s94: a copy of the BGT reference
    # given as lidarctl vectors' OUT was replaced with a warning)
    user = tmp_path / "mine.gpkg"
    pyogrio.raw.write(str(user), shapely.to_wkb([shapely.Point(500000, 3400000)]), field_data=[], fields=[],
                      layer="contours", driver="GPKG", crs="EPSG:32649", geometry_type="Point")
    with pytest.raises(OptionError, match="mine.gpkg: .*layer.s. contours have the names lidarctl contours writes "
                                          "but not the mark"):
        refuse_foreign_layers(user, ("contours",), "lidarctl contours")
    refuse_foreign_layers(user, ("contours",), "lidarctl contours", owned=True)  # the chain's own: an older version's
    pyogrio.raw.write(str(user), shapely.to_wkb([shapely.Point(500000, 3400000)]), field_data=[], fields=[],
                      layer="parcels", driver="GPKG", crs="EPSG:32649", geometry_type="Point", append=True)
    with pytest.raises(OptionError, match="holds the layer.s. parcels.*move the file"):
        refuse_foreign_layers(user, ("contours",), "lidarctl contours")


def test_a_linked_output_folder_is_replaced_through_the_link(tmp_path):
    """Review 12b: OUTDIR a link to a folder (on another disk) was replaced by a real folder, the old output left at
    the link's target. Now the target's contents are replaced and the link stays."""
    target = tmp_path / "disk2" / "strips"
    target.mkdir(parents=True)
    (target / "old.las").write_bytes(b"old")
    link = tmp_path / "project" / "strips"
    link.parent.mkdir()
    link.symlink_to(target, target_is_directory=True)
    with atomic_dir(link) as tmp:
        (tmp / "new.las").write_bytes(b"new")
    assert link.is_symlink() and sorted(p.name for p in target.iterdir()) == ["new.las"]
    assert sorted(p.name for p in target.parent.iterdir()) == ["strips"]  # no temporary left beside it
    (tmp_path / "gone").mkdir()
    broken = tmp_path / "project" / "broken"
    broken.symlink_to(tmp_path / "gone", target_is_directory=True)
    (tmp_path / "gone").rmdir()
    with pytest.raises(OptionError, match="broken: the output folder is a broken link"):
        refuse_foreign_contents(broken, _las_only, "lidarctl classify")


_KILL_MID_SWAP = """
import os, signal, sys
import aerotri.core.atomic as A
def replace(self, src, dst, kind):  # the old folder moved into the journal, killed before the new one moves in
    entry = self.record(self.rel(dst), kind)
    os.replace(os.path.join(self.base, self.rel(dst)), self.backup_path(entry))
    os.kill(os.getpid(), signal.SIGKILL)
A._Commit.replace = replace
with A.atomic_dir(sys.argv[1]) as tmp:
    (tmp / "strips.json").write_text("{}")
"""


def test_what_a_killed_run_left_beside_a_linked_outputs_target_is_recovered(tmp_path):
    """Reviewer 14's killswap.py: OUTDIR a link; a run killed between moving the old folder into the commit
    journal and the new one in left the journal (and temporaries) beside the link's target, never recovered:
    the link stayed broken. The next command recovers and sweeps there too."""
    import subprocess
    import sys

    from click.testing import CliRunner

    from lidarctl.cli.main import main

    target = tmp_path / "disk2" / "strips"
    target.mkdir(parents=True)
    (target / "strips.json").write_text('{"why": "old"}')
    link = tmp_path / "project" / "strips"
    link.parent.mkdir()
    link.symlink_to(target, target_is_directory=True)
    r = subprocess.run([sys.executable, "-c", _KILL_MID_SWAP, str(link)], capture_output=True)
    assert r.returncode == -9
    assert not target.exists() and [p.name for p in target.parent.iterdir() if ".commit-" in p.name]
    assert [p.name for p in target.parent.iterdir() if ".part-" in p.name]  # the new folder's temporary
    r = CliRunner().invoke(main, ["strips", "check", str(tmp_path / "missing.las"), str(link)])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert sorted(p.name for p in target.parent.iterdir()) == ["strips"]  # journal rolled back, temporary swept
    assert (link / "strips.json").read_text() == '{"why": "old"}'


_HOLD_TARGET = """
import sys, time
from pathlib import Path
from aerotri.core.lock import hold_lock
real = Path(sys.argv[1])
with hold_lock(real.parent / f".{real.name}.lock", "ortho mosaic", 0, str(real)):
    (real.parent / f".{real.name}.part-live").mkdir()
    print("held", flush=True)
    time.sleep(30)
"""


@pytest.mark.parametrize("link_at", ["link/out", "real/latest"])
def test_a_run_through_a_link_waits_for_a_run_on_the_links_target(tmp_path, link_at):
    """Review 15's lk.py: run A writes real/out (its lock and a live temporary beside it); run B writes link/out, a
    link to real/out. B took only the lock beside the link and swept A's live temporary. B now also takes the
    target's lock: busy, A's temporary kept. Review 16: the same with the link beside its target (latest -> out),
    where B took no target lock at all."""
    import contextlib
    import subprocess
    import sys
    import types

    from aerotri.core.commands import Command
    from aerotri.core.lock import BusyError

    real = tmp_path / "real" / "out"
    real.mkdir(parents=True)
    link = tmp_path / link_at
    link.parent.mkdir(exist_ok=True)
    link.symlink_to(real, target_is_directory=True)
    a = subprocess.Popen([sys.executable, "-c", _HOLD_TARGET, str(real)], stdout=subprocess.PIPE, text=True)
    try:
        assert a.stdout.readline().strip() == "held"
        ns = types.SimpleNamespace(_writes_to=[], per_stage=True)
        with pytest.raises(BusyError), contextlib.ExitStack() as stack:
            Command._lock_output(ns, stack, link, "ortho mosaic", 0, lambda home: None)
        assert (tmp_path / "real" / ".out.part-live").is_dir()
    finally:
        a.kill()
        a.wait()


def test_leftovers_of_an_output_are_its_own_temporaries_only(tmp_path):
    """Review 16: the sweep of ortho.v1's leftovers matched by the stem's prefix ".ortho." and deleted the live
    temporaries of ortho.v2 (and mosaic.json's those of mosaic.tif). Now whole names: the output's own, its stem's
    (the mosaic's scratch ".mosaic.part-*") and their work folders (".<stem>.tiles.part-*")."""
    from aerotri.core.atomic import remove_leftovers

    mine = [".ortho.v1.part-a", ".ortho.part-b", ".ortho.tiles.part-c", ".ortho.v1.corners.part-d"]
    others = [".ortho.v2.part-live", ".ortho.v2.tiles.part-live", ".ortho.v10.part-live", ".orthos.part-live"]
    for name in mine + others:
        (tmp_path / name).mkdir()
    gone = remove_leftovers(tmp_path, names=["ortho.v1"])
    assert sorted(p.name for p in gone) == sorted(mine)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(others)
    (tmp_path / ".mosaic.tif.part-live").mkdir()
    assert remove_leftovers(tmp_path, names=["mosaic.json"]) == []
    assert (tmp_path / ".mosaic.tif.part-live").is_dir()
    # atomic_path's file temporaries carry the stem and the suffix, a sidecar's its own suffix (ct.gpkg's preview
    # ".ct.part-XXXX.png"): swept with the output (test_faults' kill of `lidarctl contours`)
    for name in (".ct.part-dead1.gpkg", ".ct.part-dead2.png", ".cts.part-live.gpkg"):
        (tmp_path / name).write_bytes(b"")
    gone = remove_leftovers(tmp_path, names=["ct.gpkg"])
    assert sorted(p.name for p in gone) == [".ct.part-dead1.gpkg", ".ct.part-dead2.png"]
    assert (tmp_path / ".cts.part-live.gpkg").is_file()
