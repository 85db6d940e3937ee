"""trial-datum: a Chinese survey contractor's CGCS2000 / Xian 1980 grids, 7- and 4-parameter sets and 1985 heights.

Truth from pyproj directly (its Helmert step, its Gauss-Krueger grids) and surfaces chosen here; each test failed
before its fix (silent sign conventions, hand-typed parameter files, height models extrapolated without a word, a
levelling grid on the input's datum refused, point lists written outside the target's area)."""

import json
import math
import re

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner
from shapely.geometry import MultiPoint, Point, Polygon

from aerotri.crs.cli import crs
from aerotri.geom.crs.datum import load_height_model

# CGCS2000 -> Xian 1980, coordinate frame (PROJ's +convention=coordinate_frame): invented, realistic size
BW = {"x": -24.8, "y": 118.6, "z": 52.3, "rx": 1.85, "ry": -2.42, "rz": 3.15, "s": 2.70}


def _run(*args):
    return CliRunner().invoke(crs, [str(a) for a in args])


def _helmert(convention, p):
    return pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=cart +ellps=GRS80 "
        f"+step +proj=helmert +x={p['x']} +y={p['y']} +z={p['z']} +rx={p['rx']} +ry={p['ry']} +rz={p['rz']} "
        f"+s={p['s']} +convention={convention} +step +inv +proj=cart +ellps=IAU76 "
        "+step +proj=unitconvert +xy_in=rad +xy_out=deg")


def _points(seed, n, lon=(110.40, 110.62), lat=(30.72, 30.88)):
    rng = np.random.default_rng(seed)
    return rng.uniform(*lon, n), rng.uniform(*lat, n), rng.uniform(150, 650, n)


@pytest.fixture
def common(tmp_path):
    """8 common points CGCS2000 3-degree GK zone 37 (EPSG:4525) -> Xian 1980 zone 37 (EPSG:2361), exact."""
    lon, lat, h = _points(1, 8)
    lx, ly, hx = _helmert("coordinate_frame", BW).transform(lon, lat, h)
    ec, nc = pyproj.Transformer.from_crs(4490, 4525, always_xy=True).transform(lon, lat)
    ex, nx = pyproj.Transformer.from_crs(4610, 2361, always_xy=True).transform(lx, ly)
    path = tmp_path / "common.csv"
    path.write_text("id,x_from,y_from,z_from,x_to,y_to,z_to\n" + "".join(
        f"K{i},{ec[i]:.4f},{nc[i]:.4f},{h[i]:.4f},{ex[i]:.4f},{nx[i]:.4f},{hx[i]:.4f}\n" for i in range(8)))
    return path


def test_the_fit_report_gives_the_rotation_convention_and_the_position_vector_values(tmp_path, common):
    out = tmp_path / "bw.json"
    r = _run("fit", common, "--model", "bursa-wolf7", "--from", "EPSG:4525", "--to", "EPSG:2361", "-o", out)
    assert r.exit_code == 0, r.output
    assert "coordinate frame (EPSG method 1032/9607" in r.output
    d = json.loads(out.read_text())
    fitted = {k: d["parameters"][k]["value"] for k in d["parameters"]}
    for k in ("rx", "ry", "rz"):  # the fit is the known set, in its convention
        assert fitted[f"{k}_arcsec"] == pytest.approx(BW[k], abs=1e-3)
    # the position-vector values printed, put into PROJ's position-vector Helmert, give the same points
    pv = dict(zip(("rx", "ry", "rz"), map(float, re.search(
        r"position vector .*? has rx ([-+\d.]+), ry ([-+\d.]+), rz ([-+\d.]+) arcsec", r.output).groups())))
    lon, lat, h = _points(9, 5)
    want = _helmert("coordinate_frame", BW).transform(lon, lat, h)
    got = _helmert("position_vector", BW | pv).transform(lon, lat, h)
    assert np.allclose(np.array(got[:2]), np.array(want[:2]), atol=1e-8)  # degrees: < 1 mm
    assert "conventions_explained" in d and d["convention"] == "coordinate_frame"


