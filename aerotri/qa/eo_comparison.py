"""The adjusted orientations against a reference (another AT of the same frames: a national AT, a vendor's
solution): ``aerotri compare PROJECT --format F FILE...``.

The reference is read by the import format's own reader (``aerotri.exchange.IMPORT_FORMATS``: the same CRS
handling and checks as ``aerotri import``, nothing written into the project) and compared frame by frame with
``at/eo.txt`` over the frames both hold: projection centre differences dX dY dZ (m, project CRS, adjusted minus
reference), omega phi kappa differences (deg, wrapped into (-180, 180]) and the angle of the rotation between
the two attitudes (deg); with the adjustment's sigmas, each difference in its own sigmas (the reference taken as
exact). Written to ``reports/eo_comparison.json`` (atomically); the console shows the RMS and the largest.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path

import numpy as np

from aerotri.core.atomic import write_text_atomic
from aerotri.core.errors import InputError
from aerotri.core.log import counted
from aerotri.core.project import Project
from aerotri.geom.eo import ExteriorOrientations, read_eo
from aerotri.geom.rotation import rotation_matrix_opk

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1


@dataclasses.dataclass(frozen=True)
class FrameDifference:
    image_id: str
    d_centre_m: tuple[float, float, float]  # adjusted - reference, project CRS
    d_opk_deg: tuple[float, float, float]
    rotation_deg: float  # angle of R_adjusted^T R_reference
    normalised: tuple[float, ...] | None  # the six differences over the adjustment's sigmas


@dataclasses.dataclass(frozen=True)
class EoComparison:
    """RMS over the common frames (``frames``) of each difference; ``missing``: frames of at/eo.txt the
    reference lacks, ``extra``: frames only the reference has."""

    reference: tuple[str, ...]
    frames: int
    rms_centre_m: tuple[float, float, float]
    rms_opk_deg: tuple[float, float, float]
    rms_rotation_deg: float
    max_rotation_deg: float
    max_centre_m: float
    rms_normalised: tuple[float, ...] | None  # X Y Z omega phi kappa, in the adjustment's sigmas
    per_frame: tuple[FrameDifference, ...]
    missing: tuple[str, ...]
    extra: tuple[str, ...]
    note: str = ""  # why a figure is no independent check (the reference's centres are the project's GNSS)
    # what reading the reference said, as aerotri import says it (a 2D CRS's heights taken as the project's, a
    # datum operation's accuracy, a PAT-B principal distance other than the camera's); printed as warnings
    reference_notes: tuple[str, ...] = ()


# a normalised RMS beyond this is named (about 1 expected; 2 is a variance four times the stated)
NORMALISED_FLAG = 2.0
# gnss.txt within this of the reference's centres at every common frame: the GNSS came from the reference
SAME_AS_GNSS_M = 0.01


def _rms(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.square(a), axis=0))


def compare_orientations(adjusted: ExteriorOrientations, reference: ExteriorOrientations,
                         source: tuple[str, ...] = ()) -> EoComparison:
    """Frame-by-frame differences of ``adjusted`` against ``reference`` (same CRS); InputError when they share
    no frame."""
    ref_index = {iid: k for k, iid in enumerate(reference.image_id)}
    common = [i for i, iid in enumerate(adjusted.image_id) if iid in ref_index]
    if not common:
        raise InputError(f"{', '.join(source) or 'the reference'}: no frame in common with at/eo.txt (reference ids "
                         f"{', '.join(reference.image_id[:3])} ...; adjusted {', '.join(adjusted.image_id[:3])} ...)")
    k = np.array([ref_index[adjusted.image_id[i]] for i in common])
    a = np.array(common)
    d_c = adjusted.centre_m[a] - reference.centre_m[k]
    d_o = (adjusted.opk_deg[a] - reference.opk_deg[k] + 180.0) % 360.0 - 180.0
    rot = np.array([math.degrees(math.acos(np.clip((np.trace(rotation_matrix_opk(*adjusted.opk_deg[i]).T
                                                             @ rotation_matrix_opk(*reference.opk_deg[j])) - 1) / 2,
                                                   -1.0, 1.0)))
                    for i, j in zip(a, k)])
    norm = None
    if adjusted.sigma is not None and np.all(adjusted.sigma[a] > 0):
        norm = np.hstack([d_c, d_o]) / adjusted.sigma[a]
    per = tuple(FrameDifference(adjusted.image_id[i], tuple(np.round(d_c[n], 4).tolist()),
                                tuple(np.round(d_o[n], 7).tolist()), round(float(rot[n]), 7),
                                None if norm is None else tuple(np.round(norm[n], 3).tolist()))
                for n, i in enumerate(a))
    return EoComparison(
        reference=tuple(source), frames=len(a), rms_centre_m=tuple(np.round(_rms(d_c), 4).tolist()),
        rms_opk_deg=tuple(np.round(_rms(d_o), 7).tolist()), rms_rotation_deg=round(float(_rms(rot)), 7),
        max_rotation_deg=round(float(rot.max()), 7), max_centre_m=round(float(np.linalg.norm(d_c, axis=1).max()), 4),
        rms_normalised=None if norm is None else tuple(np.round(_rms(norm), 3).tolist()), per_frame=per,
        missing=tuple(iid for iid in adjusted.image_id if iid not in ref_index),
        extra=tuple(sorted(set(reference.image_id) - set(adjusted.image_id))))


def compare_with_reference(root, format_name: str, files, crs: str | None = None) -> EoComparison:
    """Read the reference orientations of ``files`` (an import format) and compare ``at/eo.txt`` with them;
    writes ``reports/eo_comparison.json``."""
    from aerotri.exchange.import_registry import importer_and_files
    from aerotri.exchange.imported import ImportSettings

    from aerotri.exchange.imported import collecting_operation_notes, heights_note_needed

    project = Project.open(root)
    importer, files = importer_and_files(format_name, files)
    with collecting_operation_notes() as operation_notes:  # said by aerotri import, dropped here before trial-exchange
        # the orientations are compared, not the control: its accuracy is no input here (trial-ngi: a .con asked for
        # --sigma-xyz-m, an option compare has not); 1 m stands in for it, unused
        block = importer.read(files, project, ImportSettings(crs=crs, sigma_xyz_m=(1.0, 1.0, 1.0)))
    notes = tuple(dict.fromkeys(list(block.notes) + heights_note_needed(project, block, operation_notes)))
    for n in notes:
        log.warning(n)
    if block.eo is None:
        raise InputError(f"{', '.join(str(f) for f in files)}: no orientations in these {format_name} files "
                         f"(expected {importer.files})")
    if not project.eo_path.is_file():
        raise InputError(f"{project.eo_path}: not found (run aerotri adjust first)")
    result = compare_orientations(read_eo(project.eo_path), block.eo, tuple(str(f) for f in files))
    result = dataclasses.replace(result, note=_gnss_from_reference(project, block.eo), reference_notes=notes)
    record = {"schema_version": SCHEMA_VERSION, "kind": "eo comparison", **dataclasses.asdict(result)}
    write_text_atomic(project.root / "reports" / "eo_comparison.json",
                      json.dumps(record, indent=1, allow_nan=False) + "\n")
    return result


def _gnss_from_reference(project: Project, reference: ExteriorOrientations) -> str:
    """A note when gnss.txt holds the reference's own projection centres (a national AT imported with
    ``--as-gnss``, as docs/your-own-block.md does): the centre differences then show how closely the adjustment
    held its GNSS, not how right the centres are; the attitudes remain a check."""
    from aerotri.geom.eo import read_gnss

    if not project.gnss_path.is_file():
        return ""
    gnss = read_gnss(project.gnss_path)
    at = {iid: k for k, iid in enumerate(gnss.image_id)}
    k = [(at[iid], n) for n, iid in enumerate(reference.image_id) if iid in at]
    if not k:
        return ""
    g, r = np.array(k).T
    largest = float(np.linalg.norm(gnss.position_m[g] - reference.centre_m[r], axis=1).max())
    if largest > SAME_AS_GNSS_M:
        return ""
    return (f"the reference's projection centres are this project's GNSS observations (gnss.txt within "
            f"{largest:.3f} m of them at the {len(k)} common frames): the centre differences show how closely the "
            f"adjustment held its GNSS, they are no independent check; the attitudes are an independent check")


def summary_lines(c: EoComparison) -> list[str]:
    """The console summary: RMS and largest differences, and the frames left out."""
    x, y, z = c.rms_centre_m
    o, p, k = c.rms_opk_deg
    lines = [f"{c.frames} frames against {', '.join(Path(r).name for r in c.reference)}: centres RMS dX {x:.3f} "
             f"dY {y:.3f} dZ {z:.3f} m (largest {c.max_centre_m:.3f} m); omega/phi/kappa RMS {o:.4f} / {p:.4f} / "
             f"{k:.4f} deg, rotation RMS {c.rms_rotation_deg:.4f} deg (largest {c.max_rotation_deg:.4f})"]
    if c.rms_normalised is not None:
        lines.append("  in the adjustment's sigmas (RMS): X Y Z " + " ".join(f"{v:.2f}" for v in c.rms_normalised[:3])
                     + ", omega phi kappa " + " ".join(f"{v:.2f}" for v in c.rms_normalised[3:]))
        beyond = [name for name, v in zip(("X", "Y", "Z", "omega", "phi", "kappa"), c.rms_normalised)
                  if v > NORMALISED_FLAG]
        if beyond:  # s95: phi 2.51 printed without a word, the stated sigma 2.5 times below the difference
            lines.append(f"  beyond {NORMALISED_FLAG:g}: {', '.join(beyond)}: the adjustment's sigmas understate "
                         "these differences, or the reference is off by as much")
        if max(c.rms_normalised) > 3.0:
            # (Tuniu trial: 4.3 sigma in kappa against OpenSfM read as the adjustment's failure)
            lines.append("  (the reference's own errors and model are not in these sigmas: about 1 is expected "
                         "against truth or a reference far more precise; against another solution of the same frames "
                         "(a peer's SfM, other self-calibration or weights) several sigmas are its difference too)")
    if c.missing:
        lines.append(f"  not in the reference: {counted(len(c.missing), 'frame')} ({', '.join(c.missing[:5])}"
                     + (" ..." if len(c.missing) > 5 else "") + ")")
    if c.extra:
        lines.append(f"  only in the reference: {counted(len(c.extra), 'frame')}")
    if c.note:
        lines.append(f"  note: {c.note}")
    return lines
