"""``cast_to_dtype``: the one cast of resampled values back to a raster's type (grid warps of
``warp_array`` and ``aerotri crs warp`` alike)."""

import numpy as np

from aerotri.geom.crs.raster_warp import cast_to_dtype


def test_integers_round_half_to_even_and_clip():
    a = np.array([-3.5, -0.5, 0.4, 0.5, 1.5, 254.5, 255.6, 300.0, 1e9], dtype=np.float32)
    np.testing.assert_array_equal(cast_to_dtype(a, np.uint8), np.array([0, 0, 0, 0, 2, 254, 255, 255, 255], np.uint8))
    np.testing.assert_array_equal(cast_to_dtype(a, "int16"),
                                  np.array([-4, 0, 0, 0, 2, 254, 256, 300, 32767], np.int16))
    assert cast_to_dtype(a, np.uint16).dtype == np.uint16


def test_floats_keep_their_values():
    a = np.array([[-3.25, 1e-7, 123456.789]], dtype=np.float64)
    out = cast_to_dtype(a, np.float32)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, a.astype(np.float32))
    same = np.array([1.5, -2.5], dtype=np.float32)
    assert cast_to_dtype(same, np.float32) is same  # already the raster's type: no copy
