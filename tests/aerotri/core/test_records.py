"""to_record: a dataclass as its JSON record (field names as keys, nested records, tuples as lists)."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from aerotri.core.records import to_record


@dataclasses.dataclass(frozen=True)
class _Bin:
    from_m: float
    to_m: float | None


@dataclasses.dataclass(frozen=True)
class _Stats:
    count: int
    rms_m: float | None = None
    ratio: float = math.nan
    bins: tuple[_Bin, ...] = ()
    html: str | None = "x.html"


def test_fields_by_name_nested_and_tuples_as_lists():
    s = _Stats(3, 0.5, 0.25, (_Bin(0.0, 1.0), _Bin(1.0, None)))
    r = to_record(s)
    assert r == {"count": 3, "rms_m": 0.5, "ratio": 0.25, "bins": [{"from_m": 0.0, "to_m": 1.0},
                                                                   {"from_m": 1.0, "to_m": None}], "html": "x.html"}
    assert list(r) == [f.name for f in dataclasses.fields(s)] and isinstance(r["bins"], list)
    # the same as dataclasses.asdict, as JSON reads it back
    assert json.loads(json.dumps(dataclasses.asdict(s))) == r


def test_exclude_drop_none_finite():
    s = _Stats(0, html=None)
    assert to_record(s, drop_none=True) == {"count": 0, "ratio": s.ratio, "bins": []}
    assert to_record(s, exclude=("bins", "ratio")) == {"count": 0, "rms_m": None, "html": None}
    assert to_record(s, finite=True)["ratio"] is None
    # a nested record keeps its Nones with drop_none (the top level only)
    assert to_record(_Stats(1, bins=(_Bin(2.0, None),)), drop_none=True)["bins"] == [{"from_m": 2.0, "to_m": None}]


def test_not_a_dataclass():
    with pytest.raises(TypeError, match="expected a dataclass instance, got dict"):
        to_record({"a": 1})
    with pytest.raises(TypeError, match="got type"):
        to_record(_Stats)
