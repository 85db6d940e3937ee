"""One serialiser for the JSON edge: a frozen dataclass as the record a report or stamp writes.

The JSON keys are the field names (which carry the units: ``rms_m``, ``area_m2``); nested dataclasses become
records too, tuples lists (as JSON reads them back). Classes whose record renames keys, rounds or adds derived
values keep a function of their own beside the writer; this is for the plain field dumps.
"""

from __future__ import annotations

import dataclasses
import math


def to_record(obj, *, exclude: tuple[str, ...] = (), drop_none: bool = False, finite: bool = False) -> dict:
    """The fields of the dataclass ``obj`` by name, recursively (``dataclasses.asdict``; tuples as lists).

    ``exclude``: fields left out; ``drop_none``: fields whose value is None left out (the top level only: a
    nested record keeps its Nones); ``finite``: non-finite floats (an undefined ratio) as None.
    """
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        raise TypeError(f"to_record: expected a dataclass instance, got {type(obj).__name__}")
    out = {}
    for f in dataclasses.fields(obj):
        if f.name in exclude:
            continue
        v = getattr(obj, f.name)
        if v is None and drop_none:
            continue
        out[f.name] = _plain(v, finite)
    return out


def _plain(v, finite: bool):
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {f.name: _plain(getattr(v, f.name), finite) for f in dataclasses.fields(v)}
    if isinstance(v, (list, tuple)):
        return [_plain(x, finite) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x, finite) for k, x in v.items()}
    if finite and isinstance(v, float) and not math.isfinite(v):
        return None
    return v
