"""The connectivity plot of a block and the track lengths of its report."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from shapely.geometry import box

from aerotri.match.report import plot_block, track_lengths


def test_connectivity_plot_x_labels_do_not_overlap(tmp_path, monkeypatch):
    """NGI's 2 x 2 block (frames 3.8 x 6.7 km, centres at x -57700..-55100 on Lo25): the x tick labels of full
    map coordinates ran into each other ("-59000-58000-57000") on the tall block's narrow axis."""
    import matplotlib.pyplot as plt

    centres = np.array([[-55094.5, -3727407.0, 5258.3], [-57710.4, -3727433.9, 5256.8],
                        [-57682.7, -3731579.6, 5229.2], [-55081.8, -3731564.4, 5243.5]])
    plan = SimpleNamespace(centre_m=centres, image_id=["a", "b", "c", "d"],
                           footprints=[box(x - 1900, y - 3350, x + 1900, y + 3350) for x, y, _ in centres])
    strength = SimpleNamespace(models=[SimpleNamespace(weak=False, i=0, j=1)])
    shown = []
    monkeypatch.setattr(plt, "close", lambda fig: shown.append(fig))
    plot_block(tmp_path / "c.png", plan, [(0, 1, 280), (2, 3, 200), (0, 3, 40), (1, 2, 120)], strength)
    assert (tmp_path / "c.png").stat().st_size > 0
    fig = shown[0]
    fig.canvas.draw()
    ax = fig.axes[0]
    r = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(r) for t in ax.get_xticklabels() if t.get_visible() and t.get_text()]
    assert len(boxes) >= 3
    for a, b in zip(boxes, boxes[1:]):
        assert b.x0 - a.x1 > 0.3 * a.height, (a, b)  # a gap of a third of the text height at least
    # the grey outlines are the pairing plan's, said so (Tuniu trial: compared with the report's draped footprints)
    assert "footprints as planned for pairing" in ax.get_title()
    plt.close(fig)


def test_track_lengths_count_the_tracks_of_each_length():
    """Tracks 0 and 1 seen in 3 frames, 2 and 4 in 2, 3 in 1 (measurement order does not matter)."""
    h = track_lengths(np.array([1, 0, 2, 0, 1, 3, 4, 0, 2, 1, 4]))
    assert h.rays.tolist() == [1, 2, 3] and h.tracks.tolist() == [1, 2, 2]
    empty = track_lengths(np.zeros(0, int))
    assert empty.rays.size == 0 and empty.tracks.size == 0


def test_a_block_without_positions_gets_a_pair_graph(tmp_path, monkeypatch):
    """Kite trial: a block without GNSS got no connectivity figure (match draws the footprints the GNSS plans), and a
    block that fell apart into 2 parts showed it nowhere. The frames on a circle in file order, a chord per pair, a
    colour per part: the two parts' dots differ in colour, each pair is a line."""
    import matplotlib.pyplot as plt

    from aerotri.match.report import plot_pair_graph

    ids = [f"IMG_{k:04d}" for k in range(8)]
    pairs = [(0, 1, 300), (1, 2, 250), (0, 2, 40), (3, 4, 500), (4, 5, 480), (5, 6, 100), (6, 7, 90), (3, 7, 20)]
    parts = [ids[:3], ids[3:]]
    shown = []
    monkeypatch.setattr(plt, "close", lambda fig: shown.append(fig))
    plot_pair_graph(tmp_path / "c.png", ids, pairs, parts)
    assert (tmp_path / "c.png").stat().st_size > 0
    ax = shown[0].axes[0]
    assert len(ax.get_lines()) == len(pairs) and "2 parts" in ax.get_title()
    colours = ax.collections[0].get_facecolors()
    assert (colours[0] == colours[2]).all() and not (colours[0] == colours[3]).all()
    assert [t.get_text() for t in ax.texts] == ids
    plt.close(shown[0])
