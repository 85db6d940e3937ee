"""DOM accuracy: planimetric displacement of an orthoimage against a reference or surveyed points.

Patch matching (``ortho.patches``): the DOM is cut into square patches on a regular grid; each
textured patch is located in the reference orthophoto (resampled onto the DOM grid) by normalised
cross-correlation. The displacement is DOM position minus reference position, in pixels (x right,
y down) and in metres (dE east, dN north). Patches whose reference texture runs in one direction only (roads: the
aperture problem, ``ortho.patches.MIN_TEXTURE_RATIO``) are left out and counted (``left_out_one_direction``); so are
those whose sub-pixel refinement fails (``left_out_unsettled``: a periodic texture).

Roofs (against a true orthophoto as the reference): a patch centred on every roof corner (``--roof-corners`` CSV,
else the outline corners of the nDSM's buildings) correlated with the reference over the cells valid in both
(masked NCC, ``measure_roof_patches``): the report's ``roofs`` row, beside the open ground's ``displacement``.

Surveyed points: a CSV ``id,x,y,x_dom,y_dom`` with the surveyed coordinates and the coordinates of
the same point measured in the DOM (both in the DOM's CRS); the displacement is DOM minus survey.

Streaming: the DOM is read in blocks of 2048 px (with a halo of a patch and its search range), the reference
and the nDSM resampled onto each block, GDAL's block cache bounded (``CHECK_CACHE_BYTES``); only five numbers per
patch are kept. The statistics take every patch; the report lists, and its plot draws, at most
``MAX_LISTED`` of them, evenly spread, so that the report of a gigapixel DOM stays the size of a demo's.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import logging
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.core.gdal_cache import MiB, stage_block_cache
from aerotri.core.limits import usable_cores
from aerotri.core.log import track
from aerotri.core.point_ids import refuse_repeated_id, warn_coincident_points
from aerotri.core.atomic import refuse_input_as_output
from aerotri.core.project import Project, project_paths
from aerotri.core.records import to_record
from aerotri.core.settings import COMMAND_LINE, Resolved, settings_of
from aerotri.core.textio import read_record, read_text, record_error
from aerotri.core.figures import pyplot, save_png
from aerotri.geom.crs.definition import height_unit_m, map_axes_unit_m, map_axis_signs, parse_crs
from aerotri.geom.crs.raster_warp import open_north_up
from ortho.grid import north_up_flips
from ortho.patches import (MAX_REFINE_PX, MIN_PATCH_PX, MIN_TEXTURE_RATIO, PatchDisplacements, match_patches,
                           parabola_peak)
from ortho.settings import CheckSettings

if TYPE_CHECKING:  # ortho.mosaic (OpenCV, scipy) is imported only where seams are measured or read
    from ortho.mosaic import SeamMisalignment

# GDAL's block cache during check (``aerotri.core.gdal_cache``): the DOM, reference and nDSM blocks of the blocks
# being compared
CHECK_CACHE_BYTES = 256 * MiB


SCHEMA_VERSION = 1  # dom_report.json (``run_check``; written without a version so far)
DOM_CHECK = "DOM check (dom_report.json)"  # the record's name in messages


@dataclasses.dataclass(frozen=True)
class GsdBin:
    """Displacements from ``from_gsd`` to ``to_gsd`` GSD (None: no upper end): their count and share (%)."""

    from_gsd: float
    to_gsd: float | None
    count: int
    pct: float


@dataclasses.dataclass(frozen=True)
class Displacement:
    """Planimetric displacements of the DOM (``displacement_statistics``): how many, the GSD (m), RMS east, north
    and plan (m; plan also in GSD), mean east and north, largest, median and 95th percentile (m), the
    distribution in GSD bins; only ``count`` (0) when nothing was measured. dom_report.json's "displacement" (and
    the accuracy report's) is ``to_record(d, drop_none=True)``: a None is not in the record."""

    count: int | None = None
    gsd_m: float | None = None
    rms_e_m: float | None = None
    rms_n_m: float | None = None
    rms_xy_m: float | None = None
    rms_xy_gsd: float | None = None
    mean_e_m: float | None = None
    mean_n_m: float | None = None
    max_xy_m: float | None = None
    max_xy_gsd: float | None = None
    median_xy_m: float | None = None
    p95_xy_m: float | None = None
    distribution_gsd: tuple[GsdBin, ...] | None = None

    @classmethod
    def of_record(cls, d: dict) -> "Displacement":
        bins = d.get("distribution_gsd")
        return cls(**{**d, "distribution_gsd": None if bins is None else tuple(GsdBin(**b) for b in bins)})



# Largest share of the DOM's textured patches (matched or not), or of a region's (a frame's region of the mosaic, a
# tile; regions of at least DOM_MIN_REGION_PATCHES of them), that may find no match in the reference (NCC peak below
# 0.7 or on the edge of the +-6 px search): a DOM, or a frame's region of it, off by more than the search loses its
# patches there instead of reading the shift, and the RMS of the rest passed (as the seams did before review 26).
# Chosen on the demo (main 6360cc7c): as made 0 of 1,231 textured patches unmatched, in every region; one frame's
# region moved 7-8 px (26 cases): 98-100 % of its region's patches unmatched while the whole DOM's share was 0.3-11 %
# and the RMS of the rest 0.080-0.090 m (as made 0.084 m, the row passed all 26; now 25 fail). Scored on the DMC
# 2 x 4 (run 2bfb756): as made 44 of 91,823 (0.05 %), at most 0.09 % of a region (s02_004, 9 of 9,837). Half lies
# far from both (bench/eval_dom_unmatched.py, bench/results/dom_unmatched.json; docs/true-ortho.md)
DOM_MAX_UNMATCHED_SHARE = 0.5
# Least textured patches of a region judged on its own: the demo's sliver regions hold 3, 11 and 15 (the 11 and 15
# judged); a region of 10 goes over half by chance with a 0.1 % unmatched rate (the DMC's) at odds of 2e-16, with
# 20 % (a reference of another year: buildings, fields changed) at 0.6 %, with 5 patches at 5.8 %
DOM_MIN_REGION_PATCHES = 10
DOM_TILE_PX = 2048  # a region of a DOM without the project's seamlines: a square tile of the check's blocks
# A share of the DOM's textured patches without a match above this is said (a warning, not a fail): a DOM as made
# loses 0-0.1 % (above), a reference of another year up to about 20 %; trial-ortho2's DOM with its top half mirrored
# lost 8 of 21 (38 %) and passed on the RMS of the rest without a word
DOM_UNUSUAL_UNMATCHED_SHARE = 0.1


@dataclasses.dataclass(frozen=True)
class UnmatchedRegion:
    """One region of the DOM (a frame's region of the project's mosaic, or a tile): its textured patches (above the
    texture floor; matched, or without a match: unsettled ones aside) and those of them that found no match."""

    name: str  # the frame's image id, or "rows R0-R1, cols C0-C1" (DOM pixels, a tile)
    textured: int
    unmatched: int

    @property
    def unmatched_share(self) -> float | None:
        """``unmatched`` of ``textured``; None without textured patches."""
        return self.unmatched / self.textured if self.textured else None


@dataclasses.dataclass(frozen=True)
class UnmatchedVerdict:
    """``UnmatchedPatches.judged_against``: ``verdict`` "fail" or None (not judged), ``reach`` the search in metres
    (" (+-2.400 m)", "" unknown), ``why`` the reason it is not judged ("" when it is)."""

    verdict: str | None
    reach: str
    why: str


@dataclasses.dataclass(frozen=True)
class UnmatchedPatches:
    """dom_report.json's ``unmatched`` (``to_record``): the open-ground patches textured enough to be matched (above
    the DOM's least texture and the texture-ratio floor) whose NCC peak in the reference was below ``min_ncc`` or on
    the edge of the +-``search_px`` search: counted, not measured (the DOM off by more than the search there, or not
    the same ground). ``textured``: those and the patches measured; ``per_region``: the same by frame region
    (``regions_by`` "frame": the project's mosaic, by ortho/seams.tif) or by tile (``regions_by`` "tile": squares of
    ``DOM_TILE_PX`` DOM pixels), regions without textured patches left out; ``lost`` says which fail the check."""

    patches: int
    textured: int
    min_ncc: float
    search_px: int
    regions_by: str
    per_region: tuple[UnmatchedRegion, ...]
    max_share: float = DOM_MAX_UNMATCHED_SHARE
    min_region_patches: int = DOM_MIN_REGION_PATCHES
    why: str = ("textured patches whose NCC peak was below min_ncc or on the edge of the search: the DOM off by more "
                "than the search there, or not the same ground")

    @property
    def share(self) -> float | None:
        """``patches`` of ``textured``; None without textured patches."""
        return self.patches / self.textured if self.textured else None

    def lost_regions(self) -> tuple[UnmatchedRegion, ...]:
        """The regions of at least ``min_region_patches`` textured patches more than ``max_share`` of which found no
        match, most unmatched first."""
        lost = (r for r in self.per_region
                if r.textured >= self.min_region_patches and r.unmatched_share > self.max_share)
        return tuple(sorted(lost, key=lambda r: (-r.unmatched_share, -r.unmatched)))

    def fails(self) -> bool:
        """Whether more than ``max_share`` of the textured patches found no match, in the whole DOM (at least one
        textured patch) or in a region judged on its own (``lost_regions``)."""
        return (self.share is not None and self.share > self.max_share) or bool(self.lost_regions())

    def too_few_matched(self) -> bool:
        """Whether more than ``max_share`` of the whole DOM's textured patches found no match: the few that did are
        no measure of the DOM (trial audit F6: a DOM 5 m off, 631 of 633 unmatched, read "plan RMS 2.370 m" from 2
        false matches)."""
        return self.share is not None and self.share > self.max_share

    def judged_against(self, limit_m: float | None, gsd_m: float | None) -> "UnmatchedVerdict":
        """The verdict of a check that ``fails`` against a plan limit (m), on a DOM of ``gsd_m``: fail where the
        +-``search_px`` search reaches the limit (a patch lost beyond it is beyond the limit), not judged where it
        is shorter (a patch beyond the search may still be within the limit) or without a limit (review 34). The
        verdict table's DOM row and the compliance section's both read it."""
        search_m = self.search_px * gsd_m if gsd_m else float("nan")
        reach = f" (+-{search_m:.3f} m)" if math.isfinite(search_m) else ""
        if limit_m is None:
            return UnmatchedVerdict(None, reach, "")
        if math.isfinite(search_m) and search_m < limit_m:
            return UnmatchedVerdict(None, reach, f"not judged: the search{reach} is shorter than the limit "
                                                 f"{limit_m:g} m, so a patch beyond it may still be within the limit")
        return UnmatchedVerdict("fail", reach, "")

    def unusual(self) -> bool:
        """Whether more than ``DOM_UNUSUAL_UNMATCHED_SHARE`` of the textured patches found no match (said, not
        failed: a reference of another date loses that many too)."""
        return self.share is not None and self.share > DOM_UNUSUAL_UNMATCHED_SHARE

    def unusual_note(self) -> str:
        """What ``unusual`` says."""
        return (f"{self.patches} of {self.textured} textured patches ({100.0 * (self.share or 0.0):.0f} %) found no "
                f"match: a DOM as made loses at most about 0.1 % (demo, DMC 2 x 4), so parts of this DOM may not be "
                "the ground the reference shows (the RMS is of the patches that matched), or the reference is of "
                "another date; look at where in the plot")

    def note(self) -> str:
        """What failed: the share of the whole DOM, the regions named (at most four)."""
        lost = self.lost_regions()
        text = (f"{self.patches} of {self.textured} textured patches ({100.0 * (self.share or 0.0):.0f} %) "
                "found no match")
        if lost:
            named = ", ".join(f"{r.name} {r.unmatched} of {r.textured}" for r in lost[:4])
            text += (f"; {len(lost)} {self.regions_by} region{'s' if len(lost) > 1 else ''} more than "
                     f"{100 * self.max_share:g} % unmatched ({named}{', ...' if len(lost) > 4 else ''})")
        return text + f": the DOM off by more than the +-{self.search_px} px search there, or not the same ground"

    @classmethod
    def of_record(cls, d: dict) -> "UnmatchedPatches":
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{**{k: v for k, v in d.items() if k in names},
                      "per_region": tuple(UnmatchedRegion(**r) for r in d.get("per_region") or ())})


