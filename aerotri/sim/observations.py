"""Tie and control observations straight from the truth geometry (no matching, no rendering).

``geometric_block`` builds a synthetic block (DMC-like camera, smooth terrain, true EO with small
tilts, GNSS antenna positions with noise, per-strip shift and drift and a lever arm) in a local ENU
frame and its project CRS. ``write_truth_observations`` reads a simulator project's ``truth/`` and
writes ``at/tiepoints.csv``, ``control/points.csv`` and ``control/image_points.csv`` with chosen
noise and blunders. Image observations are generated with the true camera (principal-point offset and
distortion) by the collinearity equations in the local tangent-plane frame (aerotri.adjust.local_frame).
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.observations import ControlPoints, ImageObservations
from aerotri.geom.camera import BrownCamera, dmc_camera
from aerotri.geom.eo import ExteriorOrientations, GnssPositions, read_eo, write_eo, write_gnss
from aerotri.core.errors import InputError
from aerotri.geom.rotation import opk_from_matrix, rotation_matrix_opk
from aerotri.core.atomic import write_text_atomic


def true_dmc_camera() -> BrownCamera:
    """The DMC-like camera with a principal-point offset and radial distortion to be recovered."""
    import dataclasses as dc

    return dc.replace(dmc_camera(), ppx_mm=0.021, ppy_mm=-0.015, k1=-4.0e-4, k2=1.5e-4, name="DMC true")


@dataclasses.dataclass
class GeometricBlock:
    """Truth of a synthetic block. Local arrays are ENU metres of ``frame``; rotations photogrammetric."""

    crs: str
    frame: LocalFrame
    camera_true: BrownCamera
    camera_nominal: BrownCamera
    image_id: list[str]
    strip: np.ndarray  # (N,) 0-based
    centre_local: np.ndarray  # (N, 3)
    R_local: np.ndarray  # (N, 3, 3) camera -> ENU
    lever_arm_m: np.ndarray  # (3,) camera frame
    gnss_shift_m: np.ndarray  # (S, 3) ENU
    gnss_drift_m_per_km: np.ndarray  # (S, 3) ENU
    along_km: np.ndarray  # (N,)
    gnss_sigma_m: np.ndarray  # (3,)
    gnss_local: np.ndarray  # (N, 3) observed antenna positions (with noise, shift, drift)
    flying_height_m: float
    relief_m: float
    extent_local: tuple[float, float, float, float]  # xmin xmax ymin ymax of the ground covered
    terrain_seed: int

    # -- truth in the project CRS -----------------------------------------------------------
    def eo_map(self) -> ExteriorOrientations:
        centre = self.frame.to_map(self.centre_local)
        R_map = np.swapaxes(self.frame.rotation_local_from_map(centre), -1, -2) @ self.R_local
        return ExteriorOrientations(list(self.image_id), centre, np.stack(opk_from_matrix(R_map), axis=-1))

    def gnss_map(self) -> GnssPositions:
        sig = np.tile(self.gnss_sigma_m, (len(self.image_id), 1))
        return GnssPositions(list(self.image_id), self.frame.to_map(self.gnss_local), sig)

    def terrain(self, x, y):
        """Ground height (ENU up, metres) at local x, y: smooth hills of amplitude ``relief_m``."""
        rng = np.random.default_rng(self.terrain_seed)
        z = np.zeros(np.broadcast(x, y).shape)
        for k in range(4):
            kx, ky = rng.uniform(0.5, 2.5, 2) * 2 * np.pi / 4000.0
            ph = rng.uniform(0, 2 * np.pi, 2)
            z += self.relief_m / (k + 1) * np.sin(kx * np.asarray(x) + ph[0]) * np.cos(ky * np.asarray(y) + ph[1])
        return z

    # -- observations -------------------------------------------------------------------------
    def project(self, points_local, camera: BrownCamera | None = None):
        """Observations of ENU points in all frames where they fall inside: (point_index, image_index, xy_px)."""
        return project_points(points_local, self.centre_local, self.R_local, camera or self.camera_true, self.flying_height_m)

    def ground_points(self, n, rng) -> np.ndarray:
        x0, x1, y0, y1 = self.extent_local
        xy = np.column_stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)])
        return np.column_stack([xy, self.terrain(xy[:, 0], xy[:, 1])])

    def tie_observations(
        self,
        points_per_image: int = 150,
        sigma_px: float = 0.3,
        min_rays: int = 3,
        blunder_fraction: float = 0.0,
        blunder_px_range=(5.0, 50.0),
        seed: int = 1,
    ):
        """Noisy tie observations of random ground points seen in at least ``min_rays`` frames.

        Returns (ImageObservations, object points ENU (M, 3), blunder mask (N,)).
        """
        rng = np.random.default_rng(seed)
        n_cand = int(points_per_image * len(self.image_id) / 1.5)
        P = self.ground_points(n_cand, rng)
        return make_observations(
            P, self.project(P), self.image_id, self.camera_true, "t", sigma_px=sigma_px, min_rays=min_rays,
            blunder_fraction=blunder_fraction, blunder_px_range=blunder_px_range, rng=rng,
        )


def project_points(points_local, centre_local, R_local, camera: BrownCamera, flying_height_m: float, margin_px=20.0):
    """All observations of points (M, 3) in frames (N): arrays point_index, image_index, xy_px (K, 2)."""
    P = np.asarray(points_local, dtype=float)
    tree = cKDTree(P[:, :2])
    radius = 0.75 * flying_height_m * np.hypot(camera.width, camera.height) * camera.pixel_um / (camera.focal_mm * 1000.0)
    pi, ii, xy = [], [], []
    for i in range(len(centre_local)):
        idx = np.asarray(tree.query_ball_point(centre_local[i, :2], radius), dtype=int)
        if len(idx) == 0:
            continue
        x, y, depth = camera.project(P[idx], centre_local[i], R_local[i])
        ok = (depth > 0) & camera.inside(x, y, margin_px)
        pi.append(idx[ok])
        ii.append(np.full(ok.sum(), i))
        xy.append(np.column_stack([x[ok], y[ok]]))
    if not pi:
        return np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2))
    pi, ii, xy = np.concatenate(pi), np.concatenate(ii), np.concatenate(xy)
    order = np.lexsort((ii, pi))
    return pi[order], ii[order], xy[order]


def make_observations(P, projected, image_id, camera, prefix, *, sigma_px, min_rays, blunder_fraction, blunder_px_range,
                      rng):
    """Keep points with >= min_rays, add Gaussian noise and blunders; ids ``<prefix>000001``..."""
    pi, ii, xy = projected
    rays = np.bincount(pi, minlength=len(P))
    keep_pt = rays >= min_rays
    m = keep_pt[pi]
    pi, ii, xy = pi[m], ii[m], xy[m]
    new_index = np.cumsum(keep_pt) - 1
    pi = new_index[pi]
    P = P[keep_pt]
    xy = xy + rng.normal(0.0, sigma_px, xy.shape)
    blunder = np.zeros(len(pi), dtype=bool)
    n_bad = int(round(blunder_fraction * len(pi)))
    if n_bad:
        bad = rng.choice(len(pi), n_bad, replace=False)
        blunder[bad] = True
        mag = rng.uniform(*blunder_px_range, n_bad)
        ang = rng.uniform(0, 2 * np.pi, n_bad)
        d = np.column_stack([np.cos(ang), np.sin(ang)]) * mag[:, None]
        moved = xy[bad] + d
        out = ~camera.inside(moved[:, 0], moved[:, 1])
        moved[out] = xy[bad][out] - d[out]  # keep the blunder inside the frame
        xy[bad] = moved
    ids = np.array([f"{prefix}{k + 1:06d}" for k in range(len(P))], dtype=object)
    obs = ImageObservations(ids[pi], np.asarray(image_id, dtype=object)[ii], xy)
    return obs, P, blunder


def geometric_block(
    n_strips: int = 3,
    n_frames: int = 6,
    *,
    camera_true: BrownCamera | None = None,
    flying_height_m: float = 1000.0,
    forward_overlap: float = 0.6,
    side_overlap: float = 0.3,
    relief_m: float = 60.0,
    tilt_sigma_deg: float = 1.0,
    gnss_sigma_m=(0.05, 0.05, 0.08),
    gnss_shift_sigma_m: float = 0.3,
    gnss_drift_sigma_m_per_km: float = 0.05,
    lever_arm_m=(0.05, -0.12, 1.25),
    crs: str = "EPSG:32649",
    origin_map=(420000.0, 3380000.0, 150.0),
    seed: int = 0,
) -> GeometricBlock:
    """A synthetic block of ``n_strips`` x ``n_frames`` frames flown east-west in alternating directions.

    Image top faces the flight direction (kappa = -90 deg flying east), the long image side is across
    track as for the DMC. Frame ids ``sSS_FFF``. GNSS errors: Gaussian noise with ``gnss_sigma_m``,
    per-strip shift and drift (ENU) drawn with the given sigmas.
    """
    rng = np.random.default_rng(seed)
    cam = camera_true or true_dmc_camera()
    frame = LocalFrame(crs, origin_map)
    scale = flying_height_m * cam.pixel_um * 1e-6 / (cam.focal_mm * 1e-3)  # GSD
    base = (1 - forward_overlap) * cam.height * scale
    spacing = (1 - side_overlap) * cam.width * scale
    ids, strip, C, R, along = [], [], [], [], []
    ys = (np.arange(n_strips) - (n_strips - 1) / 2) * spacing
    xs = (np.arange(n_frames) - (n_frames - 1) / 2) * base
    for s in range(n_strips):
        east = s % 2 == 0
        order = xs if east else xs[::-1]
        kappa = -90.0 if east else 90.0
        for f, x in enumerate(order):
            ids.append(f"s{s + 1:02d}_{f + 1:03d}")
            strip.append(s)
            C.append([x + rng.normal(0, 3.0), ys[s] + rng.normal(0, 3.0), flying_height_m + rng.normal(0, 5.0)])
            om, ph = rng.normal(0, tilt_sigma_deg, 2)
            R.append(rotation_matrix_opk(om, ph, kappa + rng.normal(0, 1.0)))
            along.append((x if east else -x) / 1000.0)
    C, R, strip, along = np.array(C), np.array(R), np.array(strip), np.array(along)
    lever = np.asarray(lever_arm_m, dtype=float)
    shift = rng.normal(0, gnss_shift_sigma_m, (n_strips, 3))
    drift = rng.normal(0, gnss_drift_sigma_m_per_km, (n_strips, 3))
    sig = np.asarray(gnss_sigma_m, dtype=float)
    antenna = C + np.einsum("nij,j->ni", R, lever)
    gnss = antenna + shift[strip] + drift[strip] * along[:, None] + rng.normal(0, 1, C.shape) * sig
    hx = (n_frames - 1) / 2 * base + 0.5 * cam.height * scale * 0.9
    hy = (n_strips - 1) / 2 * spacing + 0.5 * cam.width * scale * 0.9
    return GeometricBlock(
        crs, frame, cam, cam.ideal(), ids, strip, C, R, lever, shift, drift, along, sig, gnss,
        float(flying_height_m), float(relief_m), (-hx, hx, -hy, hy), int(rng.integers(1 << 30)),
    )


def control_layout(block: GeometricBlock, n_control: int, n_check: int, rng, min_rays: int = 2):
    """Control points spread over the block (farthest-point order from the corners), check points random.

    Returns (control ENU (n_control, 3), check ENU (n_check, 3)); all points seen in >= min_rays frames.
    """
    P = block.ground_points(20000, rng)
    pi, _, _ = block.project(P)
    rays = np.bincount(pi, minlength=len(P))
    P = P[rays >= max(min_rays, 3)]
    x0, x1, y0, y1 = block.extent_local
    chosen = []
    targets = [(x0, y0), (x1, y1), (x0, y1), (x1, y0), (0.0, 0.0)]
    for t in targets[:n_control]:
        chosen.append(int(np.argmin(np.hypot(P[:, 0] - t[0], P[:, 1] - t[1]))))
    while len(chosen) < n_control:
        d = np.min(np.hypot(P[:, None, 0] - P[chosen, 0][None], P[:, None, 1] - P[chosen, 1][None]), axis=1)
        chosen.append(int(np.argmax(d)))
    rest = np.setdiff1d(np.arange(len(P)), chosen)
    check = rng.choice(rest, n_check, replace=False)
    return P[chosen], P[check]


def block_control(
    block: GeometricBlock,
    *,
    n_control: int = 4,
    n_check: int = 10,
    control_sigma_m=(0.03, 0.03, 0.05),
    sigma_px: float = 0.3,
    bad_control_shift_m: float = 0.0,
    seed: int = 2,
):
    """Control (kind full) and check points with survey noise, and their noisy image measurements.

    Returns (ControlPoints in the project CRS, ImageObservations, true ENU coordinates (M, 3)).
    """
    rng = np.random.default_rng(seed)
    ctrl, chk = control_layout(block, n_control, n_check, rng)
    P = np.vstack([ctrl, chk])
    sig = np.asarray(control_sigma_m, dtype=float)
    given = P + rng.normal(0, 1, P.shape) * sig
    if bad_control_shift_m and n_control:
        ang = rng.uniform(0, 2 * np.pi)
        given[0, :2] += bad_control_shift_m * np.array([np.cos(ang), np.sin(ang)])
    ids = np.array([f"gcp{k + 1:02d}" for k in range(n_control)] + [f"chk{k + 1:02d}" for k in range(n_check)], dtype=object)
    kind = np.array(["full"] * n_control + ["check"] * n_check, dtype=object)
    cp = ControlPoints(ids, kind, block.frame.to_map(given), np.tile(sig, (len(P), 1)))
    pi, ii, xy = block.project(P)
    xy = xy + rng.normal(0, sigma_px, xy.shape)
    obs = ImageObservations(ids[pi], np.asarray(block.image_id, dtype=object)[ii], xy)
    return cp, obs, P


# -- files ------------------------------------------------------------------------------------
def write_image_points(path, obs: ImageObservations) -> None:
    lines = ["point_id,image_id,x_px,y_px"]
    # Python floats format several times faster than numpy scalars (millions of lines in a large block)
    xy = np.asarray(obs.xy_px, dtype=float)
    ids = zip(np.asarray(obs.point_id).tolist(), np.asarray(obs.image_id).tolist())
    lines += [f"{p},{i},{x:.3f},{y:.3f}" for (p, i), x, y in zip(ids, xy[:, 0].tolist(), xy[:, 1].tolist())]
    write_text_atomic(path, "\n".join(lines) + "\n")


def write_control_points(path, cp: ControlPoints) -> None:
    lines = ["id,kind,x,y,z,sx_m,sy_m,sz_m"]
    for pid, k, p, s in zip(cp.id, cp.kind, cp.xyz_m, cp.sigma_m):
        lines.append(f"{pid},{k},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},{s[0]:.4f},{s[1]:.4f},{s[2]:.4f}")
    write_text_atomic(path, "\n".join(lines) + "\n")


def write_block_project(block: GeometricBlock, out_dir, name: str = "geometric", control_sigma_m=(0.03, 0.03, 0.05)) -> Path:
    """Write a project folder for a geometric block: project.toml, camera.toml, gnss.txt and truth/.

    ``truth/`` holds eo.txt, camera.toml, gnss_truth.toml and truth.json, plus ``terrain.json``
    (the seed and relief of the terrain function) so that write_truth_observations can place tie points.
    """
    out = Path(out_dir)
    (out / "truth").mkdir(parents=True, exist_ok=True)
    lx, ly, lz = block.lever_arm_m
    s = block.gnss_sigma_m
    write_text_atomic(
        out / "project.toml",
        f'[project]\nname = "{name}"\ncrs = "{block.crs}"\n\n[gnss]\nsigma_xy_m = {s[0]}\nsigma_z_m = {s[2]}\n'
        f"lever_arm_m = [{lx}, {ly}, {lz}]\n\n[control]\nsigma_xy_m = {control_sigma_m[0]}\nsigma_z_m = {control_sigma_m[2]}\n",
    )
    write_text_atomic(out / "camera.toml", block.camera_nominal.to_toml())
    write_text_atomic(out / "truth" / "camera.toml", block.camera_true.to_toml())
    g = block.gnss_map()
    write_gnss(out / "gnss.txt", GnssPositions(g.image_id, g.position_m, None))
    write_eo(out / "truth" / "eo.txt", block.eo_map())
    strips = "\n".join(
        f"[strip_{k + 1:02d}]\nshift_m = {list(map(float, block.gnss_shift_m[k]))}\n"
        f"drift_m_per_km = {list(map(float, block.gnss_drift_m_per_km[k]))}\n"
        for k in range(len(block.gnss_shift_m))
    )
    write_text_atomic(out / "truth" / "gnss_truth.toml", f"lever_arm_m = [{lx}, {ly}, {lz}]\n\n{strips}")
    gsd = block.camera_true.gsd_m(block.flying_height_m)
    write_text_atomic(
        out / "truth" / "truth.json",
        json.dumps({"gsd_m": gsd, "flying_height_m": block.flying_height_m, "extent_local_m": list(block.extent_local)}, indent=1),
    )
    write_text_atomic(
        out / "truth" / "terrain.json",
        json.dumps({"terrain_seed": block.terrain_seed, "relief_m": block.relief_m, "origin_map": list(block.frame.origin_map)}),
    )
    return out


@dataclasses.dataclass(frozen=True)
class TruthObservations:
    """What ``write_truth_observations`` wrote: counts, and the blunders it put in (also in
    truth/observation_blunders.json)."""

    n_tie_observations: int
    n_tie_points: int
    n_control: int
    n_check: int
    n_control_observations: int
    tie_blunders: list  # (point id, image id) of each blundered tie observation, sorted
    bad_control: list  # ids of the control points shifted by bad_control_shift_m


def write_truth_observations(
    project_dir,
    *,
    tie_sigma_px: float = 0.3,
    control_sigma_m: float | tuple | None = None,
    n_control: int = 4,
    blunder_fraction: float = 0.0,
    blunder_px_range=(5.0, 50.0),
    bad_control_shift_m: float = 0.0,
    seed: int = 0,
    points_per_image: int = 150,
    n_check: int = 10,
    min_rays: int = 3,
    check_sigma_m: float = 0.005,
    dem=None,
    interpolation: str = "nearest",
    tie_points_per_frame: int | None = None,
) -> TruthObservations:
    """Write at/tiepoints.csv, control/points.csv, control/image_points.csv from a project's truth/.

    Needs truth/eo.txt, truth/camera.toml and either a DEM (``dem``, default truth/dem.tif: simulator
    projects; sampled ``interpolation`` nearest or bilinear) or truth/terrain.json (geometric blocks) for the
    ground heights. Tie points: random ground points seen in at least ``min_rays`` frames, from
    ``points_per_image`` x frames / 1.5 candidates, or (``tie_points_per_frame``) as many as to give that many
    tie points per frame on average. Control and check points come from
    truth/checkpoints.csv when present, else from the terrain. The first control point is moved by
    ``bad_control_shift_m`` horizontally; check points get ``check_sigma_m`` noise. ``control_sigma_m`` None: project.toml [control] sigma_xy_m,
    sigma_z_m. Returns a summary with the blunder ids (for evaluations).
    """
    root = Path(project_dir)
    with open(root / "project.toml", "rb") as f:
        cfg = tomllib.load(f)
    if control_sigma_m is None:
        cc = cfg.get("control", {})
        control_sigma_m = (float(cc.get("sigma_xy_m", 0.03)),) * 2 + (float(cc.get("sigma_z_m", 0.05)),)
    crs = cfg["project"]["crs"]
    eo = read_eo(root / "truth" / "eo.txt")
    cam = BrownCamera.read(root / "truth" / "camera.toml")
    frame = LocalFrame.at_centre(crs, eo.centre_m)
    C = frame.to_local(eo.centre_m)
    R = frame.rotation_local_from_map(eo.centre_m) @ eo.rotations()
    height_fn, extent, H_above = _ground_model(root, frame, C, cam, dem, interpolation)
    rng = np.random.default_rng(seed)

    def ground(n):
        x0, x1, y0, y1 = extent
        xy = np.column_stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)])
        return np.column_stack([xy, height_fn(xy)])

    if tie_points_per_frame is None:
        P = ground(int(points_per_image * len(C) / 1.5))
        proj = project_points(P, C, R, cam, H_above)
    else:
        P, proj = _draw_tie_points(ground, C, R, cam, H_above=H_above, n_points=int(tie_points_per_frame) * len(C),
                                   min_rays=min_rays)
    ties, P_tie, blunder = make_observations(
        P, proj, eo.image_id, cam, "t", sigma_px=tie_sigma_px, min_rays=min_rays, blunder_fraction=blunder_fraction,
        blunder_px_range=blunder_px_range, rng=rng,
    )
    # control and check points
    cands = None
    chk_file = root / "truth" / "checkpoints.csv"
    if chk_file.exists():
        rows = np.genfromtxt(chk_file, delimiter=",", names=True, dtype=None, encoding="utf-8")
        cands = frame.to_local(np.column_stack([rows["x"], rows["y"], rows["z"]]))
    if cands is None or len(cands) < n_control + 3:
        cands = ground(20000)
    pi, _, _ = project_points(cands, C, R, cam, H_above)
    cands = cands[np.bincount(pi, minlength=len(cands)) >= 2]
    sel = _spread(cands, n_control)
    rest = np.setdiff1d(np.arange(len(cands)), sel)
    chk = rng.choice(rest, min(n_check, len(rest)), replace=False)
    Pchk = cands[chk]
    if len(Pchk) < n_check:  # top up with random ground points seen in >= 2 frames
        extra = ground(20 * n_check)
        pe, _, _ = project_points(extra, C, R, cam, H_above)
        extra = extra[np.bincount(pe, minlength=len(extra)) >= 2][: n_check - len(Pchk)]
        Pchk = np.vstack([Pchk, extra])
    chk = np.arange(len(Pchk))
    Pc = np.vstack([cands[sel], Pchk])
    sig = np.broadcast_to(np.asarray(control_sigma_m, dtype=float), (3,)) if np.ndim(control_sigma_m) else np.array([control_sigma_m] * 3)
    # control points carry survey noise; check points are known better than the adjustment can reach
    sig = np.vstack([np.tile(sig, (len(sel), 1)), np.full((len(chk), 3), check_sigma_m)])
    given = Pc + rng.normal(0, 1, Pc.shape) * sig
    bad_ids = []
    if bad_control_shift_m and n_control:
        ang = rng.uniform(0, 2 * np.pi)
        given[0, :2] += bad_control_shift_m * np.array([np.cos(ang), np.sin(ang)])
        bad_ids = ["gcp01"]
    ids = np.array([f"gcp{k + 1:02d}" for k in range(len(sel))] + [f"chk{k + 1:02d}" for k in range(len(chk))], dtype=object)
    kind = np.array(["full"] * len(sel) + ["check"] * len(chk), dtype=object)
    cp = ControlPoints(ids, kind, frame.to_map(given), sig)
    pi, ii, xy = project_points(Pc, C, R, cam, H_above)
    cobs = ImageObservations(ids[pi], np.asarray(eo.image_id, dtype=object)[ii], xy + rng.normal(0, tie_sigma_px, xy.shape))
    write_image_points(root / "at" / "tiepoints.csv", ties)
    write_control_points(root / "control" / "points.csv", cp)
    write_image_points(root / "control" / "image_points.csv", cobs)
    blunders = sorted(zip(ties.point_id[blunder].tolist(), ties.image_id[blunder].tolist()))
    write_text_atomic(
        root / "truth" / "observation_blunders.json",
        json.dumps({"tie_blunders": blunders, "bad_control": bad_ids}, indent=0),
    )
    return TruthObservations(n_tie_observations=len(ties), n_tie_points=len(P_tie), n_control=len(sel),
                             n_check=len(chk), n_control_observations=len(cobs), tie_blunders=blunders,
                             bad_control=bad_ids)


def _draw_tie_points(ground, C, R, cam, *, H_above, n_points: int, min_rays: int):
    """Random ground points (``ground(n)``), drawn in batches until ``n_points`` of them are seen in at least
    ``min_rays`` frames: the points up to that one and their projections (``project_points``). The points
    are independent and uniform, so the first ``n_points`` kept are a uniform sample too."""
    points, pis, iis, xys = [], [], [], []
    drawn = kept = 0
    while kept < n_points:
        # the fraction kept so far (a quarter to start with) sets the next batch: about 10 % more than needed
        frac = kept / drawn if drawn else 0.25
        n = int(math.ceil((n_points - kept) / max(frac, 0.01) * 1.1)) + 100
        P = ground(n)
        pi, ii, xy = project_points(P, C, R, cam, H_above)
        ok = np.bincount(pi, minlength=n) >= min_rays
        if drawn == 0 and not ok.any():
            raise InputError(f"no ground point of the block is seen in {min_rays} frames: the flight needs more "
                             f"frames or overlap for tie points (flight.frames_per_strip, flight.forward_overlap)")
        if kept + int(ok.sum()) >= n_points:  # stop at the point that completes the count
            n = int(np.flatnonzero(ok)[n_points - kept - 1]) + 1
            m = pi < n
            P, pi, ii, xy, ok = P[:n], pi[m], ii[m], xy[m], ok[:n]
        points.append(P)
        pis.append(pi + drawn)
        iis.append(ii)
        xys.append(xy)
        drawn += n
        kept += int(ok.sum())
    return np.concatenate(points), (np.concatenate(pis), np.concatenate(iis), np.concatenate(xys))


def _spread(P, n):
    x0, x1, y0, y1 = P[:, 0].min(), P[:, 0].max(), P[:, 1].min(), P[:, 1].max()
    chosen = []
    for t in [(x0, y0), (x1, y1), (x0, y1), (x1, y0), ((x0 + x1) / 2, (y0 + y1) / 2)][:n]:
        chosen.append(int(np.argmin(np.hypot(P[:, 0] - t[0], P[:, 1] - t[1]))))
    while len(chosen) < n:
        d = np.min(np.hypot(P[:, None, 0] - P[chosen, 0][None], P[:, None, 1] - P[chosen, 1][None]), axis=1)
        chosen.append(int(np.argmax(d)))
    return np.array(chosen, dtype=int)


def _ground_model(root: Path, frame: LocalFrame, C, cam, dem=None, interpolation: str = "nearest"):
    """(height function of local xy, extent, typical height above ground)."""
    dem = Path(dem) if dem is not None else root / "truth" / "dem.tif"
    terrain = root / "truth" / "terrain.json"
    if terrain.exists():
        t = json.loads(terrain.read_text())
        dummy = GeometricBlock.__new__(GeometricBlock)
        dummy.terrain_seed, dummy.relief_m = int(t["terrain_seed"]), float(t["relief_m"])
        # the terrain is defined in the block's own frame (origin_map); map it into this frame
        own = LocalFrame(frame.crs, t["origin_map"])

        def height(xy):
            # iterate: local xy -> own xy -> terrain height -> local point
            z = np.zeros(len(xy))
            for _ in range(3):
                q = own.to_local(frame.to_map(np.column_stack([xy, z])))
                p = frame.to_local(own.to_map(np.column_stack([q[:, :2], dummy.terrain(q[:, 0], q[:, 1])])))
                z = z + (p[:, 2] - z)
            return z

        ground_z = float(np.mean(height(C[:, :2])))
    elif dem.exists():
        import rasterio

        with rasterio.open(dem) as src:
            z_map = src.read(1, masked=True).astype(float).filled(np.nan)
            inv = ~src.transform
        fill = float(np.nanmean(z_map))

        def sample(col, row):
            if interpolation == "bilinear":  # pixel centres at integer + 0.5
                u, v = col - 0.5, row - 0.5
                c0 = np.clip(np.floor(u).astype(int), 0, z_map.shape[1] - 2)
                r0 = np.clip(np.floor(v).astype(int), 0, z_map.shape[0] - 2)
                fu, fv = np.clip(u - c0, 0.0, 1.0), np.clip(v - r0, 0.0, 1.0)
                h = ((z_map[r0, c0] * (1 - fu) + z_map[r0, c0 + 1] * fu) * (1 - fv)
                     + (z_map[r0 + 1, c0] * (1 - fu) + z_map[r0 + 1, c0 + 1] * fu) * fv)
            else:
                r = np.clip(np.round(row).astype(int), 0, z_map.shape[0] - 1)
                c = np.clip(np.round(col).astype(int), 0, z_map.shape[1] - 1)
                h = z_map[r, c]
            return np.where(np.isfinite(h), h, fill)

        def height(xy):
            z0 = np.zeros(len(xy))
            for _ in range(2):
                m = frame.to_map(np.column_stack([xy, z0]))
                col, row = inv * (m[:, 0], m[:, 1])
                h = sample(np.asarray(col), np.asarray(row))
                z0 = frame.to_local(np.column_stack([m[:, :2], h]))[:, 2]
            return z0

        ground_z = float(np.mean(height(C[:, :2])))
    else:
        raise InputError(f"{root / 'truth'}: needs dem.tif or terrain.json for the ground heights")
    H_above = float(np.median(C[:, 2]) - ground_z)
    foot = 0.5 * H_above * max(cam.width, cam.height) * cam.pixel_um / (cam.focal_mm * 1000.0)
    extent = (C[:, 0].min() - foot, C[:, 0].max() + foot, C[:, 1].min() - foot, C[:, 1].max() + foot)
    return height, extent, H_above


def write_terrain_dem(block: GeometricBlock, path, cell_m: float = 2.0, margin_m: float = 200.0) -> Path:
    """The terrain of a geometric block as a GeoTIFF DEM in its project CRS (heights as the project's), reaching
    ``margin_m`` beyond the ground the frames cover: surface control for the adjustment of the block."""
    import rasterio
    from rasterio.transform import from_origin

    xmin, xmax, ymin, ymax = block.extent_local
    corners = block.frame.to_map(np.array([[xmin, ymin, 0.0], [xmax, ymax, 0.0]]))
    x0, y1 = corners[0, 0] - margin_m, corners[1, 1] + margin_m
    W = int((corners[1, 0] + margin_m - x0) / cell_m)
    H = int((y1 - (corners[0, 1] - margin_m)) / cell_m)
    X, Y = np.meshgrid(x0 + (np.arange(W) + 0.5) * cell_m, y1 - (np.arange(H) + 0.5) * cell_m)
    h = np.zeros_like(X)
    for _ in range(4):  # the map height whose local point lies on the terrain (the local frame's earth curvature)
        p = block.frame.to_local(np.column_stack([X.ravel(), Y.ravel(), h.ravel()]))
        h = h + (block.terrain(p[:, 0], p[:, 1]) - p[:, 2]).reshape(h.shape)
    with rasterio.open(path, "w", driver="GTiff", width=W, height=H, count=1, dtype="float32", crs=block.crs,
                       transform=from_origin(x0, y1, cell_m, cell_m), nodata=-9999.0) as ds:
        ds.write(h.astype(np.float32), 1)
    return Path(path)