def test_the_4_parameter_report_gives_the_surveying_form_with_x_northing(tmp_path):
    """A 4-parameter set in the surveying form X = northing (X' = dX + s (X cos a - Y sin a), ...), a = +100"."""
    lon, lat, _ = _points(7, 9)
    E, N = pyproj.Transformer.from_crs(4490, 4546, always_xy=True).transform(lon, lat)
    a, s, dX, dY = 100.0 / 206264.80624709636, 1 + 15e-6, -3_380_000.0, -420_000.0
    X = dX + s * (N * math.cos(a) - E * math.sin(a))
    Y = dY + s * (N * math.sin(a) + E * math.cos(a))
    path = tmp_path / "four.csv"  # the local grid, as x = easting (Y), y = northing (X), in CGCS2000 CM 111E
    path.write_text("id,x_from,y_from,x_to,y_to\n" + "".join(
        f"C{i},{E[i]:.4f},{N[i]:.4f},{Y[i]:.4f},{X[i]:.4f}\n" for i in range(9)))
    from pyproj.crs import ProjectedCRS
    from pyproj.crs.coordinate_operation import TransverseMercatorConversion

    local = ProjectedCRS(name="city grid (CGCS2000, CM 110.5E)", geodetic_crs=pyproj.CRS(4490), conversion=(
        TransverseMercatorConversion(0.0, 110.5, false_easting=50_000.0, false_northing=-3_000_000.0,
                                     scale_factor_natural_origin=1.0))).to_wkt()
    r = _run("fit", path, "--model", "helmert2d", "--from", "EPSG:4546", "--to", local, "-o", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    m = re.search(r"dX = ([-\d.]+) m, dY = ([-\d.]+) m, a = ([-+\d.]+) arcsec", r.output)
    assert m, r.output
    assert float(m[1]) == pytest.approx(dX, abs=0.01) and float(m[2]) == pytest.approx(dY, abs=0.01)
    assert float(m[3]) == pytest.approx(100.0, abs=0.01)
    assert re.search(r"rotation_arcsec\s+-100\.00", r.output)  # the toolkit's own: counter-clockwise in (E, N)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("convention"), "needs its rotation convention"),
    (lambda d: d["parameters"].update(rx_arcsec={"value": 8.97e-6, "unit": "rad"}), "rx_arcsec has unit 'rad'"),
    (lambda d: d["parameters"].update(scale_ppm={"value": 2.7e-6, "unit": "1"}), "scale_ppm has unit '1'"),
])
def test_a_hand_typed_parameter_file_states_convention_and_units(tmp_path, common, edit, message):
    """A published set typed into a file: without "convention" it was taken as coordinate frame, and "unit"
    entries were not read (radians as arc-seconds, a ratio as ppm), exit 0."""
    good = tmp_path / "bw.json"
    assert _run("fit", common, "--model", "bursa-wolf7", "--from", "4525", "--to", "2361", "-o", good).exit_code == 0
    d = json.loads(good.read_text())
    edit(d)
    typed = tmp_path / "typed.json"
    typed.write_text(json.dumps(d))
    pts = tmp_path / "p.csv"
    pts.write_text("id,x,y,z\nQ1,37450000.0,3409000.0,300.0\n")
    out = tmp_path / "out.csv"
    r = _run("transform", pts, out, "--from", "4525", "--to", "2361", "--params", typed)
    assert r.exit_code == 2 and message in r.output and str(typed) in r.output and not out.exists(), r.output


@pytest.fixture
def levelling(tmp_path):
    """12 GNSS-levelled points, h on CGCS2000, x, y in its zone 37 grid, zeta a plane chosen here."""
    lon, lat, h = _points(4, 12, lon=(110.42, 110.60), lat=(30.74, 30.86))
    e, n = pyproj.Transformer.from_crs(4490, 4525, always_xy=True).transform(lon, lat)
    zeta = -14.2 + 0.02 * (e - 37_450_000.0) / 1000.0 - 0.03 * (n - 3_410_000.0) / 1000.0
    path = tmp_path / "levelling.csv"
    path.write_text("id,x,y,h,H\n" + "".join(f"L{i},{e[i]:.4f},{n[i]:.4f},{h[i]:.4f},{h[i] - zeta[i]:.4f}\n"
                                            for i in range(12)))
    return path, e, n


