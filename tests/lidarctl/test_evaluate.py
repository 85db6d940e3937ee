"""Classification of a synthetic scene and the evaluation measures."""

import numpy as np
import pytest

from lidarctl import synthetic
from lidarctl.classify import pipeline as classify
from lidarctl.checks import classes as evaluate


def test_filter_errors_by_hand():
    truth = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 0], bool)
    pred = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], bool)
    e = evaluate.filter_errors(pred, truth)
    assert e.type_i_error_pct == pytest.approx(25.0)
    assert e.type_ii_error_pct == pytest.approx(100.0 / 6)
    assert e.total_error_pct == pytest.approx(20.0)
    po, pe = 0.8, (4 * 4 + 6 * 6) / 100
    assert e.kappa_pct == pytest.approx(100 * (po - pe) / (1 - pe))


def test_confusion_accuracies():
    truth = np.array([2, 2, 2, 6, 6, 5])
    pred = np.array([2, 2, 6, 6, 6, 6])
    c = evaluate.confusion(pred, truth)
    assert c.classes == (2, 5, 6)
    assert c.matrix == ((2, 0, 1), (0, 0, 1), (0, 0, 2))
    assert c.producers_accuracy_pct["2"] == pytest.approx(200 / 3)
    assert c.users_accuracy_pct["6"] == pytest.approx(50.0)
    assert c.overall_accuracy_pct == pytest.approx(400 / 6)
    assert "overall accuracy" in evaluate.format_confusion(c)


def test_classify_synthetic_scene():
    cloud, truth = synthetic.synthetic_scene(width_m=150.0, density_per_m2=3.0, seed=5)
    cls = classify.classify_points(cloud.x, cloud.y, cloud.z, cloud.return_number,
                                   cloud.number_of_returns, cloud.intensity)
    conf = evaluate.confusion(cls, truth)
    pa, ua = conf.producers_accuracy_pct, conf.users_accuracy_pct
    for c in ("2", "6"):
        assert pa[c] > 98.0 and ua[c] > 98.0
    veg_truth = np.isin(truth, (3, 4, 5))
    assert np.mean(np.isin(cls[veg_truth], (3, 4, 5))) > 0.95
    assert np.mean(cls[truth == 7] == 7) >= 0.99 and np.mean(cls[truth == 18] == 18) >= 0.99


def test_deep_noise_patch_of_mixed_depths_is_not_ground():
    cloud, truth = synthetic.synthetic_scene(width_m=150.0, density_per_m2=3.0, seed=8, n_low_outliers=0)
    rng = np.random.default_rng(2)
    k = 120   # a 25 m x 25 m cloud of multipath points 40-100 m below, at all depths in between
    px = cloud.x.min() + 60 + rng.uniform(0, 25, k)
    py = cloud.y.min() + 60 + rng.uniform(0, 25, k)
    pz = synthetic.terrain_height(px - 500000.0, py - 5400000.0) - rng.uniform(40, 100, k)
    n = len(cloud)
    cls = classify.classify_points(np.r_[cloud.x, px], np.r_[cloud.y, py], np.r_[cloud.z, pz])
    assert np.all(cls[n:] == classify.LOW_NOISE)
    assert np.mean(cls[:n][truth == 2] == classify.GROUND) > 0.99


def test_height_check_csv_errors_name_the_line(tmp_path):
    from lidarctl.checks import heights as heights_check
    from aerotri.core.errors import InputError

    f = tmp_path / "p.csv"
    f.write_text("id,x,y,z\nA,1,2,3\nB,1,abc,3\n")
    with pytest.raises(InputError, match="line 3"):
        heights_check.read_points_csv(f)
    f.write_text("id,x,y\nA,1,2\n")
    with pytest.raises(InputError, match="no 'z' column"):
        heights_check.read_points_csv(f)
    # a surveyor's header (Point, Northing, Easting, Elevation, Description): the names were lost (1, 2, ...)
    f.write_text("Point,Northing,Easting,Elevation,Description\nCP07,849166.5,636759.3,425.441,curb\n")
    p = heights_check.read_points_csv(f)
    assert p.ids == ("CP07",) and (p.x[0], p.y[0], p.z[0]) == (636759.3, 849166.5, 425.441) and p.group is None


def test_evaluate_says_what_a_ground_only_truth_cannot_measure():
    """`lidarctl evaluate --truth` against the ISPRS filter test (labels 2 / 0) printed "overall accuracy 53 %" over
    classes the truth does not label, and against Autzen (class 1 "unclassified", which holds ground too) a total
    error of 55 %, with no word; the notes say so and give the mapping to the two-class matrix."""
    from lidarctl.cli.evaluate import _truth_notes

    isprs = evaluate.confusion(np.array([2, 2, 3, 5, 6, 2]), np.array([2, 2, 0, 0, 0, 0]))
    notes = _truth_notes(isprs)
    assert len(notes) == 1 and "ground and class 0 only" in notes[0] and "--map-pred 3:0,5:0,6:0 " in notes[0]
    autzen = evaluate.confusion(np.array([2, 2, 2, 5]), np.array([2, 1, 1, 1]))
    notes = _truth_notes(autzen)
    assert any("class 1 (unclassified) counts as object" in n for n in notes)
    assert any("--map-pred 5:1 " in n for n in notes)
    full = evaluate.confusion(np.array([2, 6, 5, 3]), np.array([2, 6, 5, 4]))  # a truth of several classes
    assert _truth_notes(full) == []


