"""PAT-B files: the round trip of orientations, camera, control and the control points' image coordinates through
a fresh project; the files read back by a parser written from the layouts (fixed columns); bad input."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.exchange import ImportSettings, export_project, import_files
from aerotri.exchange.adjusted import read_adjusted_block
from aerotri.exchange.patb import photo_coordinates_mm
from aerotri.geom.camera import oriented_camera
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo
from aerotri.geom.observations import read_control_points, read_image_points


@pytest.fixture(scope="module")
def exported(adjusted_tiny, tmp_path_factory):
    root, _ = adjusted_tiny
    out = tmp_path_factory.mktemp("patb_exp")
    export_project(root, ["patb"], out)
    return root, out / "patb"


def test_round_trip(exported, tmp_path, fresh_project):
    root, patb = exported
    p = Project.open(root)
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "patb", [patb / f"block.{s}" for s in ("ori", "cam", "con", "im")] + [patb / "numbers.txt"])
    eo, back = read_eo(p.eo_path), read_eo(dst / "imported" / "eo.txt")
    assert back.image_id == eo.image_id
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4
    assert np.abs(back.opk_deg - eo.opk_deg).max() < 1e-7
    got, cam = read_camera(dst / "camera.toml"), oriented_camera(p)[0]
    assert got == cam  # every field written with repr: exact
    blk = read_adjusted_block(root)
    con = read_control_points(dst / "control" / "points.csv")
    assert list(con.id) == list(blk.control_id) and list(con.kind) == list(blk.control_kind)
    assert np.abs(con.xyz_m - blk.control_xyz_m).max() < 1e-4
    sig = Project.open(root).control_points
    assert np.allclose(con.sigma_m, [sig.sigma_xy_m, sig.sigma_xy_m, sig.sigma_z_m])
    # the control points' measurements, back in pixels: the .im keeps 0.1 um = 0.008 px at 12 um
    obs = read_image_points(dst / "control" / "image_points.csv")
    mine = {(blk.point_id[j], blk.image_id[i]): blk.obs_xy_px[k]
            for k, (i, j) in enumerate(zip(blk.obs_image, blk.obs_point)) if blk.point_id[j] in set(blk.control_id)}
    assert len(obs) == len(mine) > 0
    d = np.array([obs.xy_px[n] - mine[p, i] for n, (p, i) in enumerate(zip(obs.point_id, obs.image_id))])
    assert np.abs(d).max() < 0.01


def test_ori_alone_with_explicit_crs(exported, tmp_path, fresh_project):
    """A .ori alone, its CRS given with --crs (here the project's: nothing changes; another CRS goes through
    the same operation as orthority's, tested there)."""
    root, patb = exported
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "patb", [patb / "block.ori", patb / "numbers.txt"], ImportSettings(crs=Project.open(root).crs))
    assert np.abs(read_eo(dst / "imported" / "eo.txt").centre_m - read_eo(Project.open(root).eo_path).centre_m).max() < 1e-4


def test_control_on_a_datum_proj_cannot_relate_names_what_import_can_do(exported, tmp_path, fresh_project):
    """Control in CGCS2000 3-degree GK (EPSG:4546) into a WGS 84 / UTM 49N project: PROJ has only a ballpark
    operation. The refusal told the user to "pass them with --params ... or --allow-ballpark", options aerotri
    import does not have (exit 2, "No such option"); it names aerotri crs transform and --crs now."""
    import pyproj

    root, patb = exported
    crs = Project.open(root).crs
    t = pyproj.Transformer.from_crs(crs, "EPSG:4546", always_xy=True)
    lines = []
    for line in (patb / "block.con").read_text().splitlines():
        f = line.split()
        if len(f) == 4:
            x, y = t.transform(float(f[1]), float(f[2]))
            line = f"{int(f[0]):16d}{x:16.4f}{y:16.4f}{float(f[3]):16.4f}"
        lines.append(line)
    con = tmp_path / "gk.con"
    con.write_text("\n".join(lines) + "\n")
    dst = fresh_project(root, tmp_path / "p")
    r = CliRunner().invoke(aerotri_cli, ["import", str(dst), "--format", "patb", str(con), str(patb / "numbers.txt"),
                                         "--crs", "EPSG:4546"])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "EPSG:4546 (CGCS2000 / 3-degree Gauss-Kruger CM 111E) -> project CRS" in r.output
    assert "aerotri import applies no datum parameters" in r.output and "aerotri crs transform" in r.output
    assert "pass them with --params" not in r.output
    assert not (dst / "control").exists()


