"""Bad input: clear errors naming the file/record, exit code 2, and no output written."""

import pytest
from click.testing import CliRunner

from aerotri.cli import main
from aerotri.geom.observations import read_control_image_points
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


@pytest.fixture()
def project(tmp_path):
    block = geometric_block(2, 5, seed=21)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=60, n_check=3, seed=22)
    return root


def _run(root, *args):
    res = CliRunner().invoke(main, ["adjust", str(root), "--no-html", *args])
    return res


def _no_output(root):
    return not any((root / "at" / f).exists() for f in ("eo.txt", "report.txt", "report.json", "object_points.csv"))


def test_cli_runs(project):
    res = _run(project, "--gnss-correction", "shift", "--image-sigma-px", "0.3")
    assert res.exit_code == 0, res.output
    assert "sigma0" in res.output and (project / "at" / "report.txt").exists()


def _edit(path, fn):
    lines = path.read_text().splitlines()
    path.write_text("\n".join(fn(lines)) + "\n")


def test_duplicate_tie_measurement(project):
    _edit(project / "at" / "tiepoints.csv", lambda L: L + [L[5]])
    res = _run(project)
    assert res.exit_code == 2 and "duplicate measurement" in res.output and "tiepoints.csv" in res.output
    assert _no_output(project)


def test_duplicate_control_id(project):
    _edit(project / "control" / "points.csv", lambda L: L + [L[1]])
    res = _run(project)
    assert res.exit_code == 2 and "duplicate control point id 'gcp01'" in res.output
    assert _no_output(project)


def test_nan_value(project):
    _edit(project / "at" / "tiepoints.csv", lambda L: L[:3] + [",".join(L[3].split(",")[:2] + ["nan", "10.0"])] + L[4:])
    res = _run(project)
    assert res.exit_code == 2 and "tiepoints.csv:4" in res.output and "NaN" in res.output
    assert _no_output(project)


def test_control_without_image_measurement(project):
    _edit(project / "control" / "points.csv", lambda L: L + ["gcp99,full,420000.0,3380000.0,150.0,0.03,0.03,0.05"])
    res = _run(project)
    assert res.exit_code == 2 and "gcp99" in res.output and "no image measurement" in res.output
    assert _no_output(project)


def test_many_control_points_without_image_measurement_on_one_short_line(project):
    """The demo's first strip alone with the demo's control file: the 214 unmeasured ids stood on one line of
    2,400 characters; now the count, the first 10 and "and N more" (as aerotri import lists them)."""
    ids = [f"gcp{100 + k}" for k in range(214)]
    _edit(project / "control" / "points.csv",
          lambda L: L + [f"{i},full,{420000.0 + k},3380000.0,150.0,0.03,0.03,0.05" for k, i in enumerate(ids)])
    res = _run(project)
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    line = next(x for x in res.output.splitlines() if "no image measurement" in x)
    assert "214 control point(s)" in line and ", ".join(ids[:10]) + " and 204 more" in line and ids[10] not in line
    assert len(line) < 400
    assert _no_output(project)


def test_too_few_control_for_datum(project):
    _edit(project / "control" / "points.csv", lambda L: [L[0]] + [x.replace(",full,", ",check,") for x in L[1:]])
    res = _run(project, "--gnss-correction", "shift")
    assert res.exit_code == 2 and "too few control points for the datum" in res.output
    assert _no_output(project)


def test_disconnected_block(project):
    # keep only tie points seen exclusively within one strip: the two strips fall apart (no longer an error:
    # a part with a datum is adjusted, one without is named and left out)
    import csv

    rows = list(csv.reader((project / "at" / "tiepoints.csv").open()))
    head, body = rows[0], rows[1:]
    strips = {}
    for p, i, *_ in body:
        strips.setdefault(p, set()).add(i[:3])
    body = [r for r in body if len(strips[r[0]]) == 1]
    (project / "at" / "tiepoints.csv").write_text("\n".join(",".join(r) for r in [head] + body) + "\n")
    # control measurements also connect images: drop them from the second strip
    _edit(project / "control" / "image_points.csv", lambda L: [L[0]] + [x for x in L[1:] if ",s01_" in x])
    _edit(project / "control" / "points.csv", lambda L: [L[0]] + [x for x in L[1:] if x.split(",")[0] in
          {r.split(",")[0] for r in (project / "control" / "image_points.csv").read_text().splitlines()[1:]}])
    # GNSS shifts per strip need control, which only strip 1 has: strip 2 is named and left out, strip 1 adjusted
    res = _run(project, "--gnss-correction", "shift")
    assert res.exit_code == 0, res.output
    assert "not adjusted" in res.output
    import json

    left = json.loads((project / "at" / "report.json").read_text())["components"]["left_out"]
    assert len(left) == 1 and left[0]["images"] and all(i.startswith("s02") for i in left[0]["images"])
    assert "control" in left[0]["reason"]


