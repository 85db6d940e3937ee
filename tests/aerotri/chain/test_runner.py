"""The resumable stage runner: skip when up to date, re-run on changed inputs, nothing stamped on failure."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import time
from pathlib import Path

import pytest

from aerotri.chain import Stage, StageResult, format_summary, run_stages, stamp_path
from aerotri.chain.runner import stale_reason


@dataclasses.dataclass(frozen=True, kw_only=True)
class Value(StageResult):
    value: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class Points(StageResult):
    points: int


def _stages(calls):
    def double(r):
        calls.append("double")
        v = int((r / "in.txt").read_text())
        (r / "mid.txt").write_text(str(2 * v))
        return Value(value=2 * v)

    def add(r):
        calls.append("add")
        v = int((r / "mid.txt").read_text())
        if v < 0:
            raise RuntimeError("negative")
        (r / "out.txt").write_text(str(v + 1))
        return Value(value=v + 1)

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
    from aerotri.core.atomic import atomic_path, scratch_dir

    (tmp_path / "in.txt").write_text("2")
    # What a SIGKILL leaves behind in the folder of a stage's outputs: atomic_path files (the outputs', and
    # other files written there, as the frames next to ortho/frames/index.json) and scratch folders (the
    # mosaic's, the LiDAR tiles')
    names = []
    for name in ("mid.txt", "out.txt", "frame_007.tif"):
        with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / name) as tmp:
            names.append(tmp.name)
            raise KeyboardInterrupt
    with scratch_dir(tmp_path, "mosaic") as work:
        names.append(work.name)
    for n in names[:3]:  # as if the process had died before its clean-up
        (tmp_path / n).write_text("partial")
    (tmp_path / names[3]).mkdir()
    (tmp_path / names[3] / "stage.tif").write_text("partial")
    (tmp_path / ".keep").write_text("not a temporary")
    run_stages(tmp_path, _stages([]), log=lambda m: None)
    assert sorted(p.name for p in tmp_path.glob(".*")) == [".keep"]
    assert (tmp_path / "out.txt").read_text() == "5"


def test_skipped_stage_says_why_and_options_rerun_a_stage(tmp_path):
    (tmp_path / "in.txt").write_text("3")
    calls = []
    stages = _stages(calls)
    stages[1].skip = lambda r: "no mid.txt wanted" if (r / "skip").exists() else None
    (tmp_path / "skip").write_text("")
    rows = run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["double"] and rows[1]["status"] == "skipped" and rows[1]["why"] == "no mid.txt wanted"
    assert not stamp_path(tmp_path, "add").exists()
    assert "no mid.txt wanted" in format_summary(rows)
    (tmp_path / "skip").unlink()
    calls.clear()
    run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["add"]
    # changed options (tuples and paths as the JSON stamp keeps them) re-run the stage, equal ones do not
    stages[1].options = lambda r: dict(k=(1, 2), p=r / "x")
    calls.clear()
    run_stages(tmp_path, stages, log=lambda m: None)
    run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["add"]


def test_chain_stages_list_the_project_files_their_commands_read(tmp_path):
    """A changed camera, GNSS file or project.toml section they read ([gnss]/[control] sigmas, [qa] limits: an
    option since trial-rerun) re-runs the adjustments; a replaced image re-runs the matching, the control transfer and
    the rectification."""
    from aerotri.chain import chain_stages

    (tmp_path / "project.toml").write_text('[project]\ncrs = "EPSG:32649"\n')
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "a.tif").write_bytes(b"x")
    (tmp_path / "gnss.txt").write_text("")
    stages = chain_stages(tmp_path, dem=tmp_path / "dem.tif")
    inputs = {st.name: set(st.inputs(tmp_path)) for st in stages}
    for st in stages:
        if st.name in ("adjust_first", "adjust_final"):
            assert {tmp_path / "camera.toml", tmp_path / "gnss.txt"} <= inputs[st.name], st.name
            assert st.options_now(tmp_path)["project_toml"] == {"project": {"crs": "EPSG:32649"}}, st.name
    assert tmp_path / "control" / "points.csv" in inputs["adjust_final"]
    assert tmp_path / "control" / "points.csv" not in inputs["adjust_first"]  # written after it
    for name in ("match", "control", "rectify"):
        assert tmp_path / "images" / "a.tif" in inputs[name], name
    assert tmp_path / "dem.tif" in inputs["rectify"]


def test_stamps_name_inputs_relative_to_the_project(tmp_path, monkeypatch):
    """A project run from another working directory, or copied elsewhere, is still up to date."""
    import shutil

    p = tmp_path / "a" / "project"
    p.mkdir(parents=True)
    (p / "in.txt").write_text("3")
    monkeypatch.chdir(tmp_path)
    run_stages(p.relative_to(tmp_path), _stages([]), log=lambda m: None)
    stamp = json.loads(stamp_path(p, "double").read_text())
    assert list(stamp["inputs"]) == ["in.txt"]
    copy = tmp_path / "b"
    shutil.copytree(p, copy)
    monkeypatch.chdir(copy)
    calls = []
    run_stages(copy, _stages(calls), log=lambda m: None)
    run_stages(".", _stages(calls), log=lambda m: None)
    assert calls == []


def test_a_comment_in_a_toml_input_does_not_rerun_a_stage(tmp_path):
    (tmp_path / "in.txt").write_text("3")
    (tmp_path / "p.toml").write_text("[a]\nx = 1\n")
    calls = []
    stages = [Stage("s", lambda r: [r / "in.txt", r / "p.toml"], lambda r: [r / "mid.txt"],
                    lambda r: calls.append("s") or (r / "mid.txt").write_text("x") and StageResult())]
    run_stages(tmp_path, stages, log=lambda m: None)
    (tmp_path / "p.toml").write_text("# a comment\n[a]\nx = 1  # the same value\n")
    run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["s"]
    (tmp_path / "p.toml").write_text("[a]\nx = 2\n")
    run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["s", "s"]


def test_stage_cost_in_stamp_summary_and_table(tmp_path):
    """Each run stage records wall and CPU seconds and peak RSS in its stamp and summary row; the run writes
    work/run_summary.json with the rows and the load averages."""
    import numpy as np

    def heavy(r):
        a = np.ones(120 * 1024 * 1024 // 8)  # 120 MB held by the stage
        t = __import__("time").process_time()
        while __import__("time").process_time() - t < 0.3:
            pass
        (r / "heavy.txt").write_text(str(a.sum()))
        return Points(points=int(a.size))

    stages = [Stage("heavy", lambda r: [], lambda r: [r / "heavy.txt"], heavy)]
    rows = run_stages(tmp_path, stages, log=lambda m: None)
    stamp = json.loads(stamp_path(tmp_path, "heavy").read_text())
    usage = stamp["usage"]
    assert usage["cpu_s"] >= 0.3 and usage["wall_s"] >= 0.3
    assert usage["peak_rss_mb"] >= 120
    assert rows[0]["cpu_s"] == usage["cpu_s"] and rows[0]["peak_rss_mb"] == usage["peak_rss_mb"]
    assert rows[0]["points"] == 120 * 1024 * 1024 // 8
    summary = json.loads((tmp_path / "work" / "run_summary.json").read_text())
    assert [r["stage"] for r in summary["stages"]] == ["heavy"]
    assert summary["stages"][0]["cpu_s"] == usage["cpu_s"]
    assert len(summary["load_avg_start"]) == 3 and len(summary["load_avg_end"]) == 3
    table = format_summary(rows)
    assert "CPU s" in table and "peak MB" in table
    assert f"{usage['cpu_s']:.1f}" in table and "cpu_s=" not in table  # a column, not a key number
    # An up-to-date re-run costs nothing and says so in the summary file.
    rows = run_stages(tmp_path, stages, log=lambda m: None)
    assert rows[0]["status"] == "skipped (up to date)" and "cpu_s" not in rows[0]
    summary = json.loads((tmp_path / "work" / "run_summary.json").read_text())
    assert summary["stages"][0]["status"] == "skipped (up to date)"


def test_stage_cost_without_memory_figures(tmp_path, monkeypatch):
    """Where neither /proc nor getrusage give a peak (not Linux, no resource module) the stage records its
    times only and the table shows no peak."""
    from aerotri.core import resources

    monkeypatch.setattr(resources, "psutil", None)
    monkeypatch.setattr(resources, "resource", None)
    monkeypatch.setattr(resources, "_status_mb", lambda pid="self", field="VmHWM": None)
    monkeypatch.setattr(resources, "_hwm_mb", lambda pid="self": None)
    stages = [Stage("s", lambda r: [], lambda r: [r / "s.txt"], lambda r: (r / "s.txt").write_text("x") and StageResult())]
    rows = run_stages(tmp_path, stages, log=lambda m: None)
    stamp = json.loads(stamp_path(tmp_path, "s").read_text())
    assert set(stamp["usage"]) == {"wall_s", "cpu_s"}
    assert "cpu_s" in rows[0] and "peak_rss_mb" not in rows[0]
    line = format_summary(rows).splitlines()[1].split()
    assert line[0] == "s" and line[3] == f"{rows[0]['cpu_s']:.1f}" and line[4] == "-"


def _rectify_stage(root: Path, toml: str):
    """The chain of the project ``root`` with ``toml`` as its project.toml: (chain, the rectify stage's inputs, its
    options)."""
    from aerotri.chain.options import read_options
    from aerotri.chain.stages import Chain
    from aerotri.core.project import Project

    (root / "project.toml").write_text(toml)
    p = Project.open(root)
    chain = Chain(p, read_options(p))
    st = next(s for s in chain.stages() if s.name == "rectify")
    return chain, set(st.inputs(root)), st.options_now(root)


def test_the_rectify_stage_reads_the_dsm_of_the_true_ortho(tmp_path):
    """Issue 42: with LiDAR strips the rectify stage makes the true ortho on lidar_out/dsm.tif (an input: a new DSM
    re-runs it) unless [rectify] true_ortho = false; true_ortho = true without any DSM is refused before any stage."""
    from aerotri.core.errors import ConfigError

    toml = '[project]\ncrs = "EPSG:32649"\n'
    (tmp_path / "lidar").mkdir()
    (tmp_path / "lidar" / "strip_01.las").write_bytes(b"")

    def rectify(extra=""):
        return _rectify_stage(tmp_path, toml + extra)

    chain, inputs, options = rectify()
    assert tmp_path / "lidar_out" / "dsm.tif" in inputs and options["true_ortho"] is True
    assert chain.rectify_settings().sources["true_ortho"] == "aerotri run"
    # the occlusion test on the rasters stage's nearest-return DSM with the trees' fitted crowns (outputs of that
    # stage, inputs of this one)
    nearest, crowns = tmp_path / "lidar_out" / "dsm_crowns.tif", tmp_path / "lidar_out" / "crowns.gpkg"
    assert nearest in inputs and Path(options["occlusion_dsm"]) == nearest
    assert crowns in inputs and Path(options["crowns"]) == crowns
    assert {nearest, crowns} <= set(next(s for s in chain.stages() if s.name == "rasters").outputs(tmp_path))
    # back to the DSM itself; a DSM of the user's own: its occlusion test on it
    chain, inputs, options = rectify('[rectify]\nocclusion_dsm = "lidar_out/dsm.tif"\n')
    assert nearest not in inputs and Path(options["occlusion_dsm"]).resolve() == (tmp_path / "lidar_out" / "dsm.tif").resolve()
    assert crowns not in inputs and options["crowns"] is None
    (tmp_path / "own.tif").write_bytes(b"")
    chain, inputs, options = rectify('[rectify]\ndsm = "own.tif"\n')
    assert nearest not in inputs and options["occlusion_dsm"] is None
    chain, inputs, options = rectify("[rectify]\ntrue_ortho = false\n")
    assert tmp_path / "lidar_out" / "dsm.tif" not in inputs and options["true_ortho"] is False
    # no LiDAR: conventional; asked for without a DSM: refused naming project.toml and the key
    (tmp_path / "lidar" / "strip_01.las").unlink()
    chain, inputs, options = rectify("[rectify]\ndem = \"dem.tif\"\n")
    assert options["true_ortho"] is False and options["dsm"] is None
    chain, _, _ = rectify("[rectify]\ntrue_ortho = true\n")
    with pytest.raises(ConfigError, match=r"project.toml \[rectify\] true_ortho = true: no DSM"):
        chain.check_files()


def test_the_true_ortho_takes_the_lidar_roof_outlines_as_footprints_unless_a_cadastre_is_given(tmp_path):
    """Issue 42: without [rectify] footprints the true ortho's occlusion test takes the roof outlines the corners
    stage traced (lidar_out/roof_outlines.gpkg, an output of that stage and an input of rectify); not when the
    corners stage found no usable corner (it writes no outlines) or traced them in another CRS; a cadastre given
    wins."""
    from lidarctl.corners.roof_corners import CornerControlResult, CornerStats

    toml = '[project]\ncrs = "EPSG:32649"\n'
    (tmp_path / "lidar").mkdir()
    (tmp_path / "lidar" / "strip_01.las").write_bytes(b"")
    outlines = tmp_path / "lidar_out" / "roof_outlines.gpkg"

    def rectify(extra=""):
        return _rectify_stage(tmp_path, toml + extra)

    def corners_found(n_usable, crs="EPSG:32649", n_outlined_points=None):
        stats = CornerStats(1000, 500, 0.5, 3, 3, 12, 12, n_usable, 3, 4.0, "default", "flat", 0.05, 0.05, 0.5,
                            0.05 if n_usable else None, 1.0, n_outlined_points=n_outlined_points)
        (tmp_path / "lidar_out").mkdir(exist_ok=True)
        (tmp_path / "lidar_out" / "corners.json").write_text(
            CornerControlResult("s.laz", crs, None, stats, None, None if n_usable else "no usable").to_json())

    chain, inputs, options = rectify()  # before the corners stage has run: it will write them
    assert outlines in inputs and Path(options["footprints"]) == outlines
    assert chain.rectify_settings().record()["footprints"]["note"] == \
        "the LiDAR stages' roof outlines: no cadastre given"
    corners = next(s for s in chain.stages() if s.name == "corners")
    assert outlines in corners.outputs(tmp_path)
    corners_found(5)
    chain, inputs, options = rectify()
    assert outlines in inputs and Path(options["footprints"]) == outlines
    assert "(the LiDAR's roof outlines: [rectify] footprints for a cadastre)" in \
        chain.true_ortho_note(chain.rectify_settings())  # a corners.json from before the share was kept
    corners_found(5, n_outlined_points=335)  # of 500 building points
    chain, inputs, options = rectify()
    assert ("(the LiDAR's roof outlines, 67 % of the building points on an outlined roof: [rectify] footprints for a "
            "cadastre)") in chain.true_ortho_note(chain.rectify_settings())
    corners_found(0)  # no usable corner: the corners stage wrote no outlines
    chain, inputs, options = rectify()
    assert outlines not in inputs and options["footprints"] is None
    assert outlines not in next(s for s in chain.stages() if s.name == "corners").outputs(tmp_path)
    corners_found(5, crs="EPSG:32650")  # traced in another CRS than the project's
    chain, inputs, options = rectify()
    assert options["footprints"] is None
    corners_found(5)
    (tmp_path / "bgt.gpkg").write_bytes(b"")
    chain, inputs, options = rectify('[rectify]\nfootprints = "bgt.gpkg"\n')
    assert outlines not in inputs and Path(options["footprints"]).resolve() == (tmp_path / "bgt.gpkg").resolve()
    chain, inputs, options = rectify("[rectify]\ntrue_ortho = false\n")
    assert outlines not in inputs


def test_the_log_says_why_a_stage_runs(tmp_path):
    """A copied block whose stamps an older version wrote re-ran its stages (the 2 x 2 DMC block: all but three) and
    the log said only '[classify] running' (trial 8): it now names what changed, a new setting of a newer version
    among them."""
    (tmp_path / "in.txt").write_text("3")
    lines = []

    def stages(options):
        return [dataclasses.replace(st, options=(lambda r, o=options: o)) for st in _stages([])]

    run_stages(tmp_path, stages({"k": 1, "surface": {"a": 1}}), log=lines.append)
    assert "[double] running (not run before)" in lines
    lines.clear()
    run_stages(tmp_path, stages({"k": 1, "surface": {"a": 1}}), log=lines.append)
    assert "[double] up to date, skipped" in lines
    lines.clear()
    run_stages(tmp_path, stages({"k": 2, "surface": {"a": 1, "b": 0}, "new": True}), log=lines.append)
    assert "[double] running (options changed: k 1 -> 2, new (new), surface.b (new))" in lines
    lines.clear()
    (tmp_path / "in.txt").write_text("4")
    (tmp_path / "out.txt").unlink()
    run_stages(tmp_path, stages({"k": 2, "surface": {"a": 1, "b": 0}, "new": True}), log=lines.append)
    assert "[double] running (inputs changed: in.txt)" in lines
    assert "[add] running (output missing: out.txt)" in lines
    lines.clear()
    run_stages(tmp_path, stages({"k": 2, "surface": {"a": 1, "b": 0}, "new": True}), force=True, log=lines.append)
    assert "[add] running (--force)" in lines


def test_a_bumped_algorithm_version_reruns_its_stage_and_the_same_one_stays_up_to_date(tmp_path):
    """resume-keys: a stamp held inputs and options only, so a stage whose code changed its outputs (a bumped
    ``RULES_VERSION``) stayed up to date. The stamp holds the stage's algorithm versions: bumped, it runs again."""
    (tmp_path / "in.txt").write_text("3")

    def stages(calls, version):
        st = _stages(calls)
        st[0] = dataclasses.replace(st[0], versions=lambda: {"doubling": version})
        return st

    calls, logged = [], []
    run_stages(tmp_path, stages(calls, 1), log=lambda m: None)
    assert calls == ["double", "add"]
    assert json.loads(stamp_path(tmp_path, "double").read_text())["versions"] == {"doubling": 1}
    calls.clear()
    run_stages(tmp_path, stages(calls, 1), log=lambda m: None)
    assert calls == []
    run_stages(tmp_path, stages(calls, 2), log=logged.append)
    assert calls == ["double"]  # its output is the same: the next stage stays up to date
    assert "[double] running (code changed: doubling 1 -> 2)" in logged
    # after an upgrade the code versions read as the options do (one wording): a new algorithm "(new)", a retired
    # one "(dropped)", a changed one "old -> new"
    logged.clear()
    st = stages(calls, 2)
    st[0] = dataclasses.replace(st[0], versions=lambda: {"doubling": 3, "rounding": 1})
    run_stages(tmp_path, st, log=logged.append)
    assert "[double] running (code changed: doubling 2 -> 3, rounding (new))" in logged
    run_stages(tmp_path, stages(calls, 2), log=logged.append)
    assert "[double] running (code changed: doubling 3 -> 2, rounding (dropped))" in logged
    # a stamp written before versions were recorded (reviewer 10: an old project kept the outputs of replaced rules
    # for ever) runs again when the stage declares versions; one that declares none stays up to date
    for name in ("double", "add"):
        sp = stamp_path(tmp_path, name)
        doc = json.loads(sp.read_text())
        del doc["versions"]
        sp.write_text(json.dumps(doc))
    calls.clear()
    logged.clear()
    run_stages(tmp_path, stages(calls, 2), log=logged.append)
    assert calls == ["double"]
    assert "[double] running (code versions not recorded: run again)" in logged
    assert json.loads(stamp_path(tmp_path, "double").read_text())["versions"] == {"doubling": 2}
    calls.clear()
    run_stages(tmp_path, stages(calls, 2), log=lambda m: None)
    assert calls == []


