"""bench/eval_real_blocks.py's by-hand step after the EXIF import: the take-off height goes into project.toml only
where the import did not write ``[flight] mean_terrain_height_m`` (a second [flight] table is invalid TOML, and
every later command of the block stopped on it)."""

from __future__ import annotations

import importlib.util
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
NOTE = "flight: project.toml gets [flight] mean_terrain_height_m = 158.5, with which aerotri match pairs the frames"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_eval_real_blocks", ROOT / "bench" / "eval_real_blocks.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


WRITTEN = '[project]\nname = "p"\n\n[flight]\nmean_terrain_height_m = 158.5  # aerotri import\n'
COMMENTED = '[project]\nname = "p"\n# [flight]\n# mean_terrain_height_m = 0.0\n'
BY_HAND = "(by hand) p/project.toml: [flight] mean_terrain_height_m = 158.5 (the import's note)"


@pytest.mark.parametrize("config, note, height_m, flight, by_hand", [
    (WRITTEN, NOTE, 158.5, {"mean_terrain_height_m": 158.5}, []),  # the import wrote it: nothing by hand
    (COMMENTED, NOTE, 158.5, {"mean_terrain_height_m": 158.5}, [BY_HAND]),
    ('[project]\nname = "p"\n', "imported 4 frames", None, None, []),  # no height stated: nothing written
])
def test_flight_height_from_import(bench, tmp_path, config, note, height_m, flight, by_hand):
    toml = tmp_path / "p" / "project.toml"
    toml.parent.mkdir()
    toml.write_text(config)
    r = bench.Runner(tmp_path, tmp_path / "data")
    assert bench._flight_height_from_import(r, toml.parent, note) == height_m
    assert tomllib.loads(toml.read_text()).get("flight") == flight  # valid TOML: one [flight] table
    assert [c["command"] for c in r.commands] == by_hand
