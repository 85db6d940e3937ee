"""Figures and HTML tables of the adjustment report, drawn from the report dict (``report.json``) alone, so
that the consolidated report (``aerotri report``) and its PDF draw the same ones from the file.

Every figure carries its scale key: vector plots a quiver key (an arrow of a round length in metres,
microns or pixels), maps a scale bar in metres and coordinates relative to a round origin named in the
axis label (no "1e6" offsets), colours a colour bar with units. ``Figure.key`` repeats the key in words
for the HTML ``alt`` text and caption.
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import math
import os

import numpy as np

from aerotri.adjust import gnss_model
from aerotri.core.figures import png_bytes, pyplot

MAX_FRAME_PANELS = 24  # image residual panels per figure (the frames with the largest RMS beyond that)
FRAME_PANEL_IN = 2.2  # width of a frame's panel (inches)


@dataclasses.dataclass
class Figure:
    """A report figure: title, caption, the scale key in words and the matplotlib figure."""

    title: str
    caption: str
    key: str
    fig: object

    def png(self, dpi: int = 110) -> bytes:
        """The figure as PNG (drawn once; the matplotlib figure is closed then)."""
        if getattr(self, "_png", None) is None:
            self._png = png_bytes(self.fig, dpi=dpi, tight=True)
        return self._png

    def png_base64(self, dpi: int = 110) -> str:
        """The PNG for an ``<img src="data:image/png;base64,...">`` (the templates' ``figure`` macro)."""
        return base64.b64encode(self.png(dpi)).decode()


def nice_length(x: float) -> float:
    """The 1-2-5 round number nearest below ``x`` (> 0)."""
    if not (x > 0 and math.isfinite(x)):
        return 1.0
    e = 10.0 ** math.floor(math.log10(x))
    return max(m for m in (1.0, 2.0, 5.0, 10.0) if m * e <= x * 1.0000001) * e


@functools.lru_cache(maxsize=4096)
def fit_text(text: str, width_in: float, fontsize: float) -> str:
    """``text``, or its start and end with "..." between, as much as is at most ``width_in`` inches wide in
    the default font at ``fontsize`` points (image names that share a long prefix differ at their ends). Cached:
    a process that writes several reports of one block names the same frames."""
    from matplotlib.textpath import TextPath

    def fits(t: str) -> bool:
        return TextPath((0, 0), t, size=fontsize).get_extents().width / 72.0 <= width_in

    def short(keep: int) -> str:
        return f"{text[:keep // 2]}...{text[len(text) - (keep - keep // 2):]}"

    if fits(text):
        return text
    # the most characters kept that fit, by bisection: one character fewer takes one glyph from the middle (the
    # first and the last stay), so the width falls with ``keep``; each exact extent costs about 40 ms (13 names of
    # 75 characters: 12.6 CPU-s one by one from the longest)
    lo, hi = 1, len(text)  # short(lo) fits (or lo = 1: none fits), short(hi) does not
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if fits(short(mid)):
            lo = mid
        else:
            hi = mid
    return short(lo) if lo >= 2 else text[:1] + "..."


def _fmt(x: float) -> str:
    return f"{x:g}"


def _origin(xy: np.ndarray) -> tuple[float, float]:
    """A round origin (whole km) below the coordinates, so axes read in metres from it."""
    return math.floor(_finite_min(xy[:, 0]) / 1000.0) * 1000.0, math.floor(_finite_min(xy[:, 1]) / 1000.0) * 1000.0


def _finite_min(a) -> float:
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(a.min()) if len(a) else 0.0


def _p95(a) -> float:
    """95th percentile of the finite values, 0 without any (no numpy All-NaN warning)."""
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(np.percentile(a, 95)) if len(a) else 0.0


def scale_bar(ax, length: float, label: str, thickness: float, loc: str = "lower left"):
    """A bar of ``length`` data units with its label, anchored at ``loc`` of ``ax`` (framed)."""
    from matplotlib.offsetbox import AnchoredOffsetbox, AuxTransformBox, TextArea, VPacker
    from matplotlib.patches import Rectangle

    bar = AuxTransformBox(ax.transData)
    bar.add_artist(Rectangle((0, 0), length, thickness, facecolor="black", edgecolor="black"))
    box = VPacker(children=[bar, TextArea(label)], align="center", pad=0, sep=3)
    sb = AnchoredOffsetbox(loc=loc, child=box, pad=0.4, borderpad=0.5, frameon=True)
    sb.scale_bar_label = label  # what the bar says, for checks
    return sb


def offset_label(axis: str, origin: float) -> str:
    """``easting - 235 000 (m)``; a negative origin (a CRS whose false easting leaves the block west of 0: NGI's
    Lo25) as ``easting + 60 000 (m)``, not ``easting - -60 000``."""
    sign = "-" if origin >= 0 else "+"
    return f"{axis} {sign} {abs(origin):,.0f} (m)".replace(",", " ")


SCALE_BAR_CORNERS = ("lower left", "lower right", "upper left", "upper right")
SCALE_BAR_BOX = (0.3, 0.15)  # the corner a scale bar covers, in axes fractions (width, height)


def scale_bar_corner(ax, points_xy=None) -> str:
    """The first corner of ``SCALE_BAR_CORNERS`` with the fewest of ``points_xy`` (data coordinates, e.g. the
    points and their arrows' tips) under the scale bar's box, so that the bar hides none that another corner
    would not: the lower left unless points are there (the test block's gcp01 sat under the bar)."""
    if points_xy is None or not len(points_xy):
        return SCALE_BAR_CORNERS[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    p = np.asarray(points_xy, float)
    fx, fy = (p[:, 0] - x0) / (x1 - x0), (p[:, 1] - y0) / (y1 - y0)
    w, h = SCALE_BAR_BOX
    count = [int(np.sum(((fx > 1 - w) if "right" in c else (fx < w)) & ((fy > 1 - h) if "upper" in c else (fy < h))))
             for c in SCALE_BAR_CORNERS]
    return SCALE_BAR_CORNERS[int(np.argmin(count))]


def _map_axes(ax, origin, extent_m: float, points_xy=None) -> str:
    """Axis labels relative to ``origin``, equal aspect, plain tick labels and a scale bar in the corner that
    covers the fewest of ``points_xy`` (``scale_bar_corner``); returns its text."""
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_xlabel(offset_label("easting", origin[0]))
    ax.set_ylabel(offset_label("northing", origin[1]))
    bar = nice_length(extent_m / 5.0)
    ax.add_artist(scale_bar(ax, bar, f"{_fmt(bar)} m", extent_m / 300.0, loc=scale_bar_corner(ax, points_xy)))
    ax.grid(True, color="0.9", lw=0.5)
    return f"{_fmt(bar)} m"


def _named_checks(named: int, checks: int) -> str:
    """The caption's words for the check points named on the map: none, all of them, or the largest few."""
    if named == 0:
        return "; no check points"
    if named == checks:
        return "; every check point named" if checks > 1 else "; the check point named"
    return f"; the {named} largest check-point plan residuals named"


def ground_residual_map(rep: dict) -> Figure | None:
    """Control (triangles) and check points (circles) with their plan residual vectors (arrows, scale key
    in metres) and the height residual as colour (colour bar in metres); points without a height residual
    (plan-only control) in grey, and no colour bar when no point has one."""
    ctrl = [r for r in rep.get("control_points", []) if r.get("used") and r.get("given_m") and r.get("residual_m")]
    chk = [r for r in rep.get("check_points", []) if r.get("d_m") and None not in r["d_m"][:2] and r.get("measured_m")]
    if not ctrl and not chk:
        return None
    plt = pyplot()
    pos = np.array([r["given_m"] for r in ctrl] + [r["measured_m"] for r in chk], dtype=float)
    d = np.array([[np.nan if v is None else v for v in r["residual_m"]] for r in ctrl]
                 + [[np.nan if v is None else v for v in r["d_m"]] for r in chk], dtype=float)
    is_ctrl = np.arange(len(pos)) < len(ctrl)
    o = _origin(pos)
    x, y = pos[:, 0] - o[0], pos[:, 1] - o[1]
    extent = max(np.ptp(x), np.ptp(y), 1.0)
    plan = np.hypot(d[:, 0], d[:, 1])
    p95 = _p95(plan) or 1e-3
    scale = p95 / (0.08 * extent)  # the 95th percentile residual draws 8 % of the block
    key_m = nice_length(p95)
    fig, ax = plt.subplots(figsize=(10, 8), layout="constrained")  # room for the legend below the map
    dz = d[:, 2]
    has_dz = bool(np.isfinite(dz).any())  # plan-only control and no check point: no height to colour by
    lim = max(_p95(np.abs(dz)), 0.01)
    cmap = plt.colormaps["RdBu_r"].with_extremes(bad="0.8")  # grey: a point without a height residual
    sc = None
    for m, marker, label, size in ((~is_ctrl, "o", f"check points ({int((~is_ctrl).sum())})", 22),
                                   (is_ctrl, "^", f"control points ({int(is_ctrl.sum())})", 70)):
        if m.any():
            sc = ax.scatter(x[m], y[m], c=dz[m], cmap=cmap, vmin=-lim, vmax=lim, marker=marker, s=size,
                            plotnonfinite=True, edgecolors="k", linewidths=0.4, label=label, zorder=3)
    q = ax.quiver(x, y, np.nan_to_num(d[:, 0]), np.nan_to_num(d[:, 1]), angles="xy", scale_units="xy", scale=scale,
                  width=0.0025, color=np.where(is_ctrl, "tab:red", "0.15").tolist(), zorder=4)
    # the arrows' tips inside the map too: a residual beyond the 95th percentile drew past the frame, cut off
    tips = np.column_stack([x + np.nan_to_num(d[:, 0]) / scale, y + np.nan_to_num(d[:, 1]) / scale])
    ax.update_datalim(tips)
    ax.margins(0.06)
    ax.autoscale_view()
    # the key arrow starts at its point and runs right: from the left edge it stays inside the figure (from 0.97 of
    # the width it reached the figure's edge on the kite block, its head at the border)
    ax.quiverkey(q, 0.02, 1.015, key_m, f"{_fmt(key_m)} m plan residual", labelpos="E", coordinates="axes")
    bar = _map_axes(ax, o, extent, np.vstack([np.column_stack([x, y]), tips]))
    # the scale is the 95th percentile of |dZ|: the points beyond it take its end colour, which the bar's arrows and
    # the caption say (trial s100 rc F10: -0.53 .. +0.53 m with residuals to -1.37 m, nothing said)
    beyond = int(np.count_nonzero(np.abs(dz[np.isfinite(dz)]) > lim)) if has_dz else 0
    if has_dz:
        fig.colorbar(sc, ax=ax, shrink=0.8, label="height residual dZ (m)", extend="both" if beyond else "neither")
    for r, xi, yi in zip(ctrl, x[is_ctrl], y[is_ctrl]):
        ax.annotate(str(r["id"]), (xi, yi), fontsize=7, xytext=(4, 4), textcoords="offset points")
    # the largest plan residuals among the check points (control points are all named above)
    check_idx = np.flatnonzero(~is_ctrl)
    worst = check_idx[np.argsort(-np.nan_to_num(plan[check_idx]), kind="stable")[:5]]
    ids = [str(r["id"]) for r in ctrl] + [str(r["id"]) for r in chk]
    for k in worst:
        ax.annotate(ids[k], (x[k], y[k]), fontsize=7, color="tab:blue", xytext=(4, -9), textcoords="offset points")
    fig.legend(loc="outside lower center", ncols=2, fontsize=8)  # outside: inside, it hid the points' names
    ax.set_title("Ground residuals: adjusted - given (control), adjusted - measured (check)", loc="left", pad=16,
                 fontsize=11)
    return Figure("Control and check-point residual vectors",
                  "Arrows: plan residual of each point (control red, check black"
                  + _named_checks(len(worst), len(chk)) + "); "
                  + ("marker colour: height residual (grey: none)." if has_dz else
                     "plan-only control: no height residuals."),
                  f"arrow = {_fmt(key_m)} m on the ground; map scale bar {bar}; "
                  + (f"colour -{lim:.2f} .. +{lim:.2f} m dZ" + (
                      f" (the 95th percentile; {beyond} point{'s' if beyond != 1 else ''} beyond it, to "
                      f"{np.nanmin(dz):+.2f} / {np.nanmax(dz):+.2f} m, in its end colours)" if beyond else "")
                     if has_dz else "no height residuals"),
                  fig)


def image_residual_frames(rep: dict, pixel_um: float | None = None) -> Figure | None:
    """Per frame: the mean image residual in each cell of the residual grid (arrows, one common scale with
    a key in microns), over the frame's outline; the systematic pattern a camera or GNSS error leaves."""
    photos = [p for p in rep.get("photos", []) if p.get("residual_grid")]
    if not photos:
        return None
    plt = pyplot()
    shown = photos
    note = ""
    if len(photos) > MAX_FRAME_PANELS:
        rms = [math.hypot(p["rms_x_um"] or 0, p["rms_y_um"] or 0) for p in photos]
        keep = sorted(np.argsort(rms)[-MAX_FRAME_PANELS:])
        shown = [photos[i] for i in keep]
        note = f" The {MAX_FRAME_PANELS} frames with the largest RMS of {len(photos)}."
    g0 = shown[0]["residual_grid"]
    nx, ny = g0["nx"], g0["ny"]
    allv = np.concatenate([np.hypot(np.array(p["residual_grid"]["mean_vx_um"], float),
                                    np.array(p["residual_grid"]["mean_vy_um"], float)) for p in shown])
    vmax = _p95(allv) or 1e-3
    key_um = nice_length(vmax)
    cols = min(6, len(shown))
    rows = math.ceil(len(shown) / cols)
    # inches: panels FRAME_PANEL_IN wide, ``gap`` apart, each under its two-line title (the frame's name, its RMS;
    # ``title_h``), below the key's strip (``key_h``); a name wider than its column is shortened in the middle
    panel_w, gap, title_h, key_h, margin = FRAME_PANEL_IN, 0.2, 0.45, 0.55, 0.1
    panel_h = panel_w * ny / nx
    width_in = cols * panel_w + (cols - 1) * gap + 2 * margin
    height_in = key_h + rows * (title_h + panel_h) + margin
    scale = vmax / (0.9 * panel_w / nx)  # um per inch: the 95th percentile mean residual spans 0.9 of a cell
    fig, axs = plt.subplots(rows, cols, figsize=(width_in, height_in), squeeze=False)
    fig.subplots_adjust(left=margin / width_in, right=1 - margin / width_in, bottom=margin / height_in,
                        top=1 - (key_h + title_h) / height_in, wspace=gap / panel_w, hspace=title_h / panel_h)

    q = None
    for ax, p in zip(axs.ravel(), shown):
        g = p["residual_grid"]
        cx = (np.arange(g["nx"]) + 0.5)
        cy = (np.arange(g["ny"]) + 0.5)
        X, Y = np.meshgrid(cx, cy)
        n = np.array(g["n"]).reshape(g["ny"], g["nx"])
        vx = np.array(g["mean_vx_um"], float).reshape(g["ny"], g["nx"])
        vy = np.array(g["mean_vy_um"], float).reshape(g["ny"], g["nx"])
        ok = n >= 3  # a mean of fewer observations is noise
        q = ax.quiver(X[ok], Y[ok], vx[ok], -vy[ok], angles="xy", scale_units="inches", scale=scale, units="inches",
                      width=0.025, color="tab:red")
        ax.plot(X[~ok], Y[~ok], "x", color="0.7", ms=4)
        ax.set_xlim(0, g["nx"])
        ax.set_ylim(0, g["ny"])
        ax.invert_yaxis()  # image rows down
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        rms = math.hypot(p["rms_x_um"] or 0, p["rms_y_um"] or 0) / math.sqrt(2)
        ax.set_title(f"{fit_text(str(p['image_id']), panel_w + gap / 2, 8)}\n{rms:.1f} um", fontsize=8)
    for ax in axs.ravel()[len(shown):]:
        ax.axis("off")
    px = f" ({key_um / pixel_um:.2g} px)" if pixel_um else ""
    # the key in its own strip above the panels, drawn with the panels' scale (um per inch)
    kax = fig.add_axes([(margin + 0.4) / width_in, 1 - key_h / height_in, 0.5, 0.5 / height_in])  # the arrow in view
    kax.axis("off")
    kax.set_xlim(0, 1)
    kax.set_ylim(0, 1)
    kq = kax.quiver([-5.0], [-5.0], [0.0], [0.0], scale_units="inches", scale=scale, units="inches", width=0.025,
                    color="tab:red")
    kax.quiverkey(kq, 0.02, 0.5, key_um, f"{_fmt(key_um)} um{px} mean image residual", labelpos="E",
                  coordinates="axes")
    return Figure("Image residuals per frame",
                  f"Mean image residual (observed - adjusted) in a {nx} x {ny} grid of each frame, image rows "
                  f"down; grey crosses: cells with fewer than 3 observations; title: the frame's RMS.{note}",
                  f"arrow = {_fmt(key_um)} um{px} on the image", fig)


def gnss_strip_plot(rep: dict) -> Figure | None:
    """Per strip: GNSS minus the adjusted antenna (dots) against the along-track distance, and the strip's
    estimated shift (and drift) as lines; east, north, up in metres."""
    photos = [p for p in rep.get("photos", []) if p.get("gnss_offset_m") and p.get("along_km") is not None]
    if not photos:
        return None
    plt = pyplot()
    strips = sorted({p["strip"] for p in photos})
    shown = strips[:16]
    cols = min(4, len(shown))
    rows = math.ceil(len(shown) / cols)
    fig, axs = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.9 * rows), squeeze=False, sharey=True)
    colours = ("tab:blue", "tab:orange", "tab:green")
    for ax, s in zip(axs.ravel(), shown):
        ps = sorted((p for p in photos if p["strip"] == s), key=lambda p: p["along_km"])
        t = np.array([p["along_km"] for p in ps])
        off = np.array([p["gnss_offset_m"] for p in ps], float)
        corr = np.array([p.get("gnss_correction_m") or [0.0, 0.0, 0.0] for p in ps], float)
        for a, (name, c) in enumerate(zip(("east", "north", "up"), colours)):
            ax.plot(t, off[:, a], "o", color=c, ms=4, label=f"{name}")
            ax.plot(t, corr[:, a], "-", color=c, lw=1.2)
        ax.axhline(0, color="0.6", lw=0.6)
        ax.set_title(f"strip {s} ({len(ps)} frames)", fontsize=9)
        ax.set_xlabel("along track (km)")
        ax.grid(True, color="0.9", lw=0.5)
    for ax in axs[:, 0]:
        ax.set_ylabel("GNSS - adjusted (m)")
    for ax in axs.ravel()[len(shown):]:
        ax.axis("off")
    axs[0, 0].legend(fontsize=7, loc="best")
    mode = (rep.get("options") or {}).get("gps_shift_drift_correction", "")
    lines = (f"lines: the strip's estimated correction ({mode}). A trend the lines miss calls for drift correction."
             if mode.startswith("Enabled") else "no correction per strip was estimated ([adjust] gnss_correction = "
             "\"none\"): a level or a trend of the dots per strip calls for one.")
    gnss = next((c for c in rep.get("variance_components") or [] if c.get("group") == "gnss"), None)
    unchecked = ""
    if gnss is not None and gnss_model.unchecked(gnss.get("redundancy"), gnss.get("observations") or 0):
        # s95: residuals of millimetres from a GNSS nothing else checks read like a 2 mm fit
        unchecked = (f" The GNSS's redundancy is {gnss['redundancy']:.1f} of {gnss['observations']} observations: "
                     "the images do not check the positions, so small dots say nothing of their accuracy.")
    return Figure("GNSS shift and drift per strip",
                  "Dots: GNSS antenna position minus the adjusted antenna position per frame (local east, north, "
                  f"up); {lines}{unchecked}", "vertical axes in metres, horizontal in km along the strip", fig)


