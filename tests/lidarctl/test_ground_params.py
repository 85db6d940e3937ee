"""Every ground-filter parameter on the command line (grouped in --help), in a TOML parameter file and
in project.toml [classify]: the same values reach the filter, bad values stop with the file/option named."""

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.core.errors import ConfigError
from aerotri.core.settings import from_table
from lidarctl import synthetic
from lidarctl.classify import ground
from lidarctl.classify.pipeline import ClassifySettings
from lidarctl.cli.main import main


@pytest.fixture(scope="module")
def cloud_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("gp")
    cloud, truth = synthetic.synthetic_scene(width_m=60.0, density_per_m2=2.0, seed=3)
    synthetic.write_las(d / "in.laz", cloud, crs="EPSG:32632")
    return d / "in.laz", truth


def test_help_lists_every_parameter_of_every_filter_under_its_heading():
    text = CliRunner().invoke(main, ["classify", "--help"], terminal_width=200).output
    for method, flt in ground.GROUND_FILTERS.items():
        heading = text.index(f"Ground filter {method!r}")
        for name in flt.params.__dataclass_fields__:
            assert text.index(ground.option_name(method, name) + " ") > heading, (method, name)
    assert text.index("--preset") < text.index("Ground filter 'morph'")  # the plain options come first


def test_options_file_and_project_table_give_the_same_classes(cloud_file, tmp_path):
    path, truth = cloud_file
    opts = ["--method", "ptd", "--ptd-seed-cell-m", "20", "--ptd-max-angle-deg", "30"]
    r = CliRunner().invoke(main, ["classify", str(path), str(tmp_path / "a.laz"), *opts])
    assert r.exit_code == 0, r.output
    (tmp_path / "p.toml").write_text('method = "ptd"\n[ptd]\nseed_cell_m = 20\nmax_angle_deg = 30.0\n')
    r = CliRunner().invoke(main, ["classify", str(path), str(tmp_path / "b.laz"), "--ground-params",
                                  str(tmp_path / "p.toml")])
    assert r.exit_code == 0, r.output
    a, b = (laspy.read(tmp_path / f).classification for f in ("a.laz", "b.laz"))
    np.testing.assert_array_equal(a, b)
    assert np.mean(a[truth == 2] == 2) > 0.85  # PTD on a 60 m scene with a knoll it cannot climb
    # an option overrides the file; the buffer follows the seed cell (1.5 x 40 m)
    r = CliRunner().invoke(main, ["classify", str(path), str(tmp_path / "c.laz"), "--ground-params",
                                  str(tmp_path / "p.toml"), "--ptd-seed-cell-m", "40"])
    assert r.exit_code == 0 and "+ 60 m buffer" in r.output, r.output
    # project.toml [classify] takes the same table
    p = from_table(ClassifySettings, {"ground_method": "ptd", "ground_params": {"seed_cell_m": 25, "max_angle_deg": 20}},
                   "P/project.toml [classify]")
    assert p.ground_params == {"seed_cell_m": 25.0, "max_angle_deg": 20.0}
    with pytest.raises(ConfigError, match=r"project.toml \[classify\].*unknown key 'seed_cel_m'"):
        from_table(ClassifySettings, {"ground_method": "ptd", "ground_params": {"seed_cel_m": 25}},
                   "P/project.toml [classify]")


@pytest.mark.parametrize("args, toml, message", [
    (["--ptd-seed-cell-m", "20"], None, "--ptd-seed-cell-m: a parameter of the 'ptd' ground filter, but the filter "
                                        "is 'morph'"),
    (["--method", "ptd"], "[ptd]\nseed_cel_m = 20.0\n", "[ptd]: unknown key 'seed_cel_m'"),
    (["--method", "ptd"], "[ptd]\nseed_cell_m = -2\n", "[ptd] seed_cell_m = -2.0: out of range, expected >= 1"),
    ([], '[ptd]\nseed_cell_m = 20.0\n', "holds [ptd] parameters, but the ground filter is 'morph'"),
    ([], "[ptd\n", "not a TOML file"),
    (["--morph-slope", "0"], None, "Invalid value for '--morph-slope'"),
])
def test_bad_parameters_name_the_option_or_file_and_write_nothing(cloud_file, tmp_path, args, toml, message):
    path, _ = cloud_file
    if toml is not None:
        (tmp_path / "p.toml").write_text(toml)
        args = [*args, "--ground-params", str(tmp_path / "p.toml")]
    out = tmp_path / "o.laz"
    r = CliRunner().invoke(main, ["classify", str(path), str(out), *args])
    assert r.exit_code == 2 and message in r.output, r.output
    assert not out.exists() and not list(tmp_path.glob(".o*"))
