"""All frames or none: ``ortho rectify`` commits ortho/frames as a whole, consumers refuse frames that do not
belong to index.json, subset re-runs keep the other frames; 16-bit frames keep their radiometry through
the mosaic; options that would need more than the machine has stop before allocating (issue 17)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from aerotri.core.errors import ResourceError
from aerotri.core.limits import check_allocation, check_grid, physical_memory_bytes
from ortho.cli import main
from tests.shared_builds import write_synthetic_project


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def tree(folder):
    """sha1 of every file below ``folder`` (relative names), and the names of hidden temporaries next to it."""
    out = {}
    for dirpath, _, files in os.walk(folder):
        for n in files:
            p = os.path.join(dirpath, n)
            out[os.path.relpath(p, folder)] = hashlib.sha1(open(p, "rb").read()).hexdigest()
    return out


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".part-" in p.name)


@pytest.fixture(scope="module")
def rectified(tmp_path_factory):
    """A synthetic block (6 frames, truth EO) rectified and mosaicked once; tests work on copies."""
    root = tmp_path_factory.mktemp("atomic") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=11)
    r = run("rectify", root)
    assert r.exit_code == 0, r.output
    r = run("mosaic", root, "--seams", "voronoi")
    assert r.exit_code == 0, r.output
    return root


@pytest.fixture
def project(rectified, tmp_path):
    root = tmp_path / "p"
    shutil.copytree(rectified, root)
    return root


def test_index_records_every_frame_file(project):
    index = json.loads((project / "ortho/frames/index.json").read_text())
    assert len(index["frames"]) == 6
    for e in index["frames"]:
        data = (project / "ortho/frames" / e["file"]).read_bytes()
        assert e["size"] == len(data) and e["sha1"] == hashlib.sha1(data).hexdigest()


@pytest.mark.parametrize("breakage", ["truncated_image", "partial_dem"])
def test_failed_rerun_leaves_the_previous_frames(project, breakage):
    """A re-run that fails part-way (frames already written for other images) changes nothing in ortho/,
    and the mosaic of the previous complete output still works."""
    before = tree(project / "ortho")
    if breakage == "truncated_image":  # the header is fine: found only when the frame is rectified
        p = project / "images" / "s02_002.tif"
        p.write_bytes(p.read_bytes()[: p.stat().st_size // 3])
        culprit = "s02_002.tif"
    else:  # a DEM covering part of the first strip only: its frames are rectified (partly nodata, issue 42),
        # then the second strip's frames, none of whose ground it covers, fail
        with rasterio.open(project / "lidar_out/dem.tif") as ds:
            a, prof, t = ds.read(1), ds.profile, ds.transform
        keep = a[:, : int(a.shape[1] * 0.35)]
        prof.update(width=keep.shape[1])
        with rasterio.open(project / "lidar_out/dem.tif", "w", **prof) as dst:
            dst.write(keep, 1)
        culprit = "dem.tif"
    r = run("rectify", project)
    assert r.exit_code == 2 and culprit in r.stderr, r.output
    assert "Traceback" not in r.output
    assert tree(project / "ortho") == before
    assert leftovers(project / "ortho") == []
    r = run("mosaic", project, "--seams", "voronoi")
    assert r.exit_code == 0, r.output


def test_consumers_refuse_frames_that_do_not_match_the_index(project):
    """The state the issue found (new frames beside old ones under a stale index.json): mosaic and check
    refuse it, naming the frame, instead of mosaicking misplaced frames."""
    frames = project / "ortho/frames"
    shutil.copy(frames / "s01_001.tif", frames / "s01_002.tif")  # same name, another frame's content
    before = tree(project / "ortho")
    r = run("mosaic", project)
    assert r.exit_code == 2 and "s01_002.tif" in r.stderr and "index.json" in r.stderr, r.output
    r = run("check", project, "--reference", project / "truth/ortho.tif")
    assert r.exit_code == 2 and "s01_002.tif" in r.stderr, r.output
    assert tree(project / "ortho") == before


def test_an_edited_frame_of_the_same_size_is_refused(project):
    p = project / "ortho/frames/s01_003.tif"
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0xFF
    p.write_bytes(bytes(data))
    r = run("mosaic", project)
    assert r.exit_code == 2 and "s01_003.tif" in r.stderr and "content differs" in r.stderr, r.output


def test_subset_rerun_keeps_the_other_frames(project):
    frames = project / "ortho/frames"
    before = tree(frames)
    inode = {n: (frames / n).stat().st_ino for n in before}
    r = run("rectify", project, "--frames", "s01_002")
    assert r.exit_code == 0, r.output
    index = json.loads((frames / "index.json").read_text())
    assert [e["image_id"] for e in index["frames"]] == ["s01_001", "s01_002", "s01_003", "s02_001", "s02_002",
                                                       "s02_003"]
    after = tree(frames)
    assert {n: h for n, h in after.items() if n != "index.json"} == {n: h for n, h in before.items() if n != "index.json"}
    # the untouched frames came along as hard links (no copy of the data), the re-rectified one is new
    assert (frames / "s01_001.tif").stat().st_ino == inode["s01_001.tif"]
    assert (frames / "s01_002.tif").stat().st_ino != inode["s01_002.tif"]
    assert leftovers(project / "ortho") == []
    r = run("mosaic", project, "--seams", "voronoi")
    assert r.exit_code == 0, r.output
    # a subset on another grid replaces the frames: the index never mixes grids
    r = run("rectify", project, "--frames", "s01_002", "--res-m", "0.4")
    assert r.exit_code == 0, r.output
    index = json.loads((frames / "index.json").read_text())
    assert [e["image_id"] for e in index["frames"]] == ["s01_002"] and index["res_m"] == 0.4
    assert sorted(p.name for p in frames.iterdir()) == ["index.json", "s01_002.tif"]


def test_mosaic_outputs_are_committed_together(project, monkeypatch):
    """A mosaic failing while it blends leaves the previous seams, seamlines, mosaic and summary."""
    import ortho.mosaic as M

    before = tree(project / "ortho")

    def broken(*args, **kwargs):
        raise M.InputError("blending failed")

    monkeypatch.setattr(M, "_write_mosaic", broken)
    with pytest.raises(M.InputError):
        M.mosaic_block(project, M.MosaicSettings(seams="voronoi"))
    assert tree(project / "ortho") == before
    assert leftovers(project / "ortho") == []


def test_check_refuses_seams_of_other_frames(project):
    """ortho check measures seams on ortho/seams.tif: after a new rectify the seams belong to other frames."""
    r = run("rectify", project, "--frames", "s01_002")
    assert r.exit_code == 0, r.output
    r = run("check", project, "--reference", project / "truth/ortho.tif")
    assert r.exit_code == 2 and "seams.tif" in r.stderr and "ortho mosaic" in r.stderr, r.output


def _to_16bit(root, scale=257.0, photometric="RGB"):
    for p in sorted((root / "images").glob("*.tif")):
        img = cv2.cvtColor(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
        a = np.clip(np.rint(np.moveaxis(img, -1, 0).astype(float) * scale), 0, 65535).astype(np.uint16)
        with rasterio.open(p, "w", driver="GTiff", width=a.shape[2], height=a.shape[1], count=3, dtype="uint16",
                           photometric=photometric, compress="deflate") as dst:
            dst.write(a)


def _mean_dn(path):
    with rasterio.open(path) as ds:
        return ds.read(masked=True).reshape(ds.count, -1).mean(axis=1).filled(np.nan)


def test_16bit_mosaic_keeps_the_radiometry(rectified, tmp_path):
    """Frames of identical radiometry (rendered from one orthophoto with the same exposure) in 16 bits
    (x 257), stored as production tools write them: pixel-interleaved RGB, band-interleaved (planar)
    RGB, and 3 samples tagged MINISBLACK - OpenCV garbles the planar 16-bit frame and reads the
    MINISBLACK one as a single grey band. The mosaic keeps the frames' brightness per band and the gains
    stay at 1, as for the 8-bit frames."""
    root = tmp_path / "p16"
    shutil.copytree(rectified, root, ignore=shutil.ignore_patterns("ortho"))
    _to_16bit(root)
    for name, update in (("s01_003.tif", dict(photometric="MINISBLACK")), ("s02_001.tif", dict(interleave="band"))):
        with rasterio.open(root / "images" / name) as ds:
            a, prof = ds.read(), ds.profile
        prof.update(**update)
        with rasterio.open(root / "images" / name, "w", **prof) as dst:
            dst.write(a)
    r = run("rectify", root)
    assert r.exit_code == 0, r.output
    r = run("mosaic", root)
    assert r.exit_code == 0, r.output
    frames = np.array([_mean_dn(p) for p in sorted((root / "ortho/frames").glob("*.tif"))])
    eight = np.array([_mean_dn(p) for p in sorted((rectified / "ortho/frames").glob("*.tif"))]) * 257.0
    np.testing.assert_allclose(frames, eight, rtol=0.002)  # every frame ortho as its 8-bit twin
    mosaic = _mean_dn(root / "ortho/mosaic.tif")
    np.testing.assert_allclose(mosaic, frames.mean(axis=0), rtol=0.01)
    np.testing.assert_allclose(mosaic, _mean_dn(rectified / "ortho/mosaic.tif") * 257.0, rtol=0.005)
    gains = np.array(list(json.loads((root / "ortho/mosaic.json").read_text())["gains"].values()))
    assert np.abs(gains - 1.0).max() < 0.01


def test_limits():
    total = physical_memory_bytes()
    assert total > 0
    check_allocation(total * 0.1, "a small array", "--opt")
    with pytest.raises(ResourceError) as e:
        check_allocation(total * 2, "the ortho", "--res-m")
    assert "--res-m" in e.value.user_message() and "GiB" in str(e.value)
    with pytest.raises(ResourceError):
        check_grid(3e9, 10, "a grid", "--res-m")
    with pytest.raises(ResourceError):
        check_grid(0, 10, "a grid")


@pytest.mark.parametrize("args, option", [
    (["rectify", "{p}", "--res-m", "0.0005"], "--res-m"),
    (["mosaic", "{p}", "--tile-px", "1000000"], "--tile-px"),
    (["check", "{p}", "--reference", "{p}/truth/ortho.tif", "--patch-px", "400000"], "--patch-px"),
])
def test_sizes_beyond_the_machine_stop_before_allocating(project, args, option):
    before = tree(project / "ortho")
    r = run(*[a.format(p=project) for a in args])
    assert r.exit_code == 2 and option in r.stderr and "memory" in r.stderr, r.output
    assert tree(project / "ortho") == before


def _readjusted(root, dx_m=0.8):
    """at/eo.txt as a new adjustment leaves it: frame s01_002 moved by ``dx_m`` in X."""
    from aerotri.geom.eo import read_eo, write_eo

    eo = read_eo(root / "at/eo.txt")
    eo.centre_m[eo.row("s01_002"), 0] += dx_m
    write_eo(root / "at/eo.txt", eo)


def test_index_records_the_inputs_of_the_frames(project):
    index = json.loads((project / "ortho/frames/index.json").read_text())
    rec = index["inputs"]
    assert rec["eo"]["file"] == "at/eo.txt" and rec["dem"]["file"] == "lidar_out/dem.tif"
    assert rec["eo"]["sha256"] == hashlib.sha256((project / "at/eo.txt").read_bytes()).hexdigest()
    assert rec["dem"]["sha256"] == hashlib.sha256((project / "lidar_out/dem.tif").read_bytes()).hexdigest()
    assert len(rec["camera"]["sha256"]) == 64


def test_index_names_its_files_relative_to_the_project_whatever_the_working_folder(project, monkeypatch):
    """Trial "overnight" L9: the index recorded the DEM as the caller named it ("term/lidar_out/dem.tif"), so two
    runs of one project from two folders wrote two different indexes."""
    monkeypatch.chdir(project.parent)
    shutil.rmtree(project / "ortho")
    r = run("rectify", project.name)
    assert r.exit_code == 0, r.output
    index = json.loads((project / "ortho/frames/index.json").read_text())
    assert index["dem"] == "lidar_out/dem.tif" and index["eo"] == "at/eo.txt"


def test_frames_of_an_older_adjustment_are_refused(project):
    """The trial's state: ortho rectify, then a new adjustment rewrites at/eo.txt; mosaic, check and the QA
    report must not take the frames of the old orientation."""
    from aerotri.qa.report import build_qa_report

    r = run("check", project, "--reference", project / "truth/ortho.tif", "--patch-px", "24", "--search-px", "4")
    assert r.exit_code == 0, r.output
    assert not build_qa_report(project).has("dom_stale")
    _readjusted(project)
    before = tree(project)
    r = run("mosaic", project, "--seams", "voronoi")
    assert r.exit_code == 2, r.output
    assert all(s in r.stderr for s in ("index.json", "eo.txt", "ortho rectify")), r.stderr
    r = run("check", project, "--reference", project / "truth/ortho.tif")
    assert r.exit_code == 2 and "eo.txt" in r.stderr and "ortho rectify" in r.stderr, r.output
    assert tree(project) == before  # nothing written
    rep = build_qa_report(project)
    stale = rep.check("dom_stale")
    assert stale.quantity == "DOM from an older adjustment" and stale.verdict == "fail" and "eo.txt" in stale.note
    assert rep.overall == "fail"
    # after a new rectify the chain goes on
    assert run("rectify", project).exit_code == 0
    r = run("mosaic", project, "--seams", "voronoi")
    assert r.exit_code == 0, r.output


def test_the_report_does_not_take_a_dom_check_of_an_earlier_mosaic(project):
    """The overnight trial's state: a DOM check, then the mosaic made again (another setting, a new adjustment, or
    `aerotri run` without --reference, which re-mosaics but does not re-check); the report judged the new DOM by
    the old dom_report.json ("pass", 0.097 m on the demo) without a word. Now a failed row names both files and the
    compliance statement has no DOM figure; a check of the new mosaic is taken again."""
    from aerotri.qa.compliance import project_figures
    from aerotri.qa.report import build_qa_report
    from aerotri.core.project import Project

    r = run("check", project, "--reference", project / "truth/ortho.tif", "--patch-px", "24", "--search-px", "4")
    assert r.exit_code == 0, r.output
    rep = build_qa_report(project)
    assert rep.has("dom_rms_xy_m") and not rep.has("dom_check_stale")
    assert project_figures(Project.open(project)).dom.rmse_h_m is not None
    r = run("mosaic", project, "--seams", "voronoi", "--feather-m", "3")  # the mosaic made again, other pixels
    assert r.exit_code == 0, r.output
    rep = build_qa_report(project)
    stale = rep.check("dom_check_stale")
    assert stale.verdict == "fail" and "dom_report.json" in stale.note and "mosaic.tif" in stale.note, stale.note
    assert not rep.has("dom_rms_xy_m") and not rep.has("seam_misalignment_rms_px") and rep.overall == "fail"
    dom = project_figures(Project.open(project)).dom
    assert dom.rmse_h_m is None and "earlier mosaic" in dom.note
    r = run("check", project, "--reference", project / "truth/ortho.tif", "--patch-px", "24", "--search-px", "4")
    assert r.exit_code == 0, r.output
    rep = build_qa_report(project)
    assert rep.has("dom_rms_xy_m") and not rep.has("dom_check_stale")


def test_a_subset_rerun_after_a_readjustment_does_not_keep_the_old_frames(project):
    _readjusted(project)
    r = run("rectify", project, "--frames", "s01_002")
    assert r.exit_code == 0, r.output
    index = json.loads((project / "ortho/frames/index.json").read_text())
    assert [e["image_id"] for e in index["frames"]] == ["s01_002"]


def test_an_index_of_an_earlier_version_is_accepted_with_a_warning(project, caplog):
    path = project / "ortho/frames/index.json"
    index = json.loads(path.read_text())
    del index["inputs"]
    path.write_text(json.dumps(index))
    _readjusted(project)  # cannot be seen without the record
    with caplog.at_level("WARNING"):
        r = run("mosaic", project, "--seams", "voronoi")
    assert r.exit_code == 0, r.output
    assert any("index.json" in m and "earlier version" in m for m in caplog.messages), caplog.messages


def test_an_unchanged_dem_is_not_hashed_again(project, monkeypatch):
    """A re-run takes the DEM's sha256 from the index when the file has the recorded size and modification
    time (a block's DEM runs to gigabytes); a DEM touched or changed since is hashed again."""
    import ortho.block

    hashed = []
    sha256 = ortho.block.file_sha256
    monkeypatch.setattr(ortho.block, "file_sha256", lambda p: hashed.append(os.path.basename(p)) or sha256(p))
    dem = project / "lidar_out/dem.tif"

    def recorded():
        return json.loads((project / "ortho/frames/index.json").read_text())["inputs"]["dem"]

    before = recorded()
    r = run("rectify", project, "--frames", "s01_001")
    assert r.exit_code == 0, r.output
    assert "dem.tif" not in hashed and recorded() == before
    st = dem.stat()
    os.utime(dem, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # touched, same contents
    r = run("rectify", project, "--frames", "s01_001")
    assert r.exit_code == 0, r.output
    assert hashed.count("dem.tif") == 1 and recorded()["sha256"] == before["sha256"]
    with rasterio.open(dem, "r+") as ds:
        ds.write(ds.read(1) + np.float32(0.5), 1)
    r = run("rectify", project, "--frames", "s01_001")
    assert r.exit_code == 0, r.output
    assert hashed.count("dem.tif") == 2
    assert recorded()["sha256"] == hashlib.sha256(dem.read_bytes()).hexdigest() != before["sha256"]


def test_a_rerun_resumes_the_frames_an_interrupted_run_finished(project, monkeypatch):
    """A rectify stopped part-way (here: Ctrl-C in the fourth frame's task; a kill leaves the frames finished
    before it) keeps the frames it finished in work/rectify_resume; the next run takes them and rectifies only the others, into the same frame
    orthos as one uninterrupted run, and clears the folder when it commits."""
    import ortho.block as B

    before = tree(project / "ortho" / "frames")
    first_frames = json.loads((project / "ortho" / "frames" / "index.json").read_text())["frames"]
    calls = []
    real = B._rectify_frame

    def breaks_at_the_fourth(task):
        calls.append(task.image_id)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return real(task)

    monkeypatch.setattr(B, "_rectify_frame", breaks_at_the_fourth)
    r = run("rectify", project, "--workers", 1)
    assert r.exit_code != 0, r.output
    assert tree(project / "ortho" / "frames") == before  # the stage's output: all or none
    kept = sorted(p.name for p in (project / "work" / "rectify_resume").iterdir())
    finished = len(kept) // 2  # each frame: its ortho and its index entry (the other tasks run to their end)
    assert 3 <= finished <= 5 and len(kept) == 2 * finished, kept
    calls.clear()
    monkeypatch.setattr(B, "_rectify_frame", lambda task: (calls.append(task.image_id), real(task))[1])
    r = run("rectify", project, "--workers", 1)
    assert r.exit_code == 0, r.output
    assert len(calls) == 6 - finished, calls  # only the frames the first run did not finish
    assert f"resumed {finished} of 6 frames" in r.stderr, r.stderr
    after = tree(project / "ortho" / "frames")
    before.pop("index.json"), after.pop("index.json")  # (the fixture's index names the fixture's paths)
    assert after == before  # the same frame orthos as the uninterrupted run, byte for byte
    frames_now = json.loads((project / "ortho" / "frames" / "index.json").read_text())["frames"]
    assert frames_now == first_frames  # and the same index entries
    assert not (project / "work" / "rectify_resume").exists()
    calls.clear()
    r = run("rectify", project, "--workers", 1)  # committed: a new run starts from the beginning
    assert r.exit_code == 0, r.output
    assert len(calls) == 6, calls



def test_frames_kept_before_a_rectification_change_are_rectified_again(project, monkeypatch):
    """resume-keys: a frame's key held the toolkit's version (0.1.0, never bumped) only, so frame orthos kept before a
    change of the rectification were reused after it. ``ortho.rectify.RECTIFY_VERSION`` is in the key: bumped, no
    frame resumes; the same version resumes the frames it kept."""
    import ortho.block as B
    import ortho.rectify

    before = tree(project / "ortho" / "frames")
    calls = []
    real = B._rectify_frame

    def breaks_at_the_fourth(task):
        calls.append(task.image_id)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return real(task)

    monkeypatch.setattr(B, "_rectify_frame", breaks_at_the_fourth)
    assert run("rectify", project, "--workers", 1).exit_code != 0
    finished = len(list((project / "work" / "rectify_resume").glob("*.tif")))
    assert 3 <= finished <= 5
    # (the project's own CRS: its version is PROJECT_CRS_RECTIFY_VERSION; a contract grid's RECTIFY_VERSION)
    monkeypatch.setattr(ortho.rectify, "PROJECT_CRS_RECTIFY_VERSION", ortho.rectify.PROJECT_CRS_RECTIFY_VERSION + 1)
    calls.clear()
    r = run("rectify", project, "--workers", 1)
    # a resume would have left 6 - finished frames to rectify: the kept ones are rectified again
    assert r.exit_code != 0 and "resumed" not in r.stderr and len(calls) >= 4 > 6 - finished, calls
    bumped = len(list((project / "work" / "rectify_resume").glob("*.tif"))) - finished
    assert 3 <= bumped <= 5
    calls.clear()
    monkeypatch.setattr(B, "_rectify_frame", lambda task: (calls.append(task.image_id), real(task))[1])
    r = run("rectify", project, "--workers", 1)  # the same (bumped) version: its frames resume
    assert r.exit_code == 0, r.output
    assert len(calls) == 6 - bumped and f"resumed {bumped} of 6 frames" in r.stderr, r.stderr
    after = tree(project / "ortho" / "frames")
    before.pop("index.json"), after.pop("index.json")
    assert after == before

def test_an_error_leaves_no_frames_kept_for_a_resume(project, monkeypatch):
    """An error (bad input, a bad frame) leaves nothing behind, not even the frames kept for a resumed run: only a
    kill or Ctrl-C keeps them."""
    import ortho.block as B

    real, calls = B._rectify_frame, []

    def fails_at_the_fourth(task):
        calls.append(task.image_id)
        if len(calls) == 4:
            raise B.InputError(f"{task.image_id}: broken on purpose")
        return real(task)

    monkeypatch.setattr(B, "_rectify_frame", fails_at_the_fourth)
    before = tree(project)
    r = run("rectify", project, "--workers", 1)
    assert r.exit_code == 2 and "broken on purpose" in r.stderr, r.output
    assert tree(project) == before
    assert not (project / "work" / "rectify_resume").exists()


def test_a_dsm_changed_since_the_true_ortho_is_said(project, caplog):
    """trial-rerun: index.json recorded the EO, camera and DEM, so `ortho mosaic` said a DEM changed since the frames
    but nothing of a true ortho's DSM (lidarctl rasters run again by hand): the DSM is recorded and said the same."""
    import rasterio

    dsm = project / "dsm.tif"
    shutil.copy(project / "truth" / "dsm.tif", dsm)
    r = run("rectify", project, "--true-ortho", "--dsm", dsm)
    assert r.exit_code == 0, r.output
    rec = json.loads((project / "ortho/frames/index.json").read_text())["inputs"]
    assert rec["dsm"]["file"] == "dsm.tif" and "occlusion_dsm" not in rec
    with caplog.at_level("WARNING"):
        assert run("mosaic", project, "--seams", "voronoi").exit_code == 0
    assert not any("rectified on another" in m for m in caplog.messages), caplog.messages
    with rasterio.open(dsm, "r+") as ds:  # the DSM made again, 1 m higher
        ds.write(ds.read(1) + 1.0, 1)
    caplog.clear()
    with caplog.at_level("WARNING"):
        r = run("mosaic", project, "--seams", "voronoi")
    assert r.exit_code == 0, r.output
    assert any("rectified on another DSM than" in m and "dsm.tif" in m for m in caplog.messages), caplog.messages
    assert not any("another DEM" in m for m in caplog.messages)
    # and the accuracy report says it in a row (trial-upgrade F4: only the console did), not judged
    from aerotri.qa.report import build_qa_report

    r = run("check", project, "--reference", project / "truth/ortho.tif", "--patch-px", "24", "--search-px", "4")
    assert r.exit_code == 0, r.output
    rep = build_qa_report(project)
    row = rep.check("dom_surface_changed")
    assert row.verdict is None and "dsm.tif (DSM) changed since the frames were rectified" in row.note
    assert not rep.has("dom_stale")


def test_the_staleness_check_compares_the_camera_without_judging_it_again(project, monkeypatch):
    """``ortho mosaic`` / ``ortho check`` read the camera only to compare it with the one the frames were rectified
    with: its plausibility check (a lens fold search that loads the compiled lens kernels, 0.7 of the demo mosaic's
    4.3 CPU-s) is not run again; a camera changed since is still refused."""
    from aerotri.geom.camera import Camera
    from ortho.block import read_index, stale_frames

    def judged(self, *args, **kwargs):
        raise AssertionError("check_plausible called")

    monkeypatch.setattr(Camera, "check_plausible", judged)
    assert stale_frames(project, read_index(project)) is None
    monkeypatch.undo()
    cam = project / "at" / "camera.toml" if (project / "at" / "camera.toml").is_file() else project / "camera.toml"
    text = cam.read_text()
    focal = next(line for line in text.splitlines() if line.startswith("focal_mm"))
    cam.write_text(text.replace(focal, f"focal_mm = {float(focal.split('=')[1]) * 1.01!r}"))
    r = run("mosaic", project, "--seams", "voronoi")
    assert r.exit_code == 2 and "another camera" in r.stderr and "ortho rectify" in r.stderr, r.output


def test_a_frame_the_seams_give_no_cell_is_named_in_mosaic_json(project):
    """Trial-gis F4: the demo's mosaic.json listed 18 frames and seamlines.gpkg 17 polygons (s01_005 had no cell),
    nothing said. mosaic.json names such frames (``frames_without_cells``, and an info line: on the demo
    "1 of 18 frames have no cell of the mosaic ...: s01_005"); here every frame has its cell and polygon."""
    import pyogrio

    from ortho.mosaic import frames_without_cells

    labels = np.array([[0, 0, 2], [-1, 2, 2]], np.int32)
    assert frames_without_cells(labels, ["a", "b", "c", "d"]) == ["b", "d"]
    summary = json.loads((project / "ortho" / "mosaic.json").read_text())
    assert summary["frames_without_cells"] == []
    from ortho.mosaic import read_mosaic_summary

    assert read_mosaic_summary(project / "ortho" / "mosaic.json").frames_without_cells == ()
    assert pyogrio.read_info(project / "ortho" / "seamlines.gpkg")["features"] == summary["frames"]
