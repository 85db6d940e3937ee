"""One settings model (issues 39 and 40): every project.toml section is a checked dataclass, the commands over a
project read their section with the precedence default < project.toml < command line (an option given overrides
only itself), the reports say where each setting came from, and docs/settings.md is generated from the same
declarations."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.settings import COMMAND_LINE, DEFAULT, PROJECT_TOML
from ortho.cli import main as ortho_cli

REPO = Path(__file__).resolve().parents[3]
PROJECT = '[project]\nname = "t"\ncrs = "EPSG:32649"\n'


def _project(tmp_path, extra: str = "") -> Path:
    p = tmp_path / "p"
    p.mkdir(exist_ok=True)
    (p / "project.toml").write_text(PROJECT + extra)
    return p


class _Captured(Exception):
    """Raised by a stand-in stage function with the settings it was given (the command stops there)."""

    def __init__(self, settings):
        super().__init__("captured")
        self.settings = settings


def _capture(monkeypatch, module: str, name: str, position: int = 1, keyword: str = "settings"):
    """Replace the stage function ``module.name`` by one that raises ``_Captured`` with its settings argument."""
    import importlib

    def stand_in(*args, **kwargs):
        raise _Captured(kwargs[keyword] if keyword in kwargs else args[position])

    monkeypatch.setattr(importlib.import_module(module), name, stand_in)


def _settings_of(cli, args):
    r = CliRunner().invoke(cli, args)
    assert isinstance(r.exception, _Captured), r.output
    return r.exception.settings


# command, its stage function, (section, key, project.toml value, the field's value), (option, value given, value)
# and another key of the same section, set in project.toml, that the option must leave alone
CASES = {
    "match": (aerotri_cli, ["match"], ("aerotri.match.pipeline", "match_project", 1),
              ("match", "min_overlap", "0.3", 0.3), ("--min-overlap", "0.4", 0.4), ("densify", "false", False),
              "min_overlap", "densify"),
    "match_nested": (aerotri_cli, ["match"], ("aerotri.match.pipeline", "match_project", 1),
                     ("match.sparse", "budget", "800", 800), ("--budget", "900", 900), ("max_dim_px", "2000", 2000),
                     "sparse.budget", "sparse.max_dim_px"),
    "adjust": (aerotri_cli, ["adjust", "--no-exports"], ("aerotri.adjust.pipeline", "run_adjustment", 1),
               ("adjust", "gnss_correction", '"shift"', "shift"), ("--gnss-correction", "none", "none"),
               ("self_calibration", '["pp", "radial"]', ("pp", "radial")), "gnss_correction", "self_calibration"),
    "adjust_flag": (aerotri_cli, ["adjust", "--no-exports"], ("aerotri.adjust.pipeline", "run_adjustment", 1),
                    ("adjust", "use_control", "true", True), ("--no-control", None, False),
                    ("image_sigma_px", "0.8", 0.8), "use_control", "image_sigma_px"),
    "adjust_list": (aerotri_cli, ["adjust", "--no-exports"], ("aerotri.adjust.pipeline", "run_adjustment", 1),
                    ("adjust", "self_calibration", '["pp", "radial"]', ("pp", "radial")), ("--self-cal", "", ()),
                    ("alpha", "0.001", 0.001), "self_calibration", "alpha"),
    "control": (aerotri_cli, ["control"], ("aerotri.control.pipeline", "run_control", 5),
                ("control.layout", "min_frames", "2", 2), ("--min-frames", "4", 4), ("fallback", "false", False),
                "layout.min_frames", "layout.fallback"),
    "rectify": (ortho_cli, ["rectify"], ("ortho.block", "rectify_block", 1),
                ("rectify", "res_m", "0.25", 0.25), ("--res-m", "0.3", 0.3), ("interpolation", '"cubic"', "cubic"),
                "res_m", "interpolation"),
    "mosaic": (ortho_cli, ["mosaic"], ("ortho.mosaic", "mosaic_block", 1),
               ("mosaic", "seams", '"voronoi"', "voronoi"), ("--seams", "least-cost", "least-cost"),
               ("tile_px", "512", 512), "seams", "tile_px"),
    "dom_check": (ortho_cli, ["check", "--reference", "REF"], ("ortho.check", "run_check", 1),
                  ("dom_check", "patch_px", "32", 32), ("--patch-px", "64", 64), ("search_px", "9", 9),
                  "patch_px", "search_px"),
    "run": (aerotri_cli, ["run"], ("aerotri.chain.run", "run_project", 1),
            ("classify", "keep_classes", "false", False), ("--keep-lidar-classes", None, True),
            ("ground_method", '"ptd"', "ptd"), "classify.keep_classes", "classify.ground_method"),
}


def _args(base: list, p: Path) -> list:
    return [a.replace("REF", str(p / "ref.tif")) for a in base[:1]] + [str(p)] + \
        [a.replace("REF", str(p / "ref.tif")) for a in base[1:]]


def _get(settings, path: str):
    for part in path.split("."):
        settings = getattr(settings, part)
    return settings


@pytest.mark.parametrize("case", sorted(CASES))
def test_precedence_default_then_project_toml_then_the_command_line(case, tmp_path, monkeypatch):
    cli, base, (module, fn, pos), (section, key, toml_value, value), (option, given, given_value), \
        (other, other_toml, other_value), path, other_path = CASES[case]
    _capture(monkeypatch, module, fn, pos)
    p = _project(tmp_path)
    option_args = [option] + ([given] if given is not None else [])
    # no section: every field its default
    r = _settings_of(cli, _args(base, p))
    assert set(r.sources.values()) == {DEFAULT}
    default_value = _get(r.settings, path)
    # project.toml gives the key and another of its section
    _project(tmp_path, f"\n[{section}]\n{key} = {toml_value}\n{other} = {other_toml}\n")
    r = _settings_of(cli, _args(base, p))
    assert _get(r.settings, path) == value and r.sources[path] == PROJECT_TOML
    assert _get(r.settings, other_path) == other_value and r.sources[other_path] == PROJECT_TOML
    assert {s for k, s in r.sources.items() if k not in (path, other_path)} == {DEFAULT}
    # the option given overrides only itself
    r = _settings_of(cli, _args(base, p) + option_args)
    assert _get(r.settings, path) == given_value and r.sources[path] == COMMAND_LINE
    assert _get(r.settings, other_path) == other_value and r.sources[other_path] == PROJECT_TOML
    assert default_value != given_value or value != given_value


def test_the_record_of_a_stage_names_each_source(tmp_path, monkeypatch):
    _capture(monkeypatch, "aerotri.adjust.pipeline", "run_adjustment", 1)
    p = _project(tmp_path, '\n[gnss]\nlever_arm_m = [0.0, 0.1, 1.5]\n[adjust]\nself_calibration = ["pp"]\n')
    rec = _settings_of(aerotri_cli, ["adjust", str(p), "--alpha", "0.001"]).record()
    assert rec["self_calibration"] == {"value": ["pp"], "source": PROJECT_TOML}
    assert rec["alpha"] == {"value": 0.001, "source": COMMAND_LINE}
    assert rec["gnss_correction"] == {"value": "none", "source": DEFAULT}
    # the [gnss] lever arm, where [adjust] gives none
    assert rec["lever_arm_m"] == {"value": [0.0, 0.1, 1.5], "source": "project.toml [gnss]"}


# a bad value in every section: the command stops naming the file, the section and the key
BAD = [("project", "heights", "3"), ("camera", "file", "1"), ("gnss", "sigma_z_m", "-0.1"),
       ("gnss", "lever_arm_m", "[1, 2]"), ("control", "sigma_xy_m", '"ten"'), ("control", "tol_px", "0.0"),
       ("flight", "speed_mps", "0"), ("flight", "mean_terrain_height_m", '"high"'), ("qa", "pdf", '"yes"'),
       ("strips", "maps", "1"), ("strips.surface", "min_points", "2"), ("classify", "roof_rms_m", "0"),
       ("classify", "water_min_points", "0"), ("classify.noise", "slope", "-1"), ("rasters", "res_m", "-1"),
       ("corners", "roof", '"round"'), ("vectors", "enabled", '"on"'), ("match", "densify", "2"),
       ("match.match", "ratio", "1.5"), ("adjust", "image_sigma_px", "0"), ("adjust", "surface_sigma_m", '"x"'),
       ("control.measure", "min_edge_points", "2"), ("rectify", "compression", '"lzw"'),
       ("mosaic", "tile_px", "8"), ("dom_check", "patch_px", "4")]


@pytest.mark.parametrize("section, key, value", BAD)
def test_a_bad_value_in_any_section_is_refused_by_name(section, key, value, tmp_path):
    p = _project(tmp_path, f"{key} = {value}\n" if section == "project" else f"\n[{section}]\n{key} = {value}\n")
    r = CliRunner().invoke(aerotri_cli, ["settings", str(p)])
    assert r.exit_code == 2, r.output
    msg = r.stderr.strip()
    assert len(msg.splitlines()) == 1 and "Traceback" not in r.output
    assert str(p / "project.toml") in msg and f"[{section}]" in msg and key in msg


def test_an_unknown_key_of_a_section_is_refused_by_name(tmp_path):
    p = _project(tmp_path, "\n[mosaic]\nseam = \"voronoi\"\n")
    r = CliRunner().invoke(ortho_cli, ["mosaic", str(p)])
    assert r.exit_code == 2 and "[mosaic]: unknown key 'seam'" in r.stderr and "project.toml" in r.stderr


def test_the_settings_command_lists_every_setting_with_its_source(tmp_path):
    p = _project(tmp_path, "\n[adjust]\ngnss_correction = \"shift\"\n")
    r = CliRunner().invoke(aerotri_cli, ["settings", str(p)])
    assert r.exit_code == 0, r.output
    assert "gnss_correction" in r.output and "shift  [project.toml]" in r.output
    assert "crs" in r.output and "EPSG:32649  [project.toml]" in r.output
    assert "res_m" in r.output and "[default]" in r.output


def test_docs_settings_md_is_current():
    """docs/settings.md is what `aerotri settings --markdown` makes of the declarations now (regenerate it with
    `.venv/bin/aerotri settings --markdown > docs/settings.md`)."""
    r = CliRunner().invoke(aerotri_cli, ["settings", "--markdown"])
    assert r.exit_code == 0, r.output
    assert (REPO / "docs" / "settings.md").read_text() == r.output
    for section in ("project", "camera", "gnss", "control", "flight", "qa", "adjust", "match", "rectify", "mosaic",
                    "dom_check", "classify", "corners", "strips", "vectors", "rasters"):
        assert f"## [{section}]" in r.output
    assert "`aerotri adjust --gnss-correction`" in r.output and "`ortho rectify --res-m`" in r.output


def test_every_setting_has_help_and_its_unit_in_the_name():
    """Declared once: every field of every section has a help text; lengths, angles and pixel sizes say their
    unit in their name (the reference page's unit column)."""
    import dataclasses
    import typing

    from aerotri.chain.options import ALL_SECTIONS
    from aerotri.core.settings import _owner, constraints, field_named, leaf_paths, unit_of

    missing = []
    for name, cls in ALL_SECTIONS:
        for path in leaf_paths(cls):
            owner, field = _owner(cls, path)
            if not constraints(field_named(owner, field)).help:
                missing.append(f"[{name}] {path}")
    assert missing == []
    # no float setting of the stage sections named like a length without its unit
    unitless = [f.name for _, cls in ALL_SECTIONS for f in dataclasses.fields(cls)
                if typing.get_type_hints(cls).get(f.name) is float and not unit_of(f.name)
                and any(w in f.name for w in ("height", "width", "radius", "size", "spacing", "distance"))]
    assert unitless == []


def test_one_suffix_for_settings_and_no_signature_introspection():
    """Issue 40: the settings dataclasses are all named ...Settings, and nothing reads a function's signature
    for its defaults."""
    import ast
    import re

    offenders, introspection = [], []
    for path in list((REPO / "aerotri").rglob("*.py")) + list((REPO / "lidarctl").rglob("*.py")) + \
            list((REPO / "ortho").rglob("*.py")):
        text = path.read_text()
        if "inspect.signature" in text:
            introspection.append(str(path))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef) and re.search(r"(Params|Options)$", node.name) and any(
                    "dataclass" in ast.unparse(d) for d in node.decorator_list):
                offenders.append(f"{path.relative_to(REPO)}: {node.name}")
    assert introspection == [] and offenders == []