def unmatched_patches(patches: PatchDisplacements, *, min_ncc: float, search_px: int, region_of) -> UnmatchedPatches:
    """The unmatched count of a check's patches (``check_against_reference``), by region: ``region_of`` (rows, cols
    -> names, DOM pixels; ``frame_regions``), else by tile of ``DOM_TILE_PX``."""
    rows = np.concatenate([patches.row_px, patches.unmatched_row_px])
    cols = np.concatenate([patches.col_px, patches.unmatched_col_px])
    lost = np.r_[np.zeros(len(patches), bool), np.ones(len(patches.unmatched_row_px), bool)]
    if region_of is not None:
        names, by = np.asarray(region_of(rows, cols), dtype=object), "frame"
    else:
        tr, tc = (rows // DOM_TILE_PX).astype(int), (cols // DOM_TILE_PX).astype(int)
        names = np.array([f"rows {r * DOM_TILE_PX}-{(r + 1) * DOM_TILE_PX - 1}, cols {c * DOM_TILE_PX}-"
                          f"{(c + 1) * DOM_TILE_PX - 1}" for r, c in zip(tr, tc)], dtype=object)
        by = "tile"
    regions = []
    for name in sorted(set(names.tolist()), key=str):
        at = names == name
        regions.append(UnmatchedRegion(str(name), int(at.sum()), int(lost[at].sum())))
    return UnmatchedPatches(int(lost.sum()), int(len(lost)), float(min_ncc), int(search_px), by, tuple(regions))


def frame_regions(root, dom_path):
    """rows, cols (DOM pixels) -> the image id of the frame whose region of the mosaic holds them (ortho/seams.tif;
    "no frame" outside), for the project's mosaic with its seamlines in the same CRS; None otherwise."""
    import rasterio

    from aerotri.geom.crs.definition import same_horizontal
    from ortho.block import read_index

    paths = project_paths(root)
    if not (paths.seams_path.is_file() and paths.frames_index_path.is_file()):
        return None
    names = list(read_index(root).image_ids)
    with rasterio.open(paths.seams_path) as s, open_north_up(dom_path, "DOM") as d:
        if not same_horizontal(s.crs, d.crs):
            return None
        labels, to_seams, dom_transform = s.read(1), ~s.transform, d.transform

    def region_of(rows, cols):
        x, y = dom_transform @ (np.asarray(cols, float) + 0.5, np.asarray(rows, float) + 0.5)
        c, r = to_seams @ (x, y)
        r, c = np.floor(r).astype(int), np.floor(c).astype(int)
        inside = (r >= 0) & (r < labels.shape[0]) & (c >= 0) & (c < labels.shape[1])
        k = np.full(len(r), -1)
        k[inside] = labels[r[inside], c[inside]]
        return ["no frame" if not 0 <= i < len(names) else names[i] for i in k]

    return region_of


@dataclasses.dataclass(frozen=True)
class DomCheck:
    """What the report and the chain read of dom_report.json (``read_dom_check``): the displacements and, when the
    seamlines were checked, the RMS misalignment across them (px) and the patches measured."""

    displacement: Displacement
    seams_rms_px: float | None = None
    seam_patches: int | None = None
    roofs: Displacement | None = None  # the roofs row (its displacement figures), when roofs were measured
    roof_corners: int | None = None  # the roofs row: roof corners given or found (``count`` of them measured)
    roof_corners_from: str | None = None  # the roofs row: where the corners came from (a file, the nDSM)
    roofs_why: str | None = None  # the roofs row: why none were measured, when it says
    json_path: str | None = None  # the report's own file (dom_report.json), as it names itself
    one_direction: int | None = None  # open-ground patches left out as textured in one direction only (roads)
    one_direction_pct: float | None = None  # their share (%) of the patches measured and left out
    mosaic_fingerprint: str | None = None  # ``mosaic_fingerprint`` of the project's mosaic checked; None: another DOM,
    # or a report written before it was recorded
    roofs_in_nodata: int | None = None  # the roofs row: corners not measurable, their evidence in the DOM's nodata
    dom_crs: str | None = None  # the DOM's CRS as checked (a contract's CRS may not be the project's)
    reference_operation: str | None = None  # DOM CRS -> reference CRS, when they differ (its description)
    reference_ballpark: bool = False  # that operation is PROJ's ballpark: the datum shift was ignored
    of_project_mosaic: bool | None = None  # the check measured the project's ortho/mosaic.tif (False: another DOM
    # given with --dom; None: a report written before it was recorded)
    dom: str | None = None  # the DOM checked, as the command named it
    roofs_in_nodata_warning: str | None = None  # the roofs row: too many corners in nodata (``roofs_in_nodata_warning``)
    seams: SeamMisalignment | None = None  # the seam measurement whole (floor, patches left out, every seam's
    # figures, the worst seam); None: the seamlines were not checked
    method: str | None = None  # "ncc_patches" (against a reference orthophoto) or "surveyed_points" (``--points``)
    unmatched: UnmatchedPatches | None = None  # the open-ground textured patches that found no match, in all and by
    # region (``UnmatchedPatches``); None: surveyed points, or a report written before they were counted
    roofs_in_dom_holes: int | None = None  # the roofs row: corners not measured, a fifth or more of their patch in the
    # DOM's nodata (``RoofDisplacements.in_dom_holes``); None: a report written before they were counted
    # the roofs row's other corners not measured (``RoofDisplacements``: patch not whole in the DOM or the reference
    # too little valid; a weak or edge peak), so that the words add up to the corners (trial s100 rc F9)
    roofs_outside_or_invalid: int | None = None
    roofs_weak: int | None = None

    def stale_for(self, mosaic_path, report_path=None) -> bool:
        """Whether this check measured an earlier version of the project's mosaic at ``mosaic_path`` (made again
        since, e.g. by a new ``ortho mosaic`` or ``aerotri run`` without a reference): by the fingerprint, or for a
        check without one (written before it was recorded) when the mosaic is newer than the check's file
        ``report_path``; False when it cannot tell. True for a check of another DOM (``of_project_mosaic`` False,
        written into the project's dom_report.json before 12c), with or without the project's mosaic: it never
        stands for the project's DOM."""
        if self.of_project_mosaic is False:  # another DOM (--dom) measured into the project's dom_report.json
            return True
        if not Path(mosaic_path).is_file():
            return False
        if self.mosaic_fingerprint is not None:
            return mosaic_fingerprint(mosaic_path) != self.mosaic_fingerprint
        return report_path is not None and Path(report_path).is_file() and \
            os.path.getmtime(mosaic_path) > os.path.getmtime(report_path)


MOSAIC_FINGERPRINT_HEAD_BYTES = 4 * MiB


def mosaic_fingerprint(path) -> str:
    """``size:sha1`` of a DOM file, the sha1 over its first 4 MiB only: a COG's header, before its tiles, holds every
    tile's offset and byte count, so a mosaic made again with other pixels differs there, and a multi-GB mosaic is
    not read whole for it."""
    import hashlib

    with open(path, "rb") as f:
        head = f.read(MOSAIC_FINGERPRINT_HEAD_BYTES)
    return f"{os.path.getsize(path)}:{hashlib.sha1(head).hexdigest()}"


_DISPLACEMENT_FIELDS = frozenset(f.name for f in dataclasses.fields(Displacement))


def read_dom_check(path) -> DomCheck:
    """dom_report.json as ``run_check`` wrote it; InputError naming the file when it is not one."""
    d = read_record(path, DOM_CHECK, SCHEMA_VERSION)
    try:
        return _dom_check_of(d)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, DOM_CHECK, exc) from None


def _dom_check_of(d: dict) -> DomCheck:
    """The typed record of a dom_report.json document (``run_check`` builds it, ``read_dom_check`` reads it)."""
    seams = d.get("seams") or {}
    row = d.get("roofs")
    roofs = None if row is None else Displacement.of_record({k: v for k, v in row.items() if k in _DISPLACEMENT_FIELDS})
    row = row or {}
    one = d.get("left_out_one_direction") or {}
    return DomCheck(Displacement.of_record(d["displacement"]), seams.get("rms_px"), seams.get("patches"), roofs,
                    row.get("corners"), row.get("corners_from"), row.get("why"), d.get("json"), one.get("patches"),
                    one.get("pct"), d.get("mosaic_fingerprint"), (row.get("not_measured") or {}).get("in_nodata"),
                    d.get("crs"), (d.get("reference_operation") or {}).get("description"),
                    bool((d.get("reference_operation") or {}).get("ballpark")), d.get("dom_is_project_mosaic"),
                    d.get("dom"), row.get("in_nodata_warning"), _seams_of(d.get("seams")), d.get("method"),
                    UnmatchedPatches.of_record(d["unmatched"]) if d.get("unmatched") else None,
                    roofs_in_dom_holes=(row.get("not_measured") or {}).get("in_dom_holes"),
                    roofs_outside_or_invalid=(row.get("not_measured") or {}).get("outside_or_invalid"),
                    roofs_weak=(row.get("not_measured") or {}).get("weak"))


def _seams_of(d: dict | None):
    """dom_report.json's ``seams`` typed (``ortho.mosaic.SeamMisalignment``); None without it."""
    if not d:
        return None
    from ortho.mosaic import SeamMisalignment

    return SeamMisalignment.of_record(d)


def displacement_statistics(de_m, dn_m, res_m: float) -> Displacement:
    """RMS, max, mean and distribution of planimetric displacements (metres and GSD units); only ``count`` (0)
    without displacements."""
    de = np.asarray(de_m, float)
    dn = np.asarray(dn_m, float)
    n = len(de)
    if n == 0:
        return Displacement(count=0)
    dxy = np.hypot(de, dn)
    rms_xy = float(np.sqrt(np.mean(dxy ** 2)))
    edges_gsd = [0.0, 0.25, 0.5, 1.0, 2.0, 3.0, np.inf]
    hist, _ = np.histogram(dxy / res_m, bins=edges_gsd)
    return Displacement(
        count=n,
        gsd_m=res_m,
        rms_e_m=float(np.sqrt(np.mean(de ** 2))),
        rms_n_m=float(np.sqrt(np.mean(dn ** 2))),
        rms_xy_m=rms_xy,
        rms_xy_gsd=rms_xy / res_m,
        mean_e_m=float(de.mean()),
        mean_n_m=float(dn.mean()),
        max_xy_m=float(dxy.max()),
        max_xy_gsd=float(dxy.max() / res_m),
        median_xy_m=float(np.median(dxy)),
        p95_xy_m=float(np.percentile(dxy, 95)),
        distribution_gsd=tuple(
            GsdBin(from_gsd=float(lo), to_gsd=(None if not np.isfinite(hi) else float(hi)), count=int(k),
                   pct=100.0 * int(k) / n)
            for lo, hi, k in zip(edges_gsd[:-1], edges_gsd[1:], hist)
        ),
    )


