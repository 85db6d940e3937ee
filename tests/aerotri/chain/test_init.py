"""`aerotri init`: a valid project folder from a folder of frames (links or copies, project.toml with the CRS,
camera.toml from --camera or EXIF, or what to write into it), refused when it could not be right; and
docs/project.md documents every project.toml and camera.toml key the code knows."""

from __future__ import annotations

import dataclasses
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main

REPO = Path(__file__).resolve().parents[3]


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.is_symlink(), p.stat().st_size if p.is_file() else None)
            for p in root.rglob("*")}


def test_init_makes_a_project_that_matches(tiny_project, tmp_path):
    """init + gnss.txt is a project `aerotri match` runs on, frames linked, the input folder untouched."""
    images = tiny_project / "images"
    before = snapshot(images)
    p = tmp_path / "blk"
    r = run("init", p, "--images", images, "--crs", "EPSG:32649", "--camera", tiny_project / "camera.toml")
    assert r.exit_code == 0, r.output
    assert "6 frames linked" in r.output and "camera.toml from" in r.output
    links = sorted((p / "images").iterdir())
    assert len(links) == 6 and all(q.is_symlink() and q.resolve() == (images / q.name).resolve() for q in links)
    cfg = tomllib.loads((p / "project.toml").read_text())
    assert cfg == {"project": {"name": "blk", "crs": "EPSG:32649", "heights": "ellipsoidal"}}
    assert (p / "camera.toml").read_text() == (tiny_project / "camera.toml").read_text()
    assert not [q for q in tmp_path.rglob(".*")]
    shutil.copy(tiny_project / "gnss.txt", p / "gnss.txt")
    with open(p / "project.toml", "a") as f:  # the flight's terrain height, as the docs say to add it
        f.write("\n[flight]\nmean_terrain_height_m = 310.0\n")
    r = run("match", p)
    assert r.exit_code == 0, r.output
    assert (p / "at" / "tiepoints.csv").stat().st_size > 1000
    assert snapshot(images) == before


def test_init_quiet_prints_nothing(tiny_project, tmp_path):
    """s95: `init -q` printed its summary and the next step; they are progress, silenced as every command's are."""
    images = tiny_project / "images"
    r = run("init", tmp_path / "blk", "--images", images, "--crs", "EPSG:32649", "--camera",
            tiny_project / "camera.toml", "-q")
    assert r.exit_code == 0 and r.output == "", r.output
    assert (tmp_path / "blk" / "project.toml").is_file()


def test_init_into_an_existing_empty_folder(tiny_project, tmp_path, monkeypatch):
    """trial-paths: init into an existing empty folder (also `aerotri init .`) was always refused "not an empty
    folder": the command's own lock file was made in it before the check."""
    for p, arg in ((tmp_path / "empty", None), (tmp_path / "here", ".")):
        p.mkdir()
        if arg:
            monkeypatch.chdir(p)
        r = run("init", arg or p, "--images", tiny_project / "images", "--crs", "EPSG:32649", "--camera",
                tiny_project / "camera.toml")
        assert r.exit_code == 0, r.output
        assert (p / "project.toml").is_file() and len(list((p / "images").iterdir())) == 6
    spaced = tmp_path / "Block A"
    r = run("init", spaced, "--images", tiny_project / "images", "--crs", "EPSG:32649")
    assert r.exit_code == 0 and f"aerotri run '{spaced}'" in r.output  # a hint that can be pasted
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("mine")
    r = run("init", tmp_path / "full", "--images", tiny_project / "images", "--crs", "EPSG:32649")
    assert r.exit_code == 2 and "not an empty folder" in r.output


