"""The production run: every stage over one project folder, resumable, with a summary at the end.

A stage is skipped when its stamp (``work/stages/<stage>.json``) records the same input files (size
and modification time) and options as now and all its outputs exist; otherwise it runs and writes
its outputs atomically, then its stamp. Killing a run leaves finished stages stamped and the
interrupted stage without a stamp and without partial outputs, so a re-run continues there.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path

from lidarctl.atomic import write_text_atomic


@dataclasses.dataclass
class Stage:
    name: str
    inputs: Callable[[Path], list[Path]]  # files whose change re-runs the stage
    outputs: Callable[[Path], list[Path]]  # files the stage must leave behind
    run: Callable[[Path], dict]  # does the work, returns key numbers for the summary
    options: dict = dataclasses.field(default_factory=dict)


def _signature(paths: list[Path]) -> dict:
    sig = {}
    for p in sorted(paths, key=str):
        if p.is_file():
            st = p.stat()
            sig[str(p)] = [st.st_size, st.st_mtime_ns]
        else:
            sig[str(p)] = None
    return sig


def stamp_path(root: Path, stage: str) -> Path:
    return root / "work" / "stages" / f"{stage}.json"


def is_current(root: Path, st: Stage) -> bool:
    sp = stamp_path(root, st.name)
    if not sp.exists():
        return False
    try:
        stamp = json.loads(sp.read_text())
    except json.JSONDecodeError:
        return False
    if not all(p.exists() for p in st.outputs(root)):
        return False
    return stamp.get("inputs") == _signature(st.inputs(root)) and stamp.get("options") == st.options


def run_stages(root, stages: list[Stage], force: bool = False, log=print) -> list[dict]:
    """Run (or skip) the stages in order; returns one summary row per stage."""
    root = Path(root)
    rows = []
    for st in stages:
        if not force and is_current(root, st):
            stamp = json.loads(stamp_path(root, st.name).read_text())
            rows.append(dict(stage=st.name, status="skipped (up to date)", seconds=0.0, **stamp.get("result", {})))
            log(f"[{st.name}] up to date, skipped")
            continue
        log(f"[{st.name}] running")
        t = time.perf_counter()
        result = st.run(root) or {}
        dt = time.perf_counter() - t
        missing = [str(p) for p in st.outputs(root) if not p.exists()]
        if missing:
            raise RuntimeError(f"stage {st.name} finished without writing {', '.join(missing)}")
        write_text_atomic(stamp_path(root, st.name), json.dumps(
            dict(inputs=_signature(st.inputs(root)), options=st.options, result=result, seconds=round(dt, 2)),
            indent=1, default=str) + "\n")
        rows.append(dict(stage=st.name, status="done", seconds=round(dt, 1), **result))
        log(f"[{st.name}] done in {dt:.1f} s")
    return rows


def format_summary(rows: list[dict]) -> str:
    lines = [f"{'stage':<18} {'status':<22} {'time s':>7}  key numbers"]
    for r in rows:
        extra = "  ".join(f"{k}={_fmt(v)}" for k, v in r.items() if k not in ("stage", "status", "seconds"))
        lines.append(f"{r['stage']:<18} {r['status']:<22} {r['seconds']:>7.1f}  {extra}")
    return "\n".join(lines)


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)
