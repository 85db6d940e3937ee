"""``aerotri crs`` commands: happy paths and clear errors (exit code 2, no output) for bad input."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.crs.cli import crs
from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7, TRUE_HELMERT2D, simulate_plane, simulate_spatial, write_common_points
from aerotri.geom.crs.transform import CrsTransformer
from aerotri.geom.crs.datum import Transformation, load_height_model, load_transformation


def _run(*args):
    return CliRunner().invoke(crs, [str(a) for a in args])


@pytest.fixture
def common_points(tmp_path):
    """20 common points WGS 84 UTM 49N -> Xian 1980 zone 37, 1 cm noise."""
    rng = np.random.default_rng(1)
    lon, lat, h = rng.uniform(109.6, 110.2, 20), rng.uniform(34.0, 34.5, 20), rng.uniform(400, 900, 20)
    src, dst, _ = simulate_spatial(TRUE_BURSA_WOLF7, 32649, 2361, lon_deg=lon, lat_deg=lat, h_m=h, noise_m=0.01, seed=2)
    path = tmp_path / "common.csv"
    write_common_points(path, [f"P{i:02d}" for i in range(20)], src, dst)
    return path, src, dst


def test_fit_transform_round_trip(tmp_path, common_points):
    path, src, dst = common_points
    params = tmp_path / "bw7.json"
    r = _run("fit", path, "--model", "bursa-wolf7", "--from", "32649", "--to", "EPSG:2361", "-o", params)
    assert r.exit_code == 0, r.output
    assert "Sigma0:" in r.output and "rx_arcsec" in r.output and "P19" in r.output
    d = json.loads(params.read_text())
    assert d["model"] == "bursa-wolf7" and d["from_crs"] == "EPSG:32649" and d["to_crs"] == "EPSG:2361"
    assert d["convention"] == "coordinate_frame"
    assert d["parameters"]["scale_ppm"]["unit"] == "ppm" and "std_dev" in d["parameters"]["scale_ppm"]
    assert len(d["residuals"]) == 20 and set(d["residuals"][0]) >= {"id", "de_m", "dn_m", "du_m"}
    assert d["sigma0_m"] == pytest.approx(0.01, rel=0.3)
    for k, v in TRUE_BURSA_WOLF7.items():
        assert abs(d["parameters"][k]["value"] - v) < 3 * d["parameters"][k]["std_dev"]
    # transform the source points with the file: back on the target within the noise
    pts = tmp_path / "pts.csv"
    pts.write_text("id,x,y,z\n" + "".join(f"P{i},{s[0]:.4f},{s[1]:.4f},{s[2]:.4f}\n" for i, s in enumerate(src)))
    out = tmp_path / "pts_xian.csv"
    r = _run("transform", pts, out, "--from", "32649", "--to", "2361", "--params", params)
    assert r.exit_code == 0, r.output
    got = np.array([[float(v) for v in ln.split(",")[1:]] for ln in out.read_text().splitlines()[1:]])
    assert np.sqrt(np.mean((got[:, :2] - dst[:, :2]) ** 2)) < 0.02
    # back from the set's target into another CRS of its source datum (trial-cn: EPSG:4547 -> EPSG:4326 with a set
    # 32650 -> 4547 was refused, and with --allow-ballpark applied forward, 274 m off): through the set inversely
    back = tmp_path / "pts_back.csv"
    r = _run("transform", out, back, "--from", "2361", "--to", "4326", "--params", params)
    assert r.exit_code == 0 and "applied inversely" in r.output, r.output
    assert back.read_text().splitlines()[0] == "id,lon,lat,z"   # the columns named for what they hold now
    ll = np.array([[float(v) for v in ln.split(",")[1:]] for ln in back.read_text().splitlines()[1:]])
    import pyproj

    lon, lat = pyproj.Transformer.from_crs(32649, 4326, always_xy=True).transform(src[:, 0], src[:, 1])
    de = (ll[:, 0] - lon) * 111_320.0 * np.cos(np.radians(lat))
    dn = (ll[:, 1] - lat) * 111_320.0
    assert np.sqrt(np.mean(de ** 2 + dn ** 2)) < 0.03


def test_fit_heights_and_transform_with_heights(tmp_path):
    rng = np.random.default_rng(4)
    x, y = rng.uniform(37_420_000, 37_460_000, 12), rng.uniform(3_780_000, 3_820_000, 12)
    zeta = -27.0 + 0.02 * (x - 37_440_000) / 1000 - 0.01 * (y - 3_800_000) / 1000
    h = rng.uniform(300, 900, 12)
    pts = tmp_path / "levelling.csv"
    pts.write_text("id,x,y,h,H\n" + "".join(f"L{i},{x[i]:.3f},{y[i]:.3f},{h[i]:.4f},{h[i] - zeta[i]:.4f}\n" for i in range(12)))
    model = tmp_path / "zeta.json"
    r = _run("fit-heights", pts, "--model", "plane", "--epsg", "2361", "-o", model)
    assert r.exit_code == 2 and "--h-crs is required with --epsg 2361" in r.output and not model.exists()
    r = _run("fit-heights", pts, "--model", "plane", "--epsg", "2361", "--h-crs", "4610", "-o", model)
    assert r.exit_code == 0, r.output
    assert "leave-one-out RMS" in r.output
    d = json.loads(model.read_text())
    assert d["crs"] == "EPSG:2361" and d["rms_m"] < 1e-3
    lst = tmp_path / "in.txt"
    lst.write_text("Q1 37430000.0 3790000.0 600.0\n")
    out = tmp_path / "out.txt"
    r = _run("transform", lst, out, "--from", "2361", "--to", "2361", "--heights", model)
    assert r.exit_code == 0, r.output
    H = float(out.read_text().split()[3])
    assert H == pytest.approx(600.0 - (-27.0 + 0.02 * -10 - 0.01 * -10), abs=1e-3)
    # a geographic CRS for the anomaly surface, too few points for the model
    r = _run("fit-heights", pts, "--model", "quadratic", "--epsg", "4326", "--h-crs", "4326")
    assert r.exit_code == 2 and "projected" in r.output
    few = _write(tmp_path / "few.csv", "id,x,y,h,H\n" + "\n".join(pts.read_text().splitlines()[1:5]) + "\n")
    r = _run("fit-heights", few, "--model", "quadratic")
    assert r.exit_code == 2 and f"{few}: height model quadratic needs at least 6 points, got 4" in r.output


def test_a_height_model_on_a_site_grid_without_an_epsg_code_reads_back(tmp_path):
    """trial-site: `fit-heights --epsg <a site grid's PROJ string>` wrote the grid's label ("Transverse Mercator
    (...)") as the model's CRS, which `crs transform` / `crs warp` refused as an unknown CRS; its WKT is written."""
    site = ("+proj=tmerc +lat_0=30.79 +lon_0=110.5 +k=1.0002 +x_0=5000 +y_0=10000 +datum=WGS84 +units=m +no_defs "
            "+type=crs")
    rng = np.random.default_rng(6)
    x, y = rng.uniform(3000, 7000, 8), rng.uniform(8000, 12000, 8)
    h = rng.uniform(300, 400, 8)
    zeta = 25.3 + 0.001 * (x - 5000) - 0.0005 * (y - 10000)
    pts = _write(tmp_path / "lev.csv", "id,x,y,h,H\n" + "".join(
        f"L{i},{x[i]:.3f},{y[i]:.3f},{h[i]:.4f},{h[i] - zeta[i]:.4f}\n" for i in range(8)))
    model = tmp_path / "zeta.json"
    r = _run("fit-heights", pts, "--model", "plane", "--epsg", site, "--h-crs", "EPSG:4326", "-o", model)
    assert r.exit_code == 0, r.output
    assert json.loads(model.read_text())["crs"].startswith(("PROJCRS", "PROJCS"))
    lst = _write(tmp_path / "in.txt", "Q1 5000.0 10000.0 350.0\n")
    out = tmp_path / "out.txt"
    r = _run("transform", lst, out, "--from", site, "--to", site, "--heights", model)
    assert r.exit_code == 0, r.output
    assert float(out.read_text().split()[3]) == pytest.approx(350.0 - 25.3, abs=1e-3)