def test_init_takes_a_crs_file_into_the_project(tiny_project, tmp_path, monkeypatch):
    """Review 47: `aerotri init P --crs grid.prj` (the file in the current folder) wrote crs = "grid.prj", which every
    command reads in the project folder: a project no command ran. The file is copied into the project."""
    import pyproj

    from aerotri.core.project import Project

    work = tmp_path / "work"
    work.mkdir()
    (work / "grid.prj").write_text(pyproj.CRS("EPSG:32649").to_wkt("WKT1_ESRI"))
    monkeypatch.chdir(work)
    r = run("init", tmp_path / "blk", "--images", tiny_project / "images", "--crs", "grid.prj",
            "--camera", tiny_project / "camera.toml")
    assert r.exit_code == 0, r.output
    p = tmp_path / "blk"
    assert tomllib.loads((p / "project.toml").read_text())["project"]["crs"] == "grid.prj"
    assert (p / "grid.prj").read_bytes() == (work / "grid.prj").read_bytes()
    monkeypatch.chdir(tmp_path)
    assert pyproj.CRS(Project.open(p).crs).equals(pyproj.CRS("EPSG:32649"))


def test_init_copies_with_copy_and_says_what_camera_to_write(tiny_project, tmp_path):
    """--copy: real files; frames without EXIF camera data: no camera.toml, the template with their size."""
    p = tmp_path / "blk"
    r = run("init", p, "--images", tiny_project / "images", "--crs", "EPSG:32649", "--copy")
    assert r.exit_code == 0, r.output
    files = sorted((p / "images").iterdir())
    assert len(files) == 6 and not any(q.is_symlink() for q in files)
    assert files[0].read_bytes() == (tiny_project / "images" / files[0].name).read_bytes()
    assert not (p / "camera.toml").exists()
    assert "write camera.toml" in r.stderr and "width = 432" in r.stderr and "height = 240" in r.stderr
    # what the EXIF lacks, in words (the NGI frames said "the   is not in the sensor table": no make, no model)
    assert "no camera in the EXIF (no focal length, make or model)" in r.stderr and "the   is" not in r.stderr
    # said once, with the other way to get a camera (an import that carries it, as NGI's orthority files)
    assert r.stderr.count("write camera.toml") == 1 and "--format orthority" in r.stderr
    assert "Traceback" not in r.stderr


def _exif_jpeg(path: Path, size=(640, 480), focal_mm=8.8, px_per_cm=9090.9):
    """A JPEG with EXIF FocalLength and FocalPlaneXResolution (per centimetre)."""
    from PIL import Image

    img = Image.fromarray((np.random.default_rng(1).random((size[1], size[0], 3)) * 255).astype(np.uint8))
    exif = Image.Exif()
    ifd = exif.get_ifd(0x8769)
    ifd[0x920A] = focal_mm  # FocalLength
    ifd[0xA20E] = px_per_cm  # FocalPlaneXResolution
    ifd[0xA20F] = px_per_cm  # FocalPlaneYResolution
    ifd[0xA210] = 3  # FocalPlaneResolutionUnit: centimetre
    ifd[0xA002], ifd[0xA003] = size  # PixelX/YDimension
    img.save(path, exif=exif)


