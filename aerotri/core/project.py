"""A project folder (architecture doc) and its ``project.toml``.

```
project.toml   [project] name, crs; [gnss] sigmas and lever arm; [control] sigmas; stage sections
camera.toml    frame camera (aerotri.geom.camera)
gnss.txt       image_id X Y Z [sX sY sZ]
lidar/ images/ lidar_out/ control/ work/ at/ ortho/
```

The project sections ([project], [camera], [gnss], [control] sigmas, [flight], [qa]) are the settings
dataclasses below, read and checked when the project is opened (``Project.info``, ``.gnss``, ...); the
stage sections ([adjust], [match], ...) belong to the stages' settings (``aerotri.chain.options``), which
read them through ``Project.stage_table`` (``aerotri.core.settings.resolve``). Nothing else reads
project.toml. The reference of every key: docs/settings.md (``aerotri settings --markdown``).
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import ClassVar

from aerotri.core.errors import ConfigError, InputError
from aerotri.core.settings import from_table, setting
from aerotri.core.textio import read_text


@dataclasses.dataclass(frozen=True)
class ProjectSettings:
    """The project: its name, coordinate reference system and height system."""

    SECTION: ClassVar[str] = "project"
    crs: str | None = setting(None, help="Projected CRS of every coordinate of the project (EPSG:code, WKT or PROJ "
                                         "text, or a .wkt/.prj file in the project folder), a metre grid; required.")
    name: str | None = setting(None, help="Project name in reports (default: the folder's name).")
    heights: str = setting("ellipsoidal", help="Heights of the EO, GNSS and DEMs: ellipsoidal, or a vertical CRS "
                                               "such as EPSG:3855 (EGM2008).")


@dataclasses.dataclass(frozen=True)
class CameraSettings:
    """The nominal frame camera."""

    SECTION: ClassVar[str] = "camera"
    file: Path = setting(Path("camera.toml"), path=True, help="Camera file (aerotri.geom.camera TOML), relative to "
                                                              "the project folder.")


# A lever arm's component beyond this is no aircraft's (decimetres to a few metres): millimetres written as metres
# ([50, -120, 1450]) put the camera 1.45 km below its antenna and stopped aerotri adjust with a traceback
LEVER_ARM_MAX_M = 20.0


@dataclasses.dataclass(frozen=True)
class GnssSettings:
    """The GNSS antenna positions of gnss.txt: their a-priori precision and the antenna's lever arm."""

    SECTION: ClassVar[str] = "gnss"
    sigma_xy_m: float = setting(0.05, min=0.0, min_open=True, help="A-priori standard deviation of a GNSS position "
                                                                    "in plan (records of gnss.txt without their own).")
    sigma_z_m: float = setting(0.1, min=0.0, min_open=True, help="A-priori standard deviation of a GNSS height.")
    offset_sigma_xy_m: float | None = setting(
        None, min=0.0, min_open=True,
        help="A consumer receiver: a-priori standard deviation in plan of one offset common to every position of the "
             "flight (its absolute accuracy, metres), which the adjustment estimates; sigma_xy_m and sigma_z_m are "
             "then the errors between frames (decimetres). aerotri import --format exif writes it when the EXIF "
             "states no accuracy. Not given: no offset (a survey receiver's positions).")
    offset_sigma_z_m: float | None = setting(None, min=0.0, min_open=True,
                                             help="The flight offset's a-priori standard deviation in height (with "
                                                  "offset_sigma_xy_m).")
    lever_arm_m: tuple[float, float, float] = setting(
        (0.0, 0.0, 0.0), min=-LEVER_ARM_MAX_M, max=LEVER_ARM_MAX_M,
        help="Antenna offset from the projection centre in the camera frame (x right, y up, z up), m (a value beyond "
             f"{LEVER_ARM_MAX_M:g} m is taken for millimetres and refused).")

    def __post_init__(self):
        if (self.offset_sigma_xy_m is None) != (self.offset_sigma_z_m is None):
            raise ValueError("offset_sigma_xy_m and offset_sigma_z_m: give both (the flight offset's a-priori "
                             "standard deviations in plan and height, m) or neither")

    @property
    def offset_sigma_m(self) -> tuple[float, float, float] | None:
        """(east, north, up) a-priori sigma of the flight's GNSS offset (m), or None: no offset."""
        if self.offset_sigma_xy_m is None:
            return None
        return (self.offset_sigma_xy_m, self.offset_sigma_xy_m, self.offset_sigma_z_m)


