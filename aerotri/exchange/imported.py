"""What an importer read from another program's files, and how it lands in a project folder.

An importer returns an :class:`ImportedBlock` in the project's CRS (coordinates converted through the
toolkit's one coordinate-operation policy, :func:`to_project_crs`). :func:`write_imported` turns it into
the project's own files:

| block field | project file | holds |
|---|---|---|
| ``camera`` | ``camera.toml`` | the camera |
| ``eo`` | ``imported/eo.txt`` | orientations as approximations (``aerotri adjust --eo imported/eo.txt``; ``ortho rectify --eo``) |
| ``gnss`` | ``gnss.txt`` | GNSS positions the adjustment weights as observations |
| ``control`` | ``control/points.csv`` | control and check points |
| ``image_points`` | ``control/image_points.csv`` | the control points' image measurements |
| ``gnss_section`` | ``project.toml`` ``[gnss]`` | the positions' model (appended when project.toml has no [gnss]) |
| ``terrain_height_m`` | ``project.toml`` ``[flight] mean_terrain_height_m`` | the terrain height for the frames' footprints (when project.toml has none) |

``gnss.txt`` gets only what the source measured with GNSS (EXIF positions) or, with ``--as-gnss``, a
reconstruction's positions the user declares to be GNSS, with the accuracies the user states
(``--sigma-xyz-m``) or the format's own (OpenSfM ``gps_dop``); :func:`positions_as_gnss` says which.
A reconstruction's camera centres are never weighted as GNSS by default: the adjustment would take
another program's solution for measurements (at the project's default 0.05 / 0.10 m).

``imported/imports.json`` lists every import: format, input files, and one entry per file written
(:class:`WrittenFile`: path, what it holds, count, from which input file), the same lines the console
prints. Existing project files are never overwritten without ``overwrite=True``; all files of one import
are written or none (:func:`aerotri.exchange.commit.write_together`).
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import json
import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from aerotri.core.atomic import refuse_input_as_output
from aerotri.core.errors import InputError, OptionError
from aerotri.core.log import counted
from aerotri.core.project import Project
from aerotri.exchange.commit import write_together
from aerotri.geom.camera import Camera
from aerotri.geom.eo import ExteriorOrientations, GnssPositions, format_eo, format_gnss
from aerotri.geom.observations import ControlPoints, ImageObservations, format_control_points, format_image_points

log = logging.getLogger(__name__)


@dataclasses.dataclass(kw_only=True)
class ImportedBlock:
    """Camera, positions, orientations and control read from another program's files (project CRS;
    pixel coordinates with the origin at the centre of the top-left pixel, x right, y down).

    ``origin``: the input file each field came from (field name -> file, for the record and the console);
    ``crs_assumed``: coordinates were taken in the project CRS because the files carry no CRS and no
    ``--crs`` was given (the import checks refuse that in a project whose CRS is not in metres)."""

    source: list[str]  # the files read
    camera: Camera | None = None
    gnss: GnssPositions | None = None
    eo: ExteriorOrientations | None = None
    control: ControlPoints | None = None
    image_points: ImageObservations | None = None
    notes: list[str] = dataclasses.field(default_factory=list)  # what the user should know (assumptions made)
    gnss_holds: str = "GNSS positions"  # what gnss.txt holds, in words (with where its accuracies came from)
    gnss_section: str | None = None  # a [gnss] section for project.toml (the positions' model), when it has none
    # [flight] mean_terrain_height_m for project.toml when it has none (the user's value is never replaced), and
    # where it came from (the comment written beside it)
    terrain_height_m: float | None = None
    terrain_height_from: str = ""
    origin: dict = dataclasses.field(default_factory=dict)
    crs_assumed: bool = False

    def contents(self) -> list[str]:
        return [name for name in ("camera", "gnss", "eo", "control", "image_points") if getattr(self, name) is not None]

    def source_of(self, field: str) -> str:
        if self.origin.get(field):
            return self.origin[field]
        names = [Path(s).name for s in self.source]
        # a folder of frames: the first and the last, not hundreds of names on one line
        return ", ".join(names) if len(names) <= 4 else f"{len(names)} files, {names[0]} ... {names[-1]}"


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImportSettings:
    """Choices a format may need. ``crs``: the CRS of the input when the file does not carry one;
    ``sigma_xyz_m``: accuracy of positions the source gives none for; ``as_gnss``: write the imported
    positions to gnss.txt as GNSS observations (see :func:`positions_as_gnss`)."""

    crs: str | None = None
    sigma_xyz_m: tuple[float, float, float] | None = None
    as_gnss: bool = False
    heights_measured: bool = False  # control heights that are all 0 (or all one number) are real, not placeholders


@dataclasses.dataclass(frozen=True)
class WrittenFile:
    """One file an import wrote: ``path`` relative to the project, what it ``holds``, ``count`` records,
    ``source``: the input file it came from."""

    path: str
    holds: str
    count: int
    source: str

    def __str__(self) -> str:
        return f"{self.path}: {self.count} {self.holds} (from {self.source})"


# the notes of the coordinate operations an import goes through (a missing grid, an operation of metres),
# collected by import_files around the importer's read: to_project_crs is called from every format's reader,
# some of them with no block at hand (rotation Jacobians)
_OPERATION_NOTES: contextvars.ContextVar[list[str] | None] = contextvars.ContextVar("operation_notes", default=None)


class HeightsAssumed(str):
    """The note that a 2D CRS's z were taken in the project's heights (an assumption: the file states none);
    :func:`heights_note_needed` drops it when the file's heights are the project's already."""


# a file's projection centres within this of at/eo.txt's heights at every common frame hold the project's heights:
# another height system moves them all by its separation (the geoid's N: metres to tens of metres, under 1 cm only
# where it crosses zero, where the systems agree to that); our exports write at/eo.txt's centres to 0.1 mm or finer
SAME_HEIGHTS_M = 0.01


def heights_note_needed(project: Project, block: ImportedBlock, notes: list[str]) -> list[str]:
    """``notes`` without the :class:`HeightsAssumed` notes when they say nothing: the block's projection centres
    agree in height with the project's at/eo.txt within ``SAME_HEIGHTS_M`` at every common frame (our own export read
    back into its project), and gnss.txt is not those centres (else the project's heights may be the file's own,
    taken in by an earlier import). Otherwise (no at/eo.txt, no common frame, heights that differ) ``notes``."""
    from aerotri.geom.crs.definition import height_unit_m, horizontal_crs, project_crs
    from aerotri.geom.eo import read_eo, read_gnss

    if block.eo is None or not any(isinstance(n, HeightsAssumed) for n in notes) or not project.eo_path.is_file():
        return notes
    tol = SAME_HEIGHTS_M / height_unit_m(horizontal_crs(project_crs(project)))  # project z is in the CRS's unit
    at = read_eo(project.eo_path)
    index = {iid: k for k, iid in enumerate(at.image_id)}
    pairs = [(index[iid], n) for n, iid in enumerate(block.eo.image_id) if iid in index]
    if not pairs:
        return notes
    a, b = np.array(pairs).T
    dz = np.abs(at.centre_m[a, 2] - block.eo.centre_m[b, 2])
    if dz.max() > tol:
        return notes
    if project.gnss_path.is_file():
        gnss = read_gnss(project.gnss_path)
        g = {iid: k for k, iid in enumerate(gnss.image_id)}
        common = [(g[iid], n) for n, iid in enumerate(block.eo.image_id) if iid in g]
        if common:
            gi, bi = np.array(common).T
            if np.linalg.norm(gnss.position_m[gi] - block.eo.centre_m[bi], axis=1).max() <= tol:
                return notes
    log.debug("z of %d projection centres within %.4f of at/eo.txt's: the project's heights, as taken", len(a),
              float(dz.max()))
    return [n for n in notes if not isinstance(n, HeightsAssumed)]


@contextlib.contextmanager
def collecting_operation_notes() -> Iterator[list[str]]:
    """The notes (each once) of every coordinate operation ``to_project_crs`` applies inside the block."""
    notes: list[str] = []
    token = _OPERATION_NOTES.set(notes)
    try:
        yield notes
    finally:
        _OPERATION_NOTES.reset(token)


def to_project_crs(xyz_m, from_crs, project: Project, source: str, *, ellipsoidal_2d: bool = False) -> np.ndarray:
    """(N, 3) coordinates of ``from_crs`` in the project CRS (and height system), through the toolkit's
    coordinate-operation policy (no silent ballpark transform; the operation's notes go to
    :func:`collecting_operation_notes`). A 2D ``from_crs`` declares no height system: its z is read in the project's
    heights, unless the format has a convention of its own, ``ellipsoidal_2d`` (Metashape's references, DJI/EXIF
    altitudes): then ellipsoidal heights, converted to the project's."""
    from aerotri.geom.crs.definition import (crs_label, parse_crs, project_crs, project_crs_3d, project_heights,
                                             same_crs, with_heights)
    from aerotri.geom.crs.transform import BallparkRefused, CrsTransformer, grid_advice

    xyz = np.asarray(xyz_m, float).reshape(-1, 3)
    src = parse_crs(from_crs, source)
    dst = project_crs(project)
    sink = _OPERATION_NOTES.get()
    convert_z = False
    if not src.is_compound and len(src.axis_info) == 2 and ellipsoidal_2d:
        # the format's own convention (review 22): Metashape's markers in an EPSG::4326 reference carry ellipsoidal
        # heights as its cameras' geocentric coordinates do (read in the project's, markers and cameras disagreed by
        # N on a geoid-height project); the policy reads a 2D CRS's z as ellipsoidal, so through the operation
        heights = project_heights(project)
        convert_z = heights is not None
        if convert_z:
            note = (f"{source}: {crs_label(src)} is a 2D CRS: z taken as ellipsoidal heights (the format's "
                    f"convention), converted to the project's ({heights.name})")
            if sink is not None and note not in sink:
                sink.append(note)
    elif not src.is_compound and len(src.axis_info) == 2:
        # a 2D CRS declares no height system: its z is read in the project's (on an orthometric project, H), the
        # same reading whether the file's CRS is the project's or another (a tmerc header took z as ellipsoidal
        # and lowered it by the geoid's N, the project's EPSG code kept it); said, as it is an assumption
        heights = project_heights(project)
        note = HeightsAssumed(f"{source}: {crs_label(src)} is a 2D CRS (no height system): z taken in the "
                              f"project's heights ({'ellipsoidal' if heights is None else heights.name}), not "
                              "converted")
        if sink is not None and note not in sink:
            sink.append(note)
        src = with_heights(src, heights)
    if not convert_z and (same_crs(src, dst) or same_crs(src, project_crs_3d(project))):
        return xyz.copy()
    try:
        operation = CrsTransformer(src, project_crs_3d(project))
    except BallparkRefused as exc:
        # the policy's remedy names --params and --allow-ballpark, which aerotri import does not take
        why = (grid_advice(exc.missing_grids) if exc.missing_grids else
               "PROJ knows no rigorous transformation between these datums, only a 'ballpark' one that ignores the "
               "datum shift (errors of decimetres to hundreds of metres)")
        raise BallparkRefused(
            f"{source}: {crs_label(src)} ({src.name}) -> project CRS {crs_label(dst)} ({dst.name}): {why}; aerotri "
            "import applies no datum parameters: transform the coordinates into the project CRS first (aerotri crs "
            "transform, on an 'id x y z' list, with --params from aerotri crs fit on common points, or "
            "--allow-ballpark) and import the result with --crs of the project, or choose a project CRS on the "
            "file's datum", missing_grids=exc.missing_grids) from None
    x, y, z = operation.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    if sink is not None:
        sink += [f"{source}: {w}" for w in operation.warnings if f"{source}: {w}" not in sink]
    return np.column_stack([x, y, z])


