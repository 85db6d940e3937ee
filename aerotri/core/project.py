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
from aerotri.core.textio import read_json, read_text


# The sections every project may have and their keys; ``aerotri run`` adds one section per stage with
# the keys of the stage's settings dataclass (aerotri.chain.options) and refuses anything else.
PROJECT_SECTIONS = {
    "project": ("name", "crs", "heights"),
    "camera": ("file",),
    "gnss": ("sigma_xy_m", "sigma_z_m", "lever_arm_m"),
    "control": ("sigma_xy_m", "sigma_z_m"),  # a-priori sigmas of control points the simulator writes
    "flight": ("mean_terrain_height_m", "speed_mps"),
    "qa": ("map_scale", "terrain", "tolerances", "pdf"),
}
# The stage sections (their keys are the fields of each stage's settings, checked by the stage and by
# ``aerotri run``; aerotri.chain.options.STAGE_SECTIONS holds the same names).
STAGE_SECTION_NAMES = ("classify", "rasters", "corners", "match", "adjust", "control", "rectify", "mosaic")


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
        from aerotri.geom.crs import parse_crs, parse_heights

        parse_crs(config["project"]["crs"], f"{cfg_path} [project] crs")
        parse_heights(config["project"].get("heights"), f"{cfg_path} [project] heights")
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

    # Standard paths
    camera_path = property(lambda self: self.root / "camera.toml")
    gnss_path = property(lambda self: self.root / "gnss.txt")
    images_dir = property(lambda self: self.root / "images")
    lidar_dir = property(lambda self: self.root / "lidar")
    lidar_out_dir = property(lambda self: self.root / "lidar_out")
    control_dir = property(lambda self: self.root / "control")
    work_dir = property(lambda self: self.root / "work")
    at_dir = property(lambda self: self.root / "at")
    ortho_dir = property(lambda self: self.root / "ortho")
    truth_dir = property(lambda self: self.root / "truth")

    def camera(self):
        from aerotri.geom.camera import FrameCamera

        return FrameCamera.read(self.camera_path)

    def adjusted_camera(self):
        """(camera, source): the self-calibrated camera of the last adjustment (``at/report.json``)
        when there is one, else the nominal ``camera.toml``. Orientations in ``at/eo.txt`` belong to it."""
        from aerotri.geom.camera import FrameCamera

        rep = self.at_dir / "report.json"
        if rep.is_file():
            d = read_json(rep, "adjustment report")
            cam = (d.get("self_calibration") or {}).get("camera") if isinstance(d, dict) else None
            if cam:
                return FrameCamera.from_dict(cam, source=f"{rep} self_calibration.camera"), f"{rep} (self-calibrated)"
        return self.camera(), str(self.camera_path)
