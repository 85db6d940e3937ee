"""What an import writes, and says it writes: a reconstruction's orientations go to imported/eo.txt as
approximations and to gnss.txt only with --as-gnss (accuracies stated by the user, or the format's own, or the
project's [gnss] sigmas; refused without any); imports.json lists every file written with what it holds, how
many records and from which input, and the console prints the same lines; all files of an import or none."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import InputError
from aerotri.exchange import export_project
from aerotri.exchange.commit import write_together
from aerotri.geom.eo import read_eo, read_gnss

# format -> (export format, the files the import takes, relative to the export folder)
FORMATS = {
    "colmap": ("colmap", ["colmap"]),
    "orthority": ("orthority", ["orthority/int_param.yaml", "orthority/ext_param.csv"]),
    "patb": ("patb", ["patb/block.ori", "patb/block.cam", "patb/numbers.txt"]),
    "metashape": ("metashape", ["metashape/cameras.xml"]),
    "opensfm": ("odm", ["odm/opensfm/reconstruction.json"]),
}


@pytest.fixture(scope="module")
def exported(adjusted_tiny, tmp_path_factory):
    root, _ = adjusted_tiny
    out = tmp_path_factory.mktemp("rules_exp")
    export_project(root, sorted({e for e, _ in FORMATS.values()}), out)
    return root, out


def _bare(root, tmp_path, name="p"):
    """A project folder with the source's CRS and nothing else (no [gnss] sigmas)."""
    import tomllib

    crs = tomllib.loads((root / "project.toml").read_text())["project"]["crs"]
    dst = tmp_path / name
    dst.mkdir()
    (dst / "project.toml").write_text(f'[project]\nname = "{name}"\ncrs = "{crs}"\n')
    return dst


def _listing(root):
    return sorted((str(p.relative_to(root)), p.stat().st_size) for p in root.rglob("*"))


def _import(root, fmt, out, *extra):
    args = ["import", str(root), "--format", fmt] + [str(out / f) for f in FORMATS[fmt][1]] + list(extra)
    return CliRunner().invoke(aerotri_cli, args)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_orientations_are_approximations_and_every_file_is_listed(exported, tmp_path, fresh_project, fmt):
    root, out = exported
    dst = fresh_project(root, tmp_path / "p")
    r = _import(dst, fmt, out)
    assert r.exit_code == 0, r.output
    assert not (dst / "gnss.txt").exists()  # another program's solution is no GNSS measurement
    eo = read_eo(dst / "imported" / "eo.txt")
    assert np.abs(eo.centre_m - read_eo(root / "at" / "eo.txt").centre_m).max() < 1e-4
    (entry,) = json.loads((dst / "imported" / "imports.json").read_text())["imports"]
    paths = {f["path"] for f in entry["files"]}
    assert entry["format"] == fmt and paths == {"camera.toml", "imported/eo.txt"} | (
        {"control/points.csv", "control/image_points.csv"} if fmt == "metashape" else set())  # its markers
    inputs = {x.split("/")[-1] for x in FORMATS[fmt][1]} | ({"images.txt", "cameras.txt"} if fmt == "colmap" else set())
    for f in entry["files"]:
        assert (dst / f["path"]).is_file() and f["source"] in inputs, f
        line = f"{f['path']}: {f['count']} {f['holds']} (from {f['source']})"
        assert line in r.output.splitlines()
    eo_entry = next(f for f in entry["files"] if f["path"] == "imported/eo.txt")
    assert eo_entry["count"] == len(eo.image_id) and "approximate orientations" in eo_entry["holds"]
    assert f"imported/imports.json: 1 record of this import ({len(paths)} files written)" in r.output


