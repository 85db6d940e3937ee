"""One run's figures into a results file under ``bench/results/``: the run under its key, every other key kept.

Benchmarks keep the history of a figure in one JSON file (``{"round6": {...}, "round7": {...}}``); a run
replaces its own key only and the file is written atomically, so an interrupted run leaves the old file.
"""
from __future__ import annotations

import json
from pathlib import Path

from aerotri.core.atomic import write_text_atomic


def read_results(path: Path) -> dict:
    """The results file as a dict; empty when it does not exist yet."""
    path = Path(path)
    return json.loads(path.read_text()) if path.exists() else {}


def store_result(path: Path, value: dict, *, key: str | None = None, section: str | None = None) -> None:
    """Put ``value`` under ``doc[section][key]`` (either level optional; no key: merged into that level)."""
    path = Path(path)
    doc = read_results(path)
    level = doc.setdefault(section, {}) if section else doc
    if key:
        level[key] = value
    else:
        level.update(value)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")
    print(f"wrote {path}" + (f" [{section + '/' if section else ''}{key}]" if key else ""))


def git_commit(repo: Path) -> str:
    """The checkout's HEAD commit, the provenance every result records."""
    import subprocess

    return subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
