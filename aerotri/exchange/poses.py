"""Shared pieces of the block formats (orthority, COLMAP, PATB, Metashape, MicMac): orientations read in a
foreign CRS or frame brought into the project CRS, the project's orientations and camera as exporters
need them, image ids from file names, and number checks with the file and record in the message.

Rotations are camera -> object in the photogrammetric frame (x right, y up, z back; ``aerotri.geom.rotation``).
A rotation given against the axes of another CRS (grid axes of another projection, or geocentric axes) is
turned onto the project's grid axes at the projection centre by the orthonormal part of the Jacobian of
the coordinate operation there (``rotation_to_project``), so the orientation keeps its meaning.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.exchange.imported import to_project_crs
from aerotri.geom.camera import Camera, oriented_camera
from aerotri.geom.eo import ExteriorOrientations, read_eo
from aerotri.geom.rotation import opk_from_matrix, rotation_matrix_opk

IMAGE_SUFFIXES = (".tif", ".tiff", ".jpg", ".jpeg", ".png", ".jp2", ".ecw", ".img")


def image_id_of(name: str) -> str:
    """The project image id of a file name another program gives (folder and image extension dropped)."""
    p = Path(str(name).replace("\\", "/"))
    return p.stem if p.suffix.lower() in IMAGE_SUFFIXES else p.name


def number(text, where: str, what: str) -> float:
    """``text`` as a finite float; ``InputError`` naming ``where`` (file:line or file record) otherwise."""
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {what} = {text!r} is not a number") from None
    if not math.isfinite(v):
        raise InputError(f"{where}: {what} is NaN or infinite")
    return v


def rotation_to_project(from_crs, project: Project, xyz_m, source: str, step_m: float = 1.0) -> np.ndarray:
    """(N, 3, 3) rotations from the axes of ``from_crs`` at ``xyz_m`` (N, 3; in ``from_crs``) onto the project
    CRS's grid axes (identity when the CRSs are the same). The Jacobian by central differences of about
    ``step_m`` metres: in a geographic CRS a step in degrees of that length (a step of 1 unit, 1 degree, turned
    the axes 0.00008 deg off the meridian convergence at 70 N before trial-exchange)."""
    from aerotri.geom.crs.definition import parse_crs, project_crs, same_crs

    xyz = np.asarray(xyz_m, float).reshape(-1, 3)
    crs = parse_crs(from_crs, source)
    if same_crs(crs, project_crs(project)):
        return np.repeat(np.eye(3)[None], len(xyz), axis=0)
    step = np.full(3, float(step_m))
    if crs.is_geographic:  # degrees of latitude and longitude: about step_m on the ground
        step[:2] = step_m / 111_000.0
    # the six shifted copies through one operation (a transformer made once, not six times)
    shifts = np.concatenate([np.diag(step), -np.diag(step)])            # +x +y +z -x -y -z
    moved = to_project_crs((xyz[None] + shifts[:, None]).reshape(-1, 3), from_crs, project, source)
    moved = moved.reshape(6, len(xyz), 3)
    J = np.moveaxis((moved[:3] - moved[3:]) / (2 * step)[:, None, None], 0, -1)
    U, _, Vt = np.linalg.svd(J)
    return U @ Vt


def orientations_to_project(image_id, centre_m, R_photo, from_crs, project: Project, source: str
                            ) -> ExteriorOrientations:
    """Projection centres (N, 3) and camera -> object rotations (N, 3, 3, photogrammetric camera frame) in
    ``from_crs`` as project orientations (project CRS, omega phi kappa degrees)."""
    centre = np.asarray(centre_m, float).reshape(-1, 3)
    R = rotation_to_project(from_crs, project, centre, source) @ np.asarray(R_photo, float).reshape(-1, 3, 3)
    opk = np.column_stack(opk_from_matrix(R))
    return ExteriorOrientations(list(image_id), to_project_crs(centre, from_crs, project, source), opk)


def opk_orientations_to_project(image_id, centre_m, opk_deg, from_crs, project: Project, source: str
                                ) -> ExteriorOrientations:
    """As ``orientations_to_project`` for omega phi kappa angles (degrees) against ``from_crs``'s axes."""
    opk = np.asarray(opk_deg, float).reshape(-1, 3)
    return orientations_to_project(image_id, centre_m, rotation_matrix_opk(opk[:, 0], opk[:, 1], opk[:, 2]),
                                   from_crs, project, source)


def adjusted_orientations(project: Project) -> tuple[ExteriorOrientations, Camera]:
    """(orientations, camera): ``at/eo.txt`` in the project CRS and the camera they belong to (the
    self-calibrated one when the adjustment calibrated, k3 included)."""
    camera, _ = oriented_camera(project)
    return read_eo(project.eo_path), camera


def horizontal_wkt(project: Project) -> str:
    """WKT of the project's horizontal CRS (what ``.prj`` sidecars and foreign files carry)."""
    from aerotri.geom.crs.definition import horizontal_crs, project_crs

    return horizontal_crs(project_crs(project)).to_wkt()