def test_the_chain_stamps_hold_the_algorithm_versions_next_to_the_code(tmp_path):
    """Each stage with an algorithm version constant declares it (what its stamp then holds)."""
    import lidarctl.classify
    import lidarctl.rasters.crown_model
    import lidarctl.rasters.products
    import ortho.block
    import ortho.mosaic
    import ortho.rectify
    from aerotri.chain import stages as S
    from aerotri.adjust import pipeline, relative
    from aerotri.control import measure
    from aerotri.match import settings
    from lidarctl.corners import roof_corners

    from lidarctl.classify.pipeline import ClassifySettings

    # the rules' version at the stage's settings: with the whole cloud's level bodies off the version before
    # level-bodies-sparse (9), whose changes decide classes only with it on (review 19); on by default since
    # level-wire (12); 13 (high clusters), 14 (h1-tiling), 15 (rooftop-noise), 16 (roof patches) and 17 (cut pieces)
    # decide classes with it off too; 18 (foliage beyond a roof's reach) only with its own setting on (on by default)
    assert S._classify_versions(ClassifySettings(water_whole_level_bodies=False)) == {"classify rules": 18}
    assert S._classify_versions(ClassifySettings(foliage_beyond_roof_reach=False)) == {"classify rules": 17}
    assert S._classify_versions(ClassifySettings()) == {"classify rules": lidarctl.classify.RULES_VERSION} == {
        "classify rules": 18}
    assert S._rasters_versions() == {"rasters": lidarctl.rasters.products.RASTERS_VERSION,
                                     "crown model": lidarctl.rasters.crown_model.CROWNS_VERSION}
    assert S._corners_versions() == {"roof corners": roof_corners.CORNERS_VERSION}
    assert S._adjust_versions() == {"adjustment": pipeline.ADJUST_VERSION,
                                    "relative orientation": relative.RELATIVE_VERSION}
    assert S._match_versions() == {"features": settings.FEATURES_VERSION, "matching": settings.MATCH_VERSION}
    assert S._control_versions() == {"measurement": measure.MEASURE_VERSION}
    from ortho.settings import RectifySettings

    # contract-crs-speed changed a contract grid's frame orthos only (2), slope-occlusion every true ortho's (3)
    assert S._rectify_versions(RectifySettings()) == {
        "rectify": ortho.rectify.PROJECT_CRS_RECTIFY_VERSION, "heights by outline": ortho.block.HEIGHTS_BY_OUTLINE,
        "outlines of the occlusion test": ortho.block.OUTLINES_OF_THE_OCCLUSION_TEST}
    # trial-ortho's frame nodata (review 28), jpeg-decode and slope-occlusion changed frame orthos in every CRS
    assert ortho.rectify.PROJECT_CRS_RECTIFY_VERSION == 3
    assert S._rectify_versions(RectifySettings(crs="EPSG:4546"))["rectify"] == ortho.rectify.RECTIFY_VERSION == 3
    assert S._mosaic_versions() == {"blend rules": ortho.mosaic.BLEND_RULES,
                                    "gains, offsets and seamlines": ortho.mosaic.RADIOMETRY_SEAMS_VERSION}
    (tmp_path / "project.toml").write_text('[project]\ncrs = "EPSG:32649"\n')
    versions = {st.name: st.versions_now() for st in S.chain_stages(tmp_path, dem=tmp_path / "dem.tif")}
    assert versions["classify"] == {"classify rules": 18} and versions["rasters"] == S._rasters_versions()
    assert versions["match"] == S._match_versions() and versions["control"] == S._control_versions()
    assert versions["rectify"] == S._rectify_versions(RectifySettings()) and versions["mosaic"] == S._mosaic_versions()
    assert versions["corners"] == S._corners_versions()
    assert versions["adjust_first"] == versions["adjust_final"] == S._adjust_versions()
    assert versions["strips"] == S._strips_versions() and versions["dom_check"] == S._dom_check_versions()
    assert versions["dem"] == S._dem_versions() and versions["report"] == S._report_versions()
    (tmp_path / "project.toml").write_text(
        '[project]\ncrs = "EPSG:32649"\n[classify]\nwater_whole_level_bodies = false\n')
    versions = {st.name: st.versions_now() for st in S.chain_stages(tmp_path, dem=tmp_path / "dem.tif")}
    assert versions["classify"] == {"classify rules": 18}
    (tmp_path / "project.toml").write_text(
        '[project]\ncrs = "EPSG:32649"\n[classify]\nfoliage_beyond_roof_reach = false\n')
    versions = {st.name: st.versions_now() for st in S.chain_stages(tmp_path, dem=tmp_path / "dem.tif")}
    assert versions["classify"] == {"classify rules": 17}


