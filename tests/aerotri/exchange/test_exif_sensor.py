"""The EXIF camera's pixel size: FocalPlaneXResolution, else DJI's CalibratedFocalLength, else the sensor width of
the camera's make and model (aerotri/exchange/data/sensor_widths.csv), and only then the 35 mm equivalent
focal length (with a warning): checked on synthetic frames and on the real Brighton Beach, Tuniu and Coal Oil
Point frames against their cameras' published sensors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aerotri.exchange import import_files
from aerotri.exchange.exif import (
    DIAGONAL_35MM_MM,
    FROM_35MM,
    camera_from_metadata,
    pixel_size_mm,
    read_frame_metadata,
    sensor_table,
)
from aerotri.geom.camera import read_camera
from tests.aerotri.exchange.test_exif import _frame, _project

PHANTOM3 = {"EXIF_Make": "DJI", "EXIF_Model": "FC300S", "EXIF_FocalLength": "(3.61)",
            "EXIF_FocalLengthIn35mmFilm": "20", "EXIF_PixelXDimension": "4000", "EXIF_PixelYDimension": "2250"}
POSITION = dict(GpsLatitude="46.8426", GpsLongtitude="-91.9945", AbsoluteAltitude="+198.3")


def test_table_rows_are_read_and_cite_a_source():
    table = sensor_table()
    assert len(table.rows) >= 30
    assert all(0.5 < r.width_mm < 60.0 and r.source in ("opensfm", "format") for r in table.rows)
    p3 = table.width_of("DJI", "FC300S")
    assert (p3.width_mm, p3.source) == (6.16, "opensfm")
    assert table.width_of("NIKON CORPORATION", "NIKON D800").width_mm == 35.9  # make: its first word
    assert table.width_of("DJI", "NO-SUCH-CAMERA") is None


def test_sensor_width_before_the_35mm_equivalent(tmp_path):
    """A Phantom 3's 16:9 frame (4000 x 2250 of a 4:3 sensor, written at 1/50 size): the pixel size is the
    sensor width over the frame's long side, 6.16 mm / 4000 px, not the 35 mm equivalent's diagonal (7 % off:
    the diagonal of the 16:9 crop is not the sensor's)."""
    m = read_frame_metadata(_frame(tmp_path / "p3.tif", PHANTOM3, POSITION, size=(80, 45)))
    pix, source = pixel_size_mm(m, 4000, 2250)
    assert pix == pytest.approx(6.16 / 4000) and "sensor width 6.16 mm" in source
    cam, notes = camera_from_metadata(m)
    assert cam.focal_px == pytest.approx(3.61 / (6.16 / 4000) / 50, rel=1e-9)  # 2344 px at full size
    assert not any("35 mm equivalent" in n for n in notes)
    diag = DIAGONAL_35MM_MM * 3.61 / 20 / math.hypot(4000, 2250)
    assert 3.61 / diag == pytest.approx(2121.5, abs=0.5)  # what the 35 mm equivalent gives: 9.5 % short


def test_focal_plane_resolution_comes_first_and_the_35mm_equivalent_last(tmp_path):
    # FocalPlaneXResolution (pixels per cm here) wins over the table
    tags = dict(PHANTOM3, EXIF_FocalPlaneXResolution="(6000)", EXIF_FocalPlaneResolutionUnit="3")
    m = read_frame_metadata(_frame(tmp_path / "fp.tif", tags, POSITION, size=(80, 45)))
    assert pixel_size_mm(m, 4000, 2250) == (pytest.approx(10.0 / 6000), "EXIF focal plane resolution")
    # a camera the table does not know: the 35 mm equivalent, and a warning that says so
    tags = dict(PHANTOM3, EXIF_Model="UNKNOWN-CAM")
    m = read_frame_metadata(_frame(tmp_path / "u.tif", tags, POSITION, size=(80, 45)))
    pix, source = pixel_size_mm(m, 4000, 2250)
    assert source == FROM_35MM and pix == pytest.approx(DIAGONAL_35MM_MM * 3.61 / 20 / math.hypot(4000, 2250))
    _, notes = camera_from_metadata(m)
    assert any("35 mm equivalent" in n and "not in the sensor table" in n for n in notes)


@pytest.mark.realdata
def test_real_frames_take_their_published_sensor(shared_data, tmp_path):
    """Brighton Beach (Phantom 3, 1/2.3" sensor, 6.17 mm wide by its format): about 2340 px, where the 35 mm
    equivalent gave 2121 px; Tuniu (Phantom 4 RTK) keeps DJI's CalibratedFocalLength (8.8 mm / 3666.67 px =
    2.40 um, the 1" sensor's 13.2 mm / 5472 px = 2.41 um); the Coal Oil Point Canon keeps its EXIF focal plane
    resolution (22.3 mm over 4272 px, the APS-C sensor's 22.2 mm)."""
    root = _project(tmp_path, "EPSG:32615", "bb")
    import_files(root, "exif", [shared_data / "brighton_beach" / "images" / "DJI_0018.JPG"])
    cam = read_camera(root / "camera.toml")
    assert cam.focal_px == pytest.approx(3.61 / (6.17 / 4000), rel=0.003)  # 2340 px by the format's 6.17 mm
    tuniu = read_frame_metadata(sorted((shared_data / "tuniu_drone" / "images").glob("*.tif"))[0])
    pix, source = pixel_size_mm(tuniu, *tuniu.full_size)
    assert "CalibratedFocalLength" in source and pix == pytest.approx(13.2 / 5472, rel=0.01)
    kite = read_frame_metadata(sorted((shared_data / "copr_kite" / "images").glob("*.jpg"))[0])
    pix, source = pixel_size_mm(kite, *kite.full_size)
    assert source == "EXIF focal plane resolution" and 4272 * pix == pytest.approx(22.2, rel=0.01)
    assert np.isclose(sensor_table().width_of(kite.make, kite.model).width_mm, 22.2)


def test_focal_plane_resolution_in_micrometres_and_without_a_unit(tmp_path, caplog):
    """FocalPlaneResolutionUnit 5 is micrometres (TIFF/EP): 0.65 px per um is the 1.54 um pixel. Unit 1 ("no
    absolute unit") gives no pixel size: the sensor table is taken, with a warning. Both were read as inches
    (the pixel 25,400x too large; with 4000 per nothing, 6.35 um for the Phantom's 1.54 um)."""
    tags = dict(PHANTOM3, EXIF_FocalPlaneXResolution="(0.65)", EXIF_FocalPlaneResolutionUnit="5")
    m = read_frame_metadata(_frame(tmp_path / "um.tif", tags, POSITION, size=(80, 45)))
    assert pixel_size_mm(m, 4000, 2250) == (pytest.approx(1 / 650), "EXIF focal plane resolution")
    tags = dict(PHANTOM3, EXIF_FocalPlaneXResolution="(4000)", EXIF_FocalPlaneResolutionUnit="1")
    m = read_frame_metadata(_frame(tmp_path / "none.tif", tags, POSITION, size=(80, 45)))
    pix, source = pixel_size_mm(m, 4000, 2250)
    assert pix == pytest.approx(6.16 / 4000) and "sensor width 6.16 mm" in source
    assert "FocalPlaneResolutionUnit 1 is not a length" in caplog.text
