"""Figures drawn once (``aerotri.core.figures``) have the pixels ``Figure.savefig`` gives them, tight or not, with or
without a layout engine, with content beyond the canvas that only the tight crop shows."""

import io

import numpy as np
import pytest
from PIL import Image

from aerotri.core.figures import png_bytes, pyplot, save_png


def _figure(kind: str):
    plt = pyplot()
    rng = np.random.default_rng(3)
    if kind == "label_below_the_canvas":  # no layout engine; the x label is drawn below the figure
        fig, ax = plt.subplots(figsize=(4, 1.6))
        fig.subplots_adjust(bottom=0.02)
        ax.plot(rng.normal(size=50))
        ax.set_xlabel("frame (index along the strip)")
    elif kind == "constrained_with_colourbar":
        fig, axes = plt.subplots(1, 2, figsize=(6, 3), layout="constrained")
        im = axes[0].imshow(rng.normal(size=(20, 30)), cmap="RdBu_r")
        fig.colorbar(im, ax=axes[0], label="dz (m)")
        axes[1].scatter(*rng.normal(size=(2, 200)), s=4)
        axes[1].set_aspect("equal")
        fig.suptitle("two panels")
    else:  # a map with an equal aspect and a quiver key, no engine
        fig, ax = plt.subplots(figsize=(4, 4))
        x, y = np.meshgrid(np.arange(5.0), np.arange(4.0))
        q = ax.quiver(x, y, rng.normal(size=x.shape), rng.normal(size=x.shape))
        ax.quiverkey(q, 0.8, 1.05, 1.0, "1 m", labelpos="E")
        ax.set_aspect("equal")
        ax.set_title("residual vectors")
    return fig


def _savefig_rgba(kind: str, dpi: int, tight: bool) -> np.ndarray:
    fig = _figure(kind)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png", **({"bbox_inches": "tight"} if tight else {}))
    pyplot().close(fig)
    return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGBA"))


@pytest.mark.parametrize("kind", ["label_below_the_canvas", "constrained_with_colourbar", "equal_aspect_map"])
@pytest.mark.parametrize("tight", [True, False])
def test_one_drawing_gives_savefig_s_pixels(kind, tight, tmp_path):
    expected = _savefig_rgba(kind, 90, tight)
    embedded = Image.open(io.BytesIO(png_bytes(_figure(kind), dpi=90, tight=tight)))
    written = Image.open(save_png(_figure(kind), tmp_path / "f.png", dpi=90, tight=tight))
    for image in (embedded, written):
        assert image.mode == "RGB"  # opaque: no alpha channel written
        assert np.array_equal(np.asarray(image.convert("RGBA")), expected)
    if kind == "label_below_the_canvas":
        assert (expected.shape[0] > 1.6 * 90) == tight  # the crop reaches below the canvas to show the label


def test_a_transparent_figure_keeps_its_alpha():
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(2, 2))
    fig.patch.set_alpha(0.0)
    ax.plot([0, 1], [0, 1])
    image = Image.open(io.BytesIO(png_bytes(fig, dpi=50)))
    assert image.mode == "RGBA" and np.asarray(image)[0, 0, 3] == 0
    assert not plt.get_fignums() or fig.number not in plt.get_fignums()  # closed