VON_GRUBER_MIN_PER_AREA = 3  # tie observations a von Gruber area (a ninth of the frame) should hold at least
VON_GRUBER_MIN_SHRINK = 0.2  # the von Gruber map's frames: at least this share of their ground size


def von_gruber_map(rep: dict, min_per_area: int = VON_GRUBER_MIN_PER_AREA) -> Figure | None:
    """The tie observations in each frame's nine von Gruber areas, drawn as a 3 x 3 block at the frame's
    projection centre (colour: count, colour bar; red outline: fewer than ``min_per_area``)."""
    photos = [p for p in rep.get("photos", []) if p.get("von_gruber_tie_obs")]
    fa = rep.get("flight_acceptance") or {}
    pos = {f["image_id"]: (f["x_m"], f["y_m"]) for f in fa.get("frames", [])}
    photos = [p for p in photos if p["image_id"] in pos]
    if not photos:
        return None
    plt = pyplot()
    from matplotlib.collections import PolyCollection

    fp = {f["image_id"]: np.array(f["footprint"], float) for f in fa.get("frames", [])}
    xy = np.array([pos[p["image_id"]] for p in photos], float)
    o = _origin(xy)
    xy = xy - o
    # each footprint's image corners (top-left, top-right, bottom-right, bottom-left: the draped border
    # starts at the top-left corner, the same number of samples per side), shrunk about the centre so
    # that neighbouring frames' blocks do not overlap; cells stay where they lie on the ground
    corners = {}
    for p in photos:
        q = fp[p["image_id"]][:-1] - o
        m = len(q) // 4
        corners[p["image_id"]] = q[[0, m, 2 * m, 3 * m]]
    size = np.median([np.ptp(c, axis=0).max() for c in corners.values()])
    distinct = np.unique(xy, axis=0)
    if len(distinct) > 1:
        from scipy.spatial import cKDTree

        # the nearest distinct centre of each (by a k-d tree: all pairwise distances grow with the frames squared);
        # its lower quartile, not the closest pair: a kite hovering put a few centres 0.2 m apart and every frame of a
        # 40 m block was drawn at 1.5 % of its size (trial); where centres crowd, the blocks may overlap a little,
        # and they are never drawn below VON_GRUBER_MIN_SHRINK of their size
        d, _ = cKDTree(distinct).query(distinct, k=2)
        shrink = min(max(0.85 * float(np.percentile(d[:, 1], 25)) / size, VON_GRUBER_MIN_SHRINK), 1.0)
    else:
        shrink = 1.0
    # the nine areas of every frame at once: bilinear in the frame's corners (u right, v down), shrunk about the
    # frame's centre; one PolyCollection (a Polygon patch per area costs seconds per thousand frames)
    C = np.array([corners[p["image_id"]] for p in photos])  # (N, 4, 2) tl tr br bl
    centre = C.mean(axis=1)[:, None, None]
    k = np.arange(9)
    u0, v0 = (k % 3) / 3.0, (k // 3) / 3.0  # row 0 = image top
    du = np.array([0.0, 1.0, 1.0, 0.0]) / 3.0
    dv = np.array([0.0, 0.0, 1.0, 1.0]) / 3.0
    u = (u0[:, None] + du[None])[None, :, :, None]  # (1, 9, 4, 1)
    v = (v0[:, None] + dv[None])[None, :, :, None]
    tl, tr, br, bl = (C[:, q][:, None, None, :] for q in range(4))
    g = (1 - v) * ((1 - u) * tl + u * tr) + v * ((1 - u) * bl + u * br)  # (N, 9, 4, 2)
    verts = (centre + shrink * (g - centre)).reshape(-1, 4, 2)
    vals = np.array([p["von_gruber_tie_obs"] for p in photos], float).reshape(-1)
    weak = vals < min_per_area
    cell = shrink * size / 3.0
    fig, ax = plt.subplots(figsize=(10, 8))
    pc = PolyCollection(verts, cmap="viridis", edgecolor="white", linewidth=0.4 if len(photos) <= 500 else 0.0)
    pc.set_array(vals)
    ax.add_collection(pc)
    if weak.any():
        ax.add_collection(PolyCollection(verts[weak], facecolor="none", edgecolor="red", linewidth=1.5))
    if len(photos) <= 40:  # above the frame's areas (an oblique frame's lie far from its projection centre)
        for p, (x0, y0) in zip(photos, C.mean(axis=1)):
            ax.annotate(p["image_id"], (x0, y0 + 1.7 * cell), fontsize=6, ha="center")
    pad = 2 * cell
    # the areas where they lie, not only the centres: an oblique frame's areas are far ahead of its centre
    drawn = np.vstack([xy, verts.reshape(-1, 2)])
    lo, hi = drawn.min(axis=0), drawn.max(axis=0)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - 2.5 * pad, hi[1] + pad)  # room for the scale bar
    extent = max(float(np.ptp(drawn[:, 0])), float(np.ptp(drawn[:, 1])), 1.0)
    bar = _map_axes(ax, o, extent)
    fig.colorbar(pc, ax=ax, shrink=0.8, label="tie observations per von Gruber area")
    n_weak = int(weak.sum())
    # the frames drawn smaller than their ground: said where the scale bar is read (Tuniu trial: frames of 150-300 m
    # drawn 12 m across under a 20 m bar, taken for their size)
    drawn_pct = f"{100 * shrink:.2g} %"
    ax.set_title(f"Von Gruber areas: tie observations per ninth of each frame ({n_weak} areas below {min_per_area})\n"
                 + (f"frames drawn at {drawn_pct} of their ground size about their centres; the scale bar is the map's"
                    if shrink < 1.0 else "frames drawn at their ground size"), fontsize=10)
    return Figure("Von Gruber tie-point distribution",
                  "Each frame's nine areas where they lie on the ground, the frame shrunk about its centre so that "
                  f"neighbours do not overlap (to {drawn_pct} of its size on the ground); red outline: "
                  f"fewer than {min_per_area} tie observations in that area.",
                  f"colour = tie observations per area (colour bar); map scale bar {bar} (positions; frames at "
                  f"{drawn_pct} of their size)", fig)


