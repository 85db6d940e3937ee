"""Accuracy of a classification against truth labels.

Filter-test measures (Sithole & Vosselman 2004, ISPRS WG III/3), ground = bare earth:
  type I  = bare-earth points rejected as object / bare-earth points
  type II = object points accepted as bare earth / object points
  total   = all misclassified / all points
  Cohen's kappa = (p_o - p_e) / (1 - p_e) of the 2x2 table.
Confusion matrix: rows = truth class, columns = predicted class; producer's accuracy = diagonal /
row sum (how much of the truth class was found), user's accuracy = diagonal / column sum (how
much of what was labelled is right), overall accuracy = trace / total, Cohen's kappa from the
row and column sums (p_e = sum of row x column sums / total^2).

A truth in a coarser scheme (``_coarse_scheme_map``: it holds class 1 and no vegetation class 3/4/5, as AHN3's
1 2 6 9 26) is scored on its own classes: our vegetation, noise and bridge-deck classes that it does not hold
(3, 4, 5, 7, 17, 18) count as its class 1 in the confusion matrix, our bridge deck as its 26 where it holds AHN's
civil structures (bridges, viaducts) (the filter test is the same either way: none
of them is ground); the matrix before that mapping is kept beside it. A ``map_pred`` given replaces it.

Prediction and truth must hold the same points in the same order (``read_same_points``): their
coordinates are compared in metres (each file scaled by its CRS's unit) within
``SAME_POINT_TOL_M`` or 1.1 coordinate steps (the coarser scale factor), whichever is larger.
A file without CRS is taken in the other file's units; with no CRS on either side the coordinates
are compared as stored, within 1.1 coordinate steps.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.textio import read_record, record_error
from aerotri.geom import las
from lidarctl import io

SAME_POINT_TOL_M = 0.011


def read_same_points(pred_path, truth_path):
    """(pred, truth) PointClouds of two LAS/LAZ files; InputError unless they hold the same points
    in the same order (see the module docstring for the coordinate tolerance)."""
    pred = io.read_cloud(pred_path, require_crs=False)
    truth = io.read_cloud(truth_path, require_crs=False)
    if len(pred) != len(truth):
        held = [f"{p}: {int((~c.used).sum())} flagged withheld" for p, c in ((pred_path, pred), (truth_path, truth))
                if c.used is not None]
        raise InputError(f"{pred_path}: {len(pred)} points, but {truth_path} has {len(truth)} (same order needed"
                         + (f"; points flagged withheld are left out, {', '.join(held)}" if held else "") + ")")
    pu, tu = pred.units, truth.units
    # x, y of a file with a known CRS are metres; a file without CRS takes the other's unit.
    pf = 1.0 if pu.known else (tu.xy_m if tu.known else 1.0)
    tf = 1.0 if tu.known else (pu.xy_m if pu.known else 1.0)
    step = max(float(np.max(las.read_header(pred_path).scales[:2])) * (pu.xy_m if pu.known else pf),
               float(np.max(las.read_header(truth_path).scales[:2])) * (tu.xy_m if tu.known else tf))
    tol = max(SAME_POINT_TOL_M, 1.1 * step) if (pu.known or tu.known) else 1.1 * step
    unit = "m" if (pu.known or tu.known) else "file units"
    for axis in ("x", "y"):
        a, b = getattr(pred, axis) * pf, getattr(truth, axis) * tf
        d = np.abs(a - b)
        if not (d <= tol).all():
            k = int(np.argmax(~(d <= tol)))
            raise InputError(
                f"{pred_path}: point record {k}: {axis} differs from {truth_path} by {d[k]:.4g} {unit} "
                f"(tolerance {tol:.4g} {unit}; same points, same order needed)")
    return pred, truth


SCHEMA_VERSION = 1  # classification_eval.json (``evaluate_strips``; written without a version so far)
CLASSIFICATION_EVAL = "classification evaluation (classification_eval.json)"  # the record's name in messages
EVAL_VERSION = 1  # the chain's lidar_eval stage stamp: bump when classification_eval.json changes at the same inputs


@dataclasses.dataclass(frozen=True)
class FilterTest:
    """The filter test of a classification (``filter_errors``; module doc): points, true ground and object
    points, type I and II counts, type I, type II and total error and Cohen's kappa (percent)."""

    n_points: int
    n_ground: int
    n_object: int
    type_i_count: int
    type_ii_count: int
    type_i_error_pct: float
    type_ii_error_pct: float
    total_error_pct: float
    kappa_pct: float


