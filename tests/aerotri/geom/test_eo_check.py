"""Approximate orientations that cannot be right (aerotri.geom.eo_check): kappa errors read from the tie points of
a simulated block against its truth; the adjustment and ``ortho rectify --eo`` name the frames."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import ExteriorOrientations, read_eo, write_eo
from aerotri.geom.eo_check import KAPPA_LIMIT_DEG, ground_guess_m, kappa_errors
from aerotri.geom.observations import read_image_points
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """(root, truth EO, camera, tie points) of a 3 x 6 block (60 m relief, 1 deg tilts, east-west strips)."""
    root = write_block_project(geometric_block(3, 6, seed=5), tmp_path_factory.mktemp("kappa") / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=2, seed=6)
    return (root, read_eo(root / "truth" / "eo.txt"), read_camera(root / "camera.toml"),
            read_image_points(root / "at" / "tiepoints.csv"))


def _with_kappa(eo, kappa_deg, centre_m=None):
    opk = eo.opk_deg.copy()
    opk[:, 2] = kappa_deg
    return ExteriorOrientations(list(eo.image_id), eo.centre_m if centre_m is None else centre_m, opk)


def _errors(eo, cam, ties):
    return {e.image_id: e for e in kappa_errors(eo, cam, ties, ground_guess_m(eo, cam))}


def test_kappa_errors_against_the_truth(block):
    _, truth, cam, ties = block
    k = truth.opk_deg[:, 2]
    right = _errors(truth, cam, ties)
    assert len(right) == len(truth) and max(abs(e.error_deg) for e in right.values()) < 1.0  # 0.53 deg
    # one frame 180 deg off: that frame alone, with its cause
    one = _errors(_with_kappa(truth, np.where(np.arange(len(k)) == 7, k + 180.0, k)), cam, ties)
    bad = {i: e for i, e in one.items() if abs(e.error_deg) > KAPPA_LIMIT_DEG}
    assert list(bad) == [truth.image_id[7]] and abs(abs(bad[truth.image_id[7]].error_deg) - 180.0) < 3.0
    assert "180 deg" in bad[truth.image_id[7]].cause
    # every frame 180 deg off (the neighbours agree in their turn: told by their bases)
    assert all(abs(abs(e.error_deg) - 180.0) < 5.0 for e in _errors(_with_kappa(truth, k + 180.0), cam, ties).values())
    # kappa in gon read as degrees: the error is a tenth of kappa, named so where it exceeds the limit
    gon = _errors(_with_kappa(truth, k / 0.9), cam, ties)
    assert all(abs(e.error_deg - 0.1 * e.kappa_deg) < 1.0 for e in gon.values())
    assert all("gon" in e.cause for e in gon.values() if abs(e.error_deg) > KAPPA_LIMIT_DEG)
    assert any(abs(e.error_deg) > KAPPA_LIMIT_DEG for e in gon.values())
    # approximations with 5 m in the centres and 3 deg in kappa: each frame's error within 3 deg
    rng = np.random.default_rng(3)
    dk = rng.normal(0.0, 3.0, len(k))
    noisy = _errors(_with_kappa(truth, k + dk, truth.centre_m + rng.normal(0.0, 5.0, truth.centre_m.shape)), cam, ties)
    assert max(abs(noisy[i].error_deg - d) for i, d in zip(truth.image_id, dk)) < 3.0


def test_adjust_names_the_frames(block, tmp_path):
    """``aerotri adjust --eo`` with every kappa 180 deg off stopped with "Solution failed" (the demo), naming nothing;
    now refused before the solve naming the frames and the likely cause. One frame so with GNSS: a warning, and the
    resection on the GNSS positions mends it."""
    root, truth, _, _ = block
    k = truth.opk_deg[:, 2]
    all180, one180 = tmp_path / "all180.txt", tmp_path / "one180.txt"
    write_eo(all180, _with_kappa(truth, k + 180.0))
    write_eo(one180, _with_kappa(truth, np.where(np.arange(len(k)) == 7, k + 180.0, k)))
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--eo", str(all180), "--no-html", "--no-exports"])
    assert r.exit_code == 2 and "180 deg off" in r.output and truth.image_id[0] in r.output, r.output
    assert not (root / "at" / "eo.txt").exists()
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--eo", str(one180), "--no-html", "--no-exports"])
    assert r.exit_code == 0 and "180 deg off" in r.output and truth.image_id[7] in r.output, r.output
    # angles in radians (trial-messy F8: "x and y swapped?" for every frame): the cause named
    import dataclasses

    rad = tmp_path / "rad.txt"
    write_eo(rad, dataclasses.replace(truth, opk_deg=np.radians((truth.opk_deg + 180.0) % 360.0 - 180.0)))
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--eo", str(rad), "--no-html", "--no-exports"])
    assert r.exit_code == 2 and "angles in radians?" in r.output, r.output


def test_ortho_rectify_refuses_a_given_kappa_off(block, tmp_path):
    """``ortho rectify --eo imported/eo.txt`` rectified the frames as they were: a kappa 180 deg off (or 10 % off,
    gon) turned the frame ortho about its nadir. The tie points now name the frame; the truth passes."""
    from ortho.block import _check_given_kappa

    root, truth, cam, _ = block
    project = Project.open(root)
    k = truth.opk_deg[:, 2]
    _check_given_kappa(project, cam, truth, "truth.txt", set(truth.image_id))
    bad = _with_kappa(truth, np.where(np.arange(len(k)) == 3, k + 180.0, k))
    with pytest.raises(InputError, match=f"{truth.image_id[3]}.*180 deg off|180 deg off.*{truth.image_id[3]}"):
        _check_given_kappa(project, cam, bad, "given.txt", set(truth.image_id))
    _check_given_kappa(project, cam, bad, "given.txt", set(truth.image_id) - {truth.image_id[3]})  # not rectified


def _two_way_block(kappa_deg_of_heading, strips=3, frames=5, base_m=400.0, spacing_m=800.0):
    """Centres of ``strips`` east-west strips flown alternately east and west (flight order), omega and phi within
    1 deg, kappa from the strip's heading (deg)."""
    from aerotri.geom.eo import ExteriorOrientations

    rng = np.random.default_rng(3)
    ids, centres, opk = [], [], []
    for s in range(strips):
        xs = np.arange(frames) * base_m if s % 2 == 0 else (frames - 1 - np.arange(frames)) * base_m
        heading = 90.0 if s % 2 == 0 else 270.0
        for x in xs:
            ids.append(f"s{s}_{len(ids):03d}")
            centres.append([500000.0 + x, 3400000.0 + s * spacing_m, 1500.0])
            kappa = (kappa_deg_of_heading(heading) + rng.uniform(-2, 2) + 180.0) % 360.0 - 180.0  # as files hold it
            opk.append([rng.uniform(-1, 1), rng.uniform(-1, 1), kappa])
    return ExteriorOrientations(ids, np.array(centres), np.array(opk))


