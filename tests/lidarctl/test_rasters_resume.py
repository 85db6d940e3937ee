"""`lidarctl rasters` resumes the tiles an interrupted run finished (OUTDIR.resume beside the output folder,
``write_rasters(resume_dir=...)``): a re-run computes only the rest and writes the same bytes."""

from __future__ import annotations

import functools
import signal

import pytest
import tile_faults  # tests/lidarctl/tile_faults.py, through tests/lidarctl/conftest.py
from click.testing import CliRunner

from aerotri.core.errors import InputError
from lidarctl import io, synthetic
from lidarctl.cli.main import main
from lidarctl.rasters import products

FIELDS = ("x", "y", "z", "intensity", "return_number", "number_of_returns")
TILING = ["--res-m", "1", "--tile-px", "64", "--buffer-px", "32"]  # 4 x 4 tiles over the 200 m scene


@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    """A classified 200 m scene (truth classes) in two overlapping strips."""
    d = tmp_path_factory.mktemp("rasters_resume")
    cloud, truth = synthetic.synthetic_scene(width_m=200.0, density_per_m2=2.0, seed=7, n_buildings=5, n_trees=40)
    u = cloud.x - cloud.x.min()
    for name, m in {"west": u < 120.0, "east": u >= 90.0}.items():
        synthetic.write_las(d / f"{name}.las", io.PointCloud(*[getattr(cloud, f)[m] for f in FIELDS], truth[m]),
                            crs="EPSG:32632")
    return [d / "west.las", d / "east.las"]


def _rasters(strips, out, *options):
    return CliRunner().invoke(main, ["rasters", *map(str, strips), str(out), *TILING, *options])


def _tree(folder) -> dict:
    return {f.name: f.read_bytes() for f in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def reference(strips, tmp_path_factory):
    out = tmp_path_factory.mktemp("rasters_ref") / "r"
    r = _rasters(strips, out)
    assert r.exit_code == 0, r.output
    assert sorted(_tree(out)) == sorted(products.FILES) and not (out.parent / "r.resume").exists()
    return _tree(out)


# ``products._tile_grids`` counting the tiles it computes, raising KeyboardInterrupt (or ``exc``) at the ``at``-th
_Tiles = functools.partial(tile_faults.Tiles, products._tile_grids)


@pytest.fixture
def one_thread(monkeypatch):
    """One tile at a time: the interrupt comes at a known tile (the next one queued is cancelled)."""
    monkeypatch.setattr(products, "_tile_threads", lambda cells: 1)


def _kept(folder) -> int:
    return len(list(folder.glob("*.npy")))


def test_rasters_resume_after_ctrl_c(strips, reference, tmp_path, monkeypatch, one_thread):
    """Ctrl-C at the fourth tile: exit 130, no raster written, three tiles kept in r.resume; the next run says so,
    computes the rest and writes the uninterrupted run's bytes (COGs and hillshade), then removes the folder."""
    out, keep = tmp_path / "r", tmp_path / "r.resume"
    monkeypatch.setattr(products, "_tile_grids", _Tiles(at=4))
    r = _rasters(strips, out)
    assert r.exit_code == 130, r.output
    assert _kept(keep) == 3 and not out.exists()  # made by this run: gone with its outputs

    count = _Tiles()
    monkeypatch.setattr(products, "_tile_grids", count)
    r = _rasters(strips, out)
    assert r.exit_code == 0, r.output
    n = count.done + 3
    assert n == 16 and f"tiles: resumed 3 of {n} tiles an interrupted run finished ({keep})" in r.stderr
    assert _tree(out) == reference
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_rasters_changed_setting_resumes_nothing_and_an_error_removes_the_kept(strips, reference, tmp_path,
                                                                               monkeypatch, one_thread):
    """Another --dem-fill-radius-px than the interrupted run's: no tile is taken; an error then removes the kept
    tiles with the outputs (the user's folder that holds them stays); --no-resume starts over."""
    out, keep = tmp_path / "r", tmp_path / "r.resume"
    monkeypatch.setattr(products, "_tile_grids", _Tiles(at=3))
    assert _rasters(strips, out).exit_code == 130 and _kept(keep) == 2

    count = _Tiles(at=5, exc=InputError)
    monkeypatch.setattr(products, "_tile_grids", count)
    r = _rasters(strips, out, "--dem-fill-radius-px", "8")
    assert r.exit_code == 2 and "broken on purpose" in r.stderr and "resumed" not in r.stderr and count.done == 4
    assert not keep.exists() and not out.exists() and tmp_path.is_dir()

    monkeypatch.setattr(products, "_tile_grids", _Tiles(at=3))
    assert _rasters(strips, out).exit_code == 130 and _kept(keep) == 2
    count = _Tiles()
    monkeypatch.setattr(products, "_tile_grids", count)
    r = _rasters(strips, out, "--no-resume")
    tile_faults.check_started_over(r, count, 16, keep, _tree(out), reference)


def test_rasters_sigkill_then_resume(strips, reference, tmp_path, monkeypatch):
    """A `lidarctl rasters` process killed (SIGKILL) as its third tile starts: two tiles kept, no raster; the next
    run sweeps the killed run's temporaries, takes the two and writes the uninterrupted run's bytes."""
    out, keep = tmp_path / "r", tmp_path / "r.resume"
    args = ["rasters", *map(str, strips), str(out), *TILING]
    code = tile_faults.killed_at("lidarctl.rasters.products", "_tile_grids", 3, args,
                                 setup="module._tile_threads = lambda cells: 1  # one tile at a time")
    assert code == -signal.SIGKILL and _kept(keep) == 2
    assert [p.name for p in out.iterdir() if ".part-" not in p.name] == []  # no raster, only the temporaries

    count = _Tiles()
    monkeypatch.setattr(products, "_tile_grids", count)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "tiles: resumed 2 of 16 tiles an interrupted run finished" in r.stderr and count.done == 14
    assert _tree(out) == reference
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]
    assert not [p for p in tmp_path.rglob("*") if ".part-" in p.name or ".commit-" in p.name]


def test_tiles_kept_before_an_algorithm_change_are_not_reused(strips, reference, tmp_path, monkeypatch, one_thread):
    """resume-keys: the key held the toolkit's version (0.1.0, never bumped) only, so tiles kept before a change of
    the grids' algorithm were reused after it. ``products.RASTERS_VERSION`` is in the key: bumped, no tile resumes;
    the same version resumes the kept tiles."""
    out, keep = tmp_path / "r", tmp_path / "r.resume"
    monkeypatch.setattr(products, "_tile_grids", _Tiles(at=3))
    assert _rasters(strips, out).exit_code == 130 and _kept(keep) == 2
    monkeypatch.setattr(products, "RASTERS_VERSION", products.RASTERS_VERSION + 1)
    monkeypatch.setattr(products, "_tile_grids", _Tiles(at=4))
    r = _rasters(strips, out)
    assert r.exit_code == 130 and "resumed" not in r.stderr and _kept(keep) == 2 + 3  # the old two stay unused

    count = _Tiles()
    monkeypatch.setattr(products, "_tile_grids", count)
    r = _rasters(strips, out)  # the same (bumped) version: its three tiles resume
    assert r.exit_code == 0, r.output
    assert count.done == 13 and f"tiles: resumed 3 of 16 tiles an interrupted run finished ({keep})" in r.stderr
    assert _tree(out) == reference
