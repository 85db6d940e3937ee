"""Settings given as ``section.key=value`` (``aerotri init --set``, ``aerotri settings PROJECT --set``): written into
project.toml line by line with its comments kept, read back as asked, refused (nothing written) when a value is bad
or the file holds the key in a form that is not a line of its own."""

from __future__ import annotations

import tomllib

import pytest
from click.testing import CliRunner

from aerotri.chain.set_settings import SettingChange, parse_item, with_settings
from aerotri.cli import main
from aerotri.core.errors import ConfigError, OptionError

TEXT = """\
# my block
[project]
name = "blk"
crs = "EPSG:32649"
heights = "ellipsoidal"  # changed when the GNSS is in EGM2008

[flight]   # the flight
speed_mps = 60 # m/s
[match.sparse]
budget = 4000"""


def changed(text, *items):
    return with_settings(text, [SettingChange(*parse_item(i)) for i in items], "project.toml")


def test_a_key_replaced_in_place_with_its_comment():
    out = changed(TEXT, "project.heights=EPSG:3855", "flight.speed_mps=65.5")
    assert 'heights = "EPSG:3855"  # changed when the GNSS is in EGM2008\n' in out
    assert "speed_mps = 65.5  # m/s\n" in out
    assert out.startswith("# my block\n[project]") and "[flight]   # the flight\n" in out
    assert len(out.splitlines()) == len(TEXT.splitlines())


def test_a_new_key_under_its_header_and_a_new_section_at_the_end():
    out = changed(TEXT, "flight.mean_terrain_height_m=411", "match.sparse.grid=4", "adjust.gnss_correction=shift",
                  "match.min_overlap=0.1")
    cfg = tomllib.loads(out)
    assert cfg["flight"] == {"mean_terrain_height_m": 411, "speed_mps": 60}
    assert cfg["match"] == {"sparse": {"budget": 4000, "grid": 4}, "min_overlap": 0.1}
    assert cfg["adjust"] == {"gnss_correction": "shift"}
    # after the section's last key (the last section's header had no line end: beneath it all the same)
    assert "[match.sparse]\nbudget = 4000\ngrid = 4\n" in out
    assert "[flight]   # the flight\nspeed_mps = 60 # m/s\nmean_terrain_height_m = 411\n[match.sparse]" in out


def test_new_keys_go_after_the_last_key_above_the_comment_lines():
    text = "[project]\nname = \"a\"\n# heights = \"EPSG:3855\"\n\n# [gnss]\n# sigma_xy_m = 0.05\n"
    out = changed(text, "project.heights=EPSG:3855", "gnss.sigma_xy_m=0.05")
    assert out.startswith('[project]\nname = "a"\nheights = "EPSG:3855"\n# heights = "EPSG:3855"\n')
    assert out.endswith("# sigma_xy_m = 0.05\n\n[gnss]\nsigma_xy_m = 0.05\n")


def test_byte_order_mark_line_ends_and_unicode_kept():
    text = "\ufeff[project]\r\nname = \"a\"  # here\r\n[flight]\r\nspeed_mps = 60\r\n"
    out = changed(text, "project.name=\u00c9tude \u00e9t\u00e9", "flight.mean_terrain_height_m=411")
    assert out == ("\ufeff[project]\r\nname = \"\u00c9tude \u00e9t\u00e9\"  # here\r\n[flight]\r\nspeed_mps = 60\r\n"
                   "mean_terrain_height_m = 411\r\n")


def test_a_file_that_is_no_toml_is_refused():
    with pytest.raises(ConfigError, match="project.toml: not valid TOML"):
        changed("[flight\nspeed_mps = 60\n", "flight.speed_mps=65")


@pytest.mark.parametrize("value", ['[GCP1, GCP2]', '"1:2000', "{a = 1", "'x"])
def test_a_value_meant_as_toml_that_is_none_is_refused(value):
    with pytest.raises(OptionError, match="is not a TOML value"):
        parse_item(f"adjust.check={value}")


def test_a_hash_inside_a_string_is_no_comment():
    text = '[qa]\nmap_scale = "1:5000 #a"  # the contract\n'
    out = changed(text, "qa.map_scale=1:2000")
    assert out == '[qa]\nmap_scale = "1:2000"  # the contract\n'


@pytest.mark.parametrize("text", [
    '[adjust]\nself_calibration = [\n  "pp",\n  "radial",\n]\n',  # a value over several lines
    'flight.speed_mps = 60\n',  # dotted keys: no [flight] header
    'flight = { speed_mps = 60 }\n',  # an inline table
])
def test_a_key_not_on_a_line_of_its_own_is_refused(text):
    item = "adjust.self_calibration=pp" if "adjust" in text else "flight.speed_mps=65"
    with pytest.raises(ConfigError, match="project.toml: .*(edit it by hand)"):
        changed(text, item)


def _project(tiny_project, tmp_path):
    p = tmp_path / "blk"
    r = CliRunner().invoke(main, ["init", str(p), "--images", str(tiny_project / "images"), "--crs", "EPSG:32649",
                                  "--camera", str(tiny_project / "camera.toml")])
    assert r.exit_code == 0, r.output
    return p