def test_a_contract_crs_on_another_datum_is_refused_before_any_stage(tmp_path):
    """trial-ortho: `[rectify] crs = "gk3:cgcs2000"` in a WGS 84 UTM project stopped `aerotri run` at the orthophotos
    (4.5 min into the demo's chain) naming --params / --allow-ballpark, which it does not take; now before any stage,
    saying how to make the contract's DOM. The same datum (another UTM zone) passes."""
    from aerotri.chain.options import read_options
    from aerotri.chain.stages import Chain
    from aerotri.core.errors import ConfigError
    from aerotri.core.project import Project

    toml = '[project]\ncrs = "EPSG:32649"\n'
    (tmp_path / "gnss.txt").write_text("s01_001 452500.0 3408800.0 1200.0\ns01_002 452700.0 3408800.0 1200.0\n")
    for crs, refused in (("gk3:cgcs2000", True), ("EPSG:4546", True), ("EPSG:32650", False)):
        (tmp_path / "project.toml").write_text(toml + f'[rectify]\ncrs = "{crs}"\n')
        p = Project.open(tmp_path)
        chain = Chain(p, read_options(p))
        if refused:
            with pytest.raises(ConfigError, match=rf"project.toml \[rectify\] crs = '{crs}': .*ballpark.*`aerotri run` "
                                                  r"takes no datum parameters: .*ortho rectify .* --crs"):
                chain._check_output_crs()
        else:
            chain._check_output_crs()


