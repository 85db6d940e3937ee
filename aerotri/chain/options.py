"""The stage options of ``aerotri run``: one ``project.toml`` section per stage.

Each section's keys are the fields of the stage's settings dataclass, with its defaults and checks
(``aerotri.core.settings``), e.g.::

    [strips]
    adjust = true
    [rasters]
    res_m = 0.5
    [corners]
    roof = "any"
    min_edge_m = 4.0
    [vectors]
    enabled = true
    [adjust]
    self_calibration = ["pp", "radial"]
    gnss_correction = "shift"
    [rectify]
    dem = "../dem/dem_2m.tif"        # relative to the project folder

Nested settings are sub-tables (``[match.sparse] budget = 8000``). A section or key the chain does
not know is refused, naming project.toml, the section and the key, before any stage runs.
"""

from __future__ import annotations

import dataclasses

from aerotri.adjust.pipeline import AdjustSettings
from aerotri.control.pipeline import ControlSettings
from aerotri.core.errors import ConfigError
from aerotri.core.settings import from_table
from aerotri.match.pipeline import MatchSettings
from aerotri.core.project import PROJECT_SECTIONS, STAGE_SECTION_NAMES, Project
from lidarctl.classify import ClassifyParams
from lidarctl.corners import CornerSettings
from lidarctl.rasters import RasterSettings
from lidarctl.strips.settings import StripsSettings
from lidarctl.vectors_settings import VectorsSettings
from ortho.settings import MosaicSettings, RectifySettings

# section -> the settings dataclass of the stage it configures (in chain order)
STAGE_SECTIONS = {
    "strips": StripsSettings,
    "classify": ClassifyParams,
    "rasters": RasterSettings,
    "corners": CornerSettings,
    "vectors": VectorsSettings,
    "match": MatchSettings,
    "adjust": AdjustSettings,
    "control": ControlSettings,
    "rectify": RectifySettings,
    "mosaic": MosaicSettings,
}
assert tuple(STAGE_SECTIONS) == STAGE_SECTION_NAMES  # the project folder knows the stage sections by name


@dataclasses.dataclass
class ChainOptions:
    """The settings of every stage, from project.toml (defaults where a section or key is absent)."""

    strips: StripsSettings = dataclasses.field(default_factory=StripsSettings)
    classify: ClassifyParams = dataclasses.field(default_factory=ClassifyParams)
    rasters: RasterSettings = dataclasses.field(default_factory=RasterSettings)
    corners: CornerSettings = dataclasses.field(default_factory=CornerSettings)
    vectors: VectorsSettings = dataclasses.field(default_factory=VectorsSettings)
    match: MatchSettings = dataclasses.field(default_factory=MatchSettings)
    adjust: AdjustSettings = dataclasses.field(default_factory=AdjustSettings)
    control: ControlSettings = dataclasses.field(default_factory=ControlSettings)
    rectify: RectifySettings = dataclasses.field(default_factory=RectifySettings)
    mosaic: MosaicSettings = dataclasses.field(default_factory=MosaicSettings)


def read_stage_sections(config: dict, source: str, base_dir=None) -> ChainOptions:
    """Check every section of a project.toml table and build the stage settings.

    ``source`` names the file in messages; ``base_dir`` anchors relative file names (the project).
    """
    values = {}
    for section, table in config.items():
        base_keys = PROJECT_SECTIONS.get(section, ())
        if section not in STAGE_SECTIONS and section not in PROJECT_SECTIONS:
            raise ConfigError(f"{source}: unknown section [{section}] (project sections: "
                              f"{', '.join(PROJECT_SECTIONS)}; stage sections: {', '.join(STAGE_SECTIONS)})")
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: {section} must be a section [{section}], not a single value")
        if section not in STAGE_SECTIONS:
            for key in table:
                if key not in base_keys:
                    raise ConfigError(f"{source} [{section}]: unknown key {key!r} (known: {', '.join(base_keys)})")
            continue
        stage_table = {k: v for k, v in table.items() if k not in base_keys}
        values[section] = from_table(STAGE_SECTIONS[section], stage_table, f"{source} [{section}]", base_dir)
    return ChainOptions(**values)


def read_options(project: Project) -> ChainOptions:
    """The stage settings of a project (its project.toml, checked whole)."""
    return read_stage_sections(project.config, str(project.config_path), project.root)
