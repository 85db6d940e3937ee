"""Project heights are in the project CRS's unit (docs/project.md: z "in the project CRS and its unit"), whatever the
unit of ``[project] heights``: EPSG:3855 (EGM2008, metres) beside a US-feet grid gives EGM2008 heights in US feet.
Review 43: the compound CRS of the project's coordinates took the vertical CRS's metres, so feet were read as metres:
a COLMAP model of such a project imported into the same grid with EGM2008 in US feet came in 3.28x high (760.39 ft
-> 2494.70), a point of the one project into the other 231.77 for 760.39, and the Metashape export placed the chunk
with the feet read as metres."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET

import numpy as np
import pyproj
import pytest

from aerotri.core.project import Project
from aerotri.exchange import export_project, import_files
from aerotri.exchange.imported import to_project_crs
from aerotri.geom.crs.definition import height_unit_m, project_crs_3d, vertical_crs
from aerotri.geom.eo import read_eo
from tests.aerotri.exchange.test_metashape import chunk_centres_geodetic

US_FT_M = 1200 / 3937
UTM_US_FT = "+proj=utm +zone=49 +datum=WGS84 +units=us-ft +no_defs"
# EGM2008 in US survey feet: the same vertical datum as EPSG:3855 (PROJ relates them by the unit alone)
EGM2008_US_FT = ('VERTCRS["EGM2008 height (ftUS)",VDATUM["EGM2008 geoid"],CS[vertical,1],AXIS["gravity-related '
                 'height (H)",up,LENGTHUNIT["US survey foot",0.304800609601219]]]')
# a point of the demo block (UTM 49N) in US feet, z an EGM2008 height in US feet (the review's s01_001)
POINT_US_FT = np.array([[1484747.6, 11179048.4, 760.3864]])


def _project(root, crs=UTM_US_FT, heights="EPSG:3855"):
    root.mkdir()
    (root / "project.toml").write_text(f"[project]\nname = \"p\"\ncrs = \"{crs}\"\nheights = '{heights}'\n")
    return Project.open(root)


def test_the_project_compound_has_its_heights_in_the_grids_unit(tmp_path):
    a = _project(tmp_path / "a")
    v = vertical_crs(project_crs_3d(a))
    assert abs(height_unit_m(project_crs_3d(a)) - US_FT_M) < 1e-12
    assert v.datum.name == pyproj.CRS("EPSG:3855").datum.name
    # a metre grid keeps EPSG:3855 as it is
    m = _project(tmp_path / "m", crs="EPSG:32649")
    assert vertical_crs(project_crs_3d(m)).to_epsg() == 3855


def test_a_point_between_two_feet_projects_of_egm2008_keeps_its_height(tmp_path):
    """Project A: EPSG:3855 (metres) beside the US-feet grid; project B: the same grid with EGM2008 in US feet. Both
    hold z in US feet: a point passes unchanged either way (was 231.77 for 760.39, B into A)."""
    a = _project(tmp_path / "a")
    b = _project(tmp_path / "b", heights=EGM2008_US_FT)
    into_a = to_project_crs(POINT_US_FT, project_crs_3d(b).to_wkt(), a, "test")
    into_b = to_project_crs(POINT_US_FT, project_crs_3d(a).to_wkt(), b, "test")
    assert np.abs(into_a - POINT_US_FT).max() < 1e-6 and np.abs(into_b - POINT_US_FT).max() < 1e-6
    # the same point given in metres (UTM 49N + EGM2008 height) comes in as US feet, its height too
    x_m, y_m = pyproj.Transformer.from_crs(UTM_US_FT, "EPSG:32649", always_xy=True).transform(*POINT_US_FT[0, :2])
    from_m = to_project_crs([[x_m, y_m, POINT_US_FT[0, 2] * US_FT_M]], "EPSG:32649+3855", a, "test")
    assert np.abs(from_m - POINT_US_FT).max() < 1e-4


def _feet_project(adjusted_tiny, dst):
    """The adjusted tiny block with its numbers read as US feet on a transverse Mercator placed so that the block
    stays where it was (lon 111 E, in the synthetic geoid's area), EGM2008 heights (EPSG:3855)."""
    root, _ = adjusted_tiny
    shutil.copytree(root, dst, symlinks=True)
    x, y = read_eo(Project.open(root).eo_path).centre_m[:, :2].mean(axis=0)
    crs = (f"+proj=tmerc +lat_0=0 +lon_0=111 +k=0.9996 +x_0={500000 - (1 - US_FT_M) * x:.3f} "
           f"+y_0={-(1 - US_FT_M) * y:.3f} +datum=WGS84 +units=us-ft +no_defs")
    toml = (dst / "project.toml").read_text()
    assert 'crs = "EPSG:32649"\n' in toml and "heights" not in toml
    (dst / "project.toml").write_text(toml.replace('crs = "EPSG:32649"\n', f'crs = "{crs}"\nheights = "EPSG:3855"\n'))
    return dst, crs


def test_colmap_of_a_feet_project_comes_back_in_feet(adjusted_tiny, tmp_path, fresh_project, synthetic_geoid):
    """`aerotri export A --format colmap`, `aerotri import B --format colmap`: B's centres are A's (were 3.28x high:
    georef.txt's origin in feet under a compound CRS in metres); into an ellipsoidal feet project h = H + N, N in
    feet."""
    a, crs = _feet_project(adjusted_tiny, tmp_path / "a")
    out = tmp_path / "out"
    export_project(a, ["colmap"], out)
    eo = read_eo(Project.open(a).eo_path)
    b = fresh_project(a, tmp_path / "b")
    (b / "project.toml").write_text((b / "project.toml").read_text().replace('"EPSG:3855"', f"'{EGM2008_US_FT}'"))
    import_files(b, "colmap", [out / "colmap"])
    assert np.abs(read_eo(b / "imported" / "eo.txt").centre_m - eo.centre_m).max() < 1e-4
    ell = fresh_project(a, tmp_path / "ell")
    (ell / "project.toml").write_text((ell / "project.toml").read_text().replace('"EPSG:3855"', '"ellipsoidal"'))
    import_files(ell, "colmap", [out / "colmap"])
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(*eo.centre_m[:, :2].T)
    h = read_eo(ell / "imported" / "eo.txt").centre_m[:, 2]
    assert np.abs(h - (eo.centre_m[:, 2] + synthetic_geoid(lon, lat) / US_FT_M)).max() < 1e-3


def test_metashape_chunk_of_a_feet_project_is_placed_in_metres(adjusted_tiny, tmp_path, fresh_project,
                                                                synthetic_geoid):
    """Metashape's compound <reference> (trial-at2) of a feet project with EGM2008 heights: its vertical axis in US
    feet, the chunk's geocentric centres at h = H (feet, as metres) + N; imported back, the project's heights."""
    a, crs = _feet_project(adjusted_tiny, tmp_path / "a")
    out = tmp_path / "out"
    export_project(a, ["metashape"], out)
    chunk = ET.parse(out / "metashape" / "cameras.xml").getroot().find("chunk")
    ref = pyproj.CRS.from_wkt(chunk.find("reference").text)
    assert abs(ref.sub_crs_list[1].axis_info[0].unit_conversion_factor - US_FT_M) < 1e-12
    lon, lat, h = chunk_centres_geodetic(chunk)
    eo = read_eo(Project.open(a).eo_path)
    assert np.abs(h - (eo.centre_m[:, 2] * US_FT_M + synthetic_geoid(lon, lat))).max() < 1e-3
    back = fresh_project(a, tmp_path / "back")
    import_files(back, "metashape", [out / "metashape" / "cameras.xml"])
    assert np.abs(read_eo(back / "imported" / "eo.txt").centre_m - eo.centre_m).max() < 1e-4


@pytest.mark.parametrize("heights", ["EPSG:3855", EGM2008_US_FT])
def test_a_vertical_crs_in_either_unit_is_restated_and_a_bound_one_refused_naming_both_units(tmp_path, heights):
    """A plain VERTCRS is restated in the grid's unit either way; what PROJ cannot restate (a vertical CRS bound to a
    geoid grid, +geoidgrids) is refused naming both units, never read in the wrong one."""
    from aerotri.core.errors import CrsError
    from aerotri.geom.crs.definition import heights_in_unit, parse_heights

    v = parse_heights(heights)
    assert abs(heights_in_unit(v, US_FT_M).axis_info[0].unit_conversion_factor - US_FT_M) < 1e-12
    assert heights_in_unit(v, 1.0).axis_info[0].unit_conversion_factor == 1.0
    bound = pyproj.CRS("+proj=utm +zone=49 +datum=WGS84 +geoidgrids=egm96_15.gtx +vunits=m +type=crs").sub_crs_list[1]
    a = _project(tmp_path / "a", heights=bound.to_wkt().replace("'", ""))
    with pytest.raises(CrsError, match="heights in metre, the project CRS's unit is US survey foot"):
        project_crs_3d(a)
