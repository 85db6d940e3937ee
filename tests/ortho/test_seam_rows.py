"""The seam rows of the accuracy report a QA reader can trust (review 25, issue 42): one frame 1 px off fails the
worst-seam row while the block RMS, diluted by the other seams, would pass; one frame more than the search off, whose
seams' patches find no match, fails it too (review 26); a block whose seams lie over ground textured in one direction
only says "not measured" with the floor and the count, not nothing; a record measured before the texture floor
leaves the worst seam unjudged."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

import ortho.synthetic as synthetic
from aerotri.core.records import to_record
from aerotri.qa.report import write_qa_report
from ortho.check import read_dom_check, run_check
from ortho.cli import main
from ortho.mosaic import (SEAM_MAX_UNMATCHED_SHARE, SEAM_MIN_PATCHES, SEAM_MIN_TEXTURE_RATIO, SEAM_SEARCH_PX,
                          SeamMisalignment, seam_misalignment)

RES_M = 0.2  # the synthetic block's GSD
SHIFTED = "s02_002"  # a frame with two seams of at least SEAM_MIN_PATCHES patches (and two shorter ones)


def _block(root, *, seed: int = 11) -> None:
    synthetic.write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=seed)
    _ortho(root)


def _ortho(root) -> None:
    for args in (["rectify", root], ["mosaic", root, "--seams", "voronoi"]):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code == 0, r.output


def _move_frame(root, frame: str, de_m: float) -> None:
    """The frame's projection centre moved ``de_m`` east in at/eo.txt: its ortho moves that far on the ground (flat,
    near-vertical frame)."""
    eo = root / "at" / "eo.txt"
    lines = []
    for line in eo.read_text().splitlines():
        f = line.split()
        if f and f[0] == frame:
            f[1] = f"{float(f[1]) + de_m:.4f}"
            line = " ".join(f)
        lines.append(line)
    eo.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def blocks(tmp_path_factory):
    """(as made, SHIFTED moved 1 px east, SHIFTED moved 6 px east: beyond the seams' search); orthos made again."""
    base = tmp_path_factory.mktemp("seam_rows")
    good = base / "good"
    _block(good)
    moved = []
    for name, px in (("bad", 1), ("far", 6)):
        moved.append(base / name)
        shutil.copytree(good, moved[-1])
        _move_frame(moved[-1], SHIFTED, px * RES_M)
        _ortho(moved[-1])
    return good, *moved


def test_one_frame_1_px_off_fails_the_worst_seam_while_the_block_rms_would_pass(blocks, tmp_path):
    good, bad, _ = blocks
    before, after = seam_misalignment(good), seam_misalignment(bad)
    assert before.min_patches == SEAM_MIN_PATCHES and before.min_texture_ratio == SEAM_MIN_TEXTURE_RATIO
    # as made: every seam within a tenth of a pixel (truth orientation)
    assert before.worst_seam is not None and before.worst_seam.rms_px < 0.1
    # moved: the frame's seams of enough patches read its 1 px, the others not; the block RMS takes them all
    w = after.worst_seam
    assert SHIFTED in (w.image_a, w.image_b) and w.patches >= SEAM_MIN_PATCHES and 0.8 < w.rms_px < 1.2
    others = [p for p in after.judged() if SHIFTED not in (p.image_a, p.image_b)]
    assert others and max(p.rms_px for p in others) < 0.1
    assert after.rms_px < 0.9  # below the block limit (1.0 px): the block RMS alone passes
    # the seams of fewer patches are listed, not judged
    assert any(p.patches < SEAM_MIN_PATCHES for p in after.per_seam)
    assert set(after.judged()) == {p for p in after.per_seam if p.patches >= SEAM_MIN_PATCHES}

    # the accuracy report: the block row passes, the worst-seam row fails the report and names the seam
    run_check(bad, reference_path=bad / "truth" / "ortho.tif")
    doc = json.loads((bad / "ortho" / "dom_report.json").read_text())["seams"]
    assert doc["min_patches"] == SEAM_MIN_PATCHES and doc["worst_seam"]["patches"] == w.patches
    assert len(doc["per_seam"]) == len(after.per_seam)
    rep = write_qa_report(bad)
    block, worst = rep.check("seam_misalignment_rms_px"), rep.check("seam_worst_rms_px")
    assert block.verdict == "pass" and block.limit == 1.0
    assert f"below the texture floor {SEAM_MIN_TEXTURE_RATIO:g} left out" in block.note
    assert worst.verdict == "fail" and worst.limit == 0.5 and worst.limit_key == "seam_worst_rms_px"
    assert worst.note.startswith(f"{w.image_a} / {w.image_b}: {w.patches} patches")
    assert rep.overall == "fail"
    html = (bad / "reports" / "index.html").read_text()
    assert "misalignment across the worst seam" in html and f"{w.image_a} / {w.image_b}" in html
    # the block as made passes both rows
    run_check(good, reference_path=good / "truth" / "ortho.tif")
    rep = write_qa_report(good)
    assert rep.check("seam_misalignment_rms_px").verdict == "pass"
    assert rep.check("seam_worst_rms_px").verdict == "pass"
    assert before.unmatched == 0 and not before.unmatched_seams()


def test_one_frame_off_by_more_than_the_search_fails_the_worst_seam_by_its_unmatched_patches(blocks):
    """SHIFTED 6 px off: its seams' textured patches find no match (peak on the edge of the +-4 px search) and drop
    out, so the seams matched are all good (worst 0.02 px, block 0.01 px: both rows passed, review 26); counted per
    seam, the seams most of whose textured patches found no match fail the worst-seam row, named."""
    _, _, far = blocks
    s = seam_misalignment(far)
    assert s.worst_seam is not None and s.worst_seam.rms_px < 0.1 and s.rms_px < 0.1  # the seams matched: good
    lost = s.unmatched_seams()
    assert lost and all(SHIFTED in (p.image_a, p.image_b) for p in lost)
    assert all(p.textured >= SEAM_MIN_PATCHES and p.unmatched_share > SEAM_MAX_UNMATCHED_SHARE for p in lost)
    assert s.examined == s.patches + s.one_direction + s.unsettled + s.unmatched
    run_check(far, reference_path=far / "truth" / "ortho.tif")
    doc = json.loads((far / "ortho" / "dom_report.json").read_text())["seams"]
    assert doc["unmatched"] == s.unmatched and doc["max_unmatched_share"] == SEAM_MAX_UNMATCHED_SHARE
    assert sum(p["unmatched"] for p in doc["per_seam"]) == s.unmatched
    rep = write_qa_report(far)
    block, worst = rep.check("seam_misalignment_rms_px"), rep.check("seam_worst_rms_px")
    assert block.verdict == "pass" and f"{s.unmatched} without a match" in block.note
    assert worst.verdict == "fail" and worst.limit == 0.5 and rep.overall == "fail"
    p = lost[0]
    assert worst.note.startswith(f"{len(lost)} seams did not match ({p.image_a} / {p.image_b} {p.unmatched} of "
                                 f"{p.textured} textured patches unmatched")
    assert f"): frames off by more than the +-{SEAM_SEARCH_PX} px search" in worst.note
    r = CliRunner().invoke(main, ["check", str(far), "--reference", str(far / "truth" / "ortho.tif")])
    assert r.exit_code == 0 and f"{len(lost)} seams did not match ({p.image_a} / {p.image_b}" in r.output


def _rows_stripes(height: int, width: int, bands: int = 3, seed: int = 0) -> np.ndarray:
    """Crop rows: grey levels varying with the column only (texture in one direction), uint8."""
    rng = np.random.default_rng(seed)
    profile = np.convolve(rng.normal(128.0, 50.0, width + 8), np.ones(3) / 3.0, mode="same")[4:-4]
    return np.repeat(np.clip(np.tile(profile, (height, 1)), 0, 255)[..., None], bands, axis=2).astype(np.uint8)


def test_a_block_without_a_textured_seam_says_not_measured_with_the_floor_and_count(tmp_path, monkeypatch):
    """Seams over crop rows only: no patch passes the texture floor; the row says so (it was left out, and a reader
    could not tell "measured: good" from "not measured"); said, not judged."""
    monkeypatch.setattr(synthetic, "textured_orthophoto", _rows_stripes)
    root = tmp_path / "p"
    _block(root, seed=5)
    s = seam_misalignment(root)
    assert s.patches == 0 and s.one_direction > 0 and s.rms_px is None and s.worst_seam is None
    r = CliRunner().invoke(main, ["check", str(root), "--reference", str(root / "truth" / "ortho.tif")])
    assert r.exit_code == 0, r.output
    assert f"seams: not measured (0 of {s.examined} patches above the texture floor 0.5)" in r.output
    check = read_dom_check(root / "ortho" / "dom_report.json")
    assert check.seams.examined == s.one_direction + s.unsettled
    rep = write_qa_report(root)
    row = rep.check("seam_misalignment_rms_px")
    assert row.value is None and row.verdict is None and row.limit == 1.0
    assert row.note.startswith(f"not measured (0 of {s.examined} patches above the texture floor "
                               f"{SEAM_MIN_TEXTURE_RATIO:g})")
    assert not rep.has("seam_worst_rms_px")
    assert "not measured (0 of" in (root / "reports" / "index.html").read_text()


def test_an_older_seams_record_is_read_and_its_worst_seam_found():
    """dom_report.json written before the worst seam was recorded (no min_patches, worst_seam): read, the worst
    seam found among its seams of at least SEAM_MIN_PATCHES patches."""
    rec = {"patch_px": 32, "patches": 14, "rms_px": 0.3, "max_px": 1.1, "one_direction": 8,
           "per_seam": [{"image_a": "a", "image_b": "b", "patches": 4, "rms_px": 0.9, "max_px": 1.1},
                        {"image_a": "a", "image_b": "c", "patches": 10, "rms_px": 0.2, "max_px": 0.4},
                        {"image_a": "b", "image_b": "c", "patches": 0, "rms_px": None, "max_px": None}]}
    s = SeamMisalignment.of_record(rec)
    assert s.min_patches is None and s.least_patches == SEAM_MIN_PATCHES and s.examined == 22
    assert s.worst().image_b == "c" and s.worst(min_patches=4).image_b == "b"
    assert SeamMisalignment.of_record(to_record(s)) == s


def _report_of(root, seams: dict):
    """The accuracy report of an adjusted block (not LiDAR only: the DOM limits apply) whose dom_report.json has
    ``seams``."""
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32649"\n')
    (root / "ortho").mkdir()
    (root / "at").mkdir()
    (root / "at" / "report.json").write_text(json.dumps(dict(
        project="t", check_rms_m=[0.1, 0.1, 0.5], rms_control_ground_m=[0.02, 0.02, 0.03],
        key_statistics=dict(sigma0_um=5.1, sigma0_px=0.425, success=True, message="Solution Successful."))))
    (root / "ortho" / "dom_report.json").write_text(json.dumps({"displacement": {"count": 10, "rms_xy_m": 0.05},
                                                                "seams": seams}))
    return write_qa_report(root)


def test_seams_too_short_to_judge_are_said_not_judged(tmp_path):
    """A block whose seams all have fewer than SEAM_MIN_PATCHES patches: the block row is judged, the worst-seam row
    says why it is not (the seam with the most patches named)."""
    seams = {"patch_px": 32, "patches": 6, "rms_px": 0.2, "max_px": 0.3, "one_direction": 2, "unsettled": 0,
             "min_texture_ratio": 0.5, "min_patches": 5, "worst_seam": None,
             "per_seam": [{"image_a": "a", "image_b": "b", "patches": 4, "rms_px": 0.2, "max_px": 0.3},
                          {"image_a": "b", "image_b": "c", "patches": 2, "rms_px": 0.2, "max_px": 0.25}]}
    rep = _report_of(tmp_path, seams)
    assert rep.check("seam_misalignment_rms_px").verdict == "pass"
    row = rep.check("seam_worst_rms_px")
    assert row.value is None and row.verdict is None and row.limit == 0.5
    assert row.note == "not judged: no seam has 5 patches (the most: 4, a / b)"


def test_a_record_measured_before_the_texture_floor_leaves_the_worst_seam_unjudged(tmp_path):
    """dom_report.json from before review 20 (no min_texture_ratio: the DOM check's floor 0.1, roads in, each read up
    to 0.4 px off): its seams are not comparable with the 0.5 px limit (the demo's read 1 over it as made, review
    26); the worst seam is said unjudged, the block row names the record's basis."""
    seams = {"patch_px": 32, "patches": 40, "rms_px": 0.3, "max_px": 1.4, "one_direction": 3,
             "per_seam": [{"image_a": "a", "image_b": "b", "patches": 25, "rms_px": 0.62, "max_px": 1.4},
                          {"image_a": "b", "image_b": "c", "patches": 15, "rms_px": 0.2, "max_px": 0.4}]}
    rep = _report_of(tmp_path, seams)
    block, worst = rep.check("seam_misalignment_rms_px"), rep.check("seam_worst_rms_px")
    assert block.verdict == "pass" and "measured before the texture floor" in block.note and "0.1" in block.note
    assert worst.value is None and worst.verdict is None and worst.limit == 0.5
    assert worst.note == "not judged: measured before the texture floor; re-run ortho check"
    assert rep.overall == "pass" and rep.not_judged == ("seam_worst_rms_px",)
    assert json.loads((tmp_path / "reports" / "summary.json").read_text())["not_judged"] == ["seam_worst_rms_px"]
    html = (tmp_path / "reports" / "index.html").read_text()
    assert f"({rep.passed} passed, 0 failed, 1 with a limit not judged)" in html


def test_seams_whose_textured_patches_all_found_no_match_fail_not_unmeasured(tmp_path):
    """Every frame off by more than the search: patches above the texture floor, none matched. Not "not measured (0
    of N patches above the texture floor)", which blamed the ground: both rows fail with the counts (review 26)."""
    seams = {"patch_px": 32, "patches": 0, "rms_px": None, "max_px": None, "one_direction": 30, "unsettled": 0,
             "unmatched": 21, "min_texture_ratio": 0.5, "min_patches": 5, "max_unmatched_share": 0.5,
             "per_seam": [{"image_a": "a", "image_b": "b", "patches": 0, "rms_px": None, "max_px": None,
                           "unmatched": 18},
                          {"image_a": "b", "image_b": "c", "patches": 0, "rms_px": None, "max_px": None,
                           "unmatched": 3}]}
    rep = _report_of(tmp_path, seams)
    block, worst = rep.check("seam_misalignment_rms_px"), rep.check("seam_worst_rms_px")
    assert block.value is None and block.verdict == "fail"
    assert block.note.startswith("0 of 51 patches matched (30 below the texture floor 0.5, 21 above it without a "
                                 "match): 1 seam did not match (a / b 18 of 18 textured patches unmatched): frames off")
    assert worst.value is None and worst.verdict == "fail" and worst.note.startswith("1 seam did not match (a / b")
    # too few textured patches to judge a seam by (3 of 5): said, with the counts, not judged
    seams["unmatched"], seams["per_seam"] = 3, seams["per_seam"][1:]
    (tmp_path / "few").mkdir()
    rep = _report_of(tmp_path / "few", seams)
    block = rep.check("seam_misalignment_rms_px")
    assert block.verdict is None and block.note == ("not measured (0 of 33 patches: 30 below the texture floor 0.5, "
                                                    "3 above it without a match)")
    assert not rep.has("seam_worst_rms_px") and rep.not_judged == ("seam_misalignment_rms_px",)


def test_unmatched_seams_fail_only_against_a_limit_and_show_no_passing_value():
    """Review 31 (Brighton): a seam all of whose textured patches found no match failed the worst-seam row showing the
    matched seams' worst, 1.895 px, under its 2.5 px limit, and failed it with no limit at all. The row now has no
    value (the unmatched share in the note) and fails against a limit only; the block row likewise."""
    import types

    from aerotri.qa.report import _seam_rows

    seams = {"patch_px": 32, "patches": 12, "rms_px": 1.9, "max_px": 3.0, "one_direction": 4, "unsettled": 0,
             "unmatched": 8, "min_texture_ratio": 0.5, "min_patches": 5, "max_unmatched_share": 0.5,
             "per_seam": [{"image_a": "a", "image_b": "b", "patches": 0, "rms_px": None, "max_px": None,
                           "unmatched": 8},
                          {"image_a": "b", "image_b": "c", "patches": 12, "rms_px": 1.895, "max_px": 3.0,
                           "unmatched": 0}]}
    s = SeamMisalignment.of_record(seams)
    dom = types.SimpleNamespace(seams=s, seams_rms_px=s.rms_px, seam_patches=s.patches)
    block, worst = _seam_rows("DOM", dom, {"seam_misalignment_rms_px": 2.5})
    assert block.verdict == "pass" and block.value == 1.9
    assert worst.value is None and worst.limit == 2.5 and worst.verdict == "fail"
    assert "the worst seam's unmatched share 100 % of its textured patches (more than 50 % fails" in worst.note
    assert "of the seams matched the worst: b / c 1.895 px" in worst.note
    block, worst = _seam_rows("DOM", dom, {})
    assert block.verdict is None and worst.verdict is None and worst.value is None and worst.limit is None
    assert worst.note.startswith("1 seam did not match (a / b 8 of 8 textured patches unmatched)")
    # nothing matched and no limit: the block row says so, unjudged
    seams.update(patches=0, rms_px=None, max_px=None, per_seam=seams["per_seam"][:1])
    s = SeamMisalignment.of_record(seams)
    rows = _seam_rows("DOM", types.SimpleNamespace(seams=s, seams_rms_px=None, seam_patches=0), {})
    assert [(r.value, r.verdict) for r in rows] == [(None, None), (None, None)]
    assert rows[0].note.startswith("0 of 12 patches matched")