@pytest.mark.parametrize("model", ["plane", "tps"])
def test_a_height_model_says_when_it_is_extrapolated(tmp_path, levelling, model):
    path, e, n = levelling
    zfile = tmp_path / "zeta.json"
    r = _run("fit-heights", path, "--model", model, "--epsg", "4525", "--h-crs", "4490", "-o", zfile)
    assert r.exit_code == 0, r.output
    assert len(load_height_model(zfile).hull_m) >= 3
    pts = tmp_path / "p.csv"
    inside = f"I1,{e.mean():.3f},{n.mean():.3f},400.0\n"
    pts.write_text("id,x,y,z\n" + inside)
    r = _run("transform", pts, tmp_path / "o1.csv", "--from", "4525", "--to", "4525", "--heights", zfile)
    assert r.exit_code == 0 and "extrapolated" not in r.output, r.output
    pts.write_text("id,x,y,z\n" + inside + f"F1,{e.max() + 40_000.0:.3f},{n.mean():.3f},400.0\n")
    r = _run("transform", pts, tmp_path / "o2.csv", "--from", "4525", "--to", "4525", "--heights", zfile)
    assert r.exit_code == 0 and "height model extrapolated: 1 of 2 points" in r.output, r.output
    beyond = float(re.search(r"up to ([\d.]+) km beyond", r.output)[1])
    hull = MultiPoint(np.column_stack([e, n])).convex_hull  # truth: shapely's distance from the points' hull
    assert beyond == pytest.approx(hull.distance(Point(e.max() + 40_000.0, n.mean())) / 1000.0, abs=1e-3)


def test_a_levelling_model_with_x_and_y_swapped_is_no_longer_silent(tmp_path, levelling):
    """X = northing, Y = easting in the levelling file and no --epsg: normal heights ~2 km off, exit 0, no word."""
    path, e, n = levelling
    rows = [ln.split(",") for ln in path.read_text().splitlines()[1:]]
    swapped = tmp_path / "swapped.csv"
    swapped.write_text("id,x,y,h,H\n" + "".join(f"{r[0]},{r[2]},{r[1]},{r[3]},{r[4]}\n" for r in rows))
    zfile = tmp_path / "z.json"
    assert _run("fit-heights", swapped, "--model", "plane", "-o", zfile).exit_code == 0
    pts = tmp_path / "p.csv"
    pts.write_text(f"id,x,y,z\nI1,{e.mean():.3f},{n.mean():.3f},400.0\n")
    r = _run("transform", pts, tmp_path / "o.csv", "--from", "4525", "--to", "4525", "--heights", zfile)
    assert r.exit_code == 0 and "height model extrapolated: 1 of 1 points" in r.output, r.output