def control_sigma_m(project: Project, options: ImportSettings, path) -> np.ndarray:
    """(sx, sy, sz) metres of imported control points that carry no accuracies: ``--sigma-xyz-m``, else project.toml's
    [control] sigma_xy_m and sigma_z_m (``ControlPointSettings``: "imports without accuracies"); an OptionError
    naming both when neither is given."""
    if options.sigma_xyz_m:
        return np.asarray(options.sigma_xyz_m, float)
    c = project.control_points
    if c.sigma_xy_m is not None and c.sigma_z_m is not None:
        return np.array([c.sigma_xy_m, c.sigma_xy_m, c.sigma_z_m], float)
    raise OptionError(f"{path}: control points without accuracies; give --sigma-xyz-m SX SY SZ (m) or [control] "
                      f"sigma_xy_m, sigma_z_m in {project.config_path}", param="--sigma-xyz-m")


def positions_as_gnss(ids, position_m, *, options: ImportSettings, project: Project, what: str,
                      own_sigma_m=None, own_sigma_name: str = "") -> tuple[GnssPositions, str]:
    """(GNSS positions, what gnss.txt holds in words) of imported positions the user declared GNSS
    (``--as-gnss``). Accuracies: ``--sigma-xyz-m`` (the user's), else ``own_sigma_m`` (N, 3; the format's,
    named ``own_sigma_name``), else project.toml [gnss] sigma_xy_m and sigma_z_m when both are set (gnss.txt
    then carries none and the adjustment takes those); ``OptionError`` otherwise: a reconstruction's
    positions have no accuracy the toolkit could assume."""
    ids = list(ids)
    pos = np.asarray(position_m, float).reshape(-1, 3)
    if options.sigma_xyz_m is not None:
        s = np.asarray(options.sigma_xyz_m, float)
        sigma, said = np.tile(s, (len(ids), 1)), f"accuracies {s[0]:g} {s[1]:g} {s[2]:g} m from --sigma-xyz-m"
    elif own_sigma_m is not None:
        sigma = np.asarray(own_sigma_m, float).reshape(-1, 3)
        said = f"accuracies from {own_sigma_name} ({sigma.min():.3g}..{sigma.max():.3g} m)"
    else:
        # the defaults of [gnss] are an aerial GNSS/IMU's: another program's centres need their accuracy stated
        if any(project.source_of("gnss", k) != "project.toml" for k in ("sigma_xy_m", "sigma_z_m")):
            raise OptionError(f"--as-gnss: the {what} come without accuracies; state them with --sigma-xyz-m SX SY SZ "
                              f"(m) or [gnss] sigma_xy_m and sigma_z_m in {project.config_path}", param="--sigma-xyz-m")
        g = project.gnss
        sigma, said = None, (f"accuracies {g.sigma_xy_m:g} / {g.sigma_z_m:g} m from {project.config_path.name} "
                             "[gnss]")
    return GnssPositions(ids, pos.copy(), sigma), f"GNSS positions ({what}, --as-gnss; {said})"