def test_init_camera_from_exif(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        _exif_jpeg(frames / f"DJI_{k:04d}.JPG")
    p = tmp_path / "blk"
    r = run("init", p, "--images", frames, "--crs", "EPSG:32611")
    assert r.exit_code == 0, r.output
    from aerotri.geom.camera import read_camera

    cam = read_camera(p / "camera.toml")
    assert (cam.width, cam.height) == (640, 480)
    assert cam.focal_mm == pytest.approx(8.8)
    assert cam.pixel_um == pytest.approx(10000.0 / 9090.9, rel=1e-4)  # 1 cm / px per cm, in micrometres
    assert "From the EXIF of DJI_0000.JPG" in (p / "camera.toml").read_text()


def test_init_writes_the_settings_given_with_set(tiny_project, tmp_path):
    """`--set section.key=value` (TOML values, or a bare word) goes into project.toml as live sections, read back by
    every command as typed settings with project.toml as their source; `aerotri import` still puts its terrain height
    under the [flight] header when --set gave none, and keeps the one --set gave."""
    from aerotri.chain.options import read_options
    from aerotri.core.project import Project

    p = tmp_path / "blk"
    r = run("init", p, "--images", tiny_project / "images", "--crs", "EPSG:32649", "--camera",
            tiny_project / "camera.toml", "--set", "project.heights=EPSG:3855", "--set", "flight.mean_terrain_height_m=411",
            "--set", "gnss.sigma_xy_m=0.05", "--set", 'adjust.self_calibration=["pp", "radial"]',
            "--set", "match.sparse.budget=8000", "--set", "rectify.dem=dem.tif", "--set", "flight.speed_mps=60")
    assert r.exit_code == 0, r.output
    cfg = tomllib.loads((p / "project.toml").read_text())
    assert cfg == {"project": {"name": "blk", "crs": "EPSG:32649", "heights": "EPSG:3855"},
                   "flight": {"mean_terrain_height_m": 411, "speed_mps": 60}, "gnss": {"sigma_xy_m": 0.05},
                   "adjust": {"self_calibration": ["pp", "radial"]}, "match": {"sparse": {"budget": 8000}},
                   "rectify": {"dem": "dem.tif"}}
    project = Project.open(p)
    assert project.info.heights == "EPSG:3855" and project.flight.mean_terrain_height_m == 411.0
    assert project.flight.speed_mps == 60.0 and project.gnss.sigma_xy_m == 0.05
    assert project.source_of("flight", "mean_terrain_height_m") == "project.toml"
    opts = read_options(project)
    assert opts.settings.adjust.self_calibration == ("pp", "radial") and opts.settings.match.sparse.budget == 8000
    assert opts.settings.rectify.dem == p / "dem.tif"
    # the template's lines stay, comments included: [project] heights replaced in place, the sections appended
    text = (p / "project.toml").read_text()
    assert 'heights = "EPSG:3855"  # "ellipsoidal", or a vertical CRS' in text
    assert text.index("# [gnss]") < text.index("\n[flight]\nmean_terrain_height_m = 411\nspeed_mps = 60\n")


def test_init_set_a_bare_word_and_the_last_of_a_key(tiny_project, tmp_path):
    p = tmp_path / "blk"
    r = run("init", p, "--images", tiny_project / "images", "--crs", "EPSG:32649", "--camera",
            tiny_project / "camera.toml", "--set", "qa.map_scale=1:2000", "--set", "flight.speed_mps=50",
            "--set", "flight.speed_mps=65.5", "--set", 'project.name=block "north"')
    assert r.exit_code == 0, r.output
    cfg = tomllib.loads((p / "project.toml").read_text())
    assert cfg["qa"] == {"map_scale": "1:2000"} and cfg["flight"] == {"speed_mps": 65.5}
    assert cfg["project"]["name"] == 'block "north"' 


@pytest.mark.parametrize("item, expect", [
    ("flight.mean_terrain_height_m=abc", "--set flight.mean_terrain_height_m=abc [flight] mean_terrain_height_m = 'abc': expected a number"),
    ("flight.height=400", "--set flight.height=400 [flight]: unknown key 'height'"),
    ("fligth.speed_mps=60", "--set fligth.speed_mps=60: unknown section [fligth]"),
    ("match.foo=1", "--set match.foo=1 [match]: unknown key 'foo'"),
    ("match.sparse=1", "--set match.sparse=1 [match.sparse]: expected a table"),
    ("adjust.self_calibration=wobble", "expected one of focal, pp, radial, tangential"),
    ("project.heights=EPSG:32633", "--set project.heights=EPSG:32633: EPSG:32633 (WGS 84 / UTM zone 33N) is not a vertical CRS"),
    ("project.crs=EPSG:32650", "the project CRS is chosen at aerotri init --crs"),
    ("heights=EPSG:3855", "expected section.key=value"),
    ("flight.speed_mps", "expected section.key=value"),
    ("gnss.sigma_xy_m=-1", "--set gnss.sigma_xy_m=-1 [gnss] sigma_xy_m"),
])
def test_init_refuses_a_bad_set(item, expect, tiny_project, tmp_path):
    """A --set item that project.toml could not hold is refused before anything is made, naming the item."""
    before = snapshot(tmp_path)
    r = run("init", tmp_path / "blk", "--images", tiny_project / "images", "--crs", "EPSG:32649", "--camera",
            tiny_project / "camera.toml", "--set", "flight.speed_mps=60", "--set", item)
    assert r.exit_code == 2 and "Traceback" not in r.stderr, r.output
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and expect in errors[0], r.stderr
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("case", ["exists", "geographic", "vertical", "two_sizes", "no_images", "inside_images"])
def test_init_refuses(case, tiny_project, tmp_path):
    frames = tmp_path / "frames"
    shutil.copytree(tiny_project / "images", frames)
    p, crs, expect = tmp_path / "blk", "EPSG:32649", None
    if case == "exists":
        p.mkdir()
        (p / "notes.txt").write_text("mine")
        expect = "not an empty folder"
    elif case == "geographic":
        crs, expect = "EPSG:4326", "--crs"
    elif case == "vertical":  # (heights only: new-user trial s51, taken by init and a traceback in match)
        crs, expect = "EPSG:5703", "is a vertical CRS (heights only)"
    elif case == "two_sizes":
        _exif_jpeg(frames / "odd.jpg")
        expect = "2 sizes"
    elif case == "no_images":
        for q in frames.iterdir():
            q.unlink()
        (frames / "readme.txt").write_text("no frames")
        expect = "no images"
    elif case == "inside_images":
        p = frames / "blk"
        expect = "inside the frames' folder"
    before = snapshot(tmp_path)
    r = run("init", p, "--images", frames, "--crs", crs, "--camera", tiny_project / "camera.toml")
    assert r.exit_code == 2 and "Traceback" not in r.stderr, r.output
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and expect in errors[0], r.stderr
    assert snapshot(tmp_path) == before


def test_docs_name_every_project_and_camera_key():
    """docs/project.md documents every section and key of project.toml the code knows, every stage section,
    and every camera.toml key of every lens model."""
    from aerotri.core.project import PROJECT_SECTIONS, STAGE_SECTION_NAMES
    from aerotri.geom.camera import MODELS

    doc = (REPO / "docs" / "project.md").read_text()
    for section, cls in PROJECT_SECTIONS.items():  # section -> its settings dataclass
        assert f"### `[{section}]`" in doc, section
        for key in (f.name for f in dataclasses.fields(cls)):
            assert f"`{key}`" in doc, f"[{section}] {key}"
    for section in STAGE_SECTION_NAMES:
        assert f"`[{section}]`" in doc, section
    for model, cls in MODELS.items():
        assert f"`{model}`" in doc or f'"{model}"' in doc, model
        for f in dataclasses.fields(cls):
            assert f"`{f.name}`" in doc, f"camera.toml {f.name}"
    assert "## `gnss.txt`" in doc and "image_id X Y Z [sX sY sZ]" in doc
    for header in ("id,kind,x,y,z,sx_m,sy_m,sz_m", "point_id,image_id,x_px,y_px"):
        assert header in doc


def test_project_toml_template_shows_the_gnss_defaults(tmp_path):
    """project.toml's commented [gnss] lines are what the adjustment takes when they stay commented (the template
    said sigma_z_m = 0.08 while the default, which the EXIF import and `aerotri settings` state, is 0.1); the flight
    offset's keys, which have no default (no offset: a survey receiver), show what the EXIF import writes for a
    consumer receiver."""
    from aerotri.chain.setup import project_toml
    from aerotri.core.project import GnssSettings
    from aerotri.exchange.exif import CONSUMER_GNSS

    text = project_toml("t", "EPSG:32615", "UTM")
    gnss = text.split("# [gnss]", 1)[1].split("\n\n", 1)[0]
    shown = tomllib.loads("\n".join(line.removeprefix("# ").split("#")[0] for line in gnss.splitlines()[1:]))
    defaults = GnssSettings()
    assert shown == {"sigma_xy_m": defaults.sigma_xy_m, "sigma_z_m": defaults.sigma_z_m,
                     "lever_arm_m": list(defaults.lever_arm_m),
                     "offset_sigma_xy_m": CONSUMER_GNSS[2], "offset_sigma_z_m": CONSUMER_GNSS[3]}
    assert defaults.offset_sigma_m is None and f"e.g. {CONSUMER_GNSS[0]:g}" in gnss
