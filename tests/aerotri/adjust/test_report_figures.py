"""The adjustment report's HTML: tables instead of text dumps, every figure with its scale key, and the
per-frame numbers the figures draw (von Gruber counts, residual grids, GNSS offsets) against the adjustment."""

from __future__ import annotations

import re

import numpy as np
import pytest
from matplotlib.quiver import QuiverKey
from matplotlib.offsetbox import AnchoredOffsetbox

from aerotri.adjust import report
from aerotri.adjust import report_figures as RF
from aerotri.adjust.flight_acceptance import Terrain
from aerotri.adjust.pipeline import AdjustSettings, adjust_project, write_outputs
from aerotri.core.records import to_record
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

GROUND_M = 150.0  # the geometric block's terrain: local height 0 (+- relief) at origin height 150 m


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    block = geometric_block(2, 5, seed=11)
    root = write_block_project(block, tmp_path_factory.mktemp("figs") / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=6, seed=5)
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3))
    return root, ba, to_record(report.build_report(ba, ground=Terrain(GROUND_M)))


def _artists(fig, kind):
    return [a for ax in fig.axes for a in ax.get_children() if isinstance(a, kind)]


def test_every_figure_has_its_scale_key(adjusted):
    _, ba, rep = adjusted
    figs = {f.title: f for f in report.report_figures(rep, ba)}
    assert {"Control and check-point residual vectors", "Image residuals per frame", "GNSS shift and drift per strip",
            "Von Gruber tie-point distribution", "Flight: footprints on the terrain", "Image residual histograms"} <= set(figs)
    ground = figs["Control and check-point residual vectors"]
    (qk,) = _artists(ground.fig, QuiverKey)
    plan = [np.hypot(*r["d_m"][:2]) for r in rep["check_points"]] + [
        np.hypot(*r["residual_m"][:2]) for r in rep["control_points"] if r["used"] and None not in r["residual_m"][:2]]
    assert qk.U == RF.nice_length(np.percentile(plan, 95)) and qk.text.get_text().endswith("m plan residual")
    (bar,) = [a for a in _artists(ground.fig, AnchoredOffsetbox) if hasattr(a, "scale_bar_label")]
    assert f"arrow = {qk.U:g} m" in ground.key and f"map scale bar {bar.scale_bar_label}" in ground.key
    assert "1e6" not in " ".join(t.get_text() for ax in ground.fig.axes for t in ax.get_xticklabels())
    frames = figs["Image residuals per frame"]
    (fk,) = _artists(frames.fig, QuiverKey)
    assert " um " in fk.text.get_text() and f"{fk.U:g} um" in frames.key
    assert _artists(figs["Von Gruber tie-point distribution"].fig, AnchoredOffsetbox)
    # the frames are drawn shrunk: the key and the title say by how much, so the bar is not read as their size
    vg = figs["Von Gruber tie-point distribution"]
    pct = re.search(r"frames at ([0-9.]+) % of their size", vg.key)
    assert pct and 0 < float(pct.group(1)) < 100, vg.key
    assert f"frames drawn at {pct.group(1)} % of their ground size" in vg.fig.axes[0].get_title()
    assert any("von Gruber" in ax.get_ylabel() for ax in figs["Von Gruber tie-point distribution"].fig.axes)  # colour bar
    assert _artists(figs["Flight: footprints on the terrain"].fig, AnchoredOffsetbox)
    assert all("(m)" in ax.get_ylabel() for ax in figs["GNSS shift and drift per strip"].fig.axes if ax.get_ylabel())
    for f in figs.values():
        assert f.key and f.caption