@dataclasses.dataclass(frozen=True)
class ControlPointSettings:
    """The a-priori precision of control points that come without their own (the sigma keys of [control];
    the section's other keys are the control stage's)."""

    SECTION: ClassVar[str] = "control"
    sigma_xy_m: float | None = setting(None, min=0.0, min_open=True,
                                       help="A-priori standard deviation of a control point in plan (imports without "
                                            "accuracies).")
    sigma_z_m: float | None = setting(None, min=0.0, min_open=True, help="A-priori standard deviation of a control "
                                                                          "point's height.")


@dataclasses.dataclass(frozen=True)
class FlightSettings:
    """The flight plan: the terrain height the footprints of the frames are placed on, the speed."""

    SECTION: ClassVar[str] = "flight"
    mean_terrain_height_m: float | None = setting(None, help="Mean terrain height (project heights) for the frame "
                                                             "footprints (default: lidar_out/dem.tif's mean).")
    speed_mps: float | None = setting(None, min=0.0, min_open=True, help="Ground speed of the aircraft.")


@dataclasses.dataclass(frozen=True)
class QaSettings:
    """The accuracy report's tolerance table. Nothing given: chosen by the block's GSD and platform
    (aerotri.core.tolerances.choose_table; docs/tolerances.md)."""

    SECTION: ClassVar[str] = "qa"
    map_scale: str | None = setting(None, help="Chinese map-scale table: 1:2000, 1:5000, 1:10000 (default: by the "
                                               "block's GSD and platform).")
    terrain: str | None = setting(None, help="Terrain class of a map-scale table: flat, hilly, mountainous (or a "
                                             "section of your own table); default flat.")
    tolerances: Path | None = setting(None, path=True, help="Your own tolerance table (TOML, the layout of "
                                                            "aerotri/core/tolerance_tables/cn_*.toml).")
    pdf: bool = setting(False, help="Also write reports/report.pdf.")
    standard: str | None = setting(None, choices=("asprs2023", "asprs2014", "usgs-lbs", "cn-at", "thesis", "cn"),
                                   help="Standard of the report: asprs2023 (classes by GSD unless given), asprs2014 "
                                        "(Edition 1: classes given, H per axis, the VVA judged), usgs-lbs "
                                        "(LiDAR quality levels), cn-at (Chinese AT specifications by map scale), thesis "
                                        "(the map-scale tables; cn is its old name); default by the block's GSD and "
                                        "platform (docs/standards.md).")
    platform: str | None = setting(None, choices=("manned", "uas"),
                                   help="manned or uas (default: from the flying height above ground).")
    horizontal_class_cm: float | None = setting(None, min=0.0, min_open=True,
                                                help="ASPRS 2023 horizontal accuracy class (RMSE_H, cm).")
    vertical_class_cm: float | None = setting(None, min=0.0, min_open=True,
                                              help="ASPRS 2023 vertical accuracy class (RMSE_V, cm).")
    accuracy_class: str | None = setting(None, help="Class tested by the compliance section: 'H7.1 V10' (asprs2023, "
                                                    "asprs2014 with H per axis; cm), QL0-QL3 (usgs-lbs), a map scale "
                                                    "1:500-1:10000 (cn-at, thesis).")
    survey_sigma_xy_m: float | None = setting(None, min=0.0, min_open=True,
                                              help="Survey accuracy (per-axis sigma) of the check points of the DOM, line "
                                                   "map and LiDAR checks (ASPRS 2023 includes it in the product figure).")
    survey_sigma_z_m: float | None = setting(None, min=0.0, min_open=True,
                                             help="Survey accuracy (sigma) of the heights of those check points.")


