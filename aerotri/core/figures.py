"""Figures: matplotlib without a display, written as PNG atomically and closed.

Every plot of the packages (stage previews, check plots, report figures) goes through here:
``pyplot()`` imports matplotlib on first use (a command that draws nothing does not pay for it) with the
Agg backend; ``save_png`` writes a figure through ``core.atomic.atomic_path`` (no half-written PNG) and
closes it, also when writing fails; ``png_bytes`` gives the PNG for a report that embeds it.
"""

from __future__ import annotations

import io
from pathlib import Path

from aerotri.core.atomic import atomic_path


def pyplot():
    """``matplotlib.pyplot`` with the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path, *, dpi: int, tight: bool = False) -> Path:
    """``fig`` as a PNG at ``dpi`` (``tight``: cropped to what is drawn), written atomically; the figure is
    closed."""
    plt = pyplot()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png", **({"bbox_inches": "tight"} if tight else {}))
    finally:
        plt.close(fig)
    return Path(path)


def png_bytes(fig, *, dpi: int, tight: bool = False) -> bytes:
    """``fig`` as PNG bytes (for a report that embeds it); the figure is closed."""
    plt = pyplot()
    buf = io.BytesIO()
    try:
        fig.savefig(buf, dpi=dpi, format="png", **({"bbox_inches": "tight"} if tight else {}))
    finally:
        plt.close(fig)
    return buf.getvalue()
