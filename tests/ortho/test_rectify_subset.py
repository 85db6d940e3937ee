"""`ortho rectify --frames` after a whole block (trial-ortho 2026-12-01): re-rectifying one NGI frame at another pixel
size removed the 3 other frame orthos with no word above the info level, and the line said "rectified 4 frames" of a
subset that kept 3 earlier frames. Now the removal is a warning and the line counts the frames given and kept."""

from __future__ import annotations

import logging

import pytest
from click.testing import CliRunner

from ortho.block import rectify_block
from ortho.cli import main
from tests.shared_builds import write_synthetic_project


@pytest.fixture
def warnings_of_ortho():
    messages: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record):
            messages.append(record.getMessage())

    handler = Collect(logging.WARNING)
    logging.getLogger("ortho").addHandler(handler)  # the CLIs' logging set-up may stop propagation
    yield messages
    logging.getLogger("ortho").removeHandler(handler)


def test_a_subset_on_another_grid_warns_that_the_other_frames_go(tmp_path, warnings_of_ortho):
    root = tmp_path / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=2, seed=3)
    gsd = rectify_block(root).res_m
    assert len(list((root / "ortho" / "frames").glob("*.tif"))) == 2

    out = CliRunner().invoke(main, ["rectify", str(root), "--frames", "s01_002"])
    assert out.exit_code == 0, out.output
    assert "rectified 1 frame (1 earlier kept) at" in out.output
    assert not any("removed" in m for m in warnings_of_ortho)

    out = CliRunner().invoke(main, ["rectify", str(root), "--frames", "s01_002", "--res-m", f"{1.5 * gsd:.4f}"])
    assert out.exit_code == 0, out.output
    assert "rectified 1 frame at" in out.output
    assert sorted(p.stem for p in (root / "ortho" / "frames").glob("*.tif")) == ["s01_002"]
    assert any("the 1 other frame ortho of the earlier run" in m and "removed" in m for m in warnings_of_ortho), \
        warnings_of_ortho


def test_an_output_grid_far_from_its_central_meridian_is_warned_of(tmp_path, warnings_of_ortho):
    """trial-ortho: the demo (lon 110.5 E) rectified into CGCS2000 GK CM 123E (EPSG:4550, a neighbouring province's
    zone) without a word: scale factor 1.0178, a 0.5 m pixel 0.491 m on the ground. Its own zone (CM 111E) is not."""
    from ortho.settings import RectifySettings

    root = tmp_path / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=2, seed=3)
    rectify_block(root, RectifySettings(crs="gk3:cgcs2000"), frames=["s01_001"], allow_ballpark=True)
    assert not any("scale factor" in m for m in warnings_of_ortho), warnings_of_ortho
    rectify_block(root, RectifySettings(crs="EPSG:4550"), frames=["s01_001"], allow_ballpark=True)
    assert any("EPSG:4550" in m and "scale factor of 1.01" in m and "EPSG:32649" in m for m in warnings_of_ortho), \
        warnings_of_ortho


def test_a_project_in_web_mercator_is_warned_when_its_orthos_are_made(tmp_path, warnings_of_ortho):
    """new-user trial of 2026-12-04: Brighton Beach with `aerotri init --crs EPSG:3857` was told once, at `aerotri
    import`, that its metres are no ground metres, then `aerotri run` made its orthos at 0.02 of them (1.4 cm) without
    a word. The project's own CRS is now checked where the pixel size is chosen, as another output CRS was."""
    from ortho.settings import RectifySettings

    root = tmp_path / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=2, seed=3, crs="EPSG:3857")
    rectify_block(root, RectifySettings(), frames=["s01_001"])
    said = [m for m in warnings_of_ortho if "scale factor" in m]
    assert len(said) == 1 and "EPSG:3857" in said[0] and "not a mapping grid for measured products" in said[0], said


@pytest.mark.parametrize("lon, lat, out, says", [
    (110.5, 30.5, "EPSG:3857", "not a mapping grid for measured products"),  # k 1.16
    (8.5, 55.0, "EPSG:3857", "not a mapping grid for measured products"),  # k 1.74
    (-94.0, 40.0, "EPSG:26917", "family of grids is EPSG:26915 (NAD83 / UTM zone 15N)"),
    (110.5, 30.5, "EPSG:4550", "family of grids is EPSG:4546 (CGCS2000 / 3-degree Gauss-Kruger CM 111E)")])
def test_the_wrong_zone_advice_fits_the_grid_and_the_block(lon, lat, out, says, caplog):
    """review 12c: the advice "is it the contract's zone? ... --crs gk3:cgcs2000" was given for Web Mercator and for
    blocks outside China; now Web Mercator is said to be no mapping grid, and the zone of the block's longitude in
    the same family is named (gk3:cgcs2000 only for a CGCS2000 grid over China)."""
    import logging

    from pyproj import CRS

    from ortho.block import _warn_output_scale

    with caplog.at_level(logging.WARNING, logger="ortho.block"):
        _warn_output_scale(CRS.from_epsg(4326), CRS.from_user_input(out), (lon, lat), 0.5)
    (msg,) = [r.getMessage() for r in caplog.records if "scale factor" in r.getMessage()]
    assert says in msg
    assert ("gk3:cgcs2000" in msg) == (out == "EPSG:4550")


@pytest.mark.parametrize("lon, lat, out, warned", [
    (8.5, 50.0, "EPSG:32633", True),    # one UTM zone off at 50 N: k 1.0019, 2 degrees outside zone 33N
    (14.9, 60.0, "EPSG:32632", True),   # one zone off at 60 N: k 1.0010, 2.9 degrees outside
    (12.3, 50.0, "EPSG:32633", False),  # in the zone, 0.3 degrees from its western edge
    (11.6, 50.0, "EPSG:32633", False),  # a block straddling the zone edge: 0.4 degrees outside
    (3.0, 46.5, "EPSG:2154", False),    # Lambert-93 over France
    (-179.5, 10.0, "EPSG:32660", False)])  # zone 60 across the antimeridian (0.5 degrees outside)
def test_a_block_outside_the_grids_area_of_use_is_warned_whatever_its_scale(lon, lat, out, warned, caplog):
    """Review 16: a UTM zone chosen one off was never warned (k 1.0010-1.0051 inside the 1 % limit); PROJ's area of
    use tells it, by more than a degree."""
    import logging

    from pyproj import CRS

    from ortho.block import _warn_output_scale

    with caplog.at_level(logging.WARNING, logger="ortho.block"):
        _warn_output_scale(CRS.from_epsg(4326), CRS.from_user_input(out), (lon, lat), 0.5)
    msgs = [r.getMessage() for r in caplog.records if "scale factor" in r.getMessage()]
    assert bool(msgs) == warned, msgs
    if warned:
        assert "outside its area of use" in msgs[0] and "family of grids is" in msgs[0]