_ID_SEPARATORS = "_-. "


def short_ids(ids: list[str]) -> tuple[list[str], str, str]:
    """The image ids without the prefix and suffix they all share, cut at a separator (``_ - .`` or space), so
    that labels on a map stay short: NGI's "3324c_2015_1004_05_0182_RGB" ... -> "05_0182" ..., prefix
    "3324c_2015_1004_", suffix "_RGB". One id, or ids that would become empty or equal, are kept whole."""
    if len(ids) < 2:
        return list(ids), "", ""
    prefix = os.path.commonprefix(ids)
    prefix = prefix[:max(prefix.rfind(c) for c in _ID_SEPARATORS) + 1]
    suffix = os.path.commonprefix([i[len(prefix):][::-1] for i in ids])[::-1]
    cut = [suffix.find(c) for c in _ID_SEPARATORS if c in suffix]
    suffix = suffix[min(cut):] if cut else ""
    short = [i[len(prefix):len(i) - len(suffix)] for i in ids]
    if not all(short) or len(set(short)) < len(set(ids)):
        return list(ids), "", ""
    return short, prefix, suffix


def flight_map(fa: dict) -> Figure | None:
    """Frame footprints on the terrain by strip, frames failing a flight check hatched, with a scale bar."""
    frames = fa.get("frames") or []
    if not frames:
        return None
    plt = pyplot()
    from matplotlib.collections import PolyCollection

    fp = [np.array(f["footprint"], float) for f in frames]
    o = _origin(np.vstack(fp))
    bad_strips = {st["strip"] for st in fa.get("strips", []) if st.get("fails")}
    fig, ax = plt.subplots(figsize=(10, 8))
    cmap = plt.get_cmap("tab10")
    strips = sorted({f["strip"] for f in frames})
    # one collection per kind of footprint and one marker layer (an artist per frame costs seconds per
    # thousand frames)
    colour = [cmap(strips.index(f["strip"]) % 10) for f in frames]
    failing = np.array([bool(f.get("fails")) for f in frames])
    for fails in (False, True):
        sel = np.flatnonzero(failing == fails)
        if not len(sel):
            continue
        ax.add_collection(PolyCollection([fp[k] - o for k in sel], closed=True, facecolors=(1, 0, 0, 0.12) if fails
                                         else "none", edgecolors=[colour[k] for k in sel], hatch="//" if fails else None,
                                         linewidths=[2.0 if frames[k]["strip"] in bad_strips else 0.9 for k in sel]))
    centres = np.array([[f["x_m"], f["y_m"]] for f in frames], float) - o[:2]
    ax.scatter(centres[:, 0], centres[:, 1], marker="+", c=colour, s=36, linewidths=1.0)
    # (long ids printed over each other: NGI's 27-character names, new-user trial s51)
    labels, prefix, suffix = short_ids([str(f["image_id"]) for f in frames]) if len(frames) <= 60 else ([], "", "")
    for f, label in zip(frames, labels):
        ax.annotate(label, (f["x_m"] - o[0], f["y_m"] - o[1]), fontsize=6, xytext=(3, 3), textcoords="offset points")
    shortened = (f" Labels: image ids without their common {' and '.join(repr(a) for a in (prefix, suffix) if a)}."
                 if prefix or suffix else "")
    allp = np.vstack(fp) - o
    pad = 0.03 * max(float(np.ptp(allp[:, 0])), float(np.ptp(allp[:, 1])), 1.0)  # edges off the frame
    ax.set_xlim(allp[:, 0].min() - pad, allp[:, 0].max() + pad)
    ax.set_ylim(allp[:, 1].min() - 2.5 * pad, allp[:, 1].max() + pad)  # room for the scale bar
    for k, s in enumerate(strips):
        ax.plot([], [], color=cmap(k % 10), label=f"strip {s}")
    ax.legend(loc="upper right", fontsize=8)
    bar = _map_axes(ax, o, max(np.ptp(allp[:, 0]), np.ptp(allp[:, 1])))
    ax.set_title("Frame footprints on the terrain (hatched: the frame fails a flight check; thick: its strip does)")
    return Figure("Flight: footprints on the terrain",
                  f"Footprints draped on {fa.get('terrain')}; +: projection centres.{shortened}", f"map scale bar {bar}",
                  fig)


