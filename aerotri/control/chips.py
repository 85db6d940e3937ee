"""Review page: an image chip per corner and frame with the predicted and the measured position.

``control/review.html`` (jinja2) and ``control/chips/<corner>_<image>.png``. Chips are enlarged
``scale`` times without interpolation; a blue circle marks the prediction, a red cross the accepted
measurement, an orange cross a rejected one.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import jinja2
import numpy as np

PAGE = jinja2.Template("""<!doctype html>
<html><head><meta charset="utf-8"><title>Control transfer review - {{ project }}</title>
<style>body{font-family:sans-serif;font-size:13px} table{border-collapse:collapse} td,th{border:1px solid #ccc;padding:3px;vertical-align:top}
.full{background:#e3f2e3}.height{background:#e3ecf7}.check{background:#f6f6f6}.rejected{background:#f7e3e3} figure{display:inline-block;margin:2px}
figcaption{font-size:11px}</style></head><body>
<h1>Control transfer review: {{ project }}</h1>
<p>{{ summary }}</p>
<p>Blue circle: predicted from the LiDAR corner and the orientations; red cross: accepted measurement; orange: rejected.
Manual measurements for rejected corners: add <code>point_id,image_id,x_px,y_px</code> lines to a CSV and run
<code>aerotri control PROJECT --import-manual FILE.csv</code>.</p>
<table><tr><th>corner</th><th>status</th><th>chips (image: x_px, y_px, ray residual)</th></tr>
{% for c in corners %}<tr class="{{ c.cls }}"><td>{{ c.id }}<br>score {{ c.score }}<br>{{ c.xyz }}</td><td>{{ c.status }}</td><td>
{% for ch in c.chips %}<figure><img src="chips/{{ ch.file }}" width="{{ ch.size }}"><figcaption>{{ ch.caption }}</figcaption></figure>{% endfor %}
</td></tr>{% endfor %}</table></body></html>
""")


def chip_png(image, pred_xy, meas_xy, ok: bool, half_px: int = 16, scale: int = 4) -> bytes:
    """PNG bytes of a chip of an RGB image (H, W, 3) centred on the prediction."""
    H, W = image.shape[:2]
    cx, cy = int(round(pred_xy[0])), int(round(pred_xy[1]))
    chip = np.zeros((2 * half_px + 1, 2 * half_px + 1, 3), np.uint8)
    r0, r1, c0, c1 = max(cy - half_px, 0), min(cy + half_px + 1, H), max(cx - half_px, 0), min(cx + half_px + 1, W)
    if r1 > r0 and c1 > c0:
        chip[r0 - (cy - half_px) : r1 - (cy - half_px), c0 - (cx - half_px) : c1 - (cx - half_px)] = np.atleast_3d(image[r0:r1, c0:c1])[..., :3]
    big = cv2.resize(chip, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)[:, :, ::-1].copy()

    def to_big(p):
        return int(round((p[0] - (cx - half_px) + 0.5) * scale)), int(round((p[1] - (cy - half_px) + 0.5) * scale))

    cv2.circle(big, to_big(pred_xy), 6, (255, 80, 0), 1)
    if meas_xy is not None and np.all(np.isfinite(meas_xy)):
        cv2.drawMarker(big, to_big(meas_xy), (0, 0, 255) if ok else (0, 160, 255), cv2.MARKER_CROSS, 14, 1)
    return cv2.imencode(".png", big)[1].tobytes()


def write_review(folder: Path, project: str, summary: str, corners: list[dict], chips: dict[str, bytes]) -> None:
    """Write review.html and chips/ into folder (a fresh temporary folder; the caller moves it in place)."""
    folder = Path(folder)
    (folder / "chips").mkdir(parents=True, exist_ok=True)
    for name, data in chips.items():
        (folder / "chips" / name).write_bytes(data)
    (folder / "review.html").write_text(PAGE.render(project=project, summary=summary, corners=corners))
