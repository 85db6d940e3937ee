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
from pathlib import Path
from typing import ClassVar

from aerotri.adjust.settings import AdjustSettings
from aerotri.control.settings import ControlSettings
from aerotri.core.project import PROJECT_SECTIONS, STAGE_SECTION_NAMES, Project, check_sections
from aerotri.core.settings import Resolved, resolve
from aerotri.match.settings import MatchSettings
from lidarctl.classify.pipeline import ClassifySettings
from lidarctl.corners.roof_corners import CornerSettings
from lidarctl.rasters.products import RasterSettings
from lidarctl.strips.settings import StripsSettings
from lidarctl.vectors.settings import VectorsSettings
from ortho.settings import CheckSettings, MosaicSettings, RectifySettings

# section -> the settings dataclass of the stage it configures (in chain order)
STAGE_SECTIONS = {
    "strips": StripsSettings,
    "classify": ClassifySettings,
    "rasters": RasterSettings,
    "corners": CornerSettings,
    "vectors": VectorsSettings,
    "match": MatchSettings,
    "adjust": AdjustSettings,
    "control": ControlSettings,
    "rectify": RectifySettings,
    "mosaic": MosaicSettings,
    "dom_check": CheckSettings,
}
assert tuple(STAGE_SECTIONS) == STAGE_SECTION_NAMES  # the project folder knows the stage sections by name
assert all(getattr(cls, "SECTION", name) == name for name, cls in STAGE_SECTIONS.items())

# every section of project.toml, what declares it and what reads it (docs/settings.md)
ALL_SECTIONS = [(name, cls) for name, cls in PROJECT_SECTIONS.items()] + list(STAGE_SECTIONS.items())


@dataclasses.dataclass(frozen=True)
class ChainSettings:
    """The settings of every stage, from project.toml (defaults where a section or key is absent)."""

    SECTION: ClassVar[str] = ""  # the whole file: one field per stage section
    strips: StripsSettings = dataclasses.field(default_factory=StripsSettings)
    classify: ClassifySettings = dataclasses.field(default_factory=ClassifySettings)
    rasters: RasterSettings = dataclasses.field(default_factory=RasterSettings)
    corners: CornerSettings = dataclasses.field(default_factory=CornerSettings)
    vectors: VectorsSettings = dataclasses.field(default_factory=VectorsSettings)
    match: MatchSettings = dataclasses.field(default_factory=MatchSettings)
    adjust: AdjustSettings = dataclasses.field(default_factory=AdjustSettings)
    control: ControlSettings = dataclasses.field(default_factory=ControlSettings)
    rectify: RectifySettings = dataclasses.field(default_factory=RectifySettings)
    mosaic: MosaicSettings = dataclasses.field(default_factory=MosaicSettings)
    dom_check: CheckSettings = dataclasses.field(default_factory=CheckSettings)


def read_stage_sections(config: dict, source: str, base_dir=None) -> ChainSettings:
    """Check every section of a project.toml table and build the stage settings.

    ``source`` names the file in messages; ``base_dir`` anchors relative file names (the project).
    """
    source = Path(source)
    project = Project(Path(base_dir) if base_dir is not None else source.parent, config, check_sections(config, source))
    return resolve(ChainSettings, project).settings


def read_options(project: Project, ctx=None) -> Resolved:
    """The stage settings of a project (its project.toml, checked whole) with the options of ``aerotri run`` given on
    the command line (``ctx``), and the source of every setting (dotted paths ``adjust.gnss_correction``)."""
    return resolve(ChainSettings, project, ctx)


# what reads each section (docs/settings.md)
READERS = {
    "project": "every command over a project", "camera": "every command over a project",
    "gnss": "`aerotri match`, `aerotri adjust`, `aerotri run`", "control": "`aerotri control`, `aerotri run` "
    "(the sigma keys: `aerotri import`, `aerotri adjust`)", "flight": "`aerotri match`, `aerotri adjust` (flight "
    "acceptance), `aerotri run`", "qa": "`aerotri report`, `aerotri adjust` (the limits of its report), `aerotri run`",
    "strips": "`aerotri run`", "classify": "`aerotri run`", "rasters": "`aerotri run`", "corners": "`aerotri run`",
    "vectors": "`aerotri run`, `aerotri report`", "match": "`aerotri match`, `aerotri run`",
    "adjust": "`aerotri adjust`, `aerotri run` (both adjustments)", "rectify": "`ortho rectify`, `aerotri run`",
    "mosaic": "`ortho mosaic`, `aerotri run`", "dom_check": "`ortho check`, `aerotri run` (with --reference)",
}


