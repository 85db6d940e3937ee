"""Atomic output: single files and folders written under a temporary name, and the outputs of a whole
command or stage committed together (all new or all old).

One file or folder
    ``atomic_path`` / ``write_text_atomic`` / ``atomic_dir`` write to a temporary next to the output and
    rename it onto the output only if the block succeeds. Every temporary these helpers make is named
    ``.<name>.part-XXXX[suffix]`` (``TEMP_MARKER``), so what a killed process left behind can be found
    and swept (``remove_leftovers``).

Many files: ``commit_outputs(folder)``
    Inside ``with commit_outputs(folder):`` every output written below ``folder`` by the helpers above
    (and by ``move_into`` / ``remove_output``) belongs to one commit, kept in an undo journal:
    before a file or folder is replaced, its old version is kept (a hard link to the file, or the folder
    renamed) in ``folder/.<label>.commit-XXXX/`` and a line naming it goes into the journal there. The
    new version is in place at once, so later steps of the same command read it. When the block ends:

    - normally: the journal is deleted (the commit point) and the kept old versions with it;
    - by an exception (an error, disk full, Ctrl-C, SIGTERM): every output the block wrote is put back
      as it was (replaced ones restored, new ones removed, folders it created removed when empty),
      then the exception goes on: the folder holds all old files;
    - by a kill (SIGKILL, power cut of the process): the journal stays; the next command that writes
      there (``recover_commits``, which ``remove_leftovers`` and every command's start call) rolls it
      back the same way. A journal whose process is still alive is never touched (it holds an
      ``flock`` on it while it lives).

    Commits nest: an inner ``commit_outputs`` over a folder an open commit covers joins it (``join``),
    so a stage's own commit becomes part of its command's; ``join=False`` makes a separate commit that
    is final when its block ends (the resumable chain commits stage by stage). Writes of other threads
    of the process belong to the commit too; writes in other processes (Dask worker processes) do not
    (they stay atomic per file). Temporaries (paths with ``.part-`` in a component) are never journaled.

Paths are compared after resolving links of their folders. Nothing is fsynced: the guarantees hold
for a killed process, not for a power cut of the machine.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

from aerotri.core.errors import OptionError

log = logging.getLogger(__name__)


TEMP_MARKER = ".part-"
# the work folders an output may have beside it, ``.<name or stem>.<word>.part-*`` (lidarctl.tiles, roof corners)
WORK_FOLDER_WORDS = ("tiles", "corners")
COMMIT_MARKER = ".commit-"
_JOURNAL = "journal"
_OLD = "old"

# errno values of a failed write that are about the place written to, not the program
DISK_ERRNOS = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded",
               errno.EFBIG: "file too large for the file system (or the process's file size limit)",
               errno.EROFS: "read-only file system", errno.EACCES: "permission denied",
               errno.EPERM: "operation not permitted", errno.EIO: "input/output error"}


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _annotate(exc: BaseException, path) -> None:
    """Name the output ``path`` in an error of a failed write: an OSError without a file name (a write() on an
    open file) or with a temporary's name gets the output's; any other exception (GDAL's through rasterio, an
    OSError without a disk errno such as rasterio's "Write failed") carries it as ``aerotri_output`` (the
    command's handler names it when the error is a full disk)."""
    if isinstance(exc, OSError) and exc.errno in DISK_ERRNOS:
        if exc.filename is None or any(m in os.fspath(exc.filename) for m in (TEMP_MARKER, COMMIT_MARKER)):
            exc.filename = str(path)
    elif getattr(exc, "aerotri_output", None) is None:  # (rasterio's RasterioIOError is an OSError without errno)
        try:
            exc.aerotri_output = str(path)
        except (AttributeError, TypeError):
            pass


def annotate_output(exc: BaseException, path) -> None:
    """Name the output ``path`` in ``exc``, a failed write of it made outside ``atomic_path`` (a work folder's files:
    the mosaic's rows and overviews), as ``atomic_path`` does (``_annotate``)."""
    _annotate(exc, path)


# ------------------------------------------------------------------------------------------------
# Commits


_LOCK = threading.RLock()
_OPEN: list["_Commit"] = []  # open commits of this process, innermost last


def _real(path) -> str:
    """``path`` absolute with the links of its folder resolved (the last component kept as it is)."""
    p = os.path.abspath(os.fspath(path))
    head, tail = os.path.split(p)
    return os.path.join(os.path.realpath(head), tail) if tail else os.path.realpath(p)


def _remove(path: str) -> None:
    if os.path.isdir(path) and not os.path.islink(path):
        shutil.rmtree(path)
    elif os.path.lexists(path):
        os.unlink(path)


def _dirs_below(base: str, depth: int) -> list[str]:
    """Folders below ``base`` down to ``depth`` levels (relative names), for pruning the ones a rolled back
    commit created."""
    out, level = [], [""]
    for _ in range(depth):
        nxt = []
        for rel in level:
            try:
                with os.scandir(os.path.join(base, rel)) as it:
                    for e in it:
                        if e.is_dir(follow_symlinks=False) and TEMP_MARKER not in e.name and COMMIT_MARKER not in e.name:
                            nxt.append(os.path.join(rel, e.name))
            except OSError:
                continue
        out += nxt
        level = nxt
    return out


class _Commit:
    """The undo journal of one commit over ``base`` (see the module docstring)."""

    def __init__(self, base, label: str = "aerotri", prune_below=None):
        self.base = _real(base)
        self.label = label
        # where a roll-back may remove new empty folders the block made (not only those above its outputs)
        self.prune_below = [os.path.relpath(_real(p), self.base) for p in (prune_below or [base])]
        self.dir: str | None = None  # made at the first journaled write
        self.fd: int | None = None
        self.journal = None
        self.entries: list[dict] = []
        self.touched: dict[str, dict] = {}  # rel -> its first entry
        self.dirs_before = set(_dirs_below(self.base, 2)) if os.path.isdir(self.base) else set()
        self.base_existed = os.path.isdir(self.base)

    # -- what it covers
    def rel(self, path) -> str | None:
        p = _real(path)
        if p == self.base or not p.startswith(self.base.rstrip(os.sep) + os.sep):
            return None
        rel = os.path.relpath(p, self.base)
        if any(TEMP_MARKER in part or COMMIT_MARKER in part for part in rel.split(os.sep)):
            return None
        return rel

    # -- the journal
    def _open_journal(self) -> None:
        if self.dir is not None:
            return
        os.makedirs(self.base, exist_ok=True)
        self.dir = tempfile.mkdtemp(prefix=f".{self.label}{COMMIT_MARKER}", dir=self.base)
        path = os.path.join(self.dir, _JOURNAL)
        self.fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        import fcntl

        fcntl.flock(self.fd, fcntl.LOCK_EX)
        self.journal = os.fdopen(os.dup(self.fd), "w", encoding="utf-8")
        header = {"base": self.base, "pid": os.getpid(), "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                  "dirs_before": sorted(self.dirs_before), "base_existed": self.base_existed}
        self.journal.write(json.dumps(header) + "\n")
        self.journal.flush()
        os.mkdir(os.path.join(self.dir, _OLD))

    def _covered_by_earlier(self, rel: str) -> bool:
        """An earlier entry of this commit restores ``rel`` already (the same path, or a folder above it
        that the commit replaced or created)."""
        if rel in self.touched:
            return True
        parts = rel.split(os.sep)
        for k in range(1, len(parts)):
            e = self.touched.get(os.sep.join(parts[:k]))
            if e is not None and (e["kind"] == "dir" or not e["existed"]):
                return True
        return False

    def record(self, rel: str, kind: str) -> dict | None:
        """Journal ``rel`` before it changes; returns the new entry (None when an earlier one covers it)."""
        if self._covered_by_earlier(rel):
            return None
        self._open_journal()
        target = os.path.join(self.base, rel)
        entry = {"n": len(self.entries), "rel": rel, "kind": kind, "existed": os.path.lexists(target)}
        self.journal.write(json.dumps(entry) + "\n")
        self.journal.flush()
        self.entries.append(entry)
        self.touched[rel] = entry
        return entry

    def backup_path(self, entry: dict) -> str:
        return os.path.join(self.dir, _OLD, str(entry["n"]))

    # -- the changes
    def replace(self, src, dst, kind: str) -> None:
        """``os.replace(src, dst)`` with the old ``dst`` kept for a roll-back (``kind``: file or dir)."""
        rel = self.rel(dst)
        entry = self.record(rel, kind)
        target = os.path.join(self.base, rel)
        if entry is not None and entry["existed"]:
            backup = self.backup_path(entry)
            if kind == "file" and not os.path.isdir(target):
                try:
                    os.link(target, backup, follow_symlinks=False)
                except OSError:
                    os.replace(target, backup)
            else:
                os.replace(target, backup)
        elif os.path.isdir(target) and not os.path.islink(target) and kind == "dir":
            shutil.rmtree(target)  # an earlier step of this commit made it: the new one replaces it
        os.replace(src, dst)

    def remove(self, path) -> None:
        rel = self.rel(path)
        target = os.path.join(self.base, rel)
        if not os.path.lexists(target):
            return
        entry = self.record(rel, "remove")
        if entry is not None:
            os.replace(target, self.backup_path(entry))
        else:
            _remove(target)

    # -- the end
    def commit(self) -> None:
        if self.dir is None:
            return
        self.journal.close()
        os.unlink(os.path.join(self.dir, _JOURNAL))  # the commit point
        os.close(self.fd)
        shutil.rmtree(self.dir, ignore_errors=True)
        self.dir = None

    def rollback(self) -> list[str]:
        """Undo this commit's changes. If that fails too (the disk gone), the journal stays for the next run."""
        if self.dir is None:
            return []
        self.journal.close()
        try:
            restored = _roll_back(self.dir, self.base, self.entries, self.dirs_before, self.base_existed,
                                  prune_below=self.prune_below)
        except OSError as exc:
            import logging

            logging.getLogger(__name__).warning(f"{self.base}: could not undo the outputs of this run ({exc}); the next "
                                                "command that writes there will")
            return []
        os.close(self.fd)
        self.dir = None
        return restored


def _roll_back(cdir: str, base: str, entries: list[dict], dirs_before: set, base_existed: bool,
               prune_below=()) -> list[str]:
    """Undo ``entries`` (newest first), remove the folders the commit made when empty (above the entries;
    ``prune_below``: also any new folder up to two levels below ``base`` that is at or below one of these
    relative names), then the journal."""
    done = []
    for e in reversed(entries):
        target = os.path.join(base, e["rel"])
        backup = os.path.join(cdir, _OLD, str(e["n"]))
        if os.path.lexists(backup):
            _remove(target)
            os.makedirs(os.path.dirname(target), exist_ok=True)
            os.replace(backup, target)
            done.append(e["rel"])
        elif not e["existed"] and os.path.lexists(target):
            _remove(target)
            done.append(e["rel"])
    # folders made since the commit began: above the entries, and any new empty one near the base
    def pruned(rel: str) -> bool:
        return any(p == "." or rel == p or rel.startswith(p + os.sep) for p in prune_below)

    candidates = {d for d in set(_dirs_below(base, 2)) - set(dirs_before) if pruned(d)} if prune_below else set()
    for e in entries:
        parts = e["rel"].split(os.sep)[:-1]
        for k in range(len(parts), 0, -1):
            rel = os.sep.join(parts[:k])
            if rel not in dirs_before:
                candidates.add(rel)
    for rel in sorted(candidates, key=lambda r: -r.count(os.sep)):
        d = os.path.join(base, rel)
        if os.path.isdir(d) and not os.path.islink(d) and rel not in dirs_before:
            with contextlib.suppress(OSError):
                os.rmdir(d)  # only when empty
    with contextlib.suppress(FileNotFoundError):
        os.unlink(os.path.join(cdir, _JOURNAL))
    shutil.rmtree(cdir, ignore_errors=True)
    if not base_existed:
        with contextlib.suppress(OSError):
            os.rmdir(base)
    return done


def _covering(path) -> tuple["_Commit", str] | tuple[None, None]:
    """The innermost open commit that covers ``path`` and its relative name."""
    with _LOCK:
        for c in reversed(_OPEN):
            rel = c.rel(path)
            if rel is not None:
                return c, rel
    return None, None


@contextlib.contextmanager
def commit_outputs(folder, join: bool = True, label: str = "aerotri", prune_below=None):
    """Commit everything written below ``folder`` in this block together (module docstring): all new
    when the block ends normally, all old when it raises or the process is killed. ``join``: inside an
    open commit that covers ``folder``, be part of it (the default) instead of a separate commit.
    ``prune_below``: the paths below which a roll-back also removes new empty folders that hold no output
    (default: all of ``folder``; a folder other processes write into too, the system's temporary folder or
    the current one, gets the command's own outputs here)."""
    folder = Path(folder)
    if join:
        c, _ = _covering(folder / "x")
        if c is not None:
            yield c
            return
    c = _Commit(folder, label, prune_below)
    with _LOCK:
        _OPEN.append(c)
    try:
        yield c
    except BaseException:
        with _LOCK:
            _OPEN.remove(c)
            c.rollback()
        raise
    else:
        with _LOCK:
            _OPEN.remove(c)
            c.commit()


def committed(folder_of):
    """Decorator: everything the function writes below ``folder_of(*args, **kwargs)`` is one commit
    (``commit_outputs``; part of the caller's open commit when there is one)."""
    import functools

    def deco(f):
        @functools.wraps(f)
        def wrapper(*args, **kwargs):
            with commit_outputs(folder_of(*args, **kwargs)):
                return f(*args, **kwargs)

        return wrapper

    return deco


def move_into(src, dst) -> None:
    """``os.replace(src, dst)`` as part of the open commit that covers ``dst`` (if any)."""
    with _LOCK:
        c, _ = _covering(dst)
        kind = "dir" if os.path.isdir(src) and not os.path.islink(src) else "file"
        if c is None:
            if kind == "dir" and os.path.isdir(dst):
                _replace_dir_alone(src, dst)
            else:
                os.replace(src, dst)
        else:
            c.replace(src, dst, kind)


def remove_output(path) -> None:
    """Remove an output file or folder (a stale product); part of the open commit that covers it (so a
    roll-back brings it back)."""
    with _LOCK:
        c, _ = _covering(path)
        if c is None:
            _remove(os.fspath(path))
        else:
            c.remove(path)


def _replace_dir_alone(src, dst) -> None:
    """A folder replaced by another outside any open commit: a one-step commit of its parent, so that a
    kill between the two renames is rolled back by the next run, not left without the folder."""
    with commit_outputs(Path(dst).parent, join=False) as c:
        c.replace(src, dst, "dir")


def recover_commits(folder) -> list[str]:
    """Roll back what killed processes left of their commits in ``folder`` (not below it); returns the
    paths restored or removed. Commits of living processes are left alone."""
    import fcntl

    folder = Path(folder)
    if not folder.is_dir():
        return []
    done = []
    for cdir in sorted(folder.glob(f".*{COMMIT_MARKER}*")):
        if not cdir.is_dir():
            continue
        jpath = cdir / _JOURNAL
        if not jpath.exists():
            shutil.rmtree(cdir, ignore_errors=True)  # committed, or never began changing anything
            continue
        try:
            fd = os.open(jpath, os.O_RDWR)
        except FileNotFoundError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                continue  # its process is alive
            lines = Path(jpath).read_text(encoding="utf-8").splitlines()
            try:
                header = json.loads(lines[0])
            except (IndexError, json.JSONDecodeError):
                shutil.rmtree(cdir, ignore_errors=True)  # killed before anything was journaled
                continue
            entries = []
            for s in lines[1:]:
                try:
                    entries.append(json.loads(s))
                except json.JSONDecodeError:
                    break  # a line cut by the kill: its change never began
            done += [str(folder / r) for r in _roll_back(str(cdir), _real(folder), entries,
                                                          set(header.get("dirs_before", [])), True)]
        finally:
            os.close(fd)
    return done


# ------------------------------------------------------------------------------------------------
# Single files and folders


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; move it onto ``path`` only if the block succeeds (as part
    of the open commit that covers ``path``, if any).

    The temporary name keeps the suffix so that libraries choosing a driver by extension work.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}{TEMP_MARKER}", suffix=path.suffix or ".tmp", dir=path.parent)
    except OSError as exc:
        _annotate(exc, path.parent)
        raise
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        # mkstemp creates 0600 files; give the output the permissions of an ordinary new file.
        os.chmod(tmp, 0o666 & ~_umask())
        move_into(tmp, path)
    except Exception as exc:
        _annotate(exc, path)
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


@contextlib.contextmanager
def atomic_dir(path):
    """Yield a temporary folder next to ``path``; it replaces ``path`` only if the block succeeds (as part
    of the open commit that covers ``path``; otherwise as a commit of its own, so that even a kill
    between moving the old folder away and the new one in leaves the old one). ``path`` a link to a folder: the
    folder it points to is replaced (the link stays; replacing the link by a real folder left the old output at
    the target, where whoever made the link looks)."""
    path = Path(path)
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = temporary_dir(path.parent, path.name)
    except OSError as exc:
        _annotate(exc, path.parent)
        raise
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        with _LOCK:
            c, _ = _covering(path)
            if c is not None:
                c.replace(tmp, path, "dir")
            elif path.exists():
                _replace_dir_alone(tmp, path)
            else:
                os.replace(tmp, path)
    except Exception as exc:
        _annotate(exc, path)
        raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def temporary_dir(parent, name: str) -> Path:
    """A new temporary folder ``.<name>.part-XXXX`` in ``parent`` (the caller removes it)."""
    Path(parent).mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{name}{TEMP_MARKER}", dir=parent))


@contextlib.contextmanager
def scratch_dir(parent, name: str):
    """``temporary_dir`` for the duration of a block, removed afterwards."""
    tmp = temporary_dir(parent, name)
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def remove_leftovers(folder, names=None) -> list[Path]:
    """Delete the temporaries a killed process left in ``folder`` (not below it): files and folders named
    ``.<name>.part-*``, after rolling back its unfinished commits there (``recover_commits``). ``names``:
    only the temporaries of these output names (``.<name>.*part-*``, ``.<stem>.*part-*``), for a folder that
    other commands may write into at the same time. Returns what was removed. Only for folders (or names)
    no other process is writing to."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    gone = [Path(p) for p in recover_commits(folder)] if names is None else []
    if names is None:
        found = folder.glob(f".*{TEMP_MARKER}*")
    else:  # .<name>.part-*, .<stem>.part-*, and the work folders named after them (.<stem>.tiles.part-*)
        # by whole names: a stem's prefix alone (".ortho.") would take the live temporaries of another output
        # written at the same time (".ortho.v2.part-*" for ortho.v1, ".mosaic.tif.part-*" for mosaic.json)
        # atomic_path's file temporaries are ".<stem>.part-XXXX<suffix>", its sidecars' too (ct.gpkg's preview
        # ".ct.part-XXXX.png"): a stem's are the output's whatever their suffix (so out.json's sweep still takes a
        # live ".out.part-XXXX.tif" of an out.tif written at the same time: review 17, left)
        def own(q, name):
            return q.name.startswith(tuple(f".{n}{w}{TEMP_MARKER}" for n in (Path(name).name, Path(name).stem)
                                           for w in ("", *(f".{w}" for w in WORK_FOLDER_WORDS))))

        found = [q for q in folder.glob(f".*{TEMP_MARKER}*") if any(own(q, name) for name in names)]
    for q in sorted(found):
        if q.is_dir():
            shutil.rmtree(q, ignore_errors=True)
        else:
            q.unlink(missing_ok=True)
        gone.append(q)
    return gone


def remove_leftovers_below(root, skip=()) -> list[Path]:
    """``remove_leftovers`` in ``root`` and every folder below it except the (relative) folders ``skip``
    (a project's inputs: images/, lidar/ are never written)."""
    root = Path(root)
    gone = []
    for dirpath, dirnames, _ in os.walk(root):
        d = Path(dirpath)
        rel = d.relative_to(root).as_posix()
        dirnames[:] = [n for n in dirnames if TEMP_MARKER not in n and COMMIT_MARKER not in n
                       and (f"{rel}/{n}" if rel != "." else n) not in skip]
        gone += remove_leftovers(d)
    return gone


def refuse_input_as_output(output, inputs, option: str = "output") -> None:
    """``InputError`` when ``output`` is (or resolves to, through links) one of ``inputs``: a writer must
    never replace what it reads. ``inputs`` may hold None (absent optional inputs)."""
    out = Path(output).resolve()
    for p in inputs:
        if p is None:
            continue
        src = Path(p).resolve()
        if out == src:
            raise OptionError(f"{output}: the output is the input {p} (inputs are never modified; "
                              "choose another output path)", param=option)


# what the OS and file browsers add to any folder they show (Finder, Explorer, a Mac's copy onto a FAT/SMB
# share: "._name" AppleDouble files): not a user's work; they go with the replaced output
OS_CLUTTER = frozenset({".ds_store", "thumbs.db", "ehthumbs.db", "desktop.ini", ".localized"})


def os_clutter(entry) -> bool:
    """Whether the folder entry ``entry`` (a Path or a name) is a file the OS or a file browser adds by itself."""
    name = Path(entry).name
    return name.lower() in OS_CLUTTER or name.startswith("._")


def refuse_foreign_contents(outdir, owned, what: str, option: str = "OUTDIR", proven=None) -> None:
    """``OptionError`` when the folder ``outdir`` (replaced as a whole by ``atomic_dir``) exists and holds an
    entry that ``owned(entry: Path) -> bool`` does not claim as a previous output of ``what`` (e.g. "lidarctl
    classify"): replacing it would delete a user's file without a word. A new folder, an empty one, a previous
    output and the OS's clutter (``os_clutter``: .DS_Store, Thumbs.db, ...) pass; ``outdir`` a file is refused.

    ``proven(entry) -> bool`` (None: every owned entry is proven): whether the entry is ours by provenance (the
    folder holds our record, the name derives from this run's inputs), not by its name alone; owned entries that
    are not proven (an output written before the records, or a user's file with one of our names) are replaced
    with a warning naming them."""
    outdir = Path(outdir)
    if outdir.is_symlink() and not outdir.exists():
        raise OptionError(f"{outdir}: the output folder is a broken link; remove it or give a folder", param=option)
    if not outdir.exists():
        return
    if not outdir.is_dir():
        raise OptionError(f"{outdir}: the output folder is a file; move it (or remove it), or give another "
                          "folder", param=option)
    entries = sorted((p for p in outdir.iterdir() if not os_clutter(p)), key=lambda p: p.name)
    foreign = [p.name for p in entries if not owned(p)]
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise OptionError(f"{outdir}: the output folder is replaced as a whole, and it holds {shown}, which "
                          f"{what} did not write: move {'it' if len(foreign) == 1 else 'them'} out of the folder "
                          f"(or remove {'it' if len(foreign) == 1 else 'them'}) and run again", param=option)
    unproven = [p.name for p in entries if proven is not None and not proven(p)]
    if unproven:
        shown = ", ".join(unproven[:5]) + (f" and {len(unproven) - 5} more" if len(unproven) > 5 else "")
        log.warning(f"{outdir}: replacing {shown}, taken for a previous output of {what} by name only (no record "
                    "of it in the folder, or not named after this run's inputs)")
