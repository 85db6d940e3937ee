"""``ortho mosaic`` resumes the rows of tiles an interrupted run wrote (work/mosaic_resume): a re-run blends only
the rest and commits the outputs of one uninterrupted run, byte for byte."""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import sqlite3

import ortho.mosaic as M
from aerotri.core.errors import InputError
from tests.ortho.test_block_atomic import project, rectified, run  # noqa: F401 (fixtures: a rectified synthetic block)

_BLEND_TILE = M._blend_tile
TILE_PX = "128"


def mosaic(root):
    return run("mosaic", root, "--seams", "voronoi", "--tile-px", TILE_PX, "--scheduler", "synchronous")


def tree(folder) -> dict:
    """sha1 of every file below ``folder``; of a GeoPackage its rows but for the time it was written."""
    out = {}
    for dirpath, _, files in os.walk(folder):
        for n in files:
            p = os.path.join(dirpath, n)
            if n.endswith(".gpkg"):
                with contextlib.closing(sqlite3.connect(p)) as db:
                    rows = [line for line in db.iterdump() if "gpkg_contents" not in line]
                out[os.path.relpath(p, folder)] = hashlib.sha1("\n".join(rows).encode()).hexdigest()
                continue
            out[os.path.relpath(p, folder)] = hashlib.sha1(open(p, "rb").read()).hexdigest()
    return out


class _Blend:
    """``_blend_tile`` counting the tiles it blends; raises ``exc`` at the ``at``-th."""

    def __init__(self, at=None, exc=KeyboardInterrupt):
        self.at, self.exc, self.done = at, exc, 0

    def __call__(self, *args):
        if self.done + 1 == self.at:
            raise self.exc("broken on purpose") if self.exc is InputError else self.exc
        self.done += 1
        return _BLEND_TILE(*args)


