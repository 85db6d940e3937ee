"""Two ``aerotri adjust`` results of one project compared in sigma units: the robust rounds' stopping rule.

``aerotri adjust`` stops re-solving its robust rounds for a change of the surface gate alone once fewer than
``solve.GATE_CHANGE_SHARE`` of the candidates changed sides and the round moved no orientation by
``solve.UPDATE_SIGMA_FRACTION`` of its sigma. The rule changes the outputs where it cuts a round; this script says
by how much: each orientation parameter and each object point of the ``new`` at/ against the ``old`` one, in the
sigma the old one reports (at/eo.txt, at/object_points.csv), and the key figures of both reports (sigma0,
iterations, the verdict line, check-point RMS, observations removed, surface points used).

    python bench/eval_adjust_rounds.py compare OLD_AT NEW_AT [--label demo] [--out bench/results/adjust_rounds.json]

The ``old`` result is the same code with the rule off (``GATE_CHANGE_SHARE = UPDATE_SIGMA_FRACTION = 0``: every
change of the gate starts another round, as before):

    python bench/eval_adjust_rounds.py adjust PROJECT [--old] [--dem DEM]

runs ``aerotri adjust PROJECT --no-exports`` in this process with the rule on, or off with ``--old``.

    python bench/eval_adjust_rounds.py pair A B [--pythonpath-a MAIN_SRC] [--dem-name dem.tif] [--label L] [--out J]

runs ``aerotri adjust`` on two copies of one project at the same time under ``/usr/bin/time -v`` (the same load
for both): A with another source tree (``--pythonpath-a``, e.g. main's), B with this one; records their CPU,
wall and peak memory and the comparison of their outputs under ``L`` in ``J``.

    python bench/eval_adjust_rounds.py timings LOG [LOG ...]

prints wall, CPU and peak memory of ``/usr/bin/time -v`` logs (runs made by hand).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _eo(path: Path):
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    ids = [r[0] for r in rows]
    a = np.array([[float(x) for x in r[1:13]] for r in rows])
    return ids, a[:, :6], a[:, 6:12]


def _points(path: Path):
    import csv

    with path.open() as f:
        rows = list(csv.DictReader(f))
    ids = [r["id"] for r in rows]
    xyz = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])
    sig = np.array([[float(r["sx_m"] or "nan"), float(r["sy_m"] or "nan"), float(r["sz_m"] or "nan")] for r in rows])
    return ids, xyz, sig


def _report(path: Path) -> dict:
    rep = json.loads(path.read_text())
    k = rep["key_statistics"]
    sc = rep.get("surface_control") or {}
    return {"sigma0_um": k.get("sigma0_um"), "iterations": k.get("iterations"), "message": k.get("message"),
            "success": k.get("success"), "weak_geometry": k.get("weak_geometry"),
            "check_rms_m": rep.get("check_rms_m"), "removed_observations": len(rep.get("removed_observations") or []),
            "rejected_control": len(rep.get("rejected_control") or []),
            "surface_used": sc.get("used") if isinstance(sc, dict) else None,
            "timings_s": rep.get("timings_s")}


def _stats(z: np.ndarray) -> dict:
    z = z[np.isfinite(z)]
    return {"max_abs": round(float(np.abs(z).max()), 4) if len(z) else None,
            "rms": round(float(np.sqrt(np.mean(z**2))), 4) if len(z) else None,
            "share_above_0_1": round(float(np.mean(np.abs(z) > 0.1)), 5) if len(z) else None}


def compare(old_at: Path, new_at: Path) -> dict:
    """The new result against the old one in the old one's sigmas."""
    ids_o, eo_o, sig_o = _eo(old_at / "eo.txt")
    ids_n, eo_n, _ = _eo(new_at / "eo.txt")
    k = {i: n for n, i in enumerate(ids_n)}
    both = [n for n, i in enumerate(ids_o) if i in k]
    d = eo_n[[k[ids_o[n]] for n in both]] - eo_o[both]
    d[:, 3:] = (d[:, 3:] + 180.0) % 360.0 - 180.0
    z = d / sig_o[both]
    names = ["X", "Y", "Z", "omega", "phi", "kappa"]
    out = {"frames": len(both), "orientation_diff_in_sigma": {n: _stats(z[:, c]) for c, n in enumerate(names)}}
    pid_o, p_o, ps_o = _points(old_at / "object_points.csv")
    pid_n, p_n, _ = _points(new_at / "object_points.csv")
    kp = {i: n for n, i in enumerate(pid_n)}
    common = [n for n, i in enumerate(pid_o) if i in kp]
    zp = (p_n[[kp[pid_o[n]] for n in common]] - p_o[common]) / ps_o[common]
    out["points"] = {"old": len(pid_o), "new": len(pid_n), "common": len(common),
                     "diff_in_sigma": {a: _stats(zp[:, c]) for c, a in enumerate("XYZ")}}
    out["old_report"], out["new_report"] = _report(old_at / "report.json"), _report(new_at / "report.json")
    return out


