"""The production chain on the simulated tiny project: the README's chain command by command through the
commands' own parsers (with and without self-calibration), ``aerotri run`` to the end (the same result as
by hand), and ``aerotri run`` without LiDAR on a DEM from elsewhere."""

from __future__ import annotations

import glob
import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import rasterio
import rasterio.transform
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.geom.eo import read_eo
from lidarctl.strips.check import read_strip_check
from tests.ortho.test_true_ortho import roofs_not_measured_said

REPO = Path(__file__).resolve().parents[3]


def readme_chain() -> list[list[str]]:
    """The commands of the README's chain block, as argument lists (comments dropped)."""
    text = (REPO / "README.md").read_text()
    block = text.split("### The chain")[1].split("```")[1]
    return [line.split("#")[0].split() for line in block.strip().splitlines() if line.split("#")[0].strip()]


def _substitute(args: list[str], p: Path) -> list[str]:
    out = []
    for a in args:
        if a == "P" or a.startswith("P/"):
            a = str(p) + a[1:]
        a = {"REF.tif": str(p / "truth" / "ortho.tif"), "POINTS.csv": str(p / "truth" / "checkpoints.csv")}.get(a, a)
        out += sorted(glob.glob(a)) if "*" in a else [a]
    return out


def _invoke(cmd: list[str]) -> SimpleNamespace:
    """``cmd`` through its console script's click command in this process, as (returncode, stdout, stderr). The
    scripts themselves are the wheel's (tests/test_packaging.py); with a process of its own per command (1-2 s of
    imports each) the fixture took 35 s, 18-21 s in this process."""
    from lidarctl.cli.main import main as lidarctl_cli
    from ortho.cli import main as ortho_cli

    command = {"aerotri": aerotri_cli, "lidarctl": lidarctl_cli, "ortho": ortho_cli}[cmd[0]]
    r = CliRunner().invoke(command, cmd[1:], catch_exceptions=False)
    return SimpleNamespace(returncode=r.exit_code, stdout=r.stdout, stderr=r.stderr)


def run_readme_chain(p: Path, self_cal: bool, start: str | None = None, stop: str | None = None) -> dict:
    """Run the README chain in ``p`` as a user would, following its rule for a block without usable
    roof corners; from the first command ``start`` on (the earlier ones' outputs are in ``p``), up to
    the command before ``stop``. Returns {command: CompletedProcess}."""
    done, no_control = {}, False
    commands = readme_chain()
    if stop is not None:
        commands = commands[:[" ".join(a[:2]) for a in commands].index(stop)]
    if start is not None:
        commands = commands[[" ".join(a[:2]) for a in commands].index(start):]
        no_control = not (p / "lidar_out" / "corners.csv").is_file()  # what lidarctl corners said before
    for args in commands:
        if not self_cal and args[:2] == ["aerotri", "adjust"]:
            args = args + ["--self-cal", ""]  # project.toml [adjust] self-calibrates; the command line turns it off
        if no_control and args[:2] == ["aerotri", "control"]:
            continue
        if no_control and "--gnss-correction" in args:
            i = args.index("--gnss-correction")
            args = args[:i] + args[i + 2:]
        for opt, name in (("--planes", "roof_planes.geojson"), ("--footprints", "roof_outlines.gpkg")):
            if opt in args and not (p / "lidar_out" / name).is_file():
                i = args.index(opt)  # lidarctl corners wrote nothing (no usable corner)
                args = args[:i] + args[i + 2:]
        cmd = [args[0]] + _substitute(args[1:], p)
        res = _invoke(cmd)
        done[" ".join(args[:2])] = res
        if args[:2] == ["lidarctl", "corners"] and res.returncode == 2:
            # the README: no usable roof corner -> no control transfer, no GNSS corrections
            assert "no usable roof corner" in res.stderr, res.stderr
            no_control = True
            continue
        assert res.returncode == 0, f"{' '.join(cmd)}\n{res.stderr}"
    return done


@pytest.fixture(scope="module")
def by_hand(tiny_project, tmp_path_factory):
    """The README chain with self-calibration, then its adjustments without (rectifying after an
    adjustment without self-calibration: tests/aerotri/chain/test_options.py)."""
    base = tmp_path_factory.mktemp("readme")
    with_cal, without = base / "with_self_cal", base / "without_self_cal"
    shutil.copytree(tiny_project, with_cal)
    runs = run_readme_chain(with_cal, self_cal=True)
    # the stages before the adjustments do not depend on it: their outputs are taken over
    shutil.copytree(tiny_project, without)
    for rel in ("lidar_out", "work", "at"):
        shutil.copytree(with_cal / rel, without / rel)
    shutil.rmtree(without / "work" / "stages", ignore_errors=True)
    for f in (without / "at").iterdir():
        if not f.name.startswith(("tiepoints", "connectivity")):
            shutil.rmtree(f) if f.is_dir() else f.unlink()
    runs_without = run_readme_chain(without, self_cal=False, start="aerotri adjust", stop="ortho rectify")
    return with_cal, runs, without, runs_without


