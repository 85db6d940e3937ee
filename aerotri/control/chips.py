"""Review page: an image chip per corner and frame with the predicted and the measured position.

``control/review.html`` (``aerotri/templates/control_review.html.j2``) and ``control/chips/<corner>_<image>.png``.
Chips are enlarged ``scale`` times without interpolation; a blue circle marks the prediction, a red cross the accepted
measurement, an orange cross a rejected one.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from aerotri.core.pages import render


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


def write_review(folder: Path, project: str, summary: str, corners: list[dict], chips: dict[str, bytes],
                 rejections=()) -> None:
    """Write review.html and chips/ into folder (a fresh temporary folder; the caller moves it in place);
    ``rejections``: the rejection table's rows (``aerotri.control.pipeline.RejectionRow``)."""
    folder = Path(folder)
    (folder / "chips").mkdir(parents=True, exist_ok=True)
    for name, data in chips.items():
        (folder / "chips" / name).write_bytes(data)
    (folder / "review.html").write_text(render("control_review.html.j2", project=project, summary=summary,
                                                    corners=corners, rejections=rejections))