def test_report_takes_qa_then_the_command_line(tmp_path, monkeypatch):
    """aerotri report: an option not given leaves the value to [qa] (then the default)."""
    import aerotri.qa.report as qa_report

    seen = []
    monkeypatch.setattr(qa_report, "write_qa_report",
                        lambda *a, **kw: seen.append(kw) or (_ for _ in ()).throw(_Captured(a)))
    p = _project(tmp_path, '\n[qa]\nmap_scale = "1:2000"\nterrain = "hilly"\n')
    CliRunner().invoke(aerotri_cli, ["report", str(p)])
    CliRunner().invoke(aerotri_cli, ["report", str(p), "--scale", "1:10000"])
    assert [(kw["terrain"], kw["scale"]) for kw in seen] == [(None, None), (None, "1:10000")]
    from aerotri.core.tolerances import qa_settings

    assert (qa_settings(p).map_scale, qa_settings(p).terrain) == ("1:2000", "hilly")


def test_adjust_without_options_takes_the_project_toml_settings_and_reports_their_sources(tmp_path):
    """Issue 39, item 9: `aerotri adjust P` with [adjust] self_calibration and gnss_correction in project.toml
    self-calibrates and corrects the GNSS (it used to report both disabled); report.json and report.txt list
    every setting with its source, and an option given overrides only itself."""
    from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

    block = geometric_block(2, 5, seed=5)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=100, n_check=6, seed=6)
    with open(root / "project.toml", "a") as f:
        f.write('\n[adjust]\nself_calibration = ["pp", "radial"]\ngnss_correction = "shift"\nimage_sigma_px = 0.3\n')
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--no-exports", "--no-html"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rep = json.loads((root / "at" / "report.json").read_text())
    assert rep["options"]["self_calibration"] == "Enabled (pp, radial)"
    assert rep["options"]["gps_shift_drift_correction"] == "Enabled (shift per strip)"
    s = rep["settings"]
    assert s["self_calibration"] == {"value": ["pp", "radial"], "source": PROJECT_TOML}
    assert s["gnss_correction"] == {"value": "shift", "source": PROJECT_TOML}
    assert s["snooping"] == {"value": True, "source": DEFAULT}
    # the inputs as read (run_adjustment takes them before the adjustment: trial-gis F9)
    assert rep["inputs"]["at/tiepoints.csv"]["size"] == (root / "at" / "tiepoints.csv").stat().st_size
    text = (root / "at" / "report.txt").read_text()
    assert "self_calibration" in text and "pp, radial  [project.toml]" in text and "[default]" in text
    # one option given: only it changes, the rest of [adjust] stays
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--no-exports", "--no-html", "--gnss-correction", "none"],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rep = json.loads((root / "at" / "report.json").read_text())
    assert rep["settings"]["gnss_correction"] == {"value": "none", "source": COMMAND_LINE}
    assert rep["options"]["gps_shift_drift_correction"] == "Disabled"
    assert rep["settings"]["self_calibration"]["source"] == PROJECT_TOML
    assert rep["options"]["self_calibration"] == "Enabled (pp, radial)"


