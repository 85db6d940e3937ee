"""Writing an imported block into a project: the project's own readers get back what was imported; nothing is
replaced without ``overwrite``; an import that cannot be written leaves the project as it was."""

import shutil

import numpy as np
import pytest

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.exchange import ImportedBlock, write_imported
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import ExteriorOrientations, GnssPositions, read_eo, read_gnss
from aerotri.geom.observations import ControlPoints, ImageObservations, read_control_points, read_image_points


@pytest.fixture
def project(tiny_project, tmp_path):
    root = tmp_path / "p"
    root.mkdir()
    shutil.copy(tiny_project / "project.toml", root / "project.toml")
    return root


def _block(tiny_project):
    cam = read_camera(tiny_project / "camera.toml")
    gnss = GnssPositions(["a", "b"], np.array([[500100.0, 4100200.0, 900.0], [500300.0, 4100200.0, 901.5]]),
                         np.array([[0.05, 0.05, 0.1], [0.05, 0.05, 0.1]]))
    eo = ExteriorOrientations(["a", "b"], gnss.position_m.copy(), np.array([[0.5, -0.3, 90.0], [0.1, 0.2, 91.0]]))
    control = ControlPoints(np.array(["g1", "g2"], object), np.array(["full", "check"], object),
                            np.array([[500150.0, 4100210.0, 12.25], [500250.0, 4100190.0, 13.5]]),
                            np.array([[0.02, 0.02, 0.03], [0.02, 0.02, 0.03]]))
    obs = ImageObservations(np.array(["g1", "g1"], object), np.array(["a", "b"], object),
                            np.array([[100.25, 200.5], [300.125, 150.0]]))
    return ImportedBlock(source=["somewhere.txt"], camera=cam, gnss=gnss, eo=eo, control=control, image_points=obs)


def test_written_files_read_back(project, tiny_project):
    block = _block(tiny_project)
    written = write_imported(project, block, "test")
    p = Project.open(project)
    assert {project / w.path for w in written} == {p.camera_path, p.gnss_path, p.imported_eo_path,
                                                   p.control_points_path, p.control_image_points_path,
                                                   p.imported_record_path}
    assert read_camera(p.camera_path) == block.camera
    g = read_gnss(p.gnss_path)
    assert g.image_id == ["a", "b"] and np.allclose(g.position_m, block.gnss.position_m, atol=1e-4)
    assert np.allclose(g.sigma_m, block.gnss.sigma_m)
    eo = read_eo(p.imported_eo_path)
    assert np.allclose(eo.opk_deg, block.eo.opk_deg, atol=1e-7) and np.allclose(eo.centre_m, block.eo.centre_m, atol=1e-4)
    c = read_control_points(p.control_points_path)
    assert list(c.kind) == ["full", "check"] and np.allclose(c.xyz_m, block.control.xyz_m, atol=1e-4)
    o = read_image_points(p.control_image_points_path)
    assert np.allclose(o.xy_px, block.image_points.xy_px, atol=1e-3)


def test_existing_files_are_not_replaced_without_overwrite(project, tiny_project):
    block = _block(tiny_project)
    p = Project.open(project)
    p.gnss_path.write_text("# mine\n")
    before = sorted(x.name for x in project.rglob("*"))
    with pytest.raises(InputError, match="gnss.txt: exists"):
        write_imported(project, block, "test")
    assert sorted(x.name for x in project.rglob("*")) == before  # all or nothing: no file of the import written
    assert p.gnss_path.read_text() == "# mine\n"
    write_imported(project, block, "test", overwrite=True)
    assert read_gnss(p.gnss_path).image_id == ["a", "b"]


def test_empty_block_is_refused(project):
    with pytest.raises(InputError, match="nothing to import"):
        write_imported(project, ImportedBlock(source=["x.txt"]), "test")