def test_settings_set_changes_the_project(tiny_project, tmp_path):
    p = _project(tiny_project, tmp_path)
    r = CliRunner().invoke(main, ["settings", str(p), "--set", "flight.mean_terrain_height_m=300",
                                  "--set", "project.heights=EPSG:3855", "--set", "mosaic.feather_m=0.8",
                                  "--set", "flight.mean_terrain_height_m=310", "--set", "rectify.dem=dem/lidar.tif"])
    assert r.exit_code == 0, r.output
    assert f"{p / 'project.toml'}: [flight] mean_terrain_height_m = 300 (was not given: its default)" in r.output
    assert f"{p / 'project.toml'}: [flight] mean_terrain_height_m = 310 (was 300)" in r.output
    # a file that is not there yet: written, with a warning naming where the commands will look
    assert f"--set rectify.dem=dem/lidar.tif: {p / 'dem' / 'lidar.tif'} is not there (yet)" in r.stderr
    assert '[project] heights = "EPSG:3855" (was "ellipsoidal")' in r.output
    r = CliRunner().invoke(main, ["settings", str(p)])
    assert r.exit_code == 0 and "mean_terrain_height_m : 310.0  [project.toml]" in r.output
    assert "heights : EPSG:3855  [project.toml]" in r.output


def test_a_file_setting_of_a_relative_project_path_is_looked_for_once_beside_it(tiny_project, tmp_path, monkeypatch):
    """Docs trial s101 F1: with the project given as a relative path P, a file setting was looked for in P/P/...: a
    warning "P/P/../dem/town_dem.tif is not there (yet)" also when the file was there."""
    _project(tiny_project, tmp_path)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "dem").mkdir()
    args = ["settings", "blk", "--set", "rectify.dem=../dem/town_dem.tif"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0 and "blk/../dem/town_dem.tif is not there (yet)" in r.stderr, r.output
    assert "blk/blk" not in r.output
    (tmp_path / "dem" / "town_dem.tif").write_bytes(b"")
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0 and "not there" not in r.output, r.output


@pytest.mark.parametrize("args, expect", [
    (["--set", "flight.speed_mps=fast"], "--set flight.speed_mps=fast [flight] speed_mps = 'fast': expected a number"),
    (["--set", "flight.speed_mps=65", "--set", "mosaic.no_such_key=1"], "--set mosaic.no_such_key=1 [mosaic]: unknown key"),
    (["--set", "project.crs=EPSG:32650"], "the project CRS is chosen at aerotri init --crs"),
    (["--markdown", "--set", "flight.speed_mps=65"], "--set changes a project's project.toml: give PROJECT"),
    (["--set", "gnss.offset_sigma_xy_m=0.1", "--set", "flight.speed_mps=70"],
     "--set gnss.offset_sigma_xy_m=0.1 [gnss]: offset_sigma_xy_m and offset_sigma_z_m: give both"),
])
def test_settings_set_refused_leaves_the_file_as_it_was(args, expect, tiny_project, tmp_path):
    p = _project(tiny_project, tmp_path)
    before = (p / "project.toml").read_bytes()
    r = CliRunner().invoke(main, ["settings", *([] if "--markdown" in args else [str(p)]), *args])
    assert r.exit_code == 2 and "Traceback" not in r.stderr, r.output
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert len(errors) == 1 and expect in errors[0], r.stderr
    assert (p / "project.toml").read_bytes() == before


def test_a_typo_already_in_project_toml_is_named_as_the_file_s(tiny_project, tmp_path):
    """Kite trial: `settings --set adjust.leave_one_out=yes` over a project.toml holding `self_calibraton` in [adjust]
    blamed the --set item for the file's typo. The file's own error is named as the file's; a --set to another
    section still works."""
    p = _project(tiny_project, tmp_path)
    with open(p / "project.toml", "a") as f:
        f.write('\n[adjust]\nself_calibraton = ["pp"]\n')
    before = (p / "project.toml").read_bytes()
    r = CliRunner().invoke(main, ["settings", str(p), "--set", "adjust.leave_one_out=true"])
    assert r.exit_code == 2, r.output
    errors = [s for s in r.stderr.splitlines() if s.startswith("Error:")]
    assert errors == [f"Error: {p / 'project.toml'} [adjust]: unknown key 'self_calibraton' (known: "
                      + errors[0].split("(known: ")[1]], r.stderr
    assert "--set" not in errors[0] and (p / "project.toml").read_bytes() == before
    r = CliRunner().invoke(main, ["settings", str(p), "--set", "mosaic.feather_m=0.8"])
    assert r.exit_code == 0, r.output


def test_two_keys_that_go_together_are_set_in_one_command(tiny_project, tmp_path):
    """Trial s97 L1: `--set gnss.offset_sigma_xy_m=0.1 --set gnss.offset_sigma_z_m=50` was refused ("give both ... or
    neither"), in either order: each item was checked alone."""
    for order in ((0, 1), (1, 0)):
        p = _project(tiny_project, tmp_path / str(order[0]))
        items = ["gnss.offset_sigma_xy_m=0.1", "gnss.offset_sigma_z_m=50"]
        r = CliRunner().invoke(main, ["settings", str(p)] + [a for k in order for a in ("--set", items[k])])
        assert r.exit_code == 0, r.output
        gnss = tomllib.loads((p / "project.toml").read_text())["gnss"]
        assert gnss["offset_sigma_xy_m"] == 0.1 and gnss["offset_sigma_z_m"] == 50