def test_a_four_parameter_fit_into_a_sites_engineering_grid(tmp_path):
    """trial-site F4: helmert2d into an engineering CRS (ENGCRS: a site's plane grid in metres, no projection) was
    refused "use bursa-wolf7 or translation3 for geographic/geocentric coordinates"; the classic "UTM + 4 parameters"
    site grid is fitted and applied."""
    eng = _write(tmp_path / "site.wkt", 'ENGCRS["Dam site grid",EDATUM["Dam site datum"],CS[Cartesian,2],'
                 'AXIS["easting (E)",east,LENGTHUNIT["metre",1]],AXIS["northing (N)",north,LENGTHUNIT["metre",1]]]')
    rng = np.random.default_rng(8)
    x, y = rng.uniform(452000, 455000, 8), rng.uniform(3406000, 3409000, 8)
    a, b = 1.0002 * np.cos(np.radians(0.25)), 1.0002 * np.sin(np.radians(0.25))

    def to_site(x, y):
        return 5000 + a * (x - 452000) - b * (y - 3406000), 10000 + b * (x - 452000) + a * (y - 3406000)
    xs, ys = to_site(x, y)
    common = _write(tmp_path / "common.csv", "id,x_from,y_from,x_to,y_to\n" + "".join(
        f"C{i},{x[i]:.4f},{y[i]:.4f},{xs[i]:.4f},{ys[i]:.4f}\n" for i in range(8)))
    params = tmp_path / "h2d.json"
    r = _run("fit", common, "--model", "helmert2d", "--from", "EPSG:32649", "--to", eng, "-o", params)
    assert r.exit_code == 0, r.output
    pts = _write(tmp_path / "in.txt", "Q1 453500.0 3407500.0 100.0\n")
    out = tmp_path / "out.txt"
    r = _run("transform", pts, out, "--from", "EPSG:32649", "--to", eng, "--params", params)
    assert r.exit_code == 0, r.output
    got = [float(v) for v in out.read_text().split()[1:3]]
    assert got == pytest.approx(list(to_site(453500.0, 3407500.0)), abs=1e-3)


def test_fit_heights_refuses_a_foot_grid_and_reads_old_foot_models(tmp_path):
    """--epsg of a grid in feet (Autzen's EPSG:2994): refused, naming it and the metre grid it needs (the model file
    would hold feet under origin_m and slopes per 1,000 ft under "m/km"); a model file written so before still
    loads and gives the same zeta."""
    x = np.array([636100.0, 637100.0, 636500.0, 636900.0])
    y = np.array([849000.0, 849100.0, 849450.0, 849300.0])
    h = np.array([100.0, 101.0, 102.0, 103.0])
    zeta = -21.0 + 0.002 * (x - 636650.0) / 1000.0
    pts = _write(tmp_path / "lev.csv", "id,x,y,h,H\n" + "".join(
        f"L{i},{x[i]:.2f},{y[i]:.2f},{h[i]:.4f},{h[i] - zeta[i]:.4f}\n" for i in range(4)))
    model = tmp_path / "zeta.json"
    r = _run("fit-heights", pts, "--epsg", "2994", "--h-crs", "EPSG:4326", "-o", model)
    assert r.exit_code == 2 and "--epsg EPSG:2994" in r.output and "x, y in ft" in r.output
    assert "metre grid" in r.output and "Traceback" not in r.output and not model.exists()
    old = _write(tmp_path / "old.json", json.dumps({  # as main up to 2026-12-01 wrote it for that table
        "model": "plane", "crs": "EPSG:2994", "origin_m": [636650.0, 849212.5], "h_crs": "EPSG:4326",
        "coefficients": [-21.0, 0.002, 0.0], "coefficient_units": "m, m/km, m/km^2 for 1, dx, dy, dx^2, dx dy, "
        "dy^2 (dx, dy in km)"}))
    m = load_height_model(old)
    np.testing.assert_allclose(m.zeta_m(x, y), zeta, atol=1e-9)


def test_transform_refuses_ballpark_without_output(tmp_path):
    pts = tmp_path / "pts.csv"
    pts.write_text("id,x,y,z\nA,441000.0,3791000.0,500.0\n")
    out = tmp_path / "out.csv"
    r = _run("transform", pts, out, "--from", "32649", "--to", "2361")
    assert r.exit_code == 2
    assert "no rigorous transformation" in r.output and "crs fit" in r.output and "--allow-ballpark" in r.output
    assert not out.exists()
    r = _run("transform", pts, out, "--from", "32649", "--to", "2361", "--allow-ballpark")
    assert r.exit_code == 0 and "BALLPARK" in r.output and out.exists()


def test_a_ballpark_into_a_vertical_datum_is_refused_even_when_accepted(tmp_path):
    """Trial s96 F1: --allow-ballpark into CGCS2000 GK + Yellow Sea 1985 height copied WGS 84 ellipsoidal heights
    unchanged into a file labelled normal heights (the anomaly about -12 m near Wuhan), exit 0; the flag is taken for
    the horizontal shift it names. With a height model (--heights) the horizontal ballpark stays accepted and the
    heights are the model's; into the 2D grid the ellipsoidal heights are kept."""
    pts = _write(tmp_path / "pts.csv", "id,x,y,z\nP01,239090.714,3362233.201,28.0425\n")
    out = tmp_path / "out.csv"
    r = _run("transform", pts, out, "--from", "32650", "--to", "EPSG:4526+5737", "--allow-ballpark")
    assert r.exit_code == 2 and not out.exists(), r.output
    assert "ballpark operation for the heights" in r.output and "Yellow Sea 1985 height (EPSG:5737)" in r.output
    assert "--heights" in r.output and "EPSG:4526, ellipsoidal heights kept" in r.output
    r = _run("transform", pts, out, "--from", "32650", "--to", "EPSG:4526", "--allow-ballpark")
    assert r.exit_code == 0 and float(out.read_text().splitlines()[1].split(",")[3]) == pytest.approx(28.0425)


def test_a_height_model_in_the_outputs_grid_serves_its_compound_crs(tmp_path):
    """Trial s96 F4: a model fitted in EPSG:2383 was refused for --to EPSG:2383+5737 ("its grid is on neither
    datum"): the model is evaluated on the output's horizontal part; the heights equal those of --to EPSG:2383."""
    rng = np.random.default_rng(5)
    x, y = rng.uniform(520_000, 540_000, 8), rng.uniform(3_370_000, 3_390_000, 8)
    zeta = -12.0 + 0.03 * (x - 530_000) / 1000
    h = rng.uniform(30, 90, 8)
    lev = _write(tmp_path / "lev.csv", "id,x,y,h,H\n" + "".join(
        f"L{i},{x[i]:.3f},{y[i]:.3f},{h[i]:.4f},{h[i] - zeta[i]:.4f}\n" for i in range(8)))
    model = tmp_path / "zeta.json"
    assert _run("fit-heights", lev, "--model", "plane", "--epsg", "2383", "--h-crs", "4610", "-o", model).exit_code == 0
    pts = _write(tmp_path / "pts.csv", "id,x,y,z\nQ1,530000.0,3380000.0,60.0\n")
    got = {}
    for to in ("EPSG:2383+5737", "EPSG:2383"):
        out = tmp_path / f"out{len(got)}.csv"
        r = _run("transform", pts, out, "--from", "2383", "--to", to, "--heights", model)
        assert r.exit_code == 0, r.output
        got[to] = float(out.read_text().splitlines()[1].split(",")[3])
    assert got["EPSG:2383+5737"] == pytest.approx(got["EPSG:2383"], abs=1e-6) == pytest.approx(72.0, abs=1e-3)


