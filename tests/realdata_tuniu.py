"""The Tuniu drone frames (../shared/data/tuniu_drone: 4 DJI Phantom 4 RTK frames, 30 degrees oblique in four
directions, EXIF GNSS with RTK accuracies) against the OpenSfM reconstruction OpenDroneMap made of them.

Used by ``tests/aerotri/adjust/test_tuniu_realdata.py`` and ``bench/eval_real_blocks.py`` (both load this file by
path). The reconstruction is a peer's product, not truth: its camera centres lie 1.6 m east and 1.5 m north of the
frames' RTK positions and its block is turned 0.89 degrees about the vertical against them (a similarity fits the
two sets of centres to 0.016 m), so orientations are compared after that similarity (``compare_with_reference``):
the attitude differences once the similarity's rotation is taken out, and the relative rotations between frames,
which no datum changes.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

CRS = "EPSG:32651"  # WGS 84 / UTM 51N (the ODM surface model's CRS)
RECONSTRUCTION = Path("opensfm") / "reconstruction.json"
DSM = Path("odm_dem") / "dsm.tif"


def reference_orientations(data_dir, work_dir):
    """OpenSfM's orientations in the project CRS (``aerotri import --format opensfm`` into a bare project under
    ``work_dir``, which must not exist)."""
    from aerotri.exchange import import_files
    from aerotri.geom.eo import read_eo

    data_dir, root = Path(data_dir), Path(work_dir)
    (root / "images").mkdir(parents=True)
    for f in sorted((data_dir / "images").glob("*.tif")):
        (root / "images" / f.name).symlink_to(f.resolve())
    (root / "project.toml").write_text(f'[project]\nname = "tuniu_opensfm"\ncrs = "{CRS}"\n')
    import_files(root, "opensfm", [data_dir / RECONSTRUCTION])
    return read_eo(root / "imported" / "eo.txt")


def _similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale s, rotation R, shift t of the least-squares similarity dst = s R src + t (Umeyama)."""
    ms, md = src.mean(0), dst.mean(0)
    U, S, Vt = np.linalg.svd((src - ms).T @ (dst - md))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    s = float(np.trace(np.diag(S) @ D) / np.sum((src - ms) ** 2))
    return s, R, md - s * R @ ms


def _angle_deg(R: np.ndarray) -> float:
    """The rotation angle of a rotation matrix (degrees)."""
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def compare_with_reference(eo, ref) -> dict:
    """Orientations ``eo`` against the reference ``ref`` (ExteriorOrientations, the same image ids, project CRS):

    - ``raw_attitude_deg``: angle of R_eo R_ref^T per frame, as they are;
    - ``similarity``: the reference's centres onto ours (scale, rotation angle and its vector in degrees, shift m)
      and the centres' RMS residual after it (m);
    - ``attitude_deg``: angle per frame after the similarity's rotation (R_eo (R_sim R_ref)^T) and their RMS;
    - ``relative_rotation_deg``: for every pair of frames the angle between our relative rotation R_i^T R_j and
      the reference's, and their RMS (no datum enters these)."""
    from scipy.spatial.transform import Rotation

    k = {i: n for n, i in enumerate(ref.image_id)}
    sel = [k[i] for i in eo.image_id]
    R, R0 = eo.rotations(), ref.rotations()[sel]
    C, C0 = np.asarray(eo.centre_m, float), np.asarray(ref.centre_m, float)[sel]
    s, Rs, t = _similarity(C0, C)
    res = C - (s * C0 @ Rs.T + t)
    after = [_angle_deg(R[i] @ (Rs @ R0[i]).T) for i in range(len(sel))]
    raw = [_angle_deg(R[i] @ R0[i].T) for i in range(len(sel))]
    rel = [_angle_deg((R[i].T @ R[j]) @ (R0[i].T @ R0[j]).T) for i in range(len(sel)) for j in range(i + 1, len(sel))]
    rms = lambda v: round(float(np.sqrt(np.mean(np.square(v)))), 4)  # noqa: E731
    return {
        "image_id": list(eo.image_id),
        "raw_attitude_deg": [round(a, 4) for a in raw], "raw_attitude_rms_deg": rms(raw),
        "similarity": {"scale": round(s, 6), "rotation_deg": round(_angle_deg(Rs), 4),
                       "rotation_vector_deg": np.degrees(Rotation.from_matrix(Rs).as_rotvec()).round(4).tolist(),
                       "shift_m": (C.mean(0) - C0.mean(0)).round(3).tolist(),
                       "centre_residual_rms_m": rms(np.linalg.norm(res, axis=1))},
        "attitude_deg": [round(a, 4) for a in after], "attitude_rms_deg": rms(after),
        "relative_rotation_deg": [round(a, 4) for a in rel], "relative_rotation_rms_deg": rms(rel),
    }