def test_a_height_model_in_a_grid_of_the_inputs_datum_serves_another_grid_of_it(tmp_path, common, levelling):
    """Levelling in CGCS2000 zone 37, points in CGCS2000 CM 111E into Xian 1980 with --params: it was refused
    (Xian 1980 -> CGCS2000 ballpark, "pass --params", which was given); now the model is reached from the input."""
    path, e, n = levelling
    zfile, params = tmp_path / "zeta.json", tmp_path / "bw.json"
    assert _run("fit-heights", path, "--model", "plane", "--epsg", "4525", "--h-crs", "4490", "-o", zfile).exit_code == 0
    assert _run("fit", common, "--model", "bursa-wolf7", "--from", "4525", "--to", "2361", "-o", params).exit_code == 0
    x, y = e[:3], n[:3]
    zone = tmp_path / "zone.csv"
    zone.write_text("id,x,y,z\n" + "".join(f"Q{i},{x[i]:.4f},{y[i]:.4f},500.0\n" for i in range(3)))
    cm_e, cm_n = pyproj.Transformer.from_crs(4525, 4546, always_xy=True).transform(x, y)
    cm = tmp_path / "cm.csv"
    cm.write_text("id,x,y,z\n" + "".join(f"Q{i},{cm_e[i]:.4f},{cm_n[i]:.4f},500.0\n" for i in range(3)))
    r1 = _run("transform", zone, tmp_path / "a.csv", "--from", "4525", "--to", "2361", "--params", params,
              "--heights", zfile)
    r2 = _run("transform", cm, tmp_path / "b.csv", "--from", "4546", "--to", "2361", "--params", params,
              "--heights", zfile)
    assert r1.exit_code == 0 and r2.exit_code == 0, r2.output
    a, b = (np.array([[float(v) for v in ln.split(",")[1:]] for ln in (tmp_path / f).read_text().splitlines()[1:]])
            for f in ("a.csv", "b.csv"))
    assert np.abs(a - b).max() < 2e-4  # the files' 4 decimals


def test_a_point_list_written_outside_the_targets_area_is_said(tmp_path):
    """Points at 110.5E into the 3-degree CM 114E grid (a 3/6-degree or zone mix-up): exit 0 without a word."""
    pts = tmp_path / "p.csv"
    pts.write_text("id,x,y,z\nQ1,37450000.0,3409000.0,300.0\n")
    r = _run("transform", pts, tmp_path / "o.csv", "--from", "EPSG:4525", "--to", "EPSG:4547")
    assert r.exit_code == 0 and "lies outside the area of use of EPSG:4547" in r.output, r.output
    assert "is --to EPSG:4547 the grid meant" in r.output
    r = _run("transform", pts, tmp_path / "o2.csv", "--from", "EPSG:4525", "--to", "EPSG:4546")
    assert r.exit_code == 0 and "outside the area" not in r.output, r.output


def test_orientations_turn_with_the_grid(tmp_path):
    """eo.txt of UTM 49N into UTM 50N at 110.5E: kappa was copied, 3.08 deg off (the convergences differ). Truth:
    the direction of a ray in the camera is the same in either grid (horizontal offsets taken at the same scale)."""
    from aerotri.geom.rotation import rotation_matrix_opk

    eo = tmp_path / "eo.txt"
    frames = [("f1", 452252.8, 3407393.9, 760.4, 0.067, 0.296, -93.94),
              ("f2", 452900.0, 3409000.0, 802.0, -1.2, 2.5, 87.3),
              ("f3", 451500.0, 3408200.0, 790.0, 3.0, -2.0, 179.5)]
    eo.write_text("# image_id X_m Y_m Z_m omega_deg phi_deg kappa_deg\n"
                  + "".join(" ".join(map(str, f)) + "\n" for f in frames))
    out = tmp_path / "eo50.txt"
    r = _run("transform", eo, out, "--from", "EPSG:32649", "--to", "EPSG:32650")
    assert r.exit_code == 0, r.output
    rows = [ln.split() for ln in out.read_text().splitlines() if not ln.startswith("#")]
    t = pyproj.Transformer.from_crs(32649, 32650, always_xy=True)
    geo = pyproj.Transformer.from_crs(32649, 4326, always_xy=True)
    p49, p50 = pyproj.Proj(32649), pyproj.Proj(32650)
    for f, row in zip(frames, rows):
        CA, RA = np.array(f[1:4]), rotation_matrix_opk(*f[4:7])
        RB = rotation_matrix_opk(*map(float, row[4:7]))
        CB = np.array([*t.transform(*CA[:2]), CA[2]])
        lon, lat = geo.transform(*CA[:2])
        k = p50.get_factors(lon, lat).meridional_scale / p49.get_factors(lon, lat).meridional_scale
        for d in ([50.0, 0.0, -800.0], [0.0, 50.0, -800.0], [-40.0, -30.0, -800.0]):
            PA = CA + d
            D = np.array([*t.transform(*PA[:2]), PA[2]]) - CB
            D[:2] /= k
            u, v = RA.T @ (PA - CA), RB.T @ D
            assert np.linalg.norm(u / np.linalg.norm(u) - v / np.linalg.norm(v)) < 1e-6
    notes = tmp_path / "notes.txt"  # a comment in prose is no header: the columns are x, y, z as ever
    notes.write_text("# phi and kappa were not measured\nQ1 452252.8 3407393.9 760.4\n")
    assert _run("transform", notes, tmp_path / "n.txt", "--from", "EPSG:32649", "--to", "EPSG:32650").exit_code == 0
    eo.write_text("# image_id X_m Y_m Z_m omega_rad phi_rad kappa_rad\nf1 452252.8 3407393.9 760.4 0.001 0.005 -1.6\n")
    r = _run("transform", eo, tmp_path / "o.txt", "--from", "EPSG:32649", "--to", "EPSG:32650")
    assert r.exit_code == 2 and "omega_rad" in r.output and "degrees" in r.output, r.output


