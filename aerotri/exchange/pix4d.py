"""Pix4D image geolocation and orientation file (export): the adjusted orientations as the input a Pix4D
project takes with "Import image geolocation and orientation" (PIX4Dmapper: Image Properties Editor > From File;
PIX4Dmatic: File > Import image geolocations and orientations).

Layout written (``pix4d/image_geolocation.csv`` and its CRS ``pix4d/image_geolocation.prj``)::

    # imagename,X,Y,Z,omega,phi,kappa,accuracy_horz_m,accuracy_vert_m (comment line: Pix4D reads no header)
    s01_001.tif,452252.8439,3407393.6127,760.5621,0.0851428,0.2980092,-93.9290552,0.0470,0.0143

Conventions (Pix4D's "projected coordinates, omega phi kappa, and accuracy values" layout): comma separated, no
header; X Y Z in the project CRS and its units (the image coordinate system Pix4D is told to use: the ``.prj``
holds its horizontal WKT; heights in the project's vertical datum, named in the comment line); omega phi kappa
in degrees, R = Rx(omega) Ry(phi) Rz(kappa) from the camera frame (x right, y up, z back, looking along -z) to
the map axes: the photogrammetric (PATB) convention of ``at/eo.txt``, so the angles pass unchanged; the
accuracies are the adjustment's standard deviations of the projection centre, horizontal = the root mean square
of sX and sY, vertical = sZ (without them in ``at/eo.txt`` the seven-column layout is written). Image names are
the file names in ``images/`` (Pix4D matches on them), the image id where there is no such file.
"""

from __future__ import annotations

import math

from aerotri.core.project import Project
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.exchange.poses import adjusted_orientations, horizontal_wkt
from aerotri.geom.images import ImageFiles, find_images


def files(block: AdjustedBlock, project: Project) -> list[ExportFile]:
    """``pix4d/image_geolocation.csv`` and ``.prj`` of the adjusted orientations (``at/eo.txt``)."""
    eo, _ = adjusted_orientations(project)
    frames = find_images(project.images_dir) if project.images_dir.is_dir() else ImageFiles((), ())
    columns = "imagename,X,Y,Z,omega,phi,kappa" + (",accuracy_horz_m,accuracy_vert_m" if eo.sigma is not None else "")
    rows = [f"# {columns} (aerotri export of {project.name}; X Y Z in {project.crs}, heights "
            f"{project.info.heights}; omega phi kappa in degrees, camera x right y up z back -> map axes)"]
    for i, iid in enumerate(eo.image_id):
        (x, y, z), (o, p, k) = eo.centre_m[i], eo.opk_deg[i]
        row = f"{frames.name_of(iid)},{x:.4f},{y:.4f},{z:.4f},{o:.7f},{p:.7f},{k:.7f}"
        if eo.sigma is not None:
            sx, sy, sz = eo.sigma[i, :3]
            row += f",{math.sqrt((sx * sx + sy * sy) / 2):.4f},{sz:.4f}"
        rows.append(row)
    return [ExportFile("pix4d/image_geolocation.csv", "\n".join(rows) + "\n"),
            ExportFile("pix4d/image_geolocation.prj", horizontal_wkt(project) + "\n")]
