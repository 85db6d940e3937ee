"""Frames left out of the mosaic (``ortho mosaic --exclude`` / ``[mosaic] exclude``): a re-flown strip's frames, a
cloud, a bad exposure (second-day trial s97: the re-flown strip's colour pulled the whole DOM, and no frame could be
kept out but by editing every polygon). Truth: the mosaic of a project whose frame orthos never held the frame."""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pyogrio
import pytest
import rasterio
import shapely
from click.testing import CliRunner

from ortho.cli import main
from tests.shared_builds import write_synthetic_project

LEFT_OUT = "s01_002"


@pytest.fixture(scope="module")
def rectified(tmp_path_factory):
    root = tmp_path_factory.mktemp("exclude") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=6, seed=3)
    r = CliRunner().invoke(main, ["rectify", str(root)])
    assert r.exit_code == 0, r.output
    return root


def _pixels(path) -> str:
    with rasterio.open(path) as ds:
        return hashlib.sha256(ds.read().tobytes() + ds.read_masks(1).tobytes()).hexdigest() + str(ds.transform)


def test_a_frame_left_out_is_as_if_it_had_never_been_rectified(rectified, tmp_path):
    root, without = tmp_path / "p", tmp_path / "without"
    shutil.copytree(rectified, root)
    shutil.copytree(rectified, without, ignore=shutil.ignore_patterns("ortho"))
    others = [f for f in json.loads((root / "ortho" / "frames" / "index.json").read_text())["frames"]
              if f["image_id"] != LEFT_OUT]
    r = CliRunner().invoke(main, ["rectify", str(without), "--frames", ",".join(f["image_id"] for f in others)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["mosaic", str(without)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["mosaic", str(root), "--exclude", LEFT_OUT])
    assert r.exit_code == 0, r.output
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    assert summary["frames"] == len(others) and summary["excluded"] == [LEFT_OUT]
    assert LEFT_OUT not in summary["gains"]
    assert summary["settings"]["exclude"] == {"value": [LEFT_OUT], "source": "command line"}
    assert _pixels(root / "ortho" / "mosaic.tif") == _pixels(without / "ortho" / "mosaic.tif")
    meta, _, wkb, fields = pyogrio.raw.read(root / "ortho" / "seamlines.gpkg")
    assert LEFT_OUT not in set(fields[list(meta["fields"]).index("frame")])
    # the same from project.toml, and its frame ortho kept
    with open(root / "project.toml", "a") as f:
        f.write(f'\n[mosaic]\nexclude = ["{LEFT_OUT}"]\n')
    r = CliRunner().invoke(main, ["mosaic", str(root)])
    assert r.exit_code == 0, r.output
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    assert summary["settings"]["exclude"]["source"] == "project.toml" and summary["excluded"] == [LEFT_OUT]
    assert _pixels(root / "ortho" / "mosaic.tif") == _pixels(without / "ortho" / "mosaic.tif")
    assert (root / "ortho" / "frames" / f"{LEFT_OUT}.tif").is_file()
    # an edited GeoPackage that still gives the frame a polygon: named as left out
    meta, fids, wkb, fields = pyogrio.raw.read(without / "ortho" / "seamlines.gpkg", return_fids=True)
    names = list(fields[list(meta["fields"]).index("frame")])
    geoms = list(shapely.from_wkb(wkb))
    names[0] = LEFT_OUT
    edited = tmp_path / "edited.gpkg"
    pyogrio.raw.write(str(edited), shapely.to_wkb(np.array(geoms, dtype=object)), [np.array(names, dtype=object)],
                      ["frame"], layer="seamlines", driver="GPKG", geometry_type="MultiPolygon", crs=meta["crs"])
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seamlines", str(edited)])
    assert r.exit_code == 2 and f"frame {LEFT_OUT} is left out of the mosaic" in r.output, r.output


@pytest.mark.parametrize("given, said", [
    ("no_such_frame", "no_such_frame (command line): not a frame of"),
    ("s01_001,s01_002,s01_003,s02_001,s02_002,s02_003", "leaves out every frame"),
])
def test_an_exclude_list_that_names_no_frame_or_every_frame_is_refused(rectified, tmp_path, given, said):
    root = tmp_path / "p"
    shutil.copytree(rectified, root)
    names = [f["image_id"] for f in json.loads((root / "ortho" / "frames" / "index.json").read_text())["frames"]]
    assert sorted(names) == sorted(given.split(",")) or "no_such" in given
    before = sorted(p.name for p in (root / "ortho").iterdir())
    r = CliRunner().invoke(main, ["mosaic", str(root), "--exclude", given])
    assert r.exit_code == 2 and said in r.output and "--exclude" in r.output and "Traceback" not in r.output
    assert sorted(p.name for p in (root / "ortho").iterdir()) == before