def test_from_table_names_a_refused_key_by_the_source_that_gave_it():
    """A key's value given elsewhere than the table's file (``sources``) is refused under that name first, the
    file's other keys as before: a caller names the option as typed without reading the message."""
    import dataclasses

    from aerotri.core.errors import ConfigError
    from aerotri.core.settings import from_table, setting

    @dataclasses.dataclass(frozen=True)
    class Flight:
        strips: int = setting(2, min=1)
        speed_mps: float = setting(60.0, min=1.0)

    given = {"strips": "--set flight.strips=0"}
    with pytest.raises(ConfigError) as exc:
        from_table(Flight, {"strips": 0, "speed_mps": 50.0}, "p.toml [flight]", sources=given)
    assert str(exc.value) == "--set flight.strips=0: p.toml [flight] strips = 0: out of range, expected >= 1"
    with pytest.raises(ConfigError) as exc:  # the file's own key: no option to name
        from_table(Flight, {"strips": 3, "speed_mps": 0.5}, "p.toml [flight]", sources=given)
    assert str(exc.value).startswith("p.toml [flight] speed_mps = 0.5: out of range")
    assert from_table(Flight, {"strips": 3}, "p.toml [flight]", sources=given) == Flight(strips=3)


def test_a_bad_element_of_a_comma_separated_option_is_named_once(tmp_path):
    """Tuniu trial: `--self-cal --dem X` (the value forgotten) read "'--dem' = '--dem': expected one of ..."; the
    element is now named once, and a list names the bad element only."""
    p = _project(tmp_path)
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(p), "--self-cal", "--dem", "x.tif"])
    assert r.exit_code == 2
    assert "Invalid value for '--self-cal': '--dem': expected one of focal, pp, radial, tangential" in r.output, r.output
    assert "' = '" not in r.output
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(p), "--self-cal", "pp,foc"])
    assert r.exit_code == 2 and "'foc': expected one of" in r.output and "' = '" not in r.output, r.output