@dataclasses.dataclass(frozen=True)
class DomPoints:
    """Surveyed points (``x``, ``y``) and where they were measured in the DOM (``x_dom``, ``y_dom``), in the DOM's
    CRS; one entry per point in file order."""

    id: list[str]
    x: np.ndarray
    y: np.ndarray
    x_dom: np.ndarray
    y_dom: np.ndarray


def read_points_csv(path) -> DomPoints:
    """Surveyed points with their DOM measurements: columns id, x, y, x_dom, y_dom (header required)."""
    path = Path(path)
    text = read_text(path, "points file (id,x,y,x_dom,y_dom)")
    reader = csv.DictReader(text.splitlines())
    need = ["id", "x", "y", "x_dom", "y_dom"]
    if reader.fieldnames is None or any(k not in reader.fieldnames for k in need):
        raise InputError(f"{path}: header must contain {','.join(need)} (got {reader.fieldnames})")
    ids, vals, lines, first_line = [], [], [], {}
    for lineno, row in enumerate(reader, start=2):
        try:
            vals.append([float(row[k]) for k in need[1:]])
        except (TypeError, ValueError):
            raise InputError(f"{path}:{lineno}: non-numeric coordinate in {row}") from None
        if not np.all(np.isfinite(vals[-1])):
            raise InputError(f"{path}:{lineno}: NaN or infinite coordinate in {row}")
        refuse_repeated_id(first_line, row["id"], lineno, f"{path}:{lineno}")
        lines.append(lineno)
        ids.append(row["id"])
    if not ids:
        raise InputError(f"{path}: no points")
    a = np.array(vals)
    warn_coincident_points(path, ids, lines, a[:, 0], a[:, 1])
    return DomPoints(ids, a[:, 0], a[:, 1], a[:, 2], a[:, 3])


@dataclasses.dataclass(frozen=True)
class SurveyedPointsDrawn:
    """The surveyed points of a check at points (``check_points``) as the plot draws them: ids, positions in the DOM
    CRS's unit (``unit_m`` metres each; ``axis_signs`` +1 / -1 where the grid counts east, north), displacements
    (m, DOM minus survey, east and north) and which were the adjustment's control (no independent check: drawn
    apart, ``aerotri.qa.compliance.dom_points_used_as_control``)."""

    ids: tuple[str, ...]
    x: np.ndarray
    y: np.ndarray
    de_m: np.ndarray
    dn_m: np.ndarray
    control: np.ndarray  # bool per point
    unit_m: float = 1.0
    axis_signs: tuple[float, float] = (1.0, 1.0)


POINT_LABELS_MAX = 40  # ids written beside the points up to this many (more would cover the map)


def _key_length_m(largest_m: float) -> float:
    """A round length (1, 2 or 5 x 10^k, in the unit given: metres, GSD) near the largest displacement, for the
    plot's scale arrow."""
    if not largest_m > 0:
        return 0.1
    k = math.floor(math.log10(largest_m))
    return max((m * 10.0 ** k for m in (1.0, 2.0, 5.0) if m * 10.0 ** k <= largest_m), default=10.0 ** k)


def _plot_points_plan(fig, ax, pts: SurveyedPointsDrawn, title: str) -> str:
    """Each surveyed point at its map position with its displacement vector, exaggerated by one factor (a scale
    arrow labelled in metres), the adjustment's control points drawn apart (trial audit F10: the points were drawn
    along x by list index with a squashed y axis). Returns the title with the exaggeration."""
    sx, sy = pts.axis_signs
    d = np.hypot(pts.de_m, pts.dn_m)
    span = max(float(np.ptp(pts.x)), float(np.ptp(pts.y)), 1e-6)  # map units
    largest_m = float(d.max()) if len(d) else 0.0
    # the largest vector a tenth of the points' extent, as the patch plot draws its patches
    scale = 0.1 * span / (largest_m / pts.unit_m) if largest_m > 0 else 1.0
    u = sx * pts.de_m / pts.unit_m * scale  # map units along the grid's axes (a westing grid counts x westwards)
    v = sy * pts.dn_m / pts.unit_m * scale
    ind = ~pts.control
    q = None
    if ind.any():
        q = ax.quiver(pts.x[ind], pts.y[ind], u[ind], v[ind], d[ind], angles="xy", scale_units="xy", scale=1,
                      cmap="viridis", width=0.004)
        fig.colorbar(q, ax=ax, label="displacement (m)")
        ax.plot(pts.x[ind], pts.y[ind], "o", ms=4, color="k", label=f"check points ({int(ind.sum())})")
    if pts.control.any():
        qc = ax.quiver(pts.x[pts.control], pts.y[pts.control], u[pts.control], v[pts.control], angles="xy",
                  scale_units="xy", scale=1, color="tab:red", width=0.004)
        ax.plot(pts.x[pts.control], pts.y[pts.control], "^", ms=7, mfc="none", color="tab:red",
                label=f"the adjustment's control ({int(pts.control.sum())}): not independent")
    if len(pts.ids) <= POINT_LABELS_MAX:
        for i, x, y in zip(pts.ids, pts.x, pts.y):
            ax.annotate(i, (x, y), xytext=(3, 3), textcoords="offset points", fontsize=7)
    key_m = _key_length_m(largest_m)
    if largest_m > 0:  # the scale arrow: a round length in metres drawn at the vectors' exaggeration
        ax.quiverkey(q if q is not None else qc, 0.78, 0.06, key_m / pts.unit_m * scale, f"{key_m:g} m",
                     labelpos="E", coordinates="axes", color="k")
    pad = 0.15 * span
    ax.set_xlim(pts.x.min() - pad, pts.x.max() + pad)
    ax.set_ylim(pts.y.min() - pad, pts.y.max() + pad)
    if sx < 0:  # east to the right, north up, whichever way the grid counts
        ax.invert_xaxis()
    if sy < 0:
        ax.invert_yaxis()
    unit = "m" if pts.unit_m == 1.0 else f"x {pts.unit_m:g} m"
    ax.set_xlabel(f"x ({unit})" + (" (reversed: east to the right)" if sx < 0 else ""))
    ax.set_ylabel(f"y ({unit})" + (" (reversed: north up)" if sy < 0 else ""))
    ax.ticklabel_format(useOffset=False, style="plain")  # whole coordinates, not "+3.407e6"
    ax.legend(loc="lower left", fontsize=7)
    return f"{title}: vectors x {scale:.3g}"


def plot_displacements(path, patches: PatchDisplacements | None, stats: Displacement, title: str,
                       points: SurveyedPointsDrawn | None = None, extent_px=None,
                       flips: tuple[bool, bool] = (False, False)) -> None:
    """Vector plot of displacements (exaggerated; at most ``MAX_LISTED`` patches drawn, evenly spread) and a histogram
    of the lengths of every patch (those the statistics take: its count is the title's n); PNG. ``flips``: the DOM's
    pixel rows, columns drawn reversed so that north is up (``ortho.grid.north_up_flips``: a westing / southing
    grid)."""
    plt = pyplot()

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5.5), gridspec_kw={"width_ratios": [1.4, 1]})
    if patches is not None and len(patches):
        drawn = patches.select(_spread(len(patches), MAX_LISTED))
        d = np.hypot(drawn.dx_px, drawn.dy_px)
        scale = 0.1 * (extent_px or max(drawn.col_px.max(), drawn.row_px.max())) / max(d.max(), 1e-3)
        q = ax.quiver(drawn.col_px, drawn.row_px, drawn.dx_px * scale, drawn.dy_px * scale, d, angles="xy",
                      scale_units="xy", scale=1, cmap="viridis")
        fig.colorbar(q, ax=ax, label="displacement (GSD)")
        # the scale arrow (s95: the colour bar alone gave no length to read an arrow against)
        key = _key_length_m(float(d.max()))
        metres = f" ({key * stats.gsd_m:.3g} m)" if stats.gsd_m else ""
        ax.quiverkey(q, 0.06, 0.04, key * scale, f"{key:g} GSD{metres}", labelpos="E", coordinates="figure", color="k")
        title = f"{title}: vectors x {scale:.3g}"
        if not flips[0]:  # (row 0 at the top; a south-oriented grid's row 0 is its southern edge)
            ax.invert_yaxis()
        if flips[1]:
            ax.invert_xaxis()
        turned = " (reversed: north up)"
        ax.set_xlabel("column (px)" + (turned if flips[1] else ""))
        ax.set_ylabel("row (px)" + (turned if flips[0] else ""))
        if len(drawn) < len(patches):
            title = f"{title}: {len(drawn):,} of {len(patches):,} patches drawn"
        bx.hist(np.hypot(patches.dx_px, patches.dy_px), bins=30)
    elif points is not None and len(points.ids):
        title = _plot_points_plan(fig, ax, points, title)
        bx.hist(np.hypot(points.de_m, points.dn_m) / (stats.gsd_m if stats.gsd_m is not None else 1.0), bins=20)
    ax.set_title(title)
    ax.set_aspect("equal")
    bx.set_xlabel("displacement (GSD)")
    bx.set_ylabel("count")
    if stats.count:
        control = int(points.control.sum()) if points is not None else 0
        bx.set_title(f"RMS {stats.rms_xy_m:.3f} m ({stats.rms_xy_gsd:.2f} GSD), max {stats.max_xy_m:.3f} m, "
                     f"n={stats.count}" + (f"\n({control} of them the adjustment's control)" if control else ""))
    fig.tight_layout()
    save_png(fig, path, dpi=100)


def write_json(path, obj) -> None:
    from aerotri.core.atomic import write_text_atomic

    write_text_atomic(path, json.dumps(obj, indent=2) + "\n")


@contextlib.contextmanager
def _reading(path, what):
    """Read errors of a raster (truncated or corrupt data) as an InputError naming it."""
    import rasterio

    try:
        yield
    except (rasterio.errors.RasterioIOError, rasterio.errors.WarpOperationError) as exc:
        raise InputError(f"{path}: cannot read the {what} (truncated or corrupt? {exc})") from None


def check_block_memory(patch_px: int, search_px: int, block_px: int = 2048) -> None:
    """``ResourceError`` naming --patch-px or --search-px (the larger) when the blocks the check reads
    (``block_px`` plus a halo of a patch and its search range, DOM and reference) cannot fit this machine's memory."""
    from aerotri.core.limits import check_allocation

    side = block_px + patch_px + search_px
    option, value = ("--search-px", search_px) if search_px > patch_px else ("--patch-px", patch_px)
    check_allocation(float(side) * side * (3 * 4 + 3 * 4 + 4 * 4),
                     f"{option} {value}: DOM and reference blocks of {side:,} x {side:,} px", option)


