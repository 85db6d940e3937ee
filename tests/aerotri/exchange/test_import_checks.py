"""Import checks: each refusal exits 2 with a message naming what is wrong and writes nothing; the accepted
cases (a CRS in feet, a file in the neighbouring UTM zone near the project's) are converted rigorously."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import Transformer

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import InputError
from aerotri.exchange.patb import numbering, orientation_text
from aerotri.geom.eo import ExteriorOrientations, GnssPositions, format_gnss, read_eo

OPK = np.array([[0.5, -0.3, 10.0], [0.2, 0.4, 12.0], [-0.1, 0.1, 8.0]])


def _project(tmp_path, crs, name="p"):
    root = tmp_path / name
    root.mkdir()
    (root / "project.toml").write_text(f'[project]\nname = "{name}"\ncrs = "{crs}"\n')
    return root


def _listing(root):
    return sorted((str(p.relative_to(root)), p.stat().st_size) for p in root.rglob("*"))


def _lonlat_block(lon, lat, h=1200.0):
    """Three projection centres 200 m apart around lon, lat (WGS84), height h."""
    d = np.array([[0.0, 0.0], [0.002, 0.0], [0.004, 0.0005]])
    return np.column_stack([lon + d[:, 0], lat + d[:, 1], np.full(3, h)])


def _to(crs, lonlat_h):
    x, y = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lonlat_h[:, 0], lonlat_h[:, 1])
    return np.column_stack([x, y, lonlat_h[:, 2]])


def _opk_csv(tmp_path, xyz, prj_crs, ids=("a", "b", "c")):
    from pyproj import CRS

    f = tmp_path / "ext_param.csv"
    f.write_text("filename,x,y,z,omega,phi,kappa\n" + "".join(
        f"{i},{x:.4f},{y:.4f},{z:.4f},{o},{p},{k}\n" for i, (x, y, z), (o, p, k) in zip(ids, xyz, OPK)))
    f.with_suffix(".prj").write_text(CRS(prj_crs).to_wkt())
    return f


def _ori(tmp_path, xyz, ids=("a", "b", "c")):
    eo = ExteriorOrientations(list(ids), np.asarray(xyz, float), OPK.copy())
    numbers = numbering(ids)  # not plain integers: 1, 2, ... in order
    (tmp_path / "block.ori").write_text(orientation_text(eo, numbers))
    (tmp_path / "numbers.txt").write_text("".join(f"photo {n} {i}\n" for i, n in zip(numbers.ids, numbers.numbers)))
    return [tmp_path / "block.ori", tmp_path / "numbers.txt"]


def _import(root, fmt, files, *extra):
    return CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", fmt, *map(str, files), *extra])


def _refused(root, fmt, files, message, *extra):
    before = _listing(root)
    r = _import(root, fmt, files, *extra)
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output, r.output
    assert _listing(root) == before


def test_geographic_project_crs_is_refused(tmp_path):
    root = _project(tmp_path, "EPSG:4326")
    f = _opk_csv(tmp_path, _to("EPSG:32610", _lonlat_block(-121.9, 37.4)), "EPSG:32610")
    _refused(root, "orthority", [f], "is geographic")


def test_project_in_feet(tmp_path):
    """A State Plane project in US survey feet: a file with its CRS is converted (positions in feet, the console
    says so); a file without a CRS needs --crs (metres or feet cannot be told), then it is taken as stated."""
    ft = "EPSG:2227"  # NAD83 / California zone 3 (ftUS)
    root = _project(tmp_path, ft)
    lonlat = _lonlat_block(-121.9, 37.4)
    utm = _to("EPSG:26910", lonlat)  # NAD83 / UTM 10N, metres
    r = _import(root, "orthority", [_opk_csv(tmp_path, utm, "EPSG:26910")])
    assert r.exit_code == 0, r.output
    assert "is in US survey foot: imported positions converted to US survey foot" in r.output
    eo = read_eo(root / "imported" / "eo.txt")
    want = _to(ft, lonlat)
    assert np.abs(eo.centre_m[:, :2] - want[:, :2]).max() < 1e-3
    assert np.allclose(eo.centre_m[:, 2], utm[:, 2] * 3937 / 1200, atol=1e-3)  # heights in feet too
    other = _project(tmp_path, ft, "q")
    files = _ori(tmp_path, want)
    _refused(other, "patb", files, "carry no CRS and the project CRS EPSG:2227 is in US survey foot")
    r = _import(other, "patb", files, "--crs", ft)
    assert r.exit_code == 0, r.output
    assert np.abs(read_eo(other / "imported" / "eo.txt").centre_m - want).max() < 1e-3


def test_declared_neighbouring_zone_is_transformed_rigorously(tmp_path):
    """UTM 11N coordinates of a block 0.6 degrees east of zone 10's edge, with their CRS, into a UTM 10N project:
    transformed through the CRS policy (pyproj's own result to 1 mm)."""
    root = _project(tmp_path, "EPSG:32610")
    lonlat = _lonlat_block(-119.4, 36.0)
    r = _import(root, "orthority", [_opk_csv(tmp_path, _to("EPSG:32611", lonlat), "EPSG:32611")])
    assert r.exit_code == 0, r.output
    assert np.abs(read_eo(root / "imported" / "eo.txt").centre_m - _to("EPSG:32610", lonlat)).max() < 1e-3


def test_block_far_in_another_zone_is_refused(tmp_path):
    """The same with a block 3 degrees east of zone 10 (in the middle of zone 11): the project's CRS does not fit
    the block."""
    root = _project(tmp_path, "EPSG:32610")
    f = _opk_csv(tmp_path, _to("EPSG:32611", _lonlat_block(-117.0, 36.0)), "EPSG:32611")
    _refused(root, "orthority", [f], "lies outside the area of use of EPSG:32610")
    # the numbers quoted are the file's converted into the project CRS, said so (kite trial: read as the file's)
    _refused(root, "orthority", [f], "These are the file's coordinates converted from the CRS it names (or --crs) "
                                     "into the project CRS EPSG:32610: if the file is right, the project's CRS")


def test_undeclared_coordinates_of_another_zone_are_refused(tmp_path):
    """PAT-B orientations carry no CRS: UTM 11N numbers read in a UTM 10N project land 5 degrees west, inside zone
    10, where only the project's own positions (gnss.txt) can tell: refused, naming the distance."""
    root = _project(tmp_path, "EPSG:32610")
    lonlat = _lonlat_block(-119.3, 36.0)
    (root / "gnss.txt").write_text(format_gnss(GnssPositions(["a", "b", "c"], _to("EPSG:32610", lonlat))))
    files = _ori(tmp_path, _to("EPSG:32611", lonlat))
    _refused(root, "patb", files, "km from the project's positions")
    r = _import(root, "patb", files, "--crs", "EPSG:32611")  # stated: transformed, and near the project's
    assert r.exit_code == 0, r.output
    assert np.abs(read_eo(root / "imported" / "eo.txt").centre_m - _to("EPSG:32610", lonlat)).max() < 1e-3


def test_image_ids_that_are_no_frames(tmp_path):
    root = _project(tmp_path, "EPSG:32610")
    (root / "images").mkdir()
    for name in ("a.tif", "b.tif"):
        (root / "images" / name).write_bytes(b"")
    files = _ori(tmp_path, _to("EPSG:32610", _lonlat_block(-121.9, 37.4)), ids=("a", "b", "x9"))
    _refused(root, "patb", files, "orientations of image(s) x9 that are not frames in")
    files = _ori(tmp_path, _to("EPSG:32610", _lonlat_block(-121.9, 37.4)), ids=("a", "b", "b2"))[:1]
    _refused(root, "patb", files, "orientations of image(s) 1, 2, 3 that are not frames")  # numbers without the map


@pytest.mark.parametrize("crs", ["EPSG:4978", "EPSG:4979"])
def test_geocentric_or_3d_geographic_project_is_refused(tmp_path, crs):
    root = _project(tmp_path, crs)
    f = _opk_csv(tmp_path, _to("EPSG:32610", _lonlat_block(-121.9, 37.4)), "EPSG:32610")
    _refused(root, "orthority", [f], "the photo block needs a projected CRS")


def test_measurements_of_points_that_are_no_control(tmp_path):
    """MicMac measurements of a point that neither the imported control nor control/points.csv has: named, exit 2;
    measurements alone without any control file: refused too."""
    root = _project(tmp_path, "EPSG:32610")
    x, y, _ = _to("EPSG:32610", _lonlat_block(-121.9, 37.4))[0]
    gcp = tmp_path / "gcp.xml"
    gcp.write_text(f"<Global><DicoAppuisFlottant><OneAppuisDAF><Pt>{x} {y} 10</Pt><NamePt>g1</NamePt>"
                   "<Incertitude>0.02 0.02 0.03</Incertitude></OneAppuisDAF></DicoAppuisFlottant></Global>")
    mes = tmp_path / "measures.xml"
    mes.write_text("<SetOfMesureAppuisFlottants><MesureAppuiFlottant1Im><NameIm>a.tif</NameIm>"
                   "<OneMesureAF1I><NamePt>g1</NamePt><PtIm>10 20</PtIm></OneMesureAF1I>"
                   "<OneMesureAF1I><NamePt>g7</NamePt><PtIm>30 40</PtIm></OneMesureAF1I>"
                   "</MesureAppuiFlottant1Im></SetOfMesureAppuisFlottants>")
    _refused(root, "micmac", [gcp, mes], "measurements of point(s) g7 that are not control points in gcp.xml")
    _refused(root, "micmac", [mes], "image measurements of points no control file names")


def test_control_of_any_format_with_unmeasured_heights_is_plan_only():
    """All heights 0 (or one number for 3 or more points) in any importer's control: full points horizontal,
    height-only points dropped, a note; --heights-measured keeps them; surveyed heights stay as they are."""
    import numpy as np

    from aerotri.exchange.import_checks import plan_only_when_unmeasured
    from aerotri.exchange.imported import ImportedBlock
    from aerotri.geom.observations import ControlPoints

    def block(z):
        ids = np.array(["a", "b", "c", "d"], dtype=object)
        kind = np.array(["full", "full", "height", "horizontal"], dtype=object)
        xyz = np.column_stack([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0], z])
        b = ImportedBlock(source=["x.con"])
        b.control = ControlPoints(ids, kind, xyz, np.ones((4, 3)))
        return b

    b = block([0.0, 0.0, 0.0, 0.0])
    plan_only_when_unmeasured(b, False, "patb")
    assert list(b.control.id) == ["a", "b", "d"] and set(b.control.kind) == {"horizontal"}
    assert "all 3 heights are 0" in b.notes[-1] and "--heights-measured" in b.notes[-1]
    b = block([12.5, 12.5, 12.5, 0.0])
    plan_only_when_unmeasured(b, False, "patb")
    assert "all 3 heights are 12.5" in b.notes[-1]
    b = block([0.0, 0.0, 0.0, 0.0])
    plan_only_when_unmeasured(b, True, "patb")
    assert list(b.control.kind) == ["full", "full", "height", "horizontal"] and not b.notes
    b = block([10.1, 12.4, 9.8, 0.0])
    plan_only_when_unmeasured(b, False, "patb")
    assert list(b.control.kind) == ["full", "full", "height", "horizontal"] and not b.notes