def test_a_levelling_table_saved_as_gbk_is_said(tmp_path):
    """Trial s96 F5: GBK bytes of "水准G1" are valid UTF-8 by chance ("ˮ׼G1"): read without a word; the point names
    garbled in the model file. Said now, naming the line and both readings; UTF-8 Chinese reads as before."""
    rows = "".join(f"水准G{i},{520000 + 3000 * i}.0,{3370000 + 1700 * i * i % 9000}.0,{50 + i}.0,{62 + i}.0\n"
                   for i in range(1, 6))
    gbk = tmp_path / "gbk.csv"
    gbk.write_bytes(("id,x,y,h,H\n" + rows).encode("gbk"))
    r = _run("fit-heights", gbk, "--model", "plane", "--epsg", "2383", "--h-crs", "4610", "-o", tmp_path / "g.json")
    assert f"{gbk}:2: reads as UTF-8" in r.output and "as GBK '水准G1" in r.output and "iconv -f GBK" in r.output
    utf = _write(tmp_path / "utf.csv", "id,x,y,h,H\n" + rows)
    r = _run("fit-heights", utf, "--model", "plane", "--epsg", "2383", "--h-crs", "4610", "-o", tmp_path / "u.json")
    assert r.exit_code == 0 and "GBK" not in r.output and "水准G1" in r.output


def test_a_raster_warped_into_a_zone_far_from_it_is_said(tmp_path):
    """Trial s96 F9: a DEM near Wuhan (114 E) into Xian 1980 GK CM 102E was written without a word (point lists and LAS
    files warn of the area of use); said now, and still written; into its own zone nothing is said."""
    import rasterio
    from rasterio.transform import from_origin

    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=50, height=50, count=1, dtype="float32", crs="EPSG:32650",
                       transform=from_origin(239000.0, 3363000.0, 2.0, 2.0)) as ds:
        ds.write(np.full((1, 50, 50), 30.0, np.float32))
    far, near = tmp_path / "far.tif", tmp_path / "near.tif"
    r = _run("warp", dem, far, "--to", "EPSG:2379", "--allow-ballpark")
    assert r.exit_code == 0 and far.exists(), r.output
    assert "outside the area of use of EPSG:2379" in r.output and "is --to EPSG:2379 the grid meant" in r.output
    r = _run("warp", dem, near, "--to", "EPSG:4526", "--allow-ballpark")
    assert r.exit_code == 0 and "area of use" not in r.output, r.output


def test_chinese_id_columns_and_separators_a_spreadsheet_writes(tmp_path, common_points):
    """Trial s96 F12: crs fit refused an id column named 点号 (crs transform took it); a semicolon- or full-width-comma
    separated file was refused as "header [...] must name x and y columns" without saying why; a 4-parameter fit of
    points on a line warned "weakly determined across that line" (two points fix a similarity)."""
    path, _, _ = common_points
    cn = _write(tmp_path / "cn.csv", path.read_text().replace("id,", "点号,", 1))
    r = _run("fit", cn, "--model", "bursa-wolf7", "--from", "32649", "--to", "2361", "-o", tmp_path / "p.json")
    assert r.exit_code == 0, r.output
    for sep, name in ((";", "semicolons"), ("，", "full-width commas")):
        bad = _write(tmp_path / "bad.csv", f"id{sep}x{sep}y{sep}z\nP1{sep}441000,5{sep}3791000,2{sep}500,0\n")
        r = _run("transform", bad, tmp_path / "o.csv", "--from", "32649", "--to", "32649")
        assert r.exit_code == 2 and f"separated by {name}" in r.output and not (tmp_path / "o.csv").exists()
    line = _write(tmp_path / "line.csv", "id,x_from,y_from,x_to,y_to\n" + "".join(
        f"L{i},{500000 + 1000 * i},{3400000 + 100 * i},{500010 + 1000 * i},{3400020 + 100 * i}\n" for i in range(5)))
    r = _run("fit", line, "--model", "helmert2d", "--from", "32649", "--to", "32649", "-o", tmp_path / "h.json")
    assert r.exit_code == 0 and "collinear" not in r.output, r.output


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "body,args,message",
    [
        # too few points for the model
        ("id,x_from,y_from,x_to,y_to\nA,441000,3791000,37441000,3791000\nB,442000,3792000,37442000,3792000\n",
         ("--model", "affine2d"), "needs at least 3 common points"),
        # duplicate ids
        ("id,x_from,y_from,x_to,y_to\nA,441000,3791000,37441000,3791000\nB,442000,3792000,37442000,3792000\n"
         "A,443000,3791000,37443000,3791000\n", ("--model", "helmert2d"), "line 4: duplicate point id 'A' (first on line 2)"),
        # mixed units in the header
        ("id,x_from_deg,y_from_m,x_to,y_to\nA,441000,3791000,37441000,3791000\n", ("--model", "helmert2d"),
         "mixed units"),
        # degrees in a UTM column
        ("id,x_from,y_from,x_to,y_to\nA,441000,3791000,37441000,3791000\nB,109.6,34.2,37442000,3792000\n",
         ("--model", "helmert2d"), "line 3 (id B): (109.600, 34.200) lies outside the area of use of EPSG:32649"),
        # Gauss-Krueger easting without the zone prefix
        ("id,x_from,y_from,x_to,y_to\nA,441000,3791000,441000,3791000\n", ("--model", "helmert2d"),
         "does not carry the zone prefix 37"),
        # a non-number
        ("id,x_from,y_from,x_to,y_to\nA,441000,3791000,37441000,north\n", ("--model", "helmert2d"),
         "line 2: y_to = 'north' is not a number"),
        # missing column
        ("id,x_from,y_from,x_to\nA,441000,3791000,37441000\n", ("--model", "helmert2d"), "lacks column(s) y_to"),
        # spatial model without heights
        ("id,x_from,y_from,x_to,y_to\nA,441000,3791000,37441000,3791000\n", ("--model", "bursa-wolf7"),
         "need ellipsoidal heights"),
    ],
)
def test_fit_bad_input_exit_2_without_output(tmp_path, body, args, message):
    path = _write(tmp_path / "cp.csv", body)
    out = tmp_path / "params.json"
    r = _run("fit", path, *args, "--from", "32649", "--to", "2361", "-o", out)
    assert r.exit_code == 2, r.output
    assert message in r.output and r.output.startswith(f"Error: {path}")
    assert not out.exists()


def test_unknown_epsg_and_missing_file(tmp_path):
    path = _write(tmp_path / "cp.csv", "id,x_from,y_from,x_to,y_to\nA,1,2,3,4\n")
    r = _run("fit", path, "--model", "helmert2d", "--from", "99999", "--to", "2361")
    assert r.exit_code == 2 and "--from: unknown CRS '99999'" in r.output
    r = _run("transform", path, tmp_path / "o.csv", "--from", "32649", "--to", "EPSG:123456")
    assert r.exit_code == 2 and "unknown CRS" in r.output
    r = _run("fit", tmp_path / "nope.csv", "--model", "helmert2d", "--from", "32649", "--to", "2361")
    assert r.exit_code == 2 and "file not found" in r.output
    bad_params = _write(tmp_path / "p.json", "{not json")
    r = _run("transform", path, tmp_path / "o.csv", "--from", "2361", "--to", "2361", "--params", bad_params)
    assert r.exit_code == 2 and "not valid JSON" in r.output