# The project sections: read when the project is opened. [control] is shared with the control stage.
PROJECT_SECTIONS = {c.SECTION: c for c in (ProjectSettings, CameraSettings, GnssSettings, ControlPointSettings,
                                           FlightSettings, QaSettings)}
# The stage sections (their keys are the fields of each stage's settings, checked by the stage and by
# ``aerotri run``; aerotri.chain.options.STAGE_SECTIONS holds the same names).
STAGE_SECTION_NAMES = ("strips", "classify", "rasters", "corners", "vectors", "match", "adjust", "control", "rectify",
                       "mosaic", "dom_check")


def _keys(cls) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


@dataclasses.dataclass(frozen=True)
class ProjectSections:
    """The project sections of a project.toml, checked (``PROJECT_SECTIONS``; a section not given: its defaults).
    Field names are the section names."""

    project: ProjectSettings = dataclasses.field(default_factory=ProjectSettings)
    camera: CameraSettings = dataclasses.field(default_factory=CameraSettings)
    gnss: GnssSettings = dataclasses.field(default_factory=GnssSettings)
    control: ControlPointSettings = dataclasses.field(default_factory=ControlPointSettings)
    flight: FlightSettings = dataclasses.field(default_factory=FlightSettings)
    qa: QaSettings = dataclasses.field(default_factory=QaSettings)


assert tuple(f.name for f in dataclasses.fields(ProjectSections)) == tuple(PROJECT_SECTIONS)  # one field a section


def check_sections(config: dict, source) -> ProjectSections:
    """Refuse an unknown section, an unknown key of a project section, a bad value of one, and a section given
    as a value, naming ``source`` (project.toml), the section and the key; returns the project sections'
    settings."""
    out = {}
    for section, table in config.items():
        if section not in PROJECT_SECTIONS and section not in STAGE_SECTION_NAMES:
            raise ConfigError(f"{source}: unknown section [{section}] (project sections: "
                              f"{', '.join(PROJECT_SECTIONS)}; stage sections: {', '.join(STAGE_SECTION_NAMES)})")
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: {section} must be a section [{section}], not a single value")
    for section, cls in PROJECT_SECTIONS.items():
        table = config.get(section, {})
        if section in STAGE_SECTION_NAMES:  # shared with a stage: the stage checks its own keys
            table = {k: v for k, v in table.items() if k in _keys(cls)}
        # file names stay as written (relative to the project folder, which the folder's paths anchor)
        out[section] = from_table(cls, table, f"{source} [{section}]")
    return ProjectSections(**out)