# -- writing -----------------------------------------------------------------------------------------

def _files(project: Project, block: ImportedBlock) -> list[tuple[Path, str, WrittenFile]]:
    """(path, text, record) of every project file the block fills."""
    rel = lambda p: str(p.relative_to(project.root))  # noqa: E731
    out = []
    if block.camera is not None:
        out.append((project.camera_path, block.camera.to_toml(),
                    WrittenFile(path=rel(project.camera_path), holds=f"camera ({block.camera.MODEL}, "
                                f"{block.camera.width} x {block.camera.height} px)", count=1,
                                source=block.source_of("camera"))))
    if block.eo is not None:
        out.append((project.imported_eo_path, format_eo(block.eo),
                    WrittenFile(path=rel(project.imported_eo_path), holds="approximate orientations (projection "
                                "centres and attitudes; adjust with --eo imported/eo.txt)", count=len(block.eo),
                                source=block.source_of("eo"))))
    if block.gnss is not None:
        out.append((project.gnss_path, format_gnss(block.gnss, f" ({block.gnss_holds}, from "
                                                              f"{block.source_of('gnss')})"),
                    WrittenFile(path=rel(project.gnss_path), holds=block.gnss_holds, count=len(block.gnss.image_id),
                                source=block.source_of("gnss"))))
    if block.control is not None:
        kinds = {k: int(np.sum(block.control.kind == k)) for k in dict.fromkeys(block.control.kind)}
        out.append((project.control_points_path, format_control_points(block.control),
                    WrittenFile(path=rel(project.control_points_path), holds="control and check points ("
                                + ", ".join(f"{n} {k}" for k, n in kinds.items()) + ")", count=len(block.control.id),
                                source=block.source_of("control"))))
    if block.image_points is not None:
        out.append((project.control_image_points_path, format_image_points(block.image_points),
                    WrittenFile(path=rel(project.control_image_points_path), holds="image measurements of control "
                                "points", count=len(block.image_points), source=block.source_of("image_points"))))
    return out


