"""Frame rendering by ray casting, radiometry (exposure, vignetting, noise) and visibility.

Each pixel is the mean of ``samples x samples`` rays through the true camera (principal-point
offset and lens distortion included), so relief displacement, occlusion and distortion in the
images are real and the truth image coordinates follow from the collinearity equations alone.
"""

from __future__ import annotations

import numpy as np

from aerotri.geom.camera import Camera
from aerotri.geom.rotation import FLIP_YZ
from aerotri.sim import raycast
from aerotri.sim.scene import Scene

SUN = raycast.SUN


def tone_map(radiance: np.ndarray) -> np.ndarray:
    """Linear radiance (0..~1) to 8-bit display values (gamma 2.2)."""
    return 255.0 * np.clip(1.25 * radiance, 0.0, 1.0) ** (1.0 / 2.2)


class PixelRays:
    """Viewing directions of every pixel sample in the camera frame (computer-vision axes).

    They depend on the interior orientation only, so a block computes them once and rotates them
    per frame. Large frames are computed per block of rows instead of cached.
    """

    def __init__(self, camera: Camera, samples: int = 1, cache_limit: int = 12_000_000):
        self.camera = camera
        self.samples = samples
        self.offsets = (np.arange(samples) + 0.5) / samples - 0.5
        self._cache = {}
        self.cache = camera.width * camera.height * samples * samples <= cache_limit

    def block(self, r0: int, r1: int, ox: float, oy: float) -> np.ndarray:
        key = (r0, r1, ox, oy)
        if key in self._cache:
            return self._cache[key]
        rows = np.arange(r0, r1, dtype=np.float64) + oy
        cols = np.arange(self.camera.width, dtype=np.float64) + ox
        yy, xx = np.meshgrid(rows, cols, indexing="ij")
        xn, yn = self.camera.pixel_to_normalized(xx.ravel(), yy.ravel())
        d = np.stack([xn, yn, np.ones_like(xn)], axis=1)
        if self.cache:
            self._cache[key] = d
        return d


def render_frame(scene: Scene, accel, camera: Camera, centre_m, R, *, samples: int = 2,
                 rows_per_block: int = 256, with_ids: bool = False, pixel_rays: PixelRays | None = None):
    """Radiance image (H, W, 3) float32 of one frame, and optionally the surface id of each pixel centre: a ray per
    pixel sample in the flat world (scene coordinates as a Cartesian frame; the reference of the rasteriser's
    flat mode in the tests; the simulated projects' frames are rendered on the earth, ``aerotri.sim.earth``)."""
    W, H = camera.width, camera.height
    pr = pixel_rays if pixel_rays is not None else PixelRays(camera, samples)
    M = (np.asarray(R, dtype=np.float64) @ FLIP_YZ).T  # camera (cv) -> object, applied to row vectors
    out = np.empty((H, W, 3), np.float32)
    ids = np.empty((H, W), np.int64) if with_ids else None
    origin = np.asarray(centre_m, dtype=np.float64)[None, :]
    for r0 in range(0, H, rows_per_block):
        r1 = min(H, r0 + rows_per_block)
        acc = np.zeros((r1 - r0, W, 3), np.float32)
        for oy in pr.offsets:
            for ox in pr.offsets:
                d = np.ascontiguousarray(pr.block(r0, r1, ox, oy) @ M)
                rad, _ = raycast.render_rays(origin, d, accel, roads=scene.roads, ponds=scene.ponds,
                                             targets=scene.targets, roof_albedo=scene.roof_albedo, seed=scene.seed,
                                             sun=SUN)
                acc += rad.reshape(r1 - r0, W, 3)
        out[r0:r1] = acc / (pr.samples * pr.samples)
        if with_ids:
            rows = np.arange(r0, r1, dtype=np.float64)
            yy, xx = np.meshgrid(rows, np.arange(W, dtype=np.float64), indexing="ij")
            d = camera.rays(xx.ravel(), yy.ravel(), R)
            _, idb = raycast.render_rays(origin, np.ascontiguousarray(d), accel, roads=scene.roads, ponds=scene.ponds,
                                         targets=scene.targets, roof_albedo=scene.roof_albedo, seed=scene.seed, sun=SUN)
            ids[r0:r1] = idb.reshape(r1 - r0, W)
    return out, ids


def expose(radiance: np.ndarray, camera: Camera, gain: float, vignetting: float, noise_dn: float, rng) -> np.ndarray:
    """Per-frame exposure gain, radial vignetting (fraction lost at the corner) and sensor noise -> uint8 RGB."""
    H, W = radiance.shape[:2]
    y, x = np.mgrid[0:H, 0:W]
    r2 = ((x - (W - 1) / 2) ** 2 + (y - (H - 1) / 2) ** 2) / (((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2)
    vig = (1.0 - vignetting * r2).astype(np.float32)
    dn = tone_map(radiance * (gain * vig)[..., None])
    dn = dn + rng.normal(0.0, noise_dn, dn.shape)
    return np.clip(np.rint(dn), 0, 255).astype(np.uint8)


def vertical_render(scene: Scene, accel, x_m: np.ndarray, y_m: np.ndarray):
    """Surface height, radiance and surface id seen straight down at local (x, y) (true ortho, DSM)."""
    n = x_m.size
    top = accel[-1] + 10.0
    origins = np.empty((n, 3))
    origins[:, 0] = x_m.ravel()
    origins[:, 1] = y_m.ravel()
    origins[:, 2] = top
    dirs = np.zeros((n, 3))
    dirs[:, 2] = -1.0
    rad, ids = raycast.render_rays(origins, dirs, accel, roads=scene.roads, ponds=scene.ponds, targets=scene.targets,
                                   roof_albedo=scene.roof_albedo, seed=scene.seed, sun=SUN)
    t, kind, _, _ = raycast.cast_many(origins, dirs, accel, True)
    z = np.where(np.isfinite(t), top - t, np.nan)
    return z.reshape(x_m.shape), rad.reshape(x_m.shape + (3,)), ids.reshape(x_m.shape)


def visible(accel, centre_m, points_m, tol_m: float = 0.05) -> np.ndarray:
    """True where the straight line from the projection centre to each point is not blocked."""
    P = np.atleast_2d(points_m).astype(np.float64)
    d = P - np.asarray(centre_m, dtype=np.float64)
    dist = np.linalg.norm(d, axis=1)
    origins = np.repeat(np.asarray(centre_m, dtype=np.float64)[None, :], len(P), axis=0)
    t, kind, _, _ = raycast.cast_many(origins, np.ascontiguousarray(d / dist[:, None]), accel, True)
    return t >= dist - tol_m
