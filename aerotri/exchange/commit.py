"""All of a set of files written, or none: the one place where imports and exports put their files on disk.

The files are written through ``aerotri.core.atomic`` as one commit (``commit_outputs``): inside a command's
own commit (every ``aerotri`` command over a project holds one) they join it; otherwise they make their own
over the nearest existing folder that holds them all. Either way the folder holds the old set or the new
set, never a mix, and a killed run's leftovers are rolled back by the next command.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from aerotri.core.atomic import atomic_path, commit_outputs
from aerotri.core.errors import InputError


@dataclasses.dataclass(frozen=True)
class ExportFile:
    """One file of an export: its path relative to the output folder and its content (text or bytes)."""

    path: str
    content: str | bytes


def _existing_folder(paths: list[Path]) -> Path:
    """The nearest existing folder holding every path (the commit's base: its journal is made there)."""
    base = Path(os.path.commonpath([os.path.abspath(p.parent) for p in paths]))
    while not base.is_dir():
        base = base.parent
    return base


def write_together(contents: dict) -> list[Path]:
    """Write ``{path: text (str) or bytes}`` all or none (see the module docstring); returns the paths."""
    paths = [Path(p) for p in contents]
    for path in paths:
        if path.is_dir():
            raise InputError(f"{path}: a folder is in the way of the file to write (move it away)")
    if not paths:
        return []
    with commit_outputs(_existing_folder(paths), prune_below=sorted({p.parent for p in paths})):
        for path, content in zip(paths, contents.values()):
            with atomic_path(path) as tmp:
                tmp.write_bytes(content.encode() if isinstance(content, str) else content)
    return paths