@pytest.mark.parametrize("fmt", [f for f in FORMATS if f != "opensfm"])
def test_as_gnss_needs_accuracies(exported, tmp_path, fmt):
    """--as-gnss without --sigma-xyz-m, without the format's or the project's accuracies: exit 2, nothing written.
    With --sigma-xyz-m: gnss.txt holds the projection centres with those accuracies, and says so."""
    root, out = exported
    dst = _bare(root, tmp_path)
    before = _listing(dst)
    r = _import(dst, fmt, out, "--as-gnss")
    assert r.exit_code == 2 and "--sigma-xyz-m" in r.output and "Traceback" not in r.output
    assert _listing(dst) == before
    r = _import(dst, fmt, out, "--as-gnss", "--sigma-xyz-m", "0.5", "0.5", "1.0")
    assert r.exit_code == 0, r.output
    g, eo = read_gnss(dst / "gnss.txt"), read_eo(dst / "imported" / "eo.txt")
    assert g.image_id == eo.image_id and np.allclose(g.position_m, eo.centre_m) and np.allclose(g.sigma_m, [0.5, 0.5, 1.0])
    header = (dst / "gnss.txt").read_text().splitlines()[0]
    assert "--as-gnss" in header and "--sigma-xyz-m" in header
    (entry,) = json.loads((dst / "imported" / "imports.json").read_text())["imports"]
    holds = next(f["holds"] for f in entry["files"] if f["path"] == "gnss.txt")
    assert "accuracies 0.5 0.5 1 m from --sigma-xyz-m" in holds and f"gnss.txt: {len(g.image_id)} GNSS positions" in r.output


def test_as_gnss_with_the_project_sigmas(exported, tmp_path):
    root, out = exported
    dst = _bare(root, tmp_path)
    with open(dst / "project.toml", "a") as f:
        f.write("\n[gnss]\nsigma_xy_m = 0.2\nsigma_z_m = 0.3\n")
    r = _import(dst, "colmap", out, "--as-gnss")
    assert r.exit_code == 0, r.output
    assert read_gnss(dst / "gnss.txt").sigma_m is None  # the adjustment takes project.toml's
    assert "accuracies 0.2 / 0.3 m from project.toml [gnss]" in r.output


def test_opensfm_as_gnss_takes_the_shots_gnss_and_gps_dop(exported, adjusted_tiny, tmp_path, fresh_project):
    """OpenSfM's gps_position is the GNSS the reconstruction was made with: --as-gnss writes it (here the source
    project's gnss.txt, exported with gps_dop = its default sigma) with gps_dop as accuracy."""
    root, out = exported
    dst = fresh_project(root, tmp_path / "p")
    r = _import(dst, "opensfm", out)
    assert "10 shots carry gps_position (gps_dop 0.05..0.05 m): not imported; --as-gnss writes them" in r.output
    dst2 = fresh_project(root, tmp_path / "q")
    r = _import(dst2, "opensfm", out, "--as-gnss")
    assert r.exit_code == 0, r.output
    g, src = read_gnss(dst2 / "gnss.txt"), read_gnss(root / "gnss.txt")
    # the export wrote OpenSfM's centre priors: the antennas reduced by the source's lever arm (trial s100 ex F1), and
    # the import says that the project's lever arm would be applied to them again
    assert g.image_id == src.image_id and np.abs(g.position_m - src.position_m).max() > 1.0
    assert np.allclose(g.sigma_m, 0.05) and "accuracies from OpenSfM gps_dop" in r.output
    said = "positions are projection centres, but project.toml [gnss] lever_arm_m = [0.05, -0.12, 1.25] m"
    assert said in r.output, r.output
    eo = read_eo(dst2 / "imported" / "eo.txt")
    up = {i: c for i, c in zip(eo.image_id, eo.centre_m)}
    assert max(abs(float(p[2] - up[i][2])) for i, p in zip(g.image_id, g.position_m)) < 0.5  # (1.25 m before)


@pytest.mark.parametrize("fmt", ["odm", "micmac"])
def test_as_gnss_refused_for_formats_without_positions(tiny_project, tmp_path, fresh_project, fmt):
    dst = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "x.txt"
    f.write_text("x\n")
    r = CliRunner().invoke(aerotri_cli, ["import", str(dst), "--format", fmt, str(f), "--as-gnss"])
    assert r.exit_code == 2 and "--as-gnss" in r.output and "hold no positions" in r.output


