"""Settings given on the command line as ``section.key=value`` (``aerotri init --set``, ``aerotri settings PROJECT
--set``), checked and written into project.toml.

An item is ``section[.sub].key=value``; the value is TOML (``411``, ``0.05``, ``true``, ``"text"``, ``["pp",
"radial"]``) or, when it does not parse as TOML, the text as written (a bare ``EPSG:3855`` or ``brown``). Every
item is checked as the commands check project.toml (``aerotri.core.project.check_sections`` for the project
sections, each stage's settings class for its section, and ``[project] heights`` as a vertical CRS), in the order
given, so that an error names the item. ``[project] crs`` is not set this way: it is chosen at ``aerotri init
--crs`` and every product of a project is in it.

The file's text is edited line by line, its comments, layout, byte-order mark and line ends kept: a key's line
replaced (its comment kept), a new key put after its section's last key, a new section appended. The edited text must
read back as the settings asked for, else nothing is written (a multi-line value, an inline table, dotted or quoted
keys: edit those by hand).
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import re
import tomllib
from pathlib import Path

from aerotri.core.errors import ConfigError, InputError, OptionError

log = logging.getLogger(__name__)

EXAMPLE = "e.g. flight.mean_terrain_height_m=411 or project.heights=EPSG:3855"


def parse_item(item: str) -> tuple[tuple[str, ...], object]:
    """``section[.sub].key=value`` -> (the key's path, its value)."""
    key, sep, value = item.partition("=")
    path = tuple(p.strip() for p in key.split("."))
    if not sep or len(path) < 2 or not all(path):
        raise OptionError(f"--set {item!r}: expected section.key=value, {EXAMPLE}", param="--set")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError as exc:
        if value.strip()[:1] in ("[", "{", '"', "'"):  # meant as a TOML list, table or string, and not one
            raise OptionError(f"--set {item!r}: {value.strip()} is not a TOML value ({exc}); e.g. "
                              "'adjust.self_calibration=[\"pp\", \"radial\"]' (quote the whole item for the shell)",
                              param="--set") from None
        parsed = value.strip()  # a bare word: EPSG:3855, brown, 1:2000, ...
    return path, parsed


@dataclasses.dataclass(frozen=True)
class SettingChange:
    """One ``--set`` item, checked: the key's path in project.toml, its new value and the one it had (None: not given)."""

    path: tuple[str, ...]
    value: object
    was: object = None


def checked_settings(items, root, config: dict | None = None) -> list[SettingChange]:
    """The ``--set`` ``items`` applied in order to ``config`` (a project.toml's tables; None: a new project's), each
    checked (module docstring; ``root`` anchors relative file names). ``OptionError`` naming the item."""
    from aerotri.chain.options import STAGE_SECTIONS
    from aerotri.core.project import PROJECT_SECTIONS, Project, check_sections
    from aerotri.core.settings import from_table
    from aerotri.geom.crs.definition import parse_heights

    root = Path(root)
    tables = copy.deepcopy(config) if config is not None else {}
    if config is not None:
        # the file's own errors are named as the file's (kite trial: a key typo already in project.toml was
        # reported as "--set adjust.leave_one_out=yes [adjust]: unknown key 'self_calibraton'")
        here = str(root / "project.toml")
        sections = check_sections(tables, here)
        for section in dict.fromkeys(parse_item(item)[0][0] for item in items):
            if section in STAGE_SECTIONS and section in tables:
                from_table(STAGE_SECTIONS[section], Project(root, tables, sections).stage_table(section),
                           f"{here} [{section}]", base_dir=root)
    changes, deferred = [], []
    for item in items:
        path, value = parse_item(item)
        if path[:2] == ("project", "crs"):
            raise OptionError(f"--set {item!r}: the project CRS is chosen at aerotri init --crs (every product of the "
                              "project is in it)", param="--set")
        where = f"--set {item}"
        table = tables.setdefault(path[0], {})
        for head in path[1:-1]:
            table = table.setdefault(head, {})
            if not isinstance(table, dict):
                raise OptionError(f"{where}: {head} is a value, not a section", param="--set")
        if isinstance(table.get(path[-1]), dict):
            raise OptionError(f"{where}: {'.'.join(path)} is a section; give one of its keys", param="--set")
        was, table[path[-1]] = table.get(path[-1]), value

        def check(path=path, where=where):
            sections = check_sections(tables, where)
            project_cls = PROJECT_SECTIONS.get(path[0])
            if project_cls is not None and path[1] in {f.name for f in dataclasses.fields(project_cls)}:
                typed = getattr(sections, path[0])
            else:  # a stage's key ([control] holds the project's sigmas and the control stage's keys)
                own = Project(root, tables, sections).stage_table(path[0])
                typed = from_table(STAGE_SECTIONS[path[0]], own, f"{where} [{path[0]}]", base_dir=root)
            _warn_missing_file(typed, path[1:], root, where)
            if path[:2] == ("project", "heights"):
                parse_heights(sections.project.heights, where)

        try:
            check()
        except InputError as exc:
            # a key that needs another (offset_sigma_xy_m with offset_sigma_z_m) is judged again with the items
            # after it (trial s97 L1: both given in one command, the first was refused "give both ... or neither")
            deferred.append((check, exc))
        changes.append(SettingChange(path, value, was))
    for check, exc in deferred:
        try:
            check()
        except InputError:
            raise OptionError(str(exc), param="--set") from None
    return changes


def _warn_missing_file(typed, path: tuple[str, ...], root: Path, where: str) -> None:
    """A file setting names a file that is not there (yet): a warning, since the commands look for it when they run
    (a DEM, a tolerance table or an EO file may be put in later)."""
    from aerotri.core.settings import get_path

    try:
        value = get_path(typed, ".".join(path))
    except AttributeError:
        return
    # (already anchored at the project folder: joined to ``root`` again, a relative project path P gave P/P/..., and
    # the file was "not there" also when it was, docs trial s101 F1)
    if isinstance(value, Path) and not value.exists():
        log.warning(f"{where}: {value} is not there (yet); the commands that read it will look for it")


def _header(text: str, section: tuple[str, ...]) -> re.Match | None:
    name = r"[ \t]*\.[ \t]*".join(re.escape(s) for s in section)
    return re.search(rf"(?m)^[ \t]*\[[ \t]*{name}[ \t]*\][ \t]*(#[^\n]*)?(\n|\Z)", text)


def _value_end(rest: str) -> int | None:
    """Where the value of ``key = <rest>`` ends on its line (before a comment), or None when it does not end there."""
    # the first "#" before which the text is a whole value starts the comment (TOML reads "v = 1 # c" too)
    for i in [m.start() for m in re.finditer("#", rest)] + [len(rest)]:
        try:
            tomllib.loads("v = " + rest[:i])
            return i
        except tomllib.TOMLDecodeError:
            continue
    return None


def with_settings(text: str, changes: list[SettingChange], source: str) -> str:
    """project.toml's ``text`` with the ``changes`` (``checked_settings``) written in (module docstring);
    ``ConfigError`` naming ``source`` when a change cannot be written as a line of its own."""
    from aerotri.core.settings import toml_value

    bom = "\ufeff" if text.startswith("\ufeff") else ""
    newline = "\r\n" if "\r\n" in text else "\n"
    text = text[len(bom):].replace("\r\n", "\n")
    if text and not text.endswith("\n"):
        text += "\n"
    try:
        expected = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from None
    for change in changes:
        section, key, value = change.path[:-1], change.path[-1], change.value
        line = f"{key} = {toml_value(value)}"
        header = _header(text, section)
        if header is None:
            text = text.rstrip("\n") + f"\n\n[{'.'.join(section)}]\n{line}\n"
        else:
            body_start = header.end()
            nxt = re.search(r"(?m)^[ \t]*\[", text[body_start:])
            body_end = body_start + nxt.start() if nxt else len(text)
            old = re.search(rf"(?m)^([ \t]*){re.escape(key)}[ \t]*=[ \t]*([^\n]*)$", text[body_start:body_end])
            if old is None:  # after the section's last key (its comment lines, the template's, stay below)
                keys = list(re.finditer(r"(?m)^[ \t]*[^#\s][^\n]*$", text[body_start:body_end]))
                at = body_start + keys[-1].end() + 1 if keys else body_start
                text = text[:at] + line + "\n" + text[at:]
            else:
                rest = old.group(2)
                end = _value_end(rest)
                if end is None:
                    raise ConfigError(f"{source}: [{'.'.join(section)}] {key} spans several lines; edit it by hand")
                comment = rest[end:].strip()
                new = old.group(1) + line + ("  " + comment if comment else "")
                text = text[:body_start + old.start()] + new + text[body_start + old.end():]
        target = expected
        for head in section:
            target = target.setdefault(head, {})
        target[key] = value
    try:
        ok = tomllib.loads(text) == expected
    except tomllib.TOMLDecodeError:
        ok = False
    if not ok:
        raise ConfigError(f"{source}: the settings given could not be written as lines of their own (the file gives "
                          "one of their keys or sections otherwise: quoted or dotted keys, an inline table, a multi-line "
                          "string); edit it by hand")
    return bom + text.replace("\n", newline)


def set_in_project(project, items) -> list[str]:
    """Write the ``--set`` ``items`` into the project.toml of ``project`` (an ``aerotri.core.project.Project``),
    each checked first (``checked_settings``: nothing is written when one is refused); returns a line per change
    saying what the key held before."""
    from aerotri.core.atomic import write_text_atomic
    from aerotri.core.settings import toml_value

    changes = checked_settings(items, project.root, project.config)
    path = project.config_path
    write_text_atomic(path, with_settings(path.read_text(encoding="utf-8"), changes, str(path)))
    return [f"{path}: [{'.'.join(c.path[:-1])}] {c.path[-1]} = {toml_value(c.value)} "
            f"(was {'not given: its default' if c.was is None else toml_value(c.was)})" for c in changes]
