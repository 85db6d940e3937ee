"""Typed values from a configuration section (``project.toml``): numbers and vectors, checked where read.

``source`` names the file and section in messages, e.g. ``P/project.toml [gnss]``; a bad value is a
``ConfigError`` naming the key, the value found and what was expected.
"""

from __future__ import annotations

import math

from aerotri.core.errors import ConfigError


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def config_number(section: dict, key: str, default, source: str, *, positive: bool = False,
                  minimum: float | None = None) -> float | None:
    """``section[key]`` as a finite float (``default`` when absent); ``positive``: > 0; ``minimum``: >= it."""
    if key not in section:
        return default
    v = section[key]
    want = "a positive number" if positive else ("a number >= %g" % minimum if minimum is not None else "a number")
    if not _is_number(v) or not math.isfinite(v):
        raise ConfigError(f"{source} {key} = {v!r}: expected {want}")
    if (positive and not v > 0) or (minimum is not None and v < minimum):
        raise ConfigError(f"{source} {key} = {v!r}: expected {want}")
    return float(v)


def config_vector(section: dict, key: str, default, n: int, source: str) -> tuple | None:
    """``section[key]`` as a tuple of ``n`` finite floats (``default`` when absent)."""
    if key not in section:
        return default
    v = section[key]
    if not isinstance(v, (list, tuple)) or len(v) != n or not all(_is_number(a) and math.isfinite(a) for a in v):
        raise ConfigError(f"{source} {key} = {v!r}: expected {n} finite numbers, e.g. [{', '.join(['0.0'] * n)}]")
    return tuple(float(a) for a in v)