ORI_OK = "7 500000.0 4100000.0 1000.0\n 1 0 0 0 1\n 0.0 0 0 1.0\n"


@pytest.mark.parametrize("name, text, match", [
    ("b.ori", ORI_OK.replace(" 0.0 0 0 1.0\n", " 0.0 0 0\n"), r"b.ori:3: expected 4 numbers \(a23 a31 a32 a33\)"),
    ("b.ori", ORI_OK.replace("1000.0", "nan"), r"b.ori:1: Z0 is NaN"),
    ("b.ori", ORI_OK.replace(" 1 0 0 0 1\n", " 2 0 0 0 1\n"), "is not a rotation"),
    ("b.ori", ORI_OK + ORI_OK, r"b.ori:4: duplicate photo '7'"),
    ("b.ori", "7 1 2 3\n 1 0 0 0 1\n", "needs 2 more records"),
    ("b.ori", "7 1 2\n 1 0 0 0 1\n 0.0 0 0 1.0\n", r"b.ori:1: expected 'photo_number \[c\] X0 Y0 Z0'"),
    ("b.cam", "name x\nfocal_mm 120\n-99\n", "missing pixel_um, width, height"),
    ("b.con", "g1 1 2\n-99\n", r"b.con:1: expected 'point_number X Y Z'"),
    ("b.con", "g1 500000 4100000 10\n", "b.con: no -99 at the end"),
    ("b.im", "a\n g1 1.0 2.0\n", "has no -99 at its end"),
    ("b.txt", "x\n", "not a PAT-B file"),
])
def test_bad_input(tiny_project, tmp_path, name, text, match, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / name
    f.write_text(text)
    extra = []
    if name.endswith(".im"):
        (tmp_path / "c.con").write_text("g1 500000 4100000 10\n-99\n")
        extra = [tmp_path / "c.con"]
    with pytest.raises(InputError, match=match):
        import_files(root, "patb", [f] + extra, ImportSettings(sigma_xyz_m=(0.02, 0.02, 0.03)))
    assert not (root / "imported").exists() and not (root / "control").exists()


def test_control_needs_sigmas_and_cli_exit(tiny_project, tmp_path):
    root = tmp_path / "p"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "x"\ncrs = "EPSG:32649"\n')
    (tmp_path / "c.con").write_text("g1 500000 4100000 10  * height\n-99\n")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "patb", str(tmp_path / "c.con")])
    assert r.exit_code == 2 and "give --sigma-xyz-m" in r.output and "Traceback" not in r.output
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "patb", "--sigma-xyz-m", "0.02", "0.02", "0.03",
                                         str(tmp_path / "c.con")])
    assert r.exit_code == 0, r.output
    c = read_control_points(root / "control" / "points.csv")
    assert list(c.kind) == ["height"] and np.allclose(c.sigma_m, [[0.02, 0.02, 0.03]])


def _fields(line: str, widths):
    """Fortran fixed-column fields of a record (an ``nX`` field: width given as a negative number, skipped)."""
    out, at = [], 0
    for w in widths:
        if w > 0:
            out.append(line[at:at + w])
        at += abs(w)
    assert len(line) == at, (line, widths)
    return out


def _f(text: str, decimals: int) -> float:
    """An Fw.d field: right-justified, exactly ``decimals`` digits after the point."""
    assert re.fullmatch(rf" *-?\d+\.\d{{{decimals}}}", text), text
    return float(text)


def _i(text: str) -> int:
    assert re.fullmatch(r" *-?\d+", text), text
    return int(text)