def test_a_7_parameter_fit_into_the_wrong_zone_width_is_called_implausible(tmp_path):
    """Xian 1980 coordinates in the 3-degree CM 114E grid given as --to the 6-degree CM 117E one (Wuhan): rz -10,792"
    and -988 ppm with 4 m residuals, no warning; the right grid: no warning."""
    lon, lat, h = _points(3, 8, lon=(114.15, 114.45), lat=(30.45, 30.65))
    lx, ly, hx = _helmert("coordinate_frame", BW).transform(lon, lat, h)
    ec, nc = pyproj.Transformer.from_crs(4490, 4547, always_xy=True).transform(lon, lat)
    ex, nx = pyproj.Transformer.from_crs(4610, 2383, always_xy=True).transform(lx, ly)
    path = tmp_path / "wuhan.csv"
    path.write_text("id,x_from,y_from,z_from,x_to,y_to,z_to\n" + "".join(
        f"W{i},{ec[i]:.4f},{nc[i]:.4f},{h[i]:.4f},{ex[i]:.4f},{nx[i]:.4f},{hx[i]:.4f}\n" for i in range(8)))
    r = _run("fit", path, "--model", "bursa-wolf7", "--from", "4547", "--to", "2383", "-o", tmp_path / "ok.json")
    assert r.exit_code == 0 and "implausible" not in r.output, r.output
    r = _run("fit", path, "--model", "bursa-wolf7", "--from", "4547", "--to", "2345", "-o", tmp_path / "bad.json")
    assert r.exit_code == 0 and "implausible datum change" in r.output and "rz -10791" in r.output, r.output


@pytest.mark.parametrize("frm, x, y", [("EPSG:4525", 37446554.443, 3412779.468),  # zone-prefixed
                                       ("EPSG:4546", 446554.443, 3412779.468)])  # CM 111E
def test_a_list_in_the_surveying_order_x_northing_is_refused_saying_so(tmp_path, frm, x, y):
    pts = tmp_path / "XY.csv"
    pts.write_text(f"点号,X,Y,H\nK09,{y},{x},583.925\n")
    out = tmp_path / "o.csv"
    r = _run("transform", pts, out, "--from", frm, "--to", "EPSG:4490")
    assert r.exit_code == 2 and "x and y swapped?" in r.output and "line 2" in r.output and not out.exists(), r.output
    pts.write_text(f"点号,northing,easting,H\nK09,{y},{x},583.925\n")  # named: read as they are
    r = _run("transform", pts, out, "--from", frm, "--to", "EPSG:4490")
    assert r.exit_code == 0, r.output
    lon, lat = map(float, out.read_text().splitlines()[1].split(",")[1:3][::-1])
    assert (lat, lon) == pytest.approx(pyproj.Transformer.from_crs(frm, 4490).transform(y, x), abs=1e-8)


