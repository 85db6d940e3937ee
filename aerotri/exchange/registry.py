"""The export formats (name -> Exporter) and the export of a project folder."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Callable

from aerotri.core.atomic import atomic_path, write_text_atomic
from aerotri.core.errors import OptionError
from aerotri.core.project import Project
from aerotri.exchange import colmap, layers, odm, patb
from aerotri.exchange.adjusted import AdjustedBlock, read_adjusted_block
from aerotri.geom.images import find_images

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Exporter:
    name: str
    description: str
    files: Callable[[AdjustedBlock, Project], dict]  # relative path -> text (or bytes, for binary files)


EXPORT_FORMATS = {
    "patb": Exporter("patb", "PATB-style image coordinates and control (patb/block.im, .con)",
                     lambda block, project: patb.files(block)),
    "colmap": Exporter("colmap", "COLMAP text model (colmap/cameras.txt, images.txt, points3D.txt)",
                       lambda block, project: colmap.files(
                           block, {k: p.name for k, p in find_images(project.images_dir).items()}
                           if project.images_dir.is_dir() else None)),
    "odm": Exporter("odm", "OpenDroneMap/OpenSfM ground control (odm/gcp_list.txt, odm/ground_control_points.json)",
                    lambda block, project: odm.files(block, project, {k: p.name for k, p in find_images(
                        project.images_dir).items()} if project.images_dir.is_dir() else None)),
    "gpkg": Exporter("gpkg", "GeoPackage map layers: control/check points with ground residuals, frame footprints, "
                             "projection centres (layers/block.gpkg, project CRS)",
                     lambda block, project: layers.files(block, project, "gpkg")),
    "kml": Exporter("kml", "the same layers as KML (layers/block.kml, WGS84)",
                    lambda block, project: layers.files(block, project, "kml")),
}
DEFAULT_FORMATS = ("patb", "colmap")


def export_project(root, formats=DEFAULT_FORMATS, out_dir=None) -> list[Path]:
    """Export the adjusted block of a project folder into ``out_dir`` (default ``at/``); every format's
    files are produced first and written afterwards (each atomically). Returns the files written."""
    unknown = [f for f in formats if f not in EXPORT_FORMATS]
    if unknown:
        raise OptionError(f"unknown export format(s) {', '.join(unknown)}; expected {', '.join(EXPORT_FORMATS)}",
                          param="--format")
    project = Project.open(root)
    block = read_adjusted_block(project.root)
    texts = {}
    for name in formats:
        texts.update(EXPORT_FORMATS[name].files(block, project))
    out = Path(out_dir) if out_dir is not None else project.at_dir
    written = []
    for rel, text in texts.items():
        if isinstance(text, bytes):
            with atomic_path(out / rel) as tmp:
                tmp.write_bytes(text)
        else:
            write_text_atomic(out / rel, text)
        written.append(out / rel)
    log.info(f"exported {', '.join(formats)} of {project.root} -> {out}")
    return written