def _option_names(groups: list[tuple[str, object]]) -> dict:
    """``{(section dataclass, path): ["aerotri adjust --dem", ...]}`` over the commands of the click ``groups``
    (``(program name, group)``): every option declared from a settings field (``core.settings.click_option``)."""
    from aerotri.core.settings import setting_options

    out: dict = {}

    def walk(prefix: str, command) -> None:
        for name, sub in sorted(getattr(command, "commands", {}).items()):
            walk(f"{prefix} {name}", sub)
        for param in setting_options(command):
            cls, path = param.settings_cls, param.field
            if cls is ChainSettings:  # aerotri run's options: [section] key
                head, _, path = path.partition(".")
                cls = STAGE_SECTIONS[head]
            out.setdefault((cls, path), []).append(f"{prefix} {param.opts[0]}")

    for prog, group in groups:
        walk(prog, group)
    return out


def reference_page(groups: list[tuple[str, object]]) -> str:
    """docs/settings.md: every section of project.toml with its keys (``core.settings.markdown_reference``)."""
    from aerotri.core.settings import markdown_reference

    head = """# project.toml: every setting

Generated by `aerotri settings --markdown` from the settings dataclasses (`aerotri.core.project` for the
project sections, each stage's `*Settings` for its section); `tests/aerotri/core/test_settings.py` checks that
this page is current.

Every command over a project folder reads its section of `project.toml`; an option given on the command line
overrides only its own setting; anything else keeps its default. The order, lowest first: **default <
project.toml < command line**. Each stage's report says where each setting came from (`settings` in
`at/report.json`, `at/connectivity.json`, `control/transfer.json`, `ortho/frames/index.json`,
`ortho/mosaic.json`, `ortho/dom_report.json`; the "Settings" block of `at/report.txt`); `aerotri settings
PROJECT` prints them for a project. `aerotri init P ... --set section.key=value` and `aerotri settings P --set
section.key=value` write a setting into project.toml (its comments kept) after the same checks. A key that is not
listed here, or a value of the wrong type or out of range, stops the command with a message naming the file, the
section and the key. Nested tables are
sub-sections (`[match.sparse]`); file names are relative to the project folder. Commands over plain files
(`lidarctl contours DEM OUT`, ...) read no project.toml: their options alone.

"""
    sections: dict = {}
    for name, cls in ALL_SECTIONS:  # [control]: the control points' sigmas (core), then the control stage's keys
        sections.setdefault(name, []).append(cls)
    return head + markdown_reference([(n, cs, READERS[n]) for n, cs in sections.items()], _option_names(groups))


def project_settings_text(project: Project, ctx=None, completed: dict | None = None) -> str:
    """Every setting of a project with where it came from (``aerotri settings PROJECT``); ``completed``: section ->
    (its settings record, its title) where the chain completes the section (``Chain.completed_settings``)."""
    from aerotri.core.settings import Resolved, settings_lines

    lines = []
    for name, cls in PROJECT_SECTIONS.items():
        typed = getattr(project.sections, name)
        sources = {f.name: project.source_of(name, f.name) for f in dataclasses.fields(cls)}
        lines += settings_lines(Resolved(typed, sources).record(), f"[{name}]")
    from aerotri.adjust.pipeline import project_settings

    stages = read_options(project, ctx).record()
    for name in STAGE_SECTIONS:
        head = name + "."
        record = {p[len(head):]: row for p, row in stages.items() if p.startswith(head)}
        title = f"[{name}]"
        if name == "adjust":  # as aerotri adjust P completes it from the project folder
            adjust = project_settings(project, resolve(AdjustSettings, project, ctx))
            record, title = adjust.record(), "[adjust] (as aerotri adjust PROJECT takes it)"
        elif name in (completed or {}):  # as the chain completes it (``Chain.completed_settings``)
            record, title = completed[name]
        lines += settings_lines(record, title)
    return "\n".join(lines)