def test_helmert2d_cli_on_gk_grids(tmp_path):
    """CGCS2000 3-degree CM 111E -> Xian 1980 zone 37: a 4-parameter set recovered through the CLI."""
    rng = np.random.default_rng(6)
    src = np.column_stack([rng.uniform(420_000, 480_000, 10), rng.uniform(3_770_000, 3_830_000, 10)])
    truth = {**TRUE_HELMERT2D, "tx_m": 37_000_000.0 + TRUE_HELMERT2D["tx_m"]}
    dst, _ = simulate_plane(truth, src, noise_m=0.005, seed=7)
    path = tmp_path / "cp.csv"
    write_common_points(path, range(10), src, dst)
    out = tmp_path / "h4.json"
    r = _run("fit", path, "--model", "helmert2d", "--from", "4546", "--to", "2361", "-o", out)
    assert r.exit_code == 0, r.output
    t = Transformation.from_dict(json.loads(out.read_text()))
    for k, v in truth.items():
        assert abs(t.parameters[k] - v) < 3 * t.std_devs[k], k
    X, Y, _ = CrsTransformer(4546, 2361, params=t).transform(src[:, 0], src[:, 1])
    assert np.sqrt(np.mean((X - dst[:, 0]) ** 2 + (Y - dst[:, 1]) ** 2)) < 0.01
    # a plane model leaves the heights as they are: the transform says so (it copied WGS 84 ellipsoidal heights
    # into a Xian 1980 file without a word, 119 m off Xian's ellipsoid at Yichang)
    pts = tmp_path / "pts.csv"
    pts.write_text("id,x,y,z\n" + "".join(f"Q{i},{x:.3f},{y:.3f},100.0\n" for i, (x, y) in enumerate(src[:3])))
    r = _run("transform", pts, tmp_path / "pts_out.csv", "--from", "4546", "--to", "2361", "--params", out)
    assert r.exit_code == 0, r.output
    assert "heights unchanged (a plane model)" in r.output
    assert [line.split(",")[3] for line in (tmp_path / "pts_out.csv").read_text().splitlines()[1:]] == ["100.0000"] * 3


def test_transform_las_uses_the_file_crs(tmp_path):
    import laspy
    import pyproj

    rng = np.random.default_rng(8)
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.offsets = np.array([440_000.0, 3_790_000.0, 0.0])
    header.scales = np.array([0.001, 0.001, 0.001])
    las = laspy.LasData(header)
    las.x, las.y, las.z = rng.uniform(440_000, 441_000, 500), rng.uniform(3_790_000, 3_791_000, 500), rng.uniform(0, 50, 500)
    las.classification = rng.integers(1, 7, 500, dtype=np.uint8)
    no_crs = tmp_path / "no_crs.las"
    las.write(no_crs)
    r = _run("transform", no_crs, tmp_path / "o.las", "--to", "4326")
    assert r.exit_code == 2 and "no CRS record in the file; give --from" in r.output
    las.header.add_crs(pyproj.CRS.from_epsg(32649))
    src = tmp_path / "utm.las"
    las.write(src)
    out = tmp_path / "cm111.laz"
    r = _run("transform", src, out, "--to", "2382", "--allow-ballpark")  # WGS 84 -> Xian 1980
    assert r.exit_code == 0, r.output
    assert "500 points" in r.output and "BALLPARK" in r.output
    res = laspy.read(out)
    assert res.header.parse_crs().to_epsg() == 2382 and len(res.points) == 500
    assert np.array_equal(res.classification, las.classification)
    r = _run("transform", src, tmp_path / "o.csv", "--to", "32650")
    assert r.exit_code == 2 and "needs a .las or .laz output" in r.output
    assert not (tmp_path / "o.csv").exists()


