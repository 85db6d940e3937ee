"""The export formats (name -> Exporter) and the export of a project folder."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Callable

from aerotri.core.errors import OptionError
from aerotri.core.project import Project
from aerotri.exchange import colmap, layers, metashape, micmac, odm_export, orthority, patb, pix4d
from aerotri.exchange.adjusted import AdjustedBlock, read_adjusted_block
from aerotri.exchange.commit import ExportFile, write_together
from aerotri.geom.crs.transform import BallparkRefused
from aerotri.geom.images import find_images

log = logging.getLogger(__name__)


def _image_names(project: Project) -> dict | None:
    """image id -> file name in images/ (None without images/), as the COLMAP writers take them."""
    return {k: p.name for k, p in find_images(project.images_dir).pairs()} if project.images_dir.is_dir() else None


def _georef_crs(project: Project) -> str:
    """The CRS of a COLMAP model's georef.txt: the project's with its heights (a vertical CRS: the compound's WKT)."""
    from aerotri.geom.crs.definition import project_crs_3d, project_heights

    return project.crs if project_heights(project) is None else project_crs_3d(project).to_wkt()


@dataclasses.dataclass(frozen=True)
class Exporter:
    name: str
    description: str
    files: Callable[[AdjustedBlock, Project], list[ExportFile]]  # paths relative to the output folder


EXPORT_FORMATS = {
    "patb": Exporter("patb", "PAT-B orientations, control and image coordinates (patb/block.ori, .con, .im; check and "
                             "partial control in their own .con files), the number map and aerotri's camera (patb/"
                             "numbers.txt, block.cam)", patb.files),
    "colmap": Exporter("colmap", "COLMAP text model (colmap/cameras.txt, images.txt, points3D.txt)",
                       lambda block, project: colmap.files(block, _image_names(project), _georef_crs(project))),
    "colmap-bin": Exporter("colmap-bin", "COLMAP binary model (colmap_bin/cameras.bin, images.bin, points3D.bin)",
                           lambda block, project: colmap.binary_files(block, _image_names(project),
                                                                      _georef_crs(project))),
    "orthority": Exporter("orthority", "orthority interior YAML, OPK CSV + .prj and exterior GeoJSON (orthority/)",
                          orthority.files),
    "metashape": Exporter("metashape", "Agisoft Metashape cameras XML with markers (metashape/cameras.xml)",
                          metashape.files),
    "micmac": Exporter("micmac", "MicMac ground control and image measurement XML (micmac/gcp.xml, check.xml, "
                                 "measures.xml)", micmac.files),
    "odm": Exporter("odm", "OpenDroneMap/OpenSfM: orientations, camera and points (odm/opensfm/reconstruction.json, "
                           "odm/cameras.json), ground control (odm/gcp_list.txt; plan-only control: "
                           "odm/opensfm/ground_control_points.json), "
                           "check points and rejected measurements (odm/gcp_list_check.txt, gcp_list_rejected.txt)",
                    lambda block, project: odm_export.files(block, project, _image_names(project))),
    "pix4d": Exporter("pix4d", "Pix4D image geolocation and orientation file: X Y Z omega phi kappa and accuracies "
                               "(pix4d/image_geolocation.csv + .prj)", pix4d.files),
    "gpkg": Exporter("gpkg", "GeoPackage map layers: control/check points with ground residuals, frame footprints, "
                             "projection centres (layers/block.gpkg, project CRS)",
                     lambda block, project: layers.files(block, project, "gpkg")),
    "kml": Exporter("kml", "the same layers as KML (layers/block.kml, WGS84)",
                    lambda block, project: layers.files(block, project, "kml")),
}
DEFAULT_FORMATS = ("patb", "colmap")


def _export_refusal(name: str, exc) -> Exception:
    """The CRS policy's refusal in the export's terms: its remedy names ``--params`` and ``--allow-ballpark``,
    which aerotri export does not take (a missing geoid grid: the grid is the fix)."""
    text = str(exc)
    cut = text.find("; or fit parameters")
    if cut < 0:
        cut = text.find("fit parameters from common points")
    if cut >= 0:
        text = text[:cut].rstrip("; ")
    # the policy's "<state the datum>; otherwise fit parameters ..." (a definition by its ellipsoid alone) lost its
    # alternative with the cut: the "otherwise" goes with the export's own (review 43: "...file); otherwise; aerotri")
    otherwise = text.endswith("otherwise")
    if otherwise:
        text = text[:-len("otherwise")].rstrip("; ")
    if not exc.missing_grids:
        text += ("; aerotri export applies no datum parameters: " + ("otherwise, " if otherwise else "")
                 + "choose a project CRS on a datum PROJ relates to the format's rigorously")
    return BallparkRefused(f"{name} export: {text}", missing_grids=exc.missing_grids)


def export_project(root, formats=DEFAULT_FORMATS, out_dir=None) -> list[Path]:
    """Export the adjusted block of a project folder into ``out_dir`` (default ``at/``); every format's
    files are produced first and written afterwards, all or none. Returns the files written."""
    unknown = [f for f in formats if f not in EXPORT_FORMATS]
    if unknown:
        raise OptionError(f"unknown export format(s) {', '.join(unknown)}; expected {', '.join(EXPORT_FORMATS)}",
                          param="--format")
    project = Project.open(root)
    block = read_adjusted_block(project.root)
    out = Path(out_dir) if out_dir is not None else project.at_dir
    if not block.heights_measured:
        # trial-kite: ODM's reference_lla altitude 20.7 m, read as a WGS 84 height, for a beach about -30 m
        log.warning(f"{project.root}: no height of this block was measured (plan-only control, no GNSS or DEM; "
                    f"{project.adjustment_report_path} DATUM): every height exported ({', '.join(formats)}: camera "
                    "and point heights, ODM's reference_lla altitude) is relative, 0 at the control points' median "
                    "ground, not an ellipsoidal or orthometric height")
    contents = {}  # (a later format's file of the same name replaces the earlier one's)
    refused = []  # every format a missing grid stops, named at once (trial s96 L1: one per run, three runs)
    for name in formats:
        try:
            files = EXPORT_FORMATS[name].files(block, project)
        except BallparkRefused as exc:
            if not exc.missing_grids:
                raise _export_refusal(name, exc) from None
            refused.append((name, exc))
            continue
        if not files:
            # trial-odm: "exported micmac" for a block without control, and no file (MicMac's export holds control
            # only); a format with nothing to write says so
            log.warning(f"{name}: nothing to write for this block ({EXPORT_FORMATS[name].description}); no {name} "
                        "files")
        contents.update({out / f.path: f.content for f in files})
    if refused:
        first = _export_refusal(*refused[0])
        others = [n for n, _ in refused[1:]]
        raise BallparkRefused(str(first) + (f" (the same grid stops {', '.join(others)} too)" if others else ""),
                              missing_grids=first.missing_grids)
    written = write_together(contents)
    log.info(f"exported {', '.join(formats)} of {project.root} -> {out}")
    return written