def test_camera_of_another_size_than_the_frames(tmp_path):
    """A COLMAP model made on frames resized by 2 (as pipelines downscale them) is refused at the import, naming
    the factor, and nothing is written (it was written, and refused only by ``aerotri match``)."""
    import rasterio

    root = _project(tmp_path, "EPSG:32610")
    (root / "images").mkdir()
    xyz = _to("EPSG:32610", _lonlat_block(-121.9, 37.4))
    m = tmp_path / "model"
    m.mkdir()
    (m / "cameras.txt").write_text("1 PINHOLE 100 80 120 120 50 40\n")
    (m / "images.txt").write_text("".join(f"{n + 1} 1 0 0 0 {-x:.4f} {-y:.4f} {-z:.4f} 1 {i}.jpg\n\n"
                                          for n, (i, (x, y, z)) in enumerate(zip("abc", xyz))))
    (m / "georef.txt").write_text("frame crs\ncrs EPSG:32610\n")
    for size in ((200, 160), (100, 80)):
        for i in "abc":
            with rasterio.open(root / "images" / f"{i}.tif", "w", driver="GTiff", width=size[0], height=size[1],
                               count=1, dtype="uint8") as ds:
                ds.write(np.zeros((1, size[1], size[0]), np.uint8))
        if size == (200, 160):
            _refused(root, "colmap", [m], "the camera is 100 x 80 px but the frames in")
            assert "scaled by 2 would fit" in _import(root, "colmap", [m]).output
        else:
            assert _import(root, "colmap", [m]).exit_code == 0 and (root / "camera.toml").is_file()