def test_html_has_tables_and_keys_not_text_dumps(adjusted):
    _, ba, rep = adjusted
    html = report.format_html(rep, ba)
    assert "<pre" not in html and html.count("<table>") >= 8
    imgs = re.findall(r"<img src='data:image/png;base64,[^']+' alt='([^']*)'>", html)
    assert len(imgs) == html.count("<img") >= 6 and all("Scale:" in alt for alt in imgs)
    assert html.count("<figcaption>") == len(imgs)
    for h in ("PhotoT Triangulation Options", "Parameters", "Key Statistics", "Flight acceptance", "Control and check points"):
        assert f">{h}</h" in html
    # the ISAT parameters row carries the numbers of report.json
    rms = rep["parameters"]["rms_check_m"]
    assert f"<td class='num'>{rms[0]:.4f}</td>" in html


def test_frame_numbers_agree_with_the_adjustment(adjusted):
    _, ba, rep = adjusted
    b, r = ba.block, ba.result
    tie = r.obs_active & ~np.isin(b.obs_point, b.control_point)
    v_um = r.residual_px * ba.camera_apriori.pixel_um
    for i, p in enumerate(rep["photos"]):
        k = tie & (b.obs_image == i)
        assert sum(p["von_gruber_tie_obs"]) == int(k.sum())
        top_left = k & (b.obs_xy_px[:, 0] < ba.camera_apriori.width / 3) & (b.obs_xy_px[:, 1] < ba.camera_apriori.height / 3)
        assert p["von_gruber_tie_obs"][0] == int(top_left.sum())
        g = p["residual_grid"]
        assert sum(g["n"]) == p["obs"]
        a = r.obs_active & (b.obs_image == i)
        c0 = a & (b.obs_xy_px[:, 0] < ba.camera_apriori.width / g["nx"]) & (b.obs_xy_px[:, 1] < ba.camera_apriori.height / g["ny"])
        if c0.sum():
            assert g["mean_vx_um"][0] == pytest.approx(v_um[c0, 0].mean(), abs=0.01)
    # GNSS: with shift correction, the correction is one vector per strip, and offset = correction - residual
    for s in {p["strip"] for p in rep["photos"]}:
        corr = np.array([p["gnss_correction_m"] for p in rep["photos"] if p["strip"] == s])
        assert np.allclose(corr, corr[0], atol=1e-4)
        assert np.allclose(corr[0], rep["gnss_strips"][s - 1]["shift_m"], atol=2e-4)
    # the offset: GNSS minus the adjusted antenna in the local frame's metres (as the correction); the residual is
    # in map axes and units (here metres: the same numbers but for the grid's rotation and scale)
    from aerotri.adjust.variance_components import adjusted_gnss

    local_residual = adjusted_gnss(b, ba.opts, r.state) - b.gnss_local
    for i, p in enumerate(rep["photos"]):
        assert np.allclose(p["gnss_offset_m"], np.subtract(p["gnss_correction_m"], local_residual[i]), atol=2e-4)
        assert np.allclose(p["gnss_offset_m"], np.subtract(p["gnss_correction_m"], p["gnss_residual_m"]), atol=0.01)


def test_flight_section_of_the_block(adjusted):
    """The geometric block flies 60 % forward / 30 % side overlap at 1000 m over terrain at +-60 m, tilts
    of 1 deg sigma: the report's overlaps are near the plan, tilts are those of the adjusted omega and phi."""
    _, ba, rep = adjusted
    fa = rep["flight_acceptance"]
    fwd = [f["forward_overlap_pct"] for f in fa["frames"] if f["forward_overlap_pct"] is not None]
    assert len(fwd) == 8 and abs(np.mean(fwd) - 60.0) < 3.0
    side = [s["side_overlap_median_pct"] for s in fa["strips"]]
    assert all(abs(v - 30.0) < 3.0 for v in side)
    opk = ba.eo_map.opk_deg
    tilt = np.degrees(np.arccos(np.cos(np.radians(opk[:, 0])) * np.cos(np.radians(opk[:, 1]))))
    assert [f["tilt_deg"] for f in fa["frames"]] == pytest.approx(tilt, abs=1e-3)


