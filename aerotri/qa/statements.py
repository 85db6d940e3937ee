"""Accuracy statements as a deliverable's metadata and report quote them, from a compliance section.

A QA engineer signs a delivery with the standard's own sentence, for the class the product was found to meet (the
finest class every judged row of the product meets, ``compliance.summarise``), not the class asked for: a DEM that
fails V10 but meets V15 is "tested to meet ... a 15-cm RMSEV Vertical Accuracy Class".

- ASPRS Edition 2 (2023): "This data set was tested to meet ASPRS Positional Accuracy Standards for Digital
  Geospatial Data, Edition 2, Version 1.0 (2023) for a __ (cm) RMSEV Vertical Accuracy Class. NVA accuracy was found
  to be RMSEV = __ cm." (the figure judged: with the check points' own accuracy combined), the VVA reported; the same
  for RMSEH and a Horizontal Positional Accuracy Class.
- ASPRS Edition 1 (2014): "... (2014) for a __ (cm) RMSEz Vertical Accuracy Class. Actual NVA accuracy was found to
  be RMSEz = __ cm, equating to +/- __ cm at 95 % confidence level. Actual VVA accuracy was found to be +/- __ cm at
  the 95th percentile."; horizontal: RMSEx / RMSEy and +/- 1.7308 RMSEr at 95 % (NSSDA).
- USGS LBS (FGDC metadata, Vertical Positional Accuracy Report): "Tested __ meters (NVA) vertical accuracy at 95
  percent confidence level" and the VVA "at the 95th percentile".

The sentences are recalled from the standards' reporting clauses (Edition 1 section 7.15, Edition 2's reporting
section, the LBS metadata examples), not read in their text here: said with every statement set. A product that
meets no class, is not testable or was checked on the project's own LiDAR corners gets no statement but the reason;
the AT, the swath overlaps and the density get none. A project in feet gets the feet beside the
metres (US survey feet when its CRS is)."""

from __future__ import annotations

import dataclasses
import math
import re

# (the compliance section's classes are read, not imported: aerotri.qa.compliance makes the statements)

SOURCE_NOTE = ("wording after the standard's reporting clause, recalled (not read in the standard's text here): check "
               "it against the contract's copy before signing")
# The deliverables a statement is written for (the AT is a step towards them, the swath overlaps and the density no
# positional accuracy class; the demo's report stated its AT "tested to meet" a class on LiDAR roof corners)
STATED_PRODUCTS = ("DOM", "Line map (DLG)", "LiDAR DEM")
NOT_INDEPENDENT = ("LiDAR check points",)  # (``compliance.CheckSet.points``) checks the product's own data made
NSSDA_RADIAL_95 = 1.7308  # NSSDA: accuracy_r at 95 % = 1.7308 RMSE_r (RMSE_x = RMSE_y)
NSSDA_EQUAL_AXES = 0.6  # NSSDA's approximations hold for RMSE_min / RMSE_max between this and 1
NORMAL_95 = 1.96


@dataclasses.dataclass(frozen=True)
class AccuracyStatement:
    """One product's statement (``text``), or why it has none (``text`` empty, ``why``); both: a class left out of
    the statement and why (ASPRS 2023 without the check points' own accuracy in one dimension)."""

    product: str
    text: str
    why: str = ""


def _classes(finest: str) -> dict[str, str]:
    """{"H": "7.1", "V": "15"} of a finest class text "H7.1cm V15cm" (none when not established)."""
    if finest.startswith("not established") or finest.startswith("not measured"):
        return {}
    return {m.group(1): m.group(2) for m in re.finditer(r"\b([HV])([0-9.]+)cm\b", finest)}


def _length(m: float, unit_m: float, unit_name: str, digits_cm: int = 1) -> str:
    """``m`` in centimetres, with the project's feet beside them."""
    text = f"{100 * m:.{digits_cm}f} cm"
    return text + (f" ({m / unit_m:.3f} {unit_name})" if unit_m != 1.0 else "")