def test_files_in_the_documented_columns(exported):
    """A reader written from the layouts in the module docstring and docs/exchange.md (fixed columns, not split on
    blanks) reads the export back: .ori records I16,F16.5,3F16.5 / 5F16.12 / 4F16.12 equal at/eo.txt (centres to
    0.01 mm, matrix to 1e-12) and the principal distance at/camera.toml's focal length (0.01 um; trial s100 exchange
    F2: columns 17-32 were blank); .im records I16 / I16,2F16.6 / -99 equal the undistorted photo coordinates
    (1e-6 mm); .con records I16,3F16.4 and -99 equal the control coordinates (0.1 mm)."""
    root, patb = exported
    p = Project.open(root)
    blk = read_adjusted_block(root)
    photo, point = {}, {}
    for line in (patb / "numbers.txt").read_text().splitlines()[1:]:
        kind, n, ident, *_ = line.split()
        (photo if kind == "photo" else point)[int(n)] = ident
    # orientations
    eo = read_eo(p.eo_path)
    f_mm = read_camera(p.camera_path).focal_mm
    ori = (patb / "block.ori").read_text().splitlines()
    assert len(ori) == 3 * len(eo.image_id)
    for k, iid in enumerate(eo.image_id):
        n, c, *xyz = _fields(ori[3 * k], (16, 16, 16, 16, 16))
        assert abs(_f(c, 5) - f_mm) < 1e-5 and photo[_i(n)] == iid
        a = [_f(v, 12) for v in _fields(ori[3 * k + 1], (16,) * 5) + _fields(ori[3 * k + 2], (16,) * 4)]
        assert np.abs(np.array([_f(v, 5) for v in xyz]) - eo.centre_m[k]).max() < 1e-5
        assert np.abs(np.array(a).reshape(3, 3) - eo.rotation(k)).max() < 1e-12
    # image coordinates
    x_mm, y_mm, _ = photo_coordinates_mm(blk)
    want = {(blk.image_id[i], str(blk.point_id[j])): (x, y) for i, j, x, y in zip(blk.obs_image, blk.obs_point, x_mm, y_mm)}
    # and the check points' measurements (trial s96 M2: block_check.con without them in block.im)
    cp = read_control_points(p.control_points_path)
    obs = read_image_points(p.control_image_points_path)
    is_check = np.isin(obs.point_id.astype(str), cp.id[cp.kind == "check"].astype(str))
    assert is_check.sum() > 0
    cx, cy, _ = photo_coordinates_mm(blk, obs.xy_px[is_check])
    want.update({(i, str(q)): (x, y) for q, i, x, y in zip(obs.point_id[is_check], obs.image_id[is_check], cx, cy)})
    got, current = {}, None
    for line in (patb / "block.im").read_text().splitlines():
        if current is None:
            current = photo[_i(_fields(line, (16,))[0])]
        elif len(line) == 16:
            assert _i(line) == -99
            current = None
        else:
            n, x, y = _fields(line, (16, 16, 16))
            got[(current, point[_i(n)])] = (_f(x, 6), _f(y, 6))
    assert current is None and got.keys() == want.keys()
    assert max(np.abs(np.subtract(got[k], want[k])).max() for k in want) < 1e-6
    # control: full control in block.con, the check points in block_check.con
    for name, ids in (("block.con", blk.control_id[blk.control_kind == "full"]), ("block_check.con", cp.id[cp.kind == "check"])):
        lines = (patb / name).read_text().splitlines()
        assert _i(lines[-1]) == -99 and len(lines[-1]) == 16
        rows = {point[_i(f[0])]: [_f(v, 4) for v in f[1:]] for f in (_fields(ln, (16,) * 4) for ln in lines[:-1])}
        assert sorted(rows) == sorted(ids)
        xyz = dict(zip(cp.id, cp.xyz_m))
        assert max(np.abs(np.array(rows[q]) - xyz[q]).max() for q in rows) < 1e-4


def test_numbering_keeps_integer_ids():
    from aerotri.exchange.patb import numbering

    kept = numbering(["1001", "1002", "17", "1001"])
    assert kept.ids == ("1001", "1002", "17") and kept.numbers == (1001, 1002, 17) and kept.number_of("17") == 17
    # a leading zero, a letter, a sign: all numbered in order (one rule for the whole set keeps numbers unique)
    assert numbering(["0018", "1002"]).numbers == (1, 2)
    mixed = numbering(["s01_001", "s01_002", "7"])
    assert mixed.numbers == (1, 2, 3) and mixed.number_of("7") == 3


