"""Consolidated accuracy report of a project: ``reports/index.html`` and ``reports/summary.json``.

It gathers what the stages wrote (LiDAR classification and height checks, control-point transfer,
the adjustment's ISAT-style numbers, the DOM check) and marks each quantity that has a tolerance
as pass or fail. Tolerances come from a TOML table per map scale and standard (default: the Chinese
specification for 1:5000 / 1:10000 photogrammetric office work, ``aerotri/adjust/tolerances``), for
the terrain class of the project; users pass their own table for their contract.
"""

from __future__ import annotations

import html
import json
import tomllib
from pathlib import Path

from aerotri.adjust.report import TOLERANCES
from lidarctl.atomic import write_text_atomic


def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def _check(name: str, value, limit, unit: str) -> dict:
    row = dict(quantity=name, value=value, limit=limit, unit=unit)
    row["verdict"] = None if value is None or limit is None else ("pass" if value <= limit else "fail")
    return row


def build_qa_report(root, tolerance_file=None, terrain: str = "flat") -> dict:
    root = Path(root)
    tol_path = Path(tolerance_file) if tolerance_file else TOLERANCES
    tol_all = tomllib.loads(tol_path.read_text())
    tol = tol_all.get(terrain, {})
    at = _json(root / "at" / "report.json")
    ctl = _json(root / "control" / "transfer.json").get("summary", {})
    dom = _json(root / "ortho" / "dom_report.json").get("displacement", {})
    hc = _json(root / "lidar_out" / "height_check.json").get("overall", {})
    ce = _json(root / "lidar_out" / "classification_eval.json").get("filter_test", {})
    chk = at.get("check_rms_m")
    rows = []
    if chk and None not in chk:
        rows.append(_check("aerotriangulation check points, plan RMS", round((chk[0] ** 2 + chk[1] ** 2) ** 0.5, 4),
                           tol.get("rms_xy_m"), "m"))
        rows.append(_check("aerotriangulation check points, height RMS", chk[2], tol.get("rms_z_m"), "m"))
    ctrl = at.get("rms_control_ground_m")
    if ctrl and None not in ctrl:
        rows.append(_check("control points, plan RMS residual", round((ctrl[0] ** 2 + ctrl[1] ** 2) ** 0.5, 4),
                           tol.get("rms_xy_m"), "m"))
        rows.append(_check("control points, height RMS residual", ctrl[2], tol.get("rms_z_m"), "m"))
    if dom.get("rms_xy_m") is not None:
        rows.append(_check("DOM displacement on ground patches, plan RMS", round(dom["rms_xy_m"], 4),
                           tol.get("feature_rms_xy_m"), "m"))
    ks = at.get("key_statistics", {})
    info = dict(
        adjustment=dict(sigma0_um=ks.get("sigma0_um"), success=ks.get("success"), message=ks.get("message"),
                        counts=at.get("counts"), rejected_control=at.get("rejected_control")),
        control_transfer=ctl,
        lidar_height_check=hc.get("all"),
        lidar_classification=ce or None,
        dom=dom or None,
    )
    verdicts = [r["verdict"] for r in rows if r["verdict"]]
    return dict(project=at.get("project", root.name), tolerance_table=str(tol_path.name), terrain=terrain,
                checks=rows, overall=("fail" if "fail" in verdicts else "pass") if verdicts else None, details=info)


def format_html(rep: dict) -> str:
    def cell(v):
        return "" if v is None else html.escape(f"{v:.4g}" if isinstance(v, float) else str(v))

    rows = "".join(
        f"<tr><td>{cell(r['quantity'])}</td><td>{cell(r['value'])}</td><td>{cell(r['limit'])}</td><td>{cell(r['unit'])}</td>"
        f"<td class='{r['verdict'] or ''}'>{cell(r['verdict'])}</td></tr>" for r in rep["checks"])
    details = "".join(f"<h3>{html.escape(k.replace('_', ' '))}</h3><pre>{html.escape(json.dumps(v, indent=1))}</pre>"
                      for k, v in rep["details"].items() if v)
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>Accuracy report {html.escape(rep['project'])}</title>
<style>body{{font-family:sans-serif;margin:2em}}td,th{{border:1px solid #ccc;padding:4px 8px}}table{{border-collapse:collapse}}
.pass{{background:#cfc}}.fail{{background:#fcc}}pre{{background:#f6f6f6;padding:8px}}</style></head><body>
<h1>Accuracy report: {html.escape(rep['project'])}</h1>
<p>Tolerances: {html.escape(rep['tolerance_table'])}, terrain class <b>{html.escape(rep['terrain'])}</b>.
Overall verdict: <b class="{rep['overall'] or ''}">{html.escape(str(rep['overall']))}</b></p>
<table><tr><th>quantity</th><th>value</th><th>limit</th><th>unit</th><th>verdict</th></tr>{rows}</table>
<p>Stage reports: <a href="../at/report.html">adjustment (ISAT layout)</a>, <a href="../at/report.txt">report.txt</a>,
<a href="../control/review/review.html">control transfer review</a>, <a href="../ortho/dom_report.png">DOM check plot</a>,
<a href="../at/connectivity.png">tie-point connectivity</a>.</p>
{details}</body></html>
"""


def write_qa_report(root, tolerance_file=None, terrain: str = "flat") -> dict:
    root = Path(root)
    rep = build_qa_report(root, tolerance_file, terrain)
    write_text_atomic(root / "reports" / "summary.json", json.dumps(rep, indent=1) + "\n")
    write_text_atomic(root / "reports" / "index.html", format_html(rep))
    return rep
