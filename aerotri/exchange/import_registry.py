"""The import formats (name -> Importer) and the import of other programs' files into a project.

Adding a format is one module with a ``read(files, project, options) -> ImportedBlock`` function and one
line in ``IMPORT_FORMATS``; ``aerotri import --format`` offers the registry's names.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

from aerotri.core.errors import InputError, OptionError
from aerotri.core.project import Project
from aerotri.exchange import colmap, exif, metashape, micmac, odm, opensfm, orthority, patb
from aerotri.exchange.imported import ImportedBlock, ImportSettings, write_imported


@dataclasses.dataclass(frozen=True)
class Importer:
    name: str
    description: str
    read: Callable[[list[Path], Project, ImportSettings], ImportedBlock]
    files: str = "FILE..."  # what the format expects, for messages (e.g. "reconstruction.json")


IMPORT_FORMATS: dict[str, Importer] = {
    "orthority": Importer("orthority", "orthority interior YAML and exterior OPK CSV (+ .prj) or GeoJSON",
                          orthority.read, files="int_param.yaml [ext_param.csv | ext_param.geojson]"),
    "colmap": Importer("colmap", "COLMAP model, text or binary (cameras, images; world frame from georef.txt or --crs)",
                       colmap.read, files="MODEL_FOLDER (cameras.txt/.bin, images.txt/.bin[, georef.txt])"),
    "patb": Importer("patb", "PATB-style orientations, camera, control and image coordinates (aerotri's layout)",
                     patb.read, files="block.ori block.cam block.con block.im (any of them)"),
    "metashape": Importer("metashape", "Agisoft Metashape cameras XML (cameras, sensor, markers and their projections)",
                          metashape.read, files="cameras.xml"),
    "micmac": Importer("micmac", "MicMac DicoAppuisFlottant (control; 'check' in the name: check points) and "
                                 "SetOfMesureAppuisFlottants (image measurements) XML",
                       micmac.read, files="gcp.xml [check.xml] [measures.xml]"),
    "exif": Importer("exif", "GNSS positions, DJI RTK accuracies, camera (DJI DewarpData) and gimbal attitudes "
                             "from the images' EXIF/XMP", exif.read, files="IMAGE... or a folder"),
    "opensfm": Importer("opensfm", "OpenSfM/OpenDroneMap reconstruction: camera, orientations, GNSS positions",
                        opensfm.read, files="reconstruction.json"),
    "odm": Importer("odm", "OpenDroneMap ground control (control points and their image measurements)", odm.read,
                    files="gcp_list.txt"),
}


def import_files(root, format_name: str, files, options: ImportSettings | None = None,
                 overwrite: bool = False) -> list[Path]:
    """Read ``files`` of format ``format_name`` and write what they hold into the project folder ``root``
    (``aerotri.exchange.imported.write_imported``). Returns the files written."""
    if format_name not in IMPORT_FORMATS:
        raise OptionError(f"unknown import format {format_name!r}; expected one of {', '.join(IMPORT_FORMATS)}",
                          param="--format")
    files = [Path(f) for f in files]
    if not files:
        raise OptionError(f"no input file; {format_name} expects {IMPORT_FORMATS[format_name].files}", param="FILE")
    for f in files:
        if not f.exists():
            raise InputError(f"{f}: not found ({format_name} expects {IMPORT_FORMATS[format_name].files})")
    project = Project.open(root)
    block = IMPORT_FORMATS[format_name].read(files, project, options or ImportSettings())
    return write_imported(project.root, block, format_name, overwrite=overwrite)