def test_principal_distance_of_the_ori_against_the_camera(exported, tmp_path, fresh_project):
    """MATCH-AT and ISAT write the principal distance c in the .ori's columns 17-32. It was read and dropped: an AT
    computed with c = f + 0.5 mm imported beside the camera's f gave no word (trial-exchange). Now a warning names
    the file line, c and f; the same c as the camera's is accepted without one."""
    root, patb = exported
    f_mm = read_camera(Project.open(root).camera_path).focal_mm
    lines = (patb / "block.ori").read_text().splitlines()

    def with_c(c_mm):
        out = []
        for n, line in enumerate(lines):
            if n % 3 == 0:  # a photo's first record: number, c, X0 Y0 Z0
                line = line[:16] + f"{c_mm:16.5f}" + line[32:]
            out.append(line)
        path = tmp_path / f"c{c_mm:.5f}.ori"
        path.write_text("\n".join(out) + "\n")
        return path

    def project(name):  # a project with its camera (aerotri init writes one), the AT's orientations imported into it
        dst = fresh_project(root, tmp_path / name)
        shutil.copy(Project.open(root).camera_path, dst / "camera.toml")
        return dst

    same = project("same")
    r = CliRunner().invoke(aerotri_cli, ["import", str(same), "--format", "patb", str(with_c(f_mm)),
                                         str(patb / "numbers.txt"), "--crs", Project.open(root).crs])
    assert r.exit_code == 0 and "principal distance" not in r.output, r.output
    other = project("other")
    r = CliRunner().invoke(aerotri_cli, ["import", str(other), "--format", "patb", str(with_c(f_mm + 0.5)),
                                         str(patb / "numbers.txt"), "--crs", Project.open(root).crs])
    text = " ".join(r.output.split())
    assert r.exit_code == 0 and f"c = {f_mm + 0.5:g} mm" in text and f"f = {f_mm:g} mm" in text, r.output
    assert ".ori:1: photo" in text, r.output
    # aerotri compare reads the reference as the import does and says the same (it dropped the notes before)
    r = CliRunner().invoke(aerotri_cli, ["compare", str(root), "--format", "patb", str(with_c(f_mm + 0.5)),
                                         str(patb / "numbers.txt"), "--crs", Project.open(root).crs])
    assert r.exit_code == 0 and f"c = {f_mm + 0.5:g} mm" in " ".join(r.output.split()), r.output
    # with the .con (and .im) beside it: the control's accuracy is no input of a comparison (trial-ngi: it asked for
    # --sigma-xyz-m, an option compare has not)
    bare = tmp_path / "bare"
    shutil.copytree(root, bare)
    toml = (bare / "project.toml").read_text()
    (bare / "project.toml").write_text(toml[:toml.index("[control]")])     # no [control] accuracies
    r = CliRunner().invoke(aerotri_cli, ["compare", str(bare), "--format", "patb", str(patb / "block.ori"),
                                         *(str(patb / f) for f in ("block.cam", "block.con", "block.im", "numbers.txt")),
                                         "--crs", Project.open(root).crs])
    assert r.exit_code == 0 and "sigma-xyz-m" not in r.output, r.output


