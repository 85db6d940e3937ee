"""A project folder (architecture doc) and its ``project.toml``.

```
project.toml   [project] name, crs; [gnss] sigmas and lever arm; [control] sigmas; stage options
camera.toml    frame camera (aerotri.geom.camera)
gnss.txt       image_id X Y Z [sX sY sZ]
lidar/ images/ lidar_out/ control/ work/ at/ ortho/
```
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

from aerotri.core.errors import ConfigError, InputError
from aerotri.core.textio import read_text


# The sections every project may have and their keys; ``aerotri run`` adds one section per stage with
# the keys of the stage's settings dataclass (aerotri.chain.options) and refuses anything else.
PROJECT_SECTIONS = {
    "project": ("name", "crs", "heights"),
    "camera": ("file",),
    "gnss": ("sigma_xy_m", "sigma_z_m", "lever_arm_m"),
    "control": ("sigma_xy_m", "sigma_z_m"),  # a-priori sigmas of control points the simulator writes
    "flight": ("mean_terrain_height_m", "speed_mps"),
    "qa": ("map_scale", "terrain", "tolerances", "pdf", "standard", "platform", "horizontal_class_cm",
           "vertical_class_cm"),
}
# The stage sections (their keys are the fields of each stage's settings, checked by the stage and by
# ``aerotri run``; aerotri.chain.options.STAGE_SECTIONS holds the same names).
STAGE_SECTION_NAMES = ("strips", "classify", "rasters", "corners", "vectors", "match", "adjust", "control", "rectify", "mosaic")


def check_sections(config: dict, source) -> None:
    """Refuse an unknown section, an unknown key of a project section, and a section given as a value,
    naming ``source`` (project.toml), the section and the key."""
    for section, table in config.items():
        if section not in PROJECT_SECTIONS and section not in STAGE_SECTION_NAMES:
            raise ConfigError(f"{source}: unknown section [{section}] (project sections: "
                              f"{', '.join(PROJECT_SECTIONS)}; stage sections: {', '.join(STAGE_SECTION_NAMES)})")
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: {section} must be a section [{section}], not a single value")
        if section in PROJECT_SECTIONS and section not in STAGE_SECTION_NAMES:
            known = PROJECT_SECTIONS[section]
            for key in table:
                if key not in known:
                    raise ConfigError(f"{source} [{section}]: unknown key {key!r} (known: {', '.join(known)})")


@dataclasses.dataclass
class Project:
    root: Path
    config: dict

    @classmethod
    def open(cls, root) -> "Project":
        root = Path(root)
        if not root.is_dir():
            raise InputError(f"{root}: project folder not found")
        cfg_path = root / "project.toml"
        if not cfg_path.exists():
            raise InputError(f"{cfg_path}: missing (every project folder needs project.toml with [project] crs)")
        try:
            config = tomllib.loads(read_text(cfg_path, "project file (TOML)"))
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{cfg_path}: not valid TOML ({exc})") from None
        check_sections(config, cfg_path)
        if "crs" not in config.get("project", {}):
            raise ConfigError(f"{cfg_path}: [project] crs is missing (e.g. crs = \"EPSG:32649\")")
        return cls(root, config)

    @property
    def config_path(self) -> Path:
        return self.root / "project.toml"

    @property
    def name(self) -> str:
        return str(self.config.get("project", {}).get("name", self.root.name))

    @property
    def crs(self) -> str:
        return str(self.config["project"]["crs"])

    def section(self, name: str) -> dict:
        return dict(self.config.get(name, {}))

    # The folder layout (architecture doc); nothing else spells these paths.
    camera_path = property(lambda self: self.root / "camera.toml")
    gnss_path = property(lambda self: self.root / "gnss.txt")
    images_dir = property(lambda self: self.root / "images")
    lidar_dir = property(lambda self: self.root / "lidar")
    truth_dir = property(lambda self: self.root / "truth")  # simulated projects only (aerotri.sim)
    truth_lidar_dir = property(lambda self: self.truth_dir / "lidar")
    trajectory_dir = property(lambda self: self.root / "trajectory")  # scanner trajectories of the strips

    def trajectories(self) -> list[Path]:
        """The strips' trajectory files (``trajectory/*.txt``, lidarctl.strips.trajectory format), sorted."""
        return sorted(p for p in self.trajectory_dir.glob("*.txt") if p.is_file())

    def lidar_strips(self) -> list[Path]:
        """The LAS/LAZ strips in ``lidar/``, sorted by name."""
        return sorted(p for p in self.lidar_dir.glob("*") if p.suffix.lower() in (".las", ".laz"))
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

    def adjusted_strips(self) -> list[Path]:
        """The corrected copies of ``lidar_strips()`` a strip adjustment writes (same file names)."""
        return [self.strips_dir / p.name for p in self.lidar_strips()]
    dem_path = property(lambda self: self.lidar_out_dir / "dem.tif")
    dsm_path = property(lambda self: self.lidar_out_dir / "dsm.tif")
    ndsm_path = property(lambda self: self.lidar_out_dir / "ndsm.tif")
    corners_path = property(lambda self: self.lidar_out_dir / "corners.csv")
    corners_summary_path = property(lambda self: self.lidar_out_dir / "corners.json")
    roof_planes_path = property(lambda self: self.lidar_out_dir / "roof_planes.geojson")  # lidarctl corners
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