def test_the_stage_keys_hold_every_file_a_stage_reads(tmp_path):
    """The mosaic's and the DOM check's nDSM (lidar_out/ndsm.tif, or [mosaic] / [dom_check] ndsm), the adjustment's
    check DEM ([adjust] check_dem) and a user's tolerance table ([qa] tolerances, judging adjust_final and the
    report) are inputs: a changed one makes the stage stale (before s11-fixes none was in the key); the stages
    without versions so far declare them."""
    from aerotri.chain import stages as S
    from aerotri.chain.runner import _plain, _signature, stale_reason, stamp_path

    (tmp_path / "tol.toml").write_text("# a user's table\n")
    (tmp_path / "check_dem.tif").write_bytes(b"dem")
    (tmp_path / "project.toml").write_text('[project]\ncrs = "EPSG:32649"\n[qa]\ntolerances = "tol.toml"\n'
                                           '[adjust]\ncheck_dem = "check_dem.tif"\n')
    (tmp_path / "lidar_out").mkdir()
    (tmp_path / "lidar_out" / "ndsm.tif").write_bytes(b"ndsm")
    stages = {st.name: st for st in S.chain_stages(tmp_path, dem=tmp_path / "dem.tif", reference_ortho=tmp_path / "r.tif")}
    ndsm, tol, cdem = tmp_path / "lidar_out" / "ndsm.tif", (tmp_path / "tol.toml").resolve(), tmp_path / "check_dem.tif"
    assert ndsm in stages["mosaic"].inputs(tmp_path) and ndsm in stages["dom_check"].inputs(tmp_path)
    assert tol in stages["adjust_final"].inputs(tmp_path) and tol in stages["report"].inputs(tmp_path)
    assert cdem in [p.resolve() for p in stages["adjust_final"].inputs(tmp_path)]
    for name in ("strips", "dom_check", "report"):
        assert stages[name].versions_now(), name
    for name, changed in (("mosaic", ndsm), ("report", tol), ("adjust_final", cdem)):
        st = stages[name]
        for o in st.outputs(tmp_path):
            o.parent.mkdir(parents=True, exist_ok=True)
            o.exists() or o.write_text("")
        stamp_path(tmp_path, name).parent.mkdir(parents=True, exist_ok=True)
        stamp_path(tmp_path, name).write_text(json.dumps(dict(
            inputs=_signature(st.inputs(tmp_path), tmp_path), options=_plain(st.options_now(tmp_path), tmp_path),
            versions=st.versions_now())))
        assert stale_reason(tmp_path, st) is None, name
        changed.write_bytes(changed.read_bytes() + b" changed")
        assert "inputs changed" in (stale_reason(tmp_path, st) or ""), name