def _holds_camera(path: Path, camera: Camera | None) -> bool:
    """True when the camera file ``path`` exists and holds ``camera`` (model and every value; the name aside)."""
    if camera is None or not path.is_file():
        return False
    try:
        there = Camera.read(path).to_dict()
    except InputError:
        return False
    here = camera.to_dict()
    there.pop("name"), here.pop("name")
    return there == here


def _with_terrain_height(project: Project, config: str, block: ImportedBlock) -> str | None:
    """project.toml's text with ``[flight] mean_terrain_height_m`` of the block and a comment saying where it came
    from: appended as a [flight] section, or put under the file's [flight] header; None when the file gives the key
    already (the user's value stays) or has no [flight] header line to put it under (a dotted key or inline table),
    and a note says so."""
    import re

    line = f"mean_terrain_height_m = {block.terrain_height_m:.1f}  # {block.terrain_height_from}\n"
    if project.source_of("flight", "mean_terrain_height_m") == "project.toml":
        block.notes.append(f"flight: {project.config_path.name} gives [flight] mean_terrain_height_m = "
                           f"{project.flight.mean_terrain_height_m:g}, kept (the import's "
                           f"{block.terrain_height_m:.1f} m is {block.terrain_height_from})")
        return None
    if "flight" not in project.config:
        return config.rstrip("\n") + "\n\n[flight]\n" + line
    header = re.search(r"(?m)^[ \t]*\[flight\][^\n]*(\n|\Z)", config)
    if header is None:
        block.notes.append(f"flight: {project.config_path.name} has [flight] keys but no [flight] header line to "
                           f"put mean_terrain_height_m = {block.terrain_height_m:.1f} under: not written")
        return None
    head = config[:header.end()] + ("" if header.group(1) else "\n")
    return head + line + config[header.end():]


