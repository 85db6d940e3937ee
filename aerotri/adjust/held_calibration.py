"""Tests of the principal point and the focal length held at camera.toml's values (trial-cam F1; s95).

A principal point entered with the wrong sign (a certificate's y down read as y up) is absorbed by a small block:
6 frames in two strips flown each way, GNSS only, turned every frame 2.45 deg in kappa and the ground with it, the GNSS
residuals stayed at 4 mm and sigma0 rose only from 14.5 to 19.4 um, and the verdict read "Solution Successful". The
images do tell it: the same block with the principal point estimated goes back to -0.247 mm (truth -0.3).

So when the principal point is held (not in ``self_calibration``), the final least squares is solved once more from
its solution with the principal point free, and the held value is tested by the drop of the residuals' weighted sum
of squares (chi2): F = (chi2_held - chi2_free) / 2 / sigma0_free^2 against Fisher's F(2, dof) at ``alpha``. A held
principal point that the images reject (F beyond the limit) by more than ``PP_MIN_SHIFT_PX`` (what it moves on the
ground in GSD, for a near-nadir frame) makes the verdict weak, naming the values. Small shifts of a real certificate
(a few um: a tenth or two of a pixel) are left alone, significant or not.

The focal length the same way (s95, a drone trial: camera.toml's pixel 1.20 um instead of 1.54, the focal length
3008 px for 2344, adjusted with the DEM of the block's cloud and the EXIF's consumer GNSS: "Solution Successful",
the projection centres 11.8 m above the GNSS heights, the flying height 48 m for 40; with the focal length asked for,
the block measured 2379 +- 12 px, 54 sigma off, and fixed it at 3008 as "not determinable", its 3 sigma 1.48 % over
the 1 % limit): when the focal length is held and the ground's heights are observed (a DEM, control with heights;
without, the focal length is the flying height's and the test says nothing), the solve is repeated with it free and
F = (chi2_held - chi2_free) / sigma0_free^2 against F(1, dof). A held focal length the images reject by more than
``FOCAL_MIN_SHIFT`` of it makes the verdict weak, naming the camera file's values.

The radial distortion the same way (trial s97 M1: a certificate's K1, K2 on r in mm typed as the k1, k2 of
normalised coordinates, 10 px at a Phase One frame's corner: check points 1.48 m off at 3.4 cm GSD, "Solution weak"
naming the GNSS, the control and the principal point, never the lens): when the radial terms are held, the solve is
repeated with k1, k2 free and F = (chi2_held - chi2_free) / 2 / sigma0_free^2 against F(2, dof). Held terms the
images reject whose change moves the frame's corner by more than ``RADIAL_MIN_SHIFT_PX`` make the verdict weak.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from aerotri.adjust import graph as G
from aerotri.core.quantiles import f_isf

log = logging.getLogger(__name__)

PP_ALPHA = 1e-3
PP_MIN_SHIFT_PX = 1.0
# a held radial distortion the images reject is left alone when freeing it moves the frame's corner by less (a
# certificate's terms of another camera unit differ by a few tenths of a pixel)
RADIAL_MIN_SHIFT_PX = 1.0
# a held focal length the images reject by less than this share of it is left alone (the determinability check's 1 %:
# a camera's own focal length is known far better; a nominal EXIF one is off by a few %, which self-calibration takes)
FOCAL_MIN_SHIFT = 0.01


@dataclasses.dataclass(frozen=True)
class _TestFigures:
    """What every held-value test gives: sigma0 held and freed (um on the sensor), the F statistic and its limit."""

    sigma0_held_um: float
    sigma0_free_um: float
    f_statistic: float
    f_limit: float


@dataclasses.dataclass(frozen=True)
class HeldPrincipalPoint(_TestFigures):
    """The held principal point against the images: the freed estimate's shift from it (px, x right / y down, and
    mm, x right / y up), sigma0 held and freed (um on the sensor), the F statistic and its limit."""

    shift_px: tuple[float, float]
    shift_mm: tuple[float, float]
    held_mm: tuple[float, float]

    @property
    def rejected(self) -> bool:
        return self.f_statistic > self.f_limit and float(np.hypot(*self.shift_px)) > PP_MIN_SHIFT_PX

    def text(self) -> str:
        ppx_mm, ppy_mm = (h + s for h, s in zip(self.held_mm, self.shift_mm))
        return (f"The principal point held at camera.toml's ppx_mm = {self.held_mm[0]:g}, ppy_mm = {self.held_mm[1]:g} "
                f"is not what the images give: estimated, it moves {self.shift_mm[0]:+.4f} / {self.shift_mm[1]:+.4f} mm "
                f"(x right / y up; {float(np.hypot(*self.shift_px)):.1f} px) to {ppx_mm:.4f} / {ppy_mm:.4f} mm and sigma0 "
                f"falls from {self.sigma0_held_um:.3f} to {self.sigma0_free_um:.3f} um (F = {self.f_statistic:.1f} > "
                f"{self.f_limit:.1f}): check the certificate's principal point (photo coordinates, y up; its sign, "
                "PPA or PBS) or estimate it (self_calibration \"pp\"). Held wrong, it turns the frames and the ground.")


@dataclasses.dataclass(frozen=True)
class _FreedTest(_TestFigures):
    """The held values' test by the drop of chi2 with ``n`` parameters freed: sigma0 held and freed (um on the
    sensor), F = (chi2_held - chi2_free) / n / sigma0_free^2 and its limit F(n, dof) at alpha; ``cal`` the freed
    Cal3DS2 values (fx fy s u0 v0 ... px)."""

    cal: np.ndarray

    def fields(self) -> dict:
        """The test's figures as the Held* results' fields."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(_TestFigures)}