def test_a_bad_contract_crs_names_project_toml_and_a_missing_grid_is_the_fix(tmp_path, monkeypatch):
    """review 12c: [rectify] crs in feet or degrees was refused naming --crs, which `aerotri run` does not have; a
    compound CRS refused for a geoid grid not installed advised --params instead of the grid."""
    import aerotri.geom.crs.transform as T
    from aerotri.chain.options import read_options
    from aerotri.chain.stages import Chain
    from aerotri.core.errors import InputError
    from aerotri.core.project import Project

    def chain(crs):
        (tmp_path / "project.toml").write_text(f'[project]\ncrs = "EPSG:32649"\n[rectify]\ncrs = "{crs}"\n')
        p = Project.open(tmp_path)
        return Chain(p, read_options(p))

    for crs, why in (("EPSG:4326", "is not a projected CRS"), ("EPSG:2240", "has axes in US survey foot")):
        with pytest.raises(InputError, match=rf"project.toml \[rectify\] crs = EPSG:{crs[5:]} .*{why}") as e:
            chain(crs)._check_output_crs()
        assert "--crs" not in str(e.value)

    def refused(src, dst, *a, **k):  # as PROJ refuses WGS 84 -> + EGM96 height without us_nga_egm96_15.tif
        raise T.BallparkRefused("... --params ...", missing_grids=[("us_nga_egm96_15.tif", "https://cdn.proj.org")])

    monkeypatch.setattr(T, "CrsTransformer", refused)
    with pytest.raises(InputError, match=r"\[rectify\] crs = 'EPSG:32649\+5773': .*needs the PROJ grid "
                                         r"us_nga_egm96_15.tif.*pyproj sync --file us_nga_egm96_15.tif") as e:
        chain("EPSG:32649+5773")._check_output_crs()
    assert "--params" not in str(e.value) and "ballpark" not in str(e.value)


