"""Tie-point matching on the simulated tiny block, caching, and refusal of bad inputs."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_main
from aerotri.match import match_project
from aerotri.match.pairs import candidate_pairs, plan_block
from aerotri.match.tracks import build_tracks
from aerotri.sim.evaluate import tie_point_errors


@pytest.fixture(scope="module")
def matched(tiny_project, tmp_path_factory):
    """A private copy of the tiny project (inputs only) with tie points matched once."""
    p = tmp_path_factory.mktemp("match") / "tiny"
    shutil.copytree(tiny_project, p)
    rep = match_project(p)
    return p, rep


def test_tiny_block_is_connected_and_accurate(matched):
    p, rep = matched
    assert rep.components == 1
    assert rep.pairs_by_kind["along"] == 4 and rep.pairs_by_kind["second"] == 2 and rep.pairs_by_kind["cross"] >= 3
    # Not exhaustive: fewer pairs than all 15 combinations of 6 frames.
    assert rep.pairs < 15
    assert rep.tracks_3plus_fraction >= 0.15
    assert all(not c.weak for c in rep.cross_strip)
    assert all(min(min(r) for r in m.regions) >= 3 for m in rep.models)
    err = tie_point_errors(p)
    assert err.observations == rep.observations > 2000
    assert err.off_fraction < 0.01
    assert err.median_residual_px < 0.25
    assert (p / "at" / "connectivity.png").stat().st_size > 10_000


def test_rerun_reuses_cached_features_and_matches(matched):
    p, rep = matched
    again = match_project(p)
    assert again.feature_cache_hits == again.frames
    assert again.match_cache_hits >= again.pairs_with_ties
    assert (p / "at" / "tiepoints.csv").read_text().count("\n") == rep.observations + 1


def test_track_completion_adds_true_observations_to_the_same_tracks(matched):
    """Without completion (same cached matches) the block has the same tracks with fewer observations and a
    lower share in 3+ frames; what completion added is as true as what matching found."""
    import dataclasses

    from aerotri.match import MatchSettings

    p, rep = matched
    with_c = tie_point_errors(p)
    plain = match_project(p, dataclasses.replace(MatchSettings(), complete_px=0.0))
    without = tie_point_errors(p)
    assert plain.tracks == rep.tracks and plain.observations < rep.observations
    assert plain.tracks_3plus_fraction < rep.tracks_3plus_fraction
    added = rep.observations - plain.observations
    assert with_c.off_count - without.off_count <= max(1, 0.02 * added)
    match_project(p)  # the module's copy as the other tests expect it
    # the stage's phases, wall and CPU seconds, add up to its time
    ph = rep.phase_seconds
    assert list(ph) == ["plan", "features", "matching", "tracks", "densify", "output"]
    assert all(w >= 0 and c >= 0 for w, c in ph.values())
    assert sum(w for w, _ in ph.values()) <= rep.seconds + 0.01


def test_tracks_drop_inconsistent_chains():
    # Image 0 kp 0 <-> image 1 kp 0 <-> image 2 kp 0 <-> image 0 kp 1: image 0 twice -> dropped.
    m01 = np.array([[0, 0], [2, 2]])
    m12 = np.array([[0, 0], [2, 2]])
    m20 = np.array([[0, 1]])
    track, image, kp, bad = build_tracks([3, 3, 3], [(0, 1, m01), (1, 2, m12), (2, 0, m20)])
    assert bad == 1
    assert len(np.unique(track)) == 1 and sorted(image.tolist()) == [0, 1, 2] and set(kp.tolist()) == {2}


def test_pairs_follow_the_footprints():
    from aerotri.geom.camera import dmc_camera

    cam = dmc_camera()
    # Two strips flown east and west at 1000 m, base 300 m, strips 1000 m apart.
    pos = [(x, 0.0, 1000.0) for x in (0, 300, 600, 900)] + [(x, 1000.0, 1000.0) for x in (900, 600, 300, 0)]
    ids = [f"a{i}" for i in range(4)] + [f"b{i}" for i in range(4)]
    plan = plan_block(ids, np.array(pos), cam, [0, 0, 0], 0.0)
    assert plan.strip.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    assert np.allclose(plan.kappa_deg[:4], -90) and np.allclose(plan.kappa_deg[4:], 90)
    pairs = candidate_pairs(plan)
    kinds = {(ids[p.i], ids[p.j]): p.kind for p in pairs}
    assert kinds[("a0", "a1")] == "along" and kinds[("a0", "a2")] == "second"
    assert ("a0", "a3") not in kinds  # 900 m apart with a 768 m footprint: no overlap
    assert kinds[("a0", "b3")] == "cross"


def test_a_portrait_sensor_flies_with_its_long_side_across_track():
    """The same DMC frame stored portrait (turned by 90 degrees): without an option the plan turns its top
    90 degrees from the flight direction, so its footprints are the landscape frame's and so are the pairs."""
    from aerotri.geom.camera import BrownCamera, dmc_camera

    land = dmc_camera()
    portrait = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=7680, height=13824, name="DMC portrait")
    pos = np.array([(x, 0.0, 1000.0) for x in (0, 300, 600, 900)] + [(x, 1000.0, 1000.0) for x in (900, 600, 300, 0)])
    ids = [f"a{i}" for i in range(4)] + [f"b{i}" for i in range(4)]
    a, b = plan_block(ids, pos, land, [0, 0, 0], 0.0), plan_block(ids, pos, portrait, [0, 0, 0], 0.0)
    assert a.image_top_deg == 0.0 and b.image_top_deg == 90.0
    for fa, fb in zip(a.footprints, b.footprints):
        assert fa.symmetric_difference(fb).area < 1e-6 * fa.area
    assert [(q.i, q.j, q.kind) for q in candidate_pairs(a)] == [(q.i, q.j, q.kind) for q in candidate_pairs(b)]
    # an explicit value wins
    assert plan_block(ids, pos, portrait, [0, 0, 0], 0.0, image_top_deg=270.0).image_top_deg == 270.0