def _metres(m: float, unit_m: float, unit_name: str) -> str:
    text = f"{m:.3f} meters"
    return text + (f" ({m / unit_m:.3f} {unit_name})" if unit_m != 1.0 else "")


def _nva(checks):
    return next((c for c in checks if c.quantity.startswith("NVA") and c.figure is not None), None)


def _vva(checks):
    return next((c for c in checks if c.quantity.startswith("VVA") and c.figure is not None), None)


def _horizontal(checks):
    return next((c for c in checks if c.dimension == "H" and c.figure is not None and c.judged), None)


def _uncombined(check) -> bool:
    """A judged row whose check points' own accuracy is not stated (``compliance._cp_note``: not judged, not
    combined): Edition 2's RMSE includes it, so the row's figure is not the standard's."""
    return check.limit is not None and check.checkpoints_accurate is None


def _survey_option(check) -> str:
    return "[qa] survey_sigma_z_m" if check.dimension == "V" else "[qa] survey_sigma_xy_m"


def _asprs2023(classes: dict, checks, u: float, un: str) -> tuple[str, str]:
    """The statement and, for a class left out, why: Edition 2 combines the check points' own accuracy with the
    measured RMSE; where it is not stated the figure found is not the standard's and no class is stated."""
    head = ("This data set was tested to meet ASPRS Positional Accuracy Standards for Digital Geospatial Data, "
            "Edition 2, Version 1.0 (2023) for a ")
    parts, left_out = [], []
    if "V" in classes and (nva := _nva(checks)) is not None:
        if _uncombined(nva):
            left_out.append(f"no vertical class stated: the check points' own accuracy is not stated "
                            f"({_survey_option(nva)}), and Edition 2's RMSEV combines it with the measured "
                            f"{_length(nva.figure, u, un)}")
        else:
            s = (f"{head}{classes['V']} (cm) RMSEV Vertical Accuracy Class. NVA accuracy was found to be RMSEV = "
                 f"{_length(nva.figure, u, un)}.")
            if (vva := _vva(checks)) is not None:
                s += f" VVA accuracy was found to be RMSEV = {_length(vva.figure, u, un)}."
            parts.append(s)
    if "H" in classes and (h := _horizontal(checks)) is not None:
        if _uncombined(h):
            left_out.append(f"no horizontal class stated: the check points' own accuracy is not stated "
                            f"({_survey_option(h)}), and Edition 2's RMSEH combines it with the measured "
                            f"{_length(h.figure, u, un)}")
        else:
            parts.append(f"{head}{classes['H']} (cm) RMSEH Horizontal Positional Accuracy Class. The tested "
                         f"horizontal positional accuracy was found to be RMSEH = {_length(h.figure, u, un)}.")
    return " ".join(parts), "; ".join(left_out)


def _asprs2014(classes: dict, checks, u: float, un: str) -> tuple[str, str]:
    """The statement and, for a class left out, why: Edition 1 asks check points three times as accurate as the class
    (asprs2014.toml checkpoint_accuracy_factor); where their own accuracy is not stated no class is stated (s95: the
    rows read "accuracy unknown" and the statement was issued, where Edition 2's withheld it)."""
    head = ("This data set was tested to meet ASPRS Positional Accuracy Standards for Digital Geospatial Data (2014) "
            "for a ")
    parts, left_out = [], []
    if "V" in classes and (nva := _nva(checks)) is not None and nva.measured is not None:
        if _uncombined(nva):
            left_out.append(f"no vertical class stated: the check points' own accuracy is not stated "
                            f"({_survey_option(nva)}), and Edition 1 asks them three times as accurate as the class")
        else:
            s = (f"{head}{classes['V']} (cm) RMSEz Vertical Accuracy Class. Actual NVA accuracy was found to be "
                 f"RMSEz = {_length(nva.measured, u, un)}, equating to +/- "
                 f"{_length(NORMAL_95 * nva.measured, u, un)} at 95 % confidence level.")
            if (vva := _vva(checks)) is not None:
                s += f" Actual VVA accuracy was found to be +/- {_length(vva.figure, u, un)} at the 95th percentile."
            parts.append(s)
    if "H" in classes and (h := _horizontal(checks)) is not None and h.measured is not None:
        if _uncombined(h):
            left_out.append(f"no horizontal class stated: the check points' own accuracy is not stated "
                            f"({_survey_option(h)}), and Edition 1 asks them three times as accurate as the class")
        else:
            parts.append(_asprs2014_horizontal(head + classes["H"], h, u, un))
    return " ".join(parts), "; ".join(left_out)