# -- HTML tables (rendered by the templates' ``table`` macro) -------------------------------------

@dataclasses.dataclass(frozen=True)
class Cell:
    """A table cell: its text (plain, the template escapes it) and CSS classes ("num", "pass", "fail")."""

    text: str
    css: str = ""


@dataclasses.dataclass(frozen=True)
class Table:
    """An HTML table: header texts and rows of cells; ``folded``: the summary of the <details> element a long
    table folds into (click to open), None for a table shown open."""

    headers: tuple[str, ...]
    rows: tuple[tuple[Cell, ...], ...]
    folded: str | None = None


def cell(v, nd: int = 3) -> str:
    """A value as table text: None empty, booleans yes/no, floats with ``nd`` decimals (not finite: empty; a value
    that rounds to zero is 0, never -0, as the text report's figures since trial s103 F1)."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{round(v, nd) + 0.0:.{nd}f}" if math.isfinite(v) else ""
    return str(v)


def table(headers: list[str], rows: list[list], nd: int = 3, verdict_col: int | None = None,
          num_from: int = 1) -> Table:
    """A table; numbers right-aligned from column ``num_from``; a verdict column coloured."""
    out = []
    for r in rows:
        cells = []
        for j, v in enumerate(r):
            css = []
            if j >= num_from and isinstance(v, (int, float)) and not isinstance(v, bool):
                css.append("num")
            if verdict_col is not None and j == verdict_col and v in ("pass", "fail"):
                css.append(v)
            cells.append(Cell(cell(v, nd), " ".join(css)))
        out.append(tuple(cells))
    return Table(tuple(headers), tuple(out))


def long_table(what: str, headers: list[str], rows: list[list], nd: int = 3, shown: int = 40,
               count: int | None = None, **kw) -> Table:
    """A table; beyond ``shown`` rows it folds into a <details> element (click to open), so that a long
    per-point list does not push the rest of the report pages down. ``count``: how many ``what`` the summary
    names when ``rows`` also holds summary rows (the check points' sum and rms), else every row is one."""
    t = table(headers, rows, nd, **kw)
    return t if len(rows) <= shown else dataclasses.replace(t, folded=f"{len(rows) if count is None else count} {what}")


def strip_label(strip: dict) -> str:
    """A strip's number in the flight tables, "(cross)" after a cross strip (no side overlap of its own)."""
    return f"{strip['strip']} (cross)" if strip.get("cross_strip") else str(strip["strip"])


def strip_fails(fa: dict, strip: dict) -> list:
    """The flight limits a strip or any of its frames breaks (tolerance-table keys, in table order)."""
    from aerotri.adjust.flight_acceptance import LIMIT_KEYS

    keys = set(strip.get("fails", []))
    for f in fa["frames"]:
        if f["strip"] == strip["strip"]:
            keys.update(f.get("fails", []))
    return [k for k in LIMIT_KEYS if k in keys]


@dataclasses.dataclass(frozen=True)
class FlightTables:
    """The flight acceptance as tables: where the figures come from, the checks with their limits, per strip and
    per frame (the templates' ``flight`` macro)."""

    source: str
    terrain: str
    checks: Table
    strips: Table
    frames: Table


def flight_tables(fa: dict) -> FlightTables | None:
    """The flight acceptance: the checks with their limits, then per strip and per frame (None: no flight)."""
    if not fa:
        return None
    ops = {"max": "<=", "min": ">="}
    from aerotri.adjust.flight_acceptance import LIMIT_KEYS

    checks = [[c["quantity"], c["value"], f"{ops[LIMIT_KEYS[c['key']][2]]} {_fmt(c['limit'])}"
               if c["limit"] is not None else "", c["unit"], c["where"], f"{c['n_fail']} of {c['n']}", c["verdict"]]
              for c in fa["checks"]]
    strips = table(["strip", "frames", "first", "last", "length m", "curvature %", "height range m",
                    "mean Z m", "above ground m", "forward min %", "forward mean %", "side median %",
                    "max tilt deg", "max kappa deg", "failing"],
                   [[strip_label(s), s["frames"], s["first"], s["last"], s["length_m"], s["curvature_pct"],
                     s["height_range_m"], s["mean_z_m"], s["mean_height_above_ground_m"], s["forward_overlap_min_pct"],
                     s["forward_overlap_mean_pct"], s["side_overlap_median_pct"], s["max_tilt_deg"],
                     s["max_kappa_deviation_deg"], ", ".join(LIMIT_KEYS[k][0] for k in strip_fails(fa, s))]
                    for s in fa["strips"]], 2)
    lim = fa["limits"]

    def mark(v, key):
        if v is None or lim.get(key) is None:
            return v
        bad = v > lim[key] if LIMIT_KEYS[key][2] == "max" else v < lim[key]
        return f"{v:.2f} !" if bad else v

    frames = long_table("frames", ["image", "strip", "Z m", "above ground m", "tilt deg", "kappa dev. deg",
                                   "height step m", "forward %", "side %"],
                        [[f["image_id"], f["strip"], f["z_m"], f["height_above_ground_m"],
                          mark(f["tilt_deg"], "flight_tilt_max_deg"), mark(f["kappa_deviation_deg"], "flight_kappa_max_deg"),
                          mark(f["height_step_m"], "flight_height_step_max_m"),
                          mark(f["forward_overlap_pct"], "flight_forward_overlap_min_pct"),
                          mark(f["side_overlap_pct"], "flight_side_overlap_min_pct")] for f in fa["frames"]], 2)
    return FlightTables(str(fa["source"]), str(fa["terrain"]),
                        table(["check", "worst", "limit", "unit", "at", "failing", "verdict"], checks, 2, verdict_col=6),
                        strips, frames)
