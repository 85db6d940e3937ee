"""Figures rounded for a report without changing their verdict.

A figure is judged unrounded (``figure <= limit`` passes) and shown rounded; where the rounding would put it on the
limit's other side (an RMSE of 0.100028 m against 0.1 m shown as "0.1 (limit 0.1): fail"), it keeps more digits
("0.10003"), so that the number printed is on the side of the limit its verdict says.
"""

from __future__ import annotations

import math

MAX_DECIMALS = 12
# a figure equal to its limit but for floating-point noise (the RMSE of dz all 0.05 m: 0.05000000000000001) meets it
RELATIVE_NOISE = 1e-9


def within(value: float, limit: float) -> bool:
    """Whether ``value`` meets ``limit`` (value <= limit, up to floating-point noise): the one comparison of the
    verdict table and the compliance section."""
    return value <= limit + RELATIVE_NOISE * max(abs(limit), 1e-12)


def _same_side(shown: float, value: float, limit: float) -> bool:
    return within(shown, limit) == within(value, limit)


def round_on_its_side(value, limit, decimals: int):
    """``round(value, decimals)``, with more decimals where fewer would move it across ``limit`` (a limit that is
    not a finite number: plain rounding; a value that is not: as it is)."""
    if not _judgeable(value, limit):
        if isinstance(value, float) and math.isfinite(value):
            return round(value, decimals)
        return value
    for d in range(decimals, MAX_DECIMALS + 1):
        shown = round(float(value), d)
        if _same_side(shown, float(value), float(limit)):
            return shown
    return float(value)


def text_on_its_side(value, limit, significant: int = 4) -> str:
    """``value`` as text to ``significant`` digits (``:g``), with more where fewer would move it across ``limit``."""
    if not _judgeable(value, limit):
        return f"{value:.{significant}g}"
    for n in range(significant, MAX_DECIMALS + 3):
        text = f"{value:.{n}g}"
        if _same_side(float(text), float(value), float(limit)):
            return text
    return repr(float(value))


def _judgeable(value, limit) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool) and isinstance(limit, (int, float))
            and not isinstance(limit, bool) and math.isfinite(value) and math.isfinite(limit))
