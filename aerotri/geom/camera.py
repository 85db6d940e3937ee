"""Frame camera interior orientation and the collinearity equations.

Conventions (see docs in README):

- Pixel coordinates ``x_px`` (column) and ``y_px`` (row) have their origin at the centre of the
  top-left pixel, x right, y down. The image centre is at ((width-1)/2, (height-1)/2).
- The principal point offset ``ppx_mm``, ``ppy_mm`` is measured from the image centre in photo
  coordinates (x right, y up), in millimetres.
- Lens distortion is the Brown model on normalised coordinates (x/z, y/z in the computer-vision
  camera frame, dimensionless), as in OpenCV, COLMAP and GTSAM's Cal3DS2:
  ``r2 = xn^2 + yn^2``, ``xd = xn (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 xn yn + p2 (r2 + 2 xn^2)``,
  ``yd = yn (1 + ...) + p1 (r2 + 2 yn^2) + 2 p2 xn yn``.
- Exterior orientation: projection centre C (object metres) and R = rotation_matrix_opk(omega, phi,
  kappa) from camera to object (see aerotri.geom.rotation).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.geom.rotation import FLIP_YZ

_FIELDS = ("focal_mm", "pixel_um", "width", "height", "ppx_mm", "ppy_mm", "k1", "k2", "k3", "p1", "p2")


@dataclasses.dataclass(frozen=True)
class FrameCamera:
    """Interior orientation of a frame camera (units in the field names)."""

    focal_mm: float
    pixel_um: float
    width: int
    height: int
    ppx_mm: float = 0.0
    ppy_mm: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    name: str = "camera"

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

    def gsd_m(self, height_above_ground_m: float) -> float:
        """Ground sample distance of a nadir frame at the given flying height above ground."""
        return height_above_ground_m * self.pixel_um * 1e-6 / (self.focal_mm * 1e-3)

    def K(self) -> np.ndarray:
        """The 3x3 computer-vision calibration matrix (pixels)."""
        f = self.focal_px
        return np.array([[f, 0.0, self.cx_px], [0.0, f, self.cy_px], [0.0, 0.0, 1.0]])

    def distortion(self) -> np.ndarray:
        """OpenCV order: k1, k2, p1, p2, k3."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    def ideal(self) -> "FrameCamera":
        """The same camera without principal-point offset and distortion (the nominal camera)."""
        return dataclasses.replace(self, ppx_mm=0.0, ppy_mm=0.0, k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0)

    def with_pixels(self, width: int, height: int) -> "FrameCamera":
        """Keep the field of view and sensor size, change the pixel count (pixel size follows)."""
        sw, _ = self.sensor_mm
        return dataclasses.replace(self, width=int(width), height=int(height), pixel_um=sw * 1000.0 / width)

    # -- distortion ---------------------------------------------------------------------------
    def distort(self, xn, yn):
        """Apply lens distortion to normalised coordinates (arrays); returns (xd, yd)."""
        xn = np.asarray(xn, dtype=float)
        yn = np.asarray(yn, dtype=float)
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = xn * radial + 2.0 * self.p1 * xn * yn + self.p2 * (r2 + 2.0 * xn * xn)
        yd = yn * radial + self.p1 * (r2 + 2.0 * yn * yn) + 2.0 * self.p2 * xn * yn
        return xd, yd

    def undistort(self, xd, yd, iterations: int = 20):
        """Invert ``distort`` by fixed-point iteration (converges for photogrammetric lenses)."""
        xd = np.asarray(xd, dtype=float)
        yd = np.asarray(yd, dtype=float)
        xn, yn = xd.copy(), yd.copy()
        if not any((self.k1, self.k2, self.k3, self.p1, self.p2)):
            return xn, yn
        for _ in range(iterations):
            r2 = xn * xn + yn * yn
            radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
            dx = 2.0 * self.p1 * xn * yn + self.p2 * (r2 + 2.0 * xn * xn)
            dy = self.p1 * (r2 + 2.0 * yn * yn) + 2.0 * self.p2 * xn * yn
            xn = (xd - dx) / radial
            yn = (yd - dy) / radial
        return xn, yn

    def normalized_to_pixel(self, xn, yn):
        xd, yd = self.distort(xn, yn)
        f = self.focal_px
        return f * xd + self.cx_px, f * yd + self.cy_px

    def pixel_to_normalized(self, x_px, y_px):
        f = self.focal_px
        xd = (np.asarray(x_px, dtype=float) - self.cx_px) / f
        yd = (np.asarray(y_px, dtype=float) - self.cy_px) / f
        return self.undistort(xd, yd)

    # -- collinearity -------------------------------------------------------------------------
    def project(self, points_m, centre_m, R):
        """Object points (N, 3) into pixels of a frame with centre C (3,) and rotation R (3, 3).

        Returns (x_px, y_px, depth_m); depth is the distance along the viewing axis, positive in
        front of the camera. Points behind the camera get NaN pixel coordinates.
        """
        P = np.atleast_2d(np.asarray(points_m, dtype=float)) - np.asarray(centre_m, dtype=float)
        d = P @ (np.asarray(R, dtype=float) @ FLIP_YZ)  # computer-vision camera coordinates
        depth = d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = np.where(depth > 0, d[:, 0] / depth, np.nan)
            yn = np.where(depth > 0, d[:, 1] / depth, np.nan)
        x_px, y_px = self.normalized_to_pixel(xn, yn)
        return x_px, y_px, depth

    def rays(self, x_px, y_px, R):
        """Unit viewing directions in object space (N, 3) for pixel coordinates of a frame with rotation R."""
        xn, yn = self.pixel_to_normalized(x_px, y_px)
        d_cv = np.stack([xn, yn, np.ones_like(xn)], axis=-1)
        d = d_cv @ (np.asarray(R, dtype=float) @ FLIP_YZ).T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def inside(self, x_px, y_px, margin_px: float = 0.0):
        x_px = np.asarray(x_px)
        y_px = np.asarray(y_px)
        return (
            (x_px >= -0.5 + margin_px)
            & (x_px <= self.width - 0.5 - margin_px)
            & (y_px >= -0.5 + margin_px)
            & (y_px <= self.height - 0.5 - margin_px)
        )

    # -- validation and files -----------------------------------------------------------------
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
        for f in ("ppx_mm", "ppy_mm", "k1", "k2", "k3", "p1", "p2"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise InputError(f"{source}: {f} must be a finite number, got {v!r}")

    def to_dict(self) -> dict:
        return {f: getattr(self, f) for f in ("name",) + _FIELDS}

    def to_toml(self) -> str:
        lines = [
            "# Frame camera interior orientation. Pixel origin: centre of the top-left pixel, x right, y down.",
            "# Principal point offset from the image centre in photo coordinates (x right, y up), mm.",
            "# Distortion: Brown model on normalised coordinates (OpenCV/COLMAP/GTSAM Cal3DS2 convention).",
            f'name = "{self.name}"',
        ]
        for f in _FIELDS:
            v = getattr(self, f)
            lines.append(f"{f} = {v if isinstance(v, int) else repr(float(v))}")
        return "\n".join(lines) + "\n"

    @classmethod
    def from_dict(cls, d: dict, source: str = "camera") -> "FrameCamera":
        missing = [f for f in ("focal_mm", "pixel_um", "width", "height") if f not in d]
        if missing:
            raise InputError(f"{source}: missing {', '.join(missing)} (expected focal_mm, pixel_um, width, height)")
        unknown = sorted(set(d) - set(_FIELDS) - {"name"})
        if unknown:
            raise InputError(f"{source}: unknown keys {unknown}; expected {list(_FIELDS)}")
        kwargs = {}
        for f in _FIELDS:
            if f in d:
                v = d[f]
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise InputError(f"{source}: {f} must be a number, got {v!r}")
                kwargs[f] = int(v) if f in ("width", "height") else float(v)
        cam = cls.__new__(cls)
        object.__setattr__(cam, "name", str(d.get("name", "camera")))
        for f in _FIELDS:
            object.__setattr__(cam, f, kwargs.get(f, 0.0))
        cam.validate(source)
        return cam

    @classmethod
    def read(cls, path) -> "FrameCamera":
        from aerotri.core.textio import read_text

        path = Path(path)
        try:
            d = tomllib.loads(read_text(path, "camera file (TOML)"))
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"{path}: not valid TOML ({exc})") from None
        return cls.from_dict(d, source=str(path))