def test_an_output_written_again_since_its_stage_re_runs_the_stage(tmp_path, caplog):
    """trial-rerun: at/eo.txt edited by hand (or written again by `aerotri adjust P --image-sigma-px 1` run by hand)
    kept the adjustment "up to date" with its old numbers in the summary, while the orthophotos were made again from
    the edited file; a fresh project has the stage's own output. The stamp holds its outputs' signatures."""
    (tmp_path / "in.txt").write_text("3")
    run_stages(tmp_path, _stages([]), log=lambda m: None)
    (tmp_path / "mid.txt").write_text("100")  # an output edited by hand
    calls, lines = [], []
    rows = run_stages(tmp_path, _stages(calls), log=lines.append)
    assert calls == ["double"] and rows[-1]["value"] == 7 and (tmp_path / "out.txt").read_text() == "7"
    assert "[double] running (outputs changed since this stage wrote them: mid.txt)" in lines
    # a stamp written before the outputs were recorded is not re-run for outputs older than itself, but records them
    # now (leftovers2: such a stamp stayed without outputs run after run, so a later edit of out.txt was never seen)
    def old_stamp(output_after_stamp_s):
        stamp = json.loads(stamp_path(tmp_path, "add").read_text())
        del stamp["outputs"]
        stamp_path(tmp_path, "add").write_text(json.dumps(stamp))
        t_ns = stamp_path(tmp_path, "add").stat().st_mtime_ns + int(output_after_stamp_s * 1e9)
        os.utime(tmp_path / "out.txt", ns=(t_ns, t_ns))

    (tmp_path / "out.txt").write_text("8")
    old_stamp(-1.0)
    calls.clear()
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == [] and list(json.loads(stamp_path(tmp_path, "add").read_text())["outputs"]) == ["out.txt"]
    (tmp_path / "out.txt").write_text("9")
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["add"] and (tmp_path / "out.txt").read_text() == "7"
    # review 44: an output edited after such a stamp, before the first run with this code (at/eo.txt X +5 m), was
    # recorded as it was found and blessed without a word; review 47: re-running it made a copy without times (cp -r)
    # re-run 7 of 11 demo stages for no edit: such an output is named (edit, or copy without times) and taken as the
    # stage's, as it was found
    (tmp_path / "out.txt").write_text("12")
    old_stamp(+1.0)
    calls.clear()
    with caplog.at_level(logging.WARNING, logger="aerotri.chain.runner"):
        run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == [] and (tmp_path / "out.txt").read_text() == "12"
    assert "[add] out.txt newer than this stage's record" in caplog.text and "cp -r" in caplog.text


def _crowns_writer_and_reader(calls: list):
    """Two stage functions: one writes crowns.gpkg (a SQLite file of two rows, made anew), one reads it (writes n.txt);
    each appends its name to ``calls``."""
    import contextlib
    import sqlite3

    def write(r):
        calls.append("write")
        (r / "crowns.gpkg").unlink(missing_ok=True)
        with contextlib.closing(sqlite3.connect(r / "crowns.gpkg")) as db:
            db.execute("CREATE TABLE crowns (id INTEGER PRIMARY KEY, radius_m REAL)")
            db.executemany("INSERT INTO crowns (radius_m) VALUES (?)", [(2.5,), (3.0,)])
            db.commit()
        return StageResult()

    def read(r):
        calls.append("read")
        (r / "n.txt").write_text("2")
        return StageResult()

    return write, read


def test_a_geopackage_opened_by_a_reader_is_no_change(tmp_path):
    """leftovers2: QGIS opening lidar_out/crowns.gpkg switches it to WAL mode (-wal and -shm beside it, header bytes
    18-19) and back on closing (change counter, SQLite version): its bytes changed, so the next run re-ran the LiDAR
    rasters that wrote it and every stage that read it. A SQLite file's signature leaves those header fields out; an
    edited row re-runs the stage, and a stamp with the file's plain hash (written before) stays up to date."""
    import contextlib
    import sqlite3

    from aerotri.chain import runner

    calls = []
    write, read = _crowns_writer_and_reader(calls)

    stages = [Stage("rasters", lambda r: [], lambda r: [r / "crowns.gpkg"], write),
              Stage("rectify", lambda r: [r / "crowns.gpkg"], lambda r: [r / "n.txt"], read)]
    run_stages(tmp_path, stages, log=lambda m: None)
    gpkg = tmp_path / "crowns.gpkg"
    before = gpkg.read_bytes()
    with contextlib.closing(sqlite3.connect(gpkg)) as db:  # as QGIS opens and closes it
        assert db.execute("PRAGMA journal_mode=WAL").fetchone() == ("wal",)
        db.execute("SELECT * FROM crowns").fetchall()
        assert (tmp_path / "crowns.gpkg-wal").exists()
        assert gpkg.read_bytes() != before
        rows = run_stages(tmp_path, stages, log=lambda m: None)  # while it is open
        db.execute("PRAGMA journal_mode=DELETE")
    assert gpkg.read_bytes() != before and not (tmp_path / "crowns.gpkg-wal").exists()
    rows += run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["write", "read"] and all(r["status"] == "skipped (up to date)" for r in rows)
    # a stamp of before holds the plain hash: up to date while the file is the same, and brought to the new record
    def record(name):
        return json.loads(stamp_path(tmp_path, name).read_text())["outputs" if name == "rasters" else "inputs"]

    for name in ("rasters", "rectify"):
        stamp = json.loads(stamp_path(tmp_path, name).read_text())
        key = "outputs" if name == "rasters" else "inputs"
        assert stamp[key]["crowns.gpkg"].startswith("sqlite:")
        stamp[key]["crowns.gpkg"] = runner.hashlib.sha1(gpkg.read_bytes()).hexdigest()
        stamp_path(tmp_path, name).write_text(json.dumps(stamp))
    run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["write", "read"] and all(record(n)["crowns.gpkg"].startswith("sqlite:") for n in ("rasters",
                                                                                                       "rectify"))
    with contextlib.closing(sqlite3.connect(gpkg)) as db:
        db.execute("PRAGMA journal_mode=WAL")
    run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["write", "read"]
    with contextlib.closing(sqlite3.connect(gpkg)) as db:  # an edit
        db.execute("UPDATE crowns SET radius_m = 4.0 WHERE id = 1")
        db.commit()
    lines = []
    run_stages(tmp_path, stages, log=lines.append)
    # the stage makes its own again, the crowns the reader read: it stays up to date
    assert calls == ["write", "read", "write"]
    assert "[rasters] running (outputs changed since this stage wrote them: crowns.gpkg)" in lines