def test_readme_chain_runs_stage_by_stage(by_hand):
    with_cal, runs, without, runs_without = by_hand
    # the strips checked first, then classified together (no merged file)
    assert [a[:2] for a in readme_chain()][:2] == [["lidarctl", "strips"], ["lidarctl", "classify"]]
    assert read_strip_check(with_cal / "lidar_out" / "strips" / "strips.json").all_pairs.n_cells > 0
    # tiny's LiDAR (1.2 m spacing) gives no usable roof corner: the README's rule applies
    assert runs["lidarctl corners"].returncode == 2 and "aerotri control" not in runs
    assert json.loads((with_cal / "lidar_out" / "height_check.json").read_text())["overall"]["all"]["n"] > 0
    reps = [json.loads((p / "at" / "report.json").read_text()) for p in (with_cal, without)]
    assert reps[0]["self_calibration"]["groups"] == ["pp", "radial"] and reps[1]["self_calibration"] is None
    # the true camera has a principal point offset and radial distortion: self-calibration fits better
    s0 = [r["key_statistics"]["sigma0_um"] for r in reps]
    assert s0[0] < s0[1]
    # the parameters not estimated are the camera's, in at/camera.toml and the report (trial s100 exchange F3: held
    # by priors, they had moved, 120.0000139 mm for 120 mm, p1 -3.5e-8)
    import tomllib

    given, adjusted = (tomllib.loads((with_cal / rel).read_text()) for rel in ("camera.toml", "at/camera.toml"))
    assert [adjusted[k] for k in ("focal_mm", "p1", "p2")] == [given[k] for k in ("focal_mm", "p1", "p2")]
    assert adjusted["ppx_mm"] != given["ppx_mm"] and adjusted["k1"] != given["k1"]   # estimated
    sc = reps[0]["self_calibration"]
    assert all(sc["adjusted"][n] == sc["apriori"][n] for n in ("fx_px", "fy_px", "skew_px", "p1", "p2")), sc
    assert (with_cal / "ortho" / "mosaic.tif").is_file()
    dom = json.loads((with_cal / "ortho" / "dom_report.json").read_text())["displacement"]
    assert dom["count"] > 10 and dom["rms_xy_m"] < 3.0  # GSD about 1 m
    summary = json.loads((with_cal / "reports" / "summary.json").read_text())
    assert summary["overall"] in ("pass", "fail")
    rows = {r["id"]: r for r in summary["checks"]}
    assert "no LiDAR control" in rows["control_points_used"]["note"]
    assert list(runs_without) == ["aerotri adjust"]