def test_transform_las_refuses_an_unreadable_vertical_units_key(tmp_path):
    """small-fixes2 1: a user-defined VerticalUnitsGeoKey without its size: exit 2, one line naming the file, no
    output (the heights' unit is unknown; it was read as the grid's)."""
    import laspy
    import pyproj
    from laspy.vlrs.known import GeoKeyEntryStruct

    header = laspy.LasHeader(version="1.2", point_format=1)
    header.offsets, header.scales = np.array([440_000.0, 3_790_000.0, 0.0]), np.array([0.001, 0.001, 0.001])
    header.add_crs(pyproj.CRS.from_epsg(32649))
    vlr = next(v for v in header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
    k = GeoKeyEntryStruct()
    k.id, k.tiff_tag_location, k.count, k.value_offset = 4099, 0, 1, 32767
    vlr.geo_keys.append(k)
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.full(10, 440_500.0), np.linspace(3_790_000, 3_790_100, 10), np.full(10, 100.0)
    src = tmp_path / "nosize.las"
    las.write(src)
    r = _run("transform", src, tmp_path / "o.las", "--to", "32650")
    assert r.exit_code == 2 and "nosize.las" in r.output and "GeogLinearUnitSizeGeoKey (2053)" in r.output, r.output
    assert r.output.strip().count("\n") == 0 and not (tmp_path / "o.las").exists()


@pytest.fixture
def yichang_levelling(tmp_path, common_points):
    """The trial's simulated GNSS levelling near Yichang: 12 points with h on WGS 84 and zeta = h - H of WGS 84
    (truth); 8 make the levelling file (x, y on Xian 1980 zone 37), 4 are held out (WGS 84 UTM 49N, their h).
    Both parameter sets fitted from the common points. Returns (levelling file, held-out file, h, H of the 4,
    h on Xian 1980's ellipsoid of the 8)."""
    import pyproj

    path, _, _ = common_points
    for model in ("bursa-wolf7", "helmert2d"):
        assert _run("fit", path, "--model", model, "--from", "32649", "--to", "2361", "-o",
                    tmp_path / f"{model}.json").exit_code == 0
    rng = np.random.default_rng(4)
    lon, lat, h = rng.uniform(109.7, 110.1, 12), rng.uniform(34.1, 34.4, 12), rng.uniform(400, 900, 12)
    zeta = -12.0 + 0.8 * (lon - 109.9) - 0.5 * (lat - 34.25)  # of WGS 84: the GNSS heights minus the levelled ones
    e, n = pyproj.Transformer.from_crs(4326, 32649, always_xy=True).transform(lon, lat)
    T = Transformation("bursa-wolf7", dict(TRUE_BURSA_WOLF7), "EPSG:32649", "EPSG:2361")
    X, Y, h_xian = CrsTransformer(32649, 2361, params=T).transform(e, n, h)
    lev = tmp_path / "levelling.csv"
    lev.write_text("id,x,y,h,H\n" + "".join(f"L{i},{X[i]:.3f},{Y[i]:.3f},{h[i]:.4f},{h[i] - zeta[i]:.4f}\n"
                                            for i in range(8)))
    pts = tmp_path / "pts.csv"
    pts.write_text("id,x,y,z\n" + "".join(f"C{i},{e[i]:.3f},{n[i]:.3f},{h[i]:.4f}\n" for i in range(8, 12)))
    return lev, pts, h[8:], (h - zeta)[8:], h_xian[:8]


def _heights_through(tmp_path, model, pts, zeta_file, to="2361", frm="32649", name="out"):
    out = tmp_path / f"{model}_{zeta_file.stem}_{name}.csv"
    r = _run("transform", pts, out, "--from", frm, "--to", to, "--params", tmp_path / f"{model}.json",
             "--heights", zeta_file)
    z = None if r.exit_code else np.array([float(ln.split(",")[3]) for ln in out.read_text().splitlines()[1:]])
    return r, z, out


def test_a_height_model_from_gnss_heights_gives_the_same_normal_heights_through_4_and_7_parameters(
        tmp_path, yichang_levelling):
    """The model records the datum of its h (--h-crs) and every route takes it on h of that datum: the trial's
    GNSS model (h on WGS 84) was right through helmert2d and 118.8 m off through bursa-wolf7; now both give the
    held-out normal heights within 1 cm, back to h as well, and in a foot grid in feet."""
    lev, pts, h, H, _ = yichang_levelling
    zeta = tmp_path / "zeta_wgs84.json"
    r = _run("fit-heights", lev, "--model", "plane", "--epsg", "2361", "--h-crs", "EPSG:4326", "-o", zeta)
    assert r.exit_code == 0 and "h taken as ellipsoidal heights on World Geodetic System 1984" in r.output, r.output
    d = json.loads(zeta.read_text())
    assert d["h_crs"] == "EPSG:4326" and d["crs"] == "EPSG:2361" and "World Geodetic System 1984" in d["h_datum"]
    for model in ("helmert2d", "bursa-wolf7"):
        r, got, out = _heights_through(tmp_path, model, pts, zeta)
        assert r.exit_code == 0 and "changed the ellipsoidal heights" not in r.output, r.output
        assert np.max(np.abs(got - H)) < 0.01, (model, got - H)
        # and back (the inverse operation, as crs warp and ortho take it): Xian normal heights -> WGS 84 h
        XY = np.array([[float(v) for v in ln.split(",")[1:3]] for ln in out.read_text().splitlines()[1:]])
        op = CrsTransformer(32649, 2361, load_transformation(tmp_path / f"{model}.json"), load_height_model(zeta))
        back = op.inverse().transform(XY[:, 0], XY[:, 1], got)[2]
        assert np.max(np.abs(back - h)) < 0.01, (model, back - h)
    # a grid in US survey feet on Xian 1980: the heights come out in feet, the same normal heights
    import pyproj

    d = pyproj.CRS.from_epsg(2361).to_json_dict()
    for ax in d["coordinate_system"]["axis"]:
        ax["unit"] = {"type": "LinearUnit", "name": "US survey foot", "conversion_factor": 0.304800609601219}
    d["name"] = "Xian 1980 / 3-degree Gauss-Kruger zone 37 (US survey foot)"
    d.pop("id")
    feet = tmp_path / "feet.wkt"
    feet.write_text(pyproj.CRS.from_json_dict(d).to_wkt())
    for model in ("helmert2d", "bursa-wolf7"):
        r, got_ft, _ = _heights_through(tmp_path, model, pts, zeta, to=feet.read_text(), name="feet")
        assert r.exit_code == 0, r.output
        assert np.max(np.abs(got_ft * 0.304800609601219 - H)) < 0.01, (model, got_ft)


def test_a_height_model_from_h_on_the_target_ellipsoid_goes_through_the_7_parameter_set_only(
        tmp_path, yichang_levelling):
    """A model fitted from h on Xian 1980's ellipsoid (--h-crs EPSG:4610) is taken after the
    spatial set (right heights); a plane set has no h on Xian 1980 (it leaves WGS 84's): refused, exit 2, no file.
    A model on Beijing 1954's h (neither side's) is refused through both."""
    lev, pts, _, H, h_xian = yichang_levelling
    text = lev.read_text().splitlines()
    rows = [ln.split(",") for ln in text[1:]]
    lev_xian = tmp_path / "levelling_xian.csv"
    lev_xian.write_text(text[0] + "\n" + "".join(f"{r[0]},{r[1]},{r[2]},{hx:.4f},{r[4]}\n"
                                                  for r, hx in zip(rows, h_xian)))
    zeta = tmp_path / "zeta_xian.json"
    r = _run("fit-heights", lev_xian, "--model", "plane", "--epsg", "2361", "--h-crs", "4610", "-o", zeta)
    assert r.exit_code == 0 and "on Xian 1980 (EPSG:4610)" in r.output, r.output
    r, got, _ = _heights_through(tmp_path, "bursa-wolf7", pts, zeta)
    # 8.3 mm at most: the file's h came through the true set, the transform's through the set fitted on 1 cm noise
    assert r.exit_code == 0 and np.max(np.abs(got - H)) < 0.02, (r.output, got - H)
    r, _, out = _heights_through(tmp_path, "helmert2d", pts, zeta)
    assert r.exit_code == 2 and not out.exists(), r.output
    assert "heights of Xian 1980 (h_crs EPSG:4610)" in r.output and "only on World Geodetic System 1984" in r.output
    assert "plane set" in r.output and "Traceback" not in r.output
    beijing = tmp_path / "zeta_beijing.json"
    assert _run("fit-heights", lev, "--epsg", "2361", "--h-crs", "4214", "-o", beijing).exit_code == 0
    for model in ("helmert2d", "bursa-wolf7"):
        r, _, out = _heights_through(tmp_path, model, pts, beijing)
        assert r.exit_code == 2 and not out.exists() and "heights of Beijing 1954" in r.output, r.output
        assert r.output.strip().count("\n") == 0


def test_an_old_height_model_through_a_7_parameter_set_says_on_which_ellipsoid_it_is_taken(
        tmp_path, yichang_levelling):
    """A model file without h_crs (written before it was recorded) keeps the old behaviour: taken on the output's
    h, right through a 4-parameter set and 118.8 m off through the 7-parameter set (trial-lidar), with the
    warning that says the change."""
    lev, pts, _, H, _ = yichang_levelling
    zeta = tmp_path / "zeta_old.json"
    assert _run("fit-heights", lev, "--model", "plane", "--epsg", "2361", "--h-crs", "4326", "-o",
                zeta).exit_code == 0
    d = json.loads(zeta.read_text())
    del d["h_crs"], d["h_datum"]
    zeta.write_text(json.dumps(d))
    got = {}
    for model in ("helmert2d", "bursa-wolf7"):
        r, got[model], _ = _heights_through(tmp_path, model, pts, zeta)
        assert r.exit_code == 0, r.output
        said = "the ellipsoid of Xian 1980" in r.output
        assert said == (model == "bursa-wolf7"), r.output
    assert np.max(np.abs(got["helmert2d"] - H)) < 0.01  # h unchanged, the GNSS model fits
    dh = got["bursa-wolf7"] - H  # h moved onto Xian's ellipsoid first
    assert np.all(np.abs(dh) > 50.0)
    import re

    said = float(re.search(r"changed the ellipsoidal heights by ([-+0-9.]+) m", r.output).group(1))
    assert abs(said - np.mean(dh)) < 0.01  # the message's number is the error a GNSS model makes


def test_warp_takes_a_gnss_height_model_on_wgs84_h_through_both_sets(tmp_path, yichang_levelling):
    """crs warp of a WGS 84 DEM (650 m everywhere) into Xian 1980 with the GNSS model (h on WGS 84): the same
    normal heights, 650 m - zeta, through the 4- and the 7-parameter set (the latter was 118.8 m off)."""
    import rasterio

    lev, pts, _, _, _ = yichang_levelling
    zeta = tmp_path / "zeta_wgs84.json"
    assert _run("fit-heights", lev, "--epsg", "2361", "--h-crs", "4326", "-o", zeta).exit_code == 0
    e0, n0 = (float(v) for v in pts.read_text().splitlines()[1].split(",")[1:3])
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=20, height=20, count=1, dtype="float32", crs="EPSG:32649",
                       transform=rasterio.Affine(50.0, 0.0, e0, 0.0, -50.0, n0), nodata=-9999.0) as ds:
        ds.write(np.full((1, 20, 20), 650.0, dtype=np.float32))
    model = load_height_model(zeta)
    for params in ("helmert2d", "bursa-wolf7"):
        out = tmp_path / f"dem_{params}.tif"
        r = _run("warp", dem, out, "--to", "2361", "--params", tmp_path / f"{params}.json", "--heights", zeta)
        assert r.exit_code == 0, r.output
        with rasterio.open(out) as ds:
            z = ds.read(1, masked=True)
            rows, cols = np.nonzero(~np.ma.getmaskarray(z))
            xs, ys = rasterio.transform.xy(ds.transform, rows, cols)
            assert len(rows) > 300
            assert np.abs(z[rows, cols] - (650.0 - model.zeta_m(np.array(xs), np.array(ys)))).max() < 0.01, params


