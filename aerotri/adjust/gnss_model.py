"""The GNSS model of an adjustment in words: how the positions are weighted, which shifts are estimated, and where
the sigmas came from (gnss.txt, project.toml [gnss], or the defaults), for the report's DATUM section.

Two receivers the toolkit models:

- a survey receiver (aerial GNSS/IMU, RTK): each position with its own sigma (centimetres), independent between
  frames; optionally a shift (and drift) per strip, free, which control points must then fix
  (``[adjust] gnss_correction``);
- a consumer receiver (a drone without RTK): the positions of one flight share an error of metres (its absolute
  accuracy) and differ among themselves by decimetres. Positions weighted with the decimetres (``[gnss]
  sigma_xy_m``, ``sigma_z_m``) plus one 3-D offset for the whole flight with the metres as its a-priori sigma
  (``[gnss] offset_sigma_xy_m``, ``offset_sigma_z_m``). One offset per flight, not per strip: the error of a
  consumer receiver changes over minutes, not at a turn, and per-strip offsets of metres would let the strips of
  a small block move apart by metres that the tie points alone must hold. Without control the block's datum is
  then held by the offset's a-priori sigma (metres, and the report says so); with a DEM or control the offset is
  estimated and the baselines between frames, weighted by decimetres, still give the block's scale.
"""

from __future__ import annotations

import numpy as np

from aerotri.adjust.graph import gnss_observed

DEFAULT_SOURCE = "the [gnss] defaults, a survey receiver's"


def sigma_source(project, per_record: bool) -> str:
    """Where the positions' sigmas came from: gnss.txt's sX sY sZ, project.toml [gnss], or the defaults."""
    if per_record:
        return f"{project.gnss_path.name} sX sY sZ"
    if all(project.source_of("gnss", k) == "project.toml" for k in ("sigma_xy_m", "sigma_z_m")):
        return f"{project.config_path.name} [gnss] sigma_xy_m, sigma_z_m"
    return DEFAULT_SOURCE


def offset_observed(block) -> bool:
    """Whether anything but the GNSS positions observes a GNSS offset or shift: control points or a surface (DEM,
    roof planes) in the solve. Without them an offset stays at its a-priori value."""
    return len(block.control_point) > 0 or block.surface is not None


def statement(correction: str, sigma_m: np.ndarray, source: str, offset_sigma_m, offset_source: str,
              shift_m: np.ndarray | None = None, observed: bool = True, weight_factor: float = 1.0) -> str:
    """The GNSS model in one paragraph. ``correction``: the solve's GNSS model (``graph.GNSS_MODELS``);
    ``sigma_m`` (N, 3) the positions' sigmas; ``offset_sigma_m`` (3,) or None the shifts' a-priori sigma;
    ``shift_m`` (S, 3) the estimated shifts (ENU, m); ``observed``: the solve has control points or a surface
    (DEM, roof planes), without which nothing but the GNSS positions themselves says where the block is;
    ``weight_factor``: the variance components' factor the solve multiplied those a-priori sigmas by."""
    med = _median_sigma_m(sigma_m)
    weights = f"positions weighted with {med[0]:.3g} / {med[2]:.3g} m (plan / height; {source})"
    if abs(weight_factor - 1.0) > 5e-4:  # (trial s102 txt2 M7: the reweighted sigmas had been named as project.toml's)
        used = med * weight_factor
        weights = (f"positions weighted with {med[0]:.3g} / {med[2]:.3g} m a priori (plan / height; {source}), "
                   f"x {weight_factor:.3f} by variance components: {used[0]:.3g} / {used[2]:.3g} m in the solve")
    if correction == "none":
        if not observed:  # (trial s99 atmut H1: the heights 14 m off with a focal length 5 % long, "as good as ...")
            return (f"GNSS: {weights}, independent between frames, no offset estimated: the datum is the GNSS "
                    "positions' alone, as good as these sigmas say only where the GNSS heights and the camera's focal "
                    "length are right; no control point or surface (DEM) in the solve checks it.")
        # (not "as good as these sigmas say": trial s100 rc F1, beside a GNSS the images cannot check)
        return f"GNSS: {weights}, independent between frames, no offset estimated: the datum is these positions'."
    what = {"offset": "one 3-D offset for the whole flight (a consumer receiver's common error)",
            "shift": "a shift per strip", "shift_drift": "a shift and drift per strip"}[correction]
    if offset_sigma_m is None:
        prior = "free (the control fixes it)"
    else:
        o = np.asarray(offset_sigma_m, dtype=float)
        prior = f"a priori {o[0]:.3g} / {o[2]:.3g} m ({offset_source})"
    text = f"GNSS: {weights} between frames, and {what}, {prior}"
    if shift_m is not None and correction == "offset":
        e, n, u = np.asarray(shift_m, dtype=float)[0]
        if observed:
            text += f"; estimated E {e:+.2f} N {n:+.2f} U {u:+.2f} m"
        else:  # the offset moves every position alike: without control or a surface it stays at its prior mean
            text += (f"; not estimated: without control points or a DEM nothing observes it, and E {e:+.2f} N "
                     f"{n:+.2f} U {u:+.2f} m is its a-priori value, not a measurement of the receiver")
    if offset_sigma_m is not None and not observed:
        text += (". Without control or a DEM the block's height is held by that a-priori sigma (BLOCK "
                 "GEOMETRY)")
    return text + "."


# the GNSS group's share of the redundancy below which nothing in the block checks the positions: the solve puts the
# centres where the GNSS says and their sigmas are the stated ones, whatever the receiver's real error. Clean simulated
# blocks hold 0.12-0.17 (tiny, 6 frames, 0.05 / 0.08 m) and 0.49 (demo, 18 frames); trial s99 atmut L3: sigmas typed
# 0.001 m held 0.0 of 18 and printed centre sigmas of 0.000 m against real errors of 0.10 m, "Solution Successful";
# s95: millimetre residuals of such a GNSS read like a 2 mm fit in the report's GNSS figure
UNCHECKED_REDUNDANCY_SHARE = 0.05


def unchecked(redundancy: float | None, n: int) -> bool:
    """Whether GNSS positions of ``n`` coordinates holding ``redundancy`` (variance components) are unchecked."""
    return redundancy is not None and n > 0 and redundancy < UNCHECKED_REDUNDANCY_SHARE * n


def unchecked_note(redundancy: float | None, n: int, sigma_m: np.ndarray) -> str | None:
    """A DATUM note when the GNSS positions (``n`` coordinates, sigmas ``sigma_m`` (N, 3)) are ``unchecked``; None
    otherwise."""
    if not unchecked(redundancy, n):
        return None
    med = _median_sigma_m(sigma_m)
    return (f"GNSS unchecked by the images: its {n} coordinates hold {redundancy:.1f} of the redundancy (their sigmas, "
            f"{med[0]:.3g} / {med[2]:.3g} m, weight them far above the images): the projection centres are where the "
            "GNSS puts them and their sigmas are the stated ones, which nothing in the block tests. If the receiver "
            "holds less, state what it holds ([gnss] sigma_xy_m, sigma_z_m, or gnss.txt sX sY sZ).")


def _median_sigma_m(sigma_m) -> np.ndarray:
    """(3,) the median sigma of the positions observed (``gnss_observed``): plan x, y and height, m."""
    sigma_m = np.asarray(sigma_m, dtype=float)
    return np.median(sigma_m[gnss_observed(sigma_m)], axis=0)