def test_match_command_reads_the_project_match_section(matched, tmp_path):
    """``aerotri match`` takes project.toml [match] (as ``aerotri run`` does); a command-line option wins."""
    import json

    p = shutil.copytree(matched[0], tmp_path / "p")
    with open(p / "project.toml", "a") as f:
        f.write("\n[match]\nimage_top_deg = 180.0\nmin_overlap = 0.2\n")
    res = CliRunner().invoke(aerotri_main, ["match", str(p)])
    assert res.exit_code == 0, res.output
    assert json.loads((p / "at" / "connectivity.json").read_text())["image_top_deg"] == 180.0
    res = CliRunner().invoke(aerotri_main, ["match", str(p), "--image-top-deg", "0"])
    assert res.exit_code == 0, res.output
    assert json.loads((p / "at" / "connectivity.json").read_text())["image_top_deg"] == 0.0
    with open(p / "project.toml", "a") as f:
        f.write("densfy = true\n")  # a misspelt key is refused, naming the file and section
    res = CliRunner().invoke(aerotri_main, ["match", str(p)])
    assert res.exit_code == 2 and "[match]" in res.output and "densfy" in res.output


def _copy_inputs(src, dst):
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("at", "work", "truth"))
    return dst


def _rewrite_frame(path, bands=None, dtype=None):
    """The frame at ``path`` rewritten with only ``bands`` (1-based) and/or in ``dtype`` (8 -> 16 bit: x 257)."""
    import rasterio

    with rasterio.open(path) as ds:
        a, profile = ds.read(bands), ds.profile
    if dtype is not None:
        a = a.astype(dtype) * 257
    profile.update(count=a.shape[0], dtype=a.dtype.name, photometric="minisblack" if a.shape[0] == 1 else "rgb")
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(a)


@pytest.mark.parametrize("case", ["unreadable", "one_band", "sixteen_bit", "missing_image", "missing_gnss",
                                  "gnss_id_typo", "gnss_csv", "gnss_header", "no_camera",
                                  "pixels_focal", "no_overlap"])