@pytest.mark.parametrize("model_crs, op_crs, same", [
    ("EPSG:9057", "EPSG:32650", True), ("EPSG:32650", "EPSG:9057", True),  # WGS 84 (G1762) <-> the ensemble
    ("EPSG:7912", "EPSG:32650", True), ("EPSG:32650", "EPSG:7912", True),  # ITRF2014 <-> the ensemble (a member)
    ("EPSG:9057", "EPSG:7912", True), ("EPSG:7912", "EPSG:9057", True),  # WGS 84 (G1762) <-> ITRF2014: 2 cm
    ("EPSG:4490", "EPSG:7908", False), ("EPSG:7908", "EPSG:4490", False),  # CGCS2000 <-> ITRF97: PROJ knows none
    ("EPSG:4610", "EPSG:4326", False), ("EPSG:4326", "EPSG:4610", False),  # Xian 1980 <-> WGS 84
    ("EPSG:6319", "EPSG:7912", False), ("EPSG:7912", "EPSG:6319", False),  # NAD83(2011) <-> ITRF2014: 2.1 m in h
])
def test_datums_of_h_are_compared_by_what_proj_knows_of_them(model_crs, op_crs, same):
    """Ensemble and member, and frames PROJ links at the cm level, give the same h, with a note naming both and
    the size of the difference; datums PROJ does not link (or links metres apart) do not."""
    import pyproj

    from aerotri.geom.crs.transform import compare_h_datums

    m = compare_h_datums(pyproj.CRS(model_crs), pyproj.CRS(op_crs), 110.0, 34.2)
    assert m.same == same and not m.exact, m
    if same:
        a, b = (pyproj.CRS(c).datum.name for c in (model_crs, op_crs))
        import re

        assert a in m.note and b in m.note and re.search(r"\d m\b", m.note), m.note  # both named, a size in m


def test_a_gnss_height_model_on_a_wgs84_realization_serves_a_project_in_the_ensemble(tmp_path, yichang_levelling):
    """A model fitted with --h-crs WGS 84 (G1762) or ITRF2014 on the GNSS heights was refused against the WGS 84
    ensemble (EPSG:32649) by datum name: now the same normal heights as the ensemble's model (the h are the same
    numbers), with a note naming both datums, and the ensemble's model on points given in WGS 84 (G1762); a CGCS2000
    one stays refused (exit 2, no output)."""
    lev, pts, _, H, _ = yichang_levelling
    for h_crs in ("EPSG:9057", "EPSG:7912"):
        zeta = tmp_path / f"zeta_{h_crs[5:]}.json"
        assert _run("fit-heights", lev, "--epsg", "2361", "--h-crs", h_crs, "-o", zeta).exit_code == 0
        for model in ("helmert2d", "bursa-wolf7"):
            r, got, _ = _heights_through(tmp_path, model, pts, zeta)
            assert r.exit_code == 0 and np.max(np.abs(got - H)) < 0.01, (r.output, got - H)
            assert "World Geodetic System 1984 ensemble" in r.output and "taken as the same heights" in r.output
    # the other way round: the ensemble's model (h_crs EPSG:4326) on points in WGS 84 (G1762) (EPSG:9057), the only h
    # the operation has (refused before): H = h - zeta, with the note
    from aerotri.geom.crs.datum import HeightAnomalyModel

    plane = HeightAnomalyModel("plane", (300_000.0, 3_800_000.0), coefficients=[-12.0, 0.01, -0.005],
                               crs="EPSG:32649", h_crs="EPSG:4326")
    op = CrsTransformer("EPSG:9057", "EPSG:9057", heights=plane)
    lon, lat = np.array([109.8, 110.0]), np.array([34.2, 34.3])
    got = op.transform(lon, lat, np.array([500.0, 700.0]))[2]
    import pyproj

    e, n = pyproj.Transformer.from_crs(4326, 32649, always_xy=True).transform(lon, lat)
    assert np.max(np.abs(got - (np.array([500.0, 700.0]) - plane.zeta_m(e, n)))) < 1e-6
    assert any("World Geodetic System 1984 (G1762) is a member of the ensemble" in w for w in op.warnings), op.warnings
    zeta = tmp_path / "zeta_cgcs2000.json"
    assert _run("fit-heights", lev, "--epsg", "2361", "--h-crs", "EPSG:4490", "-o", zeta).exit_code == 0
    r, _, out = _heights_through(tmp_path, "helmert2d", pts, zeta)
    assert r.exit_code == 2 and not out.exists() and "heights of China 2000" in r.output, r.output


def test_normal_heights_back_to_ellipsoidal_heights_from_the_cli(tmp_path, yichang_levelling):
    """crs transform --normal-to-ellipsoidal: h -> H -> h round trip of the held-out Yichang GNSS points through
    both parameter sets within 0.1 mm (the files' 4 decimals); refused without --heights (exit 2, no output)."""
    lev, pts, h, _, _ = yichang_levelling
    zeta = tmp_path / "zeta_wgs84.json"
    assert _run("fit-heights", lev, "--epsg", "2361", "--h-crs", "EPSG:4326", "-o", zeta).exit_code == 0
    for model in ("helmert2d", "bursa-wolf7"):
        r, _, normal = _heights_through(tmp_path, model, pts, zeta)
        assert r.exit_code == 0, r.output
        back = tmp_path / f"back_{model}.csv"
        r = _run("transform", normal, back, "--from", "2361", "--to", "32649", "--params", tmp_path / f"{model}.json",
                 "--heights", zeta, "--normal-to-ellipsoidal")
        assert r.exit_code == 0 and "ellipsoidal heights from" in r.output, r.output
        got = np.array([float(ln.split(",")[3]) for ln in back.read_text().splitlines()[1:]])
        assert np.max(np.abs(got - h)) <= 1.0001e-4, (model, got - h)
    out = tmp_path / "no_model.csv"
    r = _run("transform", pts, out, "--from", "32649", "--to", "2361", "--normal-to-ellipsoidal")
    assert r.exit_code == 2 and not out.exists() and "--normal-to-ellipsoidal" in r.output and "--heights" in r.output
    assert r.output.strip().count("\n") == 0, r.output


def test_a_spatial_fit_knows_which_heights_its_z_columns_hold(tmp_path, common_points):
    """leftovers2: bursa-wolf7 fitted on z_to = 1985 normal heights took up the height anomaly (tilted, 12 m here) with
    1 cm residuals, and `crs transform --heights` subtracted it again. A compound --to whose heights PROJ cannot take to
    ellipsoidal ones (1985: no geoid) and an H_to column are refused saying what the z are; h_to declares ellipsoidal
    heights (the same set as z_to); the report and the parameter file say what the z were taken as."""
    path, src, dst = common_points
    header, *rows = path.read_text().splitlines()
    out = tmp_path / "p.json"
    r = _run("fit", path, "--model", "bursa-wolf7", "--from", "32649", "--to", "EPSG:2361+5737", "-o", out)
    assert r.exit_code == 2 and not out.exists(), r.output
    assert "--to" in r.output and "z_to are heights of Yellow Sea 1985" in r.output
    assert "--heights would subtract it a second time" in r.output and "fit-heights" in r.output
    normal = _write(tmp_path / "normal.csv", "\n".join([header.replace("z_to", "H_to")] + rows) + "\n")
    r = _run("fit", normal, "--model", "bursa-wolf7", "--from", "32649", "--to", "2361", "-o", out)
    assert r.exit_code == 2 and not out.exists() and "column H_to holds normal heights" in r.output, r.output
    declared = _write(tmp_path / "h.csv", "\n".join([header.replace("z_", "h_")] + rows) + "\n")
    for f, o in ((path, tmp_path / "z.json"), (declared, tmp_path / "h.json")):
        r = _run("fit", f, "--model", "bursa-wolf7", "--from", "32649", "--to", "2361", "-o", o)
        assert r.exit_code == 0, r.output
        assert "Heights: z_from ellipsoidal heights h on World Geodetic System 1984" in r.output
        assert "z_to ellipsoidal heights h on Xian 1980" in r.output
    z, h = (json.loads((tmp_path / n).read_text()) for n in ("z.json", "h.json"))
    assert z["parameters"] == h["parameters"] and z["heights"].startswith("z_from ellipsoidal heights h")