def test_consolidated_report_has_flight_rows_and_no_json_dumps(adjusted):
    from aerotri.qa.report import write_qa_report

    root, ba, _ = adjusted
    with open(root / "project.toml", "a") as f:
        f.write(f"\n[flight]\nmean_terrain_height_m = {GROUND_M}\n\n[qa]\npdf = true\n")
    write_outputs(ba, root)
    rep = write_qa_report(root)
    rows = [r for r in rep.checks if r.section == "Flight acceptance"]
    assert len(rows) == 7 and all(r.limit is not None for r in rows)
    worst = max(f["tilt_deg"] for f in rep.flight_acceptance["frames"])
    tilt = rep.check("flight_tilt_max_deg")
    assert tilt.quantity == "tilt of the camera axis" and tilt.value == pytest.approx(worst, abs=0.005)
    assert tilt.verdict == ("fail" if worst > 2.0 else "pass")  # 1 deg sigma tilts
    html = (root / "reports" / "index.html").read_text()
    assert "<pre" not in html and "Flight acceptance" in html
    alts = re.findall(r"alt='([^']*)'", html)
    assert len(alts) >= 5 and all("Scale:" in a for a in alts)
    pdf = (root / "reports" / "report.pdf").read_bytes()
    assert pdf.count(b"/Type /Page\n") + pdf.count(b"/Type /Page ") >= 1 + 2 + len(alts)


def test_pdf_flight_page_names_the_whole_flight_specification(adjusted, monkeypatch):
    """trial-quick: the PDF's flight page cut the specification's name at 80 characters ("... (manned aircraft),
    as tabulated )"); its title wraps to two lines instead, as the other pages' titles."""
    import matplotlib.figure

    from aerotri.qa.report import write_qa_report

    root, ba, _ = adjusted
    toml = (root / "project.toml").read_text()
    if "[flight]" not in toml:   # the test above may have added them (one fixture for the module)
        with open(root / "project.toml", "a") as f:
            f.write(f"\n[flight]\nmean_terrain_height_m = {GROUND_M}\n\n[qa]\npdf = true\n")
    write_outputs(ba, root)
    texts = []
    real_text = matplotlib.figure.Figure.text
    monkeypatch.setattr(matplotlib.figure.Figure, "text",
                        lambda self, x, y, s_, *a, **k: texts.append(s_) or real_text(self, x, y, s_, *a, **k))
    rep = write_qa_report(root)
    fa = rep.flight_acceptance
    spec = str(fa["spec"])
    assert len(spec) > 80
    (title,) = [t for t in texts if t.startswith("Flight acceptance (")]
    assert " ".join(title.split("\n")).endswith(f"limits: {spec})")
    assert max(len(line) for line in title.split("\n")) <= 95


def _frames_rep(names, nx=6, ny=4, seed=3):
    rng = np.random.default_rng(seed)
    return {"photos": [{"image_id": name, "rms_x_um": 3.0 + k, "rms_y_um": 2.5,
                        "residual_grid": {"nx": nx, "ny": ny, "n": [5] * (nx * ny),
                                          "mean_vx_um": rng.normal(0, 2, nx * ny).round(2).tolist(),
                                          "mean_vy_um": rng.normal(0, 2, nx * ny).round(2).tolist()}}
                       for k, name in enumerate(names)]}