def _on_grid(ds, window_transform, shape, crs, resampling, band_indexes=None, *, operation=None):
    """Resample (part of) an open raster onto a target window grid; returns (bands, rows, cols), valid.

    A raster in another CRS than the grid's goes through the toolkit's coordinate-operation policy
    (``operation``: grid CRS -> raster CRS; built without parameters when None, refusing a ballpark)."""
    import rasterio
    from rasterio.warp import reproject
    from rasterio.windows import transform as window_transform_of

    from aerotri.geom.crs.definition import same_horizontal
    from aerotri.geom.crs.raster_warp import read_on_grid
    from aerotri.geom.crs.transform import CrsTransformer

    idx = band_indexes or list(range(1, min(ds.count, 3) + 1))
    if operation is not None or not same_horizontal(ds.crs, crs):
        op = operation or CrsTransformer(crs, ds.crs)
        maximum = resampling == rasterio.enums.Resampling.max
        # antialiased like GDAL's bilinear below: a point-sampled reference read the same DOM in a contract CRS
        # 0.148 m RMS against 0.101 m in the project CRS (demo at 0.5 m on its 0.25 m truth; docs/new-user-trial.md)
        return read_on_grid(ds, window_transform.c, window_transform.f, window_transform.a, shape, op,
                            resampling="bilinear", bands=idx, maximum=maximum, antialias=not maximum)
    out = np.full((len(idx),) + shape, np.nan, np.float32)
    valid = np.zeros(shape, np.uint8)
    src = _source_window(ds, window_transform, shape)
    if src is None:
        return out, valid > 0
    # only the source pixels under the window are read (the whole mask per block made the check
    # quadratic in the block size); the margin keeps every bilinear / maximum kernel whole
    src_transform = window_transform_of(src, ds.transform)
    reproject(ds.read(idx, window=src), out, src_transform=src_transform, src_crs=ds.crs, src_nodata=ds.nodata,
              dst_transform=window_transform, dst_crs=crs, resampling=resampling, dst_nodata=np.nan,
              init_dest_nodata=True, num_threads=usable_cores())
    if _all_valid_over(ds, idx, window_transform, shape):
        # no mask and the grid a pixel inside the raster: the mask warped would be valid everywhere (a reference
        # orthophoto: a fifth of the block's warping on the DMC 2 x 4)
        return out, np.all(np.isfinite(out), axis=0)
    reproject(ds.dataset_mask(window=src), valid, src_transform=src_transform, src_crs=ds.crs,
              dst_transform=window_transform, dst_crs=crs, resampling=rasterio.enums.Resampling.nearest)
    return out, (valid > 0) & np.all(np.isfinite(out), axis=0)


def _all_valid_over(ds, band_indexes, window_transform, shape) -> bool:
    """Whether every cell of a target grid (same CRS) has a valid source cell: the raster's bands have no nodata,
    mask or alpha (GDAL's all-valid mask) and the grid lies at least a source pixel inside the raster."""
    from rasterio.enums import MaskFlags

    flags = ds.mask_flag_enums
    if not all(flags[i - 1] == [MaskFlags.all_valid] for i in range(1, ds.count + 1)):
        return False
    left, top = window_transform.c, window_transform.f
    right, bottom = left + shape[1] * window_transform.a, top + shape[0] * window_transform.e
    b = ds.bounds
    px, py = abs(ds.transform.a), abs(ds.transform.e)
    return (min(left, right) >= b.left + px and max(left, right) <= b.right - px
            and min(top, bottom) >= min(b.bottom, b.top) + py and max(top, bottom) <= max(b.bottom, b.top) - py)


def _source_window(ds, window_transform, shape, margin_px: int = 3):
    """The window of ``ds`` (same CRS) under a target grid, widened by a margin, clipped to the raster;
    None when they do not overlap."""
    from rasterio.windows import Window, from_bounds

    left, top = window_transform.c, window_transform.f
    right = left + shape[1] * window_transform.a
    bottom = top + shape[0] * window_transform.e
    w = from_bounds(min(left, right), min(top, bottom), max(left, right), max(top, bottom), ds.transform)
    c0 = max(0, math.floor(w.col_off) - margin_px)
    r0 = max(0, math.floor(w.row_off) - margin_px)
    c1 = min(ds.width, math.ceil(w.col_off + w.width) + margin_px)
    r1 = min(ds.height, math.ceil(w.row_off + w.height) + margin_px)
    if c1 <= c0 or r1 <= r0:
        return None
    return Window(c0, r0, c1 - c0, r1 - r0)


def _operation_to(dom_path, other_path, params, allow_ballpark: bool, what: str):
    """DOM CRS -> the other raster's CRS (None when they are the same and no parameters are given)."""
    from aerotri.geom.crs.definition import same_horizontal
    from aerotri.geom.crs.datum import load_transformation
    from aerotri.geom.crs.transform import CrsTransformer

    with open_north_up(dom_path, "DOM") as a, open_north_up(other_path, what) as b:
        if same_horizontal(a.crs, b.crs):
            return None
        return CrsTransformer(a.crs, b.crs, params=load_transformation(params) if params else None,
                              allow_ballpark=allow_ballpark)


COARSE_REFERENCE_FACTOR = 2.0  # a reference pixel beyond this many DOM pixels is said (the search is in DOM pixels)


def _pixel_m(ds) -> float | None:
    """A reference raster's pixel in metres; None for a CRS without a map length unit (a reference in degrees is
    read through the coordinate operation, and its pixel is not compared)."""
    try:
        return abs(ds.transform.a) * metres_per_unit(ds, "reference orthophoto")
    except CrsError:
        return None


def check_against_reference(dom_path, reference_path, ndsm_path=None, max_ndsm_m: float = 0.5, *, block_px: int = 2048,
                            patch_px: int = 48, step_px: int = 48, search_px: int = 6, min_ncc: float = 0.7,
                            reference_operation=None, ndsm_operation=None, min_texture_ratio: float = MIN_TEXTURE_RATIO):
    """Patch displacements of a DOM against a reference orthophoto, block by block (bounded memory: a block
    of the DOM, the reference and nDSM resampled onto it, GDAL's cache at ``CHECK_CACHE_BYTES``; only the
    patches' numbers are kept, five per patch).

    The reference (and the nDSM used to keep only ground patches, height above ground <= max_ndsm_m)
    is resampled onto each DOM block (bilinear; nDSM by maximum so that patches touching objects drop).
    A reference or nDSM in another CRS is mapped through ``reference_operation`` / ``ndsm_operation``
    (DOM CRS -> its CRS; ``aerotri.geom.crs.transform.CrsTransformer``), by default PROJ's operation when
    it is rigorous (a ballpark one is refused). Patches of texture in one direction only (``min_texture_ratio``,
    ``ortho.patches.match_patches``) are left out; their centres are in the result's ``one_direction_*``; those
    whose sub-pixel refinement failed in its ``unsettled_*``.
    """
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.windows import Window
    from rasterio.windows import transform as wtransform

    with stage_block_cache(CHECK_CACHE_BYTES), open_north_up(dom_path, "DOM") as dom, \
            open_north_up(reference_path, "reference orthophoto") as ref:
        ndsm = open_north_up(ndsm_path, "nDSM") if ndsm_path else None
        # heights above ground in the nDSM's own unit (its CRS says which); the threshold is in metres
        ndsm_unit_m = height_unit_m(parse_crs(ndsm.crs.to_wkt(), f"{ndsm_path} CRS")) if ndsm is not None else 1.0
        res = abs(dom.transform.a) * metres_per_unit(dom)  # metres: the patches' shifts in metres
        ref_res = _pixel_m(ref)
        if ref_res is not None and ref_res > COARSE_REFERENCE_FACTOR * res:
            # s95: a 0.2 m reference against a 0.05 m DOM lost 60 % of its patches as "off by more than the search",
            # with no word of the reference's pixel
            logging.getLogger(__name__).warning(
                f"{reference_path}: its pixel {ref_res:.3g} m is {ref_res / res:.1f} times the DOM's {res:.3g} m: the "
                "patches are matched on the DOM's grid, where the reference is that much blurred, and its +-"
                f"{search_px} px search reaches {search_px * res:.3g} m, {search_px * res / ref_res:.1f} reference "
                "pixels; a reference of about the DOM's resolution, or a DOM made at the reference's (--res-m), "
                "measures better")
        white, white_from = dom_white_level(dom, dom_path)
        min_std = MIN_STD_GREY_8BIT * white / 255.0  # the same patches in an 8- and a 16-bit DOM
        logging.getLogger(__name__).debug("DOM check: least patch texture %.4g DN (DOM white %g, %s)", min_std, white, white_from)
        pieces = []
        halo = search_px + patch_px
        try:
            blocks = [(r0, c0) for r0 in range(0, dom.height, block_px) for c0 in range(0, dom.width, block_px)]
            for r0, c0 in track(blocks, "DOM check, open ground", "blocks"):
                w = Window(c0, r0, min(block_px + halo, dom.width - c0), min(block_px + halo, dom.height - r0))
                shape = (int(w.height), int(w.width))
                if shape[0] < patch_px + 2 * search_px or shape[1] < patch_px + 2 * search_px:
                    continue
                with _reading(dom_path, "DOM"):
                    dmask = dom.read_masks(1, window=w) > 0
                    if not dmask.any():
                        continue
                    d = np.moveaxis(dom.read(list(range(1, min(dom.count, 3) + 1)), window=w), 0, -1)
                wt = wtransform(w, dom.transform)
                with _reading(reference_path, "reference orthophoto"):
                    rimg, rvalid = _on_grid(ref, wt, shape, dom.crs, Resampling.bilinear,
                                            operation=reference_operation)
                keep = None
                if ndsm is not None:
                    with _reading(ndsm_path, "nDSM"):
                        nd, nvalid = _on_grid(ndsm, wt, shape, dom.crs, Resampling.max, [1],
                                              operation=ndsm_operation)
                    keep = nvalid & (nd[0] * ndsm_unit_m <= max_ndsm_m)
                p = match_patches(d, np.moveaxis(rimg, 0, -1), dmask, rvalid, res_m=res, patch_px=patch_px,
                                  step_px=step_px, search_px=search_px, min_ncc=min_ncc, min_std=min_std,
                                  keep=keep, min_texture_ratio=min_texture_ratio)
                # a patch belongs to the block whose core holds its centre (no duplicates from halos)
                core = (p.row_px < block_px) & (p.col_px < block_px)
                one = (p.one_direction_row_px < block_px) & (p.one_direction_col_px < block_px)
                uns = (p.unsettled_row_px < block_px) & (p.unsettled_col_px < block_px)
                lost = (p.unmatched_row_px < block_px) & (p.unmatched_col_px < block_px)
                p = dataclasses.replace(p.select(core), one_direction_row_px=p.one_direction_row_px[one] + r0,
                                        one_direction_col_px=p.one_direction_col_px[one] + c0,
                                        unsettled_row_px=p.unsettled_row_px[uns] + r0,
                                        unsettled_col_px=p.unsettled_col_px[uns] + c0,
                                        unmatched_row_px=p.unmatched_row_px[lost] + r0,
                                        unmatched_col_px=p.unmatched_col_px[lost] + c0)
                p.row_px += r0
                p.col_px += c0
                pieces.append(p)
        finally:
            if ndsm is not None:
                ndsm.close()
        cat = lambda f: np.concatenate([getattr(q, f) for q in pieces]) if pieces else np.zeros(0)
        return PatchDisplacements(cat("row_px"), cat("col_px"), cat("dx_px"), cat("dy_px"), cat("ncc"), res,
                                  cat("one_direction_row_px"), cat("one_direction_col_px"),
                                  *map_axis_signs(dom.crs), cat("unsettled_row_px"), cat("unsettled_col_px"),
                                  cat("unmatched_row_px"), cat("unmatched_col_px")), \
            (dom.width, dom.height)


MIN_STD_GREY_8BIT = 4.0  # a patch's least texture: 4 of the 255 grey levels from black to the DOM's white level


