"""Pair matching: the BLAS mutual ratio test against OpenCV's brute force, and guided matching from the
flight plan on a simulated pair against matching without a guide."""

import cv2
import numpy as np

from aerotri.core.project import Project
from aerotri.geom.camera import project_camera
from aerotri.geom.eo import check_block_crs, read_gnss
from aerotri.match.features import FeatureSettings, extract
from aerotri.match.matching import guided_matches, match_pair, mutual_ratio_matches
from aerotri.match.pairs import candidate_pairs, plan_block
from aerotri.match.settings import PairMatchSettings
from aerotri.geom.images import read_gray


def _knn_reference(da, db, ratio):
    bf = cv2.BFMatcher(cv2.NORM_L2)
    ab, ba = bf.knnMatch(da, db, k=2), bf.knnMatch(db, da, k=2)
    best_ba = np.array([m[0].trainIdx if m[0].distance < ratio * m[1].distance else -1 for m in ba])
    return np.array([(m[0].queryIdx, m[0].trainIdx) for m in ab
                     if m[0].distance < ratio * m[1].distance and best_ba[m[0].trainIdx] == m[0].queryIdx],
                    dtype=int).reshape(-1, 2)


def test_mutual_ratio_matches_equals_opencv_brute_force():
    rng = np.random.default_rng(3)
    a = rng.random((700, 128)).astype(np.float32)
    planted = rng.permutation(700)[:400]
    b = np.vstack([a[planted] + rng.normal(0, 0.02, (400, 128)).astype(np.float32),
                   rng.random((300, 128)).astype(np.float32)])
    ref = _knn_reference(a, b, 0.8)
    assert len(ref) > 300
    for chunk in (2048, 128, 1):
        np.testing.assert_array_equal(mutual_ratio_matches(a, b, 0.8, chunk=chunk), ref)
    # The planted correspondences are what is found.
    truth = {(int(k), n) for n, k in enumerate(planted)}
    assert sum((int(i), int(j)) in truth for i, j in ref) == len(ref)


def test_guided_matching_keeps_the_true_matches(tiny_project):
    project = Project.open(tiny_project)
    camera = project_camera(project)
    gnss = read_gnss(project.gnss_path, check_block_crs(project.crs, "project.toml"))
    terrain = float(project.flight.mean_terrain_height_m)
    plan = plan_block(list(gnss.image_id), gnss.position_m, camera, (0.0, 0.0, 0.0), terrain)
    p = PairMatchSettings()
    for kind in ("along", "cross"):
        pr = next(q for q in candidate_pairs(plan) if q.kind == kind)
        fa, fb = (extract(read_gray(project.images_dir / f"{plan.image_id[k]}.tif"), FeatureSettings())
                  for k in (pr.i, pr.j))
        guide = plan.guide(pr.i, pr.j, p.guide_margin)
        in_a, in_b = guide.in_overlap(camera, fa.xy_px, fb.xy_px)
        assert 0 < in_a.sum() < len(in_a)  # only part of each frame is compared
        g = guided_matches(fa, fb, camera, p.ratio, guide)
        assert in_a[g[:, 0]].all() and in_b[g[:, 1]].all()
        free = match_pair(fa, fb, camera, p)
        guided = match_pair(fa, fb, camera, p, guide)
        # Every verified match without the guide lies in the predicted overlap and is found with it.
        assert len(free) >= p.min_inliers
        common = {tuple(m) for m in free.tolist()} & {tuple(m) for m in guided.tolist()}
        assert len(common) >= 0.95 * len(free), (kind, len(common), len(free), len(guided))