def test_bad_inputs_name_the_culprit(tiny_project, tmp_path, case):
    p = _copy_inputs(tiny_project, tmp_path / "p")
    if case == "unreadable":
        (p / "images" / "s01_002.tif").write_bytes(b"II*\x00garbage")
        expect = "s01_002.tif: cannot read the image"
        assert "take it out of images/ (and its line out of gnss.txt) to go on without it" in \
            CliRunner().invoke(aerotri_main, ["match", str(p)]).output
    elif case == "missing_image":  # a bad frame taken out of images/: the error says how to go on without it
        (p / "images" / "s02_003.tif").unlink()
        expect = "no image file for GNSS record(s) s02_003 of"
        assert "take their lines out of gnss.txt" in CliRunner().invoke(aerotri_main, ["match", str(p)]).output
    elif case == "one_band":  # a grey frame among colour ones: the chain's mosaic stopped on it with a traceback
        _rewrite_frame(p / "images" / "s01_002.tif", bands=[1])
        expect = "s01_002.tif: 1 band of uint8, but s01_001.tif has 3 bands of uint8"
    elif case == "sixteen_bit":  # a 16-bit frame among 8-bit ones
        _rewrite_frame(p / "images" / "s01_002.tif", dtype=np.uint16)
        expect = "s01_002.tif: 3 bands of uint16, but s01_001.tif has 3 bands of uint8"
    elif case == "missing_gnss":
        lines = (p / "gnss.txt").read_text().splitlines()
        (p / "gnss.txt").write_text("\n".join(l for l in lines if not l.startswith("s02_003")) + "\n")
        expect = "no GNSS position for frame(s) s02_003"
    elif case == "gnss_id_typo":  # trial s94: the record of a typo'd id was not named
        text = (p / "gnss.txt").read_text()
        (p / "gnss.txt").write_text(text.replace("s02_003 ", "s02_03 ", 1))
        expect = "no GNSS position for frame(s) s02_003; its records of no frame: s02_03 (a typo in an id?)"
    elif case in ("gnss_csv", "gnss_header"):  # trial s94: a CSV export with its header read "got 1 fields"
        lines = (p / "gnss.txt").read_text().splitlines()
        if case == "gnss_csv":
            (p / "gnss.txt").write_text("\n".join(",".join(l.split()) for l in lines) + "\n")
            expect = "this line has commas (a CSV: replace them)"
        else:
            (p / "gnss.txt").write_text("\n".join(["image_id x y z", *lines]) + "\n")
            expect = "gnss.txt:1: non-numeric value in 'image_id x y z'"
            assert "a header line? start it with # (a comment)" in \
                CliRunner().invoke(aerotri_main, ["match", str(p)]).output
    elif case == "no_camera":  # trial s94: "file not found" alone
        (p / "camera.toml").unlink()
        expect = "aerotri init printed a template"
    elif case == "pixels_focal":
        cam = (p / "camera.toml").read_text().replace("focal_mm = 120.0", "focal_mm = 312.5")
        cam = cam.replace("pixel_um = 384.0", "pixel_um = 1.0")
        cam = cam.replace("focal_mm = 312.5", "focal_mm = 312500.0")
        (p / "camera.toml").write_text(cam)
        expect = "not a plausible focal length in millimetres"
    else:
        lines = (p / "gnss.txt").read_text().splitlines()
        out = [lines[0]]
        for k, l in enumerate(lines[1:]):
            f = l.split()
            f[1] = f"{float(f[1]) + 5000.0 * k:.4f}"
            out.append(" ".join(f))
        (p / "gnss.txt").write_text("\n".join(out) + "\n")
        expect = "no two frames overlap"  # with the footprints' size and the frames' spacing (s95)
    res = CliRunner().invoke(aerotri_main, ["match", str(p)])
    assert res.exit_code == 2, res.output
    assert expect in res.output
    if expect == "no two frames overlap":
        assert "(footprints about " in res.output and " apart, in the project CRS's units)" in res.output
    assert not (p / "at" / "tiepoints.csv").exists()


def test_gnss_without_a_terrain_height_pairs_by_retrieval(tiny_project, tmp_path):
    """A drone block as `aerotri import --format exif` leaves it: gnss.txt but no terrain height ([flight], a DEM):
    the footprints cannot be placed, so the pairs come from thumbnail retrieval (as for a block without GNSS),
    with a warning saying so and how to pair by footprints; the tie points are as true as with the footprints."""
    import re

    p = shutil.copytree(tiny_project, tmp_path / "p", ignore=shutil.ignore_patterns("at", "work"))
    toml = (p / "project.toml").read_text()
    (p / "project.toml").write_text(re.sub(r"(?m)^mean_terrain_height_m = .*$", "", toml))
    assert not (p / "lidar_out" / "dem.tif").exists()
    res = CliRunner().invoke(aerotri_main, ["match", str(p)])
    assert res.exit_code == 0, res.output
    assert "no terrain height for the GNSS footprints" in res.output and "thumbnail retrieval of all 15 pairs" in res.output
    err = tie_point_errors(p)
    assert err.observations > 1500
    assert err.off_fraction < 0.01 and err.median_residual_px < 0.25