def dmc_camera() -> FrameCamera:
    """The nominal Z/I DMC: f = 120 mm, 12 um pixels, 13824 x 7680 px (long side across track)."""
    return FrameCamera(focal_mm=120.0, pixel_um=12.0, width=13824, height=7680, name="DMC")


def project_camera(project) -> FrameCamera:
    """The nominal camera of a project folder (``camera.toml``)."""
    return FrameCamera.read(project.camera_path)


def adjusted_camera(project) -> tuple[FrameCamera, str]:
    """(camera, source): the self-calibrated camera of the project's last adjustment (``at/report.json``)
    when there is one, else the nominal ``camera.toml``. Orientations in ``at/eo.txt`` belong to it."""
    from aerotri.core.textio import read_json

    rep = project.adjustment_report_path
    if rep.is_file():
        d = read_json(rep, "adjustment report")
        cam = (d.get("self_calibration") or {}).get("camera") if isinstance(d, dict) else None
        if cam:
            return FrameCamera.from_dict(cam, source=f"{rep} self_calibration.camera"), f"{rep} (self-calibrated)"
    return project_camera(project), str(project.camera_path)


def observations_without_k3(cam: FrameCamera, xy_px: np.ndarray) -> np.ndarray:
    """Image measurements of a camera with radial term k3 as the same camera without k3 sees the same rays.

    The adjustment's camera model (Cal3DS2) has k1 k2 p1 p2 only; a known k3 (held fixed) is taken
    off the measurements instead: x' = x - f xn k3 r^6 (likewise y), with (xn, yn) the normalised ray
    of the measurement. Exact for a fixed camera; with self-calibrated k1, k2 the ray moves by second
    order only.
    """
    if not cam.k3 or not len(xy_px):
        return xy_px
    xn, yn = cam.pixel_to_normalized(xy_px[:, 0], xy_px[:, 1])
    t = cam.k3 * (xn * xn + yn * yn) ** 3
    return xy_px - cam.focal_px * np.column_stack([xn * t, yn * t])
