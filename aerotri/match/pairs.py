"""Candidate image pairs from the flight plan: strips, approximate orientations, predicted footprints.

Before any matching the frames' exterior orientation is approximated from GNSS: centre = antenna
minus the lever arm, omega = phi = 0, kappa from the strip direction with the top of the image
facing forward (``image_top_deg`` turns that, e.g. 180 for cameras mounted backwards). Footprints are
the image corners intersected with a horizontal plane at the mean terrain height. Pairs are frames
whose footprints overlap: neighbours along a strip, second neighbours (triple overlap) and frames of
adjacent strips. No exhaustive matching.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import shapely
from shapely.geometry import Polygon

from aerotri.geom.strips import strips_from_track
from aerotri.geom.camera import BrownCamera
from aerotri.core.errors import InputError
from aerotri.geom.rotation import rotation_matrix_opk


def flat_ground_xy(centre_m: np.ndarray, kappa_deg: float, terrain_height_m: float, camera: BrownCamera,
                   xy_px: np.ndarray) -> np.ndarray:
    """Ground (x, y) in metres of image points of a frame at ``centre_m`` with nominal attitude
    (omega = phi = 0, ``kappa_deg``) over flat terrain at ``terrain_height_m``."""
    d = camera.rays(xy_px[:, 0], xy_px[:, 1], rotation_matrix_opk(0.0, 0.0, kappa_deg))
    t = (terrain_height_m - centre_m[2]) / d[:, 2]
    return centre_m[:2] + d[:, :2] * t[:, None]


@dataclasses.dataclass
class BlockPlan:
    image_id: list[str]
    strip: np.ndarray  # (N,) 0-based strip index
    centre_m: np.ndarray  # (N, 3) approximate projection centres
    kappa_deg: np.ndarray  # (N,)
    terrain_height_m: float
    footprints: list[Polygon]
    image_top_deg: float = 0.0

    def rotation(self, i: int) -> np.ndarray:
        return rotation_matrix_opk(0.0, 0.0, self.kappa_deg[i])

    def ground_xy(self, i: int, camera: BrownCamera, xy_px: np.ndarray) -> np.ndarray:
        """Approximate ground coordinates of image points of frame i (flat terrain)."""
        return flat_ground_xy(self.centre_m[i], self.kappa_deg[i], self.terrain_height_m, camera, xy_px)


    def guide(self, i: int, j: int, margin: float) -> "PairGuide":
        """What guided matching of frames i and j needs (small, sent with the pair's task)."""
        fp = [self.footprints[k].buffer(margin * np.sqrt(self.footprints[k].area)) for k in (i, j)]
        return PairGuide(self.centre_m[[i, j]], self.kappa_deg[[i, j]], self.terrain_height_m, fp[0], fp[1])


@dataclasses.dataclass
class PairGuide:
    """Guided matching of one frame pair from the flight plan: a keypoint is compared only when its
    predicted ground position (nominal attitude, flat terrain) lies inside the other frame's footprint
    grown by the plan's margin (a share of the footprint's size that covers attitude, crab and relief)."""

    centre_m: np.ndarray  # (2, 3) approximate projection centres of the two frames
    kappa_deg: np.ndarray  # (2,)
    terrain_height_m: float
    footprint_a: Polygon  # grown
    footprint_b: Polygon

    def _ground_xy(self, k: int, camera: BrownCamera, xy_px: np.ndarray) -> np.ndarray:
        return flat_ground_xy(self.centre_m[k], self.kappa_deg[k], self.terrain_height_m, camera, xy_px)

    def in_overlap(self, camera: BrownCamera, xy_a_px: np.ndarray, xy_b_px: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Masks of the keypoints of frame a (b) predicted inside the grown footprint of frame b (a)."""
        ga = self._ground_xy(0, camera, xy_a_px)
        gb = self._ground_xy(1, camera, xy_b_px)
        return (shapely.contains_xy(self.footprint_b, ga[:, 0], ga[:, 1]),
                shapely.contains_xy(self.footprint_a, gb[:, 0], gb[:, 1]))


def image_top_from_sensor(camera: BrownCamera) -> float:
    """The image top's direction from the flight direction (degrees) that puts the sensor's long side across
    track, as large-format frame cameras fly (DMC, UltraCam): 0 for a landscape frame, 90 for a portrait one
    (a frame turned by +-90 degrees has the same footprint either way)."""
    return 90.0 if camera.height > camera.width else 0.0


def plan_block(image_id, antenna_m, camera: BrownCamera, lever_arm_m, terrain_height_m: float,
               image_top_deg: float | None = None) -> BlockPlan:
    """The flight plan of GNSS-positioned frames; ``image_top_deg`` None: ``image_top_from_sensor``."""
    if image_top_deg is None:
        image_top_deg = image_top_from_sensor(camera)
    antenna_m = np.asarray(antenna_m, dtype=float)
    strip = strips_from_track(antenna_m)
    kappa = np.zeros(len(image_id))
    for s in np.unique(strip):
        idx = np.flatnonzero(strip == s)
        if len(idx) > 1:
            d = antenna_m[idx[-1], :2] - antenna_m[idx[0], :2]
        else:  # a single frame: take the direction of the previous strip, or north
            d = np.array([0.0, 1.0])
        kappa[idx] = np.degrees(np.arctan2(-d[0], d[1])) + image_top_deg
    R = rotation_matrix_opk(np.zeros_like(kappa), np.zeros_like(kappa), kappa)
    centre = antenna_m - np.einsum("nij,j->ni", R, np.asarray(lever_arm_m, dtype=float))
    if np.any(centre[:, 2] <= terrain_height_m + 1.0):
        bad = image_id[int(np.argmin(centre[:, 2]))]
        raise InputError(f"frame {bad}: camera at {centre[:, 2].min():.1f} m is not above the terrain height "
                         f"{terrain_height_m:.1f} m (check gnss.txt heights and the terrain height)")
    W, H = camera.width, camera.height
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    plan = BlockPlan(list(image_id), strip, centre, kappa, float(terrain_height_m), [], float(image_top_deg))
    for i in range(len(image_id)):
        plan.footprints.append(Polygon(plan.ground_xy(i, camera, corners)))
    return plan


@dataclasses.dataclass
class Pair:
    i: int
    j: int
    kind: str  # along | second | cross | extra
    overlap: float  # overlap area / smaller footprint area


def candidate_pairs(plan: BlockPlan, min_overlap: float = 0.15, grow: float = 0.1) -> list[Pair]:
    """Pairs of frames whose (slightly grown) footprints overlap by at least ``min_overlap``."""
    fps = [fp.buffer(grow * np.sqrt(fp.area)) for fp in plan.footprints]
    pairs = []
    n = len(fps)
    # Bounding-box prefilter keeps this O(N log N)-like for thousands of frames.
    bounds = np.array([fp.bounds for fp in fps])
    order = np.argsort(bounds[:, 0])
    for a_pos, i in enumerate(order):
        for j in order[a_pos + 1:]:
            if bounds[j, 0] > bounds[i, 2]:
                break
            if bounds[j, 1] > bounds[i, 3] or bounds[j, 3] < bounds[i, 1]:
                continue
            inter = fps[i].intersection(fps[j]).area
            ov = inter / min(fps[i].area, fps[j].area)
            if ov < min_overlap:
                continue
            a, b = (int(i), int(j)) if i < j else (int(j), int(i))
            pairs.append(Pair(a, b, _kind(plan, a, b), float(ov)))
    pairs.sort(key=lambda p: (p.i, p.j))
    if n > 1 and not pairs:
        raise InputError("no two frames overlap according to gnss.txt, the camera and the terrain height"
                         + _sizes_text(plan) + ": check the GNSS positions, the camera file (its focal length and "
                         "pixel size: frames resized need the pixel size scaled with them) and project.toml "
                         "[flight] terrain height")
    return pairs


def _sizes_text(plan: BlockPlan) -> str:
    """The footprints' size beside the spacing of the frames, for the refusal of a block whose frames do not overlap
    (s95: the certificate's 12 um pixel on frames downsampled 12 times made footprints of 0.3 km, 2.6 km apart)."""
    from scipy.spatial import cKDTree

    xy = plan.centre_m[:, :2]
    if len(xy) < 2 or not plan.footprints:
        return ""
    # each frame's nearest other (a tree: the distance matrix of a 10,000-frame block would take 1.6 GB)
    d, _ = cKDTree(xy).query(xy, k=2)
    spacing = float(np.median(d[:, 1]))
    size = float(np.median([np.sqrt(fp.area) for fp in plan.footprints]))
    above = float(np.median(plan.centre_m[:, 2])) - plan.terrain_height_m
    return (f" (footprints about {size:,.0f} across from {above:,.0f} above the terrain, the nearest frames "
            f"{spacing:,.0f} apart, in the project CRS's units)")


def _kind(plan: BlockPlan, a: int, b: int) -> str:
    if plan.strip[a] != plan.strip[b]:
        return "cross"
    same = np.flatnonzero(plan.strip == plan.strip[a])
    gap = abs(int(np.searchsorted(same, b)) - int(np.searchsorted(same, a)))
    return "along" if gap == 1 else ("second" if gap == 2 else "extra")