def _freed(block: G.Block, opts: G.SolveSettings, state: G.State, info: G.SolveInfo, obs_active, control_active,
           group: str, n: int, alpha: float) -> _FreedTest | None:
    """The final least squares once more from ``state`` with the calibration ``group`` (``n`` parameters) free,
    tested against ``info`` (the solve that held it); None when the group is estimated already, the camera model has
    none, or there are no degrees of freedom or no finite chi2 to test with."""
    if (group in opts.self_calibration or group not in block.camera.SELF_CAL_GROUPS or not info.dof > n
            or not info.chi2 > 0):
        return None
    free = dataclasses.replace(opts, self_calibration=tuple(opts.self_calibration) + (group,))
    gr = G.build_graph(block, free, state, obs_active, control_active, robust=False)
    values, info_free = G.optimize(gr, free)
    if not info_free.dof > 0 or not np.isfinite(info_free.chi2):
        return None
    s2 = info_free.chi2 / info_free.dof
    um = opts.image_sigma_px * block.camera.pixel_um  # sigma0 (in image sigmas) on the sensor
    return _FreedTest(cal=np.asarray(values.atCal3DS2(G.K_KEY).vector(), dtype=float),
                      sigma0_held_um=float(np.sqrt(info.chi2 / info.dof)) * um, sigma0_free_um=float(np.sqrt(s2)) * um,
                      f_statistic=float(max(0.0, info.chi2 - info_free.chi2) / n / s2),
                      f_limit=float(f_isf(alpha, n, info_free.dof)))


def held_principal_point(block: G.Block, opts: G.SolveSettings, state: G.State, info: G.SolveInfo, obs_active,
                         control_active, alpha: float = PP_ALPHA) -> HeldPrincipalPoint | None:
    """The test of the module docstring for a solution ``state`` (``info``: its final least squares, the principal
    point held), or None when the principal point is estimated, the camera model has none or nothing is left to
    test it with."""
    freed = _freed(block, opts, state, info, obs_active, control_active, "pp", 2, alpha)
    if freed is None:
        return None
    shift_px = (float(freed.cal[3] - state.cal[3]), float(freed.cal[4] - state.cal[4]))
    pix_mm = block.camera.pixel_um / 1000.0
    test = HeldPrincipalPoint(
        shift_px=shift_px, shift_mm=(shift_px[0] * pix_mm, -shift_px[1] * pix_mm),
        held_mm=(float(block.camera.ppx_mm), float(block.camera.ppy_mm)), **freed.fields())
    log.info(f"held principal point: freed it moves {shift_px[0]:+.2f} / {shift_px[1]:+.2f} px (x right / y down), "
             f"F = {test.f_statistic:.2f} against {test.f_limit:.2f}")
    return test


@dataclasses.dataclass(frozen=True)
class HeldFocal(_TestFigures):
    """The held focal length against the images: held and freed (px), the camera's pixel (um), sigma0 held and freed
    (um on the sensor), the F statistic and its limit."""

    held_px: float
    free_px: float
    pixel_um: float
    focal_mm: float

    @property
    def shift(self) -> float:
        """The freed focal length's relative change from the held one."""
        return self.free_px / self.held_px - 1.0

    @property
    def rejected(self) -> bool:
        return self.f_statistic > self.f_limit and abs(self.shift) > FOCAL_MIN_SHIFT

    def text(self, asked: bool = False) -> str:
        """The finding; ``asked``: the focal length was asked for and fixed as not determinable, so estimating it is
        no advice (the block measures it well enough to reject the held value, not to 1 %)."""
        how = ("" if asked else " or estimate it (self_calibration \"focal\")")
        return (f"The focal length held at camera.toml's {self.held_px:.1f} px (focal_mm = {self.focal_mm:g}, "
                f"pixel_um = {self.pixel_um:g}) is not what the images give: estimated it is {self.free_px:.1f} px "
                f"({100 * self.shift:+.1f} %), and sigma0 falls from {self.sigma0_held_um:.3f} to "
                f"{self.sigma0_free_um:.3f} um (F = {self.f_statistic:.1f} > {self.f_limit:.1f}): check the camera "
                f"file's focal length and pixel size (frames resized need the pixel size scaled with them: "
                f"{self.pixel_um * self.held_px / self.free_px:.3g} um would give the estimate){how}. Held wrong, it "
                "puts the block at the wrong height above the ground.")