def test_filter_test_read_back_from_its_json_file_as_written(tmp_path):
    """classification_eval.json's filter test as a typed record: the numbers as ``filter_errors`` gave them, the
    same record (keys, order, values) when turned back into a dict."""
    import dataclasses
    import json

    truth = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 0], bool)
    pred = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], bool)
    errors = evaluate.filter_errors(pred, truth)
    path = tmp_path / "classification_eval.json"
    path.write_text(json.dumps({"filter_test": dataclasses.asdict(errors), "confusion": {}}, indent=2))
    ft = evaluate.read_filter_test(path)
    assert ft.type_i_count == 1 and ft.type_ii_count == 1 and ft.type_i_error_pct == 25.0
    assert ft == errors and json.dumps(dataclasses.asdict(ft)) == json.dumps(dataclasses.asdict(errors))


def test_evaluate_scores_a_coarser_truth_on_its_own_classes(tmp_path):
    """AHN3's classes (1 2 6 9 26: vegetation in 1) read "overall accuracy 66.94 %" against a right classification:
    our 3/4/5 counted against its 1. A truth with class 1 and no vegetation class is now scored on its classes (our
    3 4 5 7 17 18 as its 1), said, with the matrix as labelled beside it; the filter test is the same; a truth in the
    full scheme and a --map-pred given are scored as before."""
    import json

    from click.testing import CliRunner

    from lidarctl.cli.main import main

    cloud, fine = synthetic.synthetic_scene(width_m=80.0, density_per_m2=2.0, seed=3)
    assert {2, 4, 5, 6, 7}.issubset(set(np.unique(fine).tolist()))
    coarse = np.where(np.isin(fine, (3, 4, 5, 7, 18)), 1, fine)     # the truth in AHN3's scheme
    pred = fine.copy()
    wrong = np.flatnonzero(fine == 6)[:10]
    pred[wrong] = 5                                                 # 10 building points called high vegetation
    for name, cls in (("pred", pred), ("coarse", coarse), ("fine", fine)):
        synthetic.write_las(tmp_path / f"{name}.laz", cloud, classification=cls, crs="EPSG:32632")

    r = evaluate.evaluate_files(tmp_path / "pred.laz", tmp_path / "coarse.laz")
    n = len(fine)
    assert r.confusion.overall_accuracy_pct == pytest.approx(100.0 * (n - 10) / n)
    assert r.class_map == {str(c): 1 for c in sorted(set(np.unique(pred)) & {3, 4, 5, 7, 17, 18})}
    assert "no vegetation class" in r.class_map_reason
    assert r.confusion_before_map.overall_accuracy_pct == pytest.approx(100.0 * np.mean(pred == coarse))
    assert r.confusion_before_map.overall_accuracy_pct < 90.0
    assert r.filter_test == evaluate.evaluate_files(tmp_path / "pred.laz", tmp_path / "fine.laz").filter_test

    full = evaluate.evaluate_files(tmp_path / "pred.laz", tmp_path / "fine.laz")
    assert full.class_map is None and full.confusion_before_map is None
    assert full.confusion.overall_accuracy_pct == pytest.approx(100.0 * (n - 10) / n)
    given = evaluate.evaluate_files(tmp_path / "pred.laz", tmp_path / "coarse.laz", {3: 1})
    assert given.class_map is None and given.confusion.overall_accuracy_pct < r.confusion.overall_accuracy_pct

    out = CliRunner().invoke(main, ["evaluate", str(tmp_path / "pred.laz"), "--truth", str(tmp_path / "coarse.laz"),
                                    "--json", str(tmp_path / "eval.json")])
    assert out.exit_code == 0, out.output
    assert "scored on the truth's classes" in out.output and "as labelled, before the mapping" in out.output
    assert "class 1: producer's" in out.output
    js = json.loads((tmp_path / "eval.json").read_text())
    assert js["class_map"] == r.class_map and js["confusion_before_map"]["overall_accuracy_pct"] < 90.0


def test_two_class_note_repeats_the_coarse_mapping():
    """Against a truth of ground and class 1 (Autzen) the --map-pred offered for the two-class matrix replaces the
    coarse mapping already applied, so it must hold it too."""
    from lidarctl.cli.evaluate import _truth_notes

    conf = evaluate.confusion(np.array([2, 1, 1, 6]), np.array([2, 1, 1, 1]))
    notes = _truth_notes(conf, {"3": 1, "5": 1})
    assert any("--map-pred 3:1,5:1,6:1 " in n for n in notes)


def test_filter_errors_refuses_no_points_and_unequal_masks():
    # no points raised ZeroDivisionError (trial-api F7)
    with pytest.raises(ValueError, match="0 predicted and 0 true labels"):
        evaluate.filter_errors(np.zeros(0, bool), np.zeros(0, bool))
    with pytest.raises(ValueError, match="2 predicted and 3 true labels"):
        evaluate.filter_errors(np.ones(2, bool), np.ones(3, bool))


def test_our_bridge_deck_is_ahn_s_civil_structures_in_its_scheme():
    """Trial s94: AHN3 Delft's class 26 (civil structures: bridges, viaducts) scored 0 % found, 755 of its 1,365
    points our bridge deck (17), which the coarse scheme counted as its class 1. Where the truth holds 26 and no 17,
    our 17 is scored as its 26; without a 26 in the truth, as its 1."""
    from lidarctl.checks.classes import _coarse_scheme_map

    assert _coarse_scheme_map([2, 5, 6, 17], [1, 2, 6, 9, 26]) == {5: 1, 17: 26}
    assert _coarse_scheme_map([2, 5, 6, 17], [1, 2, 6, 9]) == {5: 1, 17: 1}
    assert _coarse_scheme_map([2, 5, 6, 17], [1, 2, 6, 17, 26]) == {5: 1}
