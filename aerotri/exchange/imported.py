"""What an importer read from another program's files, and how it lands in a project folder.

An importer returns an :class:`ImportedBlock` in the project's CRS (coordinates converted through the
toolkit's one coordinate-operation policy, :func:`to_project_crs`). :func:`write_imported` turns it into
the project's own files:

| block field | project file |
|---|---|
| ``camera`` | ``camera.toml`` |
| ``gnss`` | ``gnss.txt`` (positions and, when the source gives them, their accuracies) |
| ``eo`` | ``imported/eo.txt`` (orientations; ``ortho rectify --eo imported/eo.txt``) |
| ``control`` | ``control/points.csv`` |
| ``image_points`` | ``control/image_points.csv`` (the control points' image measurements) |

plus a record of every import in ``imported/imports.json``. Existing project files are never
overwritten without ``overwrite=True``; all files of one import are written or none.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from pathlib import Path

import numpy as np

from aerotri.core.atomic import TEMP_MARKER, refuse_input_as_output
from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.geom.camera import Camera
from aerotri.geom.eo import ExteriorOrientations, GnssPositions, format_eo, format_gnss
from aerotri.geom.observations import ControlPoints, ImageObservations, format_control_points, format_image_points

log = logging.getLogger(__name__)


@dataclasses.dataclass(kw_only=True)
class ImportedBlock:
    """Camera, positions, orientations and control read from another program's files (project CRS;
    pixel coordinates with the origin at the centre of the top-left pixel, x right, y down)."""

    source: list[str]  # the files read
    camera: Camera | None = None
    gnss: GnssPositions | None = None
    eo: ExteriorOrientations | None = None
    control: ControlPoints | None = None
    image_points: ImageObservations | None = None
    notes: list[str] = dataclasses.field(default_factory=list)  # what the user should know (assumptions made)

    def contents(self) -> list[str]:
        return [name for name in ("camera", "gnss", "eo", "control", "image_points") if getattr(self, name) is not None]


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImportSettings:
    """Choices a format may need. ``crs``: the CRS of the input when the file does not carry one;
    ``sigma_xyz_m``: accuracy of positions the source gives none for."""

    crs: str | None = None
    sigma_xyz_m: tuple[float, float, float] | None = None


def to_project_crs(xyz_m, from_crs, project: Project, source: str) -> np.ndarray:
    """(N, 3) coordinates of ``from_crs`` in the project CRS (and height system), through the toolkit's
    coordinate-operation policy (no silent ballpark transform)."""
    from aerotri.geom.crs import parse_crs, project_crs, project_heights, same_crs
    from aerotri.geom.transform import transform_points

    xyz = np.asarray(xyz_m, float).reshape(-1, 3)
    src = parse_crs(from_crs, source)
    dst = project_crs(project)
    if same_crs(src, dst):
        return xyz.copy()
    x, y, z = transform_points(xyz[:, 0], xyz[:, 1], xyz[:, 2], from_crs=src, to_crs=dst,
                               heights=project_heights(project))
    return np.column_stack([x, y, z])


def _texts(project: Project, block: ImportedBlock) -> dict[Path, str]:
    texts = {}
    if block.camera is not None:
        texts[project.camera_path] = block.camera.to_toml()
    if block.gnss is not None:
        texts[project.gnss_path] = format_gnss(block.gnss, f" (imported from {', '.join(block.source)})")
    if block.eo is not None:
        texts[project.imported_eo_path] = format_eo(block.eo)
    if block.control is not None:
        texts[project.control_points_path] = format_control_points(block.control)
    if block.image_points is not None:
        texts[project.control_image_points_path] = format_image_points(block.image_points)
    return texts


def write_imported(root, block: ImportedBlock, format_name: str, overwrite: bool = False) -> list[Path]:
    """Write an imported block into a project folder (see the module docstring); returns the files written.

    Refuses (``InputError``) to replace an existing file unless ``overwrite``, and to write onto a file the
    import read. Every file goes to a temporary name first and all are renamed at the end, so an error
    leaves the project as it was."""
    project = Project.open(root)
    if not block.contents():
        raise InputError(f"{', '.join(block.source)}: nothing to import (no camera, positions, orientations or control)")
    texts = _texts(project, block)
    for path in texts:
        refuse_input_as_output(path, block.source, option="FILE")
    existing = [p for p in texts if p.exists()]
    if existing and not overwrite:
        raise InputError(f"{', '.join(str(p) for p in existing)}: exists; the import would replace it "
                         f"(use --force to replace, or import into another project)")
    record_path = project.imported_record_path
    record = json.loads(record_path.read_text()) if record_path.is_file() else {"imports": []}
    record["imports"].append({"format": format_name, "source": block.source,
                              "files": [str(p.relative_to(project.root)) for p in texts], "notes": block.notes})
    texts[record_path] = json.dumps(record, indent=2) + "\n"
    temps = {}
    try:
        for path, text in texts.items():
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.name}{TEMP_MARKER}import")
            tmp.write_text(text)
            temps[path] = tmp
        for path, tmp in temps.items():
            os.replace(tmp, path)
    finally:
        for tmp in temps.values():
            if tmp.exists():
                tmp.unlink()
    for note in block.notes:
        log.warning(note)
    log.info(f"imported {', '.join(block.contents())} ({format_name}) from {', '.join(block.source)} into {project.root}")
    return list(texts)