def test_camera_convention_mistakes_are_refused_in_the_files_terms(tmp_path):
    """Review 21: COLMAP's cx, cy = 0, 0 put the principal point exactly half the frame off the centre, which the
    strict "outside the frame" test passed (exit 0, pp at the corner); now over a quarter of the side is refused,
    naming COLMAP's fields and its convention. Metashape's corner values in its centre-offset fields alike."""
    root = _project(tmp_path, "EPSG:32610")
    xyz = _to("EPSG:32610", _lonlat_block(-121.9, 37.4))
    m = tmp_path / "model"
    m.mkdir()
    (m / "images.txt").write_text("".join(f"{n + 1} 1 0 0 0 {-x:.4f} {-y:.4f} {-z:.4f} 1 {i}.jpg\n\n"
                                          for n, (i, (x, y, z)) in enumerate(zip("abc", xyz))))
    (m / "georef.txt").write_text("frame crs\ncrs EPSG:32610\n")
    (m / "cameras.txt").write_text("1 PINHOLE 100 80 120 120 0 0\n")
    _refused(root, "colmap", [m], "cameras.txt cx, cy put the principal point -50.0 / -40.0 px (x right / y down) "
             "from the image centre, 50 / 50 % of the 100 x 80 px frame (limit 25 %")
    assert "COLMAP's cx, cy are pixels from the image's top-left corner" in _import(root, "colmap", [m]).output
    (m / "cameras.txt").write_text("1 PINHOLE 100 80 120 120 70 50\n")  # 20 / 12.5 % off: a camera, read
    assert _import(root, "colmap", [m]).exit_code == 0
    # Metashape: cx, cy are offsets from the centre in px; 864, 480 (the centre's pixel position) on 1728 x 960
    from aerotri.exchange.import_checks import CAMERA_FILE_FIELDS
    from aerotri.geom.camera import BrownCamera

    pix = 0.0096  # mm, as metashape.py builds it: ppx_mm = cx * pix, ppy_mm = -cy * pix
    cam = BrownCamera(focal_mm=120.0, pixel_um=9.6, width=1728, height=960, ppx_mm=864 * pix, ppy_mm=-480 * pix)
    with pytest.raises(InputError, match=r"cameras.xml: <calibration> cx, cy put the principal point \+864.0 / "
                                         r"\+480.0 px .* Metashape's cx, cy are the offset from the image centre"):
        cam.check_plausible("cameras.xml", CAMERA_FILE_FIELDS["metashape"])


def test_an_orthority_focal_length_in_mm_without_sensor_size_is_said(tmp_path):
    """Review 21: focal_len 8.8 (mm) with sensor_size left out reads as 8.8 image widths, a 15,206 px lens on
    1728 px frames (a 6.5 deg field of view), which passed without a word; the import now says so (over 4 sides)."""
    root = _project(tmp_path, "EPSG:32610")
    f = tmp_path / "int_param.yaml"
    for focal, said in ((8.8, True), (0.67, False)):  # 0.67: Tuniu's DJI FC6310R over its width
        f.write_text(f"cam:\n  type: pinhole\n  im_size: [1728, 960]\n  focal_len: {focal}\n")
        r = _import(root, "orthority", [f], "--force")
        assert r.exit_code == 0, r.output
        warning = ("focal_len 8.8 without sensor_size is over the image width (orthority's convention): 15206.4 px, "
                   "8.8 x the longer side, a field of view of 6.5 deg; if focal_len is in mm, give sensor_size")
        assert (warning in r.output) == said