def test_an_operators_hand_made_output_is_kept_and_a_new_time_alone_is_no_edit(tmp_path, caplog, monkeypatch):
    """Review 41: an edited-seamline mosaic (`ortho mosaic P --seamlines EDITED.gpkg`) was replaced by the next
    `aerotri run` with the chain's own; a stage that says why outputs changed by hand are the operator's keeps them
    (warned) and the later stages follow them. And a large output (size and time in the stamp) touched, restored from a
    backup or rsynced without -t re-ran its stage (a classify, a 4 GB DOM): its size decides."""
    import dataclasses
    import logging
    import os

    from aerotri.chain import runner

    (tmp_path / "in.txt").write_text("3")
    run_stages(tmp_path, _stages([]), log=lambda m: None)
    (tmp_path / "mid.txt").write_text("100")  # the operator's own
    stages = _stages(calls := [])
    stages[0] = dataclasses.replace(stages[0], hand_made=lambda r: "edited by the operator")
    with caplog.at_level(logging.WARNING):
        rows = run_stages(tmp_path, stages, log=lambda m: None)
    assert calls == ["add"] and rows[-1]["value"] == 101
    assert "[double] kept: mid.txt changed since this stage wrote it (edited by the operator)" in caplog.text
    # a stage that runs for another reason as well does not say "kept" (trial s106 F3: "kept", then the mosaic made
    # again with the edited seamlines): it says itself how it treats the operator's output
    caplog.clear()
    (tmp_path / "in.txt").write_text("4")
    with caplog.at_level(logging.WARNING):
        run_stages(tmp_path, stages, log=lambda m: None)
    assert "double" in calls and "kept:" not in caplog.text
    # outputs over the hash limit: a new time alone keeps the stage, a new size re-runs it
    monkeypatch.setattr(runner, "_signature", lambda paths, root, hash_limit_bytes=0, before=None: {
        runner._key(p, root): [p.stat().st_size, p.stat().st_mtime_ns] for p in paths if p.is_file()})
    run_stages(tmp_path, _stages([]), force=True, log=lambda m: None)
    st = (tmp_path / "out.txt").stat()
    os.utime(tmp_path / "out.txt", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    calls.clear()
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == []
    (tmp_path / "out.txt").write_text("12345")
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["add"]


def test_a_crs_file_in_project_toml_is_read_in_the_project_folder_and_its_content_is_stamped(tmp_path, monkeypatch):
    """Review 44: `crs = "grid.prj"` ([project] or [rectify]) was read from the current directory (exit 2 from outside
    the project, another grid.prj there taken in silence) and the stamps recorded only the name. Now the name is
    relative to the project folder and the stamps hold the CRS itself: an edited grid.prj re-runs the stages."""
    import pyproj

    from aerotri.chain import chain_stages
    from aerotri.core.errors import CrsError
    from aerotri.core.project import Project
    from aerotri.geom.crs.definition import project_crs

    root, elsewhere = tmp_path / "p", tmp_path / "cwd"
    root.mkdir(), elsewhere.mkdir()
    (root / "project.toml").write_text('[project]\ncrs = "grid.prj"\n[rectify]\ncrs = "out.prj"\n')
    (root / "grid.prj").write_text(pyproj.CRS("EPSG:32649").to_wkt("WKT1_ESRI"))
    (root / "out.prj").write_text(pyproj.CRS("EPSG:32650").to_wkt())
    (elsewhere / "grid.prj").write_text(pyproj.CRS("EPSG:32650").to_wkt("WKT1_ESRI"))  # the wrong one
    monkeypatch.chdir(elsewhere)
    assert project_crs(Project.open(root)).to_epsg() == 32649

    def options():
        stages = {st.name: st for st in chain_stages(root, dem=root / "dem.tif")}
        return {n: stages[n].options_now(root) for n in ("strips", "classify", "adjust_final", "rectify")}

    before = options()
    assert pyproj.CRS(before["rectify"]["crs"]).to_epsg() == 32650
    assert pyproj.CRS(before["strips"]["crs"]).to_epsg() == 32649
    (root / "grid.prj").write_text(pyproj.CRS("EPSG:32648").to_wkt("WKT1_ESRI"))
    (root / "out.prj").write_text(pyproj.CRS("EPSG:32651").to_wkt())
    after = options()
    for name in before:
        assert before[name] != after[name], name  # (the stage re-runs)
    monkeypatch.chdir(root)
    (root / "out.prj").unlink()
    with pytest.raises(CrsError, match=r"project.toml \[rectify\] crs: cannot read the CRS file .*out.prj"):
        options()


def test_an_edit_still_in_the_geopackages_wal_file_re_runs_the_stages(tmp_path):
    """Review 44: an edit QGIS has not written back (still in crowns.gpkg-wal: QGIS open, or a crash left it) is what
    every reader of the file sees, but the signature hashed the file alone: the stage that wrote it and the one that
    reads it said up to date. A non-empty -wal joins the signature; a reader alone leaves it empty."""
    import contextlib
    import sqlite3

    calls = []
    write, read = _crowns_writer_and_reader(calls)

    rasters = Stage("rasters", lambda r: [], lambda r: [r / "crowns.gpkg"], write)
    rectify = Stage("rectify", lambda r: [r / "crowns.gpkg"], lambda r: [r / "n.txt"], read)
    run_stages(tmp_path, [rasters, rectify], log=lambda m: None)
    with contextlib.closing(sqlite3.connect(tmp_path / "crowns.gpkg")) as db:  # QGIS, open
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA wal_autocheckpoint=0")
        db.execute("SELECT * FROM crowns").fetchall()
        assert stale_reason(tmp_path, rasters) is None and stale_reason(tmp_path, rectify) is None  # a reader
        db.execute("DELETE FROM crowns WHERE id = 1")  # a false crown deleted and saved
        db.commit()
        assert (tmp_path / "crowns.gpkg-wal").stat().st_size > 0
        assert "outputs changed since this stage wrote them: crowns.gpkg" in stale_reason(tmp_path, rasters)
        assert "inputs changed: crowns.gpkg" in stale_reason(tmp_path, rectify)
    assert calls == ["write", "read"]


def test_a_run_that_stops_leaves_no_earlier_run_summary(tmp_path):
    """trial-overnight: a run that failed at a stage left work/run_summary.json of the run before it, every stage
    "done" (bench/scale.py reads it as this run's record). A failed or interrupted run now writes its rows so far and
    the stage that stopped; a run killed outright leaves none (scale.py then reads the finished stages' stamps)."""
    (tmp_path / "in.txt").write_text("3")
    run_stages(tmp_path, _stages([]), log=lambda m: None)
    summary_path = tmp_path / "work" / "run_summary.json"
    assert [r["status"] for r in json.loads(summary_path.read_text())["stages"]] == ["done", "done"]
    (tmp_path / "in.txt").write_text("-3")  # add fails on a negative value
    with pytest.raises(RuntimeError, match="negative"):
        run_stages(tmp_path, _stages([]), log=lambda m: None)
    summary = json.loads(summary_path.read_text())
    assert summary["stopped"] == "failed"
    assert [(r["stage"], r["status"]) for r in summary["stages"]] == [("double", "done"), ("add", "failed")]
    assert summary["stages"][1]["why"] == "negative"

    def interrupted(r):
        assert not summary_path.exists()  # the earlier run's summary is gone while this one runs
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_stages(tmp_path, [Stage("i", lambda r: [], lambda r: [r / "i.txt"], interrupted)], log=lambda m: None)
    summary = json.loads(summary_path.read_text())
    assert summary["stopped"] == "interrupted" and summary["stages"] == [
        dict(stage="i", status="interrupted", seconds=0.0, why="KeyboardInterrupt")]

    def after_a_while(r):  # (trial s96 L2: a stage stopped after 11 s read 0.0 s)
        time.sleep(0.3)
        raise KeyboardInterrupt("SIGTERM")

    with pytest.raises(KeyboardInterrupt):
        run_stages(tmp_path, [Stage("w", lambda r: [], lambda r: [r / "w.txt"], after_a_while)], log=lambda m: None)
    (row,) = json.loads(summary_path.read_text())["stages"]
    assert row["status"] == "interrupted" and row["why"] == "SIGTERM" and 0.3 <= row["seconds"] < 5.0


def test_under_a_memory_limit_each_stage_gives_its_freed_memory_back(tmp_path, monkeypatch):
    """In a container or batch job with a memory limit the chain hands what a stage freed back to the system after
    the stage (glibc kept it for the next stage: the demo at 1 GiB was killed in its 12th stage); without a limit
    the allocator keeps it, as before."""
    from aerotri.chain import runner

    calls = []
    monkeypatch.setattr(runner, "release_freed_memory", lambda: calls.append(1))
    stages = [Stage(n, lambda r: [], lambda r, n=n: [r / f"{n}.txt"],
                    lambda r, n=n: (r / f"{n}.txt").write_text("x") and StageResult()) for n in ("a", "b")]
    monkeypatch.setattr(runner, "memory_limited", lambda: False)
    (tmp_path / "free").mkdir()
    (tmp_path / "limited").mkdir()
    run_stages(tmp_path / "free", stages, log=lambda m: None)
    assert calls == []
    monkeypatch.setattr(runner, "memory_limited", lambda: True)
    run_stages(tmp_path / "limited", stages, log=lambda m: None)
    assert calls == [1, 1]


def test_memory_limited_only_below_the_machine_s_memory(monkeypatch):
    from aerotri.core import limits

    machine = limits.physical_memory_bytes()
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: None)
    assert not limits.memory_limited()
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: 2**30)
    assert limits.memory_limited() == (machine > 2**30)
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: 2**62)   # a cgroup's "no limit" figure
    assert not limits.memory_limited()