def held_focal(block: G.Block, opts: G.SolveSettings, state: G.State, info: G.SolveInfo, obs_active, control_active,
               ground_heights: bool, alpha: float = PP_ALPHA) -> HeldFocal | None:
    """The focal length's test of the module docstring for a solution ``state`` (``info``: its final least squares,
    the focal length held); None when it is estimated, nothing observes the ground's heights (``ground_heights``),
    or nothing is left to test it with."""
    if not ground_heights:
        return None
    freed = _freed(block, opts, state, info, obs_active, control_active, "focal", 1, alpha)
    if freed is None:
        return None
    test = HeldFocal(held_px=float(state.cal[0]), free_px=float(freed.cal[0]), pixel_um=float(block.camera.pixel_um),
                     focal_mm=float(block.camera.focal_mm), **freed.fields())
    log.info(f"held focal length: freed it moves {100 * test.shift:+.2f} % ({test.held_px:.1f} -> "
             f"{test.free_px:.1f} px), F = {test.f_statistic:.2f} against {test.f_limit:.2f}")
    return test


@dataclasses.dataclass(frozen=True)
class HeldRadial(_TestFigures):
    """The held radial distortion (k1, k2 of normalised coordinates) against the images: held and freed, the shift
    freeing it makes at the frame's corner (px), sigma0 held and freed (um on the sensor), the F statistic and its
    limit."""

    held: tuple[float, float]
    free: tuple[float, float]
    corner_shift_px: float

    @property
    def rejected(self) -> bool:
        return self.f_statistic > self.f_limit and self.corner_shift_px > RADIAL_MIN_SHIFT_PX

    def text(self) -> str:
        return (f"The radial distortion held at camera.toml's k1 = {self.held[0]:.6g}, k2 = {self.held[1]:.6g} is not "
                f"what the images give: estimated, k1 = {self.free[0]:.6g}, k2 = {self.free[1]:.6g}, "
                f"{self.corner_shift_px:.1f} px of change at the frame's corner, and sigma0 falls from "
                f"{self.sigma0_held_um:.3f} to {self.sigma0_free_um:.3f} um (F = {self.f_statistic:.1f} > "
                f"{self.f_limit:.1f}): check the certificate's distortion terms (k1, k2 are of normalised "
                "coordinates, x / f: a certificate's K1, K2 on r in mm are k1 = K1 f^2, k2 = K2 f^4, with the sign of "
                "distortion, not of correction; docs/your-own-block.md) or estimate them (self_calibration "
                "\"radial\"). Held wrong, they bend the block and shift every point off the frame's centre.")


def held_radial(block: G.Block, opts: G.SolveSettings, state: G.State, info: G.SolveInfo, obs_active, control_active,
                alpha: float = PP_ALPHA) -> HeldRadial | None:
    """The radial distortion's test of the module docstring for a solution ``state`` (``info``: its final least
    squares, k1 and k2 held); None when they are estimated, the camera model has none or nothing is left to test
    them with."""
    freed = _freed(block, opts, state, info, obs_active, control_active, "radial", 2, alpha)
    if freed is None:
        return None
    k = block.camera.SELF_CAL_GROUPS["radial"]
    held = (float(state.cal[k[0]]), float(state.cal[k[1]]))
    free = (float(freed.cal[k[0]]), float(freed.cal[k[1]]))
    # the corner's radius in normalised coordinates, and what the change of k1, k2 moves it there (px)
    f_px = float(state.cal[0])
    r = float(np.hypot(block.camera.width / 2.0, block.camera.height / 2.0)) / f_px
    shift = abs(f_px * r * ((free[0] - held[0]) * r**2 + (free[1] - held[1]) * r**4))
    test = HeldRadial(held=held, free=free, corner_shift_px=shift, **freed.fields())
    log.info(f"held radial distortion: freed it moves the corner {shift:.2f} px (k1 {held[0]:.4g} -> {free[0]:.4g}, "
             f"k2 {held[1]:.4g} -> {free[1]:.4g}), F = {test.f_statistic:.2f} against {test.f_limit:.2f}")
    return test
