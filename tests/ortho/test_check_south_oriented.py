"""The DOM check of a DOM in a south-oriented grid (trial-ortho 2026-12-01): South Africa's Lo grids (EPSG:2046-2055)
count westing and southing. The NGI mosaic in Lo25 (EPSG:2051) against a reference placed 12 m east and 6 m north of
it read "mean +12.0 m east, +6.0 m north" (the same mosaic in the project's Lo25 of east/north axes: -12.0, -6.0);
an operator moving the DOM by it would double the error. Now east and north whatever the grid's axes."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS

from ortho.check import check_points, measure_roof_patches, run_check
from ortho.synthetic import textured_orthophoto, write_geotiff

SHIFT_PX = 3  # the DOM shows the reference's content 3 cells further right (higher column) in the image


def _pair(tmp_path, crs, x_left, y_top):
    ref = textured_orthophoto(240, 240, 1, seed=5)[:, :, 0]
    dom = np.concatenate([np.repeat(ref[:, :1], SHIFT_PX, axis=1), ref[:, :-SHIFT_PX]], axis=1)
    write_geotiff(tmp_path / "ref.tif", ref, x_left, y_top, 1.0, crs)
    write_geotiff(tmp_path / "dom.tif", dom, x_left, y_top, 1.0, crs)
    (tmp_path / "proj").mkdir(exist_ok=True)


# x grows with the column in both; in UTM 35S that is east, in Lo25 west (westing)
@pytest.mark.parametrize("epsg, x_left, y_top, east", [(32735, 300000.0, 6300000.0, 1.0),
                                                        (2051, 53130.0, 3735156.0, -1.0)])
def test_displacements_are_east_and_north_in_a_south_oriented_grid(tmp_path, epsg, x_left, y_top, east):
    crs = CRS.from_epsg(epsg)
    _pair(tmp_path, crs, x_left, y_top)
    rep = run_check(tmp_path / "proj", reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "dom.tif",
                    out_stem=tmp_path / "dom_report")
    assert rep.displacement.count >= 9
    assert rep.displacement.mean_e_m == pytest.approx(east * SHIFT_PX, abs=0.05)
    assert rep.displacement.mean_n_m == pytest.approx(0.0, abs=0.05)
    roofs = measure_roof_patches(tmp_path / "dom.tif", tmp_path / "ref.tif", [x_left + 120.0], [y_top - 120.0])
    assert roofs.de_m[0] == pytest.approx(east * SHIFT_PX, abs=0.1) and abs(roofs.dn_m[0]) < 0.1
    # a point surveyed at (x, y) and measured in the DOM 2 units further along x and 1 further along y
    (tmp_path / "points.csv").write_text(f"id,x,y,x_dom,y_dom\nP1,{x_left + 50},{y_top - 50},{x_left + 52},"
                                         f"{y_top - 49}\n")
    stats, table = check_points(tmp_path / "points.csv", 1.0, None, 1.0, crs)
    north = 1.0 if epsg == 32735 else -1.0
    assert table["points"][0]["de_m"] == pytest.approx(2.0 * east) and table["points"][0]["dn_m"] == pytest.approx(north)


@pytest.mark.parametrize("crs, signs", [("EPSG:3413", (1.0, 1.0)), ("EPSG:5041", (1.0, 1.0)), ("EPSG:3031", (1.0, 1.0)),
                                        (CRS.from_epsg(3413).to_wkt("WKT1_GDAL"), (1.0, 1.0)),  # as a GeoTIFF gives it
                                        ("EPSG:2051", (-1.0, -1.0)),
                                        (CRS.from_epsg(2051).to_wkt("WKT1_ESRI"), (-1.0, -1.0)),
                                        ("+proj=tmerc +lon_0=25 +ellps=WGS84 +axis=wsu +units=m", (-1.0, -1.0)),
                                        # a BoundCRS (reviewer 14: (1, 1) from the bound CRS's JSON)
                                        ("+proj=tmerc +axis=wsu +towgs84=0,0,0", (-1.0, -1.0))])
def test_polar_grids_are_not_south_oriented(crs, signs):
    """PROJ labels a polar stereographic grid's axes "south along 45°E" (EPSG:3413, 5041): they still run right and
    up on the map (review 12c: 3413 read content 3 m south as n +3.02)."""
    from aerotri.geom.crs.definition import map_axis_signs

    assert map_axis_signs(CRS.from_user_input(crs)) == signs


def test_north_polar_dom_check_reads_south_as_south(tmp_path):
    ref = textured_orthophoto(240, 240, 1, seed=5)[:, :, 0]
    dom = np.concatenate([np.repeat(ref[:1], SHIFT_PX, axis=0), ref[:-SHIFT_PX]], axis=0)  # content 3 rows lower
    x_left, y_top, crs = -200000.0, -2500000.0, CRS.from_epsg(3413)
    write_geotiff(tmp_path / "ref.tif", ref, x_left, y_top, 1.0, crs)
    write_geotiff(tmp_path / "dom.tif", dom, x_left, y_top, 1.0, crs)
    (tmp_path / "proj").mkdir()
    rep = run_check(tmp_path / "proj", reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "dom.tif",
                    out_stem=tmp_path / "dom_report")
    assert rep.displacement.mean_n_m == pytest.approx(-SHIFT_PX, abs=0.05)
    assert rep.displacement.mean_e_m == pytest.approx(0.0, abs=0.05)


@pytest.mark.parametrize("epsg, x_left, y_top, flips", [(32735, 300000.0, 6300000.0, (False, False)),
                                                         (2051, 53130.0, 3735156.0, (True, True))])
def test_the_plot_of_a_south_oriented_dom_is_drawn_north_up(tmp_path, monkeypatch, epsg, x_left, y_top, flips):
    """dom_report.png drew a Lo25 DOM's patches by row and column as stored: south-up (new-user trial, NGI). Its rows
    run up and its columns left now (north up, east right), the axes labelled so."""
    import ortho.check as check

    axes = {}
    save = check.save_png

    def keep(fig, path, **kwargs):
        ax = fig.axes[0]
        axes.update(rows_down=ax.yaxis_inverted(), cols_left=ax.xaxis_inverted(), y=ax.get_ylabel(), x=ax.get_xlabel())
        return save(fig, path, **kwargs)

    monkeypatch.setattr(check, "save_png", keep)
    _pair(tmp_path, CRS.from_epsg(epsg), x_left, y_top)
    run_check(tmp_path / "proj", reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "dom.tif",
              out_stem=tmp_path / "dom_report")
    assert (axes["rows_down"], axes["cols_left"]) == (not flips[0], flips[1])
    assert ("north up" in axes["y"]) == flips[0] and ("north up" in axes["x"]) == flips[1]
    assert (tmp_path / "dom_report.png").stat().st_size > 0
