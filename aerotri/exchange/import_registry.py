"""The import formats (name -> Importer) and the import of other programs' files into a project.

Adding a format is one module with a ``read(files, project, options) -> ImportedBlock`` function and one
line in ``IMPORT_FORMATS``; ``aerotri import --format`` offers the registry's names. ``Importer.positions``
says what the format's positions are: ``"reconstruction"`` (another program's solution: orientations as
approximations in imported/eo.txt, gnss.txt only with ``--as-gnss``), ``"gnss"`` (GNSS measurements, as
the EXIF tags: gnss.txt) or ``None`` (no positions; ``--as-gnss`` refused).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

from aerotri.core.errors import InputError, OptionError
from aerotri.core.project import Project
from aerotri.exchange import colmap, exif, metashape, micmac, odm, opensfm, orthority, patb
from aerotri.exchange.imported import (ImportedBlock, ImportSettings, WrittenFile, collecting_operation_notes,
                                       heights_note_needed, write_imported)


@dataclasses.dataclass(frozen=True)
class Importer:
    name: str
    description: str
    read: Callable[[list[Path], Project, ImportSettings], ImportedBlock]
    files: str = "FILE..."  # what the format expects, for messages (e.g. "reconstruction.json")
    positions: str | None = "reconstruction"  # "reconstruction", "gnss" or None (see the module docstring)


IMPORT_FORMATS: dict[str, Importer] = {
    "orthority": Importer("orthority", "orthority interior YAML and exterior OPK CSV (+ .prj) or GeoJSON",
                          orthority.read, files="int_param.yaml [ext_param.csv | ext_param.geojson]"),
    "colmap": Importer("colmap", "COLMAP model, text or binary (cameras, images; world frame from georef.txt or --crs)",
                       colmap.read, files="MODEL_FOLDER (cameras.txt/.bin, images.txt/.bin[, georef.txt])"),
    "patb": Importer("patb", "PAT-B orientations (.ori), control (.con), image coordinates (.im) and aerotri's camera "
                             "(.cam)", patb.read, files="block.ori block.cam block*.con block.im numbers.txt (any of them)"),
    "metashape": Importer("metashape", "Agisoft Metashape cameras XML (cameras, sensor, markers and their projections)",
                          metashape.read, files="cameras.xml"),
    "micmac": Importer("micmac", "MicMac DicoAppuisFlottant (control; 'check' in the name: check points) and "
                                 "SetOfMesureAppuisFlottants (image measurements) XML",
                       micmac.read, files="gcp.xml [check.xml] [measures.xml]", positions=None),
    "exif": Importer("exif", "GNSS positions, DJI RTK accuracies, camera (DJI DewarpData) and gimbal attitudes "
                             "from the images' EXIF/XMP", exif.read, files="IMAGE... or a folder", positions="gnss"),
    "opensfm": Importer("opensfm", "OpenSfM/OpenDroneMap reconstruction: camera, orientations (and with --as-gnss "
                                   "the shots' GNSS positions)", opensfm.read, files="reconstruction.json"),
    "odm": Importer("odm", "OpenDroneMap ground control (control points and their image measurements)", odm.read,
                    files="gcp_list.txt", positions=None),
}


def importer_and_files(format_name: str, files) -> tuple[Importer, list[Path]]:
    """The registered importer of ``format_name`` and ``files`` as paths, each existing (OptionError naming
    ``--format`` or ``FILE``, InputError naming a missing file); ``import_files`` and ``aerotri compare`` read
    through it."""
    if format_name not in IMPORT_FORMATS:
        raise OptionError(f"unknown import format {format_name!r}; expected one of {', '.join(IMPORT_FORMATS)}",
                          param="--format")
    importer = IMPORT_FORMATS[format_name]
    files = [Path(f) for f in files]
    if not files:
        raise OptionError(f"no input file; {format_name} expects {importer.files}", param="FILE")
    for f in files:
        if not f.exists():
            raise InputError(f"{f}: not found ({format_name} expects {importer.files})")
    return importer, files


def import_files(root, format_name: str, files, options: ImportSettings | None = None,
                 overwrite: bool = False) -> list[WrittenFile]:
    """Read ``files`` of format ``format_name``, check them against the project
    (``aerotri.exchange.import_checks``) and write what they hold into the project folder ``root``
    (``aerotri.exchange.imported.write_imported``). Returns what was written, one record per file."""
    from aerotri.exchange.import_checks import check_import, plan_only_when_unmeasured
    from aerotri.geom.eo import check_block_crs

    options = options or ImportSettings()
    importer, files = importer_and_files(format_name, files)
    if options.as_gnss and importer.positions is None:
        raise OptionError(f"{format_name} files hold no positions; --as-gnss is for formats with camera positions",
                          param="--as-gnss")
    project = Project.open(root)
    check_block_crs(project.crs, f"{project.config_path} [project] crs")  # before reading: no degrees, no geocentric
    with collecting_operation_notes() as operation_notes:
        block = importer.read(files, project, options)
    block.notes += heights_note_needed(project, block, operation_notes)
    if importer.positions == "reconstruction" and block.eo is not None and block.gnss is None \
            and not any("--as-gnss" in n for n in block.notes):
        block.notes.append(f"positions: the {len(block.eo)} projection centres are another program's solution: "
                           "imported/eo.txt (approximations), not gnss.txt (--as-gnss with --sigma-xyz-m to weight them "
                           "as GNSS)")
    replaced = {p for p, name in ((project.camera_path, "camera"), (project.gnss_path, "gnss"),
                                  (project.imported_eo_path, "eo"), (project.control_points_path, "control"),
                                  (project.control_image_points_path, "image_points"))
                if getattr(block, name) is not None}
    block.notes += check_import(project, block, replaced, format_name)
    plan_only_when_unmeasured(block, options.heights_measured, format_name)
    return write_imported(project.root, block, format_name, overwrite=overwrite)