def record(out: Path, label: str, entry: dict) -> None:
    doc = json.loads(out.read_text()) if out.exists() else {}
    doc[label] = entry
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(out)


def _time_v(log_text: str) -> dict:
    sys.path.insert(0, str(Path(__file__).parent))
    from adjust_scale import _time_v as parse

    return parse(log_text)


def pair(a: Path, b: Path, pythonpath_a: str | None, dem_name: str | None, logs: list | None = None) -> dict:
    """``aerotri adjust`` on ``a`` (source tree ``pythonpath_a``) and ``b`` (this tree) at the same time; ``logs``:
    the ``/usr/bin/time -v`` logs of two such runs made already (their outputs in ``a`` and ``b``), read instead."""
    import threading

    sys.path.insert(0, str(Path(__file__).parent))
    from adjust_scale import _aerotri

    if logs:
        res = {k: _time_v(Path(log).read_text()) for k, log in zip(("a", "b"), logs)}
        res["compare"] = compare(a / "at", b / "at")
        return res
    out = {}

    def run(key, root, pp):
        args = ["adjust", str(root), "--no-exports"] + (["--dem", str(root / dem_name)] if dem_name else [])
        out[key] = _aerotri(args, pp)

    threads = [threading.Thread(target=run, args=("a", a, pythonpath_a)), threading.Thread(target=run, args=("b", b, None))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    res = {k: {f: out[k][f] for f in ("wall_s", "cpu_s", "user_s", "system_s", "peak_rss_mb", "load_average_1min")}
           for k in ("a", "b")}
    res["compare"] = compare(a / "at", b / "at")
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("compare")
    c.add_argument("old_at", type=Path)
    c.add_argument("new_at", type=Path)
    c.add_argument("--label", default="block")
    c.add_argument("--out", type=Path, default=None)
    r = sub.add_parser("adjust")
    r.add_argument("project", type=Path)
    r.add_argument("--old", action="store_true")
    r.add_argument("--dem", default=None)
    pa = sub.add_parser("pair")
    pa.add_argument("a", type=Path)
    pa.add_argument("b", type=Path)
    pa.add_argument("--pythonpath-a", default=None)
    pa.add_argument("--dem-name", default=None)
    pa.add_argument("--label", default="pair")
    pa.add_argument("--out", type=Path, default=None)
    pa.add_argument("--from-logs", type=Path, nargs=2, default=None, help="time -v logs of runs of A and B made already")
    pa.add_argument("--note", default=None, help="what A and B are (recorded with the result)")
    tv = sub.add_parser("timings")
    tv.add_argument("logs", type=Path, nargs="+")
    a = ap.parse_args(argv)
    if a.cmd == "timings":
        for log in a.logs:
            print(log, json.dumps(_time_v(log.read_text())))
        return None
    if a.cmd == "pair":
        res = pair(a.a, a.b, a.pythonpath_a, a.dem_name, a.from_logs)
        if a.note:
            res = {"what": a.note, **res}
        print(json.dumps(res, indent=1))
        if a.out:
            record(a.out, a.label, res)
        return None
    if a.cmd == "adjust":
        import aerotri.adjust.solve as solve
        from aerotri.cli import main as cli

        if a.old:
            solve.GATE_CHANGE_SHARE = solve.UPDATE_SIGMA_FRACTION = 0.0
        sys.argv = ["aerotri", "adjust", str(a.project), "--no-exports"] + (["--dem", a.dem] if a.dem else [])
        return cli()
    res = compare(a.old_at, a.new_at)
    print(json.dumps(res, indent=1))
    if a.out:
        record(a.out, a.label, res)


if __name__ == "__main__":
    sys.exit(main())
