"""Broken LAS/LAZ input in every lidarctl command: one line naming the file (and record), exit code 2,
no output; header point counts, scale factors, CRSs of several strips, impossible grids, option
ranges and outputs that would replace an input (issue 17)."""

from __future__ import annotations

import importlib.util
import struct
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from click.testing import CliRunner
from laspy.vlrs.known import GeoKeyEntryStruct

from aerotri.core.errors import CrsError, InputError
from lidarctl import io, synthetic
from lidarctl.cli.main import main
from aerotri.geom.las import FOOT_M

_spec = importlib.util.spec_from_file_location("corners_synth", Path(__file__).with_name("corners_synth.py"))
cs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cs)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A classified synthetic scene as LAS 1.4, LAS 1.2 and LAZ (two LAZ chunks of 50,000 points)."""
    d = tmp_path_factory.mktemp("robust")
    cloud, truth = synthetic.synthetic_scene(width_m=130.0, density_per_m2=4.0, seed=3, n_buildings=4)
    assert len(cloud) > 50_000
    synthetic.write_las(d / "c14.las", cloud, classification=truth, crs="EPSG:32632")
    synthetic.write_las(d / "c12.las", cloud, classification=truth, crs="EPSG:32632", version="1.2")
    synthetic.write_las(d / "c.laz", cloud, classification=truth, crs="EPSG:32632")
    # another scene on the same ground: a second strip that is not the first one again (the same points under other
    # bytes are refused, lidarctl.io.check_distinct_clouds)
    other, other_truth = synthetic.synthetic_scene(width_m=130.0, density_per_m2=4.0, seed=4, n_buildings=4)
    synthetic.write_las(d / "other14.las", other, classification=other_truth, crs="EPSG:32632")
    rng = np.random.default_rng(1)
    px, py = cloud.x.min() + rng.uniform(10, 120, 5), cloud.y.min() + rng.uniform(10, 120, 5)
    (d / "points.csv").write_text("id,x,y,z\n" + "".join(
        f"P{k},{a:.3f},{b:.3f},{synthetic.terrain_height(a - 500000.0, b - 5400000.0):.3f}\n"
        for k, (a, b) in enumerate(zip(px, py))))
    return d, len(cloud)


def _commands(bad: Path, good: Path, points: Path, out: Path):
    """Every lidarctl command reading ``bad`` (a classified cloud), writing under ``out``."""
    return {
        "classify": ["classify", bad, out / "o.laz"],
        "rasters": ["rasters", bad, out / "r", "--res-m", "2"],
        "evaluate": ["evaluate", bad, "--truth", good],
        "evaluate-truth": ["evaluate", good, "--truth", bad],
        "check-heights": ["check-heights", bad, points, "--json", out / "hc.json"],
        "corners": ["corners", bad, out / "co"],
        "corners-second": ["corners", good.parent / "other14.las", bad, out / "co2"],
    }


def _fails_everywhere(bad: Path, good: Path, points: Path, out: Path, *texts):
    out.mkdir(exist_ok=True)
    for name, args in _commands(bad, good, points, out).items():
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code == 2, (name, r.output, r.exception)
        assert r.output.startswith("Error: ") and r.output.count("\n") == 1, (name, r.output)
        for t in (str(bad), *texts):
            assert t in r.output, (name, t, r.output)
    assert not any(p for p in out.rglob("*")), list(out.rglob("*"))      # nothing written


def _set_count(src: Path, dst: Path, n: int) -> None:
    b = bytearray(src.read_bytes())
    b[107:111] = struct.pack("<I", n)          # legacy point count
    if b[25] >= 4:
        b[247:255] = struct.pack("<Q", n)      # LAS 1.4 point count
    dst.write_bytes(bytes(b))


@pytest.mark.parametrize("name", ["c14.las", "c12.las", "c.laz"])
def test_header_point_count_lower_than_the_records_is_refused(files, tmp_path, name):
    d, n = files
    bad = tmp_path / f"low_{name}"
    _set_count(d / name, bad, n // 2)
    held = str(n) if name.endswith(".las") else "at least 50001"
    _fails_everywhere(bad, d / "c14.las", d / "points.csv", tmp_path / "out", f"header says {n // 2} points",
                      f"holds {held} point records")
    # a count above the records: a truncated file, both counts named
    _set_count(d / name, bad, n + 10 if name.endswith(".las") else 100_001)
    with pytest.raises(InputError, match="truncated"):
        io.read_cloud(bad)


def test_an_empty_laz_is_refused_as_holding_no_points(files, tmp_path):
    """laspy with lazrs writes an empty cloud as one chunk of no bytes; it was refused as a header that says 0 points
    over 'at least 1 point records' (fix the header), which sent the user after a header that is right (a helper's
    crash hunt, stop 118)."""
    d, _ = files
    las = laspy.read(d / "c.laz")
    empty = laspy.LasData(las.header)
    empty.points = las.points[:0]
    empty.update_header()
    empty.write(tmp_path / "empty.laz", laz_backend=laspy.LazBackend.Lazrs)   # the single-threaded writer
    _fails_everywhere(tmp_path / "empty.laz", d / "c14.las", d / "points.csv", tmp_path / "out",
                      "the file holds no points")


@pytest.mark.realdata
def test_autzen_with_half_its_header_count_is_refused(shared_data, tmp_path):
    src = shared_data / "autzen" / "autzen_trim.laz"
    if not src.is_file():
        pytest.skip(f"{src} not found")
    _set_count(src, tmp_path / "half.laz", 55_000)
    with pytest.raises(InputError, match=r"header says 55000 points but the file holds at least 100001"):
        io.read_cloud(tmp_path / "half.laz")


@pytest.mark.parametrize("offset,value,text", [(131, 0.0, "x scale factor 0.0"), (139, float("nan"), "y scale factor nan"),
                                               (147, float("inf"), "z scale factor inf"),
                                               (155, float("nan"), "x offset nan")])
def test_zero_or_non_finite_scales_and_offsets(files, tmp_path, offset, value, text):
    d, _ = files
    b = bytearray((d / "c14.las").read_bytes())
    b[offset:offset + 8] = struct.pack("<d", value)
    bad = tmp_path / "scale.las"
    bad.write_bytes(bytes(b))
    _fails_everywhere(bad, d / "c14.las", d / "points.csv", tmp_path / "out", text)


@pytest.mark.parametrize("kind", ["truncated_laz", "truncated_las", "corrupt_laz"])
def test_truncated_or_corrupt_files_in_every_command(files, tmp_path, kind):
    d, n = files
    bad = tmp_path / ("bad.laz" if kind.endswith("laz") else "bad.las")
    data = (d / ("c.laz" if kind.endswith("laz") else "c14.las")).read_bytes()
    if kind.startswith("truncated"):
        bad.write_bytes(data[: len(data) * 2 // 3])
        texts = ["truncated"]
    else:
        # garbage inside the second LAZ chunk: the decoder fails in that block of records
        b = bytearray(data)
        start = len(b) // 2
        b[start:start + 3000] = np.random.default_rng(0).integers(0, 256, 3000).astype(np.uint8).tobytes()
        bad.write_bytes(bytes(b))
        texts = ["corrupt point data in records 0-", f"of {n}"]
    _fails_everywhere(bad, d / "c14.las", d / "points.csv", tmp_path / "out", *texts)


def _corner_strip(path, crs, e0, n0, seed):
    buildings = cs.default_buildings()
    x, y, z, cls, sid = cs.make_cloud(buildings, seed=seed)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([e0, n0, 0.0])
    header.add_crs(pyproj.CRS(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x + e0, y + n0, z
    las.classification, las.point_source_id = cls, sid
    las.write(path)


def test_strips_in_different_crss_are_refused_naming_the_file(tmp_path):
    _corner_strip(tmp_path / "a.las", "EPSG:32649", 452000.0, 3407000.0, 1)
    _corner_strip(tmp_path / "b.las", "EPSG:32650", 248000.0, 3407000.0, 2)
    r = CliRunner().invoke(main, ["corners", str(tmp_path / "a.las"), str(tmp_path / "b.las"), str(tmp_path / "o")])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert f"{tmp_path / 'b.las'}: CRS EPSG:32650" in r.output and "differs from the CRS of" in r.output
    assert not (tmp_path / "o").exists()


def test_strips_far_apart_are_refused_before_allocating(tmp_path):
    """Two strips labelled with one UTM zone but 700 km apart (one of them belongs to the next zone):
    corners work by tiles where the points are (no grid over the gap), so they come out of both
    strips as from each alone (up to the grid's anchoring: the joint grid starts at the union's
    corner); the commands that still need one grid refuse it instead of running out of memory."""
    _corner_strip(tmp_path / "a.las", "EPSG:32649", 452000.0, 3407000.0, 1)
    _corner_strip(tmp_path / "b.las", "EPSG:32649", 1152000.0, 4107000.0, 2)

    def corners(*names):
        out = tmp_path / ("o_" + "".join(names))
        r = CliRunner().invoke(main, ["corners", *[str(tmp_path / f"{n}.las") for n in names], str(out)])
        assert r.exit_code == 0, r.output
        xyz = np.loadtxt(out / "corners.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3, 14))
        return xyz[:, :3], xyz[:, 3].astype(bool)

    (xa, ua), (xb, ub), (xab, uab) = corners("a"), corners("b"), corners("a", "b")
    alone, alone_usable = np.vstack([xa, xb]), np.concatenate([ua, ub])
    assert uab.sum() == alone_usable.sum() > 0
    d_m = np.linalg.norm(alone[alone_usable][:, None, :2] - xab[uab][None, :, :2], axis=2).min(axis=1)
    assert d_m.max() < 0.5, d_m.max()
    merged = tmp_path / "merged.las"
    a, b = laspy.read(tmp_path / "a.las"), laspy.read(tmp_path / "b.las")
    las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    las.header.scales, las.header.offsets = a.header.scales, a.header.offsets
    las.header.add_crs(pyproj.CRS("EPSG:32649"))
    las.x, las.y, las.z = np.concatenate([a.x, b.x]), np.concatenate([a.y, b.y]), np.concatenate([a.z, b.z])
    las.classification = np.concatenate([a.classification, b.classification])
    las.write(merged)
    for args, text in ((["rasters", merged, tmp_path / "r", "--res-m", "1"], "--res-m"),
                       (["classify", merged, tmp_path / "c.laz"], "are strips far apart")):
        r = CliRunner().invoke(main, [str(x) for x in args])
        assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
        assert str(merged) in r.output and "GiB" in r.output and text in r.output, r.output
    assert not (tmp_path / "r").exists() and not (tmp_path / "c.laz").exists()


@pytest.mark.parametrize("args,option", [
    (["classify", "{las}", "{out}/o.laz", "--tile-size-m", "0"], "--tile-size-m"),
    (["classify", "{las}", "{out}/o.laz", "--tile-size-m", "-50"], "--tile-size-m"),
    (["classify", "{las}", "{out}/o.laz", "--buffer-m", "0"], "--buffer-m"),
    (["classify", "{las}", "{out}/o.laz", "--buffer-m", "-5"], "--buffer-m"),
    (["classify", "{las}", "{out}/o.laz", "--tile-size-m", "nan"], "--tile-size-m"),
    (["rasters", "{las}", "{out}/r", "--res-m", "0"], "--res-m"),
    (["rasters", "{las}", "{out}/r", "--res-m", "-1"], "--res-m"),
    (["rasters", "{las}", "{out}/r", "--res-m", "nan"], "--res-m"),
    (["check-heights", "{las}", "{pts}", "--radius-m", "-1"], "--radius-m"),
    (["check-heights", "{las}", "{pts}", "--radius-m", "0"], "--radius-m"),
    (["check-heights", "{las}", "{pts}", "--exclude-m", "-0.5"], "--exclude-m"),
    (["check-heights", "{las}", "{pts}", "--radius-m", "inf"], "--radius-m"),
    (["corners", "{las}", "{out}/co", "--min-edge-m", "0.1"], "--min-edge-m"),
    (["corners", "{las}", "{out}/co", "--sigma-strip-xy-m", "-1"], "--sigma-strip-xy-m"),
])
def test_out_of_range_options_name_the_option(files, tmp_path, args, option):
    d, _ = files
    args = [a.format(las=d / "c14.las", out=tmp_path, pts=d / "points.csv") for a in args]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    assert option in r.output, r.output
    assert not any(tmp_path.iterdir())


def test_outputs_never_replace_an_input(files, tmp_path):
    d, _ = files
    las = tmp_path / "in.las"
    las.write_bytes((d / "c14.las").read_bytes())
    before = las.read_bytes()
    pts = tmp_path / "points.csv"
    pts.write_bytes((d / "points.csv").read_bytes())
    # a classified cloud that happens to carry an output's name inside the output folder
    (tmp_path / "out").mkdir()
    disguised = tmp_path / "out" / "dem.tif"
    disguised.write_bytes(before)
    corners_json = tmp_path / "out" / "corners.json"
    corners_json.write_bytes(before)
    for args in (["classify", las, las],
                 ["evaluate", las, "--truth", d / "c14.las", "--json", las],
                 ["check-heights", las, pts, "--json", pts],
                 ["rasters", disguised, tmp_path / "out", "--res-m", "2"],
                 ["corners", corners_json, tmp_path / "out"]):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code == 2 and "the output is the input" in r.output, (args, r.output)
    assert las.read_bytes() == before and pts.read_bytes() == (d / "points.csv").read_bytes()
    assert disguised.read_bytes() == before and corners_json.read_bytes() == before
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["corners.json", "dem.tif"]


def test_vertical_unit_from_the_geotiff_keys(files, tmp_path):
    """A LAS 1.2 file with a metric EPSG CRS and VerticalUnitsGeoKey = foot: z is scaled as feet."""
    d, _ = files
    las = laspy.read(d / "c12.las")
    vlr = next(v for v in las.header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
    key = GeoKeyEntryStruct()
    key.id, key.tiff_tag_location, key.count, key.value_offset = 4099, 0, 1, 9002
    vlr.geo_keys.append(key)
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)
    las.write(tmp_path / "zft.las")
    c = io.read_cloud(tmp_path / "zft.las")
    assert c.units.xy_m == 1.0 and c.units.z_m == FOOT_M
    ref = io.read_cloud(d / "c12.las")
    np.testing.assert_allclose(c.z, ref.z * FOOT_M)
    np.testing.assert_array_equal(c.x, ref.x)


def _user_defined_vertical_copy(files, tmp_path, name, size_m):
    """c12.las (EPSG:32632, metres) with heights in feet, keyed VerticalUnitsGeoKey = 32767 (user-defined) and,
    when given, GeogLinearUnitSizeGeoKey (2053) = ``size_m`` in a GeoDoubleParams record."""
    import ctypes

    from laspy.vlrs.known import GeoDoubleParamsVlr

    d, _ = files
    src = laspy.read(d / "c12.las")
    las = laspy.LasData(laspy.LasHeader(version="1.2", point_format=src.header.point_format.id))
    las.header.vlrs = [v for v in src.header.vlrs if type(v).__name__ != "GeoDoubleParamsVlr"]
    las.header.scales, las.header.offsets = src.header.scales, src.header.offsets
    for dim in ("classification", "intensity", "return_number", "number_of_returns"):
        las[dim] = src[dim]
    las.x, las.y, las.z = src.x, src.y, src.z / FOOT_M
    vlr = next(v for v in las.header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
    keys = [(4099, 0, 32767)] + ([(2053, 34736, 0)] if size_m is not None else [])
    for key_id, location, value in keys:
        key = GeoKeyEntryStruct()
        key.id, key.tiff_tag_location, key.count, key.value_offset = key_id, location, 1, value
        vlr.geo_keys.append(key)
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)
    if size_m is not None:
        doubles = GeoDoubleParamsVlr()
        doubles.doubles = [ctypes.c_double(size_m)]
        las.header.vlrs.append(doubles)
    las.write(tmp_path / name)
    return tmp_path / name


def test_user_defined_vertical_units_key_takes_its_size(files, tmp_path):
    """trial-qa: VerticalUnitsGeoKey 32767 (user-defined) fell back to the horizontal unit: heights in feet read as
    metres (3.28x too high, silently). Its size is GeogLinearUnitSizeGeoKey's (2053, GeoTIFF 1.1 annex B); without
    it the file is refused naming the file and the key, and --crs replaces it, as for the horizontal units key."""
    d, _ = files
    ref = io.read_cloud(d / "c12.las")
    c = io.read_cloud(_user_defined_vertical_copy(files, tmp_path, "zft.las", FOOT_M))
    assert c.units.xy_m == 1.0 and c.units.z_m == pytest.approx(FOOT_M, rel=1e-12)
    np.testing.assert_allclose(c.z, ref.z, atol=0.01)
    np.testing.assert_array_equal(c.x, ref.x)
    bad = _user_defined_vertical_copy(files, tmp_path, "nosize.las", None)
    with pytest.raises(InputError, match=r"nosize.las: CRS record present but unreadable \(VerticalUnitsGeoKey "
                                         r"\(4099\) is user-defined \(32767\) but GeogLinearUnitSizeGeoKey \(2053\)"):
        io.read_cloud(bad)
    r = CliRunner().invoke(main, ["rasters", str(bad), str(tmp_path / "r"), "--res-m", "2"])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "nosize.las" in r.output, r.output
    assert "GeogLinearUnitSizeGeoKey (2053)" in r.output and "--crs" in r.output and not (tmp_path / "r").exists()
    # --crs in its place: a compound CRS gives the heights' unit (NAVD88 height (ft), EPSG:8228)
    c = io.read_cloud(bad, crs="EPSG:32632+8228")
    assert c.units.z_m == pytest.approx(FOOT_M) and c.units.xy_m == 1.0
    np.testing.assert_allclose(c.z, ref.z, atol=0.01)
    r = CliRunner().invoke(main, ["rasters", str(bad), str(tmp_path / "r"), "--res-m", "2", "--crs", "EPSG:32632+8228"])
    assert r.exit_code == 0 and "--crs EPSG:32632+8228 used in its place" in r.output, r.output


def test_a_vertical_unit_without_an_epsg_code_is_written_with_its_size(tmp_path):
    """add_crs wrote VerticalUnitsGeoKey 32767 without a size for a vertical unit no EPSG code names (now refused
    when read back): the size goes into GeogLinearUnitSizeGeoKey."""
    from aerotri.geom.las import add_crs, geokey_vertical_unit_m

    vertical = pyproj.CRS.from_epsg(5703).to_json_dict()   # NAVD88 height, in a unit of 0.5 m
    for axis in vertical["coordinate_system"]["axis"]:
        axis["unit"] = {"type": "LinearUnit", "name": "half metre", "conversion_factor": 0.5}
    vertical.pop("id", None)
    crs = pyproj.CRS.from_json_dict({"type": "CompoundCRS", "name": "UTM 32N + NAVD88 (half metre)",
                                     "components": [pyproj.CRS.from_epsg(32632).to_json_dict(), vertical]})
    header = laspy.LasHeader(version="1.2", point_format=1)
    add_crs(header, crs)
    assert geokey_vertical_unit_m(header) == pytest.approx(0.5)
    header = laspy.LasHeader(version="1.2", point_format=1)
    add_crs(header, pyproj.CRS("EPSG:32632+6360"))     # NAVD88 height (ftUS): the EPSG code, no size
    keys = {k.id: k.value_offset for v in header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr" for k in v.geo_keys}
    assert keys[4099] == 9003 and 2053 not in keys and geokey_vertical_unit_m(header) == pytest.approx(1200 / 3937)


def _header_with_keys(crs, **overrides):
    """A LAS 1.2 header with ``crs``'s GeoTIFF keys, the keys in ``overrides`` (k4099=5703) set to other values."""
    from aerotri.geom.las import add_crs

    header = laspy.LasHeader(version="1.2", point_format=1)
    add_crs(header, pyproj.CRS(crs))
    vlr = next(v for v in header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
    for k in vlr.geo_keys:
        if f"k{k.id}" in overrides:
            k.value_offset = overrides[f"k{k.id}"]
    return header


def test_a_datum_code_in_the_vertical_units_key_gives_way_to_the_vertical_crs(tmp_path):
    """sf-fixes: some writers put the vertical datum's code (5703) in VerticalUnitsGeoKey (4099); small-fixes refused
    such a file though VerticalCSTypeGeoKey (4096) names the vertical CRS and so its unit. Now that unit is read;
    without a vertical CRS the file is still refused. An EPSG unit beyond 9001-9003 (1025 millimetre) is read."""
    from aerotri.geom.las import geokey_vertical_unit_m

    header = _header_with_keys("EPSG:32632+5703", k4099=5703)           # NAVD88 height: metres
    keys = {k.id: k.value_offset for v in header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr" for k in v.geo_keys}
    assert keys[4096] == 5703 and keys[4099] == 5703
    assert geokey_vertical_unit_m(header) == 1.0
    header = _header_with_keys("EPSG:32632+6360", k4099=5703)           # NAVD88 height (ftUS)
    assert geokey_vertical_unit_m(header) == pytest.approx(1200 / 3937)
    las = laspy.LasData(_header_with_keys("EPSG:32632+5703", k4099=5703))
    las.x, las.y, las.z = [500000.0, 500010.0, 500020.0], [4e6, 4e6 + 10, 4e6], [200.0, 210.0, 205.0]
    las.classification = np.array([2, 2, 2], np.uint8)
    las.write(tmp_path / "vk5703.las")
    c = io.read_cloud(tmp_path / "vk5703.las")
    assert c.units.z_m == 1.0 and c.units.xy_m == 1.0
    np.testing.assert_allclose(c.z, [200.0, 210.0, 205.0])
    with pytest.raises(ValueError, match=r"\(4099\) is 5703, not an EPSG linear unit code, and VerticalCSTypeGeoKey"):
        geokey_vertical_unit_m(_header_with_keys("EPSG:32632+5703", k4099=5703, k4096=0))
    header = _header_with_keys("EPSG:32632+5703", k4099=1025)           # millimetre
    assert geokey_vertical_unit_m(header) == pytest.approx(0.001)


def test_a_huge_point_count_is_refused_before_allocating(files, tmp_path):
    """A LAZ file without chunk table (allowed) whose LAS 1.4 header claims 5 billion points: the
    count cannot be checked against the records, but reading it whole would not fit in memory."""
    d, _ = files
    b = bytearray((d / "c.laz").read_bytes())
    offset = struct.unpack("<I", b[96:100])[0]                 # offset to point data
    b[offset:offset + 8] = struct.pack("<q", -1)             # no chunk table
    b[247:255] = struct.pack("<Q", 5_000_000_000)
    bad = tmp_path / "huge.laz"
    bad.write_bytes(bytes(b))
    r = CliRunner().invoke(main, ["evaluate", str(bad), "--truth", str(d / "c.laz")])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert "huge.laz: reading its 5,000,000,000 points at once would need" in r.output and "GiB" in r.output
    # check-heights reads by chunks: it finds the records missing instead
    r = CliRunner().invoke(main, ["check-heights", str(bad), str(d / "points.csv")])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert "huge.laz: truncated or corrupt point data in records 0-" in r.output and "of 5000000000" in r.output


def _with_linear_units_key(las, code: int) -> None:
    vlr = next(v for v in las.header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
    vlr.geo_keys = [k for k in vlr.geo_keys if k.id != 3076]
    key = GeoKeyEntryStruct()
    key.id, key.tiff_tag_location, key.count, key.value_offset = 3076, 0, 1, code
    vlr.geo_keys.append(key)
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)


def test_linear_units_key_overrides_the_projected_crs_code(files, tmp_path):
    """GeoTIFF keys "EPSG:32632, ProjLinearUnitsGeoKey = US survey foot" (GDAL, PDAL and QGIS read feet): the
    coordinates were taken as metres (laspy reads the code alone), the rasters written 3.28x too large in EPSG:32632."""
    import rasterio

    from aerotri.geom.las import US_SURVEY_FOOT_M

    d, _ = files
    src = laspy.read(d / "c12.las")
    ref = io.read_cloud(d / "c12.las")
    las = laspy.LasData(laspy.LasHeader(version="1.2", point_format=src.header.point_format.id))
    las.header.vlrs = src.header.vlrs
    las.header.scales = np.array([0.01, 0.01, 0.01])
    las.header.offsets = np.array([1_640_000.0, 17_700_000.0, 0.0])
    for dim in ("classification", "intensity", "return_number", "number_of_returns"):
        las[dim] = src[dim]
    las.x, las.y, las.z = src.x / US_SURVEY_FOOT_M, src.y / US_SURVEY_FOOT_M, src.z / US_SURVEY_FOOT_M
    _with_linear_units_key(las, 9003)
    path = tmp_path / "ftus.las"
    las.write(path)
    c = io.read_cloud(path)
    assert c.units.xy_m == pytest.approx(US_SURVEY_FOOT_M) and c.units.z_m == pytest.approx(US_SURVEY_FOOT_M)
    np.testing.assert_allclose(c.x, ref.x, atol=0.01)
    np.testing.assert_allclose(c.y, ref.y, atol=0.01)
    # the CRS keeps its projection: the same places on the earth as the metre file
    lonlat = pyproj.Transformer.from_crs(c.crs, "EPSG:4326", always_xy=True).transform(las.x[:5], las.y[:5])
    np.testing.assert_allclose(lonlat, pyproj.Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True)
                               .transform(src.x[:5], src.y[:5]), atol=1e-8)
    r = CliRunner().invoke(main, ["rasters", str(path), str(tmp_path / "r"), "--res-m", "2"])
    assert r.exit_code == 0, r.output
    with rasterio.open(tmp_path / "r" / "dem.tif") as ds:
        assert ds.crs.linear_units == "US survey foot" and ds.res[0] == pytest.approx(2 / US_SURVEY_FOOT_M)
        assert ds.bounds.left <= las.x.min() <= ds.bounds.left + ds.res[0]
    # a key that agrees with the code changes nothing
    _with_linear_units_key(src, 9001)
    src.write(tmp_path / "m.las")
    assert io.read_cloud(tmp_path / "m.las").crs == ref.crs


def _ftus_copy(files, tmp_path, name, *, unit_key: int, size_m: float | None):
    """c12.las in US survey feet, keyed EPSG:32632 with ProjLinearUnitsGeoKey ``unit_key`` and (when given)
    ProjLinearUnitSizeGeoKey ``size_m`` in a GeoDoubleParams record; (path, the metre file's cloud)."""
    import ctypes

    from laspy.vlrs.known import GeoDoubleParamsVlr

    from aerotri.geom.las import US_SURVEY_FOOT_M

    d, _ = files
    src = laspy.read(d / "c12.las")
    las = laspy.LasData(laspy.LasHeader(version="1.2", point_format=src.header.point_format.id))
    las.header.vlrs = [v for v in src.header.vlrs if type(v).__name__ != "GeoDoubleParamsVlr"]
    las.header.scales = np.array([0.01, 0.01, 0.01])
    las.header.offsets = np.array([1_640_000.0, 17_700_000.0, 0.0])
    for dim in ("classification", "intensity", "return_number", "number_of_returns"):
        las[dim] = src[dim]
    las.x, las.y, las.z = src.x / US_SURVEY_FOOT_M, src.y / US_SURVEY_FOOT_M, src.z / US_SURVEY_FOOT_M
    _with_linear_units_key(las, unit_key)
    if size_m is not None:
        vlr = next(v for v in las.header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
        key = GeoKeyEntryStruct()
        key.id, key.tiff_tag_location, key.count, key.value_offset = 3077, 34736, 1, 0
        vlr.geo_keys.append(key)
        vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)
        doubles = GeoDoubleParamsVlr()
        doubles.doubles = [ctypes.c_double(size_m)]
        las.header.vlrs.append(doubles)
    path = tmp_path / name
    las.write(path)
    return path, io.read_cloud(d / "c12.las")


def test_user_defined_linear_units_key_takes_its_size(files, tmp_path):
    """ProjLinearUnitsGeoKey 32767 (user-defined) with ProjLinearUnitSizeGeoKey 0.3048006096 m: the file was read
    in the EPSG code's metres (coordinates 3.28x too large, silently); without the size it is refused."""
    from aerotri.geom.las import US_SURVEY_FOOT_M

    path, ref = _ftus_copy(files, tmp_path, "user.las", unit_key=32767, size_m=US_SURVEY_FOOT_M)
    c = io.read_cloud(path)
    assert c.units.xy_m == pytest.approx(US_SURVEY_FOOT_M, rel=1e-12)
    assert c.crs.axis_info[0].unit_name == "US survey foot"
    np.testing.assert_allclose(c.x, ref.x, atol=0.01)
    # a unit no EPSG code names: its size
    odd, _ = _ftus_copy(files, tmp_path, "odd.las", unit_key=32767, size_m=0.5)
    from aerotri.geom.las import read_header, read_header_crs
    crs = read_header_crs(odd, read_header(odd))
    assert crs.axis_info[0].unit_conversion_factor == pytest.approx(0.5) and "0.5 m" in crs.name
    bad, _ = _ftus_copy(files, tmp_path, "nosize.las", unit_key=32767, size_m=None)
    r = CliRunner().invoke(main, ["rasters", str(bad), str(tmp_path / "r"), "--res-m", "2"])
    assert r.exit_code == 2 and "ProjLinearUnitSizeGeoKey (3077)" in r.output and "nosize.las" in r.output, r.output
    assert not (tmp_path / "r").exists()
    from aerotri.cli import main as aerotri_main  # crs transform said "no CRS record in the file; give --from"

    r = CliRunner().invoke(aerotri_main, ["crs", "transform", str(bad), str(tmp_path / "o.las"), "--to", "EPSG:4978"])
    assert r.exit_code == 2 and "nosize.las: CRS record present but unreadable (ProjLinearUnitsGeoKey" in r.output
    assert "give --from" in r.output and not (tmp_path / "o.las").exists()


def test_units_key_crs_is_named_by_its_unit_and_crs_transform_says_why(files, tmp_path):
    """The CRS of "EPSG:32632 + US survey foot" keys kept the EPSG name ("WGS 84 / UTM zone 32N"), so that
    `aerotri crs transform --from EPSG:32632` refused it as "the file's CRS (WGS 84 / UTM zone 32N) is not --from
    EPSG:32632"; it is named with its unit now, and the refusal says the units."""
    from aerotri.cli import main as aerotri_main

    path, _ = _ftus_copy(files, tmp_path, "ftus.las", unit_key=9003, size_m=None)
    c = io.read_cloud(path)
    assert c.crs.name == "WGS 84 / UTM zone 32N (US survey foot)"
    r = CliRunner().invoke(aerotri_main, ["crs", "transform", str(path), str(tmp_path / "o.las"), "--from",
                                          "EPSG:32632", "--to", "EPSG:4978"])
    assert r.exit_code == 2 and "(WGS 84 / UTM zone 32N (US survey foot)) is not --from EPSG:32632" in r.output
    assert "coordinates are in US survey foot, --from's in metre" in r.output, r.output
    r = CliRunner().invoke(aerotri_main, ["crs", "transform", str(path), str(tmp_path / "o.las"), "--to",
                                          "EPSG:32632"])
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(laspy.read(tmp_path / "o.las").x, io.read_cloud(files[0] / "c12.las").x, atol=0.01)


def test_nebraska_read_from_its_geotiff_keys_alone_equals_its_wkt(shared_data, tmp_path):
    """laspy's Nebraska file keys EPSG:32104 (metres) with ProjLinearUnitsGeoKey US survey foot beside a WKT of
    NAD83(2011) / Nebraska (ftUS); without the WKT (as in a LAS 1.2 delivery) it was read as metres."""
    src = laspy.read(shared_data / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las")
    las = laspy.LasData(laspy.LasHeader(version="1.2", point_format=3))
    las.header.scales, las.header.offsets = src.header.scales, src.header.offsets
    las.header.vlrs = [v for v in src.header.vlrs if type(v).__name__ != "WktCoordinateSystemVlr"]
    las.x, las.y, las.z = src.x, src.y, src.z
    las.classification = src.classification
    las.write(tmp_path / "keys_only.las")
    c, ref = io.read_cloud(tmp_path / "keys_only.las"), io.read_cloud(
        shared_data / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las")
    assert c.units.xy_m == pytest.approx(ref.units.xy_m, rel=1e-12) and c.units.xy_m == pytest.approx(0.3048006096)
    np.testing.assert_allclose(c.x, ref.x, atol=1e-6)


def test_a_wkt_record_in_another_unit_than_the_keys_is_refused(shared_data, tmp_path, caplog):
    """Trial s99 lidmut H6: Nebraska's WKT record replaced by EPSG:32104's (metres), its GeoTIFF keys still in US
    survey feet: its 2,445,180 ft were read as metres, exit 0. The two units are named and nothing is written; with
    --crs in metres the coordinates lie 20 deg east of Nebraska (refused), and with the feet CRS it is read. The WKT
    record alone cannot be told wrong by a unit: that its coordinates lie far from its area is said."""
    from laspy.vlrs.known import WktCoordinateSystemVlr

    src = laspy.read(shared_data / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las")
    keys = [v for v in src.header.vlrs if not isinstance(v, WktCoordinateSystemVlr)]
    src.header.vlrs = [WktCoordinateSystemVlr(pyproj.CRS.from_epsg(32104).to_wkt())]
    src.write(tmp_path / "wkt_only.las")
    with caplog.at_level("WARNING", logger="lidarctl.io"):  # (before a command: the CLI's logging does not propagate)
        io.read_cloud(tmp_path / "wkt_only.las")
        io.read_cloud(tmp_path / "wkt_only.las")
    (said,) = [m for m in caplog.messages if "is the file's CRS record right?" in m]
    assert "more than 10 deg outside the area of use of EPSG:32104" in said and "aerotri crs assign" in said, said
    src.header.vlrs += keys
    path = tmp_path / "edited.las"
    src.write(path)
    with pytest.raises(CrsError, match="more than 10 deg outside the area of use"):
        io.read_cloud(path, crs="EPSG:32104")
    assert io.read_cloud(path, crs="EPSG:6880").units.xy_m == pytest.approx(0.3048006096)
    r = CliRunner().invoke(main, ["rasters", str(path), str(tmp_path / "r"), "--res-m", "10"])
    assert r.exit_code == 2 and not (tmp_path / "r").exists(), r.output
    assert "CRS records disagree (its WKT record (NAD83 / Nebraska) states metre, its GeoTIFF keys " \
           "ProjLinearUnitsGeoKey 9003 (US survey foot)" in r.output and "aerotri crs assign" in r.output, r.output


def _withheld_pair(d, tmp_path):
    """(file without 200 points, file with them flagged withheld and lowered 3-20 m, their indices, mask of the
    others) from c14.las (LAS 1.4); the points are interior, so that both files have the same horizontal bounds."""
    src = laspy.read(d / "c14.las")
    x, y = np.asarray(src.x), np.asarray(src.y)
    rng = np.random.default_rng(44)
    inner = np.flatnonzero((x > x.min() + 5) & (x < x.max() - 5) & (y > y.min() + 5) & (y < y.max() - 5))
    idx = np.sort(rng.choice(inner, 200, replace=False))
    moved = laspy.read(d / "c14.las")
    z = np.asarray(moved.z).copy()
    z[idx] -= rng.uniform(3.0, 20.0, len(idx))
    moved.z = z
    flag = np.zeros(len(x), bool)
    flag[idx] = True
    moved.withheld = flag
    moved.write(tmp_path / "withheld.las")
    keep = ~flag
    without = laspy.LasData(src.header)
    without.points = src.points[keep]
    without.write(tmp_path / "without.las")
    return tmp_path / "without.las", tmp_path / "withheld.las", idx, keep


@pytest.mark.parametrize("tiled", [False, True])
def test_withheld_points_are_left_out(files, tmp_path, tiled):
    """Points flagged withheld (the LAS spec: not to be used) were classified and gridded like the others (lidR
    Topography with 200 withheld points lowered 3-20 m: 10 became ground, the DEM moved by up to 4.41 m in 526 cells).
    Now they are left out of every computation (``aerotri.geom.las.usable``): the same classes and DEM as the file
    without them; ``classify`` writes every record, the withheld ones with their delivered class and flag."""
    import rasterio

    d, _ = files
    without, withheld, idx, keep = _withheld_pair(d, tmp_path)
    tile = ["--tile-size-m", "60"] if tiled else []
    said = []
    for src, name in ((without, "a"), (withheld, "b")):
        r = CliRunner().invoke(main, ["classify", str(src), str(tmp_path / f"{name}.las"), *tile])
        assert r.exit_code == 0, r.output
        said += r.output.splitlines()
        r = CliRunner().invoke(main, ["rasters", str(tmp_path / f"{name}.las"), str(tmp_path / f"r{name}"),
                                      "--res-m", "1"])
        assert r.exit_code == 0, r.output
    a, b = laspy.read(tmp_path / "a.las"), laspy.read(tmp_path / "b.las")
    delivered = laspy.read(withheld)
    assert len(b.points) == len(delivered.points)                # every record written
    np.testing.assert_array_equal(np.asarray(b.classification)[keep], np.asarray(a.classification))
    np.testing.assert_array_equal(np.asarray(b.classification)[idx], np.asarray(delivered.classification)[idx])
    np.testing.assert_array_equal(np.asarray(b.withheld), np.asarray(delivered.withheld))
    np.testing.assert_array_equal(np.asarray(b.z), np.asarray(delivered.z))
    for name in ("dem", "dsm"):
        with rasterio.open(tmp_path / "ra" / f"{name}.tif") as ra, rasterio.open(tmp_path / "rb" / f"{name}.tif") as rb:
            assert ra.transform == rb.transform
            np.testing.assert_array_equal(ra.read(1), rb.read(1))
    notes = [line for line in said if "withheld flag" in line]
    assert notes and "200 of" in notes[0] and f"first record {idx[0]}" in notes[0] and "left out" in notes[0]


def test_a_cloud_whose_every_point_is_withheld_is_refused_saying_so(files, tmp_path):
    """Every command refuses a cloud whose every record carries the withheld flag with that reason; ``rasters`` and
    ``corners`` (chunked readers) said "no ground points ... run lidarctl classify first" and "among 0 points, all
    of them unclassified" (a helper's crash hunt, stop 118)."""
    d, _ = files
    cloud = laspy.read(d / "c14.las")
    cloud.withheld = np.ones(len(cloud.points), bool)
    cloud.write(tmp_path / "withheld.las")
    _fails_everywhere(tmp_path / "withheld.las", d / "c14.las", d / "points.csv", tmp_path / "out",
                      f"every one of its {len(cloud.points):,} points carries the withheld flag")


def test_evaluate_names_withheld_points_when_the_counts_differ(files, tmp_path):
    """``evaluate`` compares point by point; a prediction whose withheld points are left out has fewer points than a
    truth without the flag: the message says why (it said only "same order needed")."""
    d, _ = files
    _, withheld, _, _ = _withheld_pair(d, tmp_path)
    r = CliRunner().invoke(main, ["evaluate", str(withheld), "--truth", str(d / "c14.las")])
    assert r.exit_code == 2 and "200 flagged withheld" in r.output, r.output
    r = CliRunner().invoke(main, ["evaluate", str(withheld), "--truth", str(withheld)])
    assert r.exit_code == 0, r.output


def test_crs_option_replaces_an_unreadable_crs_record(files, tmp_path):
    """review1: ProjLinearUnitsGeoKey 32767 without its size was refused "...; pass --crs", but the header's CRS
    was read before --crs was looked at, so --crs did not help (exit 2 anyway): now --crs is used in its place."""
    from aerotri.geom.las import US_SURVEY_FOOT_M

    bad, ref = _ftus_copy(files, tmp_path, "nosize.las", unit_key=32767, size_m=None)
    with pytest.raises(InputError, match="CRS record present but unreadable"):
        io.read_cloud(bad)
    ftus = "+proj=utm +zone=32 +datum=WGS84 +units=us-ft +no_defs"
    c = io.read_cloud(bad, crs=ftus)
    assert c.units.xy_m == pytest.approx(US_SURVEY_FOOT_M, rel=1e-12)
    np.testing.assert_allclose(c.x, ref.x, atol=0.01)
    r = CliRunner().invoke(main, ["rasters", str(bad), str(tmp_path / "r"), "--res-m", "2", "--crs", ftus])
    assert r.exit_code == 0, r.output
    assert "nosize.las: CRS record present but unreadable" in r.output and "--crs" in r.output
    assert (tmp_path / "r").is_dir()


def test_a_unit_already_in_the_crs_name_is_replaced():
    """review1: EPSG:2264 keyed in metres was named "NAD83 / North Carolina (ftUS) (metre)"."""
    from aerotri.geom.las import with_linear_unit

    assert with_linear_unit(pyproj.CRS.from_epsg(2264), 9001).name == "NAD83 / North Carolina (metre)"
    assert with_linear_unit(pyproj.CRS.from_epsg(2994), 9001).name == "NAD83(HARN) / Oregon GIC Lambert (metre)"
    assert with_linear_unit(pyproj.CRS.from_epsg(32104), 9003).name == "NAD83 / Nebraska (US survey foot)"
    odd = with_linear_unit(pyproj.CRS.from_epsg(26910), 0.5)
    assert with_linear_unit(odd, 9002).name == "NAD83 / UTM zone 10N (foot)"


def test_crs_option_naming_another_crs_than_the_files_record_is_refused(files, tmp_path):
    """``--crs`` is the CRS of files without one and never reprojects: naming another CRS than the file's record was
    ignored, the products written in the file's CRS with exit 0 (trial-lidar: `rasters autzen.laz --crs EPSG:3740`
    gave EPSG:2994 rasters in feet). Now refused by every command, naming the file and both CRSs; the same CRS passes."""
    d, _ = files
    cloud, points, out = d / "c14.las", d / "points.csv", tmp_path / "out"
    out.mkdir()
    commands = {
        "classify": ["classify", cloud, out / "o.laz"],
        "rasters": ["rasters", cloud, out / "r", "--res-m", "2"],
        "trees": ["trees", cloud, out / "t"],
        "vectors": ["vectors", cloud, out / "v.gpkg"],
        "corners": ["corners", cloud, out / "co"],
        "check-heights": ["check-heights", cloud, points, "--json", out / "hc.json"],
        "strips check": ["strips", "check", cloud, d / "other14.las", out / "s"],
    }
    for name, args in commands.items():
        r = CliRunner().invoke(main, [str(a) for a in args] + ["--crs", "EPSG:32633"])
        assert r.exit_code == 2, (name, r.output, r.exception)
        assert r.output.startswith("Error: ") and r.output.count("\n") == 1, (name, r.output)
        for t in (str(cloud), "EPSG:32632", "--crs EPSG:32633", "never reprojects"):
            assert t in r.output, (name, t, r.output)
    assert not any(out.rglob("*")), list(out.rglob("*"))
    r = CliRunner().invoke(main, ["check-heights", str(cloud), str(points), "--crs", "EPSG:32632"])
    assert r.exit_code == 0, r.output


def test_the_vertical_part_of_crs_is_not_dropped_silently(files, tmp_path, caplog):
    """s27: Autzen with `--crs EPSG:2994+5703` (NAVD88 height, metres) still read its heights in feet, without a word:
    a compound --crs over a file's 2D record now warns, naming the record and the heights' unit used. And
    `evaluate --truth --crs` (ignored) is refused."""
    d, _ = files
    cloud = d / "c14.las"
    with caplog.at_level("WARNING", logger="lidarctl.io"):
        io.read_cloud(cloud, crs="EPSG:32632+5773")
    msg = caplog.text
    assert str(cloud) in msg and "vertical part of --crs, EPSG:5773 (EGM96 height, metre), is not used" in msg
    assert "EPSG:32632, a 2D CRS" in msg and "heights read in m" in msg and "aerotri crs assign" in msg
    caplog.clear()
    with caplog.at_level("WARNING", logger="lidarctl.io"):
        io.read_cloud(cloud, crs="EPSG:32632")
    assert "vertical part" not in caplog.text
    r = CliRunner().invoke(main, ["evaluate", str(cloud), "--truth", str(d / "c.laz"), "--crs", "EPSG:32632"])
    assert r.exit_code == 2 and "--crs" in r.output and "--reference only" in r.output, r.output


def test_a_crs_given_for_a_file_without_one_is_checked_against_its_coordinates(tmp_path):
    """Trial s94: a UTM cloud without a CRS record classified with --crs EPSG:6880 (Nebraska, US feet; the points far
    outside its area of use) was read in feet, exit 0 and no word. Now outside the area of use is a warning (grids
    are used past their zone's area), coordinates the CRS cannot hold a refusal; the right CRS is silent."""
    cloud, truth = synthetic.synthetic_scene(width_m=60.0, density_per_m2=2.0, seed=3, n_buildings=1, n_trees=5)
    path = tmp_path / "nocrs.las"
    synthetic.write_las(path, cloud, classification=truth)  # UTM 32N coordinates, no CRS record
    runner = CliRunner()
    # Lambert-93 would put them at 36 deg N, 5 deg south of France: said, the rasters written
    r = runner.invoke(main, ["rasters", str(path), str(tmp_path / "r1"), "--res-m", "2", "--crs", "EPSG:2154"])
    assert r.exit_code == 0, r.output
    assert "outside the area of use of EPSG:2154" in r.output and "--crs EPSG:2154 used all the same" in r.output
    r = runner.invoke(main, ["rasters", str(path), str(tmp_path / "r2"), "--res-m", "2", "--crs", "EPSG:32632"])
    assert r.exit_code == 0 and "area of use" not in r.output, r.output
    # the trial's Nebraska feet put them more than 10 deg beyond its area: another CRS, refused, nothing written
    r = runner.invoke(main, ["classify", str(path), str(tmp_path / "c.las"), "--crs", "EPSG:6880"])
    assert r.exit_code == 2 and "--crs EPSG:6880: the coordinates cannot be" in r.output, r.output
    assert "Traceback" not in r.output and not (tmp_path / "c.las").exists()


def test_delivered_class_11_of_a_las_1_2_file_is_not_called_road(tmp_path):
    """Trial s94: `classify --keep-classes` of lidR's MixedConifer (LAS 1.2) printed "road 5"; 11 is reserved
    before LAS 1.4."""
    cloud, truth = synthetic.synthetic_scene(width_m=60.0, density_per_m2=2.0, seed=3, n_buildings=1, n_trees=5)
    truth = truth.copy()
    truth[:5] = 11
    for version, name in (("1.2", "class 11 (reserved in LAS 1.2) 5"), ("1.4", "road 5")):
        path = tmp_path / f"c{version}.las"
        synthetic.write_las(path, cloud, classification=truth, crs="EPSG:32632", version=version)
        r = CliRunner().invoke(main, ["classify", "--keep-classes", str(path), str(tmp_path / f"k{version}.las")])
        assert r.exit_code == 0 and name in r.output, r.output


def test_classes_a_las_1_2_file_reserves_are_said(tmp_path):
    """Trial s94: AHN3 Delft (LAS 1.2) classified got bridge deck (17) and high noise (18), classes LAS 1.2 reserves,
    without a word; the output keeps the input's version."""
    cloud, truth = synthetic.synthetic_scene(width_m=60.0, density_per_m2=2.0, seed=3, n_buildings=1, n_trees=5)
    for version in ("1.2", "1.4"):
        synthetic.write_las(tmp_path / f"in{version}.las", cloud, classification=truth, crs="EPSG:32632",
                            version=version)
        r = CliRunner().invoke(main, ["classify", str(tmp_path / f"in{version}.las"),
                                      str(tmp_path / f"o{version}.las")])
        assert r.exit_code == 0, r.output
        assert ("18 (high noise) are ASPRS LAS 1.4 classes, which LAS 1.2" in r.output) == (version == "1.2"), r.output
        assert str(laspy.read(tmp_path / f"o{version}.las").header.version) == version


def test_absurd_coordinates_are_named_as_numbers():
    """Trial s96 F14: a corrupt LAZ's refusal printed "(np.float64(273527.612), ...)"; plain numbers now."""
    from lidarctl.io import _validate_xyz

    x, y, z = np.array([1.0, 273527.612]), np.array([2.0, 5470511.29275]), np.array([3.0, 124194.73375])
    with pytest.raises(InputError, match=r"point record 8: absurd or non-finite coordinates \(273527\.612, "
                                         r"5470511\.29275, 124194\.73375\)"):
        _validate_xyz("f.laz", x, y, z, 7)
