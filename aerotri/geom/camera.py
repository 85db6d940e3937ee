"""Frame camera models: interior orientation and the collinearity equations.

One base class (``Camera``: the frame geometry every model shares) and one subclass per lens model,
registered by name in ``MODELS`` (the ``model`` key of a camera file; absent = ``brown``):

- ``BrownCamera`` (``model = "brown"``): radial k1 k2 k3 and tangential
  p1 p2 distortion;
- ``PinholeCamera`` (``model = "pinhole"``): no distortion.

A new model is its class here (lens coefficient fields, ``MODEL``, ``kernel_params``, what the adjustment
and the exports need) plus its entry in ``MODELS``, and its compiled lens kernels in
``aerotri.geom.lens_kernels``, which hold the only implementation of each model's arithmetic.

Conventions (see docs in README):

- Pixel coordinates ``x_px`` (column) and ``y_px`` (row) have their origin at the centre of the
  top-left pixel, x right, y down. The image centre is at ((width-1)/2, (height-1)/2).
- The principal point offset ``ppx_mm``, ``ppy_mm`` is measured from the image centre in photo
  coordinates (x right, y up), in millimetres.
- Lens distortion acts on normalised coordinates (x/z, y/z in the computer-vision camera frame,
  dimensionless), as in OpenCV, COLMAP and GTSAM's Cal3DS2. Brown:
  ``r2 = xn^2 + yn^2``, ``xd = xn (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 xn yn + p2 (r2 + 2 xn^2)``,
  ``yd = yn (1 + ...) + p1 (r2 + 2 yn^2) + 2 p2 xn yn``.
- Exterior orientation: projection centre C (object metres) and R = rotation_matrix_opk(omega, phi,
  kappa) from camera to object (see aerotri.geom.rotation).
- The adjustment's calibration vector is GTSAM's Cal3DS2 ``[fx fy s u0 v0 k1 k2 p1 p2]`` (pixels) for
  every model (``calibration_vector``, ``from_calibration_vector``); ``SELF_CAL_GROUPS`` of a model
  names the entries each self-calibration group frees.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
from pathlib import Path
from typing import ClassVar

import numpy as np

from aerotri.core.errors import InputError, StageOrderError
from aerotri.geom.rotation import FLIP_YZ


class _LensKernels:
    """``aerotri.geom.lens_kernels``, imported on first use: numba takes 0.3 CPU-s to import, which commands
    that only read a camera (``ortho mosaic`` checking its frames against the orientation) need not pay."""

    def __getattr__(self, name):
        from aerotri.geom import lens_kernels as module

        return getattr(module, name)


lens_kernels = _LensKernels()

_GEOMETRY = ("focal_mm", "pixel_um", "width", "height", "ppx_mm", "ppy_mm")
CAL3DS2 = ("fx", "fy", "s", "u0", "v0", "k1", "k2", "p1", "p2")  # the adjustment's calibration vector
UNDISTORT_ITERATIONS = 20


def _as_array(v) -> np.ndarray:
    return np.asarray(v, dtype=float)


def _flat(a, b) -> tuple[tuple, np.ndarray, np.ndarray]:
    """(shape, a, b): two arrays broadcast together and flattened into writeable contiguous float64 vectors
    (what the array kernels take)."""
    a, b = _as_array(a), _as_array(b)
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    flat = [np.require(np.ravel(v), np.float64, ("C", "W")) for v in (a, b)]
    return a.shape, flat[0], flat[1]


# the fold search: normalised radii up to 10 (84 deg off the axis) in steps of 0.0025
FOLD_SEARCH_MAX_R = 10.0
FOLD_SEARCH_STEPS = 4000


def _corner_folds(camera: "Camera"):
    """Per frame corner (its normalised distance from the principal point, ``norm``): the normalised radius where the
    lens model's image position along the corner's direction stops growing outwards (None: it grows up to
    ``FOLD_SEARCH_MAX_R``) and that position there (normalised)."""
    params = camera.kernel_params()
    r = np.linspace(0.0, FOLD_SEARCH_MAX_R, FOLD_SEARCH_STEPS + 1)[1:]
    for cx, cy in ((0.0, 0.0), (camera.width - 1.0, 0.0), (0.0, camera.height - 1.0),
                   (camera.width - 1.0, camera.height - 1.0)):
        ux, uy = (cx - camera.cx_px) / camera.focal_px, (cy - camera.cy_px) / camera.focal_px
        norm = math.hypot(ux, uy)
        if norm == 0.0:
            continue
        xd, yd = lens_kernels.distort_points(params, r * ux / norm, r * uy / norm)
        outwards = (xd * ux + yd * uy) / norm  # distorted position along the corner's direction
        turn = np.flatnonzero(np.diff(outwards) <= 0.0)
        yield norm, (float(r[turn[0]]), float(outwards[turn[0]])) if turn.size else (None, None)


@functools.lru_cache(maxsize=64)
def _fold_radius(camera: "Camera") -> float | None:
    """``Camera.fold_radius``, computed once per camera (a frozen dataclass: cameras equal in every field share it)."""
    turns = [fold for _, (fold, _) in _corner_folds(camera) if fold is not None]
    return min(turns) if turns else None


def _fold_inside_frame(camera: "Camera") -> tuple[float, float] | None:
    """(the angle off the axis where the lens model turns back, the frame corner's angle), deg, for the first corner
    direction the model cannot reach (the distorted position at the fold short of the corner), else None."""
    for norm, (fold, reach) in _corner_folds(camera):
        if fold is not None and reach < norm:
            return math.degrees(math.atan(fold)), math.degrees(math.atan(norm))
    return None


def inside_frame(x_px, y_px, width: int, height: int, margin_px: float = 0.0):
    """Whether pixel positions lie on a frame of ``width`` x ``height`` px (pixel centres at integers: -0.5 ..
    width - 0.5), ``margin_px`` in from its edges."""
    x_px = np.asarray(x_px)
    y_px = np.asarray(y_px)
    return (
        (x_px >= -0.5 + margin_px)
        & (x_px <= width - 0.5 - margin_px)
        & (y_px >= -0.5 + margin_px)
        & (y_px <= height - 0.5 - margin_px)
    )


@dataclasses.dataclass(frozen=True)
class CameraFileFields:
    """How another program's camera file names the numbers ``Camera.check_plausible`` judges, for its messages:
    ``pp`` the principal point's fields (e.g. "cameras.txt cx, cy"), ``focal`` the focal length's, and a hint each
    in that format's convention (its units, its origin)."""

    pp: str
    pp_hint: str
    focal: str
    focal_hint: str = ""


@dataclasses.dataclass(frozen=True)
class Camera:
    """Interior orientation of a frame camera (units in the field names); the lens model is the subclass.

    Subclasses set ``MODEL`` (their name in camera files and ``MODELS``), ``COEFFICIENTS`` (their lens
    coefficient fields, in kernel order), ``SELF_CAL_GROUPS`` and implement ``kernel_params``,
    ``calibration_vector``, ``from_calibration_vector`` and ``colmap_model``.
    """

    focal_mm: float
    pixel_um: float
    width: int
    height: int
    ppx_mm: float = 0.0
    ppy_mm: float = 0.0
    name: str = "camera"

    MODEL: ClassVar[str] = ""
    COEFFICIENTS: ClassVar[tuple[str, ...]] = ()
    # self-calibration group -> indices of the Cal3DS2 vector it frees
    SELF_CAL_GROUPS: ClassVar[dict[str, tuple[int, ...]]] = {"focal": (0, 1), "pp": (3, 4)}

    def __post_init__(self):
        self.validate()

    # -- derived quantities -------------------------------------------------------------------
    @property
    def focal_px(self) -> float:
        return self.focal_mm * 1000.0 / self.pixel_um

    @property
    def cx_px(self) -> float:
        return (self.width - 1) / 2.0 + self.ppx_mm * 1000.0 / self.pixel_um

    @property
    def cy_px(self) -> float:
        return (self.height - 1) / 2.0 - self.ppy_mm * 1000.0 / self.pixel_um

    @property
    def sensor_mm(self) -> tuple[float, float]:
        return self.width * self.pixel_um / 1000.0, self.height * self.pixel_um / 1000.0

    @property
    def coefficients(self) -> tuple[float, ...]:
        """The lens coefficients, in ``COEFFICIENTS`` order."""
        return tuple(float(getattr(self, c)) for c in self.COEFFICIENTS)

    def gsd_m(self, height_above_ground_m: float) -> float:
        """Ground sample distance of a nadir frame at the given flying height above ground."""
        return height_above_ground_m * self.pixel_um * 1e-6 / (self.focal_mm * 1e-3)

    def K(self) -> np.ndarray:
        """The 3x3 computer-vision calibration matrix (pixels)."""
        f = self.focal_px
        return np.array([[f, 0.0, self.cx_px], [0.0, f, self.cy_px], [0.0, 0.0, 1.0]])

    def fold_radius(self) -> float | None:
        """The normalised radius (tan of the angle off the optical axis) where the lens model stops growing
        outwards towards any corner of the frame, None when it grows up to 84 deg off the axis.

        Past this radius a polynomial lens model turns back: rays far outside the field of view land
        inside the frame again (a DJI DewarpData model with k1 = -0.27 folds at 53 deg, just past its frame's
        corners). Anything projecting ground points into the frame must drop rays beyond it."""
        return _fold_radius(self)

    def ideal(self) -> "Camera":
        """The same camera without principal-point offset and distortion (the nominal camera)."""
        return dataclasses.replace(self, ppx_mm=0.0, ppy_mm=0.0, **{c: 0.0 for c in self.COEFFICIENTS})

    def with_pixels(self, width: int, height: int) -> "Camera":
        """Keep the field of view and sensor size, change the pixel count (pixel size follows)."""
        sw, _ = self.sensor_mm
        return dataclasses.replace(self, width=int(width), height=int(height), pixel_um=sw * 1000.0 / width)

    # -- the model: kernel parameters, adjustment calibration, exports --------------------------
    def kernel_params(self) -> tuple:
        """The parameter tuple the compiled kernels take (``aerotri.geom.lens_kernels``: f, cx, cy in
        pixels, then the lens coefficients)."""
        raise NotImplementedError

    def calibration_vector(self) -> np.ndarray:
        """The adjustment's calibration (Cal3DS2 ``fx fy s u0 v0 k1 k2 p1 p2``, pixels) of this camera."""
        raise NotImplementedError

    def from_calibration_vector(self, cal) -> "Camera":
        """This camera with the interior orientation of Cal3DS2 values (fx and fy averaged into the focal
        length); what Cal3DS2 does not hold stays as it is."""
        raise NotImplementedError

    def calibration_observations(self, xy_px: np.ndarray) -> np.ndarray:
        """Image measurements (K, 2) as the camera of ``calibration_vector`` sees the same rays (the
        measurements themselves for a model that Cal3DS2 holds entirely)."""
        return xy_px

    def calibration_camera(self, cal) -> "Camera":
        """The camera that Cal3DS2 values describe exactly, the one that sees ``calibration_observations``
        (this model with the parameters Cal3DS2 lacks set to zero)."""
        return self.from_calibration_vector(cal)

    def colmap_model(self) -> tuple[str, list[float]]:
        """COLMAP camera model name and its PARAMS (COLMAP's pixel origin: the corner of the top-left
        pixel, so the principal point is shifted by +0.5)."""
        raise NotImplementedError

    def _calibration_geometry(self, cal) -> dict:
        f_px = 0.5 * (cal[0] + cal[1])
        pix_mm = self.pixel_um / 1000.0
        return dict(focal_mm=float(f_px * pix_mm), ppx_mm=float((cal[3] - (self.width - 1) / 2.0) * pix_mm),
                    ppy_mm=float(-(cal[4] - (self.height - 1) / 2.0) * pix_mm))

    # -- distortion ---------------------------------------------------------------------------
    def distort(self, xn, yn):
        """Apply lens distortion to normalised coordinates (arrays); returns (xd, yd)."""
        shape, xn, yn = _flat(xn, yn)
        xd, yd = lens_kernels.distort_points(self.kernel_params(), xn, yn)
        return xd.reshape(shape), yd.reshape(shape)

    def undistort(self, xd, yd, iterations: int = UNDISTORT_ITERATIONS):
        """Invert ``distort`` by fixed-point iteration (converges for photogrammetric lenses)."""
        shape, xd, yd = _flat(xd, yd)
        if not any(self.coefficients):
            return xd.reshape(shape).copy(), yd.reshape(shape).copy()
        xn, yn = lens_kernels.undistort_points(self.kernel_params(), xd, yd, int(iterations))
        return xn.reshape(shape), yn.reshape(shape)

    def distort_jacobian(self, xn, yn) -> np.ndarray:
        """d(xd, yd) / d(xn, yn) (..., 2, 2) at normalised coordinates."""
        shape, xn, yn = _flat(xn, yn)
        return lens_kernels.distort_jacobian_points(self.kernel_params(), xn, yn).reshape(shape + (2, 2))

    def coefficient_jacobian(self, xn, yn) -> np.ndarray:
        """d(xd, yd) / d(lens coefficients in ``COEFFICIENTS`` order) (..., 2, n) at normalised coordinates."""
        shape, xn, yn = _flat(xn, yn)
        n = len(self.COEFFICIENTS)
        return lens_kernels.coefficient_jacobian_points(self.kernel_params(), xn, yn, n).reshape(shape + (2, n))

    def normalized_to_pixel(self, xn, yn):
        xd, yd = self.distort(xn, yn)
        f = self.focal_px
        return f * xd + self.cx_px, f * yd + self.cy_px

    def pixel_to_normalized(self, x_px, y_px):
        f = self.focal_px
        xd = (_as_array(x_px) - self.cx_px) / f
        yd = (_as_array(y_px) - self.cy_px) / f
        return self.undistort(xd, yd)

    # -- collinearity -------------------------------------------------------------------------
    def project(self, points_m, centre_m, R):
        """Object points (N, 3) into pixels of a frame with centre C (3,) and rotation R (3, 3).

        Returns (x_px, y_px, depth_m); depth is the distance along the viewing axis, positive in
        front of the camera. Points behind the camera, or beyond the fold of the lens model
        (``fold_radius``: where it would put them inside the frame, far from where they are), get NaN pixel
        coordinates.
        """
        P = np.atleast_2d(_as_array(points_m)) - _as_array(centre_m)
        d = P @ (_as_array(R) @ FLIP_YZ)  # computer-vision camera coordinates
        depth = d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = np.where(depth > 0, d[:, 0] / depth, np.nan)
            yn = np.where(depth > 0, d[:, 1] / depth, np.nan)
        fold = self.fold_radius()
        if fold is not None:
            with np.errstate(invalid="ignore"):
                beyond = xn * xn + yn * yn > fold * fold
            xn, yn = np.where(beyond, np.nan, xn), np.where(beyond, np.nan, yn)
        x_px, y_px = self.normalized_to_pixel(xn, yn)
        return x_px, y_px, depth

    def rays(self, x_px, y_px, R):
        """Unit viewing directions in object space (N, 3) for pixel coordinates of a frame with rotation R."""
        xn, yn = self.pixel_to_normalized(x_px, y_px)
        d_cv = np.stack([xn, yn, np.ones_like(xn)], axis=-1)
        d = d_cv @ (_as_array(R) @ FLIP_YZ).T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def inside(self, x_px, y_px, margin_px: float = 0.0):
        return inside_frame(x_px, y_px, self.width, self.height, margin_px)

    # -- validation and files -----------------------------------------------------------------
    @classmethod
    def fields(cls) -> tuple[str, ...]:
        """The numeric keys of this model's camera files."""
        return _GEOMETRY + cls.COEFFICIENTS

    def validate(self, source: str = "camera"):
        for f in ("focal_mm", "pixel_um", "width", "height"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"{source}: {f} must be a positive number, got {v!r}")
        if self.focal_mm > 1000.0:
            raise InputError(
                f"{source}: focal_mm = {self.focal_mm} is not a plausible focal length in millimetres "
                f"(did you give it in pixels? {self.focal_mm} px x {self.pixel_um} um = "
                f"{self.focal_mm * self.pixel_um / 1000:.3f} mm)"
            )
        if self.pixel_um > 1000.0 or self.pixel_um < 0.5:
            raise InputError(f"{source}: pixel_um = {self.pixel_um} is not a plausible pixel size in micrometres")
        for f in ("ppx_mm", "ppy_mm") + self.COEFFICIENTS:
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise InputError(f"{source}: {f} must be a finite number, got {v!r}")

    # Widest lens a camera file may hold: focal length >= this share of the longer image side (a field of view of
    # 157 deg across it); the Brown model's widest real cameras (action cameras) are near 0.45.
    MIN_FOCAL_PER_SIDE: ClassVar[float] = 0.1
    # Narrowest: at most this many times the longer side (a 0.57 deg field of view; a 600 mm lens on an APS-C back,
    # 23.5 mm wide, is 25.5, which 20 refused). A focal length in mm read as one normalised by the image width was
    # 120 x the width, one in other units is >= 100 x off
    MAX_FOCAL_PER_SIDE: ClassVar[float] = 100.0
    # The principal point at most this share of the image side from the centre: real cameras are near 0 (the shared
    # data and the demo: DJI FC6310R 0.15 / 0.48 %, DMC and the demo truth under 0.1 %); a corner's pixel position
    # in a centre-offset field (Metashape cx, cy = 864, 480 on 1728 x 960) is 50 %, COLMAP's cx, cy = 0, 0 likewise
    PP_MAX_SIDE_FRACTION: ClassVar[float] = 0.25

    def check_plausible(self, source: str = "camera", fields: "CameraFileFields | None" = None):
        """Refuse (``InputError``) a camera read from a file whose numbers are in other units than its keys':
        a focal length of a tenth of the longer image side or less (in metres, 0.12 for 120 mm: the adjustment
        stopped on a singular matrix) or over ``MAX_FOCAL_PER_SIDE`` times it, and a principal point over
        ``PP_MAX_SIDE_FRACTION`` of the side from the image centre (in pixels, or a corner's position), and lens
        coefficients whose model turns back inside the frame (a certificate's mm-based or table values typed as
        the normalised coefficients: the adjustment ended on a singular matrix). ``fields``:
        how another program's file names these numbers, for the message (None: camera.toml's keys). Only for
        cameras read from files: self-calibration's intermediate cameras are not held to it."""
        side_px = max(self.width, self.height)
        focal_name = f"focal_mm = {self.focal_mm:g}"
        if fields:
            focal_name = f"{fields.focal} ({focal_name})"
        format_hint = f" ({fields.focal_hint})" if fields and fields.focal_hint else ""
        if self.focal_px < self.MIN_FOCAL_PER_SIDE * side_px:
            fov_deg = 2.0 * math.degrees(math.atan(side_px / 2.0 / self.focal_px))
            hint = format_hint
            if self.focal_px * 1000.0 >= self.MIN_FOCAL_PER_SIDE * side_px and self.focal_mm * 1000.0 <= 1000.0:
                hint = f"; in metres? {self.focal_mm:g} m = {self.focal_mm * 1000.0:g} mm{format_hint}"
            raise InputError(f"{source}: {focal_name} is {self.focal_px:.4g} px at pixel_um = {self.pixel_um:g}: a "
                             f"field of view of {fov_deg:.1f} deg across the {side_px} px side, expected a focal "
                             f"length of at least {self.MIN_FOCAL_PER_SIDE:g} x that side{hint}")
        if self.focal_px > self.MAX_FOCAL_PER_SIDE * side_px:
            fov_deg = 2.0 * math.degrees(math.atan(side_px / 2.0 / self.focal_px))
            hint = f" (a pixel size or focal length in other units?{';' + format_hint[1:-1] if format_hint else ''})"
            raise InputError(f"{source}: {focal_name} is {self.focal_px:.6g} px at pixel_um = {self.pixel_um:g}: a "
                             f"field of view of {fov_deg:.2g} deg across the {side_px} px side, expected a focal "
                             f"length of at most {self.MAX_FOCAL_PER_SIDE:g} x that side{hint}")
        off_px = (self.cx_px - (self.width - 1) / 2.0, self.cy_px - (self.height - 1) / 2.0)
        share = (abs(off_px[0]) / self.width, abs(off_px[1]) / self.height)
        if max(share) > self.PP_MAX_SIDE_FRACTION:
            limit = f"{100 * self.PP_MAX_SIDE_FRACTION:g} %"
            if fields:
                raise InputError(f"{source}: {fields.pp} put the principal point {off_px[0]:+.1f} / "
                                 f"{off_px[1]:+.1f} px "
                                 f"(x right / y down) from the image centre, {100 * share[0]:.0f} / "
                                 f"{100 * share[1]:.0f} % of the {self.width} x {self.height} px frame (limit {limit}; "
                                 f"a real camera's is near 0): {fields.pp_hint}")
            a = 0 if share[0] >= share[1] else 1
            key, size_px = (("ppx_mm", self.width), ("ppy_mm", self.height))[a]
            raise InputError(f"{source}: {key} = {getattr(self, key):g} puts the principal point "
                             f"{100 * share[a]:.0f} % of the {size_px} px side from the image centre (limit {limit}, "
                             f"{self.PP_MAX_SIDE_FRACTION * size_px * self.pixel_um / 1000.0:g} mm); expected the "
                             f"offset from the image centre in mm (in pixels? x {self.pixel_um / 1000.0:g} mm/px)")

        folds = _fold_inside_frame(self) if any(self.coefficients) else None
        if folds is not None:
            lens = ", ".join(f"{c} = {v:g}" for c, v in zip(self.COEFFICIENTS, self.coefficients) if v)
            raise InputError(f"{source}: the lens coefficients ({lens}) make the lens model turn back "
                             f"{folds[0]:.1f} deg off the axis, inside the frame (its corner {folds[1]:.1f} deg): "
                             "expected coefficients on normalised image coordinates (x / f): a certificate's K1, K2 "
                             "on r in mm are k1 = K1 x f_mm^2, k2 = K2 x f_mm^4; a radial distortion table (um "
                             "against mm) is fitted first (docs/your-own-block.md)")

    def to_dict(self) -> dict:
        """The camera file's keys: ``name``, ``model`` and the model's fields."""
        return {"name": self.name, "model": self.MODEL} | {f: getattr(self, f) for f in self.fields()}

    def to_toml(self) -> str:
        lines = [
            "# Frame camera interior orientation. Pixel origin: centre of the top-left pixel, x right, y down.",
            "# Principal point offset from the image centre in photo coordinates (x right, y up), mm.",
            f"# {self._toml_comment()}",
        ]
        for k, v in self.to_dict().items():
            if isinstance(v, str):
                lines.append(f'{k} = "{v}"')
            else:
                lines.append(f"{k} = {v if isinstance(v, int) else repr(float(v))}")
        return "\n".join(lines) + "\n"

    @classmethod
    def _toml_comment(cls) -> str:
        return f"Lens model {cls.MODEL!r}."

    @classmethod
    def from_dict(cls, d: dict, source: str = "camera", *, plausible: bool = True) -> "Camera":
        """The camera of a camera file's keys; its ``model`` key (absent: ``brown``) picks the class in
        ``MODELS``, whichever class this is called on. ``plausible=False``: not held to ``check_plausible``
        (a camera read only to compare it with one recorded before, e.g. the frame orthos' staleness check:
        its lens fold search loads the compiled lens kernels, 0.7 CPU-s, a sixth of the demo's mosaic)."""
        model = d.get("model", DEFAULT_MODEL)
        if model not in MODELS:
            raise InputError(f"{source}: model = {model!r} is not one of {sorted(MODELS)}")
        sub = MODELS[model]
        fields = sub.fields()
        missing = [f for f in ("focal_mm", "pixel_um", "width", "height") if f not in d]
        if missing:
            raise InputError(f"{source}: missing {', '.join(missing)} (expected focal_mm, pixel_um, width, height)")
        unknown = sorted(set(d) - set(fields) - {"name", "model"})
        if unknown:
            raise InputError(f"{source}: unknown keys {unknown} for model {model!r}; expected {list(fields)}")
        kwargs = {}
        for f in fields:
            if f in d:
                v = d[f]
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise InputError(f"{source}: {f} must be a number, got {v!r}")
                kwargs[f] = int(v) if f in ("width", "height") else float(v)
        cam = sub.__new__(sub)
        object.__setattr__(cam, "name", str(d.get("name", "camera")))
        for f in fields:
            object.__setattr__(cam, f, kwargs.get(f, 0.0))
        cam.validate(source)
        if plausible:
            cam.check_plausible(source)
        return cam

    @classmethod
    def read(cls, path, *, plausible: bool = True) -> "Camera":
        """A camera file (TOML); its ``model`` key picks the class (see ``from_dict``)."""
        from aerotri.core.textio import read_text

        path = Path(path)
        try:
            # (trial s94: a project whose frames' EXIF holds no camera stopped `match` on "file not found" alone)
            d = tomllib.loads(read_text(path, "camera file (TOML)", hint=(
                "write it with the calibrated camera: aerotri init printed a template, docs/project.md#cameratoml; "
                "or bring it with the orientations: aerotri import --format orthority|patb|colmap|opensfm|metashape")
                if path.name == "camera.toml" and path.parent.name != "at" else ""))
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"{path}: not valid TOML ({exc})") from None
        return cls.from_dict(d, source=str(path), plausible=plausible)


