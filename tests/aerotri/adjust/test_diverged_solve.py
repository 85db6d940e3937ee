"""A solve that diverges is "Solution failed", exit 2, not a traceback (trial-messy F1): one control height typed in
feet (312.97 m as 1026.80) on the tiny block; the snooping left the point out, the second solve (the principal point
fixed as not determinable) diverged to an infinite covariance, and the calibration groups' check stopped on numpy's
"SVD did not converge" (LinAlgError, exit 1, LAPACK's DLASCL messages)."""

from __future__ import annotations

import csv

from click.testing import CliRunner

from aerotri.cli import main
from aerotri.sim.command import simulate_command


def test_a_control_height_in_feet_fails_the_solution_without_a_traceback(tmp_path):
    root = tmp_path / "blk"
    simulate_command("tiny", root, seed=0, observations_only=True)
    path = root / "control" / "points.csv"
    rows = list(csv.DictReader(path.open()))
    rows[0]["z"] = f"{float(rows[0]['z']) / 0.3048:.4f}"
    with path.open("w") as f:
        f.write(",".join(rows[0]) + "\n" + "".join(",".join(r.values()) + "\n" for r in rows))
    r = CliRunner().invoke(main, ["adjust", str(root), "--dem", str(root / "dem.tif")])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and "Solution failed" in r.output, r.output
    assert f"{rows[0]['id']} w = " in r.output  # the point the snooping left out, named
    assert "determined by" not in r.output  # no shares of infinite variances ("image 7727 %")
    assert not (root / "at" / "report.json").exists()  # the failed solve's report apart (work/adjust_failed)