@pytest.mark.parametrize("names, nx, ny", [
    ([f"3324c_2015_1004_0{5 + k // 4}_0{182 + k}_RGB" for k in range(8)], 6, 4),   # NGI's names, 8 frames
    ([f"3324c_2015_1004_05_0{182 + k}_RGB" for k in range(4)], 4, 6),              # portrait frames
    ([f"a_very_long_project_prefix_of_a_survey_flown_in_2026_strip_{k:02d}_frame_{k:04d}.tif" for k in range(13)],
     6, 4),
    (["IMG_0031.jpg"], 6, 4),
])
def test_frame_panel_titles_do_not_overlap(names, nx, ny):
    """Each panel's title (the frame's name, its RMS below) stays within its column and clear of the other
    panels and titles; a name too long for the column keeps its start and its end (NGI's 27-character names
    overlapped their neighbours)."""
    f = RF.image_residual_frames(_frames_rep(names, nx, ny), pixel_um=12.0)
    fig = f.fig
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert len(panels) == len(names)
    boxes = [ax.title.get_window_extent(r) for ax in panels]
    for i, (ax, box) in enumerate(zip(panels, boxes)):
        name, rms = ax.get_title().split("\n")
        assert rms.endswith(" um")
        if len(names[i]) <= 30:
            assert name == names[i]
        else:
            head, tail = name.split("...")
            assert names[i].startswith(head) and names[i].endswith(tail) and len(tail) >= 8
        for j, other in enumerate(boxes):
            if j != i:
                assert not box.overlaps(other), (ax.get_title(), panels[j].get_title())
        for other in panels:
            assert not box.overlaps(other.get_window_extent(r))
        fig_box = fig.bbox
        assert fig_box.x0 <= box.x0 and box.x1 <= fig_box.x1


def test_fit_text_keeps_the_most_characters_that_fit():
    """A shortened name fits and one character more (the next in the middle) would not; a name that fits stays."""
    from matplotlib.textpath import TextPath

    def width_in(t):
        return TextPath((0, 0), t, size=8).get_extents().width / 72.0

    assert RF.fit_text("IMG_0031.jpg", 2.3, 8) == "IMG_0031.jpg"
    for text, w in [("a_very_long_project_prefix_of_a_survey_flown_in_2026_strip_07_frame_0007.tif", 2.3),
                    ("3324c_2015_1004_05_0182_RGB", 0.8), ("WWWWWWWWWWiiiiiiiiii", 0.5)]:
        s = RF.fit_text(text, w, 8)
        head, tail = s.split("...")
        assert text.startswith(head) and text.endswith(tail) and width_in(s) <= w
        keep = len(head) + len(tail) + 1
        assert width_in(f"{text[:keep // 2]}...{text[len(text) - (keep - keep // 2):]}") > w


def test_ground_residual_legend_hides_no_point_name():
    """The legend sits outside the map: a control point in the map's upper left corner keeps its name in
    view (the kite block's gcp09 sat under the legend)."""
    ctrl = [{"id": f"gcp{k:02d}", "used": True, "given_m": [235000.0 + x, 3811000.0 + y, 0.0],
             "residual_m": [0.5, -0.3, None]}
            for k, (x, y) in enumerate([(0, 300), (10, 290), (150, 150), (300, 0), (300, 300), (20, 10)], start=4)]
    chk = [{"id": "chk1", "d_m": [0.2, 0.1, 0.05], "measured_m": [235100.0, 3811200.0, 0.0]}]
    fig = RF.ground_residual_map({"control_points": ctrl, "check_points": chk}).fig
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    (legend,) = fig.legends
    lb = legend.get_window_extent(r)
    ax = fig.axes[0]
    assert not lb.overlaps(ax.get_window_extent(r))
    names = [t for t in ax.texts if t.get_text().startswith("gcp")]
    assert len(names) == len(ctrl)
    for t in names:
        assert not lb.overlaps(t.get_window_extent(r))
    assert [t.get_text() for t in legend.get_texts()] == ["check points (1)", "control points (6)"]


def test_the_template_places_every_figure_once(adjusted, monkeypatch):
    """format_html hands every figure to the template, which alone decides where each goes: each appears once,
    in its section, and one without a section of its own (or whose section is absent) after the rest."""
    _, ba, rep = adjusted
    figs = report.report_figures(rep, ba)
    extra = RF.Figure("A figure without a section", "caption", "key", figs[0].fig)
    extra._png = figs[0].png()
    monkeypatch.setattr(report, "report_figures", lambda rep, ba=None: [*figs, extra])
    html = report.format_html(rep, ba)
    alts = re.findall(r"<img src='data:image/png;base64,[^']+' alt='([^.']*)\.", html)
    assert sorted(alts) == sorted(f.title for f in [*figs, extra])
    assert alts[-1] == extra.title and html.index("<h2>Flight acceptance</h2>") < html.index(
        "alt='Flight: footprints on the terrain")


