"""Resumable stages: the files a stage's tasks finished, kept outside the stage's commit until it commits.

A stage's outputs are one commit (``aerotri.core.atomic``): a Ctrl-C, SIGTERM or SIGKILL rolls back all it
wrote, so a run killed at frame 2,900 of 3,000 would redo 3,000. Inside ``with resumable(folder) as keep:``
each task links what it finished into ``folder`` under a key of everything the file depends on (``resume_key``)
(``keep.keep``; a hard link, no copy, and never journaled); the next run of the stage takes it back
(``keep.take``) instead of computing it. The folder goes when the block ends normally (committed: nothing to
resume) or by an error (bad input, a bad frame: no output of any kind is left); only an interrupt (Ctrl-C,
SIGTERM, which end a command as Ctrl-C does) or a kill leaves it.

Outside a project (``lidarctl classify``, ``lidarctl rasters``) the folder is ``beside(OUTPUT)``: ``OUTPUT.resume``
next to the command's output file or folder.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import shutil
from pathlib import Path

from aerotri.core.atomic import TEMP_MARKER, atomic_path

logger = logging.getLogger(__name__)
RESUME_SUFFIX = ".resume"


def beside(output) -> Path:
    """The resume folder of a command's output file or folder outside a project: ``OUTPUT.resume`` next to it
    (the output's own lock covers it: a second command on the same output is refused)."""
    out = Path(os.path.abspath(output))
    return out.with_name(out.name + RESUME_SUFFIX)


def is_beside(folder, output) -> bool:
    """Whether ``folder`` is ``beside(output)`` (its parent is then the user's folder, not a project's work/)."""
    return Path(os.path.abspath(folder)) == beside(output)


def resume_key(doc) -> str:
    """sha256 (32 hex digits) of a JSON document of what a kept file depends on (include the toolkit's version)."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=repr).encode()).hexdigest()[:32]


def file_stamp(path) -> list[int]:
    """Size and modification time (ns) of a file: what a key holds of an input too large to hash per run."""
    st = os.stat(path)
    return [st.st_size, st.st_mtime_ns]


def link_or_copy(src, dst) -> None:
    """A hard link (no copy of the data) where the file system allows it, else a copy."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def discard_kept(folder) -> None:
    """Start over (``--no-resume``): remove what an interrupted run kept in ``folder``, saying so."""
    folder = Path(folder)
    if folder.is_dir():
        shutil.rmtree(folder)
        logger.info(f"{folder}: what an interrupted run kept there removed (--no-resume)")


@dataclasses.dataclass(frozen=True)
class ResumeFolder:
    """The files kept for a resumed run, ``<key><suffix>`` in ``path`` (picklable: tasks on Dask workers keep
    their own)."""

    path: Path

    def kept(self, key: str, suffix: str) -> Path | None:
        f = self.path / f"{key}{suffix}"
        return f if f.is_file() else None

    def keep(self, src, key: str, suffix: str) -> None:
        """Keep the finished file ``src`` (whole) under ``key``; outside any commit, so that a roll-back of the
        stage leaves it."""
        self.path.mkdir(parents=True, exist_ok=True)
        part = self.path / f".{key}{TEMP_MARKER}keep{suffix}"  # (a kill's is swept by the next command)
        part.unlink(missing_ok=True)
        link_or_copy(src, part)
        os.replace(part, self.path / f"{key}{suffix}")

    def put_text(self, key: str, suffix: str, text: str) -> None:
        """Keep a finished result written as ``text`` under ``key`` (whole or not at all)."""
        self.path.mkdir(parents=True, exist_ok=True)
        part = self.path / f".{key}{TEMP_MARKER}keep{suffix}"
        part.write_text(text)
        os.replace(part, self.path / f"{key}{suffix}")

    def get_text(self, key: str, suffix: str) -> str | None:
        """The text kept under ``key``, None when none is kept."""
        f = self.kept(key, suffix)
        try:
            return f.read_text() if f is not None else None
        except OSError:
            return None

    def take(self, key: str, suffix: str, dst) -> bool:
        """Put the file kept under ``key`` at ``dst`` (atomic, part of the open commit that covers it); False
        when none is kept."""
        src = self.kept(key, suffix)
        if src is None:
            return False
        with atomic_path(dst) as tmp:
            os.unlink(tmp)
            link_or_copy(src, tmp)
        return True


@contextlib.contextmanager
def resumable(folder, *, remove_empty_parent: bool = True):
    """A ``ResumeFolder`` for a stage's block (module docstring): removed when the block ends normally or by an
    error (an ``Exception``), kept when it is interrupted (KeyboardInterrupt, SystemExit) or killed (an interrupt
    says where). After an error the parent folder (``work``) goes too when it is left empty and held nothing else
    before (made by this block or by the interrupted run for the kept files), unless ``remove_empty_parent`` is
    False (a user's output folder)."""
    folder = Path(folder)
    try:
        if remove_empty_parent:
            with os.scandir(folder.parent) as entries:  # closed when any() stops early
                parent_existed = any(e.name != folder.name for e in entries)
        else:
            parent_existed = True
    except OSError:
        parent_existed = False
    try:
        yield ResumeFolder(folder)
    except Exception:
        shutil.rmtree(folder, ignore_errors=True)
        if not parent_existed:
            with contextlib.suppress(OSError):
                folder.parent.rmdir()  # only when empty
        raise
    except BaseException:
        if folder.is_dir():
            logger.info(f"{folder}: what this run finished is kept there; the next run of the same inputs and "
                        "settings resumes it")
        raise
    shutil.rmtree(folder, ignore_errors=True)