def _asprs2014_horizontal(head: str, h, u: float, un: str) -> str:
    """Edition 1's horizontal sentence: RMSE_r from the axes where the check gives them (the row judges the larger
    axis, and that read as RMSE_r under-stated it, s95: 6.3 cm for 7.2, +/- 10.9 for 12.4 cm)."""
    r = math.hypot(*h.rmse_axes_m) if h.rmse_axes_m is not None else h.measured
    s = (f"{head} (cm) RMSEx / RMSEy Horizontal Accuracy Class. Actual positional accuracy was found to be RMSEr = "
         f"{_length(r, u, un)}, equating to +/- {_length(NSSDA_RADIAL_95 * r, u, un)} at 95 % confidence level.")
    if h.rmse_axes_m is not None and min(h.rmse_axes_m) < NSSDA_EQUAL_AXES * max(h.rmse_axes_m):
        s += (f" (RMSEx {_length(h.rmse_axes_m[0], u, un)}, RMSEy {_length(h.rmse_axes_m[1], u, un)}: their ratio "
              f"below NSSDA's {NSSDA_EQUAL_AXES:g}, for which the 95 % figure is an approximation.)")
    return s


def _lbs(checks, u: float, un: str) -> str:
    parts = []
    if (nva := next((c for c in checks if c.quantity.startswith("NVA") and c.measured is not None), None)) is not None:
        parts.append(f"Tested {_metres(NORMAL_95 * nva.measured, u, un)} non-vegetated vertical accuracy (NVA) at 95 "
                     f"percent confidence level (RMSEz {_metres(nva.measured, u, un)} x 1.9600).")
    if (vva := _vva(checks)) is not None:
        parts.append(f"Tested {_metres(vva.figure, u, un)} vegetated vertical accuracy (VVA) at the 95th percentile.")
    return " ".join(parts)


def accuracy_statements(comp: "Compliance", unit_m: float = 1.0, unit_name: str = "m") -> tuple[AccuracyStatement, ...]:
    """The statements of ``comp``'s products under ASPRS 2023 / 2014 and the USGS LBS (none for other standards);
    ``unit_m``, ``unit_name``: metres per unit of the project's CRS and its name, said beside the metres when not
    metres."""
    if comp.key not in ("asprs2023", "asprs2014", "usgs-lbs"):
        return ()
    out = []
    for p in comp.products:
        if p.product not in STATED_PRODUCTS:
            continue
        checks = [c for c in comp.checks if c.product == p.product]
        if any(c.counted in NOT_INDEPENDENT for c in checks):
            out.append(AccuracyStatement(p.product, "", "no statement: its check points are roof corners of the "
                                                        "project's own LiDAR, not surveyed: no independent test"))
            continue
        if p.verdict != "pass" and comp.key == "usgs-lbs":
            out.append(AccuracyStatement(p.product, "", f"no statement: {p.verdict} against {comp.class_tested}"))
            continue
        if comp.key == "usgs-lbs":
            text = _lbs(checks, unit_m, unit_name)
        else:
            classes = _classes(p.finest_class)
            if not classes:
                out.append(AccuracyStatement(p.product, "", f"no statement: no class established ({p.finest_class})"))
                continue
            text, left_out = (_asprs2023 if comp.key == "asprs2023" else _asprs2014)(classes, checks, unit_m,
                                                                                       unit_name)
            if left_out:
                out.append(AccuracyStatement(p.product, text, left_out if text else f"no statement: {left_out}"))
                continue
        out.append(AccuracyStatement(p.product, text, "" if text else "no statement: no figure of the rows it needs"))
    return tuple(out)