def _colour_bars(fig):
    return [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]


def test_ground_residual_map_of_plan_only_control_has_no_height_colour_bar():
    """Plan-only control (no height observation) and no check point: no dZ colour bar (the kite block showed a
    +-0.01 m bar over nothing), the key says so; a check point with a height brings the bar back, the plan-only
    control points drawn grey (no colour of a height residual they do not have)."""
    ctrl = [{"id": f"gcp{k}", "used": True, "given_m": [235000.0 + 50 * k, 3811000.0 + 30 * k, 0.0],
             "residual_m": [0.02 * k, -0.01, None]} for k in range(5)]
    f = RF.ground_residual_map({"control_points": ctrl, "check_points": []})
    assert _colour_bars(f.fig) == []
    assert "plan-only control: no height residuals" in f.caption and "no height residuals" in f.key
    assert "dZ" not in f.key
    (pts,) = f.fig.axes[0].collections[:1]
    assert len(pts.get_offsets()) == 5
    chk = [{"id": "chk1", "d_m": [0.01, 0.02, -0.04], "measured_m": [235100.0, 3811050.0, 0.0]}]
    f = RF.ground_residual_map({"control_points": ctrl, "check_points": chk})
    (bar,) = _colour_bars(f.fig)
    assert "dZ" in bar.get_ylabel() and "-0.04 .. +0.04 m dZ" in f.key
    f.fig.canvas.draw()
    check_pts, ctrl_pts = f.fig.axes[0].collections[:2]
    assert np.allclose(ctrl_pts.get_facecolors()[:, :3], 0.8)  # grey: no height residual
    assert not np.allclose(check_pts.get_facecolors()[:, :3], 0.8)
    assert "beyond" not in f.key
    # a residual beyond the scale's 95th percentile is said, with the residuals' range (trial s100 rc F10)
    many = [{"id": f"c{k}", "d_m": [0.01, 0.02, 0.01 * (k % 5) - 0.02], "measured_m": [235000.0 + 9 * k, 3811000.0,
                                                                                         0.0]} for k in range(39)]
    many.append({"id": "far", "d_m": [0.01, 0.02, -1.37], "measured_m": [235500.0, 3811200.0, 0.0]})
    f = RF.ground_residual_map({"control_points": [], "check_points": many})
    assert "(the 95th percentile; 1 point beyond it, to -1.37 / +0.02 m, in its end colours)" in f.key, f.key


def test_ground_residual_map_names_the_largest_check_residuals_and_says_how_many():
    """The blue names are the largest plan residuals among the check points (a large control residual no longer
    takes one of the five places), and the caption says what is named: none without check points (the kite's
    map said "the five largest check residuals are named" over control points alone), all of few."""
    ctrl = [{"id": f"gcp{k}", "used": True, "given_m": [235000.0 + 50 * k, 3811000.0, 0.0],
             "residual_m": [1.0 + k, 0.0, 0.0]} for k in range(3)]  # larger than every check residual
    chk = [{"id": f"chk{k}", "d_m": [0.01 * k, 0.0, 0.0], "measured_m": [235000.0 + 20 * k, 3811100.0, 0.0]}
           for k in range(8)]

    def blue_names(f):
        return sorted(t.get_text() for t in f.fig.axes[0].texts if t.get_color() == "tab:blue")

    f = RF.ground_residual_map({"control_points": ctrl, "check_points": chk})
    assert blue_names(f) == ["chk3", "chk4", "chk5", "chk6", "chk7"]
    assert "the 5 largest check-point plan residuals named" in f.caption
    f = RF.ground_residual_map({"control_points": ctrl, "check_points": chk[5:]})
    assert blue_names(f) == ["chk5", "chk6", "chk7"] and "every check point named" in f.caption
    f = RF.ground_residual_map({"control_points": ctrl, "check_points": []})
    assert blue_names(f) == [] and "no check points" in f.caption and "largest" not in f.caption


