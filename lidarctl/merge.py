"""Merge LAS/LAZ strips into one file, chunk by chunk (bounded memory), every dimension preserved.

Points keep their values; integer coordinates are re-expressed in the first file's scales and
offsets when the strips differ. ``point_source_id`` keeps telling the strips apart.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np

from aerotri.core.atomic import atomic_path
from aerotri.core.errors import InputError


def merge_las(paths, out_path, chunk_points: int = 2_000_000) -> int:
    """Concatenate ``paths`` into ``out_path`` (written atomically); returns the number of points."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("no LAS/LAZ files to merge")
    headers = []
    for p in paths:
        try:
            with laspy.open(p) as f:
                headers.append(f.header)
        except (laspy.LaspyException, OSError, ValueError) as exc:
            raise InputError(f"{p}: not a readable LAS/LAZ file ({exc})") from None
    first = headers[0]
    for p, h in zip(paths[1:], headers[1:]):
        if h.point_format.id != first.point_format.id:
            raise InputError(f"{p}: point format {h.point_format.id} differs from {paths[0]} "
                             f"({first.point_format.id}); convert before merging")
    header = laspy.LasHeader(point_format=first.point_format, version=first.version)
    header.scales = first.scales
    header.offsets = first.offsets
    header.vlrs = list(first.vlrs)
    header.creation_date = first.creation_date
    header.global_encoding = first.global_encoding
    total = 0
    with atomic_path(out_path) as tmp:
        with laspy.open(tmp, mode="w", header=header) as w:
            for p in paths:
                with laspy.open(p) as r:
                    for chunk in r.chunk_iterator(chunk_points):
                        if np.array_equal(r.header.scales, header.scales) and np.array_equal(r.header.offsets, header.offsets):
                            w.write_points(chunk)
                        else:
                            rec = laspy.ScaleAwarePointRecord.zeros(len(chunk), header=header)
                            for name in chunk.point_format.dimension_names:
                                if name not in ("X", "Y", "Z"):
                                    rec[name] = chunk[name]
                            rec.x, rec.y, rec.z = chunk.x, chunk.y, chunk.z
                            w.write_points(rec)
                        total += len(chunk)
    return total