@dataclasses.dataclass(frozen=True)
class BrownCamera(Camera):
    """Frame camera with Brown's lens distortion: radial k1 k2 k3, tangential (decentring) p1 p2.

    Kernel parameters ``lens_kernels.BrownParams(f, cx, cy, k1, k2, k3, p1, p2)``. In the adjustment k1 k2
    p1 p2 are Cal3DS2's; k3 (not in Cal3DS2) is held fixed by taking its effect off the measurements
    (``calibration_observations``)."""

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    MODEL: ClassVar[str] = "brown"
    COEFFICIENTS: ClassVar[tuple[str, ...]] = ("k1", "k2", "k3", "p1", "p2")
    SELF_CAL_GROUPS: ClassVar[dict[str, tuple[int, ...]]] = {"focal": (0, 1), "pp": (3, 4), "radial": (5, 6),
                                                             "tangential": (7, 8)}

    def kernel_params(self) -> lens_kernels.BrownParams:
        return lens_kernels.BrownParams(float(self.focal_px), float(self.cx_px), float(self.cy_px), *self.coefficients)

    def distortion(self) -> np.ndarray:
        """OpenCV order: k1, k2, p1, p2, k3."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    def calibration_vector(self) -> np.ndarray:
        f = self.focal_px
        return np.array([f, f, 0.0, self.cx_px, self.cy_px, self.k1, self.k2, self.p1, self.p2])

    def from_calibration_vector(self, cal) -> "BrownCamera":
        return dataclasses.replace(self, **self._calibration_geometry(cal), k1=float(cal[5]), k2=float(cal[6]),
                                   p1=float(cal[7]), p2=float(cal[8]))

    def calibration_observations(self, xy_px: np.ndarray) -> np.ndarray:
        """Image measurements as the same camera without k3 sees the same rays.

        The adjustment's camera model (Cal3DS2) has k1 k2 p1 p2 only; a known k3 (held fixed) is taken
        off the measurements instead: x' = x - f xn k3 r^6 (likewise y), with (xn, yn) the normalised ray
        of the measurement. Exact for a fixed camera; with self-calibrated k1, k2 the ray moves by second
        order only.
        """
        if not self.k3 or not len(xy_px):
            return xy_px
        xn, yn = self.pixel_to_normalized(xy_px[:, 0], xy_px[:, 1])
        t = self.k3 * (xn * xn + yn * yn) ** 3
        return xy_px - self.focal_px * np.column_stack([xn * t, yn * t])

    def calibration_camera(self, cal) -> "BrownCamera":
        return dataclasses.replace(self.from_calibration_vector(cal), k3=0.0)

    def colmap_model(self) -> tuple[str, list[float]]:
        """OPENCV (fx fy cx cy k1 k2 p1 p2), FULL_OPENCV (... k3 k4 k5 k6) when k3 is not zero."""
        f = self.focal_px
        params = [f, f, self.cx_px + 0.5, self.cy_px + 0.5, self.k1, self.k2, self.p1, self.p2]
        if self.k3:
            return "FULL_OPENCV", params + [self.k3, 0.0, 0.0, 0.0]
        return "OPENCV", params

    @classmethod
    def _toml_comment(cls) -> str:
        return "Distortion: Brown model on normalised coordinates (OpenCV/COLMAP/GTSAM Cal3DS2 convention)."


@dataclasses.dataclass(frozen=True)
class PinholeCamera(Camera):
    """Frame camera without lens distortion (kernel parameters ``lens_kernels.PinholeParams(f, cx, cy)``);
    in the adjustment a Cal3DS2 with its distortion held at zero."""

    MODEL: ClassVar[str] = "pinhole"

    def kernel_params(self) -> lens_kernels.PinholeParams:
        return lens_kernels.PinholeParams(float(self.focal_px), float(self.cx_px), float(self.cy_px))

    def calibration_vector(self) -> np.ndarray:
        f = self.focal_px
        return np.array([f, f, 0.0, self.cx_px, self.cy_px, 0.0, 0.0, 0.0, 0.0])

    def from_calibration_vector(self, cal) -> "PinholeCamera":
        return dataclasses.replace(self, **self._calibration_geometry(cal))

    def colmap_model(self) -> tuple[str, list[float]]:
        """PINHOLE (fx fy cx cy)."""
        f = self.focal_px
        return "PINHOLE", [f, f, self.cx_px + 0.5, self.cy_px + 0.5]


# model name (the ``model`` key of camera files) -> class
MODELS: dict[str, type[Camera]] = {"brown": BrownCamera, "pinhole": PinholeCamera}
DEFAULT_MODEL = "brown"  # camera files without a ``model`` key

# every self-calibration group some model offers (choices of the adjustment's ``--self-cal``)
SELF_CALIBRATION_GROUPS: tuple[str, ...] = tuple(dict.fromkeys(g for m in MODELS.values() for g in m.SELF_CAL_GROUPS))


def read_camera(path) -> Camera:
    """The camera of a camera file (TOML), of the class its ``model`` key names."""
    return Camera.read(path)


def dmc_camera() -> BrownCamera:
    """The nominal Z/I DMC: f = 120 mm, 12 um pixels, 13824 x 7680 px (long side across track)."""
    return BrownCamera(focal_mm=120.0, pixel_um=12.0, width=13824, height=7680, name="DMC")


def project_camera(project, *, plausible: bool = True) -> Camera:
    """The nominal camera of a project folder (``camera.toml``); ``plausible``: see ``Camera.from_dict``."""
    return Camera.read(project.camera_path, plausible=plausible)


def oriented_camera(project, *, plausible: bool = True) -> tuple[Camera, str]:
    """(camera, source): the camera the project's adjusted orientations (``at/eo.txt``) belong to:
    ``at/camera.toml``, which the adjustment writes beside them (self-calibrated, or the nominal camera it held
    fixed), else the nominal ``camera.toml`` (no adjustment yet). The source says "self-calibrated" when the
    adjustment's camera differs from the nominal one."""
    path = project.adjusted_camera_path
    if not path.is_file():
        if project.eo_path.is_file() and project.adjustment_report_path.is_file():
            # adjusted by a version that wrote no camera file: the nominal camera may not be the one of eo.txt
            raise StageOrderError(f"{project.eo_path}: no {path.name} beside it (the camera its orientations belong "
                                  f"to; written by aerotri adjust since 0.1): adjust again (aerotri adjust "
                                  f"{project.root})")
        return project_camera(project, plausible=plausible), str(project.camera_path)
    camera = Camera.read(path, plausible=plausible)
    nominal = project_camera(project, plausible=plausible) if project.camera_path.is_file() else None
    if nominal is not None and camera.to_dict() == nominal.to_dict():
        return camera, str(path)
    return camera, f"{path} (self-calibrated)"


def orientations_camera(project, eo_path=None, camera_path=None, *, plausible: bool = True) -> tuple[Camera, str]:
    """(camera, source) to project with the orientations of ``eo_path``: ``camera_path`` when given; for the
    project's own adjusted orientations (``eo_path`` None or ``at/eo.txt`` itself) the camera they belong to
    (``oriented_camera``: at/camera.toml); for other orientations (an EO file given with --eo: a truth, an
    import, another adjustment) the nominal ``camera.toml``, as at/camera.toml's self-calibration was
    estimated with at/eo.txt and belongs to no other orientations. ``project`` may be None with a ``camera_path``.
    ``plausible``: see ``Camera.from_dict``."""
    if camera_path is not None:
        return Camera.read(camera_path, plausible=plausible), str(camera_path)
    if eo_path is None or Path(eo_path).resolve() == project.eo_path.resolve():
        return oriented_camera(project, plausible=plausible)
    return project_camera(project, plausible=plausible), str(project.camera_path)