def write_imported(root, block: ImportedBlock, format_name: str, overwrite: bool = False) -> list[WrittenFile]:
    """Write an imported block into a project folder (see the module docstring); returns what was written
    (the record file ``imported/imports.json`` last).

    Refuses (``InputError``) to replace an existing file unless ``overwrite`` (a camera.toml that holds the
    imported camera already is kept: aerotri init wrote it from the same EXIF), and to write onto a file the
    import read. All files are written or none (an error leaves the project as it was)."""
    project = Project.open(root)
    if not block.contents():
        raise InputError(f"{', '.join(block.source)}: nothing to import (no camera, positions, orientations or control)")
    files = _files(project, block)
    for path, _, _ in files:
        refuse_input_as_output(path, block.source, option="FILE")
    # camera.toml already holding this camera (aerotri init wrote it from the same EXIF) is kept, not replaced
    kept = [p for p, _, _ in files if p == project.camera_path and _holds_camera(p, block.camera)]
    files = [f for f in files if f[0] not in kept]
    existing = [p for p, _, _ in files if p.exists()]
    if existing and not overwrite:
        raise InputError(f"{', '.join(str(p) for p in existing)}: exists; the import would replace it "
                         f"(use --force to replace, or import into another project)")
    record_path = project.imported_record_path
    record = {"imports": []}
    if record_path.is_file():
        try:
            record = json.loads(record_path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            record = None
        if not isinstance(record, dict) or not isinstance(record.get("imports"), list):
            raise InputError(f"{record_path}: not a record of imports (expected {{\"imports\": [...]}}); move it away "
                             "to import")
    written = [w for _, _, w in files]
    contents = {p: text for p, text, _ in files}
    if block.gnss_section is not None and block.gnss is not None and "gnss" not in project.config:
        # appended, not replaced: the user's project.toml keeps every line
        contents[project.config_path] = (project.config_path.read_text(encoding="utf-8").rstrip("\n") + "\n\n"
                                         + block.gnss_section)
        written.append(WrittenFile(path=project.config_path.name, holds="[gnss] the GNSS positions' model (no "
                                   "accuracy in the source)", count=1, source=block.source_of("gnss")))
    if block.terrain_height_m is not None:
        config = contents.get(project.config_path) or project.config_path.read_text(encoding="utf-8")
        with_height = _with_terrain_height(project, config, block)
        if with_height is not None:
            contents[project.config_path] = with_height
            written.append(WrittenFile(path=project.config_path.name, holds=f"[flight] mean_terrain_height_m "
                                       f"({block.terrain_height_from})", count=1, source=block.source_of("gnss")))
    record["imports"].append({"format": format_name, "source": block.source,
                              "files": [dataclasses.asdict(w) for w in written], "notes": block.notes})
    contents[record_path] = json.dumps(record, indent=2) + "\n"
    write_together(contents)
    for path in kept:
        log.info(f"{path.relative_to(project.root)}: holds this camera already, kept")
    for note in block.notes:
        log.warning(note)
    log.debug(f"imported {', '.join(block.contents())} ({format_name}) from {', '.join(block.source)} into {project.root}")
    return written + [WrittenFile(path=str(record_path.relative_to(project.root)), holds="record of this import "
                                  f"({counted(len(written), 'file')} written)", count=1, source=format_name)]
