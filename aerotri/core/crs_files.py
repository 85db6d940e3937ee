"""CRS files named where a CRS is expected (``--crs grid.prj``, ``crs = "grid.wkt"`` in project.toml): a file's name
told from a CRS itself, and the WKT it holds read (ESRI's .prj is WKT too).

In the core because project.toml's settings (``aerotri.core.settings``, ``aerotri.core.project``) take a file's WKT,
so that stamps and index.json record the CRS itself, not a name (review 44)."""

from __future__ import annotations

from pathlib import Path

import pyproj

from aerotri.core.errors import CrsError

CRS_FILE_SUFFIXES = (".wkt", ".prj")  # a CRS given as the path of a file holding its WKT (ESRI's .prj too)


def is_crs_file(text: str) -> bool:
    """``text`` names a .wkt or .prj file (``CRS_FILE_SUFFIXES``) rather than being a CRS itself."""
    text = str(text).strip()
    return text.lower().endswith(CRS_FILE_SUFFIXES) and "\n" not in text and "[" not in text


def read_crs_file(name, source: str) -> tuple[str, pyproj.CRS]:
    """(the WKT text, the CRS) of a .wkt or .prj file; ``CrsError`` naming ``source`` and the file."""
    path = Path(name).expanduser()
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise CrsError(f"{source}: cannot read the CRS file {path} ({exc.strerror or exc})") from None
    try:
        wkt = data.decode("utf-8-sig").strip()
    except UnicodeDecodeError:
        wkt = data.decode("latin-1").strip()  # (an ESRI .prj of a Windows program)
    if not wkt:
        raise CrsError(f"{source}: the CRS file {path} is empty (expected the WKT of a CRS)")
    try:
        return wkt, pyproj.CRS.from_user_input(wkt)
    except pyproj.exceptions.CRSError:
        raise CrsError(f"{source}: the CRS file {path} holds no CRS PROJ knows (expected WKT, as a .prj holds; "
                       f"it begins {wkt[:40]!r})") from None


def crs_setting_text(value, base_dir, source: str):
    """A CRS setting of project.toml ([project] crs, [rectify] crs) as the CRS text every command uses: the WKT a
    .wkt/.prj file holds, the file's name taken relative to ``base_dir`` (the project folder), else ``value`` as
    given. Review 44: `crs = "grid.prj"` was read from the current directory (exit 2 from outside the project, another
    grid.prj taken in silence) and the stamps recorded only the name, so a changed file re-ran nothing; the WKT
    itself is what they record now. ``CrsError`` naming ``source`` and the file when it cannot be read."""
    if value is None or not is_crs_file(str(value)):
        return value
    path = Path(str(value).strip()).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return read_crs_file(path, source)[0]