@dataclasses.dataclass(frozen=True)
class Confusion:
    """A confusion matrix (``confusion``; module doc): rows truth, columns prediction, in the order of ``classes``;
    producer's and user's accuracy per class (keyed by the class code as text, as JSON holds them; None for a class
    absent on that side), overall accuracy and Cohen's kappa, percent."""

    classes: tuple[int, ...]
    matrix: tuple[tuple[int, ...], ...]
    producers_accuracy_pct: dict[str, float | None]
    users_accuracy_pct: dict[str, float | None]
    overall_accuracy_pct: float
    kappa_pct: float


@dataclasses.dataclass(frozen=True)
class ClassificationEvaluation:
    """``evaluate_strips`` / ``evaluate_files``: the filter test (ground = classes 2, 9, and 11 in LAS 1.4) and the confusion matrix.
    Against a truth in a coarser scheme (``_coarse_scheme_map``) the matrix is on the truth's classes:
    ``class_map`` (our class as text -> the truth's class), why (``class_map_reason``) and the matrix of the
    classes as labelled (``confusion_before_map``); all None otherwise."""

    filter_test: FilterTest
    confusion: Confusion
    class_map: dict[str, int] | None = None
    class_map_reason: str | None = None
    confusion_before_map: Confusion | None = None

    def to_json(self) -> str:
        """classification_eval.json's text (``lidarctl evaluate --json``, the chain's lidar_eval)."""
        return json.dumps(dataclasses.asdict(self), indent=2)


def read_filter_test(path) -> FilterTest:
    """The filter test of a classification evaluation (``evaluate_strips``'s result as JSON, e.g. the chain's
    lidar_out/classification_eval.json); InputError naming the file when it is not one."""
    d = read_record(path, CLASSIFICATION_EVAL, SCHEMA_VERSION)
    try:
        return FilterTest(**d["filter_test"])
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, CLASSIFICATION_EVAL, exc) from None


def truth_holds_unclassified(path) -> bool:
    """Whether the truth of a classification evaluation (its JSON, as ``read_filter_test`` reads) labels points class 1
    (unclassified): a production classification's class 1 may hold ground, which the filter test counts as object, so
    that its type II and total errors overstate (``lidarctl evaluate``'s note; Autzen 54.7 %, lidR Topography 18.8 %
    total against type I 0.34 / 0.04 %). False for a record without its confusion matrix."""
    d = read_record(path, CLASSIFICATION_EVAL, SCHEMA_VERSION)
    conf = d.get("confusion") or {}
    rows = dict(zip(conf.get("classes") or (), conf.get("matrix") or ()))
    return sum(rows.get(1) or ()) > 0


# ASPRS classes a scheme without vegetation classes holds in its class 1 ("unclassified"): vegetation 3/4/5, noise
# 7/18 and bridge deck 17 (AHN3's scheme: 1 2 6 9 26)
COARSE_UNCLASSIFIED = (3, 4, 5, 7, 17, 18)
BRIDGE_DECK = 17
CIVIL_STRUCTURES = 26  # AHN's "kunstwerken" (bridges, viaducts), a class the ASPRS table leaves to users
VEGETATION = (3, 4, 5)


def _coarse_scheme_map(pred_classes, truth_classes) -> dict[int, int]:
    """Our classes to score as the truth's class 1 when the truth is in a coarser scheme: it holds class 1 and none
    of the vegetation classes 3/4/5. The classes of ``COARSE_UNCLASSIFIED`` we hold and it does not; {} otherwise."""
    truth = {int(c) for c in truth_classes}
    if 1 not in truth or truth & set(VEGETATION):
        return {}
    mapping = {int(c): 1 for c in sorted({int(c) for c in pred_classes}) if c in COARSE_UNCLASSIFIED and c not in truth}
    if mapping.get(BRIDGE_DECK) and CIVIL_STRUCTURES in truth:
        # AHN's civil structures (26: bridges, viaducts) hold what we call bridge deck (trial s94: AHN3 Delft's 26
        # scored 0 % found, 755 of its 1,365 points ours 17; mapped, 55 % found, 78 % right)
        mapping[BRIDGE_DECK] = CIVIL_STRUCTURES
    return mapping


