"""Connectivity report: JSON numbers and a plot of the block (footprints, pairs, tie counts, weak areas)."""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.core.figures import pyplot, save_png


def plot_block(path, plan, pairs_ties: list[tuple[int, int, int]], strength) -> None:
    """The block (footprints, frame centres, a line per pair coloured by its ties, weak models in red) as PNG;
    ``strength``: ``aerotri.match.weak.BlockStrength``."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 8))
    for fp in plan.footprints:
        x, y = fp.exterior.xy
        ax.plot(x, y, color="0.75", lw=0.6)
    c = plan.centre_m
    tmax = max([t for _, _, t in pairs_ties] + [1])
    for i, j, t in pairs_ties:
        ax.plot([c[i, 0], c[j, 0]], [c[i, 1], c[j, 1]], color=plt.cm.viridis(t / tmax), lw=0.5 + 3.0 * t / tmax,
                alpha=0.8)
    for m in strength.models:
        if m.weak:
            ov = plan.footprints[m.i].intersection(plan.footprints[m.j])
            if not ov.is_empty:
                x, y = ov.exterior.xy
                ax.fill(x, y, color="red", alpha=0.15)
    ax.scatter(c[:, 0], c[:, 1], s=12, c="k", zorder=3)
    for k, iid in enumerate(plan.image_id):
        ax.annotate(iid, c[k, :2], fontsize=6, xytext=(2, 2), textcoords="offset points")
    sm = plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(0, tmax))
    fig.colorbar(sm, ax=ax, label="tie points per pair")
    weak = sum(m.weak for m in strength.models)
    # the plan's footprints, not the draped ones of the adjustment report (Tuniu trial: read as the frames' ground)
    ax.set_title(f"{len(plan.image_id)} frames, {len(pairs_ties)} pairs, {weak} weak models (red)\n"
                 "grey: footprints as planned for pairing (the frames' corners, approximate orientations, flat "
                 "ground)", fontsize=10)
    ax.set_aspect("equal")
    ax.set_xlabel("X (m)")
    ax.set_ylabel("Y (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    # full map coordinates (e.g. -59000 on NGI's Lo25) run into each other on a tall block's narrow x axis
    ax.tick_params(axis="x", labelrotation=90)
    save_png(fig, path, dpi=120, tight=True)


def plot_pair_graph(path, image_ids: list[str], pairs_ties: list[tuple[int, int, int]],
                    components: list[list[str]]) -> None:
    """The block without positions to draw it at (no GNSS, no given orientations: a kite, a handheld block): its
    frames on a circle in file order, a chord per matched pair coloured by its ties, each part that no tie point
    connects to the others in a colour of its own, as PNG (kite trial: such a block got no connectivity figure,
    and one that fell apart into 2 parts showed it nowhere)."""
    plt = pyplot()
    n = len(image_ids)
    angle = np.pi / 2 - 2 * np.pi * np.arange(n) / max(n, 1)  # clockwise from the top
    xy = np.column_stack([np.cos(angle), np.sin(angle)])
    part = {k: i for i, c in enumerate(components) for k in c}
    fig, ax = plt.subplots(figsize=(8, 8))
    tmax = max([t for _, _, t in pairs_ties] + [1])
    for i, j, t in sorted(pairs_ties, key=lambda p: p[2]):  # the strongest on top
        ax.plot(xy[[i, j], 0], xy[[i, j], 1], color=plt.cm.viridis(t / tmax), lw=0.5 + 3.0 * t / tmax, alpha=0.8)
    colours = [plt.cm.tab10(part.get(k, 0) % 10) for k in image_ids]
    ax.scatter(xy[:, 0], xy[:, 1], s=30, c=colours, edgecolors="k", linewidths=0.5, zorder=3)
    step = max(1, n // 60)  # labels readable up to about 60 frames; every step-th beyond
    for k in range(0, n, step):
        side = "left" if xy[k, 0] > 0.2 else "right" if xy[k, 0] < -0.2 else "center"  # outward, clear of the dot
        ax.annotate(image_ids[k], xy[k] * 1.06, fontsize=6, ha=side, va="center")
    sm = plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(0, tmax))
    fig.colorbar(sm, ax=ax, shrink=0.7, label="tie points per pair")
    ax.set_title(f"{n} frames, {len(pairs_ties)} pairs, {len(components)} part{'s' if len(components) != 1 else ''} "
                 "(a colour each)\nno positions before the adjustment: frames on a circle in file order",
                 fontsize=10)
    ax.set_aspect("equal")
    ax.set_xlim(-1.25, 1.25)
    ax.set_ylim(-1.25, 1.25)
    ax.axis("off")
    save_png(fig, path, dpi=120, tight=True)


@dataclasses.dataclass(frozen=True)
class TrackLengths:
    """How long the tracks are: ``rays`` (the frames a track is measured in, ascending, each length that occurs)
    and ``tracks`` (how many tracks have that length), int arrays of one length."""

    rays: np.ndarray
    tracks: np.ndarray


def track_lengths(track: np.ndarray) -> TrackLengths:
    """The track lengths of the measurements' track numbers ``track`` (one per image measurement)."""
    lengths = np.bincount(track) if len(track) else np.zeros(0, int)
    rays, tracks = np.unique(lengths[lengths > 0], return_counts=True)
    return TrackLengths(rays.astype(int), tracks.astype(int))