def test_normal_height_columns_are_refused_in_any_case_and_only_for_the_spatial_models(tmp_path, common_points):
    """Review 44: the H_from/H_to refusal was case-sensitive while columns match without case (H_TO got past it and
    bursa-wolf7 took normal heights for ellipsoidal ones), and it also refused the plane models, which read no
    heights (helmert2d on a file with H columns: exit 0 before leftovers2, then exit 2). The capital H marks them."""
    path, src, dst = common_points
    header, *rows = path.read_text().splitlines()
    out = tmp_path / "p.json"
    for name in ("H_TO", "H_To_m"):
        f = _write(tmp_path / "upper.csv", "\n".join([header.replace("z_to", name)] + rows) + "\n")
        r = _run("fit", f, "--model", "bursa-wolf7", "--from", "32649", "--to", "2361", "-o", out)
        assert r.exit_code == 2 and not out.exists() and f"column {name} holds normal heights" in r.output, r.output
    plane = _write(tmp_path / "plane.csv", "\n".join(
        [",".join(c for c in header.split(",") if not c.startswith("z_"))]
        + [",".join(v for c, v in zip(header.split(","), row.split(",")) if not c.startswith("z_")) for row in rows])
        + "\n")
    normal = _write(tmp_path / "normal.csv", "\n".join([header.replace("z_", "H_")] + rows) + "\n")
    fits = []
    for f in (plane, normal):
        o = tmp_path / f"{f.stem}.json"
        r = _run("fit", f, "--model", "helmert2d", "--from", "32649", "--to", "2361", "-o", o)
        assert r.exit_code == 0, r.output
        fits.append(json.loads(o.read_text())["parameters"])
    assert fits[0] == fits[1]


def test_to_and_from_take_a_wkt_or_prj_file(tmp_path):
    """leftovers2: `--to grid.wkt` was refused as an unknown CRS (only WKT pasted on the command line was taken). A
    .wkt or .prj path (ESRI's WKT too) is read; a file that cannot be read, or holds no CRS, is named (exit 2, no
    output)."""
    import pyproj

    pts = _write(tmp_path / "pts.csv", "id,x,y,z\nA,441000.0,3791000.0,500.0\n")
    want = tmp_path / "want.csv"
    assert _run("transform", pts, want, "--from", "32649", "--to", "32650").exit_code == 0
    (tmp_path / "utm50.wkt").write_text(pyproj.CRS.from_epsg(32650).to_wkt())
    (tmp_path / "utm49.prj").write_text(pyproj.CRS.from_epsg(32649).to_wkt("WKT1_ESRI"))
    out = tmp_path / "out.csv"
    r = _run("transform", pts, out, "--from", tmp_path / "utm49.prj", "--to", tmp_path / "utm50.wkt")
    assert r.exit_code == 0, r.output
    assert out.read_text() == want.read_text()
    _write(tmp_path / "bad.prj", "PROJCS[nonsense")
    for to, message in ((tmp_path / "missing.wkt", f"--to: cannot read the CRS file {tmp_path / 'missing.wkt'}"),
                        (tmp_path / "bad.prj", f"--to: the CRS file {tmp_path / 'bad.prj'} holds no CRS PROJ knows")):
        r = _run("transform", pts, tmp_path / "o.csv", "--from", "32649", "--to", to)
        assert r.exit_code == 2 and message in r.output and not (tmp_path / "o.csv").exists(), r.output


LOCAL_GK = "+proj=tmerc +lat_0=0 +lon_0=114.5 +k=1 +x_0=500000 +y_0=0 +ellps=GRS80 +units=m +no_defs"


def test_a_local_gauss_krueger_grid_on_grs80_takes_its_stated_datum(tmp_path):
    """leftovers2: a user's local Gauss-Krueger grid of CGCS2000, "+proj=tmerc +lon_0=114.5 ... +ellps=GRS80", names an
    ellipsoid and no datum, so PROJ offers only a ballpark operation from CGCS2000 / 3-degree GK CM 114E (EPSG:4547)
    and it was refused as that, with the advice to fit parameters. The refusal now says what is missing (its datum:
    +datum=EPSG:4490, CGCS2000 having GRS 1980's ellipsoid); stated, the operation is exact (a change of projection on
    one datum: PROJ's own conversion through EPSG:4490's coordinates); an ellipsoid other than the stated datum's is
    refused naming both."""
    import pyproj

    pts = _write(tmp_path / "pts.csv", "id,x,y,z\nA,480000.0,3400000.0,50.0\nB,520000.0,3450000.0,80.0\n")
    out = tmp_path / "out.csv"
    r = _run("transform", pts, out, "--from", "EPSG:4547", "--to", LOCAL_GK)
    assert r.exit_code == 2 and not out.exists(), r.output
    assert "names the ellipsoid GRS 1980 but no datum" in r.output and "+datum=EPSG:4490" in r.output
    r = _run("transform", pts, out, "--from", "EPSG:4547", "--to", LOCAL_GK + " +datum=EPSG:4490")
    assert r.exit_code == 0 and "BALLPARK" not in r.output, r.output
    got = np.array([[float(v) for v in ln.split(",")[1:3]] for ln in out.read_text().splitlines()[1:]])
    lon, lat = pyproj.Transformer.from_crs(4547, 4490, always_xy=True).transform([480000.0, 520000.0],
                                                                                [3400000.0, 3450000.0])
    want = np.column_stack(pyproj.Proj(LOCAL_GK)(lon, lat))  # the same latitudes and longitudes, projected
    assert np.abs(got - want).max() < 1e-3 and np.abs(got[:, 0] - [480000.0, 520000.0]).min() > 1000  # moved 0.5 deg
    r = _run("transform", pts, tmp_path / "o.csv", "--from", "EPSG:4547", "--to",
             LOCAL_GK.replace("GRS80", "krass") + " +datum=EPSG:4490")
    assert r.exit_code == 2 and "Krassovsky" in r.output and "China 2000" in r.output, r.output
    assert not (tmp_path / "o.csv").exists()