def test_map_axes_of_a_block_west_of_the_false_origin_read_plus():
    """NGI's Lo25 coordinates are negative: the map figures' axes read 'easting - -60 000 (m)'; now '+ 60 000'."""
    ctrl = [{"id": f"gcp{k}", "used": True, "given_m": [-59000.0 + 500 * k, -3730000.0 + 300 * k, 400.0],
             "residual_m": [0.2 * k, -0.1, 0.05]} for k in range(5)]
    ax = RF.ground_residual_map({"control_points": ctrl, "check_points": []}).fig.axes[0]
    assert re.fullmatch(r"easting \+ \d[\d ]* \(m\)", ax.get_xlabel()), ax.get_xlabel()
    assert re.fullmatch(r"northing \+ 3 7\d\d \d{3} \(m\)", ax.get_ylabel()), ax.get_ylabel()
    ctrl = [{**c, "given_m": [235000.0 + 50 * k, 3811000.0 + 30 * k, 0.0]} for k, c in enumerate(ctrl)]
    ax = RF.ground_residual_map({"control_points": ctrl, "check_points": []}).fig.axes[0]
    assert ax.get_xlabel().startswith("easting - 23") and ax.get_ylabel().startswith("northing - 3 81")


def test_ground_residual_map_shows_every_arrow_and_keeps_the_scale_bar_off_the_points():
    """A simulated block's map cut chk04's arrow (3 x the 95th percentile) at the frame and hid gcp01 under the
    scale bar in the lower left: every arrow's tip is now inside the axes, and the bar takes a corner without
    points (the lower left while it is free)."""
    from matplotlib.offsetbox import AnchoredOffsetbox

    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 2000, (20, 2)) + [418000.0, 3378000.0]
    d = rng.normal(0, 0.02, (20, 3))
    d[7, :2] = [0.0, 0.3]  # the largest, pointing north from near the top
    xy[7] = [419000.0, 3380000.0]
    ctrl = [{"id": "gcp01", "used": True, "given_m": [418000.0, 3378000.0, 0.0], "residual_m": [0.01, 0.01, 0.0]}]
    chk = [{"id": f"chk{k}", "d_m": list(v), "measured_m": [*p, 0.0]} for k, (p, v) in enumerate(zip(xy, d))]
    f = RF.ground_residual_map({"control_points": ctrl, "check_points": chk})
    ax = f.fig.axes[0]
    q = next(c for c in ax.collections if hasattr(c, "U"))
    tips = q.get_offsets() + np.column_stack([q.U, q.V]) / q.scale
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert np.all((tips[:, 0] >= x0) & (tips[:, 0] <= x1) & (tips[:, 1] >= y0) & (tips[:, 1] <= y1))
    (bar,) = [a for a in ax.get_children() if isinstance(a, AnchoredOffsetbox)]
    assert bar.loc != AnchoredOffsetbox.codes["lower left"]  # gcp01 is there
    corner = {v: k for k, v in AnchoredOffsetbox.codes.items()}[bar.loc]
    assert RF.scale_bar_corner(ax, q.get_offsets()) == corner
    # points along the diagonal from the lower right to the upper left: the lower left is free, the bar stays there
    line = [{"id": f"c{k}", "d_m": [0.01, 0.01, 0.0], "measured_m": [418000.0 + 100 * k, 3380000.0 - 100 * k, 0.0]}
            for k in range(21)]
    f = RF.ground_residual_map({"control_points": [], "check_points": line})
    (bar,) = [a for a in f.fig.axes[0].get_children() if isinstance(a, AnchoredOffsetbox)]
    assert bar.loc == AnchoredOffsetbox.codes["lower left"]