def test_a_stage_an_interrupted_run_began_says_it_takes_its_work_over(tmp_path):
    """Trial s96 L1: after an interrupted rasters stage the log read "[rasters] running (not run before)", then
    "resumed 4 of 4 tiles": with the stage's resume folder in work/ it says that it takes the finished parts over."""
    from aerotri.chain.runner import stale_reason

    (tmp_path / "in.txt").write_text("3")
    st = _stages([])[0]
    assert stale_reason(tmp_path, st) == "not run before"
    (tmp_path / "work" / f"{st.name}_resume").mkdir(parents=True)
    assert stale_reason(tmp_path, st) == "not finished before: an interrupted run's finished parts are taken over"


def test_an_up_to_date_stage_removes_what_an_interrupted_run_of_it_left(tmp_path):
    """Trial s96 L5: a --force run killed in control left work/control_resume, which stayed through two more runs
    that found control up to date."""
    (tmp_path / "in.txt").write_text("3")
    calls = []
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    left = tmp_path / "work" / "double_resume"
    left.mkdir(parents=True)
    (left / "part.npz").write_bytes(b"x")
    rows = run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["double", "add"] and rows[0]["status"] == "skipped (up to date)"
    assert not left.exists()


def test_a_force_run_stopped_midway_is_finished_by_the_next_run(tmp_path):
    """Trial s96 L11: a --force run killed in control, then a plain run: control and every stage after it were "up
    to date" (their inputs unchanged), so the forced re-run was silently never finished."""
    (tmp_path / "in.txt").write_text("3")
    calls = []
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["double", "add"]

    def stop(r):
        raise KeyboardInterrupt

    stopping = _stages(calls)
    stopping[1] = Stage("add", stopping[1].inputs, stopping[1].outputs, stop)
    with pytest.raises(KeyboardInterrupt):
        run_stages(tmp_path, stopping, force=True, log=lambda m: None)
    assert calls == ["double", "add", "double"]
    lines = []
    rows = run_stages(tmp_path, _stages(calls), log=lines.append)
    assert calls == ["double", "add", "double", "add"]  # add re-run, double not again
    assert rows[0]["status"] == "skipped (up to date)" and rows[1]["status"] == "done"
    assert any("[add] running (the --force run of" in x and "stopped before re-running it" in x for x in lines), lines
    assert not (tmp_path / "work" / "force_pending.json").exists()
    run_stages(tmp_path, _stages(calls), log=lambda m: None)
    assert calls == ["double", "add", "double", "add"]  # and then up to date
