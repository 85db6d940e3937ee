"""Surveyed point ids as matched between files and within one (core layer: imports nothing of ours).

One rule for every package (docs/standards.md): case is ignored and a numeric id's leading zeros too. It sits in
the core layer so that lidarctl and ortho, which may not import aerotri.qa, judge duplicates in a points file by the
same key as the report matches ids across files (a file with P00 and p00 was read as two points and met ASPRS
2023's minimum of 30 check points with 29)."""

from __future__ import annotations

import logging


def point_id_key(point_id) -> str:
    """A surveyed point's id as matched between files: case ignored ("GCP06" is "gcp06"), and the leading zeros of
    a numeric id ("06" is "6", the number 6 too); "GCP06" is not "GCP6"."""
    key = str(point_id).strip().casefold()
    return (key.lstrip("0") or "0") if key.isdigit() else key


def refuse_repeated_id(first_line: dict, point_id: str, line: int, where: str) -> None:
    """Record ``point_id`` read on ``line`` in ``first_line`` (``point_id_key`` -> (id as written, line)); an
    ``InputError`` starting with ``where`` (the file and line) when the same point came before: counted twice it
    would pass a standard's minimum number of check points (P00 and p00 read as two met ASPRS 2023's 30 with 29)."""
    from aerotri.core.errors import InputError

    key = point_id_key(point_id)
    if key in first_line:
        first_id, first_no = first_line[key]
        raise InputError(f"{where}: point {point_id!r} again (first on line {first_no}"
                         + ("" if first_id == point_id else f" as {first_id!r}; ids match without case and a number's "
                            "leading zeros") + "); expected each surveyed point once")
    first_line[key] = (point_id, line)


# Two ids this close in plan (in the file's unit: a millimetre, or a third of one in feet) are one point surveyed
# or typed twice under two names far more often than two marks: counted twice they fill a standard's minimum number
COINCIDENT_XY = 0.001


def warn_coincident_points(path, ids, lines, x, y, within: float = COINCIDENT_XY) -> list[tuple[int, int]]:
    """Warn (naming both, with their lines) of each pair of points with different ids within ``within`` of each
    other in x and in y (the file's unit); returns the pairs (indices). Not refused: two marks may stand that close."""
    import numpy as np
    from scipy.spatial import cKDTree

    if len(ids) < 2:
        return []
    pairs = sorted(cKDTree(np.column_stack([x, y])).query_pairs(within, p=np.inf))
    for i, j in pairs:
        logging.getLogger(__name__).warning(
            "%s: points %r (line %d) and %r (line %d) stand at the same x, y (within %g): one point under two ids? "
            "Both are counted as check points", path, ids[i], lines[i], ids[j], lines[j], within)
    return pairs


def dom_points_used_as_control(dom_all: dict, at: dict) -> tuple[str, ...]:
    """The ids of a DOM check's surveyed points (``ortho check --points``: dom_report.json ``points``) that the
    adjustment used as control (at/report.json ``control_points``, used, of a kind other than check; ids matched by
    ``point_id_key``): the DOM stands on orientations fitted to them, so they are no independent check of it."""
    if dom_all.get("method") != "surveyed_points":
        return ()
    used = {point_id_key(c.get("id")) for c in at.get("control_points") or []
            if isinstance(c, dict) and c.get("used", True) and c.get("kind") != "check"}
    return tuple(str(p.get("id")) for p in dom_all.get("points") or [] if point_id_key(p.get("id")) in used)
