"""at-noout: the AT verdict on blocks with no control height left out by the data snooping (the height-datum check
did not run: ``height_datum_check`` returned None) and with one out (not judged by the kept heights' reliability):
"Solution Successful" while nothing checks the heights?

Blocks: review 22's 3 x 6 DMC block at 1,000 m over 120 m of relief (``geometric_block``, the layouts of
bench/eval_at_reliability.py and eval_at_verdicts.py), 0.08 m GNSS strip shifts (gnss_shift_sigma_m 0.1, the
default) or 0.3 m (gnss_shift_sigma_m 0.5, review 32's), corrected by ``none``, ``offset``, ``shift`` or
``shift_drift``; control: 3 height-only points and 2 plan-only (``h3``), 3 full (``f3``), 6 full (``f6``), 12 full
(``f12``); the control heights as surveyed (``clean``), the one farthest from gcp01 typed 2-3 m off (``typo1``, sign
and size from the seed), or the 2 farthest typed 2 / 2.4 m the same way (``typo2``). 20 check points measure the
truth (their height RMS) and are dropped for the verdict (the rule is for blocks without check points). Recorded per
block: the points left out, the true RMS Z, the verdict before (the code at main: no height-datum check with nothing
out, one out not judged by the kept heights' MDB), after (this code) and without the height-datum check, each kept
height's redundancy and Baarda MDB (``HeightDatumCheck.kept_mdb_m``) and the worst pairs' MDB. The rule for none or
one out is scored for factors ``f`` (weak when some kept height's MDB exceeds f times the limit; the code's is
``ALONE_MDB_FACTOR`` 2): seeds 0-5 (``design``) chose it, 6-13 (``scored``) score it.

Writes bench/results/at_noout.json. Run: nice .venv/bin/python bench/eval_at_noout.py (1,344 blocks, about 20 min
on a loaded 2-core machine; ``--seeds 0-6 --out A.json``, ``--seeds 7-13 --out B.json``, then ``--merge A.json
B.json`` to split it)."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from aerotri.adjust.height_datum import HeightDatumCheck
from aerotri.adjust.report import build_report
from aerotri.core.records import to_record

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_at_reliability import _Holds, adjusted_block  # noqa: E402

DESIGN, SCORED = range(0, 6), range(6, 14)
LIMIT_Z_M = 1.0  # the simulated project's height RMS limit (1:5000 flat)
# control layouts: the points' kinds in the simulator's spread order (gcp01, gcp02, ...)
CONTROLS = {"h3": ("horizontal",) * 2 + ("height",) * 3, "f3": ("full",) * 3, "f6": ("full",) * 6,
            "f12": ("full",) * 12}
CORRECTIONS = ("none", "offset", "shift", "shift_drift")
TYPOS = ("clean", "typo1", "typo2")
FACTORS = (1.0, 1.5, 2.0, 3.0, 5.0, 10.0, 30.0)


class _Main(HeightDatumCheck):
    """The check on main before at-noout: one height out not judged by the kept heights' MDB (with none out the
    check did not run: None)."""

    def judges_alone(self) -> bool:
        return False


def _verdict_with(ba, hd_new) -> str:
    hd = ba.result.height_datum
    ba.result = dataclasses.replace(ba.result, height_datum=hd_new)
    try:
        return to_record(build_report(ba))["key_statistics"]["verdict"]
    finally:
        ba.result = dataclasses.replace(ba.result, height_datum=hd)


def run(seed: int, control: str, correction: str, typo: str, shift_sigma_m: float, tmp: Path) -> dict:
    kinds = CONTROLS[control]

    def edit(head, gcp):
        for r, kind in zip(gcp, kinds):
            r[head.index("kind")] = kind
        gcp = [r for r in gcp if r[head.index("kind")] != "horizontal"]  # the heights
        xy = np.array([[float(r[head.index("x")]), float(r[head.index("y")])] for r in gcp])
        far = np.argsort(-np.hypot(*(xy - xy[0]).T))
        rng = np.random.default_rng(seed + 500)
        typed = []
        if typo == "typo1":
            i = far[0]
            z = float(gcp[i][head.index("z")]) + rng.choice([-1, 1]) * rng.uniform(2, 3)
            gcp[i][head.index("z")] = f"{z:.4f}"
            typed.append(gcp[i][head.index("id")])
        elif typo == "typo2":
            for k, i in enumerate(far[:2]):
                gcp[i][head.index("z")] = f"{float(gcp[i][head.index('z')]) + 2.0 * (1 + 0.2 * k):.4f}"
                typed.append(gcp[i][head.index("id")])
        return typed

    ba, typed, dz = adjusted_block(seed, len(kinds), shift_sigma_m, correction, tmp, edit)
    hd = ba.result.height_datum
    out = sorted(str(ba.control.id[c]) for c, _ in ba.result.rejected_control)
    fields = None if hd is None else {f.name: getattr(hd, f.name) for f in dataclasses.fields(hd)}
    holds = None if hd is None else _Holds(**fields)
    before = _verdict_with(ba, None if hd is None or not hd.height_control_out else _Main(**fields))
    rec = to_record(build_report(ba))["key_statistics"]
    return {"seed": seed, "control": control, "correction": correction, "typo": typo,
            "gnss_shift_sigma_m": shift_sigma_m, "typed": typed,
            "left_out": out, "height_out": 0 if hd is None else len(hd.height_control_out),
            "true_rms_z_m": round(float(np.sqrt(np.mean(dz**2))), 4),
            "verdict_before": before, "verdict_after": rec["verdict"],
            "verdict_without_check": _verdict_with(ba, holds),
            "check": None if hd is None else {
                "held_else": bool(hd.mdb_m <= LIMIT_Z_M and not hd.disagrees()
                                  and not hd.strips_not_held(LIMIT_Z_M)),
                "strips_not_held": [[s, round(m, 3)] for s, m in hd.strips_not_held(LIMIT_Z_M)],
                "kept": [[i, round(r, 4), round(m, 3) if math.isfinite(m) else None] for i, r, m in hd.kept_mdb_m],
                "worst_pairs": [[a, b, s, round(m, 3) if math.isfinite(m) else None] for a, b, s, m in
                                hd.pair_mdb_m[:3]]}}


def verdict_at(r: dict, factor: float, max_out: int = 0) -> str:
    """The verdict with the kept heights' MDB judged against ``factor`` times the limit when at most ``max_out``
    control heights are out (more: the code's verdict), under any correction."""
    c = r["check"]
    if c is None or r["verdict_without_check"] != "successful" or r["height_out"] > max_out:
        return r["verdict_after"] if r["height_out"] > max_out else r["verdict_without_check"]
    bad = any(m is None or m > factor * LIMIT_Z_M for _, _, m in c["kept"])
    return "weak" if bad or not c["held_else"] else "successful"


def score(rows: list[dict], key) -> dict:
    """Per control layout: runs, true RMS Z over the limit, false weak (weak within it), silent successful (over it),
    and weak over it."""
    out = {}
    for ctl in (*CONTROLS, "all"):
        rs = [r for r in rows if ctl in ("all", r["control"])]
        over = [r["true_rms_z_m"] > LIMIT_Z_M for r in rs]
        v = [key(r) for r in rs]
        out[ctl] = {"runs": len(rs), "over_limit": sum(over),
                    "false_weak": sum(x == "weak" and not o for x, o in zip(v, over)),
                    "silent_successful": sum(x == "successful" and o for x, o in zip(v, over)),
                    "weak_over_limit": sum(x == "weak" and o for x, o in zip(v, over)),
                    "weak": sum(x == "weak" for x in v)}
    return out


def summarise(rows: list[dict]) -> dict:
    res = {}
    for part, ss in (("design", DESIGN), ("scored", SCORED)):
        rs = [r for r in rows if r["seed"] in ss]
        if not rs:
            continue
        res[part] = {"before (main)": score(rs, lambda r: r["verdict_before"]),
                     "after (code)": score(rs, lambda r: r["verdict_after"]),
                     **{f"nothing out: MDB > {f:g} x limit": score(rs, lambda r, f=f: verdict_at(r, f))
                        for f in FACTORS},
                     **{f"one out too: MDB > {f:g} x limit": score(rs, lambda r, f=f: verdict_at(r, f, 1))
                        for f in FACTORS}}
    return {"limit_z_m": LIMIT_Z_M, "seeds": sorted({r["seed"] for r in rows}), "score": res, "runs": rows}


def _write(path: Path, out: dict) -> None:
    """``out`` as JSON, its runs one a line (1,344 of them)."""
    head = json.dumps({k: v for k, v in out.items() if k != "runs"}, indent=1)[:-2]
    runs = ",\n".join(json.dumps(r) for r in out["runs"])
    tmp_path = path.with_suffix(".json.tmp")
    tmp_path.write_text(f'{head},\n "runs": [\n{runs}\n ]\n}}\n')
    tmp_path.replace(path)


def main() -> None:
    """``--seeds A-B`` those seeds only; ``--out FILE`` there instead; ``--merge FILE ...`` the runs of several."""
    logging.disable(logging.WARNING)
    argv = sys.argv[1:]
    path = Path(argv[argv.index("--out") + 1]) if "--out" in argv else (
        Path(__file__).resolve().parent / "results" / "at_noout.json")
    if "--merge" in argv:
        rows = [r for f in argv[argv.index("--merge") + 1:] for r in json.loads(Path(f).read_text())["runs"]]
        out = summarise(sorted(rows, key=lambda r: r["seed"]))
        _write(path, out)
        print(json.dumps(out["score"], indent=1))
        return
    seeds = [*DESIGN, *SCORED]
    if "--seeds" in argv:
        a, b = argv[argv.index("--seeds") + 1].split("-")
        seeds = list(range(int(a), int(b) + 1))
    tmp = Path(tempfile.gettempdir())
    rows = []
    for seed in seeds:
        for control in CONTROLS:
            for correction in CORRECTIONS:
                for typo in TYPOS:
                    for shift_sigma_m in (0.1, 0.5):
                        r = run(seed, control, correction, typo, shift_sigma_m, tmp)
                        rows.append(r)
                        print(json.dumps({k: r[k] for k in ("seed", "control", "correction", "typo",
                                                             "gnss_shift_sigma_m", "left_out", "true_rms_z_m",
                                                             "verdict_before", "verdict_after")}),
                              r["check"] and [m for *_, m in r["check"]["kept"]], flush=True)
    out = summarise(rows)
    _write(path, out)
    print(json.dumps(out["score"], indent=1))


if __name__ == "__main__":
    main()