def dom_white_level(ds, path) -> tuple[float, str]:
    """The DOM's sample value at white and where it came from, which ``match_patches``' least texture is scaled by
    (``MIN_STD_GREY_8BIT`` x white / 255) so that an 8- and a 16-bit DOM of the same block measure the same patches
    (12-bit data in a 16-bit DOM: 4 grey levels of 8 bits are 64 DN, not 4): 255 for 8 bits; the NBITS tag; a 16-bit
    project mosaic's white level from the mosaic.json beside it (the frames': 4095 for the DMC's 12-bit data); else
    for 16 bits the DOM's largest sample (its smallest overview) rounded up to whole bits, 10 to 16, as the mosaic
    finds the frames'. Float samples: 1.0 when the largest is at most 1 (a 0-1 float DOM: review 15, "no usable
    patches" at 4 of 255), else 255, the threshold as given; other types: 255."""
    dtype = np.dtype(ds.dtypes[0])
    if dtype == np.uint8:
        return 255.0, "8-bit samples"
    nbits = ds.tags(1, ns="IMAGE_STRUCTURE").get("NBITS")
    if nbits and str(nbits).isdigit():
        return float((1 << int(nbits)) - 1), f"NBITS {nbits}"
    if dtype.kind == "f":
        biggest = float(_largest_sample(ds))
        if 0.0 < biggest <= 1.0:
            return 1.0, f"{dtype} samples in 0-1"
    if dtype != np.uint16:
        return 255.0, f"{dtype} samples: the threshold as given"
    summary = Path(path).with_suffix(".json")
    if Path(path).name == "mosaic.tif" and summary.is_file():
        try:
            white = (json.loads(summary.read_text()).get("white_level") or {}).get("value")
        except (OSError, ValueError):
            white = None
        if isinstance(white, (int, float)) and white > 0:
            return float(white), f"white level of {summary.name}"
    biggest = int(_largest_sample(ds))
    n = min(16, max(10, biggest.bit_length()))
    return float((1 << n) - 1), f"largest sample {biggest}: {n} bits"


