"""The adjusted tie points of a project (``at/object_points.csv`` as ``aerotri adjust`` writes it), read for the
tie points' DEM (``ortho.points_dem``) and for the check of the surface the orthos are rectified on
(``ortho.block.tie_points_off_surface``)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.textio import read_text


def read_tie_points(path: Path, min_rays: int = 3) -> np.ndarray:
    """(N, 3) project-CRS coordinates of the tie points in ``at/object_points.csv`` seen in ``min_rays`` frames."""
    xyz, rays = read_tie_points_with_rays(path)
    return xyz[rays >= min_rays]


def read_tie_points_with_rays(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Every tie point of ``at/object_points.csv``: (N, 3) project-CRS coordinates and (N,) the frames it is seen in."""
    text = read_text(path, "table of adjusted object points (CSV)", "run aerotri adjust first")
    out, rays = [], []
    for lineno, row in enumerate(csv.DictReader(io.StringIO(text, newline="")), start=2):
        try:
            if row["kind"] != "tie":
                continue
            n = int(row["rays"])
            out.append((float(row["x"]), float(row["y"]), float(row["z"])))
            rays.append(n)
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}:{lineno}: expected id,kind,x,y,z,...,rays,... (aerotri adjust's "
                             f"object_points.csv), got {row}") from None
    return np.array(out, dtype=float).reshape(-1, 3), np.array(rays, dtype=np.int64)
