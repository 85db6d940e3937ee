"""All of a set of files written, or none: the one place where imports and exports put their files on disk.

Every file goes to a temporary next to its target first (``.<name>.part-XXXX``, ``aerotri.core.atomic``'s
marker, so a killed run's leftovers are swept); then each existing target is moved aside to a backup and its
temporary renamed onto it; an error on the way puts every backup back. So the folder holds the old set or
the new set, never a mix. A multi-file commit in ``aerotri.core.atomic`` can replace the body of
:func:`write_together` without changing its callers.
"""

from __future__ import annotations

import os
import secrets
import tempfile
from pathlib import Path

from aerotri.core.atomic import TEMP_MARKER
from aerotri.core.errors import InputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_together(contents: dict) -> list[Path]:
    """Write ``{path: text (str) or bytes}`` all or none (see the module docstring); returns the paths."""
    temps: dict[Path, Path] = {}
    backups: dict[Path, Path] = {}
    done: list[Path] = []
    made: list[Path] = []  # folders this call creates (removed again on failure)
    mode = 0o666 & ~_umask()
    for path in contents:
        if Path(path).is_dir():
            raise InputError(f"{path}: a folder is in the way of the file to write (move it away)")
    try:
        for path, content in contents.items():
            path = Path(path)
            missing = [d for d in (path.parent, *path.parent.parents) if not d.exists()]
            path.parent.mkdir(parents=True, exist_ok=True)
            made += reversed(missing)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TEMP_MARKER}", suffix=".new", dir=path.parent)
            with os.fdopen(fd, "wb") as f:
                f.write(content.encode() if isinstance(content, str) else content)
            os.chmod(tmp, mode)
            temps[path] = Path(tmp)
        for path, tmp in temps.items():
            if path.exists():
                bak = path.with_name(f".{path.name}{TEMP_MARKER}{secrets.token_hex(4)}.old")
                os.replace(path, bak)
                backups[path] = bak
            os.replace(tmp, path)
            done.append(path)
    except BaseException:
        for path in done:  # the new files out, the old ones back
            path.unlink(missing_ok=True)
        for path, bak in backups.items():
            os.replace(bak, path)
        for tmp in temps.values():
            tmp.unlink(missing_ok=True)
        for d in reversed(made):
            try:
                d.rmdir()
            except OSError:  # not empty: someone else's files
                pass
        raise
    finally:
        for tmp in temps.values():
            tmp.unlink(missing_ok=True)
    for bak in backups.values():
        bak.unlink(missing_ok=True)
    return [Path(p) for p in contents]
