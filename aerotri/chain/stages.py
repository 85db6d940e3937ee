"""The production chain over one project folder, built from its inputs and its stage options.

LiDAR strips (lidar/) -> strip check (how overlapping strips disagree in height, lidar_out/strips/; with
``[strips] adjust = true`` the strip adjustment, and the corrected strips go on) -> classify (the strips together, by tiles, no merged file; one classified
copy per strip in lidar_out/classified/) -> rasters -> roof corners; images -> tie points -> first
adjustment (tie points + GNSS) -> control transfer of the LiDAR corners -> final adjustment ->
rectification (a true ortho on the DSM whenever there is one: lidar_out/dsm.tif or [rectify] dsm, unless
``[rectify] true_ortho = false``; else on the DEM) -> mosaic -> optional checks -> accuracy report.

Every stage calls its library function and returns its key numbers for the summary as a frozen record
(``aerotri.chain.results``: one ``StageResult`` per stage), read from what the library returned or from the
stage's own report file through the reader of the stage that writes it. The chain
runs what its inputs allow and says what it left out and why:

- one strip, or strips without a smooth overlap: no strip check (nor adjustment), the rest goes on;
- no LiDAR strips: no LiDAR stages and no control transfer; one adjustment, with the project's own
  control/ if there is one, else on GNSS alone; the orthophotos need a DEM from elsewhere
  (``[rectify] dem`` in project.toml or ``aerotri run --dem``), else the chain ends after the adjustment;
- no usable roof corner (or ``[adjust] use_control = false``): no control transfer, the final
  adjustment runs without LiDAR control;
- GNSS corrections per strip (``[adjust] gnss_correction``) with too few control points for their
  datum: the adjustment runs without them (GNSS carries the datum) and says so;
- no GNSS (no gnss.txt, no ``[adjust] initial_eo``): the adjustment takes its approximate orientations from the
  images (pycolmap on the tie points) and its datum from the project's control points
  (``aerotri.adjust.relative``); without a DEM from elsewhere, a DEM of the adjusted tie points (``dem`` stage,
  ``at/dem.tif``) carries the orthophotos. ``[adjust] leave_one_out = true`` adds the leave-one-out check of the
  control points (``at/leave_one_out.json``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

from aerotri.adjust.report_record import AdjustmentRecord
from aerotri.chain import results as R
from aerotri.chain.options import ChainSettings, read_options
from aerotri.chain.runner import Stage
from aerotri.core.atomic import write_text_atomic
from aerotri.core.settings import COMMAND_LINE, DEFAULT, PROJECT_TOML, Resolved, settings_of, to_table
from aerotri.core.project import Project

_log = logging.getLogger(__name__)
CLASSIFY_RESUME_DIR_NAME = "classify_resume"  # in work/: the LiDAR tiles a killed or interrupted classify finished
RASTERS_RESUME_DIR_NAME = "rasters_resume"  # in work/: the raster tiles a killed or interrupted rasters stage finished

def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def adjustment_result(rec: AdjustmentRecord, **more) -> R.AdjustResult:
    """Key numbers of an adjustment report (the record ``run_adjustment`` returns, as at/report.json) for the
    summary; ``more``: the leave-one-out numbers and notes."""
    chk = rec.check_rms_m
    plan = bool(chk) and len(chk) == 3 and None not in chk[:2]  # z None: plan-only check points
    return R.AdjustResult(sigma0_um=rec.key_statistics.sigma0_um if rec.key_statistics else None,
                          control_points=rec.counts.get("control_points"),
                          rms_check_xy_m=round(float((chk[0] ** 2 + chk[1] ** 2) ** 0.5), 4) if plan else None,
                          rms_check_z_m=chk[2] if plan else None, **more)


# The algorithm versions each stage's stamp holds (``aerotri.chain.runner.Stage.versions``): the constants next to the
# code that decides the stage's outputs, each bumped when those outputs change; imported when the stage's turn comes.
def _classify_versions(settings) -> dict:
    """The rules' version at the stage's settings (``lidarctl.classify.rules_version``: a version whose changes
    decide classes only with an option on re-runs no project with it off)."""
    from lidarctl.classify import rules_version

    return {"classify rules": rules_version(settings)}


def _rasters_versions() -> dict:
    from lidarctl.rasters.crown_model import CROWNS_VERSION
    from lidarctl.rasters.products import RASTERS_VERSION

    return {"rasters": RASTERS_VERSION, "crown model": CROWNS_VERSION}


def _corners_versions() -> dict:
    from lidarctl.corners.roof_corners import CORNERS_VERSION

    return {"roof corners": CORNERS_VERSION}


def _adjust_versions() -> dict:
    from aerotri.adjust.pipeline import ADJUST_VERSION
    from aerotri.adjust.relative import RELATIVE_VERSION

    return {"adjustment": ADJUST_VERSION, "relative orientation": RELATIVE_VERSION}


def _match_versions() -> dict:
    from aerotri.match.settings import FEATURES_VERSION, MATCH_VERSION

    return {"features": FEATURES_VERSION, "matching": MATCH_VERSION}


def _control_versions() -> dict:
    from aerotri.control.measure import MEASURE_VERSION

    return {"measurement": MEASURE_VERSION}


def _rectify_versions(settings) -> dict:
    from ortho.block import HEIGHTS_BY_OUTLINE, OUTLINES_OF_THE_OCCLUSION_TEST
    from ortho.rectify import rectify_version

    # the footprint rules the frames' resume key holds (ortho.block._resume_key's footprint_rules); the version of
    # the rectification in the grid's CRS (a [rectify] crs: a contract grid's)
    return {"rectify": rectify_version(bool(settings.crs)), "heights by outline": HEIGHTS_BY_OUTLINE,
            "outlines of the occlusion test": OUTLINES_OF_THE_OCCLUSION_TEST}


def _strips_versions() -> dict:
    from lidarctl.strips.adjust import STRIP_ADJUST_VERSION
    from lidarctl.strips.check import STRIP_CHECK_VERSION

    return {"strip check": STRIP_CHECK_VERSION, "strip adjustment": STRIP_ADJUST_VERSION}


def _vectors_versions() -> dict:
    from lidarctl.checks.vectors import VECTOR_CHECK_VERSION
    from lidarctl.vectors.layers import VECTORS_VERSION

    return {"vectors": VECTORS_VERSION, "vector check": VECTOR_CHECK_VERSION}


def _dem_versions() -> dict:
    from ortho.points_dem import POINTS_DEM_VERSION

    return {"tie point DEM": POINTS_DEM_VERSION}


def _dom_check_versions() -> dict:
    from ortho.check import DOM_CHECK_VERSION

    return {"DOM check": DOM_CHECK_VERSION}


def _height_check_versions() -> dict:
    from lidarctl.checks.heights import HEIGHT_CHECK_VERSION

    return {"height check": HEIGHT_CHECK_VERSION}


def _lidar_eval_versions() -> dict:
    from lidarctl.checks.classes import EVAL_VERSION

    return {"classification evaluation": EVAL_VERSION}


def _report_versions() -> dict:
    from aerotri.qa.report import QA_REPORT_VERSION

    return {"accuracy report": QA_REPORT_VERSION}


def _mosaic_versions() -> dict:
    from ortho.mosaic import BLEND_RULES, RADIOMETRY_SEAMS_VERSION

    return {"blend rules": BLEND_RULES, "gains, offsets and seamlines": RADIOMETRY_SEAMS_VERSION}


@dataclasses.dataclass
class Chain:
    """The stages of one project; ``stages()`` lists them in order (see the module docstring)."""

    project: Project
    settings: Resolved | ChainSettings  # every stage's settings (read_options: with their sources)
    reference_ortho: Path | None = None  # DOM check against this orthophoto
    surveyed_points: Path | None = None  # LiDAR height check at these points
    dem: Path | None = None  # overrides [rectify] dem (as aerotri run --dem)
    truth_classes: bool = False  # simulated projects: classification against truth/lidar

    def __post_init__(self):
        self.settings = settings_of(self.settings, ChainSettings)
        if self.dem is not None:
            self.settings = self.settings.replace("rectify.dem", Path(self.dem), COMMAND_LINE)

    @property
    def options(self) -> ChainSettings:
        return self.settings.settings

    def stage_settings(self, section: str) -> Resolved:
        """The settings of one stage with their sources (for its report)."""
        head = section + "."
        return Resolved(getattr(self.options, section),
                        {p[len(head):]: s for p, s in self.settings.sources.items() if p.startswith(head)},
                        {p[len(head):]: n for p, n in self.settings.notes.items() if p.startswith(head)})

    # -- paths ------------------------------------------------------------------------------------
    @property
    def root(self) -> Path:
        return self.project.root

    @property
    def lo(self) -> Path:
        return self.project.lidar_out_dir

    def classified(self, root=None) -> list[Path]:
        """The classified strips (lidar_out/classified/, one per strip of lidar/)."""
        return self.project.classified_strips()

    @property
    def first(self) -> Path:
        return self.project.first_adjustment_dir

    def images(self) -> list[Path]:
        from aerotri.core.project import input_files
        from aerotri.geom.images import IMAGE_SUFFIXES

        # a broken link among the frames (or the folder's own) is refused, not read as a LiDAR-only project
        # (trial-paths: every frame link broken, the old report kept as "up to date", exit 0)
        input_files(self.project.images_dir, IMAGE_SUFFIXES, "frames")
        return sorted(p for p in self.project.images_dir.glob("*") if p.is_file())

    # -- what the inputs allow -------------------------------------------------------------------
    @property
    def has_lidar(self) -> bool:
        return bool(self.project.lidar_strips())

    @property
    def has_gnss(self) -> bool:
        return self.options.adjust.use_gnss and self.project.gnss_path.is_file()

    def dem_path(self) -> Path | None:
        """The DEM of the orthophotos: --dem, else [rectify] dem, else the LiDAR stages' DEM, else the DEM of the
        adjusted tie points."""
        if self.dem is not None:
            return Path(self.dem)
        if self.options.rectify.dem is not None:
            return Path(self.options.rectify.dem)
        if self.has_lidar:
            return self.project.dem_path
        return self.tie_point_dem_path if self.tie_point_dem() else None

    def edited_mosaic(self, root) -> str | None:
        """Why the mosaic on disk is the operator's (``ortho mosaic --seamlines EDITED.gpkg``: its mosaic.json says
        "edited (...)"), else None."""
        try:
            seams = json.loads(self.project.mosaic_summary_path.read_text()).get("seams", "")
        except (OSError, ValueError):
            return None
        return f"re-made with {seams} seamlines by ortho mosaic" if str(seams).startswith("edited") else None

    def edited_seamlines(self) -> Path | None:
        """The operator's edited seamlines GeoPackage the mosaic on disk was re-made with (``edited_mosaic``), while
        that mosaic is there (removed: the chain routes its own again), else None."""
        if not self.edited_mosaic(self.root) or not self.project.mosaic_path.exists():
            return None
        seams = json.loads(self.project.mosaic_summary_path.read_text())["seams"]
        path = Path(seams[len("edited ("):-1]) if seams.endswith(")") else None
        if path is not None and not path.is_absolute():
            from aerotri.core.errors import InputError

            # (mosaic.json of before review 49: the name as typed, relative to a folder nobody recorded)
            raise InputError(f"{self.project.mosaic_summary_path}: the mosaic was re-made with the edited seamlines "
                             f"{path}, a name relative to the folder ortho mosaic ran in: run `ortho mosaic "
                             f"{self.root} --seamlines <that file>` again (recorded with its whole path), or remove "
                             f"{_rel(self.project.mosaic_path, self.root)} to have the chain route its own")
        return path

    def mosaic_ndsm(self) -> list[Path]:
        """The nDSM the mosaic's seamlines avoid objects by (``ortho.mosaic.mosaic_block``'s choice): [mosaic] ndsm,
        else lidar_out/ndsm.tif when it is there (listed either way: one written later is a change)."""
        given = self.options.mosaic.ndsm
        return [Path(given) if given is not None else self.project.ndsm_path]

    def dom_check_ndsm(self) -> list[Path]:
        """The nDSM of the DOM check (``ortho.check.run_check``'s choice): [dom_check] ndsm, else with a reference
        lidar_out/ndsm.tif when it is there (its ground patches; the roofs it finds); listed either way."""
        given = self.options.dom_check.ndsm
        if given is not None:
            return [Path(given)]
        return [self.project.ndsm_path] if self.reference_ortho is not None else []

    def qa_tolerances(self) -> list[Path]:
        """A user's tolerance table ([qa] tolerances), which the adjustment's and the accuracy report judge by."""
        from aerotri.core.tolerances import read_qa_config

        tol = read_qa_config(self.root).tolerances
        return [Path(tol)] if tol else []

    @property
    def tie_point_dem_path(self) -> Path:
        return self.project.at_dir / "dem.tif"

    def tie_point_dem(self) -> bool:
        """A DEM from the adjusted tie points carries the orthophotos when the project has no LiDAR and no DEM is
        given (a drone block with EXIF GNSS, a kite block)."""
        return self.dem is None and self.options.rectify.dem is None and not self.has_lidar

    def no_tie_point_dem(self, root=None) -> str | None:
        if self.tie_point_dem():
            return None
        return "a DEM is given or made from LiDAR"

    def no_frames(self, root=None) -> str | None:
        """Why the photo stages (match to the DOM check) are left out: no frames in images/, a LiDAR-only project
        (it stopped at match, "camera.toml: file not found", once its corners stage was passed)."""
        if self.images():
            return None
        return f"no frames in {self.project.images_dir}: a LiDAR-only project, no photo stages"

    def or_no_frames(self, why):
        """A skip of a photo stage: no frames first, then ``why``'s reason."""
        return lambda root=None: self.no_frames() or why(root)

    def no_lidar(self, root=None) -> str | None:
        if not self.has_lidar:
            return f"no LiDAR strips (*.las, *.laz) in {self.project.lidar_dir}"
        return None

    def no_corners(self, root=None) -> str | None:
        """Why no LiDAR control is transferred (None: it is)."""
        why = self.no_lidar()
        if why:
            return why
        if not self.options.adjust.use_control:
            return f"{self.project.config_path}: [adjust] use_control = false"
        if self.own_control():
            # the control stage writes control/: a surveyor's own points there would be replaced (an input lost)
            return (f"{self.project.control_points_path} is the surveyor's own control (no "
                    f"{self.project.control_transfer_path.name} beside it): the adjustment takes it, the LiDAR control "
                    "is not transferred over it (move control/ aside to transfer the LiDAR's)")
        from lidarctl.corners.roof_corners import read_corner_summary

        path = self.project.corners_summary_path
        summary = read_corner_summary(path) if path.is_file() else None
        if summary is not None and summary.no_usable:
            if summary.stats.n_building_points == 0:
                return f"no building points in the classified cloud, so no roof corner ({self.lo / 'corners.json'})"
            return f"no usable roof corner ({self.lo / 'corners.json'})"
        if not self.has_gnss and self.options.adjust.initial_eo is None:
            return ("no orientations to measure the corners with: no GNSS (gnss.txt) for a first adjustment and "
                    "no [adjust] initial_eo")
        return None

    def own_control(self) -> bool:
        """Whether control/ holds control points that no control transfer made (no control/transfer.json)."""
        return self.project.control_points_path.is_file() and not self.project.control_transfer_path.is_file()

    def true_ortho_dsm(self) -> list[Path]:
        """The DSM the rectify stage reads (none for a conventional ortho)."""
        s = self.rectify_settings().settings
        return [Path(p) for p in (s.dsm, s.occlusion_dsm, s.footprints, s.crown_base, s.crowns)
                if s.true_ortho and s.dsm is not None and p is not None]

    def no_dem(self, root=None) -> str | None:
        if self.dem_path() is None:
            return ("no DEM for the orthophotos: no LiDAR strips to make one; give one in project.toml "
                    "([rectify] dem = \"DEM.tif\") or with aerotri run --dem DEM.tif")
        return None

    def no_dom_check(self, root=None) -> str | None:
        """Why the DOM is not checked (None: it is): no DEM, or no reference orthophoto; then also what becomes of
        an earlier run's ortho/dom_report.json (still the current mosaic's, or of an earlier mosaic: the report then
        says the DOM was not checked)."""
        why = self.no_dem()
        if why or self.reference_ortho is not None:
            return why
        why = "no reference orthophoto (aerotri run --reference REF.tif): the DOM is not checked"
        report = self.project.dom_report_path
        if report.is_file():
            from aerotri.core.errors import InputError
            from ortho.check import read_dom_check

            try:
                check = read_dom_check(report)
                stale = check.stale_for(self.project.mosaic_path, report)
            except InputError as e:  # not this run's business: the report names it
                return f"{why}; {report.name} of an earlier run is unreadable ({e})"
            if stale and check.of_project_mosaic is False:
                why += (f"; {report.name} measured another DOM ({check.dom}, ortho check --dom): the report says the "
                        "DOM was not checked")
            elif stale:
                why += (f"; {report.name} of an earlier run measured an earlier mosaic: the report says the DOM was "
                        "not checked")
            else:
                why += f"; {report.name} of an earlier run measured this mosaic and stays in the report"
        return why

    def check_files(self) -> None:
        """The inputs of every stage that the project (or the command line) gives, read and checked as the
        stage will before the first stage writes anything: a bad input of a late stage stops the run with
        the project as it was, not hours into it with the early stages' outputs replaced. Files named in
        project.toml must exist."""
        from aerotri.core.errors import ConfigError

        for section, key, path in (("rectify", "dem", self.options.rectify.dem),
                                   ("rectify", "dsm", self.options.rectify.dsm),
                                   ("rectify", "occlusion_dsm", self.options.rectify.occlusion_dsm),
                                   ("mosaic", "ndsm", self.options.mosaic.ndsm),
                                   ("adjust", "initial_eo", self.options.adjust.initial_eo)):
            if path is not None and not Path(path).is_file():
                raise ConfigError(f"{self.project.config_path} [{section}] {key}: {path} not found")
        # a given DEM is read before the first stage: one band of heights, north up, in the project's CRS
        # (a wrong one would otherwise stop the chain at the orthophotos, after the adjustment)
        given = self.options.rectify.dem
        if given is not None:
            from aerotri.geom.crs.definition import project_crs
            from ortho.dem import open_height_raster

            with open_height_raster(given, project_crs(self.project)) as ds:
                _read_ends(ds, given, "DEM")
        if self.options.rectify.true_ortho and self.dsm_path() is None:
            raise ConfigError(f"{self.project.config_path} [rectify] true_ortho = true: no DSM for it (no LiDAR strips "
                              "to make lidar_out/dsm.tif); give one with [rectify] dsm = \"DSM.tif\" or set "
                              "true_ortho = false")
        self._check_output_crs()
        self._check_stage_inputs()

    def _check_output_crs(self) -> None:
        """(``check_files``) [rectify] crs reached from the project CRS as ``ortho rectify`` will, before the first
        stage: the chain has no datum parameters or ``--allow-ballpark``, and a contract's grid on another datum
        (CGCS2000 Gauss-Krueger for a WGS 84 UTM project) stopped it at the orthophotos, after minutes to hours of
        matching and adjustment, naming options `aerotri run` does not have."""
        from aerotri.core.errors import ConfigError
        from aerotri.geom.crs.definition import crs_label, project_crs
        from aerotri.geom.crs.transform import BallparkRefused, CrsTransformer, grid_advice
        import numpy as np

        from aerotri.geom.eo import read_gnss
        from ortho.grid import resolve_output_crs

        spec = self.options.rectify.crs
        p = self.project
        if spec is None:
            return
        pcrs = project_crs(p)
        if str(spec).lower().startswith("gk3"):
            if not p.gnss_path.is_file():
                return  # the zone needs the block's centre: ortho rectify finds it from the orientations
            centre = np.median(read_gnss(p.gnss_path, pcrs).position_m[:, :2], axis=0)
        else:
            centre = (0.0, 0.0)
        out = resolve_output_crs(spec, pcrs, centre, f"{p.config_path} [rectify] crs =")
        try:
            CrsTransformer(pcrs, out)
        except BallparkRefused as exc:
            if exc.missing_grids:  # a geoid or datum grid not installed: the grid is the fix, not parameters
                raise ConfigError(
                    f"{p.config_path} [rectify] crs = {spec!r}: {crs_label(pcrs)} -> {crs_label(out)} ({out.name}): "
                    f"{grid_advice(list(exc.missing_grids))}; then run again") from None
            raise ConfigError(
                f"{p.config_path} [rectify] crs = {spec!r}: {exc}. `aerotri run` takes no datum parameters: run the "
                f"chain in the project's CRS (without [rectify] crs), then `ortho rectify {p.root} --crs {spec} "
                f"--params FILE` (or --allow-ballpark), `ortho mosaic {p.root}` and `ortho check {p.root} --reference "
                "REF.tif` with the same --params / --allow-ballpark") from None

    def _check_stage_inputs(self) -> None:
        """(``check_files``) the project's own inputs of the stages, each with its stage's reader."""
        from aerotri.geom.crs.definition import project_crs
        from aerotri.geom.eo import read_eo
        from aerotri.geom.observations import read_control_points, read_image_points
        from aerotri.match.pipeline import check_inputs as check_match_inputs
        from ortho.dem import open_height_raster

        p, o = self.project, self.options
        if self.has_lidar:
            from lidarctl.io import checked_headers

            for _ in checked_headers(p.lidar_strips(), crs=p.crs, crs_name="[project] crs"):
                pass
            if o.strips.adjust and o.strips.use_trajectory:
                from lidarctl.strips.trajectory import read_trajectory

                for t in p.trajectories():
                    read_trajectory(t)
        if self.images():  # (a project without frames fails at its match stage, as before)
            check_match_inputs(p.root, o.match)
        if not self.has_lidar and o.adjust.use_control and p.control_points_path.is_file():
            read_control_points(p.control_points_path, project_crs(p))
            if p.control_image_points_path.is_file():
                read_image_points(p.control_image_points_path)
        if o.adjust.initial_eo is not None:
            read_eo(o.adjust.initial_eo, project_crs(p))
        for what, path in (("DSM", o.rectify.dsm), ("occlusion DSM", o.rectify.occlusion_dsm), ("nDSM", o.mosaic.ndsm)):
            if path is not None:
                with open_height_raster(path, project_crs(p), what) as ds:
                    _read_ends(ds, path, what)
        if self.reference_ortho is not None:
            from aerotri.geom.crs.raster_warp import open_north_up

            _check_raster(self.reference_ortho, "reference orthophoto")
            open_north_up(self.reference_ortho, "reference orthophoto").close()  # georeferenced, with a CRS
            if self.roof_corners_path() is not None:
                from ortho.check import read_roof_corners

                read_roof_corners(self.roof_corners_path())
        if self.surveyed_points is not None:
            from lidarctl.checks.heights import read_points_csv

            read_points_csv(self.surveyed_points)

    # -- stages ---------------------------------------------------------------------------------
    def stages(self) -> list[Stage]:
        o, lo, first = self.options, self.lo, self.first
        stages = [
            # only reads the strips unless [strips] adjust (then classify takes the corrected ones)
            Stage("strips", self.strips_inputs, self.strips_outputs, self.run_strips,
                  options=dict(to_table(o.strips), crs=self.project.crs), skip=self.no_lidar,
                  versions=_strips_versions),
            Stage("classify", lambda r: self.classify_inputs(), self.classified, self.run_classify,
                  options=dict(to_table(o.classify), crs=self.project.crs), skip=self.no_lidar,
                  versions=lambda: _classify_versions(o.classify)),
            Stage("rasters", self.classified,
                  lambda r: [lo / f for f in ("dem.tif", "dsm.tif", "ndsm.tif", "dsm_nearest.tif", "crowns.gpkg",
                                              "dsm_crowns.tif")], self.run_rasters,
                  options=to_table(o.rasters), skip=self.no_lidar, versions=_rasters_versions),
            Stage("corners", self.classified, self.corner_outputs, self.run_corners,
                  options=to_table(o.corners), skip=self.no_lidar, versions=_corners_versions),
        ]
        if o.vectors.enabled:
            # optional ([vectors] enabled): the line map of the classified strips and its check
            stages.append(Stage("vectors", self.vectors_inputs, self.vectors_outputs, self.run_vectors,
                                options=self.vectors_options, skip=self.no_lidar, versions=_vectors_versions))
        stages += [
            Stage("match", lambda r: self.images() + [self.project.gnss_path, self.project.camera_path],
                  lambda r: [self.project.tiepoints_path], self.run_match,
                  # [flight] terrain height and [gnss] lever arm place the footprints of the pairs
                  options=dict(to_table(o.match), flight=to_table(self.project.flight),
                               gnss=to_table(self.project.gnss)), skip=self.no_frames, versions=_match_versions),
            # project.toml carries the [gnss] sigmas, [adjust] options and the [qa] limits of the report: its sections
            # the adjustment reads are options (adjust_project_toml), a change of another stage's does not re-run it
            Stage("adjust_first", lambda r: self.adjust_inputs(r, control=False),
                  lambda r: [first / "eo.txt", first / "camera.toml"], self.run_adjust_first,
                  options=lambda r: dict(to_table(self.first_settings().settings),
                                         project_toml=self.adjust_project_toml()),
                  skip=self.or_no_frames(self.no_first_adjustment),
                  versions=_adjust_versions),
            Stage("control", self.control_inputs,
                  lambda r: [self.project.control_points_path, self.project.control_image_points_path], self.run_control,
                  options=to_table(o.control), skip=self.or_no_frames(self.no_corners), versions=_control_versions),
            Stage("adjust_final", self.adjust_inputs, self.adjust_final_outputs,
                  self.run_adjust_final, options=lambda r: dict(to_table(self.final_settings().settings),
                                                              project_toml=self.adjust_project_toml()),
                  skip=self.no_frames, versions=_adjust_versions),
            # a block without GNSS, LiDAR or DEM: the DEM of its adjusted tie points
            Stage("dem", lambda r: [self.project.object_points_path, self.project.eo_path],
                  lambda r: [self.tie_point_dem_path], self.run_tie_point_dem,
                  skip=self.or_no_frames(self.no_tie_point_dem),
                  versions=_dem_versions),
            # (the self-calibrated camera in at/report.json changes only with at/eo.txt)
            Stage("rectify", lambda r: [self.project.eo_path, self.dem_path()] + self.true_ortho_dsm() + self.images(),
                  lambda r: [self.project.frames_index_path], self.run_rectify,
                  options=lambda r: to_table(self.rectify_settings().settings), skip=self.or_no_frames(self.no_dem),
                  versions=lambda: _rectify_versions(self.rectify_settings().settings),
                  listed_missing=lambda r: _frame_orthos_missing(self.project.frames_index_path)),
            # the nDSM the seamlines avoid objects by ([mosaic] ndsm, else the LiDAR stages' when there is one)
            Stage("mosaic", lambda r: [self.project.frames_index_path] + self.mosaic_ndsm(),
                  lambda r: [self.project.mosaic_path],
                  self.run_mosaic, options=to_table(o.mosaic), skip=self.or_no_frames(self.no_dem),
                  versions=_mosaic_versions,
                  hand_made=self.edited_mosaic),
        ]
        # always planned: without --reference it is skipped with why (an earlier run's check is not dropped silently)
        stages.append(Stage("dom_check", lambda r: [self.project.mosaic_path]
                            + ([Path(self.reference_ortho)] if self.reference_ortho is not None else [])
                            + ([self.roof_corners_path()] if self.roof_corners_path() else []) + self.dom_check_ndsm(),
                            # (its plot too: a deleted dom_report.png left the stage up to date)
                            lambda r: [self.project.dom_report_path, self.project.dom_report_path.with_suffix(".png")],
                            self.run_dom_check,
                            options=to_table(o.dom_check), skip=self.or_no_frames(self.no_dom_check),
                            versions=_dom_check_versions))
        if self.surveyed_points is not None:
            stages.append(Stage("height_check", lambda r: self.classified() + [Path(self.surveyed_points)],
                                lambda r: [self.project.height_check_path], self.run_height_check, skip=self.no_lidar,
                                versions=_height_check_versions))
        if self.truth_classes:
            stages.append(Stage("lidar_eval", lambda r: self.classified() + self.project.truth_strips(),
                                lambda r: [self.project.classification_eval_path],
                                self.run_lidar_eval, skip=self.no_lidar, versions=_lidar_eval_versions))
        # every file the report reads: the DOM check is shown only while it measured the mosaic there now
        # (DomCheck.stale_for, by the mosaic's fingerprint), so a mosaic made again (by hand too) re-runs the report
        report_inputs = [self.project.config_path, self.project.strips_check_path, self.project.strips_adjust_path,
                         self.project.strips_check_after_path, self.project.adjustment_report_path,
                         self.project.control_transfer_path, self.project.dom_report_path,
                         self.project.height_check_path, self.project.classification_eval_path,
                         self.project.vectors_check_path, self.project.mosaic_path, self.project.mosaic_summary_path,
                         self.project.frames_index_path, self.project.dem_path,
                         self.project.at_dir / "leave_one_out.json"]
        if self.options.vectors.check_json is not None:
            report_inputs.append(Path(self.options.vectors.check_json))
        report_inputs += self.qa_tolerances()  # a user's tolerance table judges the block
        stages.append(Stage("report", lambda r: report_inputs, lambda r: [self.project.report_index_path],
                            self.run_report, versions=_report_versions))
        return stages

    # -- LiDAR ----------------------------------------------------------------------------------
    def adjusting(self) -> bool:
        """The strips are adjusted: [strips] adjust, unless the check found nothing to compare."""
        from lidarctl.strips.check import nothing_compared

        return self.options.strips.adjust and not nothing_compared(self.project.strips_check_path)

    def strip_trajectories(self) -> list[Path]:
        return self.project.trajectories() if self.options.strips.use_trajectory else []

    def strips_inputs(self, root=None) -> list[Path]:
        extra = self.strip_trajectories() if self.options.strips.adjust else []
        return self.project.lidar_strips() + extra

    def strips_outputs(self, root=None) -> list[Path]:
        p = self.project
        return [p.strips_adjust_path] + p.adjusted_strips() if self.adjusting() else [p.strips_check_path]

    def classify_inputs(self) -> list[Path]:
        """The strips the classification reads: the corrected ones when the strips were adjusted."""
        return self.project.adjusted_strips() if self.adjusting() else self.project.lidar_strips()

    def run_strips(self, root) -> R.StripsResult:
        from aerotri.core.atomic import atomic_dir
        from lidarctl.strips.adjust import adjust_strips
        from lidarctl.strips.check import check_strips, record_nothing_compared
        from lidarctl.strips.overlap import NothingToCompare

        s, p = self.options.strips, self.project
        try:
            if s.adjust:
                a = adjust_strips(p.lidar_strips(), p.strips_dir, s.adjustment, s.surface,
                                  trajectories=self.strip_trajectories(), crs=p.crs, png=s.maps, option=None)
                return R.StripsResult(model=a.model, rms_before_m=round(a.check_before.rms_m, 4),
                                      rms_after_m=round(a.check_after.rms_m, 4), sigma0=round(a.sigma0, 3))
            c = check_strips(p.lidar_strips(), p.strips_dir, s.surface, crs=p.crs, png=s.maps, option=None)
        except NothingToCompare as e:
            # recorded, so that the report and a re-run know (the folder holds nothing else)
            why = f"nothing to compare: {e}"
            with atomic_dir(p.strips_dir) as tmp:
                record_nothing_compared(tmp, why)
            return R.StripsResult(why=why)
        a = c.all_pairs
        return R.StripsResult(pairs=len(c.pairs), rms_m=round(a.rms_m, 4), nmad_m=round(a.nmad_m, 4))

    def run_classify(self, root) -> R.ClassifyResult:
        from aerotri.core.atomic import remove_leftovers
        from lidarctl.tiles import classify_files

        # what a killed run left next to classified/ (the set's temporary folder, the tiles' work folder); the
        # tiles it finished are in work/classify_resume until the set commits
        remove_leftovers(self.lo)
        st = classify_files(self.classify_inputs(), self.project.classified_dir, crs=self.project.crs,
                            params=self.options.classify, suffix=".laz",
                            resume_dir=self.project.work_dir / CLASSIFY_RESUME_DIR_NAME)
        return R.ClassifyResult(points=st.n_points, strips=st.n_files, tiles=st.run.n_tiles)

    def run_rasters(self, root) -> R.RastersResult:
        from lidarctl.rasters.crown_model import write_crown_model
        from lidarctl.rasters.products import write_rasters

        write_rasters(self.classified(), self.lo, self.options.rasters.res_m, crs=self.project.crs,
                      resume_dir=self.project.work_dir / RASTERS_RESUME_DIR_NAME)
        # the trees' crowns for the true ortho's occlusion test (docs/true-ortho.md, "Tree crowns fitted to their
        # returns"), after the nearest-return DSM they are cut into
        write_crown_model(self.classified(), self.project.dsm_nearest_path, self.lo)
        return R.RastersResult(res_m=self.options.rasters.res_m)

    def corner_outputs(self, root) -> list[Path]:
        from lidarctl.corners.roof_corners import read_corner_summary

        path = self.project.corners_summary_path
        usable = read_corner_summary(path).stats.n_usable > 0 if path.is_file() else True
        return [self.project.corners_summary_path] + (
            [self.project.corners_path, self.project.roof_planes_path, self.project.roof_outlines_path]
            if usable else [])

    def run_corners(self, root) -> R.CornersResult:
        from lidarctl.corners.roof_corners import corner_control

        res = corner_control(self.classified(), self.lo, self.stage_settings("corners"), record_none=True)
        notes = ()
        if res.no_usable and res.stats.n_building_points == 0:
            # a cloud without buildings (docs/chain.md: as no usable roof corner): no setting gives it corners
            notes = (f"{res.no_usable}; the chain goes on without LiDAR control",)
        elif res.no_usable:
            hint = "a smaller min_edge_m"
            if self.options.corners.roof == "flat":
                hint = "roof = \"any\" or " + hint
            notes = (f"{res.no_usable}; the chain goes on without LiDAR control (or try [corners] {hint} "
                     "in project.toml)",)
        return R.CornersResult(corners=res.stats.n_corners, usable=res.stats.n_usable, notes=notes)

    def vectors_reference(self) -> Path | None:
        """[vectors] reference, else the simulator's true building outlines when present."""
        ref = self.options.vectors.reference
        if ref is not None:
            return Path(ref)
        return self.project.truth_buildings_path if self.project.truth_buildings_path.is_file() else None

    def vectors_inputs(self, root=None) -> list[Path]:
        ref = self.vectors_reference()
        return self.classified() + ([ref] if ref is not None else []) + self.qa_tolerances()

    def vectors_options(self, root=None) -> dict:
        """[vectors] and [qa], and the map scale and terrain class the check is judged at (``qa_settings`` of the
        block's scale: from the camera, the frames' positions and the DEM, which change with the adjustment)."""
        from aerotri.core.tolerances import qa_settings
        from aerotri.geom.block_scale import project_block_scale

        out = dict(to_table(self.options.vectors), qa=to_table(self.project.qa))
        if self.vectors_reference() is not None:  # only the check is judged by the table
            qa = qa_settings(self.root, project_block_scale(self.project))
            out["judged_at"] = dict(map_scale=qa.map_scale, terrain=qa.terrain)
        return out

    def vectors_outputs(self, root=None) -> list[Path]:
        return [self.project.vectors_path] + ([self.project.vectors_check_path] if self.vectors_reference() else [])

    def run_vectors(self, root) -> R.VectorsResult:
        from aerotri.core.tolerances import qa_settings
        from aerotri.geom.block_scale import project_block_scale
        from lidarctl.vectors.layers import MapVectorSettings, vectors_to_file
        from lidarctl.checks.vectors import VectorCheckSettings, check_files

        p = self.project
        s = vectors_to_file(self.classified(), p.vectors_path, params=MapVectorSettings(), crs=p.crs, owned=True)
        c = s.counts
        counts = dict(buildings=c.buildings, roads=c.roads, water=c.water, spot_heights=c.spot_heights)
        ref = self.vectors_reference()
        if ref is None:
            return R.VectorsResult(**counts, notes=("no reference vectors ([vectors] reference): the line map is "
                                                    "not checked",))
        if ref == p.truth_buildings_path:
            ref = self.truth_outline_reference()
        qa = qa_settings(root, project_block_scale(p))
        check = check_files(p.vectors_path, ref, VectorCheckSettings(layers=("buildings",), scale=qa.map_scale,
                                                             terrain=qa.terrain), p.vectors_check_path)
        b = check.record.buildings
        return R.VectorsResult(**counts, checked=True, corner_rms_xy_m=b.rms_xy_corner_m if b else None,
                               corners=b.n_matched_corners if b else None)

    def truth_outline_reference(self) -> Path:
        """The simulator's roof outlines (truth/buildings.geojson, part "roof_outline": what the LiDAR sees;
        in the project's grid) as the "buildings" layer of a GeoPackage in the project's CRS
        (work/vectors_reference.gpkg)."""
        import numpy as np
        import pyproj
        import shapely

        from aerotri.core.vector_files import VectorLayer, write_layers

        feats = [f for f in _json(self.project.truth_buildings_path)["features"]
                 if f["properties"].get("part") == "roof_outline"]
        geoms = [shapely.geometry.shape(f["geometry"]) for f in feats]
        ids = np.array([f["properties"]["building_id"] for f in feats])
        return write_layers(self.project.work_dir / "vectors_reference.gpkg",
                            [VectorLayer("buildings", "Polygon", geoms, {"building_id": ids})],
                            crs=pyproj.CRS(self.project.crs).to_wkt())

    # -- tie points and adjustments -------------------------------------------------------------
    def run_match(self, root) -> R.MatchResult:
        from aerotri.match import match_project

        rep = match_project(root, self.stage_settings("match"))
        from aerotri.adjust.flight_acceptance import say_split_block

        say_split_block(root, rep.components)
        return R.MatchResult(tracks=rep.tracks, observations=rep.observations, components=rep.components)

    def adjust_inputs(self, root, control: bool = True) -> list[Path]:
        # project.toml by its sections the adjustment reads (``adjust_project_toml``, an option), not as a file
        files = [self.project.tiepoints_path, self.project.gnss_path, self.project.camera_path]
        if control:
            files += [self.project.control_points_path, self.project.control_image_points_path]
        s = self.first_settings().settings if not control else self.final_settings().settings
        if s.initial_eo is not None:
            files.append(Path(s.initial_eo))
        files += [Path(p) for p in (s.dem, s.ndsm, s.check_dem) if p is not None]
        if control:  # the final adjustment's report judges the block by [qa] (a user's tolerance table)
            files += self.qa_tolerances()
        if s.planes is not None:  # a corners folder or the file itself
            files.append(Path(s.planes) / "roof_planes.geojson" if Path(s.planes).is_dir() else Path(s.planes))
        return files

    def adjust_project_toml(self) -> dict:
        """The sections of project.toml the adjustments read: the project's own ([project], [camera], [gnss],
        [control], [flight], [qa]), [adjust], and any other but the sections of the stages they do not read. Part of
        their options instead of project.toml as a file (trial-rerun: [rectify] res_m, [mosaic] seams or any other
        stage's key re-ran both bundle adjustments, whose at/eo.txt came out the same)."""
        import tomllib

        from aerotri.core.project import PROJECT_SECTIONS, STAGE_SECTION_NAMES

        not_read = set(STAGE_SECTION_NAMES) - {"adjust"} - set(PROJECT_SECTIONS)
        with open(self.project.config_path, "rb") as f:
            table = {k: v for k, v in tomllib.load(f).items() if k not in not_read}
        if isinstance(table.get("qa"), dict) and "pdf" in table["qa"]:
            # the accuracy report's PDF is no input of an adjustment (trial s96 L8: qa.pdf = false re-ran
            # adjust_final, about 11 min on a 10,000-frame block, at/eo.txt the same)
            table["qa"] = {k: v for k, v in table["qa"].items() if k != "pdf"}
        if isinstance(table.get("project"), dict) and "crs" in table["project"]:
            # the CRS itself, not the name of a .prj file holding it (review 44: an edited grid.prj re-ran nothing)
            table["project"] = dict(table["project"], crs=self.project.crs)
        return table

    def no_first_adjustment(self, root=None) -> str | None:
        why = self.no_corners()
        if why:
            return f"only needed for the control transfer: {why}"
        if not self.has_gnss:
            return "no GNSS (gnss.txt): the control transfer starts from [adjust] initial_eo"
        return None

    def first_settings(self) -> Resolved:
        """The first adjustment: tie points and GNSS only (the datum from GNSS, no corrections per strip), with the
        LiDAR surface control (``aerotri.adjust.pipeline.project_settings``, as ``aerotri adjust P --no-control``)."""
        from aerotri.adjust.pipeline import project_settings

        return project_settings(self.project, self.stage_settings("adjust"), first=True)

    def run_adjust_first(self, root) -> R.AdjustResult:
        from aerotri.adjust.pipeline import run_adjustment

        res = run_adjustment(root, self.first_settings(), out_dir=self.first, html=False)
        # the orientations belong to this camera (self-calibrated, or the nominal one)
        write_text_atomic(self.first / "camera.toml", res.adjustment.camera_adjusted.to_toml())
        return adjustment_result(res.record)

    def final_settings(self) -> Resolved:
        """The final adjustment: [adjust] with LiDAR control when it was transferred, completed from the project
        folder as ``aerotri adjust P`` completes it (``aerotri.adjust.pipeline.project_settings``)."""
        from aerotri.adjust.pipeline import project_settings

        r = self.stage_settings("adjust")
        if self.has_lidar:
            why = self.no_corners()
            if why and r.settings.use_control and self.own_control():
                # the surveyor's own control/ (no transfer.json: not made from the LiDAR) stays the control (trial-cn:
                # its check points dropped without a word, "check points 0", where aerotri adjust used them)
                r = r.replace("use_control", True, "aerotri run",
                              f"with the control points of {self.project.control_points_path} (no LiDAR control: {why})")
            elif why and r.settings.use_control:
                r = r.replace("use_control", False, "aerotri run", f"without LiDAR control: {why}")
        elif r.settings.dem is None and (self.dem is not None or self.options.rectify.dem is not None):
            # the DEM the orthos go on holds the block too (s95: `aerotri run P --dem DEM.tif` on a drone block left
            # the tie points 3.56 m below it, the orthos up to 3.48 m off it and 45 % of the mosaic empty; rectify's
            # own warning said to orient the block on it)
            dem = Path(self.dem if self.dem is not None else self.options.rectify.dem)
            r = r.replace("dem", dem, "aerotri run --dem" if self.dem is not None else "[rectify] dem",
                          f"surface control on {dem}, the DEM of the orthophotos ([adjust] dem unset, no LiDAR)")
        return project_settings(self.project, r)

    def final_notes(self, r: Resolved) -> list[str]:
        """The summary's notes on the final adjustment's settings."""
        s, notes = r.settings, []
        if s.dem is not None:
            notes.append(f"surface control: tie points on the ground held to {s.dem}"
                         + (f", on roofs to the roof planes of {s.planes}" if s.planes is not None else ""))
        if "use_control" in r.notes:
            notes.append(r.notes["use_control"])
        elif not self.has_lidar and s.use_control and self.project.control_points_path.is_file():
            notes.append(f"with the control points of {self.project.control_dir / 'points.csv'} (no LiDAR)")
        elif not self.has_lidar:
            notes.append("no LiDAR and no control/points.csv: the datum comes from GNSS"
                         + (", the heights from the DEM too" if s.dem is not None else " alone"))
        if "gnss_correction" in r.notes:
            notes.append(f"[adjust] gnss_correction: {r.notes['gnss_correction']}")
        return notes

    def control_inputs(self, root) -> list[Path]:
        eo, camera = self.control_orientations()
        return [self.project.corners_path, eo, camera] + self.images()

    def control_orientations(self) -> tuple[Path, Path]:
        """EO and camera the corners are measured with: the first adjustment's, else [adjust] initial_eo."""
        if self.has_gnss:
            return self.first / "eo.txt", self.first / "camera.toml"
        return Path(self.options.adjust.initial_eo), self.project.camera_path

    def run_control(self, root) -> R.ControlResult:
        from aerotri.control.pipeline import run_control

        eo, camera = self.control_orientations()
        sm = run_control(root, self.project.corners_path, eo, camera, settings=self.stage_settings("control"))
        return R.ControlResult(corners_accepted=sm.corners_accepted, control_full=sm.control_full,
                               control_height=sm.control_height, check_points=sm.check_points,
                               layout_targets=sm.layout_targets, layout_targets_unfilled=sm.layout_targets_unfilled)

    def adjust_final_outputs(self, root=None) -> list[Path]:
        out = [self.project.eo_path, self.project.adjusted_camera_path, self.project.adjustment_report_path]
        if self.options.adjust.leave_one_out:
            out.append(self.project.at_dir / "leave_one_out.json")
        return out

    def warn_hand_options_dropped(self, r: Resolved) -> None:
        """Warn when the adjustment on disk (at/report.json) was made by ``aerotri adjust`` with options on its
        command line that the chain's settings do not repeat: the chain adjusts again by project.toml and replaces
        it (new-user trial s51: NGI adjusted by hand with ``--dem``, then ``aerotri run``: re-adjusted without the
        DEM, 0.0128 -> 0.0554 deg from the national AT, with no word)."""
        from aerotri.core.settings import COMMAND_LINE

        try:
            before = json.loads(self.project.adjustment_report_path.read_text()).get("settings") or {}
        except (OSError, ValueError, AttributeError):
            return
        if not isinstance(before, dict):  # (review 52: a report.json of another shape stopped the chain)
            return
        root = self.project.root

        def files(v) -> list[Path]:  # where a file named then may be: from here, or from the project folder
            return [q for q in (Path(v), root / v) if q.is_file()] if isinstance(v, str) and v else []

        def same(a, b) -> bool:
            if a == b:
                return True
            if isinstance(a, list) and isinstance(b, list):  # (--self-cal radial,pp is [adjust]'s ["pp", "radial"])
                return sorted(map(str, a)) == sorted(map(str, b))
            fa, fb = files(a), files(b)
            if fa and fb:  # (review 52: another folder's dem.tif is another DEM)
                return any(x.resolve() == y.resolve() for x in fa for y in fb)
            # a file's name as typed then, relative to that command's folder and not found from here: by its name
            return isinstance(a, str) and isinstance(b, str) and Path(a).name == Path(b).name

        def shown(v) -> str:  # (a file by its whole path: [adjust] reads a relative one from the project folder)
            f = files(v)
            return json.dumps(str(f[0].resolve()) if f else v)

        now = r.record()
        dropped = [f"{k} = {shown(row.get('value'))} (now {json.dumps(now[k]['value'])})"
                   for k, row in before.items() if isinstance(row, dict) and row.get("source") == COMMAND_LINE
                   and k in now and not same(now[k].get("value"), row.get("value"))]
        if dropped:
            _log.warning(f"{self.project.adjustment_report_path}: the adjustment there was made by `aerotri adjust` "
                         f"with {', '.join(dropped)} on its command line; the chain adjusts again with project.toml's "
                         "[adjust] and replaces it: put those in [adjust] to keep them (docs/settings.md)")

    def run_adjust_final(self, root) -> R.AdjustResult:
        from aerotri.adjust.pipeline import run_adjustment

        from aerotri.exchange import export_project

        settings = self.final_settings()
        notes = self.final_notes(settings)
        self.warn_hand_options_dropped(settings)
        res = run_adjustment(root, settings)
        export_project(root)  # PATB and COLMAP, read back from at/
        notes = notes + list(res.record.datum_notes)  # no GNSS: what the datum rests on
        loo = {}
        if settings.settings.leave_one_out:
            from aerotri.adjust.leave_one_out import run_leave_one_out

            run = run_leave_one_out(root, settings.settings, full=res.adjustment)
            loo = dict(loo_rms_xy_m=round(run.rms_xy_m, 3), control_scatter_xy_m=round(run.scatter.rms_xy_dof_m, 3))
        return adjustment_result(res.record, **loo, notes=tuple(notes))

    def run_tie_point_dem(self, root) -> R.TiePointDemResult:
        from ortho.points_dem import chain_min_rays, write_points_dem

        min_rays = chain_min_rays(root)
        s = write_points_dem(root, self.tie_point_dem_path, min_rays=min_rays)
        return R.TiePointDemResult(res_m=s.res_m, points=s.points, cells_measured=s.cells_measured,
                                   notes=("no LiDAR or given DEM: the orthophotos on the DEM of the adjusted tie "
                                          f"points ({self.tie_point_dem_path})",)
                                   + ((f"tie points seen in 2 frames or more: too few in 3 to follow the ground "
                                       f"({s.points} points used)",) if min_rays == 2 else ())
                                   + ((s.extension_words(),) if s.cells_extrapolated else ()))

    # -- orthophotos ----------------------------------------------------------------------------
    def dsm_path(self) -> Path | None:
        """The DSM of the true ortho: [rectify] dsm, else the LiDAR stages' DSM (lidar_out/dsm.tif, written by the
        rasters stage), else none."""
        if self.options.rectify.dsm is not None:
            return Path(self.options.rectify.dsm)
        if self.has_lidar:
            return self.project.dsm_path
        return None

    def rectify_settings(self) -> Resolved:
        """[rectify] with the chain's defaults: the DEM of ``dem_path``; a true ortho on the DSM whenever there is
        one (``dsm_path``) and [rectify] true_ortho is not set (``true_ortho = false``: the conventional ortho); on
        the LiDAR stages' DSM its occlusion test on their nearest-return DSM with the trees' fitted crowns
        (lidar_out/dsm_crowns.tif and lidar_out/crowns.gpkg) unless [rectify] occlusion_dsm says otherwise, and the
        roof outlines the corners stage traced as the building footprints (lidar_out/roof_outlines.gpkg,
        ``lidar_roof_outlines``) unless [rectify] footprints names a cadastre."""
        r = self.stage_settings("rectify")
        if r.settings.dem is None and self.dem_path() is not None:
            # (trial s105: a block without LiDAR has the tie points' DEM, said to be "the LiDAR stages' DEM")
            r = r.replace("dem", self.dem_path(), r.sources.get("dem", "default"),
                          "the LiDAR stages' DEM" if self.has_lidar else "the adjusted tie points' DEM: no LiDAR")
        dsm = self.dsm_path()
        if dsm is not None and r.sources.get("true_ortho", DEFAULT) == DEFAULT:
            r = r.replace("true_ortho", True, "aerotri run", "a DSM exists: the chain makes the true ortho")
        if r.settings.true_ortho and r.settings.dsm is None and dsm is not None:
            r = r.replace("dsm", dsm, r.sources.get("dsm", DEFAULT), "the LiDAR stages' DSM")
            if r.settings.occlusion_dsm is None:
                r = r.replace("occlusion_dsm", self.project.dsm_crowns_path, r.sources.get("occlusion_dsm", DEFAULT),
                              "the LiDAR stages' nearest-return DSM with the trees' fitted crowns")
                if r.settings.crowns is None:
                    r = r.replace("crowns", self.project.crowns_path, r.sources.get("crowns", DEFAULT),
                                  "the LiDAR stages' tree crowns fitted to their returns")
            if r.settings.footprints is None and self.lidar_roof_outlines() is not None:
                r = r.replace("footprints", self.project.roof_outlines_path, r.sources.get("footprints", DEFAULT),
                              "the LiDAR stages' roof outlines: no cadastre given")
        return r

    def _outlined_share_words(self) -> str:
        """The corners stage's outlined share (corners.json) for the rectify note: ", 90 % of the building points on an
        outlined roof"; "" when it has none (not run yet, or a record from before it was kept)."""
        from lidarctl.corners.roof_corners import read_corner_summary

        path = self.project.corners_summary_path
        share = read_corner_summary(path).stats.outlined_share if path.is_file() else None
        return "" if share is None else f", {100 * share:.0f} % of the building points on an outlined roof"

    def lidar_roof_outlines(self) -> Path | None:
        """lidar_out/roof_outlines.gpkg when the corners stage writes it (it has, or has not run yet: its outputs are
        decided as ``corner_outputs`` decides them) in the project CRS; None without LiDAR, when it found no usable
        corner (it writes no outlines then) or traced them in another CRS."""
        from aerotri.geom.crs.definition import same_horizontal
        from lidarctl.corners.roof_corners import read_corner_summary

        outlines = self.project.roof_outlines_path
        if not self.has_lidar or outlines not in self.corner_outputs(self.root):
            return None
        path = self.project.corners_summary_path
        if path.is_file():
            crs = read_corner_summary(path).crs
            from pyproj import CRS

            if crs is None or not same_horizontal(CRS.from_user_input(crs), CRS.from_user_input(self.project.crs)):
                return None
        return outlines

    def completed_settings(self) -> dict:
        """The sections the chain completes from the project folder, as ``aerotri settings`` lists them: section ->
        (its settings record, its title). [rectify]: the true ortho whenever a DSM exists (trial s105 F2: listed as
        ``true_ortho : False [default]`` beside a chain that made the true ortho)."""
        return {"rectify": (self.rectify_settings().record(),
                            "[rectify] (as aerotri run PROJECT takes it; ortho rectify PROJECT alone makes the "
                            "conventional ortho unless --true-ortho or true_ortho = true)")}

    def run_rectify(self, root) -> R.RectifyResult:
        from ortho.block import rectify_block

        settings = self.rectify_settings()
        done = rectify_block(root, settings)
        note = self.true_ortho_note(settings)
        return R.RectifyResult(frames=len(done.image_ids), res_m=done.res_m,
                               ortho="true (DSM)" if settings.settings.true_ortho else "conventional (DEM)",
                               notes=(note,) if note else ())

    def true_ortho_note(self, settings: Resolved) -> str | None:
        """What the summary and the console say of the true ortho: on (and why) or off with a DSM at hand."""
        s, source = settings.settings, settings.sources.get("true_ortho", DEFAULT)
        if s.true_ortho:
            why = ("the chain's default with a DSM" if source == "aerotri run"
                   else f"[rectify] true_ortho = true in {self.project.config_path.name}" if source == PROJECT_TOML
                   else f"true_ortho from the {source}")
            occl = f", occlusion on {_rel(s.occlusion_dsm, self.root)}" if s.occlusion_dsm is not None else ""
            if s.footprints is not None:
                occl += f" with the building footprints {_rel(s.footprints, self.root)}"
                if Path(s.footprints) == self.project.roof_outlines_path:
                    occl += f" (the LiDAR's roof outlines{self._outlined_share_words()}: [rectify] footprints for a " \
                            "cadastre)"
            return (f"true ortho on the DSM {_rel(s.dsm, self.root)}{occl} ({why}; occluded cells filled from the frames "
                    f"that see them; [rectify] true_ortho = false for the conventional ortho on the DEM)")
        if self.dsm_path() is not None:
            return (f"conventional ortho on the DEM: [rectify] true_ortho = false (the DSM "
                    f"{_rel(self.dsm_path(), self.root)} is not used)")
        return None

    def run_mosaic(self, root) -> R.MosaicResult:
        from aerotri.core.errors import InputError
        from ortho.mosaic import mosaic_block

        edited = self.edited_seamlines()
        if edited is None:
            done = mosaic_block(root, self.stage_settings("mosaic"))
        else:
            # the mosaic must be made again (new frames, settings or blend rules): with the operator's seamlines, not
            # over them (the edit would be lost without a word)
            _log.warning(f"[mosaic] made again with the edited seamlines {edited} the mosaic on disk was made with "
                         f"(remove {_rel(self.project.mosaic_path, self.root)} to have the chain route its own)")
            try:
                # frame orthos made again (another rectify setting) may cover a little more than when the polygons
                # were drawn: the cells only such a frame sees go to it, said (trial s105 F3: 10 m2 beside the one
                # frame that sees them stopped the chain until the operator edited again or dropped the edit)
                done = mosaic_block(root, self.stage_settings("mosaic"), seamlines=edited, give_sole_gaps=True)
            except InputError as e:
                raise InputError(f"{e}; the chain re-makes the operator's edited mosaic with these seamlines: fix them, "
                              f"or remove {_rel(self.project.mosaic_path, self.root)} to have the chain route its "
                              "own") from None
        return R.MosaicResult(width_px=done.width_px, height_px=done.height_px)

    # -- checks and report ----------------------------------------------------------------------
    def roof_corners_path(self) -> Path | None:
        """The roof corners of the DOM check (``ortho.check.run_check``'s choice): [dom_check] roof_corners, else the
        simulator's beside its true orthophoto as the reference, else None (the check finds roofs in the nDSM)."""
        from ortho.check import simulator_roof_corners

        given = self.options.dom_check.roof_corners
        return Path(given) if given is not None else simulator_roof_corners(self.reference_ortho)

    def run_dom_check(self, root) -> R.DomCheckResult:
        from ortho.check import run_check

        rep = run_check(root, self.stage_settings("dom_check"), reference_path=self.reference_ortho)
        d, roofs = rep.displacement, rep.roofs
        return R.DomCheckResult(rms_xy_m=d.rms_xy_m, rms_xy_gsd=d.rms_xy_gsd, count=d.count,
                                roofs_rms_xy_m=roofs.rms_xy_m if roofs else None,
                                roofs_rms_xy_gsd=roofs.rms_xy_gsd if roofs else None,
                                roofs_count=roofs.count if roofs else None)

    def run_height_check(self, root) -> R.HeightCheckResult:
        from lidarctl.checks.heights import check_heights_file

        result = check_heights_file(self.classified(), self.surveyed_points)
        write_text_atomic(self.project.height_check_path, result.to_json())
        r = result.record
        return R.HeightCheckResult(rmse_m=r.rmse_m, mean_abs_dz_m=r.mean_abs_dz_m, n=r.n_checked)

    def run_lidar_eval(self, root) -> R.LidarEvalResult:
        from lidarctl.checks.classes import evaluate_strips, read_filter_test

        # each classified strip against its truth strip (truth/lidar/, same name, same points)
        result = evaluate_strips(self.classified(), self.project.truth_strips())
        write_text_atomic(self.project.classification_eval_path, result.to_json())
        g = read_filter_test(self.project.classification_eval_path)
        return R.LidarEvalResult(type_i_error_pct=g.type_i_error_pct, type_ii_error_pct=g.type_ii_error_pct,
                                 kappa_pct=g.kappa_pct)

    def run_report(self, root) -> R.ReportResult:
        from aerotri.qa.report import write_qa_report

        rep = write_qa_report(root)
        return R.ReportResult(verdict=rep.overall, passed=rep.passed, failed=rep.failed)


def _rel(path, root: Path) -> str:
    """A path as the project names it: relative to the project folder when inside it."""
    try:
        return Path(path).absolute().relative_to(Path(root).absolute()).as_posix()
    except ValueError:
        return str(path)


def _check_raster(path, what: str) -> None:
    """``InputError`` unless ``path`` is a raster GDAL reads, of at least 2 x 2 pixels, with its first and last
    rows readable."""
    import rasterio

    from aerotri.core.errors import InputError

    try:
        with rasterio.open(path) as ds:
            size = (ds.width, ds.height)
            if min(size) >= 2:
                _read_ends(ds, path, what)
    except (rasterio.errors.RasterioIOError, OSError) as exc:
        raise InputError(f"{path}: cannot read the {what} ({exc})") from None
    if min(size) < 2:
        raise InputError(f"{path}: the {what} is {size[0]} x {size[1]} px; expected a raster of at least 2 x 2")


def _frame_orthos_missing(index_path: Path) -> str | None:
    """Why the frame orthos ``index_path`` lists are not all there as it records them (missing, or of another size:
    a stat each, no hashing), None when they are or the index cannot be read (the stage's own checks say why)."""
    import json

    try:
        frames = json.loads(index_path.read_text())["frames"]
        listed = [(index_path.parent / e["file"], e.get("size")) for e in frames]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    missing = [p.name for p, _ in listed if not p.is_file()]
    if missing:
        return (f"output missing: {', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''} ({len(missing)} of "
                f"{len(listed)} frame orthos {index_path.name} lists)")
    other = [p.name for p, size in listed if size is not None and p.stat().st_size != size]
    if other:
        return (f"outputs changed: {', '.join(other[:4])}{' ...' if len(other) > 4 else ''} (frame orthos of another "
                f"size than {index_path.name} records)")
    return None


def _read_ends(ds, path, what: str) -> None:
    """Read a raster's first and last rows: a file cut short (a copy that stopped) has a valid header but no
    end, found here rather than by the stage that reads it after earlier stages have written."""
    import rasterio
    from rasterio.windows import Window

    from aerotri.core.errors import InputError

    try:
        for row in {0, ds.height - 1}:
            ds.read(1, window=Window(0, row, ds.width, 1))
    except (rasterio.errors.RasterioError, rasterio.errors.RasterioIOError) as exc:
        raise InputError(f"{path}: the {what} cannot be read to its end ({exc}); a file cut short?") from None


def chain_stages(root, options: ChainSettings | Resolved | None = None, reference_ortho=None, surveyed_points=None,
                 dem=None, truth_classes: bool = False) -> list[Stage]:
    """The stages of the project in ``root`` (its project.toml gives the options unless ``options``)."""
    project = Project.open(root)
    def path(p):
        return Path(p) if p else None

    chain = Chain(project, options if options is not None else read_options(project), path(reference_ortho),
                  path(surveyed_points), path(dem), truth_classes)
    return chain.stages()
