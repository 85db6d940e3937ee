"""aerotri compare: the adjusted orientations against a reference read by an import format; known differences
come back, frame by frame and as RMS, and bad input is one clear error."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.geom.eo import ExteriorOrientations, format_eo

PROJECT = '[project]\nname = "t"\ncrs = "EPSG:32632"\n'


def _project(tmp_path):
    rng = np.random.default_rng(4)
    ids = [f"f{i:02d}" for i in range(6)]
    centre = np.c_[500000 + 100 * np.arange(6), np.full(6, 5400000.0), np.full(6, 1200.0)] + rng.normal(0, 1, (6, 3))
    opk = np.c_[rng.normal(0, 1, 6), rng.normal(0, 1, 6), rng.uniform(-180, 180, 6)]
    sigma = np.tile([0.02, 0.02, 0.04, 0.002, 0.002, 0.001], (6, 1))
    tmp_path.mkdir(parents=True)
    (tmp_path / "project.toml").write_text(PROJECT)
    (tmp_path / "at").mkdir()
    (tmp_path / "at" / "eo.txt").write_text(format_eo(ExteriorOrientations(ids, centre, opk, sigma)))
    return tmp_path, ids, centre, opk


def test_known_differences_come_back(tmp_path):
    root, ids, centre, opk = _project(tmp_path / "p")
    d_c = np.array([0.03, -0.04, 0.08])
    d_o = np.array([0.002, -0.001, 0.004])
    ref = tmp_path / "ext_param.csv"
    rows = ["filename,x,y,z,omega,phi,kappa"]
    for i, iid in enumerate(ids[:5]):  # the reference lacks the last frame
        x, y, z = centre[i] - d_c
        o, p, k = opk[i] - d_o
        rows.append(f"{iid},{x:.4f},{y:.4f},{z:.4f},{o:.7f},{p:.7f},{k:.7f}")
    ref.write_text("\n".join(rows) + "\n")
    r = CliRunner().invoke(aerotri_cli, ["compare", str(root), "--format", "orthority", "--crs", "EPSG:32632", str(ref)])
    assert r.exit_code == 0, r.output
    assert "5 frames against ext_param.csv" in r.output and "not in the reference: 1 frame (f05)" in r.output
    rec = json.loads((root / "reports" / "eo_comparison.json").read_text())
    assert rec["frames"] == 5 and rec["missing"] == ["f05"]
    assert np.allclose(rec["rms_centre_m"], np.abs(d_c), atol=2e-4) and np.allclose(rec["rms_opk_deg"], np.abs(d_o), atol=2e-7)
    assert rec["per_frame"][0]["d_centre_m"] == [0.03, -0.04, 0.08]
    # in the adjustment's sigmas: 1.5 2 2 and 1 0.5 4
    assert np.allclose(rec["rms_normalised"], [1.5, 2.0, 2.0, 1.0, 0.5, 4.0], atol=0.02)
    # kappa 4 sigma: the console says the reference's own errors are not in the sigmas (Tuniu against OpenSfM: 4.3)
    assert "the reference's own errors and model are not in these sigmas" in r.output
    assert "kappa: the adjustment's sigmas understate these differences" in r.output  # named beyond 2 (s95)
    # the rotation between the attitudes is about the size of the angle differences
    assert 0.003 < rec["rms_rotation_deg"] < 0.0047


def test_bad_input_is_one_clear_error(tmp_path):
    root, *_ = _project(tmp_path / "p")
    ref = tmp_path / "ext_param.csv"
    ref.write_text("filename,x,y,z,omega,phi,kappa\nzz,1,2,3,0,0,0\n")
    r = CliRunner().invoke(aerotri_cli, ["compare", str(root), "--format", "orthority", "--crs", "EPSG:32632", str(ref)])
    assert r.exit_code == 2 and "no frame in common with at/eo.txt" in r.output and "Traceback" not in r.output
    assert not (root / "reports" / "eo_comparison.json").exists()
    r = CliRunner().invoke(aerotri_cli, ["compare", str(root), "--format", "orthority", str(tmp_path / "none.csv")])
    assert r.exit_code == 2 and "none.csv: not found" in r.output


def test_centres_that_are_the_projects_gnss_are_no_check(tmp_path):
    """docs/your-own-block.md imports the NGI national AT's centres as GNSS and compares with the same AT: the
    centres then agree to 0.002 m RMS by construction, and nothing said so."""
    root, ids, centre, opk = _project(tmp_path / "p")
    ref = tmp_path / "ext_param.csv"
    rows = ["filename,x,y,z,omega,phi,kappa"] + [f"{iid},{x:.4f},{y:.4f},{z:.4f},{o:.7f},{p:.7f},{k:.7f}"
                                                 for iid, (x, y, z), (o, p, k) in zip(ids, centre + 0.002, opk)]
    ref.write_text("\n".join(rows) + "\n")
    args = ["compare", str(root), "--format", "orthority", "--crs", "EPSG:32632", str(ref)]
    r = CliRunner().invoke(aerotri_cli, args)
    assert r.exit_code == 0 and "note:" not in r.output  # no gnss.txt: nothing to say
    (root / "gnss.txt").write_text("".join(f"{iid} {x:.4f} {y:.4f} {z:.4f} 0.05 0.05 0.05\n"
                                           for iid, (x, y, z) in zip(ids, centre + 0.002)))
    r = CliRunner().invoke(aerotri_cli, args)
    assert r.exit_code == 0, r.output
    assert "note: the reference's projection centres are this project's GNSS observations" in r.output
    assert "no independent check" in json.loads((root / "reports" / "eo_comparison.json").read_text())["note"]
    # GNSS of its own (0.5 m from the reference): a real check, no note
    (root / "gnss.txt").write_text("".join(f"{iid} {x:.4f} {y:.4f} {z:.4f}\n" for iid, (x, y, z) in zip(ids, centre + 0.5)))
    assert "note:" not in CliRunner().invoke(aerotri_cli, args).output


def test_the_2d_crs_heights_note_only_when_the_heights_could_differ(tmp_path):
    """exchange-fixes2: "EPSG:32632 is a 2D CRS ... z taken in the project's heights" was said for our own exports
    read back into their project (noise beside the real warning). Said now only when the file's centres are not at
    at/eo.txt's heights (1 cm), or those heights may have come from the file (gnss.txt holds its centres)."""
    root, ids, centre, opk = _project(tmp_path / "p")

    def said(z_shift_m):
        ref = tmp_path / "ext_param.csv"
        rows = ["filename,x,y,z,omega,phi,kappa"] + [f"{iid},{x:.4f},{y:.4f},{z + z_shift_m:.4f},{o:.7f},{p:.7f},"
                                                     f"{k:.7f}" for iid, (x, y, z), (o, p, k) in zip(ids, centre, opk)]
        ref.write_text("\n".join(rows) + "\n")
        r = CliRunner().invoke(aerotri_cli, ["compare", str(root), "--format", "orthority", "--crs", "EPSG:32632",
                                             str(ref)])
        assert r.exit_code == 0, r.output
        notes = json.loads((root / "reports" / "eo_comparison.json").read_text())["reference_notes"]
        return "is a 2D CRS" in r.output, any("is a 2D CRS" in n for n in notes)

    assert said(0.0) == (False, False)  # our own export: at/eo.txt's heights to 0.1 mm
    assert said(0.004) == (False, False)
    assert said(25.0) == (True, True)  # heights of another system (a geoid's N of 25 m)
    assert said(0.05) == (True, True)  # another AT of the frames: cannot tell
    # at/eo.txt's heights taken in from the file itself (its centres are the project's GNSS): no confirmation
    (root / "gnss.txt").write_text("".join(f"{iid} {x:.4f} {y:.4f} {z:.4f} 0.05 0.05 0.05\n"
                                           for iid, (x, y, z) in zip(ids, centre)))
    assert said(0.0) == (True, True)