def filter_errors(pred_ground: np.ndarray, true_ground: np.ndarray) -> FilterTest:
    """Type I / type II / total error (%) and Cohen's kappa (%) for boolean ground masks."""
    pred_ground = np.asarray(pred_ground, bool)
    true_ground = np.asarray(true_ground, bool)
    n = len(true_ground)
    if n == 0 or len(pred_ground) != n:
        raise ValueError(f"filter_errors: {len(pred_ground)} predicted and {n} true labels: expected the same number "
                         "of points, at least one")
    a = int(np.sum(true_ground & pred_ground))      # ground kept
    b = int(np.sum(true_ground & ~pred_ground))     # type I
    c = int(np.sum(~true_ground & pred_ground))     # type II
    d = int(np.sum(~true_ground & ~pred_ground))    # object kept
    po = (a + d) / n
    pe = ((a + b) * (a + c) + (c + d) * (b + d)) / (n * n)
    kappa = (po - pe) / (1 - pe) if pe < 1 else 1.0
    return FilterTest(
        n_points=n,
        n_ground=a + b,
        n_object=c + d,
        type_i_count=b,
        type_ii_count=c,
        type_i_error_pct=100.0 * b / max(a + b, 1),
        type_ii_error_pct=100.0 * c / max(c + d, 1),
        total_error_pct=100.0 * (b + c) / n,
        kappa_pct=100.0 * kappa,
    )


def confusion(pred: np.ndarray, truth: np.ndarray, classes=None) -> Confusion:
    """Confusion matrix (rows truth, columns prediction) with producer's/user's/overall accuracy (%)."""
    pred = np.asarray(pred).astype(np.int64)
    truth = np.asarray(truth).astype(np.int64)
    if classes is None:
        classes = np.union1d(np.unique(pred), np.unique(truth))
    classes = [int(c) for c in classes]
    index = {c: k for k, c in enumerate(classes)}
    lut = np.full(max(max(classes), int(pred.max(initial=0)), int(truth.max(initial=0))) + 1, -1)
    for c, k in index.items():
        lut[c] = k
    pi, ti = lut[pred], lut[truth]
    ok = (pi >= 0) & (ti >= 0)
    m = np.zeros((len(classes), len(classes)), np.int64)
    np.add.at(m, (ti[ok], pi[ok]), 1)
    diag = np.diag(m).astype(float)
    rows, cols = m.sum(axis=1), m.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        producers = np.where(rows > 0, 100.0 * diag / rows, np.nan)
        users = np.where(cols > 0, 100.0 * diag / cols, np.nan)
    n = max(int(m.sum()), 1)
    po, pe = float(diag.sum()) / n, float(np.dot(rows.astype(float), cols.astype(float))) / (n * n)
    return Confusion(
        classes=tuple(classes),
        matrix=tuple(tuple(row) for row in m.tolist()),
        producers_accuracy_pct={str(c): _num(v) for c, v in zip(classes, producers)},
        users_accuracy_pct={str(c): _num(v) for c, v in zip(classes, users)},
        overall_accuracy_pct=100.0 * po,
        kappa_pct=100.0 * ((po - pe) / (1 - pe) if pe < 1 else 1.0),
    )


def _num(v):
    return None if not np.isfinite(v) else float(v)


def format_filter_table(rows: dict[str, FilterTest], published: dict | None = None) -> str:
    """Readable table: sample, type I, type II, total, kappa (%), and published numbers if given."""
    head = f"{'sample':<10}{'type I':>9}{'type II':>9}{'total':>9}{'kappa':>9}"
    if published:
        head += f"   {'published type I / II / total':>30}"
    lines = [head, "-" * len(head)]
    for name, r in rows.items():
        line = (f"{name:<10}{r.type_i_error_pct:9.2f}{r.type_ii_error_pct:9.2f}"
                f"{r.total_error_pct:9.2f}{r.kappa_pct:9.2f}")
        if published and name in published:
            pub = published[name]
            line += f"   {pub[0]:>9.2f} / {pub[1]:6.2f} / {pub[2]:6.2f}"
        lines.append(line)
    return "\n".join(lines)


def format_confusion(conf: Confusion, names: dict | None = None) -> str:
    names = names or {}
    classes = conf.classes
    labels = [names.get(c, str(c)) for c in classes]
    w = max(12, max(len(s) for s in labels) + 2)
    lines = ["truth \\ predicted".ljust(w) + "".join(s.rjust(w) for s in labels) + "producer %".rjust(w)]
    for c, lab, row in zip(classes, labels, conf.matrix):
        pa = conf.producers_accuracy_pct[str(c)]
        lines.append(lab.ljust(w) + "".join(str(v).rjust(w) for v in row)
                     + (f"{pa:.2f}" if pa is not None else "-").rjust(w))
    ua = [conf.users_accuracy_pct[str(c)] for c in classes]
    lines.append("user %".ljust(w) + "".join((f"{u:.2f}" if u is not None else "-").rjust(w) for u in ua))
    line = f"overall accuracy: {conf.overall_accuracy_pct:.2f} %, kappa {conf.kappa_pct:.2f} %"
    lines.append(line)
    return "\n".join(lines)


