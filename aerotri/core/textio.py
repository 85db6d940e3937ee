"""Reading the project's text files (tables, EO/GNSS lists, JSON) with one set of rules.

Text files are UTF-8 (a UTF-8 byte-order mark is accepted and dropped). Everything that makes a file
unreadable as such - not found, a folder in its place, no permission, UTF-16 (as some Windows tools
save tables), binary data, invalid UTF-8 - becomes one ``InputError`` naming the file (and the line of
the first bad byte), never a ``UnicodeDecodeError`` or ``IsADirectoryError`` from deep inside a
reader.
"""

from __future__ import annotations

import codecs
import json
import logging
from pathlib import Path

from aerotri.core.errors import InputError


def read_text(path, what: str = "text file", hint: str = "") -> str:
    """The text of ``path`` (UTF-8); ``what`` names the file's role in messages, ``hint`` is added
    when the file does not exist (e.g. the stage that writes it)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: file not found, expected a {what}{f' ({hint})' if hint else ''}") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, expected a {what}") from None
    except PermissionError:
        raise InputError(f"{path}: cannot read the {what} (permission denied)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    return decode_text(data, path, what)


def decode_text(data: bytes, path, what: str = "text file") -> str:
    """Bytes of a text file as str (see ``read_text``); errors name ``path`` and the line."""
    if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE, codecs.BOM_UTF32_LE, codecs.BOM_UTF32_BE)):
        raise InputError(f"{path}: the {what} is UTF-16/UTF-32 text; expected UTF-8 (save it as UTF-8 or ASCII)")
    nul = data.find(b"\x00")
    if nul >= 0:
        line = data.count(b"\n", 0, nul) + 1
        raise InputError(f"{path}:{line}: binary data (NUL byte at offset {nul}); expected a UTF-8 {what}")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"{path}:{line}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
                         f"expected a UTF-8 {what} (one saved as GBK: iconv -f GBK -t UTF-8)") from None
    if not data.isascii() and not data.startswith(codecs.BOM_UTF8):
        _say_if_gbk(data, text, path)
    return text


def _say_if_gbk(data: bytes, text: str, path) -> None:
    """Warn when UTF-8 text reads as Chinese in GBK and as no script's letters in UTF-8: GBK pairs of bytes can be
    valid UTF-8 by chance (a levelling table's "水准G1" read as "ˮ׼G1", trial s96 F5). A file with CJK or Latin
    letters in UTF-8 is taken as it reads."""
    try:
        gbk = data.decode("gb18030")
    except UnicodeDecodeError:
        return
    odd = [c for c in text if ord(c) > 0x7F]
    # CJK, Latin letters and symbols (the degree sign of a WKT's area of use: trial s97 L3), Greek, Cyrillic,
    # punctuation, units and mathematical signs are what UTF-8 files hold; GBK bytes read as UTF-8 by chance
    # give modifier letters, Hebrew, Arabic and the like
    if any(0x3000 <= ord(c) <= 0x9FFF or 0xA0 <= ord(c) <= 0x24F or 0x370 <= ord(c) <= 0x4FF
           or 0x2000 <= ord(c) <= 0x22FF for c in odd):
        return
    if not any(0x4E00 <= ord(c) <= 0x9FFF for c in gbk):
        return
    lines, glines = text.splitlines(), gbk.splitlines()
    k = next((i for i, (a, b) in enumerate(zip(lines, glines)) if a != b), 0)
    # the excerpts from a little before where the two readings part
    col = next((i for i, (a, b) in enumerate(zip(lines[k], glines[k])) if a != b), 0) if lines else 0
    a = max(0, col - 10)
    logging.getLogger("aerotri").warning(
        f"{path}:{k + 1}: reads as UTF-8 {lines[k][a:a + 40]!r}, as GBK {glines[k][a:a + 40]!r}: a file saved as GBK "
        "(Chinese Windows' default) is read wrong; save it as UTF-8 (iconv -f GBK -t UTF-8)")


def read_xml(path, what: str = "XML file"):
    """The root element of an XML document (``xml.etree.ElementTree``), in the encoding its declaration states
    (``<?xml ... encoding="ISO-8859-1"?>``: a legal XML that UTF-8 refused; trial-messy F11), UTF-8 without one; a
    syntax error names the file, line and column."""
    import xml.etree.ElementTree as ET

    path = Path(path)
    data = path.read_bytes() if path.is_file() else read_text(path, what).encode()  # read_text: the missing file's error
    head = data[:200].lstrip(codecs.BOM_UTF8)
    if not (head.startswith(b"<?xml") and b"encoding=" in head.split(b"?>")[0]):
        data = decode_text(data, path, what).encode("utf-8")  # its checks (UTF-16, NUL, not UTF-8) by line
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        raise InputError(f"{path}:{exc.position[0]}: not valid XML ({exc}); expected a {what}") from None
    except LookupError as exc:  # an encoding Python does not know
        raise InputError(f"{path}: the XML declaration's encoding is unknown ({exc}); expected a {what}") from None


def read_json(path, what: str = "JSON file", hint: str = ""):
    """A JSON document; a syntax error (e.g. a truncated file) names the file and line."""
    path = Path(path)
    text = read_text(path, what, hint)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg}, column {exc.colno}); "
                         f"the {what} is corrupt or truncated") from None


def read_record(path, what: str, schema_version: int) -> dict:
    """A versioned report record (a stage's JSON file): a JSON object whose ``schema_version`` (absent: taken
    as ``schema_version``, the records written before versions were numbered) is an integer no newer than
    ``schema_version``, the newest this version reads. ``what`` names the record without article, e.g.
    ``"strip check (strips.json)"``; every error is an InputError naming the file and the record expected
    (``record_error`` for the caller's own field checks)."""
    path = Path(path)
    d = read_json(path, what)
    if not isinstance(d, dict):
        kind = {list: "array", str: "string", bool: "boolean", int: "number", float: "number"}.get(type(d), "null")
        raise InputError(f"{path}: not a {what}: a JSON {kind}, expected an object")
    v = d.get("schema_version", schema_version)
    if not isinstance(v, int) or isinstance(v, bool) or v > schema_version:
        raise InputError(f"{path}: not a {what} of schema version {schema_version} or older "
                         f"(schema_version {json.dumps(v)})")
    return d


def record_error(path, what: str, exc: Exception) -> InputError:
    """The InputError for a record (``read_record``) lacking a field or holding one of the wrong type."""
    return InputError(f"{path}: not a {what}: {type(exc).__name__} {exc}")