def test_a_stated_datum_refuses_a_second_datum_and_keeps_the_heights_unit_and_geoid():
    """Review 44: "+datum=EPSG:4490" beside +towgs84 dropped the stated datum (without +ellps ending on WGS 84), beside
    +geoidgrids stopped with an AttributeError traceback, beside +vunits dropped the heights' unit, and a 3D CRS
    (EPSG:4979) was taken as the datum. A second datum and a 3D one are refused naming them; +vunits and +geoidgrids
    mean what PROJ makes of them (feet heights; heights above the geoid, a compound CRS)."""
    import pyproj

    from aerotri.core.errors import CrsError
    from aerotri.geom.crs.definition import height_unit_m, horizontal_crs, parse_crs, same_horizontal, vertical_crs

    gk = LOCAL_GK.replace(" +no_defs", "")
    for extra, message in ((" +towgs84=10,20,30", r"states its datum twice, \+datum=EPSG:4490 and \+towgs84=10,20,30"),
                           (" +nadgrids=@null", r"states its datum twice"),
                           (" +datum=WGS84", r"states its datum twice")):
        for text in (gk + " +datum=EPSG:4490" + extra, gk.replace(" +ellps=GRS80", "") + " +datum=EPSG:4490" + extra):
            with pytest.raises(CrsError, match=message):
                parse_crs(text, "--to")
    with pytest.raises(CrsError, match=r"--to: \+datum=EPSG:4979 is WGS 84, a 3D geographic CRS .*EPSG:4326"):
        parse_crs(gk + " +datum=EPSG:4979", "--to")
    plain = parse_crs(gk + " +datum=EPSG:4490")
    lon, lat, h = 114.6, 30.4, 100.0
    feet = parse_crs(gk + " +datum=EPSG:4490 +vunits=ft")
    assert height_unit_m(feet) == pytest.approx(0.3048) and feet.datum.name == "China 2000"
    e, n, z = pyproj.Transformer.from_crs(pyproj.CRS(4490).to_3d(), feet, always_xy=True).transform(lon, lat, h)
    assert z == pytest.approx(h / 0.3048) and (e, n) == pytest.approx(pyproj.Proj(LOCAL_GK)(lon, lat), abs=1e-6)
    assert len(feet.geodetic_crs.axis_info) == 3  # (its base the 3D geographic CRS of the datum, as the axes say)
    geographic = parse_crs("+proj=longlat +datum=EPSG:4490 +vunits=ft")  # (was EPSG:4490 itself: heights in metres)
    assert geographic.datum.name == "China 2000" and height_unit_m(geographic) == pytest.approx(0.3048)
    assert pyproj.Transformer.from_crs(pyproj.CRS(4490).to_3d(), geographic, always_xy=True).transform(
        lon, lat, h) == pytest.approx((lon, lat, h / 0.3048))
    geoid = parse_crs(gk + " +datum=EPSG:4490 +geoidgrids=egm96_15.gtx", "--to")
    assert geoid.is_compound and vertical_crs(geoid) is not None and same_horizontal(horizontal_crs(geoid), plain)
    assert horizontal_crs(geoid).datum.name == "China 2000"
    # the heights above the grid's geoid, as PROJ takes the same text on the ellipsoid alone (the grid's heights in
    # feet with +vunits=ft)
    for extra in (" +geoidgrids=egm96_15.gtx", " +geoidgrids=egm96_15.gtx +vunits=ft"):
        geoid = parse_crs(gk + " +datum=EPSG:4490" + extra, "--to")
        assert vertical_crs(geoid) == pyproj.CRS(gk + extra).sub_crs_list[1], extra
    assert height_unit_m(geoid) == pytest.approx(0.3048)


def test_a_parameter_file_keeps_its_crs_as_wkt_so_any_crs_fitted_is_applied(tmp_path):
    """Review 44: the parameter file recorded from_crs/to_crs as labels and `crs transform --params` parsed them
    again: a PROJ string's, a stated datum's (+datum=EPSG:4490) and a .prj file's labels were "unknown CRS". The file
    keeps the CRSs as WKT beside the labels; a file of before (labels only) is read as it was."""
    import pyproj

    rng = np.random.default_rng(4)
    e, n = rng.uniform(470000, 530000, 8), rng.uniform(3380000, 3460000, 8)
    local = LOCAL_GK + " +datum=EPSG:4490"
    x, y = pyproj.Transformer.from_crs(4547, pyproj.CRS(LOCAL_GK), always_xy=True).transform(e, n)
    x, y = x + 1.5 + rng.normal(0, 0.01, 8), y - 2.0 + rng.normal(0, 0.01, 8)  # a local shift to fit
    pts = _write(tmp_path / "cp.csv", "id,x_from,y_from,x_to,y_to\n" + "".join(
        f"P{i},{a:.3f},{b:.3f},{c:.3f},{d:.3f}\n" for i, (a, b, c, d) in enumerate(zip(e, n, x, y))))
    (tmp_path / "local.prj").write_text(pyproj.CRS(local.replace(" +datum=EPSG:4490", "")).to_wkt("WKT1_ESRI"))
    one = _write(tmp_path / "one.csv", f"id,x,y\nA,{e[0]:.3f},{n[0]:.3f}\n")
    for k, to in enumerate((local, "+proj=tmerc +lon_0=114.5 +x_0=500000 +datum=NAD83", tmp_path / "local.prj")):
        par, out = tmp_path / f"p{k}.json", tmp_path / f"o{k}.csv"
        r = _run("fit", pts, "--model", "helmert2d", "--from", "EPSG:4547", "--to", to, "-o", par)
        assert r.exit_code == 0, r.output
        d = json.loads(par.read_text())
        assert pyproj.CRS(d["to_crs_wkt"]) == parse_to(to) and pyproj.CRS(d["from_crs_wkt"]).to_epsg() == 4547
        r = _run("transform", one, out, "--from", "EPSG:4547", "--to", to, "--params", par)
        assert r.exit_code == 0 and out.is_file(), r.output
        if k == 0:  # the fitted set applied: the point where the fit put it (observed plus its residual)
            got = [float(v) for v in out.read_text().splitlines()[1].split(",")[1:3]]
            res = d["residuals"][0]
            assert abs(got[0] - (x[0] + res["de_m"])) < 2e-3 and abs(got[1] - (y[0] + res["dn_m"])) < 2e-3, res
    d = json.loads((tmp_path / "p1.json").read_text())  # a file of before: labels only
    del d["from_crs_wkt"], d["to_crs_wkt"]
    d["to_crs"] = "EPSG:4547"
    (tmp_path / "old.json").write_text(json.dumps(d))
    r = _run("transform", one, tmp_path / "old.csv", "--from", "EPSG:4547", "--to", "EPSG:4547", "--params",
             tmp_path / "old.json")
    assert r.exit_code == 0, r.output


def parse_to(text):
    from aerotri.geom.crs.definition import parse_crs

    return parse_crs(str(text))


def test_an_odm_header_with_a_null_towgs84_is_its_epsg_code(tmp_path):
    """leftovers2: OpenDroneMap's header "+proj=utm +zone=49 +datum=WGS84 +towgs84=0,0,0,0,0,0,0" was taken for the
    same coordinates as EPSG:32649 but named "Position Vector transformation (geog2D domain) ()" in every message
    and imports.json (and "+datum=WGS84" without TOWGS84 by its projection parameters); both are EPSG:32649 now,
    and a TOWGS84 that moves the points (173 m) is not."""
    from aerotri.exchange.odm_export import _crs_line
    from aerotri.geom.crs.definition import crs_label, parse_crs, same_crs

    odm = "+proj=utm +zone=49 +datum=WGS84 +towgs84=0,0,0,0,0,0,0 +units=m +no_defs"
    for text in (odm, "+proj=utm +zone=49 +datum=WGS84 +towgs84=0,0,0", "+proj=utm +zone=49 +datum=WGS84 +units=m"):
        assert crs_label(parse_crs(text)) == "EPSG:32649" and same_crs(text, "EPSG:32649"), text
        assert _crs_line(text) == "EPSG:32649"
    # (PROJ applies no TOWGS84 to a datum named WGS84: such a header is the same whatever it says; on the ellipsoid
    # alone, a shift of 100 m in each axis)
    moved = "+proj=utm +zone=49 +ellps=WGS84 +towgs84=100,100,100 +units=m"
    assert crs_label(parse_crs(moved)) != "EPSG:32649" and not same_crs(moved, "EPSG:32649")
    assert crs_label(parse_crs(moved)).startswith("Transverse Mercator (Longitude of natural origin 111")
    # an ellipsoid alone states no datum: not named by the ETRS89 grid PROJ finds for it at 70 %
    assert crs_label(parse_crs("+proj=utm +zone=32 +ellps=GRS80 +units=m")) != "EPSG:25832"