def test_angles_in_radians_are_told_by_a_kappa_that_does_not_turn_with_the_aircraft():
    """Trial-messy F13: orthority angles in radians imported and rectified without a word (every ortho 176 deg off).
    A camera turns with the aircraft: strips flown opposite ways differ in kappa by about 180 deg in degrees, by at
    most 2 pi read from radians."""
    import dataclasses

    from aerotri.geom.eo_check import radians_read_as_degrees

    deg = _two_way_block(lambda h: 90.0 - h)  # kappa 0 flying east, 180 flying west
    assert radians_read_as_degrees(deg) is None
    rad = dataclasses.replace(deg, opk_deg=np.radians(deg.opk_deg))
    why = radians_read_as_degrees(rad)
    assert why is not None and "radians" in why and "opposite" in why
    # near north-south strips in degrees (kappa -3 .. +3 on one way, 177 .. 183 on the other): not told
    ns = _two_way_block(lambda h: 0.0 if h == 90.0 else 180.0)
    assert radians_read_as_degrees(ns) is None
    # one strip: nothing to tell it by
    one = dataclasses.replace(rad, image_id=rad.image_id[:5], centre_m=rad.centre_m[:5], opk_deg=rad.opk_deg[:5])
    assert radians_read_as_degrees(one) is None