def test_weak_models_are_said_in_words(tiny_project, tmp_path):
    """Brighton's "12 weak models" came with no word of what they are: the console names the weak models, why
    (where their overlap lacks ties) and what it means for the adjustment. Every model of the tiny block made
    weak by its own [match] min_per_region (more ties a region than it has)."""
    p = shutil.copytree(tiny_project, tmp_path / "p", ignore=shutil.ignore_patterns("at", "work"))
    with open(p / "project.toml", "a") as f:
        f.write("\n[match]\nmin_per_region = 100000\n")
    res = CliRunner().invoke(aerotri_main, ["match", str(p), "--no-densify"])
    assert res.exit_code == 0, res.output
    rep = json.loads((p / "at" / "connectivity.json").read_text())
    n = len(rep["models"])
    assert n >= 2 and len(rep["weak_models"]) == n
    assert f"{n} of {n} stereo models (the pairs of consecutive frames of a strip, of all the pairs matched) are weak: fewer than 100000 tie points" in res.output
    left, right = rep["weak_models"][0]
    ties = next(m["ties"] for m in rep["models"] if (m["left"], m["right"]) == (left, right))
    assert f"  {left}-{right}: {ties} ties, under 100000 in every region" in res.output
    assert ("more (at/connectivity.json weak_models" in res.output) == (n > 4) and "relative orientation" in res.output


def test_weak_model_words_say_where_the_ties_are_missing():
    """The regions of Brighton's models (at/connectivity.json of the trial): ties in the right third across the
    base only; ties missing along the base; scattered short regions; none weak, no words."""
    from aerotri.match.weak import ModelStrength, weak_model_words

    def model(regions):
        flat = [v for r in regions for v in r]
        return ModelStrength("a", "b", 0, 1, sum(flat), regions, min(flat) < 3)

    across = model([[49, 58, 52], [0, 0, 0], [0, 0, 0]])
    along = model([[0, 40, 40], [1, 40, 40], [2, 40, 40]])
    scattered = model([[0, 0, 0], [50, 5, 0], [8, 0, 0]])
    strong = model([[9, 9, 9]] * 3)
    lines = weak_model_words([across, along, scattered, strong], 2, 3, show=2)
    assert lines[0].startswith("3 of 4 stereo models") and "after 2 were matched again" in lines[0]
    assert lines[1] == "  a-b: 159 ties, under 3 in the middle and left thirds across the base"
    assert lines[2] == "  a-b: 243 ties, under 3 in the first third along the base"
    assert lines[3] == "  ... and 1 more (at/connectivity.json weak_models, red in connectivity.png)"
    assert weak_model_words([scattered], 0, 3)[1] == "  a-b: 63 ties, 6 of 9 regions under 3"
    assert weak_model_words([strong], 0, 3) == []


def test_a_block_in_unconnected_parts_is_warned_by_match(matched, tmp_path, monkeypatch, caplog):
    """New-user trial s51: NGI without its terrain height matched into 2 parts that no tie point connects; `aerotri
    match` said "2 component(s)" at info level and only `aerotri adjust` warned. Match now warns, naming the parts."""
    import logging

    from aerotri.match import pipeline

    p = tmp_path / "tiny"
    shutil.copytree(matched[0], p)
    real = pipeline._components

    def split(project, ids, ties_per_pair):
        whole = real(project, ids, ties_per_pair)[0]
        return [whole[:3], whole[3:]]

    monkeypatch.setattr(pipeline, "_components", split)
    with caplog.at_level(logging.WARNING, logger="aerotri.match.pipeline"):
        rep = match_project(p)
    assert rep.components == 2
    warned = [r.getMessage() for r in caplog.records if "falls apart into 2 parts" in r.getMessage()]
    assert len(warned) == 1 and "mean_terrain_height_m" in warned[0], caplog.text