@pytest.fixture(scope="module")
def run_to_end(tiny_project, tmp_path_factory):
    """``aerotri run`` over a copy of the tiny project with the DOM and height checks; (project, its table)."""
    p = tmp_path_factory.mktemp("run") / "p"
    shutil.copytree(tiny_project, p)
    r = CliRunner().invoke(aerotri_cli, ["run", str(p), "--reference", str(p / "truth" / "ortho.tif"),
                                         "--points", str(p / "truth" / "checkpoints.csv")], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    return p, r.stdout


def test_run_goes_to_the_end_and_equals_the_chain_by_hand(by_hand, run_to_end):
    with_cal = by_hand[0]
    p, table = run_to_end
    for stage in ("strips", "classify", "rasters", "corners", "match", "adjust_final", "rectify", "mosaic",
                  "dom_check", "height_check", "report"):
        assert (p / "work" / "stages" / f"{stage}.json").is_file(), stage
    # no usable corner: said, control transfer and first adjustment left out, the rest goes on
    assert "no usable roof corner" in table and "without LiDAR control" in table
    for stage in ("adjust_first", "control"):
        assert not (p / "work" / "stages" / f"{stage}.json").exists()
    assert "usable=0" in table
    # the same options as the README chain with self-calibration ([adjust] of the tiny preset): same result
    assert (p / "at" / "eo.txt").read_bytes() == (with_cal / "at" / "eo.txt").read_bytes()
    summary = json.loads((p / "reports" / "summary.json").read_text())
    made = lambda d: {k: v for k, v in d.items() if k != "generated_utc"}  # noqa: E731  (when: its own)
    assert made(summary) == made(json.loads((with_cal / "reports" / "summary.json").read_text()))
    assert summary["generated_utc"].endswith("Z") and summary["aerotri_version"]
    # the strips checked before classification (only read: classify took lidar/), judged in the report
    strips = read_strip_check(p / "lidar_out" / "strips" / "strips.json")
    assert len(strips.pairs) == 3 and (p / "lidar_out" / "strips" / "index.html").is_file()
    classify = json.loads((p / "work" / "stages" / "classify.json").read_text())
    assert sorted(classify["inputs"]) == [f"lidar/strip_0{k}.las" for k in range(1, 5)]
    row = {r["id"]: r for r in summary["checks"]}["strip_rmsdz_m"]
    assert row["value"] == round(strips.all_pairs.rms_m, 4) and row["limit"] == 0.08
    assert row["verdict"] == ("pass" if row["value"] <= 0.08 else "fail") and "3 pairs" in row["note"]
    assert summary["details"]["lidar_strips"][0]["a"] == "strip_01"
    # a second run is up to date throughout
    r = CliRunner().invoke(aerotri_cli, ["run", str(p), "--reference", str(p / "truth" / "ortho.tif"),
                                         "--points", str(p / "truth" / "checkpoints.csv")], catch_exceptions=False)
    assert r.exit_code == 0 and " done " not in r.stdout
    # a run with nothing to do keeps the seconds of the run that did the work (trial s96 L3: it wrote 0.0 over them)
    rows = json.loads((p / "work" / "run_summary.json").read_text())["stages"]
    ran = [x for x in rows if x["status"] == "skipped (up to date)"]
    assert ran and all(x["seconds_when_run"] >= 0 for x in ran) and max(x["seconds_when_run"] for x in ran) > 0
    # the last line says the verdict (trial s96 M4), and --strict exits 3 on a failed one (M2: exit 0 beside a
    # verdict of fail, 10.9 m check RMS, that cron could not see)
    last = table.strip().splitlines()[-1]
    assert last.startswith(f"{p}: the chain ended ") and f"QA verdict {summary['overall']} (" in last, last
    import aerotri.chain.cli as chain_cli

    for verdict, code in (("fail", 3), ("pass", 0)):
        chain_cli.report_verdict, kept = (lambda root, v=verdict: v), chain_cli.report_verdict
        try:
            r = CliRunner().invoke(aerotri_cli, ["run", str(p), "--reference", str(p / "truth" / "ortho.tif"),
                                                 "--points", str(p / "truth" / "checkpoints.csv"), "--strict"])
        finally:
            chain_cli.report_verdict = kept
        assert r.exit_code == code and f"QA verdict {verdict}" in r.stdout, (verdict, r.output)


def test_run_makes_the_true_ortho_on_the_lidar_dsm_unless_told_not_to(run_to_end, tmp_path):
    """Issue 42: with LiDAR (lidar_out/dsm.tif of the rasters stage) the chain's DOM is a true ortho, said in the
    console and the summary; ``[rectify] true_ortho = false`` re-runs the orthophotos on the DEM (no LiDAR stage, the
    same orientation), and against the simulator's true orthophoto the roofs of the true ortho are closer."""
    from ortho.cli import main as ortho_cli

    p0, table = run_to_end
    index = json.loads((p0 / "ortho" / "frames" / "index.json").read_text())
    assert index["true_ortho"] and (p0 / index["dsm"]).resolve() == (p0 / "lidar_out" / "dsm.tif").resolve()
    # its occlusion test on the rasters stage's nearest-return DSM with the trees' fitted crowns
    assert (p0 / index["occlusion_dsm"]).resolve() == (p0 / "lidar_out" / "dsm_crowns.tif").resolve()
    assert (p0 / index["crowns"]).resolve() == (p0 / "lidar_out" / "crowns.gpkg").resolve()
    assert index["settings"]["true_ortho"]["value"] is True and index["settings"]["true_ortho"]["source"] == "aerotri run"
    assert "ortho=true (DSM)" in table and "rectify: true ortho on the DSM lidar_out/dsm.tif" in table
    # aerotri settings lists [rectify] as the chain takes it (trial s105 F2: "true_ortho : False [default]" beside a
    # chain that made the true ortho)
    def rectify_rows(q):
        text = CliRunner().invoke(aerotri_cli, ["settings", str(q)], catch_exceptions=False).output
        block = text.split("[rectify] (as aerotri run PROJECT takes it")[1].split("\n[")[0]
        return {ln.split(":")[0].strip(): ln for ln in block.splitlines()[1:] if ":" in ln}
    rows = rectify_rows(p0)
    assert "True  [aerotri run] (a DSM exists: the chain makes the true ortho)" in rows["true_ortho"], rows
    assert "lidar_out/dsm.tif" in rows["dsm"]
    p = tmp_path / "p"
    shutil.copytree(p0, p)
    with open(p / "project.toml", "a") as f:
        f.write("\n[rectify]\ntrue_ortho = false\n")
    rows = rectify_rows(p)
    assert "False  [project.toml]" in rows["true_ortho"] and rows["dsm"].split(":", 1)[1].split()[0] == "-", rows
    r = CliRunner().invoke(aerotri_cli, ["run", str(p), "--reference", str(p / "truth" / "ortho.tif"),
                                         "--points", str(p / "truth" / "checkpoints.csv")], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    for stage in ("classify", "rasters", "match"):
        assert "up to date" in rows[stage], rows[stage]
    # (the adjustment reads project.toml, so it runs again) the same orientation: the same frames rectified both ways
    assert (p / "at" / "eo.txt").read_bytes() == (p0 / "at" / "eo.txt").read_bytes()
    assert " done " in rows["rectify"] and "ortho=conventional (DEM)" in rows["rectify"]
    assert "[rectify] true_ortho = false (the DSM lidar_out/dsm.tif is not used)" in r.stdout
    assert json.loads((p / "ortho" / "frames" / "index.json").read_text())["true_ortho"] is False
    # the DOM check's roofs row against the simulator's true orthophoto, at the simulator's roof corners beside it
    # (the chain's default for that reference since the roof corners were configurable; before, the nDSM's buildings
    # were measured here: 0.60 against 4.74 GSD RMS)
    tables = {"true": table, "conventional": r.stdout}
    roofs = {way: json.loads((q / "ortho" / "dom_report.json").read_text())["roofs"]
             for way, q in (("true", p0), ("conventional", p))}
    for way, rf in roofs.items():
        assert rf["count"] >= 0.5 * rf["corners"], (way, rf["not_measured"])
        assert f"roofs_count={rf['count']}" in tables[way]
    assert roofs["true"]["rms_xy_gsd"] < 0.3 * roofs["conventional"]["rms_xy_gsd"], roofs
    # at the simulator's own roof corners (ortho check --roof-corners), same frames: measured 0.96 against 4.87 GSD
    rms = {}
    for way, q in (("true", p0), ("conventional", p)):
        r = CliRunner().invoke(ortho_cli, ["check", str(q), "--reference", str(q / "truth" / "ortho.tif"), "--roof-corners",
                                           str(q / "truth" / "roof_corners.csv"), "--out", str(tmp_path / way)])
        assert r.exit_code == 0, r.output
        rep = json.loads((tmp_path / f"{way}.json").read_text())["roofs"]
        said = roofs_not_measured_said(rep["not_measured"])  # said with the count (trial s98, s100 rc F9)
        assert r.stdout.splitlines()[1].startswith(f"roofs: {rep['count']} of {rep['corners']} corners{said}: RMS ")
        assert rep["count"] >= 0.5 * rep["corners"]
        rms[way] = rep["rms_xy_gsd"]
        # the chain's stage measured the same corners on the same DOM: the same figures
        assert (roofs[way]["count"], roofs[way]["rms_xy_m"]) == (rep["count"], rep["rms_xy_m"]), way
    assert rms["true"] < 1.5 and rms["true"] < 0.3 * rms["conventional"], rms


def test_the_chain_dom_check_measures_roofs_at_the_configured_or_the_simulator_corners(run_to_end, tmp_path):
    """Issue 42: the chain's DOM check measures the roofs at ``[dom_check] roof_corners`` when configured, else at the
    simulator's truth/roof_corners.csv when the reference is the simulator's truth/ortho.tif beside it (else the nDSM's
    buildings); a bad corner file is refused before the first stage; ``aerotri report`` shows the roofs row."""
    import csv

    p0, _ = run_to_end
    rep = json.loads((p0 / "ortho" / "dom_report.json").read_text())
    assert rep["roofs"]["corners_from"] == str(p0 / "truth" / "roof_corners.csv")
    assert rep["settings"]["roof_corners"]["source"] == "default"
    assert "simulator's roof corners" in rep["settings"]["roof_corners"]["note"]
    truth_rows = list(csv.DictReader(open(p0 / "truth" / "roof_corners.csv")))
    assert rep["roofs"]["corners"] == len(truth_rows)
    # the report's roofs row, not judged (no limit), with its corners and the kind of ortho
    summary = json.loads((p0 / "reports" / "summary.json").read_text())
    row = next(r for r in summary["checks"] if r["quantity"] == "displacement at roof corners, plan RMS")
    assert row["value"] == round(rep["roofs"]["rms_xy_m"], 4) and row["limit"] is None and row["verdict"] is None
    said = roofs_not_measured_said(rep["roofs"]["not_measured"])
    assert row["note"].startswith(f"{rep['roofs']['count']} of {len(truth_rows)} corners{said}, ")
    assert "corners: truth/roof_corners.csv; true ortho on the DSM" in row["note"]

    p = tmp_path / "p"
    shutil.copytree(p0, p)
    mine = p / "my_corners.csv"  # every other corner of the truth's
    with open(mine, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y"])
        w.writerows([(r["x"], r["y"]) for r in truth_rows[::2]])
    with open(p / "project.toml", "a") as f:
        f.write('\n[dom_check]\nroof_corners = "my_corners.csv"\n')
    args = ["run", str(p), "--reference", str(p / "truth" / "ortho.tif"), "--points", str(p / "truth" / "checkpoints.csv")]
    r = CliRunner().invoke(aerotri_cli, args, catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    assert " done " in rows["dom_check"] and "up to date" in rows["mosaic"], (rows["dom_check"], rows["mosaic"])
    rep = json.loads((p / "ortho" / "dom_report.json").read_text())
    assert rep["roofs"]["corners"] == len(truth_rows[::2]) and rep["roofs"]["corners_from"] == str(mine)
    assert rep["settings"]["roof_corners"]["source"] == "project.toml"
    row = next(r for r in json.loads((p / "reports" / "summary.json").read_text())["checks"]
               if r["quantity"] == "displacement at roof corners, plan RMS")
    assert row["value"] == round(rep["roofs"]["rms_xy_m"], 4) and "corners: my_corners.csv;" in row["note"]
    # a corner file without numbers: exit 2 naming its line, before any stage runs
    mine.write_text("x,y\n452000.0,3407000.0\nabc,3407001.0\n")
    before = sorted((p / "work" / "stages").glob("*.json"), key=lambda q: q.name)
    stamps = [q.stat().st_mtime_ns for q in before]
    r = CliRunner().invoke(aerotri_cli, args)
    assert r.exit_code == 2 and f"{mine}:3: non-numeric x or y" in r.output, r.output
    assert [q.stat().st_mtime_ns for q in before] == stamps


def test_run_without_reference_says_why_the_dom_is_not_checked(run_to_end, tmp_path):
    """Trial 8: `aerotri run` without --reference dropped an earlier run's DOM check stage without a word, and after a
    new mosaic the report still showed the old check's plot. Now the stage is listed as skipped with why; the report
    keeps an earlier check of this mosaic, says the DOM was not checked after the mosaic was made again (no rows,
    plot or link of the old check), and says so, not judged, when no check was ever made."""
    from aerotri.qa.report import write_qa_report

    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    assert "dom_check          skipped  " in rows["dom_check"], rows["dom_check"]
    assert "no reference orthophoto (aerotri run --reference REF.tif): the DOM is not checked; dom_report.json of " \
           "an earlier run measured this mosaic and stays in the report" in rows["dom_check"]
    summary = json.loads((p / "reports" / "summary.json").read_text())
    assert {"dom_rms_xy_m"} <= {c["id"] for c in summary["checks"]}
    with open(p / "project.toml", "a") as f:  # the mosaic made again, other pixels
        f.write("\n[mosaic]\nbalance = false\n")
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    assert " done " in rows["mosaic"] and "dom_report.json of an earlier run measured an earlier mosaic: the report " \
           "says the DOM was not checked" in rows["dom_check"], (rows["mosaic"], rows["dom_check"])
    summary = json.loads((p / "reports" / "summary.json").read_text())
    ids = {c["id"]: c for c in summary["checks"]}
    assert "dom_rms_xy_m" not in ids and "seam_misalignment_rms_px" not in ids and "dom_not_checked" not in ids
    assert ids["dom_check_stale"]["note"].startswith("the DOM was not checked: ")
    html = (p / "reports" / "index.html").read_text()
    assert "dom_report.png" not in html and "dom_report.json" in html  # the row names it; no plot, no link
    assert "../ortho/dom_report.json" not in html
    # no check at all: said, not judged
    (p / "ortho" / "dom_report.json").unlink()
    rep = write_qa_report(p)
    row = rep.check("dom_not_checked")
    assert row.verdict is None and "no reference orthophoto was given" in row.note and not rep.has("dom_check_stale")


def test_a_mosaic_made_again_by_hand_is_made_again_and_a_new_mosaic_drops_the_old_dom_check(run_to_end, tmp_path):
    """Reviewer 13: the report stage's key missed ortho/mosaic.json (and the mosaic, the frame index, the LiDAR DEM,
    at/leave_one_out.json), all of which the report reads: after a mosaic made again `aerotri run` kept the report
    "up to date", still saying the DOM check passed for a mosaic it never measured. trial-rerun: a mosaic made again
    by hand (``ortho mosaic --no-balance``) stayed "up to date" in the chain, options project.toml does not give, unlike
    a fresh project's; the chain now makes its own mosaic again, which the DOM check did measure."""
    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    assert "dom_rms_xy_m" in {c["id"] for c in json.loads((p / "reports" / "summary.json").read_text())["checks"]}
    chain_mosaic = (p / "ortho" / "mosaic.tif").read_bytes()
    from ortho.cli import main as ortho_cli

    r = CliRunner().invoke(ortho_cli, ["mosaic", str(p), "--no-balance"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert (p / "ortho" / "mosaic.tif").read_bytes() != chain_mosaic
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    assert " done " in rows["mosaic"] and " done " in rows["report"], (rows["mosaic"], rows["report"])
    assert "[mosaic] running (outputs changed since this stage wrote them: ortho/mosaic.tif)" in r.output
    assert (p / "ortho" / "mosaic.tif").read_bytes() == chain_mosaic
    ids = {c["id"] for c in json.loads((p / "reports" / "summary.json").read_text())["checks"]}
    assert "dom_rms_xy_m" in ids and "dom_check_stale" not in ids
    # another mosaic by the chain's settings, without a reference: the report drops the check of the earlier one
    with open(p / "project.toml", "a") as f:
        f.write("\n[mosaic]\nbalance = false\n")
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    assert " done " in rows["mosaic"] and " done " in rows["report"], (rows["mosaic"], rows["report"])
    ids = {c["id"] for c in json.loads((p / "reports" / "summary.json").read_text())["checks"]}
    assert "dom_rms_xy_m" not in ids and "dom_check_stale" in ids


def test_run_without_lidar_makes_the_tie_point_dem_or_uses_a_dem_from_elsewhere(tiny_project, tmp_path):
    p = tmp_path / "p"
    shutil.copytree(tiny_project, p, ignore=shutil.ignore_patterns("lidar"))
    (tmp_path / "elsewhere").mkdir()
    shutil.copy(tiny_project / "truth" / "dem.tif", tmp_path / "elsewhere" / "dem.tif")  # a DEM from another source
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    for stage in ("strips", "classify", "rasters", "corners", "adjust_first", "control"):
        assert f"{stage:<18} skipped" in r.stdout, stage
    assert "no LiDAR strips" in r.stdout and "stopped after" not in r.stderr
    eo, truth = read_eo(p / "at" / "eo.txt"), read_eo(p / "truth" / "eo.txt")
    assert np.abs(eo.centre_m - truth.centre_m).max() < 2.0  # GNSS alone carries the datum
    # a GNSS block without LiDAR or a DEM: the orthophotos on the DEM of the adjusted tie points
    index = json.loads((p / "ortho" / "frames" / "index.json").read_text())
    assert (p / index["dem"]).resolve() == (p / "at" / "dem.tif").resolve()
    # said to be the tie points' DEM, not the LiDAR stages' (trial s105: aerotri settings on the NGI block)
    assert index["settings"]["dem"]["note"] == "the adjusted tie points' DEM: no LiDAR", index["settings"]["dem"]
    assert (p / "ortho" / "mosaic.tif").is_file()
    with rasterio.open(p / "at" / "dem.tif") as tie, rasterio.open(p / "truth" / "dem.tif") as true:
        z_tie = tie.read(1, masked=True)
        rows, cols = np.nonzero(~np.ma.getmaskarray(z_tie))
        x, y = rasterio.transform.xy(tie.transform, rows, cols)
        z_true = np.array([v[0] for v in true.sample(zip(x, y))])
    # the tie points lie on the surface (roofs, trees) the truth DEM leaves out: the median, not every cell
    assert rows.size > 100 and abs(np.median(z_tie.compressed() - z_true)) < 1.0
    # the DEM given in project.toml: the orthophotos follow on it, nothing before them runs again
    with open(p / "project.toml", "a") as f:
        f.write('\n[rectify]\ndem = "../elsewhere/dem.tif"\n')
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "match              skipped (up to date)" in r.stdout
    assert "dem                skipped" in r.stdout
    index = json.loads((p / "ortho" / "frames" / "index.json").read_text())
    assert (p / index["dem"]).resolve() == (tmp_path / "elsewhere" / "dem.tif").resolve()


def test_strip_stage_skips_a_single_strip_and_adjusts_when_asked(tiny_project, tmp_path):
    """The strip stage alone: one strip is left out with the reason (the chain goes on); with [strips]
    adjust = true and the simulator's trajectories the boresight model corrects the strips, and the
    classification reads the corrected ones."""
    from aerotri.chain import Chain, read_options, run_stages
    from aerotri.core.project import Project
    from aerotri.core.tolerances import load_table
    from aerotri.qa.report import strip_rows

    def strip_stage(p):
        project = Project.open(p)
        chain = Chain(project, read_options(project))
        return project, chain, [s for s in chain.stages() if s.name == "strips"]

    one = tmp_path / "one"
    shutil.copytree(tiny_project, one, ignore=shutil.ignore_patterns("images", "truth", "strip_0[234].*"))
    project, chain, stages = strip_stage(one)
    rows = run_stages(one, stages, log=lambda m: None)
    assert rows[0]["status"] == "skipped" and "one strip only" in rows[0]["why"]
    assert chain.classify_inputs() == project.lidar_strips()
    assert run_stages(one, stages, log=lambda m: None)[0]["status"] == "skipped (up to date)"
    (row,), _ = strip_rows(project, load_table().limits)
    assert row.id == "strip_rmsdz_m" and row.value is None and row.verdict is None and "one strip only" in row.note

    p = tmp_path / "adjusted"
    shutil.copytree(tiny_project, p, ignore=shutil.ignore_patterns("images", "truth"))
    with open(p / "project.toml", "a") as f:
        f.write("\n[strips]\nadjust = true\nmaps = false\n")
    project, chain, stages = strip_stage(p)
    (r,) = run_stages(p, stages, log=lambda m: None)
    assert r["status"] == "done" and r["model"] == "boresight"  # the trajectories of trajectory/
    # the simulator's per-strip GNSS offsets (0.03 m) removed down to the range noise
    assert r["rms_after_m"] < 0.6 * r["rms_before_m"]
    assert chain.classify_inputs() == project.adjusted_strips() and all(f.is_file() for f in project.adjusted_strips())
    (row,), pairs = strip_rows(project, load_table().limits)
    assert row.value == r["rms_after_m"] and f"before: RMS {r['rms_before_m']:.3f} m" in row.note
    assert len(pairs) == 3


def test_optional_vectors_stage_checks_the_line_map_for_the_report(by_hand, tmp_path):
    """[vectors] enabled: a stage after the corners writes lidar_out/vectors.gpkg from the classified strips
    and checks it against the simulator's true outlines (truth/buildings.geojson); the report gets the
    line-map row. Off by default."""
    from aerotri.chain.options import read_options
    from aerotri.chain.stages import Chain, chain_stages
    from aerotri.core.project import Project
    from aerotri.qa.report import write_qa_report

    assert "vectors" not in [s.name for s in chain_stages(by_hand[0])]
    p = tmp_path / "p"
    shutil.copytree(by_hand[0], p, ignore=shutil.ignore_patterns("images", "ortho"))
    (p / "project.toml").write_text((p / "project.toml").read_text() + "\n[vectors]\nenabled = true\n")
    names = [s.name for s in chain_stages(p)]
    assert names.index("vectors") == names.index("corners") + 1
    project = Project.open(p)
    out = Chain(project, read_options(project)).run_vectors(p)
    assert out.buildings > 10 and out.checked and project.vectors_path.is_file()
    check = json.loads(project.vectors_check_path.read_text())
    b = check["layers"]["buildings"]
    assert b["n_matched_corners"] > 20 and b["rms_xy_corner_m"] < 1.0   # LiDAR at ~1.5 m spacing
    assert check["reference"].endswith("work/vectors_reference.gpkg")   # truth/buildings.geojson roof outlines, CRS
    rep = write_qa_report(p)
    row = rep.check("line_map_rms_xy_m")
    assert row.section == "Line map (DLG)"
    assert row.value == round(b["rms_xy_corner_m"], 4) and row.limit == rep.tolerances["feature_rms_xy_m"]
    assert row.verdict == ("pass" if row.value <= row.limit else "fail")


def test_another_stage_s_setting_leaves_the_adjustments_up_to_date(run_to_end, tmp_path):
    """trial-rerun: project.toml was an input of both adjustments as a file, so [rectify] res_m (a contract GSD) or
    [mosaic] seams re-ran the bundle adjustment; now the sections the adjustment reads are its options."""
    from aerotri.chain.runner import stale_reason
    from aerotri.chain.stages import chain_stages

    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p, ignore=shutil.ignore_patterns("truth"))

    def why(stage):
        return stale_reason(p, {s.name: s for s in chain_stages(p)}[stage])

    toml = (p / "project.toml").read_text()
    (p / "project.toml").write_text(toml + "\n[rectify]\nres_m = 2.0\n\n[mosaic]\nseams = \"voronoi\"\n")
    assert why("adjust_final") is None and "res_m null -> 2.0" in why("rectify")
    # the report's PDF switch is the report's alone (trial s96 L8: it re-ran adjust_final)
    (p / "project.toml").write_text(toml)
    r = CliRunner().invoke(aerotri_cli, ["settings", str(p), "--set", "qa.pdf=false"])
    assert r.exit_code == 0 and "pdf = false" in (p / "project.toml").read_text(), r.output
    assert why("adjust_final") is None
    (p / "project.toml").write_text(toml.replace("sigma_z_m = 0.08", "sigma_z_m = 0.5"))
    assert "options changed: project_toml.gnss.sigma_z_m 0.08 -> 0.5" in why("adjust_final")


def test_a_frame_ortho_gone_since_rectify_runs_rectify_again(run_to_end, tmp_path):
    """trial-overnight: frame orthos deleted (a night's disk cleanup) kept rectify "up to date" (its stamp recorded
    only ortho/frames/index.json) and `aerotri run` exited 0 without them. A frame ortho missing or of another size
    than index.json records now runs rectify again."""
    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    frame = p / "ortho" / "frames" / "s01_002.tif"
    whole = frame.read_bytes()
    frame.unlink()
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "[rectify] running (output missing: s01_002.tif (1 of 6 frame orthos index.json lists))" in r.output
    assert frame.read_bytes() == whole
    frame.write_bytes(whole[: len(whole) // 2])  # cut short by hand: another size than index.json records
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "[rectify] running (outputs changed: s01_002.tif (frame orthos of another size" in r.output
    assert frame.read_bytes() == whole


def test_a_deleted_dom_check_plot_runs_the_dom_check_again(run_to_end, tmp_path):
    """ortho/dom_report.png deleted left the DOM check up to date (its stamp recorded only dom_report.json)."""
    from aerotri.chain import chain_stages
    from aerotri.chain.runner import stale_reason

    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    st, = [s for s in chain_stages(p, reference_ortho=p / "truth" / "ortho.tif") if s.name == "dom_check"]
    assert stale_reason(p, st) is None
    (p / "ortho" / "dom_report.png").unlink()
    assert stale_reason(p, st) == "output missing: ortho/dom_report.png"


def test_a_run_that_stops_marks_the_earlier_report_stale(run_to_end, tmp_path, monkeypatch):
    """trial-overnight: after a failed night run reports/index.html (and summary.json) were still the last good run's
    report, nothing saying so. A run that stops before its report stage now marks them: a banner at the top of
    index.html, ``"stale"`` in summary.json; the next run that reaches the report writes it again without."""
    import errno

    from aerotri.chain.stages import Chain

    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    index, summary = p / "reports" / "index.html", p / "reports" / "summary.json"
    assert "Stale:" not in index.read_text() and "stale" not in json.loads(summary.read_text())
    (p / "ortho" / "mosaic.tif").unlink()

    def full(self, root):
        raise OSError(errno.ENOSPC, "No space left on device", str(root / "ortho" / "mosaic.tif"))

    with monkeypatch.context() as m:
        m.setattr(Chain, "run_mosaic", full)
        r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 2, r.output
    note = json.loads(summary.read_text())["stale"]
    assert f"stopped at mosaic (failed: {p / 'ortho' / 'mosaic.tif'}: no space left on device)" in note, note
    html = index.read_text()
    assert html.count("Stale: the run of ") == 1 and "stopped at mosaic" in html
    assert html.index("Stale:") < html.index("<h1>")  # at the top, before the verdict
    assert "marked stale" in r.output
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "Stale:" not in index.read_text() and "stale" not in json.loads(summary.read_text())


def test_a_full_disk_in_the_mosaic_names_the_mosaic_and_marks_the_report(run_to_end, tmp_path):
    """trial-overnight: disk full in the mosaic said "d1: a write was cut short ..." (the project, not the file), and
    GDAL's "_tiffWriteProc: File too large." came after it (the first overview, left open, flushed at exit). A real
    process whose files may not grow past the report's size + 64 kB (RLIMIT_FSIZE, as a full disk cuts a write)."""
    import os
    import resource
    import signal

    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    (p / "ortho" / "mosaic.tif").unlink()
    limit = (p / "reports" / "index.html").stat().st_size + (64 << 10)  # the banner fits, the mosaic's rows do not

    def preexec():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    code = "import sys; sys.argv[0] = 'aerotri'; from aerotri.cli import main; sys.exit(main())"
    r = subprocess.run([sys.executable, "-c", code, "run", str(p)], capture_output=True, text=True, preexec_fn=preexec,
                       env=dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[3])), timeout=300)
    assert r.returncode == 2, r.stderr
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and errors[0].startswith(f"Error: {p / 'ortho' / 'mosaic.tif'}: a write was cut short"), \
        r.stderr
    assert r.stderr.rstrip().splitlines()[-1] == errors[0] and "_tiffWriteProc" not in r.stderr, r.stderr
    assert "stopped at mosaic (failed: " in json.loads((p / "reports" / "summary.json").read_text())["stale"]
    assert "Stale: the run of " in (p / "reports" / "index.html").read_text()


def test_a_run_refused_by_its_checks_leaves_the_earlier_report_and_a_lone_mark_is_not_made(run_to_end, tmp_path,
                                                                                              monkeypatch):
    """A run refused in its checks before the first stage (a frame cut short, a malformed --scheduler) ran nothing:
    bad input changes no file, the earlier report and work/run_summary.json included (review 51 had them marked; CI 82
    on tests/test_bad_input.py). A mark that would reach summary.json but not index.html (a disk full under the
    banner) is not made: summary.json is no output of the report stage, its mark would outlive the next run."""
    from aerotri.qa import report as qa_report

    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    index, summary = p / "reports" / "index.html", p / "reports" / "summary.json"
    kept = {q: q.read_bytes() for q in (index, summary, p / "work" / "run_summary.json")}
    frame = sorted((p / "images").glob("*.tif"))[0]
    whole = frame.read_bytes()
    frame.write_bytes(whole[:len(whole) // 2])
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 2 and frame.name in r.output, r.output
    assert all(q.read_bytes() == b for q, b in kept.items())
    frame.write_bytes(whole)
    r = CliRunner().invoke(aerotri_cli, ["run", str(p), "--scheduler", "bogus"], catch_exceptions=False)
    assert r.exit_code == 2 and "--scheduler bogus: expected" in r.output, r.output
    assert all(q.read_bytes() == b for q, b in kept.items())

    written = qa_report.write_text_atomic

    def full_for_the_index(path, text):
        if Path(path) == index:
            raise OSError(28, "No space left on device")
        written(path, text)

    monkeypatch.setattr(qa_report, "write_text_atomic", full_for_the_index)
    marked, failed = qa_report.mark_report_stale(p, "the run of now stopped at mosaic (failed: disk full)")
    assert marked == [] and len(failed) == 1 and str(index) in failed[0]
    assert "stale" not in json.loads(summary.read_text())  # (its mark would outlive the next run)


def test_the_chain_says_when_it_replaces_an_adjustment_made_with_other_options(run_to_end, tmp_path, caplog):
    """New-user trial s51: NGI adjusted by hand with `aerotri adjust --dem`, then `aerotri run`: the chain adjusted
    again by project.toml (no DEM) and replaced at/eo.txt (4x further from the national AT) without a word. It now
    names the hand run's command-line options it does not repeat, and how to keep them."""
    p = tmp_path / "p"
    shutil.copytree(run_to_end[0], p)
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(p), "--max-ndsm-m", "2.5"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(aerotri_cli, ["run", str(p)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "[adjust_final] running" in r.output
    assert "the adjustment there was made by `aerotri adjust` with max_ndsm_m = 2.5 (now 1.0) on its command line" \
        in r.output and "put those in [adjust] to keep them" in r.output, r.output
    # the chain's own report.json, edited into another shape (review 52: a traceback, exit 1): adjusted again, no word
    # (the check itself, not another whole run: 10 s of the test suite)
    from aerotri.chain import Chain, read_options
    from aerotri.core.project import Project

    report = p / "at" / "report.json"
    report.write_text(json.dumps(dict(json.loads(report.read_text()), settings="x")))
    project = Project.open(p)
    chain = Chain(project, read_options(project))
    caplog.clear()
    with caplog.at_level(logging.INFO):
        chain.warn_hand_options_dropped(chain.final_settings())
    assert "the adjustment there was made by" not in caplog.text, caplog.text


def test_a_lidar_only_project_without_buildings_goes_on_past_the_corners(tmp_path):
    """lead (new-user trial, Autzen's trimmed tile): `aerotri run` on a LiDAR-only folder classified the cloud, then
    stopped at the corners stage (exit 2) with "no building points ... classify the cloud first": the cloud simply
    holds no building. As with no usable roof corner (docs/chain.md) the stage records why and the chain goes on;
    without frames the photo stages are left out, each saying why."""
    import laspy
    import pyproj

    from aerotri.chain import Chain, read_options, run_stages
    from aerotri.chain.run import closing_words
    from aerotri.core.project import Project
    from lidarctl.corners.roof_corners import read_corner_summary

    p = tmp_path / "P"
    (p / "lidar").mkdir(parents=True)
    (p / "project.toml").write_text('[project]\ncrs = "EPSG:32649"\n')
    rng = np.random.default_rng(4)
    n = 4000
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001, 0.001, 0.001]), np.array([452000.0, 3407000.0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(32649))
    las = laspy.LasData(header)
    las.x, las.y = 452000.0 + rng.uniform(0, 80, n), 3407000.0 + rng.uniform(0, 80, n)
    las.z = rng.normal(0, 0.05, n)
    las.classification = np.where(np.arange(n) % 4 == 0, 5, 2)   # ground and high vegetation: classified, no building
    las.point_source_id = np.ones(n)
    las.write(p / "lidar" / "strip_01.laz")
    project = Project.open(p)
    (classified,) = project.classified_strips()      # as the classify stage leaves it
    classified.parent.mkdir(parents=True)
    shutil.copy(p / "lidar" / "strip_01.laz", classified)
    chain = Chain(project, read_options(project))
    stages = [s for s in chain.stages() if s.name not in ("strips", "classify", "rasters", "report")]
    rows = {r["stage"]: r for r in run_stages(p, stages, log=lambda m: None)}
    corners = rows["corners"]
    assert corners["status"] == "done" and corners["usable"] == 0
    (note,) = corners["notes"]
    assert "no building points (ASPRS class 6) among 4000 points of a classified cloud (class 2: 3000, class 5: " \
           "1000): it holds no building to take roof corners from; the chain goes on without LiDAR control" in note
    assert "classify the cloud first" not in note and "min_edge_m" not in note
    summary = read_corner_summary(project.corners_summary_path)
    assert summary.no_usable and summary.stats.n_building_points == 0 and summary.stats.n_points == 4000
    assert not project.corners_path.exists() and not project.roof_planes_path.exists()
    for stage in ("match", "adjust_first", "control", "adjust_final", "dem", "rectify", "mosaic", "dom_check"):
        assert rows[stage]["status"] == "skipped", stage
        assert rows[stage]["why"] == f"no frames in {project.images_dir}: a LiDAR-only project, no photo stages"
    assert closing_words(list(rows.values())).startswith("the LiDAR stages only: no frames in ")
    # with frames (and no building points) the control transfer says why it is left out
    (p / "images").mkdir()
    (p / "images" / "f1.tif").write_bytes(b"")
    assert Chain(project, read_options(project)).no_corners() == (
        f"no building points in the classified cloud, so no roof corner ({project.lidar_out_dir / 'corners.json'})")
    # the surveyor's own control/ (no transfer.json) is the final adjustment's control then (trial-cn: dropped without
    # a word, "check points 0"); LiDAR control of an earlier run (transfer.json beside it) is not
    assert Chain(project, read_options(project)).final_settings().settings.use_control is False
    (p / "control").mkdir()
    (p / "control" / "points.csv").write_text("id,kind,x,y,z,sx,sy,sz\n")
    chain = Chain(project, read_options(project))
    r = chain.final_settings()
    assert r.settings.use_control is True and "with the control points of" in r.notes["use_control"]
    # with usable corners too: the control stage would write over them (an input lost); the surveyor's control stays
    assert "is the surveyor's own control" in chain.no_corners()
    (p / "control" / "transfer.json").write_text("{}")
    assert Chain(project, read_options(project)).final_settings().settings.use_control is False


def test_run_dem_holds_the_adjustment_too_without_lidar(tmp_path):
    """s95 (a drone trial): `aerotri run P --dem DEM.tif` put the orthos on the DEM but adjusted without it: the tie
    points stood 3.56 m below it and 45 % of the mosaic was empty. Without LiDAR and [adjust] dem the DEM of the
    orthophotos (--dem, or [rectify] dem) is the final adjustment's surface control, said in its notes."""
    from aerotri.chain.options import read_options
    from aerotri.chain.stages import Chain
    from aerotri.core.project import Project

    (tmp_path / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32649"\n')
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=10, height=10, count=1, dtype="float32", crs="EPSG:32649",
                       transform=rasterio.transform.from_origin(500000, 3000000, 1, 1)) as ds:
        ds.write(np.zeros((1, 10, 10), "float32"))
    project = Project.open(tmp_path)
    assert Chain(project, read_options(project)).final_settings().settings.dem is None
    r = Chain(project, read_options(project), dem=dem).final_settings()
    assert r.settings.dem == dem and r.sources["dem"] == "aerotri run --dem" and "surface control on" in r.notes["dem"]
    with open(tmp_path / "project.toml", "a") as f:
        f.write(f'\n[rectify]\ndem = "{dem}"\n')
    project = Project.open(tmp_path)
    r = Chain(project, read_options(project)).final_settings()
    assert r.settings.dem == dem and r.sources["dem"] == "[rectify] dem"


def test_a_run_under_way_marks_the_report_until_its_report_stage(run_to_end, tmp_path):
    """Trial s96 M1: a run killed by SIGKILL (the out-of-memory killer) left last night's report "pass" unmarked, and
    a report marked stale kept "overall": "pass" beside "stale". A run marks the report when it starts ("running",
    overall "stale", the verdict of that run kept); its report stage finds the report as it wrote it (byte for byte:
    up to date) and a run that dies before it leaves the mark."""
    from aerotri.qa.report import clear_running_mark, mark_report_stale

    p0, _ = run_to_end
    p = tmp_path / "p"
    shutil.copytree(p0, p)
    index, summary = p / "reports" / "index.html", p / "reports" / "summary.json"
    before = (index.read_bytes(), summary.read_bytes())
    mark_report_stale(p, "a run started at 2026-12-05 20:00 UTC and has not ended", running=True)
    doc = json.loads(summary.read_text())
    assert doc["overall"] == "stale" and doc["overall_of_that_run"] in ("pass", "fail") and doc["running"] is True
    assert "has not ended" in index.read_text()
    clear_running_mark(p)
    assert (index.read_bytes(), summary.read_bytes()) == before
    # a stop in a stage replaces the running mark by its own; clearing a running mark then leaves it
    mark_report_stale(p, "a run started at 2026-12-05 20:00 UTC and has not ended", running=True)
    mark_report_stale(p, "the run of 2026-12-05 20:00 UTC stopped at mosaic (failed: disk full)")
    clear_running_mark(p)
    doc = json.loads(summary.read_text())
    assert doc["overall"] == "stale" and "stopped at mosaic" in doc["stale"] and "running" not in doc
    assert index.read_text().count("Stale:") == 1 and "has not ended" not in index.read_text()