def test_a_transposed_rotation_matrix_is_told_by_the_tie_points(exported, tmp_path, fresh_project):
    """exchange-fixes2: a .ori written object -> camera (each matrix transposed) kept its diagonal and imported with
    kappa's sign flipped, unsaid. With the .im beside it the rays of the points measured in two photos miss each
    other as read and meet transposed: refused (trial s96 M6: a warning, and every photo up to 2.5 deg off under
    exit 0), naming the file and the photos; the file as written says nothing."""
    from aerotri.exchange.patb import read_ori

    root, patb = exported
    nums, centre, R, _ = read_ori(patb / "block.ori")
    flipped = tmp_path / "block.ori"
    rows = []
    for v, c, a in zip(nums, centre, R.transpose(0, 2, 1).reshape(-1, 9)):
        rows += [f"{int(v):16d}{'':16}" + "".join(f"{x:16.5f}" for x in c), "".join(f"{x:16.12f}" for x in a[:5]),
                 "".join(f"{x:16.12f}" for x in a[5:])]
    flipped.write_text("\n".join(rows) + "\n")
    rest = [patb / f for f in ("block.cam", "block.con", "block.im", "numbers.txt")]
    r = CliRunner().invoke(aerotri_cli, ["import", str(fresh_project(root, tmp_path / "ok")), "--format", "patb",
                                         str(patb / "block.ori"), *map(str, rest)])
    assert r.exit_code == 0 and "look transposed" not in r.output, r.output
    r = CliRunner().invoke(aerotri_cli, ["import", str(fresh_project(root, tmp_path / "t")), "--format", "patb",
                                         str(flipped), *map(str, rest)])
    text = " ".join(r.output.split())
    assert r.exit_code == 2 and "block.ori: the rotation matrices look transposed" in text, r.output
    assert not (tmp_path / "t" / "imported").exists()
    first = read_eo(Project.open(root).eo_path).image_id[0]
    assert f"{len(nums)} of {len(nums)} photos ({first}," in text, r.output
    m = re.search(r"miss each other by ([\d.]+) px .* as read, ([\d.]+) px transposed", text)
    assert float(m.group(1)) > 5 and float(m.group(2)) < 1, text
    # a block without control (DEM-controlled; trial-ngi): the .im's tie points alone still tell it, and an empty
    # .con (what the export writes for such a block) is no error
    empty_con = tmp_path / "block.con"
    empty_con.write_text("-99\n")
    ties = [flipped, patb / "block.cam", empty_con, patb / "block.im", patb / "numbers.txt"]
    nc = fresh_project(root, tmp_path / "nc")
    shutil.rmtree(nc / "control", ignore_errors=True)
    r = CliRunner().invoke(aerotri_cli, ["import", str(nc), "--format", "patb", *map(str, ties)])
    text = " ".join(r.output.split())
    assert r.exit_code == 2 and "block.ori: the rotation matrices look transposed" in text, r.output
    assert not (nc / "control").exists() and not (nc / "imported").exists(), r.output


def test_a_fixed_column_ori_record_missing_a_field_is_refused_by_its_columns(tmp_path):
    """Trial s96 H1: MATCH-AT / ISAT write c in columns 17-32; a record that lost Z0 read by blanks as number X0 Y0 Z0
    put X0 = c (120), Y0 = X0 and Z0 = Y0 (-3,727,433 m) under exit 0. Read by its columns now: refused naming them;
    the same layout whole, and without c (blank 17-32), read as before."""
    from aerotri.exchange.patb import read_ori

    rot = ("  1.000000000000  0.000000000000  0.000000000000  0.000000000000  1.000000000000\n"
           "  0.000000000000  0.000000000000  0.000000000000  1.000000000000\n")
    whole = f"{1:16d}{120.0:16.5f}{-55094.50448:16.5f}{-3727407.03748:16.5f}{5258.30793:16.5f}\n" + rot
    no_c = f"{2:16d}{'':16}{-57710.43528:16.5f}{-3727433.89302:16.5f}{5230.0:16.5f}\n" + rot
    lost = f"{3:16d}{120.0:16.5f}{-57682.68023:16.5f}{-3731579.57171:16.5f}\n" + rot
    ok = tmp_path / "ok.ori"
    ok.write_text(whole + no_c)
    ids, centres, _, c_mm = read_ori(ok)
    assert ids == ["1", "2"] and centres[1].tolist() == [-57710.43528, -3727433.89302, 5230.0] and set(c_mm) == {"1"}
    bad = tmp_path / "bad.ori"
    bad.write_text(whole + lost)
    with pytest.raises(InputError, match=r"bad.ori:4: .* Z0 \(columns 65-80\) empty"):
        read_ori(bad)
    # blank-separated records (no fixed columns) read by their fields as before
    free = tmp_path / "free.ori"
    free.write_text("7 -57710.43528 -3727433.89302 5230.0\n1 0 0 0 1\n0 0 0 1\n")
    assert read_ori(free)[1][0].tolist() == [-57710.43528, -3727433.89302, 5230.0]