def _ties_seen_turned(plan, camera, true_top_deg, step_px=2):
    """Tie observations (track, image, xy) of neighbouring frames of ``plan``'s strips for frames whose image top is
    really ``true_top_deg`` from the flight direction (nominal attitude, flat terrain): points of the first frame
    found on the second by the nearest ground position of a pixel grid of it (within one grid step on the ground)."""
    from scipy.spatial import cKDTree

    from aerotri.match.pairs import flat_ground_xy

    turn = true_top_deg - plan.image_top_deg
    gx, gy = np.meshgrid(np.arange(0, camera.width, step_px, dtype=float), np.arange(0, camera.height, step_px,
                                                                                       dtype=float))
    grid = np.c_[gx.ravel(), gy.ravel()]
    rng = np.random.default_rng(3)
    track, image, xy, t = [], [], [], 0
    for a in range(len(plan.image_id) - 1):
        b = a + 1
        if plan.strip[a] != plan.strip[b]:
            continue
        def ground(k, p):
            return flat_ground_xy(plan.centre_m[k], plan.kappa_deg[k] + turn, plan.terrain_height_m, camera, p)
        pa = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], size=(400, 2))
        gb = ground(b, grid)
        dist, k = cKDTree(gb).query(ground(a, pa))
        ok = dist < np.hypot(*(gb[1] - gb[0])) * 1.5
        for p, q in zip(pa[ok], grid[k[ok]]):
            track += [t, t]
            image += [a, b]
            xy += [p, q]
            t += 1
    return np.array(track), np.array(image), np.array(xy)


def test_the_tie_points_tell_a_portrait_camera_flown_with_its_long_side_along_track():
    """Trial s97 M3: a camera turned 90 deg in the aircraft (portrait frames, long side along track) was planned with
    its top across the flight (the default from the frame's shape): half the ties, every stereo model weak, and the
    report blamed water or snow. The ties' ground positions between neighbouring frames agree only turned back."""
    from aerotri.geom.camera import BrownCamera
    from aerotri.match.image_top import image_top_check

    cam = BrownCamera(focal_mm=50.0, pixel_um=40.0, width=240, height=320, name="turned")
    # one strip east at 1000 m over flat ground at 0: footprint 192 x 256 m, long side along track, base 100 m
    pos = np.array([(x, 0.0, 1000.0) for x in (0, 100, 200, 300, 400)])
    ids = [f"a{i}" for i in range(5)]
    planned = plan_block(ids, pos, cam, [0, 0, 0], 0.0)
    assert planned.image_top_deg == 90.0
    check = image_top_check(planned, cam, *_ties_seen_turned(planned, cam, true_top_deg=0.0))
    assert check.wrong and check.pairs == 4, check
    assert check.misfit_m[0.0] > 50.0 and check.misfit_m[check.best_turn_deg] < 2.0, check
    assert "image top at 0 deg from the flight direction, not the 90 deg" in check.text()
    assert "[match] image_top_deg = 0 in project.toml (aerotri run), or give aerotri match --image-top-deg 0," \
        in check.text()
    # planned right: nothing to say
    right = plan_block(ids, pos, cam, [0, 0, 0], 0.0, image_top_deg=0.0)
    check = image_top_check(right, cam, *_ties_seen_turned(right, cam, true_top_deg=0.0))
    assert not check.wrong and check.misfit_m[0.0] < 2.0, check


def test_the_flight_plan_takes_the_frames_in_image_id_order_whatever_the_order_of_gnss_txt(tiny_project, tmp_path):
    """Trial s97 M5: a frame's line put back at the end of gnss.txt broke its strip in two (a false weak model,
    16,623 tracks for 17,053): the plan takes the frames in image-id order, as the adjustment does."""
    from aerotri.core.project import Project
    from aerotri.geom.camera import project_camera
    from aerotri.geom.eo import check_block_crs
    from aerotri.match.pipeline import _read_frames
    from aerotri.match.settings import MatchSettings

    p = tmp_path / "p"
    shutil.copytree(tiny_project, p)
    project = Project.open(p)
    cam, crs = project_camera(project), check_block_crs(project.crs, "crs")
    before = _read_frames(project, crs, cam, MatchSettings())
    lines = (p / "gnss.txt").read_text().splitlines()
    body = [x for x in lines if not x.startswith("#")]
    moved = body[2:] + body[:2]  # two frames of the first strip appended at the end
    (p / "gnss.txt").write_text("\n".join([x for x in lines if x.startswith("#")] + moved) + "\n")
    after = _read_frames(Project.open(p), crs, cam, MatchSettings())
    assert after.ids == before.ids == sorted(before.ids)
    assert after.plan.strip.tolist() == before.plan.strip.tolist()
    assert np.allclose(after.plan.centre_m, before.plan.centre_m)
