"""MicMac's ground control XML (``DicoAppuisFlottant``) and image measurement XML
(``SetOfMesureAppuisFlottants``): export and import.

Layouts (MicMac's GCPConvert / SaisieAppuis files)::

    <Global><DicoAppuisFlottant>
      <OneAppuisDAF><Pt>X Y Z</Pt><NamePt>gcp1</NamePt><Incertitude>sX sY sZ</Incertitude></OneAppuisDAF> ...
    </DicoAppuisFlottant></Global>

    <SetOfMesureAppuisFlottants>
      <MesureAppuiFlottant1Im><NameIm>IMG_1.tif</NameIm>
        <OneMesureAF1I><NamePt>gcp1</NamePt><PtIm>x y</PtIm></OneMesureAF1I> ...
      </MesureAppuiFlottant1Im> ...
    </SetOfMesureAppuisFlottants>

(the ``<Global>`` wrapper is optional when reading). Coordinates in the project CRS (MicMac's files carry
none; ``--crs`` for files in another CRS). MicMac has no units: ``Incertitude`` is in the unit of ``Pt`` (US
survey feet in an EPSG:2227 project), converted from and to control/points.csv's metres (sx_m). An ``Incertitude`` of -1 marks an axis MicMac does not use:
horizontal control is written with sZ = -1, height control with sX = sY = -1, and read back so (the unused
axis gets the largest used accuracy as a placeholder: control/points.csv needs positive sigmas). MicMac has
no check-point flag: check points go to a file of their own (``micmac/check.xml``) and a control file whose
name contains ``check`` is read as check points. Image measurements: pixel coordinates with the origin at
the centre of the top-left pixel (MicMac samples a pixel's value at integer coordinates), as ours, no
shift; ``NameIm`` is the image's file name in ``images/`` (the id when there is none) and is read back
without folder and image extension.

Export (``micmac/``): ``gcp.xml`` (control), ``check.xml`` (check points, when there are any) and
``measures.xml`` (the control points' measurements of control/image_points.csv, as measured). Import: any of
those -> control/points.csv and control/image_points.csv.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_xml
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.exchange.imported import ImportedBlock, ImportSettings, to_project_crs
from aerotri.exchange.poses import image_id_of, number
from aerotri.geom.images import ImageFiles, find_images
from aerotri.geom.observations import ControlPoints, ImageObservations, read_control_points, read_image_points

NOT_USED = -1.0


def _fmt(v) -> str:
    return f"{float(v):.4f}"


def _gcp_xml(cp: ControlPoints, unit_m: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> str:
    """``unit_m``: metres per unit of the coordinates' x, y, z (``Incertitude`` is written in them)."""
    root = ET.Element("Global")
    dico = ET.SubElement(root, "DicoAppuisFlottant")
    for pid, kind, xyz, sig in zip(cp.id, cp.kind, cp.xyz_m, cp.sigma_m):
        one = ET.SubElement(dico, "OneAppuisDAF")
        ET.SubElement(one, "Pt").text = " ".join(_fmt(v) for v in xyz)
        ET.SubElement(one, "NamePt").text = str(pid)
        s = [float(v) / u for v, u in zip(sig, unit_m)]
        if kind == "horizontal":
            s[2] = NOT_USED
        elif kind == "height":
            s[0] = s[1] = NOT_USED
        ET.SubElement(one, "Incertitude").text = " ".join(f"{v:g}" for v in s)
    ET.indent(root)
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def files(block: AdjustedBlock, project: Project) -> list[ExportFile]:
    if not project.control_points_path.is_file():
        return []
    from aerotri.geom.crs.definition import map_axes_unit_m, project_crs

    cp = read_control_points(project.control_points_path)
    out = []
    check = np.array([k == "check" for k in cp.kind], bool)
    unit_m = map_axes_unit_m(project_crs(project), "[project] crs")  # sx_m (metres) -> Pt's unit
    if (~check).any():
        out.append(ExportFile("micmac/gcp.xml", _gcp_xml(cp.subset(~check), unit_m)))
    if check.any():
        out.append(ExportFile("micmac/check.xml", _gcp_xml(cp.subset(check), unit_m)))
    if project.control_image_points_path.is_file():
        from aerotri.exchange.odm_export import rejected_pairs

        obs = read_image_points(project.control_image_points_path)
        left_out = rejected_pairs(block, project, "micmac")
        obs = obs.subset(np.array([(str(p), str(i)) not in left_out for p, i in zip(obs.point_id, obs.image_id)],
                                  bool))
        frames = find_images(project.images_dir) if project.images_dir.is_dir() else ImageFiles((), ())
        root = ET.Element("SetOfMesureAppuisFlottants")
        for iid in dict.fromkeys(obs.image_id):
            im = ET.SubElement(root, "MesureAppuiFlottant1Im")
            ET.SubElement(im, "NameIm").text = frames.name_of(iid)
            for k in np.flatnonzero(obs.image_id == iid):
                one = ET.SubElement(im, "OneMesureAF1I")
                ET.SubElement(one, "NamePt").text = str(obs.point_id[k])
                ET.SubElement(one, "PtIm").text = f"{obs.xy_px[k, 0]:.3f} {obs.xy_px[k, 1]:.3f}"
        ET.indent(root)
        out.append(ExportFile("micmac/measures.xml",
                              '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding="unicode") + "\n"))
    return out


# -- import ------------------------------------------------------------------------------------------

def _parse(path: Path):
    return read_xml(path, "MicMac XML")


def _text(el, tag: str, where: str) -> str:
    t = el.find(tag)
    if t is None or t.text is None or not t.text.strip():
        raise InputError(f"{where}: <{tag}> is missing")
    return t.text.strip()


def _vector(el, tag: str, n: int, where: str) -> list[float]:
    parts = _text(el, tag, where).split()
    if len(parts) != n:
        raise InputError(f"{where}: <{tag}> needs {n} numbers, got {len(parts)}")
    return [number(p, where, tag) for p in parts]


def read_gcp(path: Path, root, project: Project, options: ImportSettings) -> ControlPoints:
    from aerotri.geom.crs.definition import height_unit_m, linear_unit_m, parse_crs, project_crs

    # Incertitude is in Pt's unit (the file's CRS: --crs, else the project's); control/points.csv's in metres
    crs = parse_crs(options.crs, "--crs") if options.crs else project_crs(project)
    unit_m = np.array([linear_unit_m(crs)] * 2 + [height_unit_m(crs)])
    unit_m = np.where(np.isfinite(unit_m), unit_m, 1.0)  # a geographic --crs: refused later by the import checks
    dico = root if root.tag == "DicoAppuisFlottant" else root.find("DicoAppuisFlottant")
    ids, kinds, xyz, sig = [], [], [], []
    check = "check" in path.stem.lower()
    for n, one in enumerate(dico.findall("OneAppuisDAF")):
        where = f"{path} OneAppuisDAF[{n}]"
        pid = _text(one, "NamePt", where)
        where = f"{path} point {pid!r}"
        if pid in ids:
            raise InputError(f"{where}: duplicate NamePt")
        p = _vector(one, "Pt", 3, where)
        if one.find("Incertitude") is not None:
            s = [v * u if v > 0 else v for v, u in zip(_vector(one, "Incertitude", 3, where), unit_m)]
        elif options.sigma_xyz_m:
            s = list(options.sigma_xyz_m)
        else:
            raise InputError(f"{where}: no <Incertitude>; give --sigma-xyz-m")
        free_xy, free_z = s[0] <= 0 or s[1] <= 0, s[2] <= 0
        if free_xy and free_z:
            raise InputError(f"{where}: Incertitude {s} leaves every axis unused")
        if (s[0] <= 0) != (s[1] <= 0):
            raise InputError(f"{where}: Incertitude {s}: X and Y must both be used or both not")
        kind = "check" if check else "height" if free_xy else "horizontal" if free_z else "full"
        # an unused axis keeps a placeholder accuracy (the project's files need positive sigmas)
        used = [v for v in s if v > 0]
        s = [v if v > 0 else max(used) for v in s]
        ids.append(pid)
        kinds.append(kind)
        xyz.append(p)
        sig.append(s)
    if not ids:
        raise InputError(f"{path}: no OneAppuisDAF points")
    a = np.array(xyz)
    if options.crs:
        a = to_project_crs(a, options.crs, project, "--crs")
    return ControlPoints(np.array(ids, object), np.array(kinds, object), a, np.array(sig, float))


def read_measures(path: Path, root) -> ImageObservations:
    pids, iids, xy, seen = [], [], [], set()
    for n, im in enumerate(root.findall("MesureAppuiFlottant1Im")):
        where = f"{path} MesureAppuiFlottant1Im[{n}]"
        iid = image_id_of(_text(im, "NameIm", where))
        for one in im.findall("OneMesureAF1I"):
            pid = _text(one, "NamePt", f"{where} (image {iid!r})")
            w = f"{path} image {iid!r} point {pid!r}"
            if (pid, iid) in seen:
                raise InputError(f"{w}: measured twice")
            seen.add((pid, iid))
            xy.append(_vector(one, "PtIm", 2, w))
            pids.append(pid)
            iids.append(iid)
    if not pids:
        raise InputError(f"{path}: no OneMesureAF1I measurements")
    return ImageObservations(np.array(pids, object), np.array(iids, object), np.array(xy, float))


def read(files: list[Path], project: Project, options: ImportSettings) -> ImportedBlock:
    block = ImportedBlock(source=[str(f) for f in files])
    controls = []
    for f in files:
        root = _parse(f)
        if root.tag == "SetOfMesureAppuisFlottants":
            if block.image_points is not None:
                raise InputError(f"{f}: a second measurement file (import one)")
            block.image_points = read_measures(f, root)
            block.origin["image_points"] = f.name
        elif root.tag == "DicoAppuisFlottant" or root.find("DicoAppuisFlottant") is not None:
            controls.append(read_gcp(f, root, project, options))
            block.origin["control"] = ", ".join(filter(None, [block.origin.get("control"), f.name]))
        else:
            raise InputError(f"{f}: neither DicoAppuisFlottant (ground control) nor SetOfMesureAppuisFlottants "
                             "(image measurements)")
    if controls:
        cp = ControlPoints(*(np.concatenate([getattr(c, k) for c in controls]) for k in ("id", "kind", "xyz_m", "sigma_m")))
        dup = sorted({p for p in cp.id if list(cp.id).count(p) > 1})
        if dup:
            raise InputError(f"{', '.join(block.source)}: points {dup} are in more than one control file")
        block.control = cp
        block.crs_assumed = options.crs is None  # DicoAppuisFlottant carries no CRS
    return block