def test_normal_heights_of_the_1985_datum_by_the_height_model_into_a_compound_crs(tmp_path, common, levelling):
    """--to Xian 1980 zone 37 + Yellow Sea 1985 height (EPSG:2361+5737) with --params and --heights was refused as
    ballpark ("pass --heights", which was given): PROJ has no geoid for it. Now the model gives those heights: the
    same numbers as into EPSG:2361, the output tagged with the compound CRS, and back with --normal-to-ellipsoidal."""
    path, e, n = levelling
    zfile, params = tmp_path / "zeta.json", tmp_path / "bw.json"
    assert _run("fit-heights", path, "--model", "plane", "--epsg", "4525", "--h-crs", "4490", "-o", zfile).exit_code == 0
    assert _run("fit", common, "--model", "bursa-wolf7", "--from", "4525", "--to", "2361", "-o", params).exit_code == 0
    pts = tmp_path / "p.csv"
    pts.write_text("id,x,y,z\n" + "".join(f"Q{i},{e[i]:.4f},{n[i]:.4f},{300.0 + i:.4f}\n" for i in range(3)))
    r0 = _run("transform", pts, tmp_path / "a.csv", "--from", "4525", "--to", "2361", "--params", params, "--heights", zfile)
    r1 = _run("transform", pts, tmp_path / "b.csv", "--from", "4525", "--to", "EPSG:2361+5737", "--params", params,
              "--heights", zfile)
    assert r0.exit_code == 0 and r1.exit_code == 0, r1.output
    assert "Yellow Sea 1985 height taken as the height model's normal heights" in r1.output
    assert (tmp_path / "a.csv").read_text() == (tmp_path / "b.csv").read_text()
    r = _run("transform", tmp_path / "b.csv", tmp_path / "back.csv", "--from", "EPSG:2361+5737", "--to", "4525",
             "--params", params, "--heights", zfile, "--normal-to-ellipsoidal")
    assert r.exit_code == 0, r.output
    back = np.array([[float(v) for v in ln.split(",")[1:]] for ln in (tmp_path / "back.csv").read_text().splitlines()[1:]])
    assert np.abs(back[:, 2] - (300.0 + np.arange(3))).max() < 2e-4
    assert np.abs(back[:, 0] - e[:3]).max() < 2e-3 and np.abs(back[:, 1] - n[:3]).max() < 2e-3
    r = _run("transform", pts, tmp_path / "c.csv", "--from", "4525", "--to", "EPSG:2361+5737", "--params", params)
    assert r.exit_code == 2 and "ballpark" in r.output and not (tmp_path / "c.csv").exists()  # no model: as before


def test_a_dem_warped_with_a_height_model_from_elsewhere_says_it_once(tmp_path, caplog):
    """crs warp evaluates the model through the inverse operation: its extrapolation is said once, per grid points."""
    import rasterio
    from rasterio.transform import from_origin

    from aerotri.geom.crs.datum import HeightAnomalyModel
    from aerotri.geom.crs.raster import warp_raster

    src = tmp_path / "dem.tif"
    with rasterio.open(src, "w", driver="GTiff", width=40, height=40, count=1, dtype="float32", crs="EPSG:4525",
                       transform=from_origin(37_450_000.0, 3_410_000.0, 1.0, 1.0), nodata=-9999.0) as ds:
        ds.write(np.full((40, 40), 300.0, np.float32), 1)
    hull = [[37_460_000.0, 3_400_000.0], [37_470_000.0, 3_400_000.0], [37_470_000.0, 3_410_000.0]]  # 10 km east
    far = HeightAnomalyModel("plane", (37_465_000.0, 3_405_000.0), coefficients=[-14.2, 0.0, 0.0], crs="EPSG:4525",
                             h_crs="EPSG:4490", hull_m=hull)
    with caplog.at_level("WARNING"):
        warp_raster(src, tmp_path / "H.tif", "EPSG:4546", heights=far)
    said = [m for m in caplog.messages if "height model extrapolated" in m]
    assert len(said) == 1 and "grid points sampled" in said[0] and str(src) in said[0], caplog.messages
    # the farthest cell centre from the triangle (shapely), within a cell
    farthest = max(Polygon(hull).distance(Point(37_450_000.5 + c, 3_409_999.5 - r)) for r in (0, 39) for c in (0, 39))
    assert float(re.search(r"up to ([\d.]+) km", said[0])[1]) == pytest.approx(farthest / 1000.0, abs=2e-3)