def test_flight_map_keeps_the_footprints_off_the_frame_and_the_scale_bar():
    """The 2 x 2 DMC block's footprint map set its limits at the footprints' extremes: the outer footprints' edges ran
    along the frame and under the scale bar (trial 8); a margin now, more below for the bar."""
    from aerotri.adjust.report_figures import flight_map

    frames = []
    for k, (x, y) in enumerate(((452465.0, 3407775.0), (452770.0, 3407775.0), (452465.0, 3408740.0))):
        ring = [(x - 385, y - 700), (x + 385, y - 690), (x + 390, y + 690), (x - 380, y + 700)]
        frames.append(dict(image_id=f"f{k}", strip=1 + k // 2, footprint=ring, x_m=x, y_m=y))
    fig = flight_map(dict(frames=frames, strips=[], terrain="dem.tif"))
    ax = fig.fig.axes[0]
    xy = np.vstack([f["footprint"] for f in frames])
    ox, oy = np.floor(xy.min(axis=0) / 1000.0) * 1000.0
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    span = np.ptp(xy, axis=0).max()
    assert x0 <= xy[:, 0].min() - ox - 0.02 * span and x1 >= xy[:, 0].max() - ox + 0.02 * span
    assert y0 <= xy[:, 1].min() - oy - 0.05 * span and y1 >= xy[:, 1].max() - oy + 0.02 * span


def test_flight_map_labels_frames_by_what_their_ids_do_not_share():
    """NGI's footprint map printed four 27-character ids ("3324c_2015_1004_05_0182_RGB", ...) over each other (new-user
    trial s51): labelled without the prefix and suffix they share, which the caption names."""
    from aerotri.adjust.report_figures import flight_map, short_ids

    ids = ["3324c_2015_1004_05_0182_RGB", "3324c_2015_1004_05_0184_RGB", "3324c_2015_1004_06_0251_RGB",
           "3324c_2015_1004_06_0253_RGB"]
    frames = []
    for k, (x, y) in enumerate(((-60000.0, -3720000.0), (-59300.0, -3720000.0), (-60000.0, -3719000.0),
                                (-59300.0, -3719000.0))):
        ring = [(x - 500, y - 400), (x + 500, y - 400), (x + 500, y + 400), (x - 500, y + 400)]
        frames.append(dict(image_id=ids[k], strip=5 + k // 2, footprint=ring, x_m=x, y_m=y))
    fig = flight_map(dict(frames=frames, strips=[], terrain="dem.tif"))
    texts = sorted(t.get_text() for t in fig.fig.axes[0].texts)
    assert texts == ["05_0182", "05_0184", "06_0251", "06_0253"]
    assert "'3324c_2015_1004_' and '_RGB'" in fig.caption
    # ids that share no separated part, or would lose what tells them apart, are kept whole
    assert short_ids(["s01_001", "s01_002", "s02_001"]) == (["s01_001", "s01_002", "s02_001"], "", "")
    assert short_ids(["DJI_0001.JPG", "DJI_0002.JPG"]) == (["0001", "0002"], "DJI_", ".JPG")
    assert short_ids(["x_1", "x_1_b"])[0] == ["1", "1_b"] and short_ids(["ab_1", "ab_2"])[0] == ["1", "2"]


def test_surface_control_map_shows_points_on_the_surface_and_keeps_its_legend_off_them():
    """The 2 x 2 DMC block's surface-control map: 1,160 of its used points within a sigma of the DEM were near-white
    dots on white, invisible, and the legend covered the block's south end (trial 8); the used points have a grey
    edge now, the legend is below the map."""
    from types import SimpleNamespace

    import matplotlib

    from aerotri.core.figures import pyplot

    rng = np.random.default_rng(2)
    n = 400
    xy = np.column_stack([rng.uniform(452000, 453000, n), rng.uniform(3407000, 3409500, n)])
    e = rng.normal(0.0, 0.02, n)
    surface = SimpleNamespace(observe=lambda pts, jacobian=False: (e, None, np.full(n, 0.05)),
                              point_class=lambda m: (np.arange(m) % 3 == 0).astype(int))
    use = np.ones(n, int)
    use[::25] = 2
    ba = SimpleNamespace(result=SimpleNamespace(surface_use=use, state=SimpleNamespace(points=None)),
                         block=SimpleNamespace(surface=surface), points_map=np.column_stack([xy, np.zeros(n)]),
                         eo_map=SimpleNamespace(centre_m=xy[:4]))
    fig = report._surface_figure(ba, pyplot())
    ax = fig.axes[0]
    used = [c for c in ax.collections if isinstance(c, matplotlib.collections.PathCollection)]
    assert len(used) == 2
    for c in used:
        edge = c.get_edgecolors()
        assert len(edge) and (edge[:, 3] > 0).all() and (edge[:, :3] < 0.7).all()  # a visible dark edge
    fig.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    assert legend.y1 <= ax.get_window_extent().y0  # below the map, on none of the points


def test_the_von_gruber_map_keeps_the_frames_visible_where_two_centres_crowd():
    """Kite trial: a kite hovering put two of 22 centres 0.2 m apart, and every frame of the 40 m block was drawn at
    1.5 % of its size (invisible ninths, labels alone). Frames 10 m across, 8 m apart, two of them 0.2 m apart: the
    map draws them at 0.85 x the lower quartile of the nearest-centre distances (68 %), the title says so."""
    def ring(x, y, h=5.0, m=4):  # a square footprint, m samples a side, closed
        side = np.linspace(-h, h, m, endpoint=False)
        pts = ([(x + s, y + h) for s in side] + [(x + h, y + h - (s + h)) for s in side]
               + [(x - s, y - h) for s in side] + [(x - h, y - h + (s + h)) for s in side])
        return [list(p) for p in pts + [pts[0]]]

    centres = [(8.0 * i, 8.0 * j) for i in range(4) for j in range(3)] + [(0.2, 0.0)]
    frames = [{"image_id": f"f{k:02d}", "x_m": x, "y_m": y, "footprint": ring(x, y)} for k, (x, y) in enumerate(centres)]
    rep = {"photos": [{"image_id": f["image_id"], "von_gruber_tie_obs": [5] * 9} for f in frames],
           "flight_acceptance": {"frames": frames}}
    fig = RF.von_gruber_map(rep)
    assert fig is not None
    pct = re.search(r"frames at ([0-9.]+) % of their size", fig.key)
    assert pct and float(pct.group(1)) == pytest.approx(68, abs=1), fig.key


def test_the_gnss_figure_says_when_nothing_checks_the_positions():
    """s95: the NGI block's GNSS residuals of millimetres (redundancy 0.0 of 12) read like a 2 mm fit."""
    from aerotri.adjust.report_figures import gnss_strip_plot

    photos = [{"strip": 1, "along_km": 2.6 * k, "gnss_offset_m": [0.001, -0.002, 0.003]} for k in range(2)]
    rep = {"photos": photos, "options": {"gps_shift_drift_correction": "Disabled"},
           "variance_components": [{"group": "gnss", "observations": 12, "redundancy": 0.0}]}
    fig = gnss_strip_plot(rep)
    assert "The GNSS's redundancy is 0.0 of 12 observations: the images do not check" in fig.caption
    rep["variance_components"][0]["redundancy"] = 6.0
    assert "redundancy" not in gnss_strip_plot(rep).caption


def test_a_table_cell_that_rounds_to_zero_is_never_minus_zero():
    """report.html's cells printed a shift held at its a-priori zero as -0.0000 (Brighton Beach's flight offset), and
    any tiny negative the same; the text report writes 0 since trial s103 F1, the HTML's cells now too."""
    assert RF.cell(-0.0, 4) == "0.0000" and RF.cell(-4e-5, 4) == "0.0000" and RF.cell(-6e-5, 4) == "-0.0001"
    assert RF.cell(0.12345, 3) == f"{0.12345:.3f}" and RF.cell(-2.5, 1) == "-2.5" and RF.cell(float("nan")) == ""
    assert RF.cell(True) == "yes" and RF.cell(3) == "3" and RF.cell(None) == ""
