"""Seamlines on a seam grid of two overlapping frames, against the geometry they must follow."""

from __future__ import annotations

import numpy as np
from affine import Affine

from ortho.seamlines import (keep_objects_whole, label_polygons, least_cost_seams, neighbour_pairs, seam_lines,
                             voronoi_labels)

H, W = 30, 40
# frame 0 covers columns 0-27, frame 1 columns 13-39; overlap 13-27
VALID = [np.ones((H, 28), bool), np.ones((H, 27), bool)]
OFFSETS = [(0, 0), (0, 13)]
NADIR_RC = np.array([[15.0, 10.25], [15.0, 30.25]])  # the Voronoi seam between columns 20 and 21


def _voronoi():
    return voronoi_labels(VALID, OFFSETS, NADIR_RC, (H, W))


def test_voronoi_cells_go_to_the_nearest_nadir():
    labels = _voronoi()
    assert (labels[:, :21] == 0).all() and (labels[:, 21:] == 1).all()
    assert neighbour_pairs(labels) == [(0, 1)]


def test_cells_no_frame_sees_are_unlabelled():
    valid = [np.ones((H, 10), bool), np.ones((H, 10), bool)]
    labels = voronoi_labels(valid, [(0, 0), (0, 30)], NADIR_RC, (H, W))
    assert (labels[:, 10:30] == -1).all() and neighbour_pairs(labels) == []


def test_least_cost_seam_runs_round_a_building_within_the_overlap():
    obj = np.zeros((H, W), bool)
    obj[8:22, 17:25] = True  # a building astride the Voronoi seam
    labels = least_cost_seams(_voronoi(), VALID, OFFSETS, object_mask=obj)
    parts = set(np.unique(labels[obj]).tolist())
    assert len(parts) == 1  # the seam does not cut the building
    # every cell is still labelled by a frame that sees it; the seam stayed inside the overlap
    assert (labels >= 0).all()
    assert (labels[:, :13] == 0).all() and (labels[:, 28:] == 1).all()


def test_a_seam_takes_a_ground_route_however_long_and_crosses_an_object_only_where_none_exists():
    """Issue 42: "never through a building or tree crown where a ground route exists". A row of buildings across
    the overlap, open only at its far end: the detour round it (about 210 cells) costs more than crossing one
    object cell and its margin at the old finite object cost (150), yet the seam takes it; closed, the seam
    crosses the row once, through its fewest cells."""
    h, w = 40, 300
    valid = [np.ones((h, 260), bool), np.ones((h, 260), bool)]   # overlap: columns 40-259
    offsets = [(0, 0), (0, 40)]
    nadir = np.array([[20.0, 100.25], [20.0, 200.25]])           # the Voronoi seam between columns 150 and 151
    labels = voronoi_labels(valid, offsets, nadir, (h, w))
    for gap in (True, False):
        obj = np.zeros((h, w), bool)
        obj[20, 40:255 if gap else 260] = True
        out = least_cost_seams(labels, valid, offsets, object_mask=obj)
        assert (out[:, :40] == 0).all() and (out[:, 260:] == 1).all()
        # a seam cell: labels differ from the right or the lower neighbour
        seam = np.zeros((h, w), bool)
        seam[:, :-1] |= out[:, :-1] != out[:, 1:]
        seam[:-1, :] |= out[:-1, :] != out[1:, :]
        if gap:
            assert not (seam & obj).any()
            assert len(np.unique(out[obj])) == 1
        else:
            assert 1 <= np.count_nonzero(seam & obj) <= 2   # one crossing of the one-cell row


def test_keep_objects_whole_gives_a_split_object_to_a_frame_that_sees_all_of_it():
    labels = _voronoi()
    obj = np.zeros((H, W), bool)
    obj[10:14, 18:23] = True  # split by column 20; both frames see all of it
    out = keep_objects_whole(labels, obj, VALID, OFFSETS)
    assert len(np.unique(out[obj])) == 1
    assert len(np.unique(labels[obj])) == 2  # the input labels are untouched
    wide = np.zeros((H, W), bool)
    wide[10:14, 5:35] = True  # no frame sees all of it: stays split
    assert len(np.unique(keep_objects_whole(labels, wide, VALID, OFFSETS)[wide])) == 2