def test_gnss_only_adjustment_without_control(project):
    """The first adjustment of the chain: tie points + GNSS, no control files (or --no-control)."""
    res = _run(project, "--no-control", "--image-sigma-px", "0.3")
    assert res.exit_code == 0, res.output
    import json

    rep = json.loads((project / "at" / "report.json").read_text())
    assert rep["counts"]["control_points"] == 0 and rep["key_statistics"]["success"]
    import shutil

    shutil.rmtree(project / "control")
    (project / "at" / "eo.txt").unlink()
    res = _run(project, "--image-sigma-px", "0.3")
    assert res.exit_code == 0, res.output
    # Strip shifts cannot be separated from the datum without control: refused.
    res = _run(project, "--no-control", "--gnss-correction", "shift")
    assert res.exit_code == 2 and "too few control points for the datum" in res.output


def test_two_control_points_at_one_place_in_a_frame(project):
    """A control measurement under the wrong name (at the pixel of another point of the same frame, within 2 px) is
    refused by name: both points, the frame, the file and its lines."""
    lines = (project / "control" / "image_points.csv").read_text().splitlines()
    first = lines[1].split(",")
    in_frame = {ln.split(",")[0] for ln in lines[1:] if ln.split(",")[1] == first[1]}
    other = next(ln.split(",")[0] for ln in lines[1:] if ln.split(",")[0] not in in_frame)
    x, y = float(first[2]) + 1.2, float(first[3]) - 0.9  # 1.5 px away
    _edit(project / "control" / "image_points.csv", lambda L: L + [f"{other},{first[1]},{x:.3f},{y:.3f}"])
    res = _run(project)
    n = len(lines) + 1  # the added line
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert f"image_points.csv:{n}: points '{first[0]}' and '{other}' are measured 1.5 px apart in frame '{first[1]}' " \
           f"(lines 2 and {n})" in res.output
    assert _no_output(project)
    # 2.5 px apart: two targets side by side, accepted by the reader
    (project / "control" / "image_points.csv").write_text(
        "\n".join(lines + [f"{other},{first[1]},{float(first[2]) + 2.5:.3f},{first[3]}"]) + "\n")
    assert len(read_control_image_points(project / "control" / "image_points.csv")) == len(lines)


def test_plain_tie_file_reads_as_line_by_line(tmp_path, monkeypatch):
    """A plain tiepoints.csv is read by whole-text splits: the same ids, pixels and line numbers as the line-by-line
    reader; a file with a problem the fast path cannot name (a line of 3 fields and one of 5, a duplicate pair, NaN,
    blanks) is refused with its line, as before."""
    import numpy as np

    from aerotri.core.errors import InputError
    from aerotri.geom import observations as O

    rows = [f"p{j},img{i},{100.25 + 3 * j},{200.5 - i}" for j in range(50) for i in range(3)]
    path = tmp_path / "tiepoints.csv"
    path.write_text("point_id,image_id,x_px,y_px\n" + "\n".join(rows) + "\n")
    fast = O.read_image_points(path)
    monkeypatch.setattr(O, "_plain_image_points", lambda text: None)
    slow = O.read_image_points(path)
    monkeypatch.undo()
    assert list(fast.point_id) == list(slow.point_id) and list(fast.image_id) == list(slow.image_id)
    assert np.array_equal(fast.xy_px, slow.xy_px) and np.array_equal(fast.line, slow.line)
    bad = {"fields": rows[:3] + ["p9,img9,1.0", "p8,img8,1.0,2.0,3.0"] + rows[3:],
           "duplicate": rows + [rows[7]], "nan": rows[:5] + ["p99,img1,nan,2.0"],
           "blank": rows[:5] + ["p99, img1,1.0,2.0"]}
    expected = {"fields": ":5: expected 4 fields", "duplicate": f":{len(rows) + 2}: duplicate measurement",
                "nan": ":7: x_px is NaN", "blank": None}
    for name, lines in bad.items():
        path.write_text("point_id,image_id,x_px,y_px\n" + "\n".join(lines) + "\n")
        if expected[name] is None:  # blanks around a field are stripped, as by the line-by-line reader
            assert "img1" in set(O.read_image_points(path).image_id)
            continue
        with pytest.raises(InputError, match=expected[name]):
            O.read_image_points(path)
