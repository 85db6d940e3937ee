"""The adjustment report's figures drawn once (``aerotri.core.figures``) against matplotlib's ``savefig``, in one
process: CPU seconds per figure, PNG sizes, and whether the pixels are the same.

The figures are made from a project's ``at/report.json`` (``aerotri.adjust.report.report_figures``: ground
residual vectors, image residuals per frame, GNSS per strip, von Gruber areas, flight footprints), each twice per
repeat (a pickled copy for ``savefig``), ``savefig`` first in odd repeats and second in even ones; the medians are
reported. Run on an adjusted project, e.g. the demo's:

  .venv/bin/python bench/figures_drawn_once.py PROJECT --repeats 5 --out bench/results/figures_drawn_once.json
"""

from __future__ import annotations

import argparse
import io
import json
import pickle
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image


def _savefig_png(fig, dpi: int) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png", bbox_inches="tight")
    return buf.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("project", type=Path)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dpi", type=int, default=110)  # report_figures.Figure.png's
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)

    from aerotri.adjust.report import report_figures
    from aerotri.core.figures import png_bytes, pyplot

    rep = json.loads((a.project / "at" / "report.json").read_text())
    plt = pyplot()
    times: dict[str, dict[str, list]] = {}
    rows = {}
    for k in range(a.repeats):
        for f in report_figures(rep):
            twin = pickle.loads(pickle.dumps(f.fig))
            order = [("savefig", twin), ("drawn_once", f.fig)] if k % 2 == 0 else [("drawn_once", f.fig), ("savefig", twin)]
            out = {}
            for how, fig in order:
                t0 = time.process_time()
                out[how] = _savefig_png(fig, a.dpi) if how == "savefig" else png_bytes(fig, dpi=a.dpi, tight=True)
                times.setdefault(f.title, {}).setdefault(how, []).append(time.process_time() - t0)
                plt.close(fig)
            old, new = (np.asarray(Image.open(io.BytesIO(out[h])).convert("RGBA")) for h in ("savefig", "drawn_once"))
            rows[f.title] = {"size_px": list(old.shape[1::-1]), "same_pixels": bool(old.shape == new.shape
                                                                                     and np.array_equal(old, new)),
                             "png_kb": {"savefig": round(len(out["savefig"]) / 1e3, 1),
                                        "drawn_once": round(len(out["drawn_once"]) / 1e3, 1)}}
    for title, t in times.items():
        rows[title]["cpu_s_median"] = {h: round(statistics.median(v), 4) for h, v in t.items()}
    total = {h: round(sum(r["cpu_s_median"][h] for r in rows.values()), 3) for h in ("savefig", "drawn_once")}
    result = {"project": str(a.project), "repeats": a.repeats, "dpi": a.dpi, "figures": rows,
              "total_cpu_s_median": total, "ratio_savefig_over_drawn_once": round(total["savefig"] / total["drawn_once"], 3),
              "all_same_pixels": all(r["same_pixels"] for r in rows.values()),
              "command": "bench/figures_drawn_once.py " + " ".join(sys.argv[1:])}
    for title, r in rows.items():
        c = r["cpu_s_median"]
        print(f"{title[:45]:45s} savefig {c['savefig']:.3f} s  drawn once {c['drawn_once']:.3f} s  "
              f"{r['png_kb']['savefig']:.0f} / {r['png_kb']['drawn_once']:.0f} kB  same pixels {r['same_pixels']}")
    print(f"total: savefig {total['savefig']:.3f} CPU-s, drawn once {total['drawn_once']:.3f} "
          f"({result['ratio_savefig_over_drawn_once']:.2f}x)")
    if a.out:
        doc = json.loads(a.out.read_text()) if a.out.exists() else {}
        doc["adjust_report_figures"] = result
        a.out.write_text(json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
