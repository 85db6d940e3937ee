"""Render a project's reports as a reviewer sees them: ``at/report.html`` and ``reports/index.html`` in
headless Chromium (Debian ``chromium``) to full-page PNGs, and ``reports/report.pdf`` page by page with
``pdftoppm -png``; then check every PNG is not blank and no page is a browser error page or shows
broken images.

    python bench/render_reports.py [PROJECT [OUTDIR]] [--width 1400]   (default out/demo/project)

Full page: Chromium's ``--screenshot`` captures the window only, so the page height is read first (a
copy of the page with a ``<base>`` pointing at the original folder and a script that writes
``scrollHeight`` and the number of broken images into the DOM, read with ``--dump-dom``), then the page
is captured in windows of ``SEGMENT_PX`` scrolled down one after the other and stitched. Writes
``OUTDIR/render.json`` (files, sizes, checks) and exits 1 when a check fails. The project is only read.
`make bench` installs chromium and poppler-utils (apt-get).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

SEGMENT_PX = 3000
MAX_HEIGHT_PX = 60000
PROBE = ("<script>window.addEventListener('load',function(){var b=0;document.querySelectorAll('img').forEach("
         "function(i){if(!i.complete||i.naturalWidth===0)b++;});var d=document.createElement('div');d.id='__probe';"
         "d.textContent='HEIGHT='+document.documentElement.scrollHeight+' BROKEN='+b;document.body.appendChild(d);});"
         "</script>")
ERROR_MARKERS = ("ERR_FILE_NOT_FOUND", "ERR_ACCESS_DENIED", "This site can", "is not available", "ERR_INVALID_URL")


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    sys.exit("chromium not found: apt-get install -y chromium (make bench does)")


def _chrome(args: list[str], timeout: int = 120) -> subprocess.CompletedProcess:
    base = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--mute-audio",
            "--allow-file-access-from-files", "--virtual-time-budget=5000", "--run-all-compositor-stages-before-draw"]
    return subprocess.run(base + args, capture_output=True, text=True, timeout=timeout)


def _page_copy(html_path: Path, tmp: Path, scroll_px: int | None) -> Path:
    """A copy of the page that resolves relative links against the original folder (and scrolls)."""
    text = html_path.read_text(encoding="utf-8")
    head = f"<base href='{html_path.parent.resolve().as_uri()}/'>"
    # a window further down: the page shifted up (scrolling before --screenshot is not reliable)
    extra = PROBE if scroll_px is None else f"<style>html{{position:relative;top:-{scroll_px}px}}</style>"
    text = re.sub(r"<head([^>]*)>", lambda m: f"<head{m.group(1)}>{head}", text, count=1) if "<head" in text \
        else head + text
    text = text.replace("</body>", extra + "</body>") if "</body>" in text else text + extra
    out = tmp / f"{html_path.stem}_{'probe' if scroll_px is None else scroll_px}.html"
    out.write_text(text, encoding="utf-8")
    return out


def render_html(html_path: Path, out_png: Path, width: int) -> dict:
    """Full-page PNG of one HTML file; returns its checks."""
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        probe = _chrome([f"--window-size={width},1000", "--dump-dom", _page_copy(html_path, tmp, None).as_uri()])
        dom = probe.stdout
        m = re.search(r"HEIGHT=(\d+) BROKEN=(\d+)", dom)
        error_page = any(e in dom for e in ERROR_MARKERS) or m is None
        height = min(int(m.group(1)), MAX_HEIGHT_PX) if m else 1000
        broken = int(m.group(2)) if m else None
        tiles, blank_windows = [], []
        for y in range(0, height, SEGMENT_PX):
            h = min(SEGMENT_PX, height - y)
            shot = tmp / f"seg_{y}.png"
            # the last window starts higher so that it is full; its top overlaps the previous one
            y0 = max(0, min(y, height - SEGMENT_PX))
            _chrome([f"--window-size={width},{SEGMENT_PX}", f"--screenshot={shot}",
                     _page_copy(html_path, tmp, y0).as_uri()])
            im = Image.open(shot).convert("RGB").crop((0, y - y0, width, y - y0 + h))
            tiles.append(im)
            if h >= 200 and im.getextrema() == ((255, 255), (255, 255), (255, 255)):  # not the bottom margin
                blank_windows.append(y)
        page = Image.new("RGB", (width, height), "white")
        for k, t in enumerate(tiles):
            page.paste(t, (0, k * SEGMENT_PX))
        out_png.parent.mkdir(parents=True, exist_ok=True)
        page.save(out_png, optimize=True)
    checks = image_checks(out_png)
    checks["blank"] = checks["blank"] or bool(blank_windows)  # a white window: the capture lost part of the page
    return dict(file=str(out_png), source=str(html_path), height_px=height, broken_images=broken,
                error_page=error_page, blank_windows_px=blank_windows, **checks)


def image_checks(png: Path) -> dict:
    """Not blank: enough pixels differ from the background, and in more than one grey level."""
    a = np.asarray(Image.open(png).convert("L"), dtype=np.int16)
    bg = int(np.bincount(a.ravel(), minlength=256).argmax())
    ink = float(np.mean(np.abs(a - bg) > 24))
    return dict(width_px=int(a.shape[1]), ink_fraction=round(ink, 4), grey_levels=int(len(np.unique(a))),
                blank=bool(ink < 0.005 or len(np.unique(a)) < 8))


def render_pdf(pdf: Path, outdir: Path, dpi: int = 80) -> list[dict]:
    if not shutil.which("pdftoppm"):
        sys.exit("pdftoppm not found: apt-get install -y poppler-utils (make bench does)")
    prefix = outdir / "report_pdf"
    for old in outdir.glob("report_pdf-*.png"):  # pages of an earlier, longer PDF
        old.unlink()
    subprocess.run(["pdftoppm", "-png", "-r", str(dpi), str(pdf), str(prefix)], check=True, timeout=300)
    return [dict(file=str(p), source=str(pdf), **image_checks(p)) for p in sorted(outdir.glob("report_pdf-*.png"))]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", type=Path, nargs="?", default=Path("out/demo/project"),
                    help="project folder (default: make demo's out/demo/project)")
    ap.add_argument("outdir", type=Path, nargs="?", default=Path("out/report_render"))
    ap.add_argument("--width", type=int, default=1400)
    a = ap.parse_args(argv)
    if not (a.project / "project.toml").is_file():
        print(f"skip: {a.project} is no project folder (run make demo first)")
        return 0
    a.outdir.mkdir(parents=True, exist_ok=True)
    pages, missing = [], []
    for rel, name in (("at/report.html", "at_report.png"), ("reports/index.html", "reports_index.png")):
        src = a.project / rel
        if src.is_file():
            pages.append(render_html(src, a.outdir / name, a.width))
        else:
            missing.append(rel)
    pdf = a.project / "reports" / "report.pdf"
    if pdf.is_file():
        pages += render_pdf(pdf, a.outdir)
    else:
        missing.append("reports/report.pdf")
    bad = [p for p in pages if p["blank"] or p.get("error_page") or p.get("broken_images")]
    (a.outdir / "render.json").write_text(json.dumps(dict(pages=pages, missing=missing, failed=len(bad)), indent=1))
    for p in pages:
        flag = "FAIL" if p in bad else "ok"
        print(f"{flag:4} {p['file']}: {p['width_px']} px wide, ink {p['ink_fraction']:.3f}"
              + (f", {p['height_px']} px tall, broken images {p['broken_images']}" if "height_px" in p else ""))
    for m in missing:
        print(f"missing {m}")
    return 1 if bad or not pages else 0


if __name__ == "__main__":
    sys.exit(main())
