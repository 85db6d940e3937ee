"""Content hashes of files: what a record compares an input with to tell an edit from a copy (file times change
with ``cp -r``, an unzip or a download; the bytes do not)."""

from __future__ import annotations

import hashlib


def file_sha256(path, chunk_bytes: int = 1 << 22) -> str:
    """The sha256 (hex) of a file's bytes, read in chunks of ``chunk_bytes`` (memory bounded whatever its size)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_bytes):
            h.update(chunk)
    return h.hexdigest()