def test_an_object_the_block_edge_cuts_goes_whole_to_a_frame_that_covers_the_rest():
    """An object whose southern part no frame covers (the block ends across it): both frames cover all of it there
    is in the mosaic, so it is not left split by the seam (issue 42: on the demo and the tall block every seam
    left on a roof was such a building at the block's edge)."""
    valid = [np.ones((25, 28), bool), np.ones((25, 27), bool)]      # rows 25-29: no frame
    labels = voronoi_labels(valid, OFFSETS, NADIR_RC, (H, W))
    assert (labels[25:] == -1).all()
    obj = np.zeros((H, W), bool)
    obj[18:30, 17:24] = True                                          # across the seam and the block's edge
    assert len(np.unique(labels[obj & (labels >= 0)])) == 2
    out = keep_objects_whole(labels, obj, valid, OFFSETS)
    assert len(np.unique(out[obj & (out >= 0)])) == 1
    assert (out[25:] == -1).all()                                     # cells no frame covers stay unlabelled


def test_an_object_no_frame_covers_with_a_margin_goes_whole_to_a_frame_that_covers_it():
    """A building in a corner of the overlap: frame 0 ends at its east wall, frame 1 at its west wall, so neither
    covers it with the cell of margin the seam keeps from a wall; it goes whole to one that covers it, the seam along
    its wall (issue 42: the tall block's conventional DOM crossed such a roof at the block's edge)."""
    valid = [np.ones((H, 23), bool), np.ones((H, 27), bool)]         # frame 0: columns 0-22, frame 1: 13-39
    labels = voronoi_labels(valid, OFFSETS, NADIR_RC, (H, W))
    obj = np.zeros((H, W), bool)
    obj[10:14, 13:23] = True                                           # columns 13-22, across the seam at 20 | 21
    assert len(np.unique(labels[obj])) == 2
    out = keep_objects_whole(labels, obj, valid, OFFSETS)
    assert np.unique(out[obj]).tolist() == [0]                         # frame 0 held most of it
    assert (out[~obj] == labels[~obj]).all()                           # nothing round it moved: the seam at its wall
    assert (out[10:14, 23] == 1).all()
    # an object whole in one frame, most of its margin in the other: left as it is (not moved into the other frame)
    row = np.zeros((H, W), bool)
    row[10, 13:23] = True
    whole = labels.copy()
    whole[9:12, 12:24] = 0
    whole[row] = 1
    assert (keep_objects_whole(whole, row, valid, OFFSETS) == whole).all()


def test_polygons_and_seam_lines_in_map_units():
    labels = _voronoi()
    transform = Affine(2.0, 0.0, 1000.0, 0.0, -2.0, 5000.0)  # 2 m seam cells
    polys = label_polygons(labels, transform, ["a", "b"])
    area = {f["properties"]["image_id"]: f["properties"]["area_m2"] for f in polys}
    assert area == {"a": 21 * H * 4.0, "b": 19 * H * 4.0}
    seams = seam_lines(labels, transform, ["a", "b"])
    assert len(seams) == 1 and seams[0]["properties"]["image_a"] == "a"
    assert abs(seams[0]["properties"]["length_m"] - H * 2.0) < 1e-9
    xs = {round(x, 6) for x, _ in seams[0]["geometry"]["coordinates"]}
    assert xs == {1000.0 + 21 * 2.0}


def test_seam_samples_are_the_cells_of_i_beside_j_for_every_touching_pair():
    from ortho.mosaic import seam_samples

    rng = np.random.default_rng(3)
    # blobs of five frames and unlabelled cells, so that pairs touch along ragged seams
    labels = np.repeat(np.repeat(rng.integers(-1, 5, size=(9, 11)), 3, axis=0), 4, axis=1)
    got = {pair: cells for pair, cells in seam_samples(labels, spacing_cells=3)}
    assert sorted(got) == neighbour_pairs(labels)
    for i, j in neighbour_pairs(labels):
        a, b = labels == i, labels == j
        beside_b = np.zeros_like(a)
        beside_b[:, :-1] |= b[:, 1:]
        beside_b[:, 1:] |= b[:, :-1]
        beside_b[:-1, :] |= b[1:, :]
        beside_b[1:, :] |= b[:-1, :]
        np.testing.assert_array_equal(got[(i, j)], np.argwhere(a & beside_b)[::3])
