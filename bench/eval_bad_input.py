"""Run the bad-input corpus of ``tests/test_bad_input.py`` and classify every case (issue 39, item 10).

Each case copies the workspace the tests build (the simulator's ``tiny`` project with every stage's outputs,
small LAS/LAZ files, strips, rasters, a line map), breaks one input, runs the command in-process (click's
``CliRunner``) with a time limit and puts it in one class:

- ``pass``: exit code 2, one ``Error:`` line naming what the case expects, nothing written or changed;
- ``traceback``: an exception other than ``SystemExit`` escaped the command;
- ``silent``: exit code 0 (the bad input was accepted without a word);
- ``hang``: still running after ``--timeout`` seconds;
- ``unclear``: exit code 2 but the message does not name the file/option the case expects, or several lines;
- ``partial``: exit code 2 but files were written, changed or removed;
- ``other``: any other exit code.

The accepted-input cases (``ACCEPTED``: unusual but valid inputs, e.g. a DEM in US feet) pass with exit 0.
``EXCHANGE_CASES`` (imports, whose checks another task of issue 39 owns) are run and reported, kind "exchange".

    .venv/bin/python bench/eval_bad_input.py [--workspace DIR] [--json bench/results/bad_input_issue39.json] [-k WORD]

``--workspace``: reuse (or build once into) this folder instead of a temporary one.

The same corpus on the code before the fixes (bench/results/bad_input_issue39_before.json): a worktree of that
commit with this script and tests/test_bad_input.py copied in, run with it first on the path:

    git worktree add --detach /tmp/before b9c55f7
    cp tests/test_bad_input.py /tmp/before/tests/; cp bench/eval_bad_input.py /tmp/before/bench/
    cd /tmp/before && PYTHONPATH=$PWD /path/to/.venv/bin/python bench/eval_bad_input.py --json before.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _load_tests():
    spec = importlib.util.spec_from_file_location("test_bad_input", REPO / "tests" / "test_bad_input.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["test_bad_input"] = mod
    spec.loader.exec_module(mod)
    return mod


def classify(tbi, case, workspace: Path, tmp: Path, timeout_s: float, accepted: bool = False) -> tuple[str, str]:
    w = tbi.prepare(case, workspace, tmp)
    before = tbi.snapshot(w)
    try:
        r = tbi.invoke(case, w, timeout_s)
    except tbi.Hang:
        return "hang", f"> {timeout_s:.0f} s"
    stderr = r.stderr
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        return "traceback", f"{type(r.exception).__name__}: {str(r.exception)[:300]}"
    if accepted:
        return ("pass", "") if r.exit_code == 0 else ("refused", stderr.strip()[:300])
    if r.exit_code == 0:
        return "silent", (r.stdout or "").strip().splitlines()[-1][:300] if (r.stdout or "").strip() else ""
    if r.exit_code != 2:
        return "other", f"exit {r.exit_code}: {stderr.strip()[:300]}"
    try:
        tbi.check_failure(case, w, before, r.exit_code, stderr, r.exception)
    except AssertionError as exc:
        msg = str(exc).splitlines()[0][:300]
        return ("partial" if "files written" in msg else "unclear"), f"{msg} | {stderr.strip()[:300]}"
    return "pass", stderr.strip()[:300]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workspace", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("-k", default=None, help="only cases whose id contains this")
    a = ap.parse_args()
    tbi = _load_tests()
    tmp_root = Path(tempfile.mkdtemp(prefix="badinput-"))
    try:
        ws = a.workspace
        if ws is None or not (ws / "p").is_dir():
            from aerotri.sim import load_preset, simulate

            tiny = tmp_root / "tiny"
            simulate(load_preset("tiny"), tiny)
            ws = ws or tmp_root / "ws"
            if ws.exists():
                shutil.rmtree(ws)
            tbi.build_workspace(tiny, ws)
        rows = []
        groups = ([("bad", c, False) for c in tbi.CASES] + [("accepted", c, True) for c in tbi.ACCEPTED]
                  + [("exchange", c, False) for c in tbi.EXCHANGE_CASES])
        for kind, case, accepted in groups:
            if a.k and a.k not in case.id:
                continue
            tmp = Path(tempfile.mkdtemp(dir=tmp_root))
            t0 = time.perf_counter()
            outcome, detail = classify(tbi, case, ws, tmp, a.timeout, accepted)
            detail = detail.replace(str(tmp / "w"), "W")  # the case's workspace copy, not this run's temporary path
            dt = time.perf_counter() - t0
            shutil.rmtree(tmp, ignore_errors=True)
            rows.append(dict(id=case.id, kind=kind, prog=case.prog, command=case.args[0], outcome=outcome,
                             seconds=round(dt, 2), detail=detail))
            print(f"{outcome:9s} {dt:6.1f}s {case.id}: {detail[:200]}", flush=True)
        counts = Counter(r["outcome"] for r in rows)
        print("\n" + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + f" of {len(rows)} cases")
        if a.json:
            a.json.parent.mkdir(parents=True, exist_ok=True)
            a.json.write_text(json.dumps(dict(cases=len(rows), counts=dict(counts), rows=rows), indent=1) + "\n")
        return 0
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