def test_latitude_first_in_a_geographic_list_is_refused(tmp_path):
    """B, L order at Kashgar (39.47N 75.99E) header-less in CGCS2000 degrees: read as lon 39.47, lat 75.99 (a
    geographic CRS's area of use was not checked) and written into the CM 75E grid at y = 8,720 km, exit 0."""
    pts = tmp_path / "bl.txt"
    pts.write_text("KS1 39.4700 75.9900 1290.0\n")
    out = tmp_path / "o.txt"
    r = _run("transform", pts, out, "--from", "EPSG:4490", "--to", "EPSG:4534")
    assert r.exit_code == 2 and "outside the area of use of EPSG:4490" in r.output and "lat, lon" in r.output
    assert not out.exists()
    pts.write_text("KS1 75.9900 39.4700 1290.0\n")
    r = _run("transform", pts, out, "--from", "EPSG:4490", "--to", "EPSG:4534")
    assert r.exit_code == 0, r.output
    e, n = map(float, out.read_text().split()[1:3])
    assert (e, n) == pytest.approx(pyproj.Transformer.from_crs(4490, 4534, always_xy=True).transform(75.99, 39.47),
                                   abs=1e-4)


@pytest.mark.parametrize("frm, x, said", [
    ("EPSG:4525", 19446554.443, "a point of EPSG:4497 (CGCS2000 / Gauss-Kruger zone 19): 6-degree zones given for "
                                "3-degree ones?"),
    ("EPSG:4497", 37446554.443, "a point of EPSG:4525 (CGCS2000 / 3-degree Gauss-Kruger zone 37): 3-degree zones"),
    ("EPSG:4525", 38330000.000, "a point of EPSG:4526 (CGCS2000 / 3-degree Gauss-Kruger zone 38): another zone"),
])
def test_a_zone_prefix_of_the_other_width_or_the_next_zone_is_named(tmp_path, frm, x, said):
    pts = tmp_path / "p.csv"
    pts.write_text(f"id,x,y\nK1,{x},3412779.468\n")
    r = _run("transform", pts, tmp_path / "o.csv", "--from", frm, "--to", "EPSG:4490")
    assert r.exit_code == 2 and said in r.output and "line 2" in r.output, r.output
    truth = pyproj.CRS(said.split("point of ")[1].split(" ")[0])  # the grid named holds the point
    lon, lat = pyproj.Transformer.from_crs(truth, 4490, always_xy=True).transform(x, 3412779.468)
    assert 109 < lon < 113 and 30 < lat < 31.5


def test_a_unit_spelt_otherwise_is_that_unit():
    """Review 38: "metre" on tx_m and "arc-sec" on rx_arcsec were refused as other units; radians still are."""
    from aerotri.core.errors import InputError
    from aerotri.geom.crs.datum import Transformation

    d = {"model": "bursa-wolf7", "convention": "coordinate_frame", "from_crs": "EPSG:4326", "to_crs": "EPSG:4326",
         "parameters": {"tx_m": {"value": 1.0, "unit": "metre"}, "ty_m": 0.0, "tz_m": 0.0,
                        "rx_arcsec": {"value": 1.0, "unit": "arc-sec"}, "ry_arcsec": 0.0, "rz_arcsec": 0.0,
                        "scale_ppm": {"value": 1.0, "unit": "ppm"}}}
    assert Transformation.from_dict(d).parameters["rx_arcsec"] == 1.0
    d["parameters"]["rx_arcsec"] = {"value": 4.8e-6, "unit": "rad"}
    with pytest.raises(InputError, match="has unit 'rad'"):
        Transformation.from_dict(d)