@dataclasses.dataclass
class Project:
    """A project folder and its ``project.toml`` (``config``: the parsed file; read it through the typed
    sections, never by key)."""

    root: Path
    config: dict
    sections: ProjectSections = dataclasses.field(default_factory=ProjectSections, repr=False)

    @classmethod
    def open(cls, root) -> "Project":
        root = Path(root)
        if not root.is_dir():
            raise InputError(f"{root}: project folder not found")
        cfg_path = root / "project.toml"
        if not cfg_path.exists():
            # a folder holding the project one level down (docs trial s98 L6: `aerotri run out/demo`, the demo's
            # project in out/demo/project)
            inner = sorted(p.parent.name for p in root.glob("*/project.toml"))
            raise InputError(f"{cfg_path}: missing (every project folder needs project.toml with [project] crs)"
                             + (f"; {', '.join(str(root / n) for n in inner[:3])} "
                                f"{'is a project' if len(inner) == 1 else 'are projects'}" if inner else ""))
        try:
            config = tomllib.loads(read_text(cfg_path, "project file (TOML)"))
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{cfg_path}: not valid TOML ({exc})") from None
        sections = check_sections(config, cfg_path)
        if sections.project.crs is None:
            raise ConfigError(f"{cfg_path}: [project] crs is missing (e.g. crs = \"EPSG:32649\")")
        return cls(root, config, sections)

    def _section(self, cls):
        return getattr(self.sections, cls.SECTION)

    info = property(lambda self: self._section(ProjectSettings), doc="[project]")
    camera = property(lambda self: self._section(CameraSettings), doc="[camera]")
    gnss = property(lambda self: self._section(GnssSettings), doc="[gnss]")
    control_points = property(lambda self: self._section(ControlPointSettings), doc="[control] sigmas")
    flight = property(lambda self: self._section(FlightSettings), doc="[flight]")
    qa = property(lambda self: self._section(QaSettings), doc="[qa]")

    @property
    def config_path(self) -> Path:
        return self.root / "project.toml"

    @property
    def name(self) -> str:
        return self.info.name or self.root.name

    @property
    def crs(self) -> str:
        """[project] crs as CRS text: a .wkt/.prj file's WKT, its name relative to the project folder
        (``crs_setting_text``; not the current directory, review 44)."""
        from aerotri.core.crs_files import crs_setting_text

        return str(crs_setting_text(self.info.crs, self.root, f"{self.config_path} [project] crs"))

    def source_of(self, section: str, key: str) -> str:
        """Where a project section's setting came from: ``project.toml`` when the file gives it, else ``default``."""
        return "project.toml" if key in self.config.get(section, {}) else "default"

    def stage_table(self, name: str) -> dict:
        """The raw table of a stage section (for ``aerotri.core.settings.resolve``, which checks it); the keys
        of a project section of the same name ([control] sigmas) left out. ``""``: every stage section, by name."""
        if name == "":
            return {n: t for n in STAGE_SECTION_NAMES if (t := self.stage_table(n))}
        table = dict(self.config.get(name, {}))
        shared = PROJECT_SECTIONS.get(name) if name in STAGE_SECTION_NAMES else None
        return {k: v for k, v in table.items() if k not in _keys(shared)} if shared else table

    def settings(self, cls, name: str | None = None):
        """The stage section ``name`` (default ``cls.SECTION``) as ``cls``, checked (no command line)."""
        from aerotri.core.settings import resolve

        return resolve(cls, self, section=name).settings

    # The folder layout (architecture doc); nothing else spells these paths.
    camera_path = property(lambda self: self.root / self.camera.file)  # [camera] file
    gnss_path = property(lambda self: self.root / "gnss.txt")
    images_dir = property(lambda self: self.root / "images")
    lidar_dir = property(lambda self: self.root / "lidar")
    truth_dir = property(lambda self: self.root / "truth")  # simulated projects only (aerotri.sim)
    truth_lidar_dir = property(lambda self: self.truth_dir / "lidar")
    trajectory_dir = property(lambda self: self.root / "trajectory")  # scanner trajectories of the strips

    def trajectories(self) -> list[Path]:
        """The strips' trajectory files (``trajectory/*.txt``, any case of the suffix, lidarctl.strips.trajectory
        format), sorted (trial-paths: ``*.TXT`` were passed over, and the strips adjusted by another model)."""
        return input_files(self.trajectory_dir, (".txt",), "trajectory files")

    def lidar_strips(self) -> list[Path]:
        """The LAS/LAZ strips in ``lidar/``, sorted by name; two of one name (``strip_01.las`` beside
        ``strip_01.LAZ``: their classified copies would be one file) refused here, before any stage (trial-paths: at
        classify, after the strips stage had written, naming an option `aerotri run` does not have)."""
        strips = input_files(self.lidar_dir, (".las", ".laz"), "LiDAR strips")
        seen: dict[str, Path] = {}
        for p in strips:
            other = seen.setdefault(p.stem.casefold(), p)
            if other is not p:
                raise InputError(f"{self.lidar_dir}: two strips of one name, {other.name} and {p.name} (their classified "
                                 "copies are one file): keep one, or rename the other")
        return strips
    # lidar_out/: the LiDAR products
    lidar_out_dir = property(lambda self: self.root / "lidar_out")
    classified_dir = property(lambda self: self.lidar_out_dir / "classified")  # one classified LAZ per strip

    def classified_strips(self) -> list[Path]:
        """The classified copies of ``lidar_strips()`` in ``classified/``: the strip's name as LAZ (the names
        ``lidarctl.tiles.classify_files`` gives with suffix ".laz", which refuses two strips with one name)."""
        return [self.classified_dir / f"{p.stem}.laz" for p in self.lidar_strips()]

    def truth_strips(self) -> list[Path]:
        """The truth-classified strips of simulated projects: ``truth/lidar/`` files named as in ``lidar/``."""
        return [self.truth_lidar_dir / p.name for p in self.lidar_strips()]
    # lidar_out/strips/: the strip check (strips.json; or what it could not compare, {"why": ...}), or with
    # [strips] adjust the adjustment (adjust.json, check_before/, check_after/, the corrected strips)
    strips_dir = property(lambda self: self.lidar_out_dir / "strips")
    strips_check_path = property(lambda self: self.strips_dir / "strips.json")
    strips_adjust_path = property(lambda self: self.strips_dir / "adjust.json")
    strips_check_after_path = property(lambda self: self.strips_dir / "check_after" / "strips.json")

    @property
    def strips_check_used_path(self) -> Path:
        """The strip check of the strips the LiDAR stages use: after the strip adjustment when there is one."""
        return self.strips_check_after_path if self.strips_adjust_path.is_file() else self.strips_check_path

    def adjusted_strips(self) -> list[Path]:
        """The corrected copies of ``lidar_strips()`` a strip adjustment writes (same file names)."""
        return [self.strips_dir / p.name for p in self.lidar_strips()]
    dem_path = property(lambda self: self.lidar_out_dir / "dem.tif")
    dsm_path = property(lambda self: self.lidar_out_dir / "dsm.tif")
    # the first return nearest each cell centre (lidarctl rasters): the DSM of the chain's true-ortho occlusion test
    dsm_nearest_path = property(lambda self: self.lidar_out_dir / "dsm_nearest.tif")
    # the tree crowns fitted to their returns and the nearest-return DSM with them (lidarctl.rasters.crown_model)
    crowns_path = property(lambda self: self.lidar_out_dir / "crowns.gpkg")
    dsm_crowns_path = property(lambda self: self.lidar_out_dir / "dsm_crowns.tif")
    ndsm_path = property(lambda self: self.lidar_out_dir / "ndsm.tif")
    corners_path = property(lambda self: self.lidar_out_dir / "corners.csv")
    corners_summary_path = property(lambda self: self.lidar_out_dir / "corners.json")
    roof_planes_path = property(lambda self: self.lidar_out_dir / "roof_planes.geojson")  # lidarctl corners
    roof_outlines_path = property(lambda self: self.lidar_out_dir / "roof_outlines.gpkg")  # lidarctl corners
    height_check_path = property(lambda self: self.lidar_out_dir / "height_check.json")
    classification_eval_path = property(lambda self: self.lidar_out_dir / "classification_eval.json")
    vectors_path = property(lambda self: self.lidar_out_dir / "vectors.gpkg")  # [vectors] enabled: the line map
    vectors_check_path = property(lambda self: self.lidar_out_dir / "vectors_check.json")  # and its check
    truth_buildings_path = property(lambda self: self.truth_dir / "buildings.geojson")  # simulated projects
    # control/: the transferred LiDAR control
    control_dir = property(lambda self: self.root / "control")
    control_points_path = property(lambda self: self.control_dir / "points.csv")
    control_image_points_path = property(lambda self: self.control_dir / "image_points.csv")
    control_transfer_path = property(lambda self: self.control_dir / "transfer.json")
    # work/: caches and stage stamps
    work_dir = property(lambda self: self.root / "work")
    stages_dir = property(lambda self: self.work_dir / "stages")
    run_summary_path = property(lambda self: self.work_dir / "run_summary.json")  # the last run's stage rows
    first_adjustment_dir = property(lambda self: self.work_dir / "at_first")
    # at/: tie points and the adjustment
    at_dir = property(lambda self: self.root / "at")
    tiepoints_path = property(lambda self: self.at_dir / "tiepoints.csv")
    connectivity_path = property(lambda self: self.at_dir / "connectivity.json")
    connectivity_plot_path = property(lambda self: self.at_dir / "connectivity.png")
    eo_path = property(lambda self: self.at_dir / "eo.txt")
    adjusted_camera_path = property(lambda self: self.at_dir / "camera.toml")  # the camera of at/eo.txt
    adjustment_report_path = property(lambda self: self.at_dir / "report.json")
    object_points_path = property(lambda self: self.at_dir / "object_points.csv")
    exports_dir = property(lambda self: self.at_dir / "exports")
    # ortho/: frame orthos, mosaic, DOM check
    imported_dir = property(lambda self: self.root / "imported")  # aerotri import: what other software delivered
    imported_eo_path = property(lambda self: self.imported_dir / "eo.txt")  # orientations (ortho rectify --eo)
    imported_record_path = property(lambda self: self.imported_dir / "imports.json")  # what was imported from where

    ortho_dir = property(lambda self: self.root / "ortho")
    frames_dir = property(lambda self: self.ortho_dir / "frames")
    frames_index_path = property(lambda self: self.frames_dir / "index.json")
    mosaic_path = property(lambda self: self.ortho_dir / "mosaic.tif")
    seams_path = property(lambda self: self.ortho_dir / "seams.tif")
    seamlines_path = property(lambda self: self.ortho_dir / "seamlines.geojson")
    mosaic_summary_path = property(lambda self: self.ortho_dir / "mosaic.json")
    dom_report_path = property(lambda self: self.ortho_dir / "dom_report.json")
    dom_report_plot_path = property(lambda self: self.ortho_dir / "dom_report.png")
    # reports/: the consolidated accuracy report
    reports_dir = property(lambda self: self.root / "reports")
    report_index_path = property(lambda self: self.reports_dir / "index.html")
    report_summary_path = property(lambda self: self.reports_dir / "summary.json")
    report_pdf_path = property(lambda self: self.reports_dir / "report.pdf")