def _largest_sample(ds):
    """The largest valid sample of band 1, read from its smallest overview (or about 1,024 px across)."""
    ov = ds.overviews(1)
    f = ov[-1] if ov else max(1, max(ds.width, ds.height) // 1024)
    return ds.read(1, out_shape=(max(1, ds.height // f), max(1, ds.width // f)), masked=True).max() or 0


def metres_per_unit(ds, what: str = "DOM") -> float:
    """Metres per unit of a north-up raster's CRS (0.3048 for a DOM in feet): the cell size and the displacements
    are reported in metres, as their ``_m`` keys say (a DOM in feet had its displacements in feet as metres:
    Autzen's 1 ft orthophoto 2.236 "m" for 0.682 m). ``CrsError`` naming the file when the CRS has no length unit
    (geographic, geocentric: ``map_axes_unit_m``; a DOM in degrees read as metres: "RMS 0.000 m")."""
    return map_axes_unit_m(ds.crs, f"{ds.name}: the {what}'s CRS")[0]


def check_points(points_path, res_m: float, dom_bounds=None, unit_m: float = 1.0,
                 dom_crs=None) -> tuple[Displacement, dict]:
    """Statistics and per-point table for surveyed points measured in the DOM (``dom_bounds``: left, bottom,
    right, top of the DOM; a point measured outside it is refused by its line); coordinates in the DOM CRS's unit,
    ``unit_m`` metres each (the displacements in metres)."""
    pts = read_points_csv(points_path)
    if dom_bounds is not None:
        left, bottom, right, top = dom_bounds
        for k, (xd, yd) in enumerate(zip(pts.x_dom, pts.y_dom)):
            if not (left <= xd <= right and bottom <= yd <= top):
                raise InputError(f"{points_path}:{k + 2}: point {pts.id[k]} measured at ({xd:.3f}, {yd:.3f}), "
                                 f"outside the DOM ({left:.1f} .. {right:.1f}, {bottom:.1f} .. {top:.1f}); coordinates "
                                 "of another CRS, zone or place?")
    sx, sy = (1.0, 1.0) if dom_crs is None else map_axis_signs(dom_crs)  # a westing / southing grid: east, north
    de = sx * (pts.x_dom - pts.x) * unit_m
    dn = sy * (pts.y_dom - pts.y) * unit_m
    stats = displacement_statistics(de, dn, res_m)
    table = [{"id": i, "x_m": float(x), "y_m": float(y), "x_dom_m": float(xd), "y_dom_m": float(yd), "de_m": float(a),
              "dn_m": float(b)} for i, x, y, xd, yd, a, b in zip(pts.id, pts.x, pts.y, pts.x_dom, pts.y_dom, de, dn)]
    return stats, {"points": table, "_de": de, "_dn": dn}


def _points_drawn(root, report: dict, table: dict, unit_m: float, dom_crs) -> SurveyedPointsDrawn:
    """``check_points``' table as the plot draws it; the points the project's adjustment (at/report.json, when
    there is one) used as control marked."""
    from aerotri.core.point_ids import dom_points_used_as_control
    from aerotri.core.textio import read_json

    at_path = project_paths(root).adjustment_report_path
    at = read_json(at_path, "adjustment report") if at_path.is_file() else {}
    control = set(dom_points_used_as_control({**report, "points": table["points"]}, at if isinstance(at, dict) else {}))
    rows = table["points"]
    return SurveyedPointsDrawn(
        ids=tuple(str(r["id"]) for r in rows), x=np.array([r["x_m"] for r in rows], dtype=float),
        y=np.array([r["y_m"] for r in rows], dtype=float), de_m=np.asarray(table["_de"], dtype=float),
        dn_m=np.asarray(table["_dn"], dtype=float), control=np.array([str(r["id"]) in control for r in rows], bool),
        unit_m=unit_m, axis_signs=(1.0, 1.0) if dom_crs is None else tuple(float(a) for a in map_axis_signs(dom_crs)))


def _check_over_dom(reference_path, ndsm_path, dom_bounds, dom_crs) -> None:
    """Before any work: the reference orthophoto and the nDSM (one band of finite heights) over the DOM."""
    from ortho.dem import require_overlap

    if reference_path is not None:
        with open_north_up(reference_path, "reference orthophoto") as ref:
            require_overlap(ref, reference_path, "reference orthophoto", dom_bounds, dom_crs.to_wkt(), "the DOM")
    if ndsm_path is not None:
        with open_north_up(ndsm_path, "nDSM", heights=True) as nd:
            require_overlap(nd, ndsm_path, "nDSM", dom_bounds, dom_crs.to_wkt(), "the DOM")


# roofs: a square patch centred on every roof corner, at least ROOF_PATCH_M and ROOF_PATCH_PX DOM pixels wide (a
# roof displaced by relief must stay inside it), correlated with the reference over the valid cells (masked NCC)
ROOF_PATCH_M = 24.0
ROOF_PATCH_PX = 48
ROOF_MIN_VALID = 0.8  # share of the patch's DOM cells with a value (only they are correlated)
ROOF_MIN_NCC = 0.5  # masked-NCC peak below which the patch is not measured (demo's true ortho: 99 % above 0.85)
ROOF_HEIGHT_M = 2.5  # nDSM above which a cell is a roof (buildings found in the nDSM)
DOM_CHECK_VERSION = 2  # the chain's dom_check stage stamp: bump when dom_report.json changes at the same inputs
ROOF_LIST_TILE_PX = 1024  # the roof corners are listed by tiles of this size (``measure_roof_patches``)
ROOF_MIN_AREA_M2 = 50.0  # smaller nDSM objects (bushes, cars) are not buildings
# a corner whose evidence lies in the DOM's nodata (ground no frame sees, beside buildings): its match is ambiguous
# (the NCC somewhere farther than ROOF_RIVAL_M from the best within ROOF_MIN_MARGIN of it) and the hole made it so
# (the reference's own chip, masked by the DOM's valid cells, keeps less than ROOF_HOLE_SEPARATION of the separation
# 1 - rival NCC that the whole chip has between its place and any other). Chosen on the 2 x 2 DMC subset (0.1 m,
# 1,648 corners: 9 matched more than 1 m off, at margins 0.001-0.017 and separations 0.12-0.34 of the whole
# chip's), scored on the 2 x 4 (docs/full-size-block.md, "The DOM check's roof corners in the DOM's holes")
ROOF_RIVAL_M = 1.0
ROOF_MIN_MARGIN = 0.02
ROOF_HOLE_SEPARATION = 0.5
# the rule can hide a real displacement: roofs moved 1.25-1.5 m beside holes (a lean, a DSM offset) had 31-44 % of
# their corners counted "in nodata" in review 12b's synthetic town, against 1.0-1.6 % on the DMC blocks it was
# chosen on (2 x 2 and 2 x 4 subsets). Over this share (of the corners with a usable peak) the check warns and the
# report says so: 3 x the blocks' highest, far below the share that hid displacements
ROOF_MAX_IN_NODATA_PCT = 5.0


@dataclasses.dataclass(frozen=True)
class RoofDisplacements:
    """Displacements (DOM minus reference, metres east and north) of the patches centred on roof corners that
    could be measured, and why the others were not."""

    x_m: np.ndarray
    y_m: np.ndarray
    de_m: np.ndarray
    dn_m: np.ndarray
    corners: int  # roof corners given or found
    outside_or_invalid: int  # patch not whole inside the DOM, or less than ROOF_MIN_VALID of the reference valid
    weak: int  # NCC peak below ROOF_MIN_NCC, or on the edge of the search (+- half a patch)
    patch_m: float
    in_nodata: int = 0  # not measurable: the evidence lies in the DOM's nodata (``roof_evidence_in_nodata``)
    # those corners: x_m, y_m and the shift of the DOM patch's own (ambiguous) best match, de_m, dn_m, one row each
    in_nodata_corners: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4)))
    # not measured: less than ROOF_MIN_VALID of the DOM's patch valid, the corner beside the DOM's holes (trial s98:
    # 493 of 2,094 on the tall block, filed with the patches off the DOM while the row said "11 in the DOM's nodata")
    in_dom_holes: int = 0

    @property
    def in_nodata_pct(self) -> float:
        """Share (%) of the corners with a usable peak (measured or counted in nodata) counted in nodata."""
        usable = len(self.de_m) + self.in_nodata
        return 100.0 * self.in_nodata / usable if usable else 0.0


def roofs_not_measured_words(report: "DomCheck") -> str:
    """The roofs row's corners not measured for the DOM's nodata, in words (empty when none): their evidence in it
    (``roof_evidence_in_nodata``), and their patch a fifth or more in it (``RoofDisplacements.in_dom_holes``)."""
    parts = ([f"{report.roofs_in_nodata} not measurable: in the DOM's nodata"] if report.roofs_in_nodata else []) + (
        [f"{report.roofs_in_dom_holes} not measured: {100 * (1 - ROOF_MIN_VALID):.0f} % or more of their patch in "
         "the DOM's nodata"] if report.roofs_in_dom_holes else []) + (
        [f"{report.roofs_outside_or_invalid} not measured: their patch not whole in the DOM, or the reference's too "
         "little valid"] if report.roofs_outside_or_invalid else []) + (
        [f"{report.roofs_weak} without a clear match (a weak peak, or one at the search's edge)"]
        if report.roofs_weak else [])
    return f" ({'; '.join(parts)})" if parts else ""


def reference_ballpark_words(report: "DomCheck") -> str:
    """Words for a reference reached through PROJ's ballpark operation (empty otherwise): the datum shift between the
    DOM's CRS and the reference's was ignored and is in the check's figures (the console, the report and the
    accuracy report say it alike)."""
    if not report.reference_ballpark:
        return ""
    return ("PROJ's ballpark operation, accepted with --allow-ballpark: the datum shift between them is ignored and "
            "is in the figure")


def roofs_in_nodata_warning(in_nodata: int, measured: int) -> str | None:
    """The warning when more than ``ROOF_MAX_IN_NODATA_PCT`` of the roof corners with a usable peak were counted
    in the DOM's nodata (``roof_evidence_in_nodata``): the rule may be hiding roofs that moved; None otherwise."""
    usable = in_nodata + measured
    pct = 100.0 * in_nodata / usable if usable else 0.0
    if pct <= ROOF_MAX_IN_NODATA_PCT:
        return None
    return (f"{in_nodata} of {usable} roof corners ({pct:.1f} %) not measured as their evidence lies in the DOM's "
            f"nodata, over the {ROOF_MAX_IN_NODATA_PCT:g} % expected (1.0-1.6 % on the DMC blocks): roofs moved "
            "beside holes (a lean, a DSM offset) are counted so too; look at those corners (dom_report.json "
            "roofs.in_nodata_corners, with the shift of each one's own best match)")


def read_roof_corners(path) -> tuple[np.ndarray, np.ndarray]:
    """x, y (DOM CRS) of the roof corners of a CSV with a header naming columns ``x`` and ``y`` (e.g. the
    simulator's truth/roof_corners.csv); InputError naming the file and line of a bad row."""
    path = Path(path)
    text = read_text(path, "roof-corner file (x,y columns)")
    reader = csv.DictReader(text.splitlines())
    if reader.fieldnames is None or not {"x", "y"} <= set(reader.fieldnames):
        raise InputError(f"{path}: header must name the columns x and y of the roof corners (got {reader.fieldnames})")
    xy = []
    for lineno, row in enumerate(reader, start=2):
        try:
            xy.append((float(row["x"]), float(row["y"])))
        except (TypeError, ValueError):
            raise InputError(f"{path}:{lineno}: non-numeric x or y in {row}") from None
        if not all(math.isfinite(v) for v in xy[-1]):
            raise InputError(f"{path}:{lineno}: NaN or infinite x or y in {row}")
    if not xy:
        raise InputError(f"{path}: no roof corners")
    a = np.array(xy)
    return a[:, 0], a[:, 1]


def roof_corners_from_ndsm(ndsm_path, dom_bounds, dom_crs, min_height_m: float = ROOF_HEIGHT_M,
                           min_area_m2: float = ROOF_MIN_AREA_M2, max_cells: float = 16e6):
    """x, y (DOM CRS) of the outline corners of the buildings of an nDSM over the DOM: cells above
    ``min_height_m`` (opened by one cell: no walls of single cells), objects of at least ``min_area_m2``, their
    outlines simplified (Douglas-Peucker, 1.5 cells). Trees are found too where the nDSM has no classes; a
    patch on a crown measures the crown, which stands where the roofs do in a true ortho. The nDSM is read
    over the DOM only, at most ``max_cells`` cells (coarser for a large block)."""
    import cv2
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.transform import Affine

    from aerotri.geom.crs.definition import same_horizontal

    with open_north_up(ndsm_path, "nDSM") as nd:
        if not same_horizontal(nd.crs, dom_crs):
            raise InputError(f"{ndsm_path}: the nDSM is in another CRS than the DOM; roofs are found only in an nDSM "
                             "of the DOM's CRS (give the roof corners with --roof-corners)")
        left, bottom, right, top = dom_bounds
        w = rasterio.windows.from_bounds(left, bottom, right, top, nd.transform).round_offsets().round_lengths()
        w = w.intersection(rasterio.windows.Window(0, 0, nd.width, nd.height))
        step = max(1, int(math.ceil(math.sqrt(w.width * w.height / max_cells))))
        shape = (max(1, int(w.height) // step), max(1, int(w.width) // step))
        with _reading(ndsm_path, "nDSM"):
            z = nd.read(1, window=w, out_shape=shape, masked=True, resampling=Resampling.average)
        unit = height_unit_m(parse_crs(nd.crs.to_wkt(), f"{ndsm_path} CRS"))
        t = nd.window_transform(w) @ Affine.scale(w.width / shape[1], w.height / shape[0])
        cell_m = abs(t.a) * metres_per_unit(nd, "nDSM")  # (in feet: objects of 50 ft2, 4.6 m2, counted as buildings)
    high = (np.ma.filled(z.astype(np.float32), 0.0) * unit > min_height_m).astype(np.uint8)
    high = cv2.morphologyEx(high, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    contours, _ = cv2.findContours(high, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    xs, ys = [], []
    for c in contours:
        if cv2.contourArea(c) * cell_m * cell_m < min_area_m2:
            continue
        for col, row in cv2.approxPolyDP(c, 1.5, True)[:, 0, :]:
            x, y = t @ (col + 0.5, row + 0.5)
            xs.append(x)
            ys.append(y)
    return np.array(xs, float), np.array(ys, float)


def masked_ncc_surface(dom, dom_weight, reference, reference_valid, search_px: int,
                       min_overlap: float = 0.5) -> np.ndarray | None:
    """Normalised cross-correlation of a DOM patch with the reference over the valid cells only, at every integer
    shift (masked NCC after Padfield 2012, by OpenCV's DFT): ``dom`` (n0 x n1) with ``dom_weight`` (0 on cells without a
    value, e.g. a Hanning window times the mask), ``reference`` (n0 + 2 S x n1 + 2 S, the same centre) with
    ``reference_valid``. Returns the NCC (2 S + 1 x 2 S + 1; [S, S] is no shift, [S + k, S + j] the patch found k
    rows down and j columns right in the reference), -1 where a shift keeps less than ``min_overlap`` of the weight
    or either side has no variance; None when either side has no valid cell. A hole has no value to correlate:
    unlike a patch mean put in its place, it cannot pull the peak."""
    n0, n1 = dom.shape
    S = int(search_px)
    N0, N1 = n0 + 2 * S, n1 + 2 * S
    if reference.shape != (N0, N1) or reference_valid.shape != (N0, N1) or dom_weight.shape != dom.shape:
        raise ValueError(f"reference {reference.shape} must be the DOM patch {dom.shape} plus {S} px on each side")
    w = np.where(np.isfinite(dom), np.asarray(dom_weight, np.float64), 0.0)
    v = (np.asarray(reference_valid, bool) & np.isfinite(reference)).astype(np.float64)
    if w.sum() <= 0 or v.sum() <= 0:
        return None
    t = np.where(w > 0, dom, 0.0).astype(np.float64)
    t = np.where(w > 0, t - (w * t).sum() / w.sum(), 0.0)  # centred: the sums below cancel less
    s = np.where(v > 0, reference, 0.0).astype(np.float64)
    s = np.where(v > 0, s - (v * s).sum() / v.sum(), 0.0)
    import cv2

    # sums over x of ref[x + k] * tmpl[x], k = 0 .. 2S, by OpenCV's real DFT (packed spectra; 1.5x numpy's FFT on the
    # DMC's 480 x 480, the sums the same to 1e-15 of their size) on a size it transforms fast (zero-padded: no wrap,
    # as tmpl is n x n in N x N or more); each reference and template transformed once
    M0, M1 = cv2.getOptimalDFTSize(N0), cv2.getOptimalDFTSize(N1)

    def spectrum(a):
        padded = np.zeros((M0, M1))
        padded[:a.shape[0], :a.shape[1]] = a
        return cv2.dft(padded, nonzeroRows=a.shape[0])  # the zero rows skipped (the same spectrum)

    fv, fs, fss = spectrum(v), spectrum(s), spectrum(s * s)
    fw, fwt, fwtt = spectrum(w), spectrum(w * t), spectrum(w * t * t)

    def corr(f_ref, f_tmpl):
        return cv2.idft(cv2.mulSpectrums(f_ref, f_tmpl, 0, conjB=True), flags=cv2.DFT_SCALE | cv2.DFT_REAL_OUTPUT,
                        nonzeroRows=2 * S + 1)[:2 * S + 1, :2 * S + 1]  # only the rows of the shifts computed

    sw, st, stt = corr(fv, fw), corr(fv, fwt), corr(fv, fwtt)
    ss, sss, sts = corr(fs, fw), corr(fss, fw), corr(fs, fwt)
    with np.errstate(invalid="ignore", divide="ignore"):
        var_t, var_s = stt - st * st / sw, sss - ss * ss / sw
        ncc = (sts - st * ss / sw) / np.sqrt(var_t * var_s)
    scale = max(float(np.abs(stt).max()), float(np.abs(sss).max()), 1e-300)
    ok = (sw >= min_overlap * w.sum()) & (var_t > 1e-9 * scale) & (var_s > 1e-9 * scale) & np.isfinite(ncc)
    return np.where(ok, ncc, -1.0) if ok.any() else None


def ncc_peak_shift(ncc: np.ndarray | None) -> tuple[float, float, float]:
    """The shift at the peak of a ``masked_ncc_surface``, refined by a parabola in x and y: (dx_px, dy_px, peak
    NCC), DOM minus reference (x right, y down); NaN shifts when the peak lies on the edge of the search or there
    is no surface."""
    if ncc is None:
        return math.nan, math.nan, -1.0
    S = (ncc.shape[0] - 1) // 2
    py, px = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
    peak = float(ncc[py, px])
    if px in (0, 2 * S) or py in (0, 2 * S):
        return math.nan, math.nan, peak
    sx = parabola_peak(ncc[py, px - 1], ncc[py, px], ncc[py, px + 1])
    sy = parabola_peak(ncc[py - 1, px], ncc[py, px], ncc[py + 1, px])
    # the DOM patch is found in the reference at offset (px + sx - S, py + sy - S): the DOM shows it moved by minus that
    return -(px + sx - S), -(py + sy - S), peak


def masked_ncc_shift(dom, dom_weight, reference, reference_valid, search_px: int,
                     min_overlap: float = 0.5) -> tuple[float, float, float]:
    """Shift of a DOM patch against the reference by masked NCC (``masked_ncc_surface``) at its peak, refined by a
    parabola in x and y (``ncc_peak_shift``): (dx_px, dy_px, peak NCC), DOM minus reference (x right, y down); NaN
    shifts when the peak lies on the edge of the search (+-``search_px``) or no shift keeps ``min_overlap`` of the
    weight."""
    return ncc_peak_shift(masked_ncc_surface(dom, dom_weight, reference, reference_valid, search_px, min_overlap))


def rival_peak(ncc: np.ndarray, at_yx, min_distance_px: float) -> float:
    """The highest NCC of a surface farther than ``min_distance_px`` from the cell ``at_yx``: how well the patch fits
    anywhere else (a second peak, or a ridge running on from this one: with the corner gone, a roof's straight edge
    lets the patch slide along it); -1 when there is none."""
    yy, xx = np.indices(ncc.shape)
    far = np.hypot(yy - at_yx[0], xx - at_yx[1]) > min_distance_px
    return float(ncc[far].max()) if far.any() else -1.0


def roof_evidence_in_nodata(ncc: np.ndarray, dom_valid, chip, chip_valid, reference, reference_valid, weight,
                            rival_px: float) -> bool:
    """Whether a roof corner's match (``ncc``, the DOM patch's ``masked_ncc_surface``) is not measurable because its
    evidence lies in the DOM's nodata: the match is ambiguous (``rival_peak`` farther than ``rival_px`` within
    ``ROOF_MIN_MARGIN`` of the best) and the hole makes it so: the reference's own ``chip`` (the patch's cells at
    no shift, ``chip_valid``) correlated with the ``reference`` over the DOM's valid cells only separates its own
    place from the best other one (1 - rival NCC) by less than ``ROOF_HOLE_SEPARATION`` of what it does whole. A
    match made ambiguous by the scene itself (repeated roofs, the whole chip ambiguous too) is not this."""
    py, px = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
    if ncc[py, px] - rival_peak(ncc, (py, px), rival_px) >= ROOF_MIN_MARGIN or np.all(dom_valid):
        return False
    S = (ncc.shape[0] - 1) // 2
    masked = masked_ncc_surface(np.where(dom_valid & chip_valid, chip, 0.0), weight * dom_valid * chip_valid,
                                reference, reference_valid, S)
    whole = masked_ncc_surface(np.where(chip_valid, chip, 0.0), weight * chip_valid, reference, reference_valid, S)
    if masked is None or whole is None:
        return True  # the DOM's valid cells hold nothing of the reference to tell the place by
    separation_masked = 1.0 - rival_peak(masked, (S, S), rival_px)
    separation_whole = 1.0 - rival_peak(whole, (S, S), rival_px)
    return separation_masked < ROOF_HOLE_SEPARATION * separation_whole


def measure_roof_patches(dom_path, reference_path, x_m, y_m, *, patch_m: float | None = None,
                         reference_operation=None, block_px: int = 2048) -> RoofDisplacements:
    """The displacement of the DOM against a reference true orthophoto at every roof corner ``x_m, y_m``: a
    square patch of ``patch_m`` (default ``max(ROOF_PATCH_M, ROOF_PATCH_PX DOM pixels)``) centred on the corner,
    the reference averaged onto the DOM's grid, grey values (the mean of the first three bands) correlated over the
    cells valid in both (``masked_ncc_shift``, the DOM patch weighted by a Hanning window, shifts up to half a patch).
    Patches less than ``ROOF_MIN_VALID`` valid or past the DOM's edge, and peaks below ``ROOF_MIN_NCC`` or on the
    edge of the search, are counted, not measured; so is a corner whose evidence lies in the DOM's nodata (its match
    ambiguous because of the hole, ``roof_evidence_in_nodata``). The DOM is read by blocks of ``block_px`` (with a
    patch's halo) that hold corners, the reference resampled once per block (with the search's halo; 2048 px: a
    third less CPU than 1024's halos on the DMC 2 x 4); the corners are listed by tiles of ``ROOF_LIST_TILE_PX`` (row
    by row), then in the given order, whatever the blocks."""
    from rasterio.enums import Resampling
    from rasterio.windows import Window

    x_m, y_m = np.atleast_1d(np.asarray(x_m, float)), np.atleast_1d(np.asarray(y_m, float))
    with stage_block_cache(CHECK_CACHE_BYTES), open_north_up(dom_path, "DOM") as dom, \
            open_north_up(reference_path, "reference orthophoto") as ref:
        res = abs(dom.transform.a) * metres_per_unit(dom)  # metres: the patch size and the shifts in metres
        patch_m = float(patch_m) if patch_m else max(ROOF_PATCH_M, ROOF_PATCH_PX * res)
        n = max(16, int(round(patch_m / res)))
        S = n // 2  # as far as phase correlation of the patch could tell a shift
        win = np.outer(np.hanning(n), np.hanning(n))
        bands = list(range(1, min(dom.count, 3) + 1))
        inv = ~dom.transform
        cols, rows = inv @ (x_m, y_m)
        r0s, c0s = np.floor(rows).astype(np.int64) - n // 2, np.floor(cols).astype(np.int64) - n // 2
        inside = (r0s >= 0) & (c0s >= 0) & (r0s + n <= dom.height) & (c0s + n <= dom.width)
        outside, weak, in_nodata, in_holes = int(np.count_nonzero(~inside)), 0, 0, 0
        rival_px = ROOF_RIVAL_M / res
        kept, hidden = [], []
        block_of = (r0s // block_px) * (dom.width // block_px + 1) + c0s // block_px
        # the order the corners are listed in (the report lists the hidden ones): as the blocks of 1024 px read them
        listed_by = ((r0s // ROOF_LIST_TILE_PX) * (dom.width // ROOF_LIST_TILE_PX + 1) + c0s // ROOF_LIST_TILE_PX) \
            * len(x_m) + np.arange(len(x_m))
        for b in track(np.unique(block_of[inside]), "DOM check, roofs", "blocks"):
            sel = np.flatnonzero(inside & (block_of == b))
            br0, bc0 = int(r0s[sel].min()), int(c0s[sel].min())
            w = Window(bc0, br0, int(c0s[sel].max()) + n - bc0, int(r0s[sel].max()) + n - br0)
            shape = (int(w.height), int(w.width))
            with _reading(dom_path, "DOM"):
                ok = dom.read_masks(1, window=w) > 0
                grey = dom.read(bands, window=w).astype(np.float32).mean(axis=0)
            wide = Window(bc0 - S, br0 - S, shape[1] + 2 * S, shape[0] + 2 * S)
            with _reading(reference_path, "reference orthophoto"):
                refimg, refok = _on_grid(ref, dom.window_transform(wide), (shape[0] + 2 * S, shape[1] + 2 * S),
                                         dom.crs, Resampling.average, operation=reference_operation)
            ref_grey = refimg.mean(axis=0)
            for i in sel:
                r, c = int(r0s[i]) - br0, int(c0s[i]) - bc0
                pv, rv = ok[r:r + n, c:c + n], refok[r + S:r + S + n, c + S:c + S + n]
                if rv.mean() < ROOF_MIN_VALID:
                    outside += 1
                    continue
                if pv.mean() < ROOF_MIN_VALID:
                    in_holes += 1
                    continue
                ref_big, refok_big = ref_grey[r:r + n + 2 * S, c:c + n + 2 * S], refok[r:r + n + 2 * S, c:c + n + 2 * S]
                ncc = masked_ncc_surface(np.where(pv, grey[r:r + n, c:c + n], 0.0), win * pv, ref_big, refok_big, S)
                dx, dy, peak = ncc_peak_shift(ncc)
                if not (peak >= ROOF_MIN_NCC and math.isfinite(dx)):
                    weak += 1
                    continue
                if roof_evidence_in_nodata(ncc, pv, ref_big[S:S + n, S:S + n], refok_big[S:S + n, S:S + n], ref_big,
                                           refok_big, win, rival_px):
                    in_nodata += 1
                    hidden.append((listed_by[i], x_m[i], y_m[i], dx * res, -dy * res))  # for a QA engineer to look at
                    continue
                kept.append((listed_by[i], x_m[i], y_m[i], dx * res, -dy * res))  # DOM minus reference along x, y
        sx, sy = map_axis_signs(dom.crs)
    k, h = (np.array([row[1:] for row in sorted(rows, key=lambda row: row[0])], float).reshape(-1, 4)
            for rows in (kept, hidden))
    for a in (k, h):
        a[:, 2] *= sx  # east and north (a south-oriented grid's x runs west, its y south)
        a[:, 3] *= sy
    return RoofDisplacements(k[:, 0], k[:, 1], k[:, 2], k[:, 3], len(x_m), outside, weak, patch_m, in_nodata, h,
                             in_holes)


def _roofs_document(roofs: RoofDisplacements, res_m: float, source: str) -> dict:
    """The report's ``roofs`` row: ``displacement_statistics`` of the measured patches (RMS and median in metres
    and GSD, count), with where the corners came from and how many were not measured."""
    stats = to_record(displacement_statistics(roofs.de_m, roofs.dn_m, res_m), drop_none=True)
    if stats["count"]:
        stats["median_xy_gsd"] = stats["median_xy_m"] / res_m
    stats.update(corners=roofs.corners, corners_from=source, patch_m=roofs.patch_m,
                 not_measured={"outside_or_invalid": roofs.outside_or_invalid, "weak": roofs.weak,
                               "in_nodata": roofs.in_nodata, "in_dom_holes": roofs.in_dom_holes})
    if roofs.in_nodata:
        h = roofs.in_nodata_corners[_spread(len(roofs.in_nodata_corners), MAX_LISTED)]
        stats["in_nodata_pct"] = round(roofs.in_nodata_pct, 2)
        # where they are and how far each one's own (ambiguous) best match puts the DOM: a QA engineer looks there
        stats["in_nodata_corners"] = [{"x_m": round(float(a), 3), "y_m": round(float(b), 3), "de_m": round(float(c), 3),
                                       "dn_m": round(float(d), 3)} for a, b, c, d in h]
        warning = roofs_in_nodata_warning(roofs.in_nodata, len(roofs.de_m))
        if warning is not None:
            stats["in_nodata_warning"] = warning
            logging.getLogger(__name__).warning(f"DOM check, roofs: {warning}")
    return stats


MAX_LISTED = 20000  # patches listed in the report and drawn in its plot


def _spread(n: int, at_most: int) -> np.ndarray:
    """Boolean selection of at most ``at_most`` of ``n`` items, evenly spread (all when n <= at_most)."""
    keep = np.zeros(n, bool)
    keep[np.unique(np.linspace(0, n - 1, min(n, at_most)).round().astype(np.int64))] = True
    return keep


def _same_file(a: Path, b: Path) -> bool:
    return a.exists() and b.exists() and os.path.samefile(a, b)


def simulator_roof_corners(reference_path) -> Path | None:
    """The simulator's roof corners when ``reference_path`` is its true orthophoto (truth/ortho.tif with
    truth/roof_corners.csv beside it, holding at least one corner: a block without buildings has a header only),
    else None."""
    if reference_path is None:
        return None
    ref = Path(reference_path)
    corners = ref.parent / "roof_corners.csv"
    if ref.name != "ortho.tif" or ref.parent.name != "truth" or not corners.is_file():
        return None
    with open(corners, errors="replace") as f:
        rows = sum(1 for line in f if line.strip())
    return corners if rows > 1 else None


def run_check(project_root, settings: CheckSettings | Resolved | None = None, *, reference_path=None, points_path=None,
              dom_path=None, out_stem=None, seams: bool = True, params=None, allow_ballpark: bool = False,
              roof_corners_path=None) -> DomCheck:
    """The ``ortho check`` report (written to ``<out_stem>.json``, returned typed as ``read_dom_check`` reads it):
    displacement statistics (+ per-seam misalignment when seamlines exist).

    With a reference orthophoto, open ground (``displacement``: NCC patches, nDSM <= max_ndsm_m with an nDSM) and,
    when roofs can be located, roofs (``roofs``: a patch on every roof corner, ``measure_roof_patches``): the corners
    of ``roof_corners_path`` (a CSV with x, y columns), else of the setting ``roof_corners``, else the simulator's
    truth/roof_corners.csv when the reference is its truth/ortho.tif (``simulator_roof_corners``), else the outline
    corners of the buildings of the nDSM (``roof_corners_from_ndsm``). The roofs row means "roofs in place" only against a
    true orthophoto as the reference (roofs where they stand, as the simulator's truth/ortho.tif).

    ``settings``: None reads [dom_check] of project.toml (a folder without project.toml: the defaults); a
    ``Resolved`` (``ortho check``, the chain) carries the source of every setting into the report (``settings``).
    The nDSM defaults to lidar_out/ndsm.tif when present. A reference (or nDSM) in another CRS than the DOM is
    mapped through the coordinate-operation policy: ``params`` (a parameter file of ``aerotri crs fit``, either
    direction) for a datum change."""
    root = Path(project_root)
    if settings is None and not (root / "project.toml").is_file():  # a DOM folder of its own
        settings = CheckSettings()
    resolved = settings_of(settings, CheckSettings, Project.open(root) if settings is None else None)
    s = resolved.settings
    ndsm_path, max_ndsm_m, patch_px, search_px = s.ndsm, s.max_ndsm_m, s.patch_px, s.search_px
    if roof_corners_path is None and s.roof_corners is not None:
        # the argument, else the setting (--roof-corners, [dom_check] roof_corners); the project's own setting does
        # not stand in the way of a check against surveyed points (no roofs are measured there)
        if reference_path is not None or resolved.sources.get("roof_corners") == COMMAND_LINE:
            roof_corners_path = s.roof_corners
    corners_in_reference_crs = False  # the simulator's corners are in its truth's CRS, given ones in the DOM's
    if roof_corners_path is None and (simulated := simulator_roof_corners(reference_path)) is not None:
        # against the simulator's true orthophoto: the roof corners that belong to it
        roof_corners_path = simulated
        corners_in_reference_crs = True
        resolved = resolved.replace("roof_corners", roof_corners_path, resolved.sources.get("roof_corners", "default"),
                                    "the simulator's roof corners beside its true orthophoto, the reference")
    if ndsm_path is None and reference_path is not None and project_paths(root).ndsm_path.is_file():
        ndsm_path = project_paths(root).ndsm_path
        resolved = resolved.replace("ndsm", ndsm_path, resolved.sources.get("ndsm", "default"), "the LiDAR stages' nDSM")
    if not (isinstance(patch_px, int) and patch_px >= MIN_PATCH_PX):
        raise OptionError(f"{patch_px!r}: expected a patch of at least {MIN_PATCH_PX} px", param="--patch-px")
    if not (isinstance(search_px, int) and search_px >= 1):
        raise OptionError(f"{search_px!r}: expected a search radius of at least 1 px", param="--search-px")
    if not math.isfinite(max_ndsm_m):
        raise OptionError(f"{max_ndsm_m!r}: expected a height in metres", param="--max-ndsm-m")
    check_block_memory(patch_px, search_px)
    dom_path = Path(dom_path) if dom_path else root / "ortho" / "mosaic.tif"
    paths = project_paths(root)
    project_stem = root / "ortho" / "dom_report"
    of_project = _same_file(dom_path, paths.mosaic_path) or dom_path.resolve() == paths.mosaic_path.resolve()
    given_stem = out_stem or None
    if not out_stem:
        # another DOM's check beside that DOM (``<dom>_dom_report.json``): the project's dom_report.json is the
        # project's mosaic's (review 12c: a check of another DOM replaced the project's passing one)
        out_stem = project_stem if of_project else dom_path.with_name(f"{dom_path.stem}_dom_report")
    out_stem = Path(out_stem)
    if not of_project and (root / "project.toml").is_file() and \
            out_stem.with_suffix(".json").resolve() == project_stem.with_suffix(".json").resolve():
        raise OptionError(f"{out_stem.with_suffix('.json')} is the project's DOM check (of {paths.mosaic_path}): the "
                          f"check of {dom_path} goes elsewhere (give another --out, or leave it out: "
                          f"{dom_path.with_name(dom_path.stem + '_dom_report.json')})", param="--out")
    for suffix in (".json", ".png"):
        refuse_input_as_output(out_stem.with_suffix(suffix), [dom_path, reference_path, points_path, ndsm_path,
                                                              roof_corners_path, root / "ortho" / "mosaic.json"], "--out")
    # before the work (minutes of matching): a DOM on a read-only disk or share, its report beside it by default
    folder = next((d for d in (out_stem.absolute().parent, *out_stem.absolute().parents) if d.is_dir()), None)
    if folder is not None and not os.access(folder, os.W_OK):
        raise OptionError(f"{out_stem.with_suffix('.json')}: cannot write into {folder} (read-only or not "
                          f"permitted){' (beside the DOM, by default)' if given_stem is None else ''}: give --out "
                          "with a report stem in a folder you can write, e.g. --out checks/dom_report", param="--out")
    if roof_corners_path is not None and reference_path is None:
        raise OptionError("the roofs are measured against a reference orthophoto: give --reference with --roof-corners",
                          param="--roof-corners")
    corners = read_roof_corners(roof_corners_path) if roof_corners_path is not None else None
    # the seams are measured on the frame orthos along ortho/seams.tif: the project's mosaic's, not another DOM's
    # (trial-ortho2: a noise DOM given by --dom read the project's 0.040 px)
    seams = seams and of_project and paths.seamlines_path.exists() and paths.frames_index_path.exists()
    # a DOM made from frames of an older adjustment is refused (the mosaic, and the seams measured on the frames)
    if paths.frames_index_path.exists() and (seams or _same_file(dom_path, paths.mosaic_path)):
        from ortho.block import read_index, require_current_frames

        require_current_frames(root, read_index(root), f"`ortho mosaic {root}` and `ortho check`")
    with open_north_up(dom_path, "DOM") as ds:
        unit_m = metres_per_unit(ds)
        res = abs(ds.transform.a) * unit_m  # the GSD in metres (a DOM in feet: 0.3048 m per foot)
        crs = ds.crs.to_string()
        dom_bounds, dom_crs = tuple(ds.bounds), ds.crs
        flips = north_up_flips(ds.transform, ds.crs)
    report = {"dom": str(dom_path), "crs": crs, "gsd_m": res}
    # the accuracy report takes the project's dom_report.json for its mosaic: a check of another DOM (--dom) says so
    # (its figures were shown as the project DOM's, "true ortho on the DSM" beside a conventional DOM's roofs)
    report["dom_is_project_mosaic"] = of_project
    if report["dom_is_project_mosaic"]:  # the report tells a check of an earlier mosaic by it
        report["mosaic_fingerprint"] = mosaic_fingerprint(dom_path)
    _check_over_dom(reference_path, ndsm_path, dom_bounds, dom_crs)
    if reference_path is not None:
        ref_op = _operation_to(dom_path, reference_path, params, allow_ballpark, "reference orthophoto")
        if corners is not None and corners_in_reference_crs and ref_op is not None:
            # a DOM delivered in another CRS than the simulator's truth: its corners read as DOM coordinates lay
            # kilometres off (the demo in Gauss-Krueger: 0 of 1,156 measured, "none measurable")
            cx, cy, _ = ref_op.inverse().transform(*corners)
            corners = (cx, cy)
        ndsm_op = _operation_to(dom_path, ndsm_path, params, allow_ballpark, "nDSM") if ndsm_path else None
        min_ncc = 0.7
        patches, (w, h) = check_against_reference(dom_path, reference_path, ndsm_path, max_ndsm_m, patch_px=patch_px,
                                                  step_px=patch_px, search_px=search_px, min_ncc=min_ncc,
                                                  reference_operation=ref_op, ndsm_operation=ndsm_op)
        stats = displacement_statistics(patches.de_m, patches.dn_m, res)
        if ref_op is not None:
            report["reference_operation"] = ref_op.record()
        report.update(method="ncc_patches", reference=str(reference_path), ndsm=str(ndsm_path) if ndsm_path else None,
                      max_ndsm_m=max_ndsm_m if ndsm_path else None, patch_px=patch_px, search_px=search_px,
                      displacement=to_record(stats, drop_none=True))
        # the statistics take every patch; the report lists and the plot draws at most MAX_LISTED of them,
        # evenly spread (a gigapixel DOM has millions: the JSON and the plot stay the size of a demo's)
        listed = patches.select(_spread(len(patches), MAX_LISTED))
        left_out = len(patches.one_direction_row_px)
        report["left_out_one_direction"] = {
            "why": "texture in one direction (the aperture problem: the NCC peak slides along a road)",
            "min_texture_ratio": MIN_TEXTURE_RATIO, "patches": left_out,
            "pct": round(100.0 * left_out / max(left_out + len(patches), 1), 2)}
        unsettled = len(patches.unsettled_row_px)
        report["left_out_unsettled"] = {
            "why": "the sub-pixel refinement did not settle within 3 px of the whole-pixel peak (no single NCC peak: "
                   "a periodic texture, crop rows)", "max_refine_px": MAX_REFINE_PX, "patches": unsettled,
            "pct": round(100.0 * unsettled / max(unsettled + len(patches), 1), 2)}
        # the textured patches that found no match, by frame region of the project's mosaic (else by tile): a DOM, or
        # a frame's region of it, off by more than the search drops them instead of reading the shift
        unmatched = unmatched_patches(patches, min_ncc=min_ncc, search_px=search_px,
                                      region_of=frame_regions(root, dom_path) if of_project else None)
        report["unmatched"] = to_record(unmatched)
        if unmatched.fails():
            logging.getLogger(__name__).warning(f"DOM check: {unmatched.note()}")
        elif unmatched.unusual():
            logging.getLogger(__name__).warning(f"DOM check: {unmatched.unusual_note()}")
        if not len(patches):  # (exit 0 with "no usable patches" and no word: trial-ortho2's 99 % nodata DOM)
            logging.getLogger(__name__).warning(
                f"DOM check: no usable patch in {dom_path}: the DOM is not measured (no texture, no ground under "
                "--max-ndsm-m, nodata, or the reference misses it)")
        report.update(patches_total=len(patches), patches_listed=len(listed),
                      patches=[{"row_px": float(r), "col_px": float(c), "de_m": float(a), "dn_m": float(b),
                                "ncc": float(n)}
                               for r, c, a, b, n in zip(listed.row_px, listed.col_px, listed.de_m, listed.dn_m,
                                                        listed.ncc)])

        roofs = _roofs_row(dom_path, reference_path, ref_op=ref_op, corners=corners, corners_path=roof_corners_path,
                           ndsm_path=ndsm_path, ndsm_op=ndsm_op, res_m=res, dom_bounds=dom_bounds, dom_crs=dom_crs)
        if roofs is not None:
            report["roofs"] = roofs

        def plot():
            plot_displacements(out_stem.with_suffix(".png"), patches, stats, f"DOM - reference ({Path(dom_path).name})",
                               extent_px=max(w, h), flips=flips)
    else:
        stats, table = check_points(points_path, res, dom_bounds, unit_m, dom_crs)
        report.update(method="surveyed_points", points_file=str(points_path),
                      displacement=to_record(stats, drop_none=True), points=table["points"])

        drawn = _points_drawn(root, report, table, unit_m, dom_crs)

        def plot():
            plot_displacements(out_stem.with_suffix(".png"), None, stats, "DOM - survey", points=drawn)
    if seams:
        from ortho.mosaic import seam_misalignment

        with stage_block_cache(CHECK_CACHE_BYTES):
            report["seams"] = to_record(seam_misalignment(root, ndsm_path=ndsm_path, max_ndsm_m=max_ndsm_m))
    plot()  # the outputs only after every measurement succeeded
    report["json"] = str(out_stem.with_suffix(".json"))
    report["plot"] = str(out_stem.with_suffix(".png"))
    report["settings"] = resolved.record()
    write_json(out_stem.with_suffix(".json"), report)
    return _dom_check_of(report)


def _roofs_row(dom_path, reference_path, *, ref_op, corners, corners_path, ndsm_path, ndsm_op, res_m, dom_bounds,
               dom_crs) -> dict | None:
    """(``run_check``) the report's ``roofs`` row: at the given roof corners, else at those of the nDSM's buildings;
    None when neither is at hand."""
    if corners is not None:
        xs, ys = corners
        source = str(corners_path)
    elif ndsm_path is not None:
        if ndsm_op is not None:
            return {"count": 0, "why": f"the nDSM {ndsm_path} is in another CRS than the DOM: roofs are found only in an "
                                       "nDSM of the DOM's CRS (give the roof corners with --roof-corners)"}
        xs, ys = roof_corners_from_ndsm(ndsm_path, dom_bounds, dom_crs)
        source = (f"nDSM {ndsm_path}: outline corners of objects above {ROOF_HEIGHT_M:g} m and of at least "
                  f"{ROOF_MIN_AREA_M2:g} m2")
    else:
        return None
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    left, bottom, right, top = dom_bounds
    if corners is not None and len(xs) and not np.any((xs >= left) & (xs <= right) & (ys >= bottom) & (ys <= top)):
        crs = dom_crs.to_string() if hasattr(dom_crs, "to_string") else str(dom_crs)
        return {"count": 0, "corners": int(len(xs)), "corners_from": source,
                "why": f"none of the {len(xs)} roof corners of {corners_path} lies on the DOM (x {xs.min():.1f} .. "
                       f"{xs.max():.1f}, y {ys.min():.1f} .. {ys.max():.1f}; the DOM {left:.1f} .. {right:.1f}, "
                       f"{bottom:.1f} .. {top:.1f}): give them in the DOM's CRS ({crs})"}
    measured = measure_roof_patches(dom_path, reference_path, xs, ys, reference_operation=ref_op)
    return _roofs_document(measured, res_m, source)