def _fail_on(monkeypatch, name):
    """Make the rename of a temporary onto ``name`` fail (a disk error between two files)."""
    import os

    from aerotri.exchange import commit

    real = os.replace

    def replace(src, dst):
        if os.path.basename(dst) == name and ".part-" in os.path.basename(src):
            raise OSError(28, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(commit.os, "replace", replace)


def test_all_files_or_none(tmp_path, monkeypatch):
    """A failure on the third file: the two before it are back as they were (old content, or absent), and no
    temporary is left; a folder in the way is refused before anything is written."""
    a, b, c = tmp_path / "a.txt", tmp_path / "sub" / "b.txt", tmp_path / "c.txt"
    a.write_text("old a\n")
    c.write_text("old c\n")
    with monkeypatch.context() as m:
        _fail_on(m, "c.txt")
        with pytest.raises(OSError):
            write_together({a: "new a\n", b: "new b\n", c: "new c\n"})
    assert a.read_text() == "old a\n" and not b.exists() and c.read_text() == "old c\n"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.txt", "c.txt"]  # no temporaries, no new folder
    write_together({a: "new a\n", b: b"new b\n"})
    assert a.read_text() == "new a\n" and b.read_bytes() == b"new b\n"
    (tmp_path / "d.txt").mkdir()
    with pytest.raises(InputError, match="a folder is in the way"):
        write_together({a: "newer a\n", tmp_path / "d.txt": "d\n"})
    assert a.read_text() == "new a\n"


def test_import_all_or_none(exported, tmp_path, fresh_project, monkeypatch):
    """An import that fails writing its last file (the record) leaves the project as it was."""
    from aerotri.exchange import import_files

    root, out = exported
    dst = fresh_project(root, tmp_path / "p")
    before = _listing(dst)
    _fail_on(monkeypatch, "imports.json")
    with pytest.raises(OSError):
        import_files(dst, "colmap", [out / "colmap"])
    assert _listing(dst) == before


@pytest.mark.parametrize("table", ["gnss", "adjust"])
def test_as_gnss_centres_with_a_lever_arm_are_named(exported, tmp_path, table):
    """Projection centres written to gnss.txt in a project with a lever arm: the adjustment takes them as antenna
    positions and moves every centre by the lever arm (the demo, [0.05, -0.12, 1.45] m: its check heights 1.64 m RMS
    off, 4 of 7 control points rejected), so the import says so; OpenSfM's gps_position too, OpenSfM's prior of the
    camera centre (aerotri's export reduces its antennas to the centres: trial s100 ex F1)."""
    root, out = exported
    dst = _bare(root, tmp_path)
    with open(dst / "project.toml", "a") as f:
        f.write(f"\n[{table}]\nlever_arm_m = [0.05, -0.12, 1.45]\n")
    r = _import(dst, "colmap", out, "--as-gnss", "--sigma-xyz-m", "0.05", "0.05", "0.08")
    assert r.exit_code == 0, r.output
    said = (f"gnss.txt: the 10 positions are projection centres, but project.toml [{table}] lever_arm_m = "
            "[0.05, -0.12, 1.45] m")
    assert said in r.output
    (entry,) = json.loads((dst / "imported" / "imports.json").read_text())["imports"]
    assert any(said in n for n in entry["notes"])
    dst2 = _bare(root, tmp_path, "q")
    with open(dst2 / "project.toml", "a") as f:
        f.write(f"\n[{table}]\nlever_arm_m = [0.05, -0.12, 1.45]\n")
    r = _import(dst2, "opensfm", out, "--as-gnss")
    assert r.exit_code == 0 and f"projection centres, but project.toml [{table}] lever_arm_m" in r.output, r.output