def format_class_map(result: ClassificationEvaluation) -> list[str]:
    """The lines under the matrix of a truth in a coarser scheme: the mapping and why, and the figures that the
    mapping changed (overall accuracy, kappa, producer's and user's accuracy per class) as labelled -> as scored."""
    if result.class_map is None or result.confusion_before_map is None:
        return []
    b, a = result.confusion_before_map, result.confusion

    def pct(v):
        return "-" if v is None else f"{v:.2f} %"

    lines = [f"scored on the truth's classes: {result.class_map_reason} (--map-pred gives another mapping)",
             f"as labelled, before the mapping: overall accuracy {b.overall_accuracy_pct:.2f} %, kappa "
             f"{b.kappa_pct:.2f} % (now {a.overall_accuracy_pct:.2f} %, {a.kappa_pct:.2f} %)"]
    for c in a.classes:
        k = str(c)
        pb, pa = b.producers_accuracy_pct.get(k), a.producers_accuracy_pct[k]
        ub, ua = b.users_accuracy_pct.get(k), a.users_accuracy_pct[k]
        if (pb, ub) != (pa, ua):
            lines.append(f"  class {c}: producer's {pct(pb)} -> {pct(pa)}, user's {pct(ub)} -> {pct(ua)}")
    return lines


def evaluate_files(pred_path, truth_path, map_pred: dict | None = None,
                   map_truth: dict | None = None) -> ClassificationEvaluation:
    """The stage (``lidarctl evaluate``): filter-test errors (ground = classes 2, 9, and 11 in LAS 1.4) and the confusion
    matrix of a classified file against a truth file with the same points in the same order.
    ``map_pred`` / ``map_truth``: class mappings applied first (e.g. ``{3: 1, 4: 1}``)."""
    return evaluate_strips([pred_path], [truth_path], map_pred, map_truth)


def evaluate_strips(pred_paths, truth_paths, map_pred: dict | None = None,
                    map_truth: dict | None = None) -> ClassificationEvaluation:
    """``evaluate_files`` over strips: each classified strip against its truth strip (same points, same
    order; ``read_same_points``), the errors and the confusion matrix over all their points together
    (only the classes of all strips are held, one byte per point each)."""
    if len(pred_paths) != len(truth_paths) or not pred_paths:
        raise InputError(f"{len(pred_paths)} classified strips for {len(truth_paths)} truth strips (one each needed)")
    preds, truths, pred_ground, true_ground = [], [], [], []
    for pred_path, truth_path in zip(pred_paths, truth_paths):
        pred, truth = read_same_points(pred_path, truth_path)
        preds.append(pred.classification)
        truths.append(truth.classification)
        # road surface (11) is ground where the file's LAS version defines it (io.ground_classes): a fused LAS 1.4
        # classification's roads are no type I error; a LAS 1.2 reference's 11 is reserved (MixedConifer: canopy)
        pred_ground.append(np.isin(pred.classification, io.ground_classes(las.read_header(pred_path))))
        true_ground.append(np.isin(truth.classification, io.ground_classes(las.read_header(truth_path))))
    pc, tc = np.concatenate(preds).astype(int), np.concatenate(truths).astype(int)
    pg, tg = np.concatenate(pred_ground), np.concatenate(true_ground)
    for mapping, arr in ((map_pred or {}, pc), (map_truth or {}, tc)):
        _remap(arr, mapping)
    if map_pred or map_truth:  # classes mapped: ground by the mapped codes (a mapping names its own classes)
        pg, tg = np.isin(pc, (2, 9)), np.isin(tc, (2, 9))
    ft, conf = filter_errors(pg, tg), confusion(pc, tc)
    coarse = {} if map_pred else _coarse_scheme_map(np.unique(pc), np.unique(tc))
    if not coarse:
        return ClassificationEvaluation(ft, conf)
    ones = [a for a, b in coarse.items() if b == 1]
    reason = (f"the truth holds class 1 and no vegetation class (classes {' '.join(map(str, np.unique(tc)))}): "
              f"our classes {', '.join(map(str, ones))} scored as its class 1"
              + (f", our bridge deck ({BRIDGE_DECK}) as its civil structures ({CIVIL_STRUCTURES}, AHN's)"
                 if coarse.get(BRIDGE_DECK) == CIVIL_STRUCTURES else ""))
    return ClassificationEvaluation(ft, confusion(_remap(pc, coarse), tc), {str(a): b for a, b in coarse.items()},
                                    reason, conf)


def _remap(classes: np.ndarray, mapping: dict) -> np.ndarray:
    """``classes`` with each class a of ``mapping`` replaced by mapping[a], in place (and returned)."""
    src = classes.copy()
    for a, b in mapping.items():
        classes[src == a] = b
    return classes