def test_a_rerun_resumes_the_rows_an_interrupted_mosaic_wrote(project, monkeypatch, caplog):
    count = _Blend()
    monkeypatch.setattr(M, "_blend_tile", count)
    r = mosaic(project)
    assert r.exit_code == 0, r.output
    total = count.done
    want = tree(project / "ortho")
    cols = -(-json.loads((project / "ortho" / "mosaic.json").read_text())["width"] // int(TILE_PX))
    assert total >= 3 * cols  # at least three rows of tiles
    for name in ("mosaic.tif", "mosaic.json", "seams.tif"):
        (project / "ortho" / name).unlink()

    # Ctrl-C in the middle of the third row: the first two rows are kept
    monkeypatch.setattr(M, "_blend_tile", _Blend(at=2 * cols + 2))
    r = mosaic(project)
    assert r.exit_code != 0 and not (project / "ortho" / "mosaic.tif").exists(), r.output
    keep = project / "work" / "mosaic_resume"
    assert len(list(keep.glob("*.tif"))) == 2

    count = _Blend()
    monkeypatch.setattr(M, "_blend_tile", count)
    with caplog.at_level(logging.INFO, logger="ortho.mosaic"):
        r = mosaic(project)
    assert r.exit_code == 0, r.output
    assert count.done == total - 2 * cols
    assert f"mosaic: resumed {2 * cols} of {total} tiles an interrupted run finished" in caplog.text
    assert tree(project / "ortho") == want
    assert not keep.exists() and [p for p in project.rglob(".*")] == []


def test_other_gains_resume_nothing_and_an_error_leaves_nothing(project, monkeypatch, caplog):
    """The rows' key holds the gains: without balancing no kept row is taken; an error then removes them all."""
    monkeypatch.setattr(M, "_blend_tile", _Blend(at=20))  # 9 tiles a row: two rows kept
    assert mosaic(project).exit_code != 0
    keep = project / "work" / "mosaic_resume"
    assert len(list(keep.glob("*.tif"))) == 2
    before = tree(project)
    count = _Blend()
    monkeypatch.setattr(M, "_blend_tile", count)
    with caplog.at_level(logging.INFO, logger="ortho.mosaic"):
        monkeypatch.setattr(M, "_blend_tile", _Blend(at=3, exc=InputError))
        r = run("mosaic", project, "--seams", "voronoi", "--tile-px", TILE_PX, "--scheduler", "synchronous",
                "--no-balance")
    assert r.exit_code == 2 and "broken on purpose" in r.output, r.output
    assert "resumed" not in caplog.text
    assert tree(project) == {k: v for k, v in before.items() if not k.startswith("work/mosaic_resume/")}
    assert not keep.exists()


def test_a_resumed_edited_mosaic_counts_the_kept_rows_tiles_as_one_run(tmp_path, monkeypatch):
    """An edited mosaic (``--seamlines EDITED.gpkg``) interrupted and resumed: the kept rows' tiles skip the blending
    and were left out of mosaic.json's counts (fewer taken over, more "blended" than the uninterrupted run's)."""
    import shutil

    import rasterio
    import shapely
    from click.testing import CliRunner

    from ortho.cli import main
    from tests.shared_builds import write_synthetic_project
    from tests.ortho.test_seamlines_gpkg import TILE_PX as GPKG_TILE_PX
    from tests.ortho.test_seamlines_gpkg import _moved_edge, _read, _write

    root = tmp_path / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=6, seed=3)
    for args in (["rectify", str(root)], ["mosaic", str(root), "--tile-px", str(GPKG_TILE_PX)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    meta, fids, names, geoms = _read(root / "ortho" / "seamlines.gpkg")
    with rasterio.open(root / "ortho" / "seams.tif") as ds:
        res = ds.res[0]

    def valid_of(k):
        from rasterio import features
        with rasterio.open(root / "ortho" / "frames" / f"{names[k]}.tif") as f:
            m = f.read_masks(1)
            shapes = [shapely.geometry.shape(g) for g, v in features.shapes(m, mask=m > 0, transform=f.transform)]
        return shapely.union_all(shapes).buffer(-2 * res)

    moved, _ = _moved_edge(names, geoms, valid_of)
    edited = tmp_path / "edited.gpkg"
    _write(edited, names, moved, meta["crs"])
    base = tmp_path / "base"
    shutil.copytree(root, base)
    args = ["--tile-px", str(GPKG_TILE_PX), "--seamlines", str(edited), "--scheduler", "synchronous"]
    count = _Blend()
    monkeypatch.setattr(M, "_blend_tile", count)
    r = CliRunner().invoke(main, ["mosaic", str(root), *args])
    assert r.exit_code == 0, r.output
    want = json.loads((root / "ortho" / "mosaic.json").read_text())["tiles"]
    assert 0 < want["blended"] < want["total"]

    # the same edit on a copy of the project before it, interrupted at its last tile to blend: the rows before kept
    monkeypatch.setattr(M, "_blend_tile", _Blend(at=count.done))
    r = CliRunner().invoke(main, ["mosaic", str(base), *args])
    assert r.exit_code != 0
    assert list((base / "work" / "mosaic_resume").glob("*.tif"))
    monkeypatch.setattr(M, "_blend_tile", _BLEND_TILE)
    r = CliRunner().invoke(main, ["mosaic", str(base), *args])
    assert r.exit_code == 0, r.output
    assert json.loads((base / "ortho" / "mosaic.json").read_text())["tiles"] == want


def test_a_resumed_8_bit_dom_counts_the_kept_rows_blended_pixels(project, monkeypatch):
    """Reviewer 13: a resumed 8-bit run's mosaic.json counted the blended pixels of the rows it blended only (519,507
    of 745,725): each kept row's counts (of the samples before the mapping) are now kept with it, and the resumed
    run's mosaic.json is the uninterrupted run's, byte for byte."""
    def mosaic8(root):
        return run("mosaic", root, "--seams", "voronoi", "--tile-px", TILE_PX, "--scheduler", "synchronous",
                   "--output-bits", "8")

    r = mosaic8(project)
    assert r.exit_code == 0, r.output
    want = tree(project / "ortho")
    summary = json.loads((project / "ortho" / "mosaic.json").read_text())
    assert summary["output"]["blended_pixels"] == summary["output"]["valid_pixels"] > 0
    cols = -(-summary["width"] // int(TILE_PX))
    for name in ("mosaic.tif", "mosaic.json", "seams.tif"):
        (project / "ortho" / name).unlink()
    monkeypatch.setattr(M, "_blend_tile", _Blend(at=2 * cols + 2))
    assert mosaic8(project).exit_code != 0
    keep = project / "work" / "mosaic_resume"
    assert len(list(keep.glob(f"*{M.BLENDED_COUNTS_SUFFIX}"))) == 2
    count = _Blend()
    monkeypatch.setattr(M, "_blend_tile", count)
    r = mosaic8(project)
    assert r.exit_code == 0, r.output
    assert tree(project / "ortho") == want


def test_the_8_bit_lookup_table_is_the_recorded_formula_at_half_steps():
    """Reviewer 13: the table was built in float32 (the scale rounded first): at a .5 tie it could round the other
    way than the formula mosaic.json records. Now float64, rounded half to even (numpy's rint), as ``v8`` states."""
    import numpy as np

    m = M.OutputMapping(8, 0.0, 326.0, "test")  # 163 DN -> 127.5 exactly: the float32 table gave 127
    lut = m._lut(np.dtype(np.uint16))
    assert lut[163] == 128 and lut[1] == 1 and lut[326] == 255 and lut[65535] == 255
    x = np.arange(65536, dtype=np.float64)
    assert np.array_equal(lut, np.clip(np.rint(x * 255 / 326), 0, 255).astype(np.uint8))
    assert np.array_equal(m.apply(np.arange(400, dtype=np.float32).reshape(1, 1, -1), np.ones((1, 400), bool))[0, 0],
                          lut[:400])