def project_paths(root) -> Project:
    """The paths of a project folder without reading its project.toml (for code that only needs to
    find files, e.g. tools that look at a finished project)."""
    return Project(Path(root), {})


def input_files(folder: Path, suffixes: tuple[str, ...], what: str) -> list[Path]:
    """The files of an input folder with one of ``suffixes`` (any case), sorted; none when the folder is absent.
    ``InputError`` naming a broken link, the folder's own or a file's of those suffixes: a link that points nowhere (a
    project copied with relative links, a share not mounted) is no "no LiDAR" (trial-paths: the run went on without
    the LiDAR, the true ortho became a conventional one on a 25 m tie-point DEM, exit 0)."""
    import os

    folder = Path(folder)
    if folder.is_symlink() and not folder.exists():
        raise InputError(f"{folder}: a link to {os.readlink(folder)}, which does not exist (moved, or a share not "
                         f"mounted?): its {what} cannot be read; mend the link")
    if not folder.is_dir():
        return []
    found, broken = [], []
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() not in suffixes:
            continue
        if p.is_symlink() and not p.exists():
            broken.append(p)
        elif p.is_file():
            found.append(p)
    if broken:
        raise InputError(f"{folder}: {len(broken)} of its {what} are links to files that do not exist ({broken[0].name} "
                         f"-> {os.readlink(broken[0])}{', ...' if len(broken) > 1 else ''}: moved, or a share not "
                         "mounted?); mend the links")
    return found
